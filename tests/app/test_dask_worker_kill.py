"""A sweep on an external Dask cluster (``dask scheduler`` and two ``dask worker`` on 127.0.0.1) survives one of its
workers killed mid-sweep: the dead worker's run is retried on the other, every run completes, exit 0."""

from __future__ import annotations

import contextlib
import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mujoco")
pytest.importorskip("distributed")

from app.core.engines import RunJournal  # noqa: E402
from tests.waiting import wait_until  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
RUNS = 8


def _start(args: list[str], log: Path) -> subprocess.Popen:
    """``dask ARGS`` (the ``dask`` command of this interpreter) in its own session, so it and anything it starts are
    killed together, logging to ``log``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}
    with open(log, "w", encoding="utf-8") as sink:
        return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT, env=env, stdout=sink,
                                stderr=subprocess.STDOUT, start_new_session=True)


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
    process.wait(timeout=10)


@pytest.mark.slow
def test_killing_one_of_two_external_workers_mid_sweep_still_completes_every_run(tmp_path: Path) -> None:
    scheduler_file = tmp_path / "scheduler.json"
    processes = [_start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                         "--scheduler-file", str(scheduler_file)], tmp_path / "scheduler.log")]
    try:
        wait_until(lambda: scheduler_file.exists() and scheduler_file.stat().st_size > 0, timeout_s=60)
        address = json.loads(scheduler_file.read_text(encoding="utf-8"))["address"]
        assert address.startswith("tcp://127.0.0.1:")
        logs = [tmp_path / f"worker{k}.log" for k in range(2)]
        for k, log in enumerate(logs):  # no nanny: a killed worker stays dead (a nanny would restart it)
            processes.append(_start(["worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                     "--no-nanny", "--no-dashboard", "--name", f"w{k}"], log))
        wait_until(lambda: all("Registered to" in log.read_text(encoding="utf-8") for log in logs), timeout_s=60)

        plan = tmp_path / "s.toml"
        plan.write_text(f'scenes = ["paper_obstacle"]\ncontrollers = ["feedforward"]\nseeds = {list(range(RUNS))}\n'
                        'seconds = 1.5\nsettle_s = 0.3\nspeed_rad_s = 0.2\nrest_cap_s = 0.0\n', encoding="utf-8")
        out = tmp_path / "out"
        sweep = subprocess.Popen([sys.executable, "-m", "app", "experiment", "sweep", str(plan), "--out", str(out),
                                  "--engine", "dask", "--scheduler", address], cwd=ROOT, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        journal = RunJournal(out)
        wait_until(lambda: len(journal.load()) >= 1 or sweep.poll() is not None, timeout_s=120)
        finished_at_kill = len(journal.load())
        _stop(processes[1])  # the first worker, mid-sweep: its run in progress is lost with it
        stdout, stderr = sweep.communicate(timeout=240)
        failures = (out / "failures.csv").read_text(encoding="utf-8") if (out / "failures.csv").exists() else ""
        assert sweep.returncode == 0, f"stderr: {stderr}\nstdout: {stdout}\nfailures.csv: {failures[-3000:]}"
        assert finished_at_kill < RUNS, "the worker was killed after the sweep ended"
        assert "(2 worker(s))" in stdout
        with open(out / "summary.csv", newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
        assert sorted(int(r["run"]) for r in rows) == list(range(RUNS))
        assert not any(r["file"].startswith("failed") for r in rows)
        assert not (out / "failures.csv").exists()
        assert len(journal.load()) == RUNS
    finally:
        for process in reversed(processes):
            _stop(process)
