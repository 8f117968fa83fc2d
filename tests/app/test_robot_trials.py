"""A trial series on the robot (app/core/robot_trials.py, ``sensnake trials``): the series' state in its folder, each
trial's run documents, the operator's outcome, STOP kept as aborted, and a series that survives a crash.

The command line runs at the wire on the simulated lab (its servo bus and board emulated in the command's own
process, ``--robot sim --daq sim``), driven as an operator drives it: Enter, an outcome, Ctrl-C, and a kill -9."""

from __future__ import annotations

import csv
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from app.cli.main import main
from app.core.catalog import Catalog
from app.core.errors import TrialsError
from app.core.robot_trials import ASK_OUTCOME, KEPT_ABORTED, NOT_RECORDED, RobotSeries, RobotSeriesOptions
from app.core.run_documents import read_documents, reserve_run_stop

ROOT = Path(__file__).resolve().parents[2]
AXES = ["pitch", "yaw"] * 6


def shape_file(folder: Path, name: str = "bump", first_rad: float = 0.2) -> Path:
    path = folder / f"{name}.json"
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": name, "axes": AXES,
                                "angles_rad": [first_rad] + [0.0] * 11}))
    return path


def scripted_lab(folder: Path) -> Path:
    path = folder / "lab.toml"
    path.write_text('[lab]\nphysics = "scripted"\n')
    return path


def write_recording(path: Path, start: dict, closed: bool = True) -> None:
    """A recording as the app's recorder leaves it: run_start, run_stop's room reserved (and written when closed)."""
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["version"] = 1
        f.attrs["started"] = "2026-12-01T10:00:00.000+00:00"
        f.attrs["config"] = ""
        f.attrs["duration_s"] = 2.5
        f.attrs["run_start"] = json.dumps(start)
        reserve_run_stop(f.attrs)
        f.create_group("daq")["time_s"] = np.arange(10) / 4.0
    if closed:
        from app.core.run_documents import write_run_stop

        write_run_stop(path, start, "success")


def record_trial(series: RobotSeries, k: int, closed: bool = True) -> Path:
    start = series.run_start(k, config_text="[lab]\n", calibration_json=None)
    path = series.begin(k)
    write_recording(path, start, closed)
    return path


@pytest.fixture
def options(tmp_path):
    return RobotSeriesOptions(shape=str(shape_file(tmp_path)), trials=3, scene="flat", speed_rad_s=0.1, note="x3")


