"""Where a sweep's, an evaluation's and a tuning's runs execute: local processes (default) or a Dask cluster.

An engine takes a picklable function and a list of tasks (each a dict of arguments, each one run of the physics lab
writing its own recording) and reports each task's result as it finishes: the summary row the function returned,
or the traceback of what it raised. Both engines run one task per single-threaded worker process:

* :class:`LocalEngine` — ``concurrent.futures.ProcessPoolExecutor``. Its workers ignore SIGINT (the terminal sends
  Ctrl-C to the whole process group: the parent decides), take SIGTERM's default, die with their parent (even by
  SIGKILL: on Linux the kernel kills them at once, elsewhere a watch ends them within half a second; no orphan keeps
  running a run nobody will read) and do not keep the folder's lock open.
* :class:`DaskEngine` — ``dask.distributed``: without a scheduler address an embedded
  ``LocalCluster(host="127.0.0.1")`` of one single-threaded worker process per job, forked from one forkserver
  (:func:`start_worker_server`); with one, that cluster (whose workers must see the output folder at the same
  path). A worker that dies takes its task to another worker (the scheduler's ``allowed-failures``); an address that
  does not answer is one line naming it within :data:`CONNECT_TIMEOUT_S`. An embedded cluster's housekeeping is
  thinned (:data:`QUIET_DASK`, :data:`WORKER_HEARTBEAT_S`: a worker's event loop takes the interpreter lock from its
  run each time it wakes); an external cluster's workers keep their own settings (docs/decisions/0017 lists the
  environment that thins theirs).

Ctrl-C, and SIGTERM or SIGHUP while :func:`interruptible` guards the wait, cancel the pending tasks and stop the
workers (their runs in progress are abandoned; their recordings are not in the folder's journal and run again on
resume); the engine then raises :class:`RunsInterrupted`. :class:`FolderLock` keeps a second command out of a folder
being written (``fcntl.flock``: the kernel releases it when the process dies, however it dies). :class:`RunJournal`
is the folder's record of finished runs, one JSON line each, written as each finishes (a line cut short by a kill is
ignored), so the same command resumes a folder without running a finished run again.

Qt-free. Called from the command's main thread.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import fcntl
import json
import math
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

from app.core.errors import EngineError, FolderBusyError, RunsInterrupted
from app.core.outputs import open_lock_file
from devices.toml_files import read_json_file, read_text_file

ENGINES = ("local", "dask")
INTERRUPT_FETCH_S = 2.0  # how long an interrupted Dask sweep waits for each finished run's row
CONNECT_TIMEOUT_S = 5.0  # a scheduler that does not answer within this is named in one line
PARENT_WATCH_S = 0.5  # how often a local worker checks that its parent is alive
HOLDER_WAIT_S = 1.0  # a command refused a folder waits this long at most for the holder's record, to name it
MAX_RUNS = 10_000  # more runs than this in one command is a mistake in the file, not a plan (refused before any run)
# Dask's periodic housekeeping, slowed and thinned. It costs twice. Its CPU: with Dask's defaults an idle embedded
# cluster of two workers (the scheduler, the nannies and the client in this process, the two workers) took 0.065 of a
# core. And the interpreter lock, in each worker: a worker runs its task in a thread beside its event loop, and each
# time the loop wakes (every periodic callback, every heartbeat) it takes the lock from the running task, two to five
# times a wake-up (again after each system call its callback makes), the task waiting each time (0.12 ms median,
# 3.5 ms at the 90th percentile on a busy machine). With Dask's settings a worker's loop woke ~8 times a second during
# a run and took the lock from a pure-Python task 19-36 times a second; with these ~1.4 and 5-6 (the lock waits
# around each task's start and end stay: ``benchmarks/probe_engine_runs.py``, decision 0017). The loop's health check ticks every 2 s (Dask: 20 ms; its "unresponsive" warning is at 3 s), its
# speed is cycled every 5 s (1 s); the system monitor samples every 10 s (500 ms), GIL contention is not polled (every
# 1 ms when ``gilknocker`` is installed); a worker neither spills nor pauses, so its own memory monitor (10 times a
# second by default) goes: the results it holds are summary rows, and the nanny still ends a worker past 95 % of its
# memory limit, every second, from this process; no work stealing (the scheduler queues the runs: a worker takes one
# when free). Heartbeats: :data:`WORKER_HEARTBEAT_S`.
QUIET_DASK: dict[str, Any] = {"distributed.admin.tick.interval": "2s",
                              "distributed.admin.tick.cycle": "5s",
                              "distributed.admin.system-monitor.interval": "10s",
                              "distributed.admin.system-monitor.gil.enabled": False,
                              "distributed.worker.memory.monitor-interval": "1s",
                              "distributed.worker.memory.spill": False,
                              "distributed.worker.memory.pause": False,
                              "distributed.scheduler.work-stealing": False}
# An embedded cluster's workers heartbeat every this many seconds. Dask's scheduler asks a cluster of up to 10
# workers for one every 0.5 s (not a setting: ``distributed.scheduler.heartbeat_interval``), and each worker then
# looks for missing data as often: 4 of a worker's ~8 wake-ups a second. Nothing here waits on a heartbeat: a dead
# worker's connection breaks (the scheduler retries its run at once), and a silent one is dropped after
# ``distributed.scheduler.worker-ttl`` (5 minutes).
WORKER_HEARTBEAT_S = 5.0
# What an embedded cluster's worker imports before its first run: imported once, in the forkserver the workers are
# forked from (``distributed`` itself, the sweep's run function and the physics lab it runs), not once per worker.
# ``app.core.worker_server`` makes the server's own end quick.
WORKER_PRELOAD = ("distributed", "app.core.sweep", "app.core.experiment", "app.core.worker_server")

Task = dict[str, Any]
Row = dict[str, Any]
# (task index, the row the function returned or None, the traceback of what it raised or "")
DoneCallback = Callable[[int, "Row | None", str], None]


def cores() -> int:
    """The cores this process may run on (its affinity, else the machine's)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def capped_words(jobs: int | None, used: int) -> str:
    """What a command says after its engine when it runs fewer at a time than ``--jobs`` asked ("" otherwise)."""
    if jobs is None or jobs <= used:
        return ""
    return f" (--jobs {jobs} capped at {used}: at most this machine's {cores()} core(s) and the runs to do)"


def capped_jobs(jobs: int | None, runs: int) -> int:
    """Runs at a time: ``jobs`` (default: every core), never more than the cores nor than the runs, at least 1."""
    if jobs is not None and jobs < 1:
        raise ValueError(f"--jobs must be 1 or more, got {jobs}")
    return max(1, min(jobs or cores(), cores(), max(runs, 1)))


class Engine(Protocol):
    """Runs ``fn(task)`` for every task, calling ``on_done`` in the caller's thread as each finishes."""

    description: str

    def run(self, fn: Callable[[Task], Row], tasks: Sequence[Task], on_done: DoneCallback) -> None: ...

    def close(self) -> None: ...


# -- the local process pool ------------------------------------------------------------------------------------------
_INHERITED_FDS: set[int] = set()  # lock files a forked worker must not keep open


def _watch_parent(parent_pid: int) -> None:
    # Deliberate polling: a dead parent sends no message. getppid changes (to init or a subreaper) once it is gone.
    while os.getppid() == parent_pid:
        time.sleep(PARENT_WATCH_S)
    os._exit(1)


def _local_worker_init(parent_pid: int, lock_fds: tuple[int, ...]) -> None:
    """A local worker: Ctrl-C is the parent's to handle, SIGTERM/SIGHUP end it, its parent's death ends it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_DFL)
    for fd in lock_fds:  # the parent's lock stays the parent's: released when it dies, whatever the workers do
        with contextlib.suppress(OSError):
            os.close(fd)
    _die_with_parent()
    if os.getppid() != parent_pid:  # it died before that took hold
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watch").start()


PR_SET_PDEATHSIG, PR_GET_PDEATHSIG = 1, 2  # prctl(2)


def _die_with_parent() -> None:
    """Linux: the kernel kills this process the moment its parent dies (``PR_SET_PDEATHSIG``), so a run in progress
    is not finished and written after a kill -9 of the command — where the half-second watch let one or two finish
    unjournaled, to be run and written again by the resuming command. The watch stays for other systems."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def parent_death_signal() -> int:
    """This process's parent-death signal (0: none; Linux only, else 0)."""
    if not sys.platform.startswith("linux"):
        return 0
    import ctypes

    value = ctypes.c_int(0)
    ctypes.CDLL(None, use_errno=True).prctl(PR_GET_PDEATHSIG, ctypes.byref(value), 0, 0, 0)
    return value.value


class LocalEngine:
    """``jobs`` worker processes on this machine (``concurrent.futures.ProcessPoolExecutor``)."""

    def __init__(self, jobs: int) -> None:
        self.jobs = max(1, jobs)
        self.description = f"{self.jobs} local process{'es' if self.jobs > 1 else ''}"

    def run(self, fn: Callable[[Task], Row], tasks: Sequence[Task], on_done: DoneCallback) -> None:
        if not tasks:
            return
        pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=min(self.jobs, len(tasks)), initializer=_local_worker_init,
            initargs=(os.getpid(), tuple(sorted(_INHERITED_FDS))))
        finished = 0
        try:
            pending = {pool.submit(fn, task): k for k, task in enumerate(tasks)}
            for future in concurrent.futures.as_completed(list(pending)):
                k = pending.pop(future)  # told once: an interruption keeps only the runs not yet told
                try:
                    row: Row | None = future.result()
                    error = ""
                except Exception as exc:  # noqa: BLE001 - a run that raised is a failure with its traceback
                    row, error = None, "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
                finished += 1
                on_done(k, row, error)
        except KeyboardInterrupt as exc:
            _stop_pool(pool)
            # Runs whose result arrived while the interruption was being taken are kept, not run again.
            for future, k in pending.items():
                if future.done() and not future.cancelled() and future.exception() is None:
                    finished += 1
                    on_done(k, future.result(), "")
            raise RunsInterrupted(finished, len(tasks), getattr(exc, "signal_name", "SIGINT")) from None
        except BaseException:
            _stop_pool(pool)
            raise
        pool.shutdown(wait=True)

    def close(self) -> None:
        return None


