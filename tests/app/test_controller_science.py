"""Pre-registered evaluation, tuning with Optuna, the engines (local processes, Dask on 127.0.0.1) and the sweep's
reliability: tiny runs of a few simulated seconds."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("mujoco")

from app.cli.main import main  # noqa: E402
from app.core import sweep  # noqa: E402
from app.core.engines import (  # noqa: E402
    FolderLock,
    RunJournal,
    capped_jobs,
    capped_words,
    check_scheduler,
    cores,
)
from app.core.errors import EngineError, EvaluationError, FolderBusyError, SweepError, TuneError  # noqa: E402
from app.core.evaluate import _interval, read_evaluation  # noqa: E402
from app.core.tune import read_tune  # noqa: E402
from models.controllers import law_gains  # noqa: E402
from models.force_feedback import FeedbackGains  # noqa: E402
from tests.waiting import wait_until  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TINY = 'seconds = 0.6\nsettle_s = 0.3\nspeed_rad_s = 0.2\nrest_cap_s = 0.0\n'


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def test_the_law_s_variants_zero_the_gains_they_leave_out():
    gains = FeedbackGains()
    assert law_gains("conform_only", gains).push_gain == 0.0
    assert law_gains("conform_only", gains).conform_gain == gains.conform_gain
    assert law_gains("push_only", gains).conform_gain == 0.0
    assert law_gains("feedback", gains) == gains
    with pytest.raises(ValueError, match="controller must be one of"):
        law_gains("feedforward", gains)


@pytest.mark.parametrize(("text", "words"), [
    ('scenes = ["flat"]\nseeds = [1.5]\n', "'seeds' must be whole numbers"),
    ('scenes = ["flat"]\ngains = []\n', "'gains' is empty"),
    ('scenes = ["flat"]\nmode = "crawl"\n', "'mode' must be one of"),
    ('scenes = ["no_such_scene"]\n', "scene file not found"),
    ('scenes = ["flat"]\ncontrollers = ["feedforward", "pid"]\n', "'controllers' must list some of"),
    ('scenes = ["flat"]\nseeds = ' + str(list(range(5001))) + '\n', "a sweep holds at most 10000"),
], ids=["fractional seed", "no gain set", "bad mode", "bad scene", "bad controller", "too many runs"])
def test_a_bad_sweep_is_refused_before_its_first_run(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SweepError, match=words):
        sweep.read_sweep(path)


def test_a_sweep_counts_its_runs_without_building_them(tmp_path):
    """A file asking for 3.6×10⁸ runs (15 kB of TOML) built every run to count them: 2.7 GB and a MemoryError
    traceback instead of the one-line refusal. The count is now the product of the lists."""
    mixed = sweep.SweepPlan(scenes=("flat", "step"), controllers=("feedforward", "feedback", "push_only"),
                            tail_loads_n=(0.0, 1.0), seeds=(1, 2, 3), gains=(FeedbackGains(),) * 4)
    assert mixed.count() == len(mixed.runs()) == 2 * (1 + 4 + 4) * 2 * 3
    huge = sweep.SweepPlan(scenes=("flat",), controllers=("feedforward", "feedback", "push_only", "conform_only"),
                           tail_loads_n=tuple(k / 1000 for k in range(600)), seeds=tuple(range(2000)),
                           gains=(FeedbackGains(),) * 100)
    assert huge.count() == (1 + 3 * 100) * 600 * 2000
    path = tmp_path / "big.toml"
    path.write_text('scenes = ["flat"]\ncontrollers = ["feedforward", "feedback"]\n'
                    f"tail_loads_n = {[k / 100 for k in range(100)]}\nseeds = {list(range(2000))}\n", encoding="utf-8")
    with pytest.raises(SweepError, match=r"big.toml: 400000 runs .*a sweep holds at most 10000: split it"):
        sweep.read_sweep(path)


def test_jobs_are_capped_at_the_runs_and_the_cores_and_a_folder_takes_one_command(tmp_path):
    assert capped_jobs(64, 3) == min(3, cores())
    assert capped_jobs(None, 1) == 1
    assert capped_words(1000, capped_jobs(1000, 3)) == \
        f" (--jobs 1000 capped at {min(3, cores())}: at most this machine's {cores()} core(s) and the runs to do)"
    assert capped_words(1, 1) == capped_words(None, 2) == ""  # as asked, or not asked: nothing to say
    with FolderLock(tmp_path, "sweep"), pytest.raises(FolderBusyError, match="another command is writing into it"), \
            FolderLock(tmp_path, "sweep"):
        pass
    with FolderLock(tmp_path, "sweep"):  # released: taken again
        pass


def test_a_command_refused_a_folder_names_its_holder_even_while_the_holder_writes_its_record(tmp_path):
    """Two commands started at the same instant: the one refused reads the lock file between the other's taking the
    lock and writing its record; it waits for the record, and names the holder."""
    import fcntl
    import threading

    fd = os.open(tmp_path / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # taken, no record yet
    late = threading.Timer(0.2, lambda: os.write(fd, b"4242 sweep\n"))
    late.start()
    try:
        with pytest.raises(FolderBusyError, match=r"\(process 4242 sweep\)"):
            FolderLock(tmp_path, "sweep").__enter__()
    finally:
        late.join()
        os.close(fd)


class _InlineEngine:
    description = "inline"

    def run(self, fn, tasks, on_done):
        for k, task in enumerate(tasks):
            try:
                on_done(k, fn(task), "")
            except Exception as exc:  # noqa: BLE001 - what an engine does: the traceback is the failure
                on_done(k, None, "".join(traceback.format_exception(exc)))

    def close(self):
        pass


def test_failed_runs_go_to_failures_csv_and_a_cut_short_sweep_resumes_keeping_finished_runs(tmp_path, monkeypatch):
    plan_file = tmp_path / "s.toml"
    plan_file.write_text('scenes = ["flat"]\ncontrollers = ["feedforward"]\nseeds = [0, 1, 2]\n', encoding="utf-8")
    plan = sweep.read_sweep(plan_file)
    calls: list[int] = []

    def fake_run(task):
        calls.append(task["run"])
        if task["seed"] == 2 and len(calls) < 4:
            raise RuntimeError("the simulated lab fell over")
        return {**dict.fromkeys(sweep.SUMMARY_COLUMNS, ""), "run": task["run"], "scene": task["scene"],
                "controller": task["controller"], "gains_index": -1, "tail_load_N": 0.0, "seed": task["seed"],
                "traversed": 0, "advance_m": 0.1, "overloads": 0, "file": Path(task["out"]).name, "valid": 1,
                "outcome": "not traversed"}

    monkeypatch.setattr(sweep, "_one", fake_run)
    monkeypatch.setattr(sweep, "open_engine", lambda *_a, **_k: _InlineEngine())
    out = tmp_path / "out"
    rows = sweep.run_sweep(plan, out)
    assert [r["file"].startswith("failed") for r in rows] == [False, False, True]
    failures = _rows(out / "failures.csv")
    assert len(failures) == 1 and "the simulated lab fell over" in failures[0]["error"]
    assert "Traceback" in failures[0]["error"]
    assert len(RunJournal(out).load()) == 2
    rows = sweep.run_sweep(plan, out)  # the same command: only the failed run runs again
    assert calls == [0, 1, 2, 2] and not (out / "failures.csv").exists()
    assert len(_rows(out / "summary.csv")) == 3
    with pytest.raises(SweepError, match="finished"):
        sweep.run_sweep(plan, out)
    other = tmp_path / "other.toml"
    other.write_text('scenes = ["flat"]\ncontrollers = ["feedforward"]\nseeds = [5]\n', encoding="utf-8")
    (out / "summary.csv").unlink()
    with pytest.raises(SweepError, match="holds another sweep"):
        sweep.run_sweep(sweep.read_sweep(other), out)


def _sensnake(*args: str, timeout_s: float = 120) -> subprocess.CompletedProcess:
    """The command in its own process (Dask's client keeps a thread pool for the life of a process)."""
    return subprocess.run([sys.executable, "-m", "app", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout_s)


def test_the_same_seeds_give_the_same_rows_on_local_processes_and_on_dask(tmp_path):
    plan = tmp_path / "s.toml"
    plan.write_text('scenes = ["paper_obstacle"]\ncontrollers = ["feedforward", "push_only"]\nseeds = [1]\n' + TINY,
                    encoding="utf-8")
    assert main(["experiment", "sweep", str(plan), "--out", str(tmp_path / "local"), "--jobs", "2"]) == 0
    done = _sensnake("experiment", "sweep", str(plan), "--out", str(tmp_path / "dask"), "--engine", "dask",
                     "--jobs", "2")
    assert done.returncode == 0, done.stderr
    assert "on Dask, an embedded cluster of 2 worker process(es) on 127.0.0.1" in done.stdout
    local, dask = _rows(tmp_path / "local" / "summary.csv"), _rows(tmp_path / "dask" / "summary.csv")
    assert len(local) == 2 and [r["controller"] for r in local] == ["feedforward", "push_only"]
    for a, b in zip(local, dask):
        assert {k: v for k, v in a.items() if k != "wall_s"} == {k: v for k, v in b.items() if k != "wall_s"}


@pytest.mark.parametrize("listening", [False, True], ids=["refused", "silent"])
def test_an_unreachable_scheduler_is_one_line_naming_it(tmp_path, listening):
    """A refused port, and a port that takes the connection but never speaks Dask (another program; a hung
    scheduler): both one line naming the address within the connect timeout, before anything is written."""
    import socket

    plan = tmp_path / "s.toml"
    plan.write_text('scenes = ["flat"]\ncontrollers = ["feedforward"]\n' + TINY, encoding="utf-8")
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)  # the kernel completes the connections; nothing is ever read or written
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}" if listening else "tcp://127.0.0.1:9"
        started = time.monotonic()
        done = _sensnake("experiment", "sweep", str(plan), "--out", str(tmp_path / "o"), "--engine", "dask",
                         "--scheduler", address, timeout_s=60)
        took = time.monotonic() - started
    err = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(err) == 1 and address in err[0], done.stderr
    assert "no Dask scheduler answered within 5 s" in err[0]
    assert took < 20  # 5 s of waiting for it, and the libraries' loading (held for good before, when listening)
    # Checked before anything is written: no folder claimed that would refuse the next command's other file.
    assert not (tmp_path / "o").exists()
    with pytest.raises(EngineError, match="not an address of the form"):
        check_scheduler("tcp://nohost")


