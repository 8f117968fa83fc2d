"""``sensnake record`` and ``sensnake export`` on the simulated board (fast clock), and their failures."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.core.recording import open_recording
from devices.config import LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def fast_board(install_sim_device):
    config = LabConfig()
    board = VirtualBoard(config.board, SimClock(20.0), ContactModel(config, None, seed=5).forces_n, seed=6)
    return install_sim_device("board", board)


def one_error_line(err: str) -> str:
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.startswith("sensnake ")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_record_then_export(fast_board, tmp_path, capsys):
    out, csv = tmp_path / "rec.h5", tmp_path / "rec.csv"
    assert main(["record", "--daq", "sim", "--seconds", "2", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "recording rec.h5:" in captured.err  # progress
    assert "recorded" in captured.out
    rec = open_recording(out)
    # Two seconds of board time at 30 Hz.
    assert 60 <= rec.n_samples <= 61  # frames at 0 … 2 s of board time; none drained past --seconds is written
    assert rec.channels[0] == "S01L" and rec.counts.shape == (rec.n_samples, 36)
    assert rec.config_text.lstrip().startswith("#")  # the packaged default config's text
    assert np.all(np.diff(rec.seq.astype(np.int64)) == 1)
    truth = fast_board.true_conductance_s(rec.seq)
    assert np.max(np.abs(rec.conductance_s - truth)) < 5 * (3.3 / 4095) / (2.5 * 900.0)
    assert main(["export", str(out), "--csv", str(csv)]) == 0
    assert f"wrote {rec.n_samples} rows" in capsys.readouterr().out
    table = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert table.shape == (rec.n_samples, 37)
    assert np.allclose(table[:, 1:], rec.conductance_s, rtol=1e-9, atol=1e-15)


def test_recorded_file_has_the_spec_layout_on_disk(fast_board, tmp_path, capsys):
    """SPEC §3.5 as another tool reads it with plain h5py: root attributes, /daq datasets and dtypes, no /robot."""
    import datetime

    import h5py

    from devices.config import load_config

    out = tmp_path / "rec.h5"
    assert main(["record", "--daq", "sim", "--seconds", "1", "--out", str(out)]) == 0
    capsys.readouterr()
    with h5py.File(out, "r") as f:
        assert f.attrs["format"] == "sensnake-recording" and int(f.attrs["version"]) == 1
        started = datetime.datetime.fromisoformat(str(f.attrs["started"]))
        assert started.tzinfo is not None
        assert f.attrs["config"] == load_config().source_text
        daq = f["daq"]
        n = daq["time_s"].shape[0]
        assert n > 0
        expected = {"time_s": (np.float64, (n,)), "seq": (np.uint32, (n,)), "counts": (np.uint16, (n, 36)),
                    "conductance_S": (np.float64, (n, 36))}
        for name, (dtype, shape) in expected.items():
            assert (daq[name].dtype, daq[name].shape) == (np.dtype(dtype), shape), name
        assert [c.decode() if isinstance(c, bytes) else c for c in daq.attrs["channels"]] == \
            list(LabConfig().board.channel_names)
        assert all(int(daq.attrs[key]) >= 0 for key in ("crc_errors", "dropped_frames", "resyncs"))
        time_s = daq["time_s"][:]
        # Seconds since ``started``: the first frame arrives within the first second, and time runs forward.
        assert 0.0 <= time_s[0] < 1.0 and np.all(np.diff(time_s) >= 0.0)
        assert "robot" not in f  # no robot is connected to ``sensnake record``


def test_port_that_cannot_be_opened_is_one_line(tmp_path, capsys):
    code = main(["record", "--daq", str(tmp_path / "ttyNOPE"), "--seconds", "1", "--out", str(tmp_path / "r.h5")])
    assert code == 1
    line = one_error_line(capsys.readouterr().err)
    assert "cannot open board port" in line and "ttyNOPE" in line
    # The OS's words once, not pyserial's echo ("[Errno 2] could not open port …: [Errno 2] No such file …").
    assert "No such file or directory" in line and "[Errno" not in line and line.count("ttyNOPE") == 1, line


def test_channel_count_mismatch_fails_naming_both_counts(fast_board, tmp_path, capsys):
    fast_board.set_channel_count(48)
    code = main(["record", "--daq", "sim", "--seconds", "2", "--out", str(tmp_path / "r.h5")])
    assert code == 1
    line = one_error_line(capsys.readouterr().err)
    assert "48 channels" in line and "36" in line


def test_wrong_baud_rate_is_one_line_naming_the_baud(fast_board, tmp_path, capsys, monkeypatch):
    from app.cli import record as record_cmd

    monkeypatch.setattr(record_cmd, "NO_FRAMES_TIMEOUT_S", 0.5)  # the default 3 s, shortened for the test
    code = main(["record", "--daq", "sim", "--baud", "115200", "--seconds", "5", "--out", str(tmp_path / "r.h5")])
    assert code == 1
    line = one_error_line(capsys.readouterr().err)
    assert "no frames from the board" in line and "bytes of noise" in line and "115200" in line


def test_crc_storm_warns_loudly_and_records_to_the_end(fast_board, tmp_path, capsys):
    out = tmp_path / "storm.h5"
    fast_board.corrupt_frames(300)
    code = main(["record", "--daq", "sim", "--seconds", "5", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "WARNING: bad board link" in captured.err and "check the cable" in captured.err
    assert "Traceback" not in captured.err
    rec = open_recording(out)
    assert rec.crc_errors >= 250  # the counters are in the file (SPEC §3.5)
    assert f"{rec.crc_errors} CRC errors" in captured.out
    assert 140 <= rec.n_samples <= 151  # 5 s at 30 Hz after the storm: the good frames are all there
    assert np.all(np.diff(rec.seq.astype(np.int64)) == 1)
    assert any(e.kind == "link" and "bad board link" in e.text for e in rec.events)


def test_cable_pull_mid_recording_is_logged_as_a_gap(fast_board, tmp_path, capsys, monkeypatch):
    out = tmp_path / "pulled.h5"
    # Pull the cable once the recorder has been running for a while: the progress update runs in the recording
    # loop, so wrapping it (and still calling it) lets the test act at a known point without any sleeping.
    from app.cli import record as record_cmd

    original_show = record_cmd._Progress.show
    pulled = []

    def show_and_pull(self, recorded_s, stats, frames):
        if frames >= 15 and not pulled:
            fast_board.unplug()
            pulled.append(True)
        elif pulled and len(pulled) == 1 and not stats.connected:
            fast_board.replug()
            pulled.append(True)
        original_show(self, recorded_s, stats, frames)

    monkeypatch.setattr(record_cmd._Progress, "show", show_and_pull)
    # 20 s of board time (1 s here): the half-second reconnect interval is 10 s of the fast board's time.
    assert main(["record", "--daq", "sim", "--seconds", "20", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "disconnected" in err and "reconnected" in err
    rec = open_recording(out)
    assert any("disconnected" in gap.text for gap in rec.gaps)
    assert any(gap.text.startswith("board frames missing") for gap in rec.gaps)
    assert np.any(np.diff(rec.seq.astype(np.int64)) > 1)


def test_export_of_a_bad_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.h5"
    bad.write_text("hello")
    assert main(["export", str(bad), "--csv", str(tmp_path / "x.csv")]) == 1
    assert "bad.h5" in one_error_line(capsys.readouterr().err)
    assert main(["export", str(tmp_path / "missing.h5"), "--csv", str(tmp_path / "x.csv")]) == 1
    assert "missing.h5" in one_error_line(capsys.readouterr().err)


@pytest.mark.slow
def test_ctrl_c_keeps_the_file(tmp_path):
    out = tmp_path / "interrupted.h5"
    child = subprocess.Popen([sys.executable, "-m", "app", "record", "--daq", "sim", "--seconds", "60",
                              "--out", str(out)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert child.stderr is not None
        seen = b""
        while b"frames" not in seen:  # wait for the first progress report (blocking read, no sleep)
            chunk = child.stderr.read1(256)
            assert chunk, "the recorder exited before reporting progress"
            seen += chunk
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=20)
    finally:
        child.kill()
        child.wait(timeout=10)
    assert child.returncode == 130
    assert b"interrupted; kept" in err
    assert open_recording(out).n_samples >= 1


@pytest.mark.parametrize("where", ["missing folder", "file as folder", "a folder"])
def test_an_out_path_that_cannot_be_written_is_one_line_naming_it(fast_board, tmp_path, capsys, where):
    """No HDF5 internals (``flags = 13, o_flags = 242``), no hidden work file in the message."""
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    out = {"missing folder": tmp_path / "nope" / "r.h5", "file as folder": blocker / "r.h5",
           "a folder": tmp_path}[where]
    code = main(["record", "--daq", "sim", "--seconds", "30", "--out", str(out)])
    assert code == 1
    line = one_error_line(capsys.readouterr().err)
    assert f"cannot create recording {out}:" in line, line
    for internal in ("errno =", "flags =", "o_flags", ".partial", "Unable to"):
        assert internal not in line, line
    assert blocker.read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]


def test_a_recording_gets_the_umask_or_keeps_the_mode_of_the_file_it_replaces(fast_board, tmp_path, capsys):
    """Output-file permissions for recordings (record and repair): never a surprise 0600, never a lost 0640."""
    import os
    import stat

    def mode(path: Path) -> int:
        return stat.S_IMODE(path.stat().st_mode)

    previous = os.umask(0o022)
    try:
        out = tmp_path / "rec.h5"
        for mask, expected in ((0o022, 0o644), (0o077, 0o600)):
            os.umask(mask)
            out.unlink(missing_ok=True)
            assert main(["record", "--daq", "sim", "--seconds", "0.5", "--out", str(out)]) == 0
            assert mode(out) == expected, f"umask {mask:03o}: {mode(out):03o}"
        kept = tmp_path / "kept.h5"  # a file that is not a recording (a recording is never replaced)
        kept.write_bytes(b"old")
        os.chmod(kept, 0o640)
        assert main(["record", "--daq", "sim", "--seconds", "0.5", "--out", str(kept)]) == 0
        assert mode(kept) == 0o640
        fixed = tmp_path / "fixed.h5"
        fixed.write_bytes(b"old")
        os.chmod(fixed, 0o604)
        assert main(["repair", str(out), "--out", str(fixed)]) == 0
        assert mode(fixed) == 0o604 and open_recording(fixed).n_samples == open_recording(out).n_samples
    finally:
        os.umask(previous)
    capsys.readouterr()
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
