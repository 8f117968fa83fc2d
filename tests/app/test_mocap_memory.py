"""A motion-capture take is written into its recording as it comes: memory stays bounded whatever its length, and
``/mocap`` is what the take written whole at the end made of it. The take is generated (tests/mocap_takes.py) and
fed straight into the inlet: no Lab Streaming Layer."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.mocap_takes import record_generated_take
from tests.waiting import wait_until

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "mocap_live_reference.npz"
ROOT = Path(__file__).resolve().parents[2]

GROWTH = """
import json, resource, sys, tempfile, os
from tests.mocap_takes import record_generated_take
from tests.waiting import wait_until
with tempfile.TemporaryDirectory() as tmp:
    record_generated_take(os.path.join(tmp, "short.h5"), 5.0)
    short = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    record_generated_take(os.path.join(tmp, "long.h5"), float(sys.argv[1]))
    long = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"growth_mb": (long - short) / 1024}))
"""


def test_mocap_is_what_the_take_written_whole_at_the_end_made_of_it(tmp_path: Path) -> None:
    """The reference is the /mocap that fitting and writing the whole take when the recording closed wrote, for
    the same generated take (dropout, a segment with two markers hidden, samples before the recording began)."""
    path = tmp_path / "take.h5"
    line = record_generated_take(path, 0.6)
    assert "432 samples" in line and "1 dropout(s), 96 sample(s) missing" in line
    reference = np.load(REFERENCE)
    with h5py.File(path, "r") as f:
        group = f["mocap"]
        assert sorted(group) == sorted(k for k in reference.files if k != "attrs")
        for name in group:
            ours, theirs = group[name][:], reference[name]
            assert ours.dtype == theirs.dtype and ours.shape == theirs.shape, name
            if name == "time_s":  # the recording's start differs between runs: its float rounding too
                np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9)
            elif ours.dtype.kind == "f":  # the same fit, to the last few bits (numpy's and scipy's builds differ there)
                np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12, equal_nan=True, err_msg=name)
            else:
                assert np.array_equal(ours, theirs), name
        attrs = json.loads(str(reference["attrs"]))
        assert sorted(group.attrs) == sorted(attrs)
        for key, value in group.attrs.items():
            value = value.tolist() if hasattr(value, "tolist") else value
            if isinstance(value, list) and value and isinstance(value[0], bytes):
                value = [v.decode() for v in value]
            expected = attrs[key]
            if isinstance(expected, float) and np.isnan(expected):
                assert np.isnan(value), key
            else:
                assert value == expected, key


def test_recording_a_long_take_takes_no_more_memory_than_a_short_one() -> None:
    """Peak resident memory after a 60 s take at 960 Hz (57 600 frames) over that after a 5 s one: kept whole, a
    minute grew it by ~380 MB; written as it comes, by a few MB whatever the length."""
    out = subprocess.run([sys.executable, "-c", GROWTH, "60"], capture_output=True, text=True, cwd=ROOT,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    growth = json.loads(out.stdout.strip().splitlines()[-1])["growth_mb"]
    assert growth < 40.0, f"peak memory grew by {growth:.0f} MB"


def test_the_replay_of_a_take_longer_than_it_holds_reads_every_kth_frame(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """The 3-D tab replays the written take; a take over MAX_MOCAP_FRAMES (here 100) is read every k-th frame."""
    from app.core import replay

    path = tmp_path / "take.h5"
    record_generated_take(path, 0.6)
    whole = replay.open_replay(path)
    monkeypatch.setattr(replay, "MAX_MOCAP_FRAMES", 100)
    thinned = replay.open_replay(path)
    with h5py.File(path, "r") as f:
        time_s = f["mocap/time_s"][:]
    track, few = whole.tracks[0], thinned.tracks[0]
    assert track.source == few.source == replay.MOCAP and track.points_m is not None
    np.testing.assert_array_equal(track.time_s, time_s)
    np.testing.assert_array_equal(few.time_s, time_s[::5])  # 432 frames: every 5th, 87 of them
    np.testing.assert_array_equal(few.points_m, track.points_m[::5])


def test_the_take_is_in_the_file_on_disk_while_the_recording_runs(tmp_path: Path) -> None:
    """Flushed with the recording's other groups (at least every 0.5 s): a crash would keep what came before it."""
    path = tmp_path / "take.h5"
    seen: list[int] = []

    def rows_on_disk() -> int:
        try:
            with h5py.File(path, "r", locking=False) as f:
                return int(f["mocap/segment_center_m"].shape[0]) if "mocap" in f else 0
        except (OSError, KeyError):  # caught between the writer's steps, or not yet moved into place
            return 0

    def check() -> None:
        assert wait_until(lambda: rows_on_disk() == 432, 30.0), f"{rows_on_disk()} rows on disk"
        with h5py.File(path, "r", locking=False) as f:
            seen.append(int(f["mocap/time_s"].shape[0]))
            assert f["mocap"].attrs["rate_hz"] == 960.0 and f["mocap"].attrs["clock_offset_s"] == 0.0

    record_generated_take(path, 0.6, before_stop=check)
    assert seen == [432]