def _stop_pool(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """Cancel what has not started and kill the workers (a run in progress is abandoned)."""
    # The executor has no public way to stop a running task: its worker processes are killed by hand (the
    # ``_processes`` map is CPython's, stable since 3.2), before shutdown so none picks up another task.
    processes = list(getattr(pool, "_processes", {}).values())
    for process in processes:
        with contextlib.suppress(OSError, ValueError):
            process.kill()
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            process.join(timeout=5.0)


# -- Dask ------------------------------------------------------------------------------------------------------------
class DaskEngine:
    """Runs on a Dask cluster: an embedded ``LocalCluster`` on 127.0.0.1 (``scheduler`` None) or the one at
    ``scheduler`` (``tcp://HOST:PORT``)."""

    def __init__(self, jobs: int, scheduler: str | None = None) -> None:
        self._cluster: Any = None
        if scheduler is None:
            start_worker_server()  # first: it imports the workers' modules while this process imports distributed
            self._cluster, self.client = _start_cluster(max(1, jobs))
            self.description = f"Dask, an embedded cluster of {max(1, jobs)} worker process(es) on 127.0.0.1"
            return
        from distributed import Client

        _configure_dask()
        try:
            self.client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise _unanswered(scheduler, exc) from None
        workers = len(self.client.scheduler_info().get("workers", {}))
        self.description = f"Dask, the cluster at {scheduler} ({workers} worker(s))"

    def run(self, fn: Callable[[Task], Row], tasks: Sequence[Task], on_done: DoneCallback) -> None:
        from distributed import as_completed

        if not tasks:
            return
        # Held by key until its result is taken, then released: a worker that dies takes only its pending and
        # running tasks with it (a finished run whose result the client still held would be run again elsewhere).
        pending: dict[Any, Any] = {}
        index: dict[Any, int] = {}
        for k, task in enumerate(tasks):
            future = self.client.submit(fn, task, pure=False, key=f"run-{k}-{os.getpid()}-{time.monotonic_ns()}")
            pending[future.key], index[future.key] = future, k
        finished = 0
        try:
            for future in as_completed(list(pending.values())):
                k = index[future.key]
                if future.status == "finished":
                    row, error = future.result(), ""
                else:  # an error raised in the run (or a task lost beyond the scheduler's retries)
                    exc = future.exception()
                    tb = future.traceback()
                    error = "".join(traceback.format_exception(type(exc), exc, tb)) if exc is not None else \
                        f"the task ended {future.status}"
                    row = None
                pending.pop(future.key, None)
                future.release()
                finished += 1
                on_done(k, row, error)
        except KeyboardInterrupt as exc:
            # Runs that finished while the interruption was being taken are kept, not run again: their rows are
            # fetched (briefly: they are small) before the workers that hold them go.
            kept: list[tuple[int, Any]] = []
            for future in [f for f in pending.values() if f.status == "finished"]:
                with contextlib.suppress(Exception):  # noqa: BLE001 - a row not fetched is only run again on resume
                    kept.append((index[future.key], future.result(timeout=INTERRUPT_FETCH_S)))
            self._kill_embedded_workers()
            self.client.cancel(list(pending.values()), force=True)
            for k, row in kept:
                finished += 1
                on_done(k, row, "")
            self.close()
            raise RunsInterrupted(finished, len(tasks), getattr(exc, "signal_name", "SIGINT")) from None

    def _kill_embedded_workers(self) -> None:
        """An embedded cluster's worker processes killed at once, as the local pool's are: a run in progress is
        abandoned, not finished and written unjournaled while the cluster closes (Ctrl-C left 15 recordings beside a
        summary of 13; the resuming command ran and wrote the 2 again). An external cluster's workers are not ours to
        kill: their runs in progress finish there."""
        if self._cluster is None:
            return
        for nanny in list(getattr(self._cluster, "workers", {}).values()):
            pid = getattr(getattr(nanny, "process", None), "pid", None)
            if isinstance(pid, int) and pid > 0:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)

    def close(self) -> None:
        if self._cluster is not None:
            _close_cluster(self._cluster, self.client)
            self._cluster = None
            stop_worker_server()
            return
        with contextlib.suppress(Exception):  # noqa: BLE001 - closing what may already be gone
            self.client.close(timeout=10)


