"""A long motion-capture take is read back without holding it: 200,000 frames (3.5 min at 960 Hz) written in blocks
(tests/mocap_long_takes.py), whose segment centres are a known function of the frame, so that every value a reader
returns is checked against the frame it says it is. The Python heap's peak (tracemalloc: numpy's arrays are traced)
is compared with the size of what the reader would have held whole."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from app.core import mocap, repeatability
from tests.app.synthetic_trials import write_trial
from tests.mocap_long_takes import RATE_HZ, add_long_take, centers_at

FRAMES = 200_000


@pytest.fixture(scope="module")
def long_take(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic trial recording (forces, goals, /sim) with the long take's /mocap added."""
    path = write_trial(tmp_path_factory.mktemp("long") / "long.h5")
    add_long_take(path, FRAMES)
    return path


def _peak_bytes(call: Callable[[], Any]) -> tuple[Any, int]:
    tracemalloc.start()
    try:
        result = call()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _frames(time_s: np.ndarray) -> np.ndarray:
    """The frame indices of the times a reader returned (frame i is at i / RATE_HZ)."""
    frames = np.rint(time_s * RATE_HZ).astype(int)
    np.testing.assert_allclose(frames / RATE_HZ, time_s, rtol=0, atol=1e-12)
    return frames


def _whole_bytes(path: Path, *names: str) -> int:
    with h5py.File(path, "r") as f:
        return sum(int(np.prod(f[name].shape)) * f[name].dtype.itemsize for name in names)


def _head_crossing(first: int, last: int, level: float) -> float:
    """When the head's x, taken at every frame from ``first`` to ``last`` (the only crossing: it only moves on),
    rises past ``level``, linear between frames."""
    frames = np.arange(first, last)
    x = centers_at(frames)[:, 0, 0]
    i = int(np.flatnonzero((x[:-1] < level) & (x[1:] >= level))[0])
    return float((frames[i] + (level - x[i]) / (x[i + 1] - x[i])) / RATE_HZ)


def test_the_figure_reads_a_few_thousand_frames_of_a_long_take_and_says_so(long_take: Path) -> None:
    (time_s, centers, what), peak = _peak_bytes(lambda: mocap.segment_positions(long_take, "mocap"))
    whole = _whole_bytes(long_take, "mocap/time_s", "mocap/segment_center_m")  # 59 MB
    assert peak < whole / 10, f"peak {peak / 2**20:.1f} MB of {whole / 2**20:.0f} MB"
    step = -(-FRAMES // mocap.PLOT_FRAMES)
    frames = _frames(time_s)
    np.testing.assert_array_equal(frames, np.arange(0, FRAMES, step))
    assert len(frames) <= mocap.PLOT_FRAMES
    np.testing.assert_array_equal(centers, centers_at(frames))  # NaN where segment 7 had no pose, too
    assert np.isnan(centers[:, 6, 0]).any()
    assert f"one frame in {step} shown ({len(frames):,} of {FRAMES:,}, {RATE_HZ / step:.3g} Hz)" in what


def test_a_short_take_is_read_whole(tmp_path: Path) -> None:
    short = tmp_path / "short.h5"
    add_long_take(short, 900)
    time_s, centers, what = mocap.segment_positions(short, "mocap")
    np.testing.assert_array_equal(_frames(time_s), np.arange(900))
    assert "shown" not in what
    record = mocap.read_mocap(short)
    assert record is not None and record.frame_step == 1 and record.markers_m.shape == (900, 48, 3)
    np.testing.assert_array_equal(record.segment_center_m, centers_at(np.arange(900)))
    assert mocap.read_mocap(short, max_frames=None).time_s.shape == (900,)  # type: ignore[union-attr]
    few = mocap.read_mocap(short, max_frames=100)
    assert few is not None and few.frame_step == 9
    np.testing.assert_array_equal(_frames(few.time_s), np.arange(0, 900, 9))


def test_read_mocap_reads_a_long_take_every_kth_frame(long_take: Path) -> None:
    record, peak = _peak_bytes(lambda: mocap.read_mocap(long_take))
    assert record is not None
    names = ("time_s", "segment_center_m", "segment_rotation", "residual_m", "markers_m")
    whole = _whole_bytes(long_take, *(f"mocap/{name}" for name in names))  # 480 MB
    held = sum(getattr(record, name).nbytes for name in names)  # RECORD_FRAMES of them, ~120 MB
    assert peak < 1.05 * held < 0.3 * whole, f"peak {peak / 2**20:.1f} MB, held {held / 2**20:.0f} MB"
    step = -(-FRAMES // mocap.RECORD_FRAMES)
    assert (record.frame_step, record.frames_in_file) == (step, FRAMES)
    frames = _frames(record.time_s)
    np.testing.assert_array_equal(frames, np.arange(0, FRAMES, step))
    np.testing.assert_array_equal(record.segment_center_m, centers_at(frames))
    assert record.markers_m.shape == (len(frames), 48, 3) and record.residual_m.shape == (len(frames), 12)


def test_aligning_on_a_position_finds_the_crossing_at_full_rate_without_holding_the_take(long_take: Path) -> None:
    """The head passes the level between frames 123,456 and 123,457 (in a later block than the first the alignment
    reads, between two frames the trial's own positions skip): the crossing is found between those two, as from the
    take held whole (the tremor makes one found from every k-th frame differ by ~0.3 ms)."""
    level = float(np.mean(centers_at(np.array([123_456, 123_457]))[:, 0, 0]))
    options = repeatability.AlignOptions("mocap", position_x_m=level)

    def load_and_align() -> tuple[repeatability.Trial, float]:
        trial = repeatability.load_trial(long_take)
        return trial, repeatability.event_time(trial, options)

    (trial, when), peak = _peak_bytes(load_and_align)
    whole = _whole_bytes(long_take, "mocap/time_s", "mocap/segment_center_m")
    assert peak < whole / 10, f"peak {peak / 2**20:.1f} MB of {whole / 2**20:.0f} MB"
    assert when == pytest.approx(_head_crossing(123_000, 124_000, level), abs=1e-9)
    assert 123_456 / RATE_HZ < when < 123_457 / RATE_HZ
    assert trial.position_source == "mocap" and trial.segment_x_m is not None and trial.position_time_s is not None
    step = -(-FRAMES // repeatability.POSITION_FRAMES)
    assert trial.position_step == step and step > 1
    frames = _frames(trial.position_time_s)
    np.testing.assert_array_equal(frames, np.arange(0, FRAMES, step))
    np.testing.assert_array_equal(trial.segment_x_m, centers_at(frames)[..., 0])
    moved = repeatability.event_time(trial, repeatability.AlignOptions("mocap", position_move_m=0.01))
    assert moved == pytest.approx(_head_crossing(0, 1_000, 0.01), abs=1e-9)  # 1 cm past its start, ~0.2 s in
