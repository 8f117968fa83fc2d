"""Recording files (SPEC §3.5): round trip, crash safety (SIGKILL), disk full, bad files, CSV export."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from app.core.errors import RecordingError, RecordingFormatError
from app.core.recording import RecordingWriter, export_csv, open_recording
from devices.board import SampleBlock, conductance_from_counts
from devices.config import BoardConfig, default_sensor_names

CHANNELS = default_sensor_names()
REPO = Path(__file__).resolve().parents[2]


def make_block(first_seq: int, n: int, host_t0: float, rate_hz: float = 30.0, seed: int = 0,
               gap_at: int | None = None) -> SampleBlock:
    rng = np.random.default_rng(seed + first_seq)
    counts = rng.integers(1, 4096, (n, len(CHANNELS))).astype(np.uint16)
    seq = (first_seq + np.arange(n)).astype(np.uint32)
    times = host_t0 + seq / rate_hz
    gap = None
    if gap_at is not None:
        gap = np.zeros(n, dtype=bool)
        gap[gap_at] = True
    return SampleBlock(counts=counts, conductance_s=conductance_from_counts(counts, BoardConfig()),
                       board_time_s=seq / rate_hz, host_time_s=times, seq=seq, saturated=counts == 0,
                       gap_before=gap)


def test_round_trip_keeps_every_field_on_one_clock(tmp_path):
    path = tmp_path / "rec.h5"
    t0 = time.monotonic()
    calibration = '{"format": "sensnake-calibration", "version": 1, "sensors": {}}'
    blocks = [make_block(0, 20, t0), make_block(20, 15, t0, gap_at=3)]
    with RecordingWriter(path, "[board]\nrate_hz = 30.0\n", CHANNELS, calibration_json=calibration,
                         with_robot=True, t0_monotonic_s=t0) as writer:
        for block in blocks:
            writer.append_daq(block)
            writer.append_forces(block.conductance_s * 1000.0)
        for k in range(5):
            angles = np.full(12, 0.1 * k)
            writer.append_robot(t0 + 0.02 * k, angles, angles - 0.01, np.full(12, 50.0 + k))
        writer.update_stats(crc_errors=3, dropped_frames=2, resyncs=1)
        writer.log_event("S10B loose: noisy", t0 + 0.5, kind="health")
        assert writer.n_daq_samples == 35
    rec = open_recording(path)
    assert rec.version == 1 and rec.started.endswith("+00:00")
    assert rec.config_text.startswith("[board]")
    assert rec.channels == CHANNELS
    assert rec.n_samples == 35
    assert np.array_equal(rec.counts, np.concatenate([b.counts for b in blocks]))
    assert rec.counts.dtype == np.uint16 and rec.seq.dtype == np.uint32
    assert np.allclose(rec.conductance_s, np.concatenate([b.conductance_s for b in blocks]))
    assert np.allclose(rec.time_s, np.arange(35) / 30.0)  # seconds since started
    assert np.allclose(rec.forces_n, rec.conductance_s * 1000.0)
    assert rec.calibration_json == calibration
    assert (rec.crc_errors, rec.dropped_frames, rec.resyncs) == (3, 2, 1)
    assert rec.robot is not None
    assert np.allclose(rec.robot.time_s, 0.02 * np.arange(5))
    assert np.allclose(rec.robot.current_ma[:, 0], 50.0 + np.arange(5))
    assert rec.robot.goal_rad.shape == (5, 12)
    assert [g.time_s for g in rec.gaps] == pytest.approx([23 / 30.0])
    assert any(e.kind == "health" and "S10B" in e.text for e in rec.events)
    # Layout exactly as SPEC §3.5 for other tools.
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "sensnake-recording" and f.attrs["version"] == 1
        assert set(f["daq"]) >= {"time_s", "seq", "counts", "conductance_S"}
        assert f["daq/counts"].dtype == np.uint16 and f["daq/counts"].shape == (35, 36)
        assert list(f["daq"].attrs["channels"].astype(str))[:2] == ["S01L", "S01R"]
        assert set(f["robot"]) == {"time_s", "goal_rad", "present_rad", "current_mA"}
        assert f["forces/force_N"].shape == (35, 36)
        assert f["forces/status"].shape == (35, 36) and not f["forces/status"][:].any()  # no flags given: all ok
    assert rec.forces_status is not None and not rec.forces_status.any()


def test_recording_without_robot_or_calibration_has_neither(tmp_path):
    path = tmp_path / "plain.h5"
    with RecordingWriter(path, "", CHANNELS) as writer:
        writer.append_daq(make_block(0, 5, time.monotonic()))
        with pytest.raises(RuntimeError, match="without a robot"):
            writer.append_robot(0.0, np.zeros(12), np.zeros(12), np.zeros(12))
    rec = open_recording(path)
    assert rec.robot is None and rec.forces_n is None and rec.n_samples == 5


def test_export_csv_writes_conductance_or_forces(tmp_path):
    t0 = time.monotonic()
    plain, with_forces = tmp_path / "a.h5", tmp_path / "b.h5"
    block = make_block(0, 12, t0)
    with RecordingWriter(plain, "", CHANNELS, t0_monotonic_s=t0) as writer:
        writer.append_daq(block)
    with RecordingWriter(with_forces, "", CHANNELS, calibration_json="{}", t0_monotonic_s=t0) as writer:
        writer.append_daq(block)
        writer.append_forces(np.full((12, 36), 2.5))
    out = export_csv(open_recording(plain), tmp_path / "a.csv")
    header = out.read_text().splitlines()[0].split(",")
    assert header == ["time_s", *CHANNELS]
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert table.shape == (12, 37)
    assert np.allclose(table[:, 0], np.arange(12) / 30.0)
    assert np.allclose(table[:, 1:], block.conductance_s, rtol=1e-9, atol=1e-15)
    forces = np.loadtxt(export_csv(open_recording(with_forces), tmp_path / "b.csv"), delimiter=",", skiprows=1)
    assert np.all(forces[:, 1:] == 2.5)


def test_forces_an_older_version_estimated_without_a_calibration_are_not_newtons(tmp_path):
    """Before 2026-11-27 the app stored typical-sensor forces when no calibration file was loaded (their calibration
    document says "defaults": true). Such forces are not a calibration: read back, no channel is in newtons and the
    CSV export writes conductance. A real calibration's NaN channels (uncalibrated sensors) are not in newtons
    either; a rejected sample of a calibrated channel stays a gap."""
    t0 = time.monotonic()
    block = make_block(0, 12, t0)
    old, partial = tmp_path / "old.h5", tmp_path / "partial.h5"
    with RecordingWriter(old, "", CHANNELS, calibration_json='{"format": "sensnake-calibration", "defaults": true}',
                         t0_monotonic_s=t0) as writer:
        writer.append_daq(block)
        writer.append_forces(np.full((12, 36), 2.5))
    forces = np.full((12, 36), np.nan)
    forces[:, 17] = 1.5
    forces[4, 17] = np.nan  # a rejected sample
    with RecordingWriter(partial, "", CHANNELS, calibration_json='{"format": "sensnake-calibration"}',
                         t0_monotonic_s=t0) as writer:
        writer.append_daq(block)
        writer.append_forces(forces)
    recording = open_recording(old)
    assert recording.forces_n is not None and recording.forces_from_defaults  # kept in the file, not shown as N
    assert not recording.force_channels.any()
    table = np.loadtxt(export_csv(recording, tmp_path / "old.csv"), delimiter=",", skiprows=1)
    assert np.allclose(table[:, 1:], block.conductance_s, rtol=1e-9, atol=1e-15)
    recording = open_recording(partial)
    assert not recording.forces_from_defaults
    assert np.flatnonzero(recording.force_channels).tolist() == [17]


def test_an_export_that_fails_midway_leaves_the_earlier_csv_whole(tmp_path, monkeypatch, capsys):
    """The disk fills while the CSV is written: the earlier export at OUT stays as it was, no temporary is left,
    and the message is one line naming OUT in the OS's words."""
    import errno

    from app.cli import main

    rec = tmp_path / "r.h5"
    with RecordingWriter(rec, "", CHANNELS) as writer:
        writer.append_daq(make_block(0, 50, time.monotonic()))
    out = tmp_path / "r.csv"
    out.write_text("an earlier export\n")
    real_savetxt = np.savetxt

    def disk_fills(handle, table, **kwargs):
        real_savetxt(handle, table[:10], **kwargs)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("app.core.recording.np.savetxt", disk_fills)
    assert main(["export", str(rec), "--csv", str(out)]) == 1
    err = capsys.readouterr().err
    assert err == f"sensnake export: error: cannot write {out}: No space left on device\n", err
    assert out.read_text() == "an earlier export\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv", "r.h5"]
    monkeypatch.undo()
    assert main(["export", str(rec), "--csv", str(out / "inside.csv")]) == 1  # OUT's folder is a file
    assert capsys.readouterr().err == f"sensnake export: error: {out / 'inside.csv'}: {out} is not a folder\n"