def _children(pid: int) -> set[int]:
    found = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        text = (task / "children").read_text()
        found |= {int(p) for p in text.split()}
    return found


def test_sigterm_stops_the_workers_keeps_what_finished_and_the_same_command_resumes(tmp_path):
    plan = tmp_path / "s.toml"
    plan.write_text('scenes = ["paper_obstacle"]\ncontrollers = ["feedforward"]\nseeds = [0, 1, 2, 3]\n'
                    'seconds = 2.5\nsettle_s = 0.3\nspeed_rad_s = 0.2\nrest_cap_s = 0.0\n', encoding="utf-8")
    out = tmp_path / "out"
    command = [sys.executable, "-m", "app", "experiment", "sweep", str(plan), "--out", str(out), "--jobs", "2"]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    journal = RunJournal(out)
    wait_until(lambda: len(journal.load()) >= 1, timeout_s=60)
    workers = _children(process.pid)
    assert workers, "the sweep's workers"
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 130, err
    assert "interrupted (SIGTERM)" in err and "the same command resumes" in err
    wait_until(lambda: not any(Path(f"/proc/{pid}").exists() for pid in workers), timeout_s=10)
    finished = len(journal.load())
    assert len(_rows(out / "summary.csv")) == finished < 4
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"{finished} finished before (resuming)" in done.stdout
    assert len(_rows(out / "summary.csv")) == 4