def test_a_series_keeps_its_state_marks_outcomes_into_run_stop_and_stop_as_aborted(tmp_path, options):
    series = RobotSeries.start(tmp_path / "series", options)
    assert series.next_trial() == 0 and series.prompt(0) == "Place the robot, then Start trial 1 of 3"
    path = record_trial(series, 0)
    assert json.loads((tmp_path / "series" / "series.json").read_text())["trials"][0]["state"] == "recording"
    assert series.ended(0, "success") == ASK_OUTCOME  # the outcome is the operator's
    assert series.pending_outcome() == 0 and series.next_trial() is None
    series.mark(0, "traversed", "clean pass")
    start, stop = read_documents(path)
    assert start["plan_name"] == "robot trials" and start["trial"] == 0 and start["series_uid"] == series.series_uid
    assert start["condition"]["scene"] == "flat" and start["condition"]["shape"] == "bump"
    assert start["note"] == "x3"
    assert stop["run_start"] == start["uid"] and stop["exit_status"] == "success"
    assert stop["outcome"] == "traversed" and stop["note"] == "clean pass"
    # STOP in trial 2: kept, marked aborted, no outcome asked.
    path = record_trial(series, 1)
    assert series.ended(1, "abort", "STOP (button or Esc)") == KEPT_ABORTED
    _start, stop = read_documents(path)
    assert (stop["exit_status"], stop["outcome"], stop["reason"]) == ("abort", "aborted", "STOP (button or Esc)")
    assert series.next_trial() == 2 and series.outcomes() == {"traversed": 1, "failed": 0, "aborted": 1}
    with open(tmp_path / "series" / "trials.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == ["file", "trial", "seed", "outcome", "duration_s", "advance_m", "exit_status", "note"]
    assert [(r["file"], r["outcome"], r["exit_status"], r["note"]) for r in rows] == [
        ("trial-000.h5", "traversed", "success", "clean pass"), ("trial-001.h5", "aborted", "abort", "")]
    assert float(rows[0]["duration_s"]) == pytest.approx(2.5)
    with Catalog() as catalog:
        entry = catalog.get(path)
    assert entry["outcome"] == "aborted" and entry["series_uid"] == series.series_uid and entry["trial"] == 1
    with Catalog() as catalog:
        assert catalog.get(tmp_path / "series" / "trial-000.h5")["note"] == "x3; clean pass"  # the run's, the outcome's
    assert not [p.name for p in (tmp_path / "series").iterdir() if p.name.startswith(".")]  # no temporaries left


def test_a_crash_mid_trial_sets_the_cut_short_file_aside_and_runs_the_trial_again(tmp_path, options):
    folder = tmp_path / "series"
    series = RobotSeries.start(folder, options)
    record_trial(series, 0)
    series.ended(0, "success")
    series.mark(0, "failed")
    record_trial(series, 1, closed=False)  # the app died while trial 2 was recording: no run_stop, state "recording"
    resumed = RobotSeries.open(folder)
    assert resumed.series_uid == series.series_uid and resumed.next_trial() == 1
    assert "cut short" in resumed.recovered[0] and "trial-001.cut-short.h5" in resumed.recovered[0]
    start, stop = read_documents(folder / "trial-001.cut-short.h5")
    assert (stop["exit_status"], stop["outcome"]) == ("fail", "aborted") and stop["run_start"] == start["uid"]
    assert not (folder / "trial-001.h5").exists()
    assert resumed.trial(0)["outcome"] == "failed"  # the finished trial is kept
    # A crash after the recording was closed but before the state said so: its outcome is asked, nothing redone.
    record_trial(resumed, 1)
    again = RobotSeries.open(folder)
    assert again.pending_outcome() == 1 and "outcome is still to be marked" in again.recovered[0]
    # And a second cut short of the same trial is kept beside the first.
    again.mark(1, "traversed")
    record_trial(again, 2, closed=False)
    third = RobotSeries.open(folder)
    assert third.set_aside == ["trial-001.cut-short.h5", "trial-002.cut-short.h5"] and third.next_trial() == 2


def test_a_trial_stopped_before_its_file_was_written_runs_again(tmp_path, options):
    series = RobotSeries.start(tmp_path / "series", options)
    series.begin(0)  # STOP before the board's first frame reached the recording: the recorder kept no file
    assert series.ended(0, "abort", "STOP (button or Esc)") == NOT_RECORDED
    assert series.next_trial() == 0 and not (tmp_path / "series" / "trial-000.h5").exists()


def test_a_folder_holds_one_condition_and_its_trials_may_only_grow(tmp_path, options):
    folder = tmp_path / "series"
    RobotSeries.start(folder, options)
    from dataclasses import replace

    with pytest.raises(TrialsError, match=r"other options \(speed_rad_s 0.1 ≠ 0.2\)"):
        RobotSeries.start(folder, replace(options, speed_rad_s=0.2))
    with pytest.raises(TrialsError, match="may grow, not shrink"):
        RobotSeries.start(folder, replace(options, trials=2))
    grown = RobotSeries.start(folder, replace(options, trials=5, note="after lunch"))
    assert grown.n_trials == 5 and RobotSeries.open(folder).options.note == "after lunch"
    physics = tmp_path / "physics"
    physics.mkdir()
    (physics / "series.json").write_text(json.dumps({"format": "sensnake-trials", "plan_name": "experiment trials",
                                                      "series_uid": "u", "condition": {}}))
    with pytest.raises(TrialsError, match="'experiment trials', not of the robot's trials"):
        RobotSeries.open(physics)
    with pytest.raises(TrialsError, match="outcome must be one of traversed, failed, aborted"):
        RobotSeries.open(folder).mark(0, "great")


def test_a_catalog_sync_stops_between_files_when_asked_and_the_next_reads_the_rest(tmp_path):
    from benchmarks.bench_catalog import write_small_recording

    for index in range(6):
        write_small_recording(tmp_path / f"run-{index}.h5", index)
    asked = []

    def cancelled() -> bool:
        asked.append(True)
        return len(asked) > 2  # stop before the third file

    with Catalog(":memory:") as catalog:
        assert catalog.sync(tmp_path, cancelled=cancelled) == (2, 0)
        assert catalog.count() == 2
        assert catalog.sync(tmp_path) == (4, 0) and catalog.count() == 6


# -- the command line, at the wire ------------------------------------------------------------------------------------
class Operator:
    """``sensnake …`` in its own process, typed at as an operator does: wait for a prompt, answer it."""

    def __init__(self, argv: list[str], data_dir: Path) -> None:
        env = {**os.environ, "SENSNAKE_DATA_DIR": str(data_dir), "PYTHONUNBUFFERED": "1"}
        self.process = subprocess.Popen([sys.executable, "-m", "app", *argv], cwd=ROOT, env=env,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.output = ""
        self._seen = 0
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, name="operator-output")
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        while chunk := os.read(self.process.stdout.fileno(), 4096):
            with self._changed:
                self.output += chunk.decode("utf-8", "replace")
                self._changed.notify_all()

    def expect(self, text: str, timeout_s: float = 60.0) -> None:
        with self._changed:
            found = self._changed.wait_for(lambda: text in self.output[self._seen:] or self.process.poll() is not None,
                                           timeout_s)
            at = self.output.find(text, self._seen)
            assert found and at >= 0, f"no {text!r} within {timeout_s} s; output:\n{self.output[-3000:]}"
            self._seen = at + len(text)

    def type(self, line: str) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write((line + "\n").encode())
        self.process.stdin.flush()

    def end(self, timeout_s: float = 60.0) -> int:
        try:
            code = self.process.wait(timeout_s)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait()
            self._reader.join()
            for pipe in (self.process.stdin, self.process.stdout):
                if pipe is not None:
                    pipe.close()
        return code


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals as on Linux")
def test_sensnake_trials_on_the_simulated_lab_stop_in_trial_2_kill_in_trial_3_then_resume(tmp_path):
    shape, lab, out, data = shape_file(tmp_path), scripted_lab(tmp_path), tmp_path / "series", tmp_path / "data"
    argv = ["trials", str(shape), "--robot", "sim", "--daq", "sim", "--config", str(lab), "--trials", "3",
            "--speed", "0.2", "--shifts", "1", "--scene", "flat", "--note", "three on the bench", "--out", str(out)]
    first = Operator(argv, data)
    first.expect("Place the robot, then Start trial 1 of 3")
    first.type("")
    first.expect("recording trial-000.h5")
    first.expect("outcome of trial 1")
    first.type("t")
    first.expect("note (Enter for none)")
    first.type("first one")
    first.expect("Place the robot, then Start trial 2 of 3")
    first.type("")
    first.expect("recording trial-001.h5")
    assert wait_for_file(out / "trial-001.h5")
    first.process.send_signal(signal.SIGINT)  # Ctrl-C while trial 2 plays: STOP
    first.expect("trial 2 stopped: kept in trial-001.h5, marked aborted")
    assert first.end() == 130
    _start, stop = read_documents(out / "trial-001.h5")
    assert (stop["exit_status"], stop["outcome"], stop["reason"]) == ("abort", "aborted", "STOP (Ctrl-C)")

    second = Operator(["trials", "--robot", "sim", "--daq", "sim", "--config", str(lab), "--out", str(out)], data)
    second.expect("Place the robot, then Start trial 3 of 3")  # resumed at the next trial, with its own options
    second.type("")
    second.expect("recording trial-002.h5")
    assert wait_for_file(out / "trial-002.h5")
    second.process.kill()  # kill -9 while trial 3 records
    assert second.end() == -signal.SIGKILL
    assert json.loads((out / "series.json").read_text())["trials"][2]["state"] == "recording"

    third = Operator(["trials", "--robot", "sim", "--daq", "sim", "--config", str(lab), "--out", str(out)], data)
    third.expect("trial 3 was cut short while recording")
    third.expect("Place the robot, then Start trial 3 of 3")
    third.type("")
    third.expect("outcome of trial 3")
    third.type("f")
    third.expect("note (Enter for none)")
    third.type("")
    third.expect("series complete: 3 of 3 trials finished (1 traversed, 1 failed, 1 aborted)")
    assert third.end() == 0
    assert "no repeatability report" in third.output  # no calibration given: no forces to compare

    uids = set()
    for k, outcome in enumerate(("traversed", "aborted", "failed")):
        start, stop = read_documents(out / f"trial-{k:03d}.h5")
        assert start["trial"] == k and start["note"] == "three on the bench" and stop["outcome"] == outcome
        assert stop["run_start"] == start["uid"]
        uids.add(start["series_uid"])
        with h5py.File(out / f"trial-{k:03d}.h5", "r") as f:
            least = 1 if k == 1 else 50  # trial 2 was stopped half a second in
            assert f["robot/goal_rad"].shape[0] > least and f["daq/time_s"].shape[0] > least  # motion and board
    assert len(uids) == 1
    assert read_documents(out / "trial-000.h5")[1]["note"] == "first one"
    with h5py.File(out / "trial-000.h5", "r") as f:
        goal = f["robot/goal_rad"][:, 0]
        assert goal.max() == pytest.approx(0.2, abs=1e-3) and goal[0] == pytest.approx(0.0, abs=1e-3)  # started
    _start, stop = read_documents(out / "trial-002.cut-short.h5")
    assert stop["exit_status"] == "fail" and "cut short" in stop["reason"]
    listing = io.StringIO()
    from contextlib import redirect_stdout

    with redirect_stdout(listing):
        assert main(["runs", "list", "--dir", str(out), "--where", f"series={uids.pop()}", "--where",
                     "status=success", "--format", "csv"]) == 0
    lines = listing.getvalue().strip().splitlines()
    assert len(lines) == 3 and {Path(line.split(",")[0]).name for line in lines[1:]} == {"trial-000.h5",
                                                                                         "trial-002.h5"}


def wait_for_file(path: Path, timeout_s: float = 30.0) -> bool:
    """The recording exists and its first flush (0.5 s) has put data in it."""
    from tests.waiting import wait_until

    def flushed() -> bool:
        try:
            with h5py.File(path, "r", locking=False) as f:
                return f["daq/time_s"].shape[0] > 0
        except (OSError, KeyError):
            return False

    return wait_until(flushed, timeout_s)


def test_sensnake_trials_refuses_what_it_cannot_run_before_anything_moves(tmp_path, capsys):
    lab = scripted_lab(tmp_path)
    assert main(["trials", "--robot", "sim", "--daq", "sim", "--config", str(lab), "--out", str(tmp_path / "s")]) == 1
    assert "needs SHAPE.json" in capsys.readouterr().err
    far = shape_file(tmp_path, "far", first_rad=9.0)
    assert main(["trials", str(far), "--robot", "sim", "--daq", "sim", "--config", str(lab), "--trials", "2",
                 "--out", str(tmp_path / "s")]) == 1
    err = capsys.readouterr().err
    assert "limit" in err and "Traceback" not in err
    assert not (tmp_path / "s").exists()
    started = time.monotonic()
    assert main(["trials", str(shape_file(tmp_path)), "--robot", "sim", "--daq", "sim", "--config", str(lab),
                 "--out", str(tmp_path / "s")]) == 1
    assert "needs --trials N" in capsys.readouterr().err and time.monotonic() - started < 5