def test_disk_almost_full_stops_cleanly_and_keeps_what_was_flushed(tmp_path):
    path = tmp_path / "full.h5"
    t0 = time.monotonic()
    writer = RecordingWriter(path, "", CHANNELS, flush_interval_s=3600.0, t0_monotonic_s=t0)
    writer.append_daq(make_block(0, 30, t0))
    writer.flush()
    # The spare-space rule is what stops it: ask for more spare space than the disk has.
    writer.min_free_bytes = shutil.disk_usage(tmp_path).free + 10**12
    writer.append_daq(make_block(30, 30, t0))
    with pytest.raises(RecordingError, match="disk is almost full") as info:
        writer.flush()
    assert isinstance(info.value, OSError)
    with pytest.raises(RecordingError):
        writer.append_daq(make_block(60, 1, t0))
    writer.close()
    rec = open_recording(path)
    assert rec.n_samples == 30


def test_bad_files_get_clear_messages(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.h5"):
        open_recording(tmp_path / "nothere.h5")
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    with pytest.raises(RecordingFormatError, match=r"notes.h5 is not a readable SenSnake recording \(not an HDF5 "
                       r"file\)$"):  # HDF5's own report ("Unable to synchronously open file …") stays inside
        open_recording(text)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(RecordingFormatError, match="other.h5 is not a SenSnake recording"):
        open_recording(other)
    future = tmp_path / "future.h5"
    with RecordingWriter(future, "", CHANNELS) as writer:
        writer.append_daq(make_block(0, 3, time.monotonic()))
    with h5py.File(future, "r+") as f:
        f.attrs["version"] = 2
    with pytest.raises(RecordingFormatError, match="future.h5 is a version-2 recording"):
        open_recording(future)
    good = tmp_path / "good.h5"
    with RecordingWriter(good, "", CHANNELS) as writer:
        writer.append_daq(make_block(0, 300, time.monotonic()))
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(RecordingFormatError, match="truncated.h5"):
        open_recording(truncated)


# -- crash safety --------------------------------------------------------------------------------------------------
CHILD_RECORDER = textwrap.dedent("""
    import sys, time
    from devices import factory
    from devices.board import BoardReader
    from devices.config import LabConfig, BoardConfig
    from devices.sim.board import VirtualBoard
    from devices.sim.clock import SimClock
    from devices.sim.contact import ContactModel
    from app.core.recording import RecordingWriter

    class BoardOnlyLab:
        def __init__(self, board):
            self.board = board
        def endpoint(self, device):
            return self.board

    board_cfg = BoardConfig(rate_hz=100.0)
    config = LabConfig(board=board_cfg)
    board = VirtualBoard(board_cfg, SimClock(1.0), ContactModel(config, None, seed=1).forces_n, seed=2)
    factory.install_sim_lab(BoardOnlyLab(board))
    reader = BoardReader(board_cfg)
    reader.start()
    writer = RecordingWriter(sys.argv[1], "", board_cfg.channel_names, flush_interval_s=0.5)
    while True:
        reader.wait_for_frames(1, 1.0)
        block = reader.read_block()
        if block is not None:
            writer.append_daq(block)
            print(time.monotonic(), writer.n_daq_samples, flush=True)
""")


@pytest.mark.slow
def test_sigkill_loses_at_most_the_last_second(tmp_path):
    path = tmp_path / "killed.h5"
    child = subprocess.Popen([sys.executable, "-c", CHILD_RECORDER, str(path)], cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    reports: list[tuple[float, int]] = []
    try:
        assert child.stdout is not None
        for line in child.stdout:  # blocks on the child's progress, no sleeping
            when, samples = line.split()
            reports.append((float(when), int(samples)))
            if reports[-1][0] - reports[0][0] >= 2.0:
                break
        killed_at = time.monotonic()
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait(timeout=10)
        child.stdout.close()
        child.stderr.close()
    assert reports, "the recorder never reported progress"
    rec = open_recording(path)
    appended_by_one_second_before = max(n for t, n in reports if t <= killed_at - 1.0)
    assert appended_by_one_second_before >= 50  # 100 Hz for ≥ 1 s: the check is not vacuous
    assert appended_by_one_second_before <= rec.n_samples <= reports[-1][1]
    assert np.all(np.diff(rec.seq.astype(np.int64)) == 1)
    assert np.all(np.diff(rec.time_s) >= 0)


CHILD_HARD_FAILURE = textwrap.dedent("""
    import os, resource, signal, sys, time
    import numpy as np
    from app.core.recording import RecordingWriter, RecordingError
    from devices.board import SampleBlock
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # so an over-size write fails with EFBIG, like ENOSPC
    resource.setrlimit(resource.RLIMIT_FSIZE, (600_000, 600_000))
    names = [f"c{i}" for i in range(36)]
    writer = RecordingWriter(sys.argv[1], "", names, flush_interval_s=0.0, min_free_bytes=0)
    t0 = time.monotonic()
    try:
        for k in range(100_000):
            counts = np.full((30, 36), k % 4096, np.uint16)
            seq = np.arange(30) + 30 * k
            writer.append_daq(SampleBlock(counts, counts * 1e-7, seq * 0.01, t0 + seq * 0.01, seq, counts == 0))
    except RecordingError as exc:
        print("STOPPED", writer._daq.rows, exc, flush=True)  # rows on disk at the last good flush
    os._exit(0)  # the file on disk is what this test is about
""")


@pytest.mark.slow
def test_a_write_error_stops_the_recording_and_the_file_still_opens_with_everything_flushed(tmp_path):
    """A write that would fail (here EFBIG from a file-size limit; ENOSPC and EDQUOT alike) fails while the flush
    reserves its room, before HDF5 touches the file (once the file no longer opened: `truncated file`): a
    RecordingError naming the cause, and the file opens with plain h5py holding every row of the last good flush."""
    import h5py

    path = tmp_path / "efbig.h5"
    done = subprocess.run([sys.executable, "-c", CHILD_HARD_FAILURE, str(path)], cwd=REPO, capture_output=True,
                          text=True, timeout=60)
    assert done.stdout.startswith("STOPPED"), done.stdout + done.stderr
    assert "File too large" in done.stdout and "ulimit -f" in done.stdout
    assert "Exception ignored" not in done.stderr and "Traceback" not in done.stderr, done.stderr
    flushed = int(done.stdout.split()[1])
    assert flushed > 0
    with h5py.File(path, "r") as f:  # plain h5py, no repair
        assert f["daq/seq"].shape == (flushed,)
    rec = open_recording(path)
    assert rec.n_samples == flushed
    assert np.all(rec.counts[:, 0] == (rec.seq // 30) % 4096)  # rows are whole, not torn


def test_frames_from_before_the_recording_started_are_not_recorded(tmp_path):
    """A block can hold frames that arrived before the recorder's t0 (the GUI starts a recording mid-stream; the
    reader back-dates frames by their bytes' wire time): they are left out, so ``time_s`` never goes below 0 and
    the forces stay aligned with their frames."""
    from app.core.recorder import Recorder

    t0 = time.monotonic()
    recorder = Recorder(tmp_path / "late.h5", "[board]\n", CHANNELS, calibration_json="{}", t0_monotonic_s=t0)
    recorder.start()
    block = make_block(0, 30, t0 - 10.5 / 30.0)  # frames 0 … 10 arrived before t0, 11 … 29 after
    forces = np.arange(30, dtype=float)[:, None] * np.ones(len(CHANNELS))
    recorder.add_block(block, forces)
    recorder.add_block(make_block(30, 10, t0 - 10.5 / 30.0), forces[:10] + 30.0)
    recorder.add_block(make_block(0, 5, t0 - 1.0), forces[:5])  # wholly before t0: nothing
    recorder.stop()
    assert recorder.error is None and recorder.n_daq_samples == 29
    rec = open_recording(tmp_path / "late.h5")
    np.testing.assert_array_equal(rec.seq, np.arange(11, 40))
    assert rec.time_s[0] >= 0.0
    np.testing.assert_allclose(rec.time_s, (np.arange(11, 40) - 10.5) / 30.0, atol=1e-9)
    np.testing.assert_array_equal(rec.forces_n[:, 0], np.arange(11, 40))
    np.testing.assert_array_equal(rec.counts, np.concatenate([block.counts[11:], make_block(30, 10, 0).counts]))


def test_hdf5_internals_and_the_hidden_work_file_never_reach_a_message(tmp_path):
    """h5py puts its whole report (``errno = 2, … flags = 13, o_flags = 242`` and the hidden ``.partial`` name)
    into ``strerror``: the user gets the OS's words and the path they asked for."""
    import errno

    from app.core.recording import _os_reason

    with pytest.raises(OSError) as raised:
        h5py.File(tmp_path / "nope" / ".r.h5.123.partial", "w")
    assert "o_flags" in str(raised.value)  # what h5py says, so this test means something
    assert _os_reason(raised.value) == os.strerror(errno.ENOENT)
    for out, words in ((tmp_path / "nope" / "r.h5", f"the folder {tmp_path / 'nope'} does not exist"),
                       (tmp_path, "is a folder")):
        with pytest.raises(RecordingError) as failed:
            RecordingWriter(out, "", CHANNELS)
        text = str(failed.value)
        assert f"cannot create recording {out}" in text and words in text, text
        for internal in ("errno =", "flags =", "o_flags", "partial", "Unable to"):
            assert internal not in text, text


def test_a_live_recording_flags_each_force_read_at_the_readout_ceiling(tmp_path):
    """LiveSession → ForcesPipeline → Recorder: /forces/status holds each force's code, so a force that is only a
    lower bound (the readout at its ceiling, counts 0) is never a silent number in the file."""
    import dataclasses
    import json

    from app.core.forces_pipeline import ForcesPipeline
    from app.core.live_session import LiveSession
    from app.core.recorder import Recorder
    from devices.config import LabConfig, SimLabConfig
    from devices.sim.lab import SimLab
    from models.sls import ForceStatus

    config = LabConfig()
    lab = SimLab(dataclasses.replace(config, lab=SimLabConfig(physics="scripted")), seed=1)
    try:
        calibration = json.dumps(lab.board.ground_truth_calibration())
    finally:
        lab.close()
    cal = tmp_path / "cal.json"
    cal.write_text(calibration, encoding="utf-8")
    pipeline = ForcesPipeline(config.board.channel_names)
    pipeline.load_calibration(cal)
    t0 = time.monotonic()
    live = LiveSession(config.board, pipeline=pipeline, t0_monotonic_s=t0)
    recorder = Recorder(tmp_path / "live.h5", "[board]\n", config.board.channel_names, calibration_json=calibration,
                        t0_monotonic_s=t0)
    recorder.start()
    live.recorder = recorder
    block = make_block(0, 30, t0)
    counts = block.counts.copy()
    counts[10:13, 4] = 0  # S02R at the ceiling for three frames
    live.process_block(SampleBlock(counts=counts, conductance_s=conductance_from_counts(counts, BoardConfig()),
                                   board_time_s=block.board_time_s, host_time_s=block.host_time_s, seq=block.seq,
                                   saturated=counts == 0))
    recorder.stop()
    rec = open_recording(tmp_path / "live.h5")
    assert rec.forces_status is not None and rec.forces_status.shape == (30, 36)
    flagged = rec.forces_status == ForceStatus.READOUT_SATURATED
    assert flagged[10:13, 4].all() and flagged.sum() == 3
    assert np.isfinite(rec.forces_n[10:13, 4]).all()  # the lower bound is kept, and said to be one
