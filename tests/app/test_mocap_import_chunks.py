"""`sensnake mocap import` of a C3D take reads, fits and writes it a block of frames at a time: the copy's ``/mocap``
is the same, bit for bit, whatever the block (and as the whole take fitted at once makes it), the memory it holds
does not grow with the take beyond the joint angles the clock offset needs, and a refusal leaves nothing behind."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest

from app.cli.main import main
from app.core.mocap import (
    ImportedTake,
    import_take,
    open_c3d,
    place_take,
    read_c3d,
    summary_lines,
    write_with_mocap,
)
from app.core.recording import open_recording
from devices.config import LabConfig
from models.errors import OffsetRefusedError
from tests.mocap_c3d_takes import RATE_HZ, Motion, write_c3d, write_recording

FRAMES = 6_100  # not a multiple of the block: the last block is short
TAKE_START_S = -1.234


@pytest.fixture(scope="module")
def take_and_recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("chunks")
    motion = write_c3d(folder / "take.c3d", FRAMES, block_frames=4_000)
    write_recording(folder / "rec.h5", motion, FRAMES / RATE_HZ - 2.0, TAKE_START_S)
    return folder / "take.c3d", folder / "rec.h5"


def _import(take: Path, rec: Path, out: Path, chunk_frames: int, take_start_s: float | None = None,
            calls: list[tuple[int, int]] | None = None) -> ImportedTake:
    config = LabConfig()
    recording = open_recording(rec)
    assert recording.robot is not None
    return import_take(open_c3d(take, config.mocap, 12), rec, out, config.mocap, config.robot.axes,
                       recording.robot.time_s, recording.robot.present_rad, take_start_s=take_start_s,
                       chunk_frames=chunk_frames, progress=None if calls is None else lambda *a: calls.append(a))


def _same_mocap(a: Path, b: Path) -> None:
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        ga, gb = fa["mocap"], fb["mocap"]
        assert sorted(ga) == sorted(gb)
        for name in ga:
            da, db = ga[name], gb[name]
            assert (da.shape, da.dtype, da.chunks, da.compression) == (db.shape, db.dtype, db.chunks, db.compression), \
                name
            assert np.array_equal(da[:], db[:], equal_nan=True), name
            if da.chunks is not None:  # whole frames a chunk: a reader of frames reads no other frames' columns
                assert da.chunks[1:] == da.shape[1:] and 16 <= da.chunks[0] <= 1 + (1 << 18) // da[0].nbytes, name
        assert sorted(ga.attrs) == sorted(gb.attrs)
        for key in ga.attrs:
            va, vb = ga.attrs[key], gb.attrs[key]
            if isinstance(va, np.ndarray) and va.dtype.kind == "f":
                assert np.array_equal(va, vb, equal_nan=True), key
            elif isinstance(va, float) and np.isnan(va):
                assert np.isnan(vb), key
            else:
                assert np.all(va == vb), key


def test_a_take_imported_in_blocks_of_1000_frames_is_the_take_imported_whole(take_and_recording: tuple[Path, Path],
                                                                            tmp_path: Path) -> None:
    take, rec = take_and_recording
    calls: list[tuple[int, int]] = []
    small = _import(take, rec, tmp_path / "small.h5", chunk_frames=1_000, calls=calls)
    assert calls == [(min(done, FRAMES), FRAMES) for done in range(1_000, FRAMES + 1_000, 1_000)]  # block by block
    one = _import(take, rec, tmp_path / "one.h5", chunk_frames=FRAMES)
    assert small.clock_offset_s == one.clock_offset_s  # the same angles in: the same offset, exactly
    assert small.clock_offset_s == pytest.approx(TAKE_START_S, abs=1e-3)
    _same_mocap(tmp_path / "small.h5", tmp_path / "one.h5")
    # and as the whole take, fitted at once in memory, is written
    config = LabConfig()
    recording = open_recording(rec)
    assert recording.robot is not None
    whole = place_take(read_c3d(take, config.mocap, 12), config.mocap, config.robot.axes, recording.robot.time_s,
                       recording.robot.present_rad)
    write_with_mocap(rec, tmp_path / "whole.h5", whole)
    _same_mocap(tmp_path / "small.h5", tmp_path / "whole.h5")
    assert summary_lines(small) == summary_lines(ImportedTake.of(whole)) == summary_lines(one)
    # every path of the fit was taken, so the comparison covered it
    assert all(small.flag_counts[flag] > 0 for flag in small.flag_counts if flag.name != "BAD_FIT")
    assert small.median_residual_m == float(np.median(whole.fit.residual_m[np.isfinite(whole.fit.center_m[..., 0])]))


def test_the_import_holds_the_joint_angles_not_the_take(take_and_recording: tuple[Path, Path], tmp_path: Path) -> None:
    """Python's heap (numpy's arrays) at its peak while importing the take in blocks of 2,000 frames, against the
    same import of a take twice as long: it grows by what is kept a frame (joint angles, times: ~100 bytes), not by
    the take's markers and poses (~5 kB a frame fitted whole)."""
    take, rec = take_and_recording
    long_take = tmp_path / "long.c3d"
    write_c3d(long_take, 2 * FRAMES, block_frames=4_000, motion=Motion(FRAMES / RATE_HZ))

    def peak(path: Path, out: Path) -> int:
        tracemalloc.start()
        try:
            _import(path, rec, out, chunk_frames=2_000, take_start_s=0.0)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    short_peak = peak(take, tmp_path / "a.h5")
    long_peak = peak(long_take, tmp_path / "b.h5")
    grown = (long_peak - short_peak) / FRAMES
    assert grown < 400, f"{grown:.0f} bytes more a frame at the peak (short {short_peak / 1e6:.1f} MB)"


def test_a_take_the_motion_cannot_place_leaves_no_file(take_and_recording: tuple[Path, Path], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """The offset is found after the take is written to the hidden copy: the refusal removes it."""
    take, _ = take_and_recording
    still = tmp_path / "still.h5"
    write_recording(still, Motion(10.0, seed=5), 10.0, 0.0)  # another motion: nothing lines up
    out = tmp_path / "out.h5"
    with pytest.raises(OffsetRefusedError):
        _import(take, still, out, chunk_frames=1_000)
    assert not out.exists() and not list(tmp_path.glob(".*partial*"))
    assert main(["mocap", "import", str(take), "--rec", str(still), "--out", str(out)]) == 1
    assert "cannot place the take" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".*partial*"))