def test_ctrl_c_to_a_dask_sweeps_process_group_leaves_one_line_and_no_worker(tmp_path):
    """The terminal sends Ctrl-C to the whole process group: the command cancels and stops the cluster; its workers
    leave it to the command (they printed a KeyboardInterrupt traceback each)."""
    plan = tmp_path / "s.toml"
    plan.write_text('scenes = ["paper_obstacle"]\ncontrollers = ["feedforward"]\nseeds = [0, 1, 2, 3, 4, 5]\n'
                    'seconds = 2.5\nsettle_s = 0.3\nspeed_rad_s = 0.2\nrest_cap_s = 0.0\n', encoding="utf-8")
    out = tmp_path / "out"
    command = [sys.executable, "-m", "app", "experiment", "sweep", str(plan), "--out", str(out), "--jobs", "2",
               "--engine", "dask"]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)  # its own group, as a terminal's foreground command
    journal = RunJournal(out)
    wait_until(lambda: len(journal.load()) >= 1, timeout_s=90)
    group = {int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and _group(int(p.name)) == process.pid}
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted (SIGINT)" in err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    wait_until(lambda: not any(_group(pid) == process.pid for pid in group), timeout_s=10)
    assert len(_rows(out / "summary.csv")) == len(journal.load()) < 6


