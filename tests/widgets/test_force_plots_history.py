"""widgets/ring_plot.py TraceHistory: bounded memory, exact recent data, peaks kept when decimated."""

from __future__ import annotations

import numpy as np
import pytest

from widgets.ring_plot import TraceHistory


def feed(history: TraceHistory, n_samples: int, rate_hz: float, block: int = 7, spike_at: int | None = None):
    rng = np.random.default_rng(0)
    t_all = np.arange(n_samples) / rate_hz
    y_all = np.sin(t_all)[:, None] + 0.01 * rng.standard_normal((n_samples, history.n_channels))
    if spike_at is not None:
        y_all[spike_at, 1] = 50.0
    for start in range(0, n_samples, block):
        history.append(t_all[start:start + block], y_all[start:start + block])
    return t_all, y_all.astype(np.float32)


def test_recent_window_is_exact():
    history = TraceHistory(3, capacity=1000)
    t, y = feed(history, 600, 30.0)
    window = history.window(t[500], t[-1], max_points=1000)
    assert window.level == 0
    np.testing.assert_array_equal(window.t_s, t[499:])
    np.testing.assert_array_equal(window.low, y[499:])
    assert history.latest()[0] == pytest.approx(t[-1])


def test_memory_is_fixed_and_old_data_stays_browsable_coarsely():
    history = TraceHistory(2, capacity=256, levels=3, factor=8)
    nbytes = history.nbytes
    t, y = feed(history, 20_000, 100.0, block=33, spike_at=1000)
    assert history.nbytes == nbytes
    assert len(history) == 256
    oldest, newest = history.span()
    assert newest == pytest.approx(t[-1])
    assert oldest < t[-256] - 100  # much older than level 0 alone could hold
    window = history.window(oldest, newest, max_points=200)
    assert window.t_s.size <= 2 * 200
    assert window.level >= 1
    assert window.high[:, 1].max() == pytest.approx(50.0)  # the single-sample spike survives decimation
    assert np.all(np.diff(window.t_s) > 0)


def test_dense_window_is_peak_decimated_to_the_budget():
    history = TraceHistory(2, capacity=50_000)
    t, _ = feed(history, 30_000, 100.0, block=100, spike_at=12_345)
    window = history.window(t[0], t[-1], max_points=500)
    assert window.t_s.size <= 600
    x, y = window.peak_interleaved(1)
    assert x.size == 2 * window.t_s.size
    assert y.max() == pytest.approx(50.0)
    assert window.t_s[-1] == pytest.approx(t[-1], abs=0.02)


def test_value_at_finds_nearest_sample():
    history = TraceHistory(2, capacity=100)
    t, y = feed(history, 90, 10.0)
    found_t, values = history.value_at(t[40] + 0.01)
    assert found_t == pytest.approx(t[40])
    np.testing.assert_allclose(values, y[40])


def test_shape_mismatch_raises_and_budget_is_respected():
    history = TraceHistory.for_budget(36, 4_000_000)
    assert 3_000_000 < history.nbytes <= 4_200_000
    with pytest.raises(ValueError, match="N×36"):
        history.append(np.zeros(2), np.zeros((2, 35)))


def test_channel_subset_matches_full_query():
    history = TraceHistory(5, capacity=200, levels=2, factor=4)
    t, _ = feed(history, 3000, 100.0, block=13)
    for t0, t1, points in ((t[-100], t[-1], 500), (t[0], t[-1], 50)):
        full = history.window(t0, t1, points)
        part = history.window(t0, t1, points, channels=np.array([3, 1]))
        np.testing.assert_array_equal(part.t_s, full.t_s)
        np.testing.assert_array_equal(part.low, full.low[:, [3, 1]])
        np.testing.assert_array_equal(part.high, full.high[:, [3, 1]])


def test_a_history_s_memory_is_committed_a_huge_page_at_a_time(monkeypatch):
    """The kernel holds the process's memory map lock for all of one madvise call and the GUI thread's allocations
    wait for it: the commit asks for at most ``COMMIT_CHUNK_BYTES`` a call, and covers every byte of the arrays."""
    import mmap

    from widgets import ring_plot

    calls: list[tuple[int, int]] = []
    rests: list[float] = []
    call_s = 0.05  # each call as slow as the kernel short of huge pages (16-23 ms seen), to see the rests' budget

    class FakeClock:
        now_s = 0.0

        @classmethod
        def perf_counter(cls) -> float:
            return cls.now_s

        @staticmethod
        def sleep(seconds: float) -> None:
            rests.append(seconds)

    class FakeLibc:
        @staticmethod
        def madvise(address: int, length: int, advice: int) -> int:
            assert advice == ring_plot.MADV_POPULATE_WRITE
            calls.append((address, length))
            FakeClock.now_s += call_s
            return 0

    monkeypatch.setattr(ring_plot.sys, "platform", "linux")
    monkeypatch.setattr(ring_plot.ctypes, "CDLL", lambda *_a, **_k: FakeLibc())
    monkeypatch.setattr(ring_plot, "time", FakeClock)
    array = np.empty(5 * ring_plot.COMMIT_CHUNK_BYTES + 12345, dtype=np.uint8)
    thread = ring_plot.commit_memory([array])
    assert thread is not None
    thread.join(timeout=10)
    calls = calls[1:]  # the first is commit_memory's one-byte probe
    assert len(calls) >= 6 and all(length <= ring_plot.COMMIT_CHUNK_BYTES for _address, length in calls)
    start = array.ctypes.data & ~(mmap.PAGESIZE - 1)
    assert calls[0][0] == start
    for (address, length), (following, _length) in zip(calls, calls[1:]):
        assert following == address + length  # contiguous, nothing skipped
    assert calls[-1][0] + calls[-1][1] == array.ctypes.data + array.nbytes
    # A slow call is followed by a rest four times as long, until the rests' budget is spent; then the short pause.
    assert rests[0] == pytest.approx(ring_plot.COMMIT_REST_PER_BUSY * call_s)
    assert sum(rests) <= ring_plot.COMMIT_REST_BUDGET_S + len(rests) * ring_plot.COMMIT_PAUSE_S
    assert rests[-1] == ring_plot.COMMIT_PAUSE_S