def _configure_dask() -> None:
    import dask

    # No statistical profiler on the workers: it holds the frames of a running task, and with them the buffers a
    # run's wire parsers have lent out, which then cannot be resized ("BufferError: Existing exports of data").
    # An external cluster's workers need the same (DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False).
    dask.config.set({"distributed.worker.profile.enabled": False, **QUIET_DASK})


def _start_cluster(jobs: int) -> tuple[Any, Any]:
    """An embedded cluster of ``jobs`` single-threaded worker processes forked from the forkserver, and its client."""
    import dask
    from distributed import Client, LocalCluster

    _configure_dask()
    # A task goes to a worker only when it is free (Dask's default, 1.1, queues a second one on each single-threaded
    # worker): at a sweep's end one worker otherwise sits idle while the other still holds two runs.
    dask.config.set({"distributed.worker.multiprocessing-method": "forkserver",
                     "distributed.scheduler.worker-saturation": 1.0})
    cluster = LocalCluster(host="127.0.0.1", n_workers=jobs, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=50, heartbeat_interval=f"{WORKER_HEARTBEAT_S:g}s")
    try:
        _slow_heartbeats(cluster.scheduler, WORKER_HEARTBEAT_S)
        return cluster, Client(cluster, timeout=CONNECT_TIMEOUT_S)
    except BaseException:
        _close_cluster(cluster, None)
        raise