def _group(pid: int) -> int | None:
    """The process group of ``pid``, None once it has gone."""
    try:
        return os.getpgid(pid)
    except ProcessLookupError:
        return None


EVAL = '''seed = 20261204
seeds_per_condition = 10
controllers = ["feedback"]
seconds = 0.5
settle_s = 0.2
rest_cap_s = 0.0
speed_rad_s = 0.2
bootstrap = 200
[[family]]
kind = "half_cylinder"
conditions = 1
tail_load_n = 0.0
'''


def test_an_evaluation_draws_from_its_file_runs_pairs_and_refuses_another_file_in_its_folder(tmp_path, capsys):
    path = tmp_path / "eval.toml"
    path.write_text(EVAL, encoding="utf-8")
    first, again = read_evaluation(path), read_evaluation(path)
    assert first.conditions == again.conditions and first.runs == 20  # 1 condition × 10 seeds × 2
    out = tmp_path / "out"
    assert main(["experiment", "evaluate", str(path), "--out", str(out)]) == 0
    table = _rows(out / "evaluation.csv")
    assert first.sha256 in (out / "evaluation.csv").read_text(encoding="utf-8").splitlines()[0]
    overloads = next(r for r in table if r["family"] == "all" and r["metric"] == "overloads")
    assert overloads["pairs"] == "10" and overloads["controller"] == "feedback"
    traversal = next(r for r in table if r["family"] == "all" and r["metric"] == "traversal")
    assert traversal["undecided_pairs"] == "10"  # no wait for rest: undecided, left out of the traversal
    assert (out / "evaluation.png").stat().st_size > 0 and (out / "evaluation.svg").exists()
    assert len(_rows(out / "runs.csv")) == 20
    path.write_text(EVAL.replace("20261204", "7"), encoding="utf-8")
    assert main(["experiment", "evaluate", str(path), "--out", str(out)]) == 1
    assert "holds the evaluation of another file" in capsys.readouterr().err


@pytest.mark.parametrize(("text", "words"), [
    (EVAL.replace("seeds_per_condition = 10", "seeds_per_condition = 5"), "'seeds_per_condition' must be"),
    (EVAL.replace("seed = 20261204\n", ""), "'seed' .the draw's seed"),
    (EVAL + "colour = 1\n", "unknown key 'colour'"),
    (EVAL.replace('kind = "half_cylinder"', 'kind = "cliff"'), "'kind' must be one of"),
    (EVAL.replace('controllers = ["feedback"]', 'controllers = ["feedforward"]'), "'controllers' must list"),
])
def test_a_bad_evaluation_file_is_refused_naming_the_key(tmp_path, text, words):
    path = tmp_path / "eval.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(EvaluationError, match=words):
        read_evaluation(path)


