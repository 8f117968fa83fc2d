"""The Forces tab's history estimated again (app/gui/forces_history.py): what the GUI thread does is a copy only."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from app.gui import forces_history
from widgets.ring_plot import TraceHistory

CEILING_S = 1.0 / 10e3  # 100 µS


class _Board:
    """What snapshot() reads of a BoardBridge: its history, its last block, its clock."""

    def __init__(self, history: TraceHistory, t_s: np.ndarray) -> None:
        self.history = history
        self._last = SimpleNamespace(board_time_s=t_s[-1:] + 5.0, host_time_s=t_s[-1:])

    def recent_blocks(self) -> list[SimpleNamespace]:
        return [self._last]

    def to_session_time(self, host_t_s: np.ndarray) -> np.ndarray:
        return host_t_s


def test_the_snapshot_is_a_copy_as_stored_and_the_worker_converts_it_a_chunk_at_a_time() -> None:
    """On the GUI thread the history is copied as stored (float32 µS: a copy, not a conversion of hours of data);
    the worker's chunks in S are what converting it whole gave, readings within float32 rounding of the readout's
    ceiling put at the ceiling and gaps (NaN rows) kept."""
    n = 2 * forces_history.CHUNK_SAMPLES + 7
    t_s = np.arange(n) / 30.0
    values_us = np.random.default_rng(1).uniform(1.0, 90.0, (n, 4)).astype(np.float32)
    values_us[5, 2] = np.float32(CEILING_S * 1e6)  # at the ceiling, as float32 stores it
    values_us[9] = np.nan  # a gap
    history = TraceHistory(4, 4 * n)
    history.append(t_s, values_us)
    source = forces_history.snapshot(_Board(history, t_s), CEILING_S)
    assert source is not None and source.conductance_us.dtype == np.float32
    assert source.board_minus_session_s == 5.0 and source.span_s == t_s[-1]
    chunks = [source.conductance_s(start, start + forces_history.CHUNK_SAMPLES)
              for start in range(0, n, forces_history.CHUNK_SAMPLES)]
    whole = np.concatenate(chunks)
    assert whole.dtype == np.float64 and whole.shape == (n, 4)
    assert whole[5, 2] == CEILING_S  # exactly: the estimator tells saturated from above the ceiling by 1e-9
    assert np.isnan(whole[9]).all()
    expected = values_us.astype(np.float64) / 1e6
    expected[5, 2] = CEILING_S
    np.testing.assert_array_equal(whole, expected)
    history.append(t_s[-1:] + 1.0, values_us[:1] + 1.0)  # the board goes on: the snapshot does not change
    assert source.session_t_s.size == n and source.conductance_us[0, 0] == values_us[0, 0]


def test_the_worker_estimates_one_chunk_per_turn_of_the_gui_threads_event_loop() -> None:
    """After each chunk the worker asks the GUI thread for a turn (``post``) and waits until that turn has run: the
    interpreter lock is the GUI thread's between chunks, whatever the worker has left to do."""
    import threading

    from app.core.forces_pipeline import ForcesPipeline

    n = 3 * forces_history.CHUNK_SAMPLES + 11
    t_s = np.arange(n) / 30.0
    history = TraceHistory(4, 4 * n)
    history.append(t_s, np.random.default_rng(2).uniform(1.0, 90.0, (n, 4)).astype(np.float32))
    turns: list = []  # the GUI thread's queue of posted calls, run by this test when it chooses
    posted = threading.Condition()

    def post(fn) -> None:
        with posted:
            turns.append(fn)
            posted.notify_all()

    done = threading.Event()
    job = forces_history.Reestimation(ForcesPipeline(("a", "b", "c", "d")), forces_history.snapshot(
        _Board(history, t_s), CEILING_S), 1_000_000, post=post)
    job.start(lambda _job: done.set())
    for chunk in range(4):
        with posted:
            assert posted.wait_for(lambda k=chunk: len(turns) > k, timeout=10.0)
        assert not done.wait(0.05)  # waiting for the turn asked for after this chunk, nothing more done
        assert len(turns) == chunk + 1
        turns[chunk]()  # the GUI thread's turn
    assert done.wait(10.0)
    assert job.error == "" and job.history is not None and job.history.span()[1] == t_s[-1]