def _slow_heartbeats(scheduler: Any, seconds: float) -> None:
    """Have ``scheduler`` (this process's own, an embedded cluster's) ask its workers for a heartbeat every
    ``seconds`` at most. A worker sets its next heartbeat from each heartbeat's reply (``heartbeat-interval``); the
    reply is amended on the way out of the scheduler's handler, for this scheduler only (Dask has no setting for it).
    Nothing to amend (a Dask that names things otherwise) leaves Dask's interval, which only costs time."""
    handlers = getattr(scheduler, "handlers", None)
    if not isinstance(handlers, dict) or handlers.get("heartbeat_worker") is None:
        return
    handler = handlers["heartbeat_worker"]

    def heartbeat_worker(*args: Any, **kwargs: Any) -> Any:
        reply = handler(*args, **kwargs)
        if isinstance(reply, dict) and isinstance(reply.get("heartbeat-interval"), (int, float)):
            reply["heartbeat-interval"] = max(float(reply["heartbeat-interval"]), seconds)
        return reply

    handlers["heartbeat_worker"] = heartbeat_worker


def _close_cluster(cluster: Any, client: Any) -> None:
    if client is not None:
        with contextlib.suppress(Exception):  # noqa: BLE001 - closing what may already be gone
            client.close(timeout=10)
    with contextlib.suppress(Exception):  # noqa: BLE001
        cluster.close(timeout=10)


_forkserver_started = False  # this module started the process's forkserver (and so stops it)


