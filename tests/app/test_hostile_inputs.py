"""Files no reader or writer should trust, given to the commands on the simulated servo bus: a FIFO, a socket, a
device node of the test's own or a link to ``/dev/zero`` where a file is expected, oversized and absurd JSON, a
recording whose dataset is a soft-link loop, a writer killed with its temporary open. Each ends with exit 1 and one
line naming the file and the cause; nothing is replaced, nothing hangs, nothing is left behind."""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from app.cli.main import main
from tests.calibration_files import write_typical_calibration

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="FIFOs, sockets and /dev/zero")
ROOT = Path(__file__).resolve().parents[2]


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def record_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    """The one error line of a ``record`` (its progress line may come first: the lock is taken by the writer's
    thread while the board already streams)."""
    err = capsys.readouterr().err
    errors = [line for line in err.replace("\r", "\n").splitlines() if ": error:" in line]
    assert len(errors) == 1 and "Traceback" not in err, err
    return errors[0]


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def shape_file(path: Path, angles: list[float]) -> Path:
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": path.stem,
                                "axes": ["pitch", "yaw"] * 6, "angles_rad": angles}))
    return path


def test_play_log_never_replaces_its_shape_a_fifo_or_an_old_log_of_a_play_that_never_started(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shape = shape_file(tmp_path / "crawl.json", [0.0] * 12)
    before = shape.read_bytes()
    assert main(["play", str(shape), "--robot", "sim", "--log", str(shape)]) == 1
    assert "also an input" in one_error_line(capsys) and shape.read_bytes() == before
    fifo = tmp_path / "log.fifo"
    os.mkfifo(fifo)  # its open for writing would wait for a reader for ever
    assert main(["play", str(shape), "--robot", "sim", "--log", str(fifo)]) == 1
    line = one_error_line(capsys)
    assert str(fifo) in line and "FIFO" in line and stat.S_ISFIFO(os.lstat(fifo).st_mode)
    old = tmp_path / "old.csv"
    old.write_text("kept\n")
    assert main(["play", str(shape), "--robot", str(tmp_path / "ttyNONE"), "--log", str(old)]) == 1
    capsys.readouterr()
    assert old.read_text() == "kept\n" and not hidden(tmp_path)  # nothing played, nothing logged
    assert main(["play", str(shape), "--robot", "sim", "--speed", "1.0", "--log", str(old)]) == 0
    rows = old.read_text().splitlines()
    assert rows[0].startswith("time_s,goal_rad_1") and len(rows) >= 2 and not hidden(tmp_path)


def test_a_device_node_or_a_socket_as_output_is_refused_and_left_what_it_is(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    targets = {tmp_path / "sock": "socket"}
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(tmp_path / "sock"))
    if os.geteuid() == 0:  # a node of our own, what /dev/null is (never the real one)
        os.mknod(tmp_path / "null", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        targets[tmp_path / "null"] = "character device"
    shape = shape_file(tmp_path / "s.json", [0.0] * 12)
    try:
        for target, kind in targets.items():
            mode = os.lstat(target).st_mode
            for argv in (["servo", "dump", "--robot", "sim", "--out"],
                         ["play", str(shape), "--robot", "sim", "--log"]):
                assert main([*argv, str(target)]) == 1
                line = one_error_line(capsys)
                assert str(target) in line and kind in line, line
                assert os.lstat(target).st_mode == mode
    finally:
        listener.close()
    assert not hidden(tmp_path)


@pytest.fixture
def hostile_json(tmp_path: Path) -> dict[Path, str]:
    """Files that are no JSON a reader should read: path → the words its one line must hold."""
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    zero = tmp_path / "endless.json"
    zero.symlink_to("/dev/zero")
    digits = tmp_path / "digits.json"
    digits.write_text('{"format": "sensnake-servos", "servos": {"4": ' + "8" * 4400 + "}}")
    deep = tmp_path / "deep.json"
    deep.write_text('{"a": ' * 90_000 + "1" + "}" * 90_000)
    return {fifo: "FIFO", zero: "character device", digits: "digits", deep: "nested too deeply"}


def test_shape_settings_and_calibration_readers_refuse_hostile_json_in_one_line(tmp_path: Path, hostile_json: dict[Path, str],
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "g.csv"
    data.write_text("time_s,S06B\n0.0,1e-4\n0.1,2e-4\n")
    readers = (lambda p: ["play", str(p), "--robot", "sim"],
               lambda p: ["servo", "restore", str(p), "--robot", "sim"],
               lambda p: ["estimate", str(data), "--cal", str(p), "--out", str(tmp_path / "f.csv")])
    for argv in readers:
        for path, words in hostile_json.items():
            assert main(argv(path)) == 1, (argv(path), words)
            line = one_error_line(capsys)
            assert str(path) in line and words in line, line
    sparse = tmp_path / "sparse.json"
    with sparse.open("wb") as handle:
        handle.truncate(17_000_000)  # above the 16 MB a shape may hold, no disk used
    for argv in readers[:2]:
        assert main(argv(sparse)) == 1
        assert "larger than" in one_error_line(capsys)


def test_a_settings_value_of_hundreds_of_digits_is_named_not_printed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    saved = tmp_path / "servos.json"
    assert main(["servo", "dump", "--robot", "sim", "--id", "3", "--out", str(saved)]) == 0
    document = json.loads(saved.read_text())
    document["servos"]["3"]["items"]["Velocity I Gain"] = -(7 ** 500)
    saved_bad = tmp_path / "bad.json"
    saved_bad.write_text(json.dumps(document))
    capsys.readouterr()
    assert main(["servo", "restore", str(saved_bad), "--robot", "sim"]) == 1
    line = one_error_line(capsys)
    assert "Velocity I Gain" in line and "423-digit integer" in line and len(line) < 300, line


def test_a_killed_dumps_temporary_is_removed_by_the_next_dump_and_a_planted_link_never_followed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "chain.json"
    killed = subprocess.run([sys.executable, "-c", "import os, sys\nfrom app.core.outputs import create_temporary\n"
                             "create_temporary(sys.argv[1], '.tmp')\nos.kill(os.getpid(), 9)", str(out)], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=60)
    assert killed.returncode == -9 and len(hidden(tmp_path)) == 1
    planted = tmp_path / f".chain.json.{os.getpid()}.tmp"  # the old predictable name, pointing elsewhere
    planted.symlink_to(tmp_path / "victim")
    assert main(["servo", "dump", "--robot", "sim", "--id", "2", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["servos"]["2"]["model_number"] == 1020
    assert hidden(tmp_path) == [planted.name] and not (tmp_path / "victim").exists()


def test_repair_names_a_soft_link_loop_and_report_runs_and_lab_identify_a_fifo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "looped.h5"
    with h5py.File(rec, "w") as f:
        f.attrs["format"], f.attrs["version"] = "sensnake-recording", 1
        f["daq/time_s"] = np.arange(25) / 30.0
        f["daq/conductance_S"] = h5py.SoftLink("/daq/again")
        f["daq/again"] = h5py.SoftLink("/daq/conductance_S")
    assert main(["repair", str(rec), "--out", str(tmp_path / "fixed.h5")]) == 1
    line = one_error_line(capsys)
    assert "looped.h5" in line and "/daq/" in line and "loops back" in line, line
    fifo = tmp_path / "take.h5"
    os.mkfifo(fifo)
    for argv in (["report", "repeatability", str(fifo), str(rec), "--out", str(tmp_path / "rep")],
                 ["runs", "show", str(fifo)]):
        assert main(argv) == 1
        line = one_error_line(capsys)
        assert str(fifo) in line and "FIFO" in line, line
    pytest.importorskip("mujoco")
    assert main(["lab", "identify", str(fifo), "--out", str(tmp_path / "fitted.toml")]) == 1
    line = one_error_line(capsys)
    assert str(fifo) in line and "FIFO" in line, line


def test_a_calibration_of_thousands_of_digits_names_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cal = write_typical_calibration(tmp_path / "cal.json", ["S06B"])
    text = cal.read_text()
    cal.write_text(text.replace("{", '{"extra": ' + "5" * 4500 + ", ", 1))
    data = tmp_path / "g.csv"
    data.write_text("time_s,S06B\n0.0,1e-4\n")
    assert main(["estimate", str(data), "--cal", str(cal), "--out", str(tmp_path / "f.csv")]) == 1
    line = one_error_line(capsys)
    assert "cal.json" in line and "digits" in line, line


def test_a_sweeps_files_never_follow_a_planted_link_nor_open_a_fifo(tmp_path: Path) -> None:
    from app.core.errors import OutputPathError
    from app.core.sweep import write_summary

    victim = tmp_path / "elsewhere.csv"
    victim.write_text("not the sweep's")
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "summary.csv").symlink_to(victim)  # planted: the old predictable names were opened through it
    (out / "summary.csv.partial").symlink_to(victim)
    write_summary(out, [], {})
    assert victim.read_text() == "not the sweep's"
    assert not (out / "summary.csv").is_symlink() and (out / "summary.csv").read_text().startswith("run,")
    os.mkfifo(out / "failures.csv")
    with pytest.raises(OutputPathError, match="failures.csv is a FIFO"):
        write_summary(out, [], {4: "a run failed"})
    assert stat.S_ISFIFO(os.lstat(out / "failures.csv").st_mode)
    assert sorted(p.name for p in out.iterdir()) == ["failures.csv", "summary.csv", "summary.csv.partial",
                                                     "summary.svg"]


def test_a_lock_file_planted_as_a_link_or_a_fifo_is_refused_never_written_through(tmp_path: Path,
                                                                                   capsys: pytest.CaptureFixture[str]
                                                                                   ) -> None:
    from app.core.engines import FolderLock
    from app.core.errors import OutputPathError

    victim = tmp_path / "notes.txt"
    victim.write_text("someone's notes")
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / ".lock").symlink_to(victim)  # the lock's pid used to be written over the file it leads to
    with pytest.raises(OutputPathError, match=r"\.lock \(the lock file\) is a symbolic link"):
        FolderLock(runs, "sweep").__enter__()
    (tmp_path / ".take.h5.lock").symlink_to(victim)
    os.mkfifo(tmp_path / ".other.h5.lock")
    for name, kind in (("take.h5", "symbolic link"), ("other.h5", "FIFO")):
        assert main(["record", "--daq", "sim", "--seconds", "0.2", "--out", str(tmp_path / name)]) == 1
        line = record_error_line(capsys)
        assert f".{name}.lock (the lock file) is a {kind}" in line, line
        assert not (tmp_path / name).exists()
    assert victim.read_text() == "someone's notes"


def test_a_servo_given_twice_and_a_huge_lab_config_are_refused_naming_the_file(tmp_path: Path,
                                                                                capsys: pytest.CaptureFixture[str]
                                                                                ) -> None:
    saved = tmp_path / "pair.json"
    assert main(["servo", "dump", "--robot", "sim", "--id", "6", "--out", str(saved)]) == 0
    entry = json.dumps(json.loads(saved.read_text())["servos"]["6"])
    twice = tmp_path / "twice.json"  # JSON would keep the second "6" without a word
    twice.write_text('{"format": "sensnake-servos", "version": 1, "servos": {"6": ' + entry + ', "6": ' + entry + "}}")
    capsys.readouterr()
    assert main(["servo", "restore", str(twice), "--robot", "sim"]) == 1
    line = one_error_line(capsys)
    assert "twice.json" in line and "'6' is given twice" in line, line
    config = tmp_path / "lab.toml"
    with config.open("wb") as handle:
        handle.truncate(3_000_000)
    assert main(["servo", "dump", "--config", str(config), "--out", str(tmp_path / "x.json")]) == 1
    line = one_error_line(capsys)
    assert "lab.toml" in line and "larger than 1 MB" in line, line


def test_a_killed_mocap_writers_hidden_take_is_removed_by_the_next_one(tmp_path: Path) -> None:
    from app.core.mocap import _hidden_beside

    out = tmp_path / "take.c3d"
    dead = tmp_path / ".take.c3d.999999999.0badcafe.partial.c3d"  # no such pid: a writer killed mid-write
    dead.write_bytes(b"C3D half")
    with _hidden_beside(out, ".c3d") as work:
        assert work.name.startswith(f".take.c3d.{os.getpid()}.") and not dead.exists()
    assert not hidden(tmp_path)


def test_a_calibration_over_its_size_cap_is_refused_before_it_is_read(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str],
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    from app.core import calfiles

    cal = write_typical_calibration(tmp_path / "cal.json", ["S06B"])
    monkeypatch.setattr(calfiles, "MAX_JSON_BYTES", cal.stat().st_size - 1)  # json reads a file whole
    data = tmp_path / "g.csv"
    data.write_text("time_s,S06B\n0.0,1e-4\n")
    assert main(["estimate", str(data), "--cal", str(cal), "--out", str(tmp_path / "f.csv")]) == 1
    line = one_error_line(capsys)
    assert "cal.json" in line and "too large for a calibration file" in line, line


def test_a_fifo_planted_at_a_sweeps_record_or_journal_is_named_not_read(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    from app.core.engines import RunJournal
    from app.core.errors import EngineError

    plan = tmp_path / "plan.toml"
    plan.write_text('scenes = ["flat"]\nseconds = 0.1\n')
    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / "sweep.json")  # its read would wait for a writer for ever
    assert main(["experiment", "sweep", str(plan), "--out", str(out)]) == 1
    line = one_error_line(capsys)
    assert "sweep.json: is a FIFO" in line, line
    os.mkfifo(out / "finished.jsonl")  # what a resumed sweep, tuning or evaluation reads first
    with pytest.raises(EngineError, match="finished.jsonl: is a FIFO"):
        RunJournal(out).load()


def test_a_fifo_planted_at_a_series_or_session_file_is_named_not_read(tmp_path: Path) -> None:
    from app.core.errors import TrialsError
    from app.core.rig_protocol import read_conditioning, read_session
    from app.core.robot_trials import RobotSeries
    from app.core.trials import SERIES_FILE

    os.mkfifo(tmp_path / SERIES_FILE)  # each read would wait for a writer for ever
    with pytest.raises(TrialsError, match="series.json: is a FIFO"):
        RobotSeries.open(tmp_path)
    os.mkfifo(tmp_path / "protocol.json")
    with pytest.raises(ValueError, match="protocol.json: is a FIFO"):
        read_session(tmp_path)
    os.mkfifo(tmp_path / "conditioning.json")
    assert read_conditioning(tmp_path) is None  # unreadable: the conditioning runs again


def test_a_255_byte_output_name_is_written_and_its_killed_temporary_removed(tmp_path: Path,
                                                                             capsys: pytest.CaptureFixture[str]
                                                                             ) -> None:
    from app.core.outputs import create_temporary

    long_csv = tmp_path / ("é" * 125 + "m.csv")  # 256 bytes would be too long for any file: 255 is legal
    assert len(long_csv.name.encode()) == 255
    fd, stale = create_temporary(long_csv)  # as a killed writer leaves it …
    os.close(fd)
    os.rename(stale, stale.with_name(stale.name.replace(f".{os.getpid()}.", ".999999999.")))  # … with a dead pid
    data = tmp_path / "g.csv"
    data.write_text("time_s,S06B\n0.0,1e-4\n0.1,1.1e-4\n")
    cal = write_typical_calibration(tmp_path / "cal.json", ["S06B"])
    assert main(["estimate", str(data), "--cal", str(cal), "--out", str(long_csv)]) == 0
    assert long_csv.read_text().startswith("time_s,") and not hidden(tmp_path)
    long_h5 = tmp_path / ("r" * 252 + ".h5")
    assert main(["record", "--daq", "sim", "--seconds", "0.2", "--out", str(long_h5)]) == 0
    assert h5py.is_hdf5(long_h5) and not hidden(tmp_path)  # no lock file, no temporary left


def test_a_recording_declaring_rows_it_never_stored_is_refused_before_it_is_read(tmp_path: Path,
                                                                                  capsys: pytest.CaptureFixture[str]
                                                                                  ) -> None:
    forged = tmp_path / "forged.h5"
    assert main(["record", "--daq", "sim", "--seconds", "0.2", "--out", str(forged)]) == 0
    capsys.readouterr()
    with h5py.File(forged, "r+") as f:  # 6·10⁷ board times declared (480 MB), none written: a file of ~0.1 MB
        del f["daq/time_s"]
        f.create_dataset("daq/time_s", shape=(60_000_000,), dtype="f8", chunks=(4096,))
    assert forged.stat().st_size < 1_000_000
    for argv in (["export", str(forged), "--csv", str(tmp_path / "o.csv")],
                 ["repair", str(forged), "--out", str(tmp_path / "fixed.h5")]):
        assert main(argv) == 1
        line = one_error_line(capsys)
        assert "forged.h5: /daq/time_s declares 60,000,000 rows" in line and "not read" in line, line


@pytest.mark.parametrize("damage", ["nan", "backwards", "short"])
def test_a_recording_whose_board_times_are_not_times_is_refused_by_every_reader(tmp_path: Path, damage: str,
                                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A NaN time, or one that runs backwards, was exported as it was and fed the repeatability report (a recording
    against its own copy: s.d. 0.006 N instead of 0). Named as damage, never read as data."""
    rec = tmp_path / "r.h5"
    assert main(["record", "--daq", "sim", "--seconds", "0.5", "--out", str(rec)]) == 0
    with h5py.File(rec, "r+") as f:
        times = f["daq/time_s"]
        if damage == "short":  # a closed recording's columns cut to different lengths (a crash leaves no run_stop)
            times.resize((10,))
        else:
            times[5] = np.nan if damage == "nan" else float(times[3]) - 1.0
    capsys.readouterr()
    assert main(["export", str(rec), "--csv", str(tmp_path / "r.csv")]) == 1
    line = one_error_line(capsys)
    assert "damaged SenSnake recording" in line and "/daq" in line
    assert {"nan": "/daq/time_s row 5 is nan", "backwards": "/daq/time_s runs backwards at row 5",
            "short": "columns differ in length: time_s 10"}[damage] in line, line
    assert not (tmp_path / "r.csv").exists()
