"""The embedded Dask cluster's stop: nothing outlives it, and its forkserver ends without the interpreter's teardown.
Dask on 127.0.0.1 only, each case in a process of its own (a Dask client keeps threads for the life of a process)."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from app.core.worker_server import SERVER_ENV  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
MARK = "SENSNAKE_TEST_MARK"  # an environment variable every process of the command inherits


def _marked(mark: str) -> list[int]:
    """The live processes (not zombies) whose environment carries ``mark``."""
    found = []
    needle = f"{MARK}={mark}".encode()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if needle in (entry / "environ").read_bytes().split(b"\0") and \
                    "zombie" not in (entry / "status").read_text().lower():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


def _run(code_or_args: list[str], mark: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *code_or_args], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, MARK: mark, **env})


def test_the_worker_server_skips_its_teardown_and_nothing_else_does():
    # An exit handler registered before the module is imported runs after the module's (last in, first out): it
    # prints only when the module let the interpreter finish the ordinary way.
    code = ("import atexit\natexit.register(lambda: print('torn down', flush=True))\n"
            "import app.core.worker_server as w\nprint(w._is_the_server(), flush=True)\n")
    mark = uuid.uuid4().hex
    server = _run(["-c", code], mark, **{SERVER_ENV: str(os.getpid())})  # this process started it: the server
    assert server.returncode == 0, server.stderr
    assert server.stdout.split() == ["True"]
    other = _run(["-c", code], mark, **{SERVER_ENV: "1"})  # another process's server: an ordinary end
    assert other.returncode == 0, other.stderr
    assert other.stdout.split() == ["False", "torn", "down"]
    plain = _run(["-c", code], mark)
    assert plain.stdout.split() == ["False", "torn", "down"]


def test_nothing_of_an_embedded_cluster_outlives_its_close():
    code = ("from app.core import engines\n"
            "engine = engines.DaskEngine(2)\n"
            "rows = []\n"
            "engine.run(abs, [-3, -4], lambda k, row, error: rows.append((k, row, error)))\n"
            "print(sorted(rows), flush=True)\n"
            "engine.close()\n"
            "print(engines._forkserver_started, flush=True)\n")
    mark = uuid.uuid4().hex
    done = _run(["-c", code], mark)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["[(0, 3, ''), (1, 4, '')]", "False"]
    assert _marked(mark) == []  # the workers, the forkserver: all gone when the command is


def test_a_dask_sweep_whose_file_is_refused_says_so_in_one_line_and_leaves_no_process(tmp_path):
    plan = tmp_path / "s.toml"
    plan.write_text('scenes = ["no_such_scene"]\ncontrollers = ["feedforward"]\n', encoding="utf-8")
    mark = uuid.uuid4().hex
    done = _run(["-m", "app", "experiment", "sweep", str(plan), "--out", str(tmp_path / "o"), "--engine", "dask",
                 "--jobs", "2"], mark)
    assert done.returncode == 1
    assert len(done.stderr.strip().splitlines()) == 1 and "no_such_scene" in done.stderr, done.stderr
    assert _marked(mark) == []  # the forkserver started for it is gone with the command


def test_the_embedded_scheduler_asks_for_a_heartbeat_every_worker_heartbeat_s_at_most() -> None:
    from app.core.engines import WORKER_HEARTBEAT_S, _slow_heartbeats

    class Scheduler:  # the two things the amendment touches: the handler table and the reply's key
        def __init__(self, interval: float) -> None:
            self.handlers = {"heartbeat_worker": lambda **kw: {"status": "OK", "heartbeat-interval": interval,
                                                               "address": kw["address"]}}

    quick, slow = Scheduler(0.5), Scheduler(2 * WORKER_HEARTBEAT_S)
    _slow_heartbeats(quick, WORKER_HEARTBEAT_S)
    _slow_heartbeats(slow, WORKER_HEARTBEAT_S)
    assert quick.handlers["heartbeat_worker"](address="w") == {"status": "OK", "heartbeat-interval": WORKER_HEARTBEAT_S,
                                                                "address": "w"}
    assert slow.handlers["heartbeat_worker"](address="w")["heartbeat-interval"] == 2 * WORKER_HEARTBEAT_S


def test_an_embedded_workers_event_loop_wakes_rarely_while_it_runs() -> None:
    # A worker runs its task in a thread beside its event loop; each wake-up of the loop takes the interpreter lock
    # from the run. After a heartbeat (forced here, so its reply has set the next one), the worker's periodic
    # callbacks are the thinned set: no memory monitor, heartbeats and the search for missing data every
    # WORKER_HEARTBEAT_S (Dask's scheduler asks for 0.5 s), the loop's check every 2 s.
    code = ("import asyncio\n"
            "from app.core import engines\n"
            "engine = engines.DaskEngine(1)\n"
            "async def beat(dask_worker):\n"
            "    await dask_worker.heartbeat()\n"
            "    dask_worker.find_missing()\n"
            "    return {k: pc.callback_time for k, pc in dask_worker.periodic_callbacks.items()}\n"
            "(times,) = engine.client.run(beat).values()\n"
            "saturation = engine.client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.WORKER_SATURATION)\n"
            "print(saturation, flush=True)\n"
            "print(sorted(times.items()), flush=True)\n"
            "engine.close()\n")
    mark = uuid.uuid4().hex
    done = _run(["-c", code], mark)
    assert done.returncode == 0, done.stderr
    times = dict(eval(done.stdout.splitlines()[-1]))  # noqa: S307 - our own child's printed list
    # a task goes to a worker only when it is free (Dask's 1.1 queues a second run on a one-thread worker, which
    # left the other worker idle at the sweep's end: up to 0.9 worker-seconds of a 17 s sweep)
    assert float(done.stdout.splitlines()[-2]) == 1.0
    from app.core.engines import WORKER_HEARTBEAT_S

    assert "memory_monitor" not in times
    assert times["heartbeat"] == times["find-missing"] == WORKER_HEARTBEAT_S * 1000
    assert times["tick"] == 2000
    wakeups_per_s = sum(1000.0 / ms for ms in times.values())
    assert wakeups_per_s < 1.5, times
    assert _marked(mark) == []