def start_worker_server() -> None:
    """Start this process's multiprocessing forkserver, importing :data:`WORKER_PRELOAD`, without waiting for it.

    An embedded cluster's workers are forked from it (``distributed.worker.multiprocessing-method``). Spawned (Dask's
    default), each worker started a fresh interpreter, imported distributed (0.4-1.2 s measured) and then the physics
    lab in its first run (0.3-1.2 s); and the cluster's stop waited 0.8-1.0 s for the spawned processes, 0.03-0.05 s
    for forked ones. The command line calls this as soon as it knows an embedded cluster is wanted, so the server's
    imports overlap the command's own; :class:`DaskEngine` calls it again (nothing to do then). Starting the cluster
    itself that early, in a thread beside the command's preparation, was measured and bought nothing (engine overhead
    +6.7 % against +6.2 %, 4 rounds each, load 4-5): the server's imports are the start's longest part, and this
    process's import of distributed, run in a thread, only slowed the preparation by what it saved. A forkserver
    already
    running (started by something else in this process) is used as it is: its workers then import what it lacks in
    their first run. Main thread."""
    global _forkserver_started
    import multiprocessing
    from multiprocessing import forkserver

    running = getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", None) is not None
    if running:
        return
    from app.core.worker_server import SERVER_ENV

    multiprocessing.get_context("forkserver").set_forkserver_preload(list(WORKER_PRELOAD))
    os.environ[SERVER_ENV] = str(os.getpid())  # the server, and only it, is told who started it
    try:
        forkserver.ensure_running()
    finally:
        del os.environ[SERVER_ENV]
    _forkserver_started = True


def stop_worker_server() -> None:
    """Stop the forkserver :func:`start_worker_server` started and wait for it (an idle process holding the physics
    lab's imports would otherwise stay until this process ends, and its workers' CPU time would not be counted in
    this process's children's). The standard library has no public stop: ``ForkServer._stop`` is the one its own
    tests use (3.8 on); without it the server is left to end with this process."""
    global _forkserver_started
    if not _forkserver_started:
        return
    _forkserver_started = False
    from multiprocessing import forkserver

    stop = getattr(getattr(forkserver, "_forkserver", None), "_stop", None)
    if stop is not None:
        with contextlib.suppress(OSError, ChildProcessError):
            stop()


def check_scheduler(scheduler: str | None) -> None:
    """Before a command writes anything into its folder: :class:`EngineError` (the same line as the engine's) unless
    a Dask scheduler answers at ``scheduler``'s TCP address within :data:`CONNECT_TIMEOUT_S` (a folder a command
    claimed and then could not run in held a record that refused the next command's other file). It is asked who it
    is, the whole exchange bounded: a port that takes the connection and never speaks Dask (another program, a
    firewall's proxy, a hung scheduler) held the command for good when only the TCP connection was checked. None, or
    another protocol than ``tcp://``: nothing checked here (the engine's own connection says it)."""
    if not scheduler:
        return
    address = scheduler[len("tcp://"):] if scheduler.startswith("tcp://") else scheduler
    if "://" in address:
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise EngineError(f"--scheduler {scheduler}: not an address of the form tcp://HOST:PORT")
    import asyncio
    import socket

    from distributed.core import rpc

    try:  # a refused port or an unknown host is said at once (Dask's own connect retries it until its timeout)
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except (OSError, ValueError) as exc:
        raise _unanswered(scheduler, exc) from None

    async def identity() -> Any:
        async with rpc(f"tcp://{address}", timeout=CONNECT_TIMEOUT_S) as remote:
            return await remote.identity()

    try:
        answer = asyncio.run(asyncio.wait_for(identity(), CONNECT_TIMEOUT_S))
    except (asyncio.TimeoutError, TimeoutError):
        raise _unanswered(scheduler, TimeoutError("it took the connection but did not answer as Dask does")) from None
    except Exception as exc:  # noqa: BLE001 - whatever the library raises on a stranger's bytes: said in one line
        raise _unanswered(scheduler, exc) from None
    kind = answer.get("type") if isinstance(answer, dict) else None
    if kind != "Scheduler":
        raise EngineError(f"--scheduler {scheduler}: answers as a Dask {kind or 'program'}, not a scheduler (give "
                          "the address `dask scheduler` printed)")