def test_the_bootstrap_interval_resamples_conditions_and_covers_the_difference():
    values = [(c, 0.0, 0.1 * c) for c in range(6) for _ in range(10)]
    entry = _interval(values, 500, 0.95, seed=1)
    assert entry["difference"] == pytest.approx(0.25)
    assert entry["ci_low"] < 0.25 < entry["ci_high"]
    assert entry["ci_low"] >= 0.0 and entry["ci_high"] <= 0.5
    alone = _interval([(3, 0.0, 0.1), (3, 0.0, 0.3)], 500, 0.95, seed=1)  # one condition: no interval
    assert alone["difference"] == pytest.approx(0.2) and math.isnan(alone["ci_low"]) and math.isnan(alone["ci_high"])


def test_an_evaluation_run_mujoco_flags_is_left_out_with_its_pair_counted_and_named(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    reason = "invalid run: MuJoCo: bad QACC (NaN, Inf or huge acceleration) at DOF 29 at t=3.21 s"

    def fake_run(task: dict[str, Any]) -> dict[str, Any]:  # the law's run of the first seed stops being physics; every other run advances 0.1 m
        row = {**dict.fromkeys(sweep.SUMMARY_COLUMNS, ""), "run": task["run"], "scene": task["scene"],
               "controller": task["controller"], "gains_index": task["gains_index"], "tail_load_N": 0.0,
               "seed": task["seed"], "file": Path(task["out"]).name}
        if task["run"] == 1:
            return {**row, "valid": 0, "invalid_reason": reason, "outcome": "invalid"}
        return {**row, "traversed": 0, "advance_m": 0.1, "advance_at_rest_m": 0.1, "overloads": 0, "valid": 1,
                "outcome": "not traversed"}

    monkeypatch.setattr(sweep, "_one", fake_run)
    monkeypatch.setattr("app.core.evaluate.open_engine", lambda *_a, **_k: _InlineEngine())
    path = tmp_path / "eval.toml"
    path.write_text(EVAL, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["experiment", "evaluate", str(path), "--out", str(out)]) == 3  # an invalid run: exit 3
    for row in _rows(out / "evaluation.csv"):  # 10 seeds, one pair left out as invalid, never data
        assert (row["invalid_pairs"], row["pairs"]) == ("1", "9"), row
    err = capsys.readouterr().err
    assert f"run 1 (half_cylinder condition 0, feedback, seed {read_evaluation(path).conditions[0].seeds[0]}) " \
           f"{reason}: left out (its pair with it)" in err
    assert json.loads((out / "evaluation.json").read_text(encoding="utf-8"))["invalid_runs"] == 1


TUNE = '''train_scenes = ["flat"]
test_scenes = ["{test}"]
seeds = [1]
seconds = 0.5
settle_s = 0.2
speed_rad_s = 0.2
rest_cap_s = 3.0
[space]
push_gain = [0.05, 0.4]
target_n = [3.0, 12.0, "log"]
'''


def test_a_tuning_keeps_its_study_in_the_folder_resumes_it_and_scores_train_and_test(tmp_path, capsys):
    test_scene = tmp_path / "rough_flat.toml"
    test_scene.write_text('[ground]\nfriction = 0.4\n[robot]\nhead_x_m = 0.48\nstart = "flat"\n', encoding="utf-8")
    path = tmp_path / "tune.toml"
    path.write_text(TUNE.format(test=test_scene), encoding="utf-8")
    out = tmp_path / "out"
    assert main(["experiment", "tune", str(path), "--trials", "2", "--out", str(out), "--jobs", "2"]) == 0
    assert len(_rows(out / "trials.csv")) == 2
    assert main(["experiment", "tune", str(path), "--trials", "3", "--out", str(out), "--jobs", "2"]) == 0
    trials = _rows(out / "trials.csv")
    assert [t["trial"] for t in trials] == ["0", "1", "2"]  # added to, never restarted
    assert trials[0]["push_gain"] == "0.2"  # the defaults first
    assert "2 trial(s) before, 1 to add" in capsys.readouterr().out
    report = _rows(out / "report.csv")
    assert {(r["gains"], r["split"]) for r in report} >= {("best", "train"), ("best", "test")}
    assert (out / "study.journal").exists() and (out / "tune.png").exists()
    run = tmp_path / "run.h5"  # best_gains.toml is a gains file experiment run takes
    assert main(["experiment", "run", "--scene", "flat", "--seconds", "0.2", "--settle", "0.1", "--rest-cap", "0",
                 "--controller", "feedback", "--gains", str(out / "best_gains.toml"), "--out", str(run)]) == 0


def test_a_tuning_file_is_refused_when_a_test_scene_is_trained_on_or_its_space_is_empty(tmp_path):
    path = tmp_path / "tune.toml"
    path.write_text(TUNE.format(test="flat"), encoding="utf-8")
    with pytest.raises(TuneError, match="is also a training scene"):
        read_tune(path)
    path.write_text(TUNE.format(test="paper_obstacle").split("[space]")[0] + "[space]\n", encoding="utf-8")
    with pytest.raises(TuneError, match=r"\[space\] is empty"):
        read_tune(path)
    # every trial runs every training condition: 2,000 seeds × 600 loads is refused, not started
    path.write_text(TUNE.format(test="paper_obstacle").replace(
        "seeds = [1]", f"seeds = {list(range(2000))}\ntail_loads_n = {[k / 1000 for k in range(600)]}"),
        encoding="utf-8")
    with pytest.raises(TuneError, match="1200000 training conditions a trial .* at most 1000 a trial"):
        read_tune(path)


def _death_signal(_task: Any) -> int:
    from app.core.engines import parent_death_signal

    return parent_death_signal()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_local_worker_is_killed_by_the_kernel_when_its_parent_dies():
    """Not only the half-second watch: a run in progress must not finish and be written after a kill -9 of the
    command (it is not journaled; the resuming command would run and write it again)."""
    from app.core.engines import LocalEngine

    told: list[Any] = []
    LocalEngine(2).run(_death_signal, [{}, {}], lambda k, row, error: told.append((row, error)))
    assert told == [(int(signal.SIGKILL), "")] * 2


INTERRUPTED_WITH_A_RUN_DONE = """
import json, sys, time
from app.core import engines
from app.core.errors import RunsInterrupted
told = []
def on_done(k, row, error):
    told.append((k, error))
    if len(told) == 1:
        # Deliberate: the interruption being taken; run 1 finishes meanwhile, run 2 has started.
        time.sleep(1.5)
        raise KeyboardInterrupt
engine = engines.DaskEngine(2) if sys.argv[1] == "dask" else engines.LocalEngine(2)
started = time.monotonic()
try:
    engine.run(time.sleep, [0.05, 0.4, 60.0], on_done)
except RunsInterrupted as exc:
    print(json.dumps({"finished": exc.finished, "told": sorted(told), "s": time.monotonic() - started}), flush=True)
engine.close()
"""


@pytest.mark.parametrize("engine", ["local", "dask"])
def test_a_run_that_finished_while_an_interruption_was_taken_is_kept_and_a_running_one_is_not_waited_for(engine):
    """Its recording is written: left out of the journal, the resuming command ran and wrote it again (Ctrl-C on an
    embedded cluster left 15 recordings beside a summary of 13). The run in progress is abandoned at once."""
    done = subprocess.run([sys.executable, "-c", INTERRUPTED_WITH_A_RUN_DONE, engine], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    said = json.loads(done.stdout.strip().splitlines()[-1])
    assert said["finished"] == 2 and said["told"] == [[0, ""], [1, ""]], said
    assert said["s"] < 30  # run 2 (a minute) was not waited for


def test_no_worker_outlives_its_parent():
    """The local workers watch their parent: one killed with SIGKILL leaves none running."""
    code = ("import time\nfrom app.core.engines import LocalEngine\n"
            "LocalEngine(1).run(time.sleep, [600], lambda *a: None)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT)
    wait_until(lambda: bool(_children(parent.pid)), timeout_s=30)
    workers = _children(parent.pid)
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait(timeout=10)
    wait_until(lambda: not any(Path(f"/proc/{pid}").exists() and "zombie" not in
                               Path(f"/proc/{pid}/status").read_text().lower() for pid in workers), timeout_s=10)