def _unanswered(scheduler: str, exc: BaseException) -> EngineError:
    """The one line for a scheduler address that did not answer, with what the connection said."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return EngineError(f"--scheduler {scheduler}: no Dask scheduler answered within {CONNECT_TIMEOUT_S:g} s "
                       f"({text[:160]})")


def open_engine(name: str, jobs: int, scheduler: str | None = None) -> Engine:
    """The engine ``name`` (:data:`ENGINES`) for ``jobs`` runs at a time; ``scheduler`` only with ``dask``."""
    if name not in ENGINES:
        raise ValueError(f"--engine must be one of {', '.join(ENGINES)}, got {name!r}")
    if scheduler and name != "dask":
        raise ValueError("--scheduler is for --engine dask")
    if name == "dask":
        if scheduler is not None and not scheduler.strip():
            raise ValueError("--scheduler needs an address, tcp://HOST:PORT")
        return DaskEngine(jobs, scheduler)
    return LocalEngine(jobs)


# -- signals ---------------------------------------------------------------------------------------------------------
class _Terminate(KeyboardInterrupt):
    def __init__(self, signal_name: str) -> None:
        super().__init__(signal_name)
        self.signal_name = signal_name


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """While in the block, SIGTERM and SIGHUP interrupt the main thread as Ctrl-C does (so the engine stops its
    workers and what finished is written), instead of ending the process with its workers left running."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[int, Any] = {}

    def interrupt(signum: int, _frame: object) -> None:
        raise _Terminate(signal.Signals(signum).name)

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            number = getattr(signal, name)
            previous[number] = signal.signal(number, interrupt)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


# -- the folder's lock, record and journal ---------------------------------------------------------------------------
def read_folder_record(record: Path, what: str, error: type[Exception]) -> dict[str, Any]:
    """The JSON object a command keeps in its --out folder (``what``: e.g. "a tuning folder's record"); ``error``,
    naming the file and saying to choose another folder, for anything else — not JSON, too deep, huge integers, a
    FIFO, not an object."""
    try:
        held = read_json_file(record, what, error)
    except error as exc:
        raise error(f"{exc}; choose another --out folder") from None
    if not isinstance(held, dict):
        raise error(f"{record}: not {what} (a JSON object expected); choose another --out folder")
    return held


class FolderLock:
    """An exclusive lock on ``folder`` (``folder/.lock``, ``fcntl.flock``) for the life of a command writing into it;
    :class:`FolderBusyError` names the folder and the holder's process when another command holds it."""

    def __init__(self, folder: str | Path, what: str) -> None:
        self.folder, self.what = Path(folder), what
        self._fd: int | None = None

    def __enter__(self) -> FolderLock:
        path = self.folder / ".lock"
        fd = open_lock_file(path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise FolderBusyError(f"{self.folder}: another command is writing into it (process {holder}); wait for "
                                  f"it to end, or choose another --out folder") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {self.what}\n".encode("ascii"))
        self._fd = fd
        _INHERITED_FDS.add(fd)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fd is not None:
            _INHERITED_FDS.discard(self._fd)
            os.close(self._fd)  # closing the last descriptor of the open file releases the lock
            self._fd = None


def _holder(fd: int) -> str:
    """The holder's record in a lock file another command holds ("PID what"). The holder writes it just after it
    took the lock: a command refused in between waits up to :data:`HOLDER_WAIT_S` for it ("?" if it never comes)."""
    give_up = time.monotonic() + HOLDER_WAIT_S
    while True:
        holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
        if holder or time.monotonic() >= give_up:
            return holder or "?"
        time.sleep(0.01)


# A run journal is a line per finished run (~1 kB): read whole, so a file beyond this is refused, not read.
MAX_JOURNAL_BYTES = 256_000_000


class RunJournal:
    """``folder/name``: one JSON line per finished run (its summary row), appended and synced as each finishes."""

    def __init__(self, folder: str | Path, name: str = "finished.jsonl") -> None:
        self.path = Path(folder) / name

    def load(self) -> dict[int, Row]:
        """The finished runs by index (a line cut short by a kill, or not JSON, is not a finished run)."""
        rows: dict[int, Row] = {}
        if not self.path.exists():
            return rows
        for line in read_text_file(self.path, "run journal", EngineError, max_bytes=MAX_JOURNAL_BYTES).splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(row, dict) and isinstance(row.get("run"), int):
                rows[int(row["run"])] = row
        return rows

    def add(self, row: Row) -> None:
        text = json.dumps(row, allow_nan=True, default=_plain)
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(text + "\n")
            f.flush()
            os.fsync(f.fileno())


def _plain(value: Any) -> Any:
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return value
    return str(value)
