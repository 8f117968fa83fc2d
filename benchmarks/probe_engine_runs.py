"""Why a run takes longer inside a Dask worker than inside the local pool's: per-run CPU, faults and switches.

Each mode runs the same short sweep (paper obstacle, feedforward and feedback, seeds 0-9) in its own process, as the
command would (``python -m benchmarks.probe_engine_runs --child MODE``); modes alternate within each round (order
reversed every other round). Each run records, inside its worker: wall, the run thread's CPU (``time.thread_time``),
the process's CPU, the thread's and process's minor faults and context switches (``getrusage``), and the worker's
setting (main thread or not, ``MALLOC_TRIM_THRESHOLD_`` in its environment and in its start environment, the switch
interval, affinity, nice, its threads).

Modes: ``serial`` (the runs one after another in this process), ``local`` (LocalEngine), ``dask`` (DaskEngine,
embedded) and the variants in :data:`VARIANTS` (``local+forkserver``: a plain process pool whose workers are forked
from the same forkserver as the Dask workers, with its imports; ``local+thread``: the local pool's runs in a thread). The thread's voluntary context switches (``t_nvcsw``) count its waits:
for the disk, and in a Dask worker for the interpreter lock its event loop takes each time it wakes. CPU and wall of
one run swing by tens of per cent on a busy shared machine; the counts do not.

Run: ``python -m benchmarks.probe_engine_runs [--seconds 3] [--rounds 4] [--modes local,dask,dask-old]`` (the first
mode is the one the others are compared with, run by run). With ``--beside``, each mode's single worker runs the runs
at the same time as one local-pool worker runs them too, so that the machine's load falls on both alike: a busy
shared machine can still compare a run's cost inside each (the cluster's own threads take from both sides then).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def _faults() -> dict[str, int]:
    t = resource.getrusage(resource.RUSAGE_THREAD)
    p = resource.getrusage(resource.RUSAGE_SELF)
    return {"t_minflt": t.ru_minflt, "t_nvcsw": t.ru_nvcsw, "t_nivcsw": t.ru_nivcsw, "p_minflt": p.ru_minflt,
            "p_nvcsw": p.ru_nvcsw, "p_nivcsw": p.ru_nivcsw}


_RUNNER: Any = None


class InlineExecutor:
    """A diagnostic executor: runs each call in the thread that submits it (a Dask worker's event-loop thread)."""

    def submit(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        import concurrent.futures

        future: concurrent.futures.Future = concurrent.futures.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the future
            future.set_exception(exc)
        return future

    def shutdown(self, wait: bool = True, **kwargs: Any) -> None:
        return None


def probe_in_thread(task: dict[str, Any]) -> dict[str, Any]:
    """probe_one in a thread of this process kept for its life (as a Dask worker runs its tasks)."""
    global _RUNNER
    import concurrent.futures

    if _RUNNER is None:
        _RUNNER = concurrent.futures.ThreadPoolExecutor(1)
    return _RUNNER.submit(probe_one, task).result()


def probe_one(task: dict[str, Any]) -> dict[str, Any]:
    from app.core import sweep


    before = _faults()
    wall0, thread0, proc0 = time.perf_counter(), time.thread_time(), time.process_time()
    row = sweep._one(task)  # noqa: SLF001 - what a worker runs
    wall, thread_cpu, proc_cpu = (time.perf_counter() - wall0, time.thread_time() - thread0,
                                  time.process_time() - proc0)
    after = _faults()
    start_env = Path("/proc/self/environ").read_bytes()
    return {"run": task["run"], "controller": task["controller"], "seed": task["seed"], "wall": wall,
            "thread_cpu": thread_cpu, "proc_cpu": proc_cpu, **{k: after[k] - before[k] for k in after},
            "advance_m": row.get("advance_m"), "pid": os.getpid(),
            "main_thread": threading.current_thread() is threading.main_thread(),
            "trim_env": os.environ.get("MALLOC_TRIM_THRESHOLD_"), "trim_start_env": b"MALLOC_TRIM" in start_env,
            "switch": sys.getswitchinterval(), "affinity": sorted(os.sched_getaffinity(0)),
            "nice": os.getpriority(os.PRIO_PROCESS, 0), "threads": len(os.listdir("/proc/self/task"))}


# Variants: environment set before the forkserver starts (``env``), Dask settings applied after the engine's own
# (``config``), the engine's previous housekeeping (``old``: Dask's heartbeats, every 0.5 s, and the settings the
# engine had before they were thinned), tasks run in a Dask worker's event-loop thread (``inline``: no thread beside
# the loop, so no lock handed back and forth; a diagnostic only, it blocks the worker's loop for a whole run).
VARIANTS: dict[str, dict[str, Any]] = {
    "dask": {},
    "dask-old": {"old": True},
    "dask+inline": {"inline": True},
    "dask+trim": {"env": {"MALLOC_TRIM_THRESHOLD_": "65536"}},
    "dask+sat1": {"config": {"distributed.scheduler.worker-saturation": 1.0}},
    "local": {},
    "local+thread": {},
    "local+forkserver": {},
}
OLD_QUIET_DASK = {"distributed.admin.tick.interval": "1s", "distributed.admin.system-monitor.interval": "2s",
                  "distributed.worker.memory.monitor-interval": "1s", "distributed.scheduler.work-stealing": False}


def _tasks(out: Path, seconds: float) -> list[dict[str, Any]]:
    from app.core import sweep

    text = ('scenes = ["paper_obstacle"]\ncontrollers = ["feedforward", "feedback"]\nseeds = [0, 1, 2, 3, 4, 5, 6, '
            f'7, 8, 9]\nseconds = {seconds!r}\nsettle_s = 1.0\nspeed_rad_s = 0.1\nrest_cap_s = 0.0\n')
    out.mkdir(parents=True, exist_ok=True)
    plan_file = out / "sweep.toml"
    plan_file.write_text(text, encoding="utf-8")
    return sweep.sweep_tasks(sweep.read_sweep(plan_file), out)


def _run_mode(mode: str, tasks: list[dict[str, Any]], jobs: int) -> list[dict[str, Any]]:
    """The tasks' rows, run as ``mode`` runs them."""
    from app.core import engines

    variant = VARIANTS.get(mode, {})
    rows: list[dict[str, Any]] = []
    if mode == "serial":
        return [probe_one(t) for t in tasks]
    if mode == "local+forkserver":  # a plain pool whose workers are forked from the Dask workers' forkserver
        import concurrent.futures
        import multiprocessing

        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(list(engines.WORKER_PRELOAD))
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
            return list(pool.map(probe_one, tasks))
    if mode.startswith("dask"):
        import dask

        original = engines._configure_dask  # noqa: SLF001

        def configure() -> None:
            original()
            dask.config.set(variant.get("config", {}))

        if variant.get("old"):
            engines.QUIET_DASK.clear()
            engines.QUIET_DASK.update(OLD_QUIET_DASK)
            engines.WORKER_HEARTBEAT_S = 1.0  # Dask's Worker default, until the scheduler's first reply
            engines._slow_heartbeats = lambda *args: None  # type: ignore[assignment]  # noqa: SLF001
        if variant.get("inline"):
            import functools

            import distributed

            distributed.LocalCluster = functools.partial(distributed.LocalCluster,  # type: ignore[misc,assignment]
                                                         executor=InlineExecutor())
        engines._configure_dask = configure  # type: ignore[assignment]  # noqa: SLF001
        engine: Any = engines.DaskEngine(jobs)
    else:
        engine = engines.LocalEngine(jobs)
    fn = probe_in_thread if mode == "local+thread" else probe_one
    try:
        engine.run(fn, tasks, lambda k, row, err: rows.append(row or {"error": err}))
    finally:
        engine.close()
    return rows


def child(mode: str, seconds: float, out: Path, jobs: int, beside: bool = False) -> None:
    """``mode``'s runs; with ``beside``, one worker of ``mode`` and one local-pool worker running the same runs at the
    same time (what the machine's load does to one does it to the other)."""
    from app.cli.main import bound_numeric_threads

    bound_numeric_threads()
    os.environ.update(VARIANTS.get(mode, {}).get("env", {}))
    if mode.startswith("dask") or mode == "local+forkserver":
        from app.core.engines import start_worker_server

        start_worker_server()
    tasks = _tasks(out, seconds)
    local_rows: list[dict[str, Any]] = []
    if beside:
        local_tasks = _tasks(out / "beside", seconds)
        side = threading.Thread(target=lambda: local_rows.extend(_run_mode("local", local_tasks, 1)))
        side.start()
        rows = _run_mode(mode, tasks, 1)
        side.join()
    else:
        rows = _run_mode(mode, tasks, jobs)
    me = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"mode": mode, "rows": rows, "beside_rows": local_rows, "parent_cpu": me.ru_utime + me.ru_stime}))


def measure(mode: str, seconds: float, folder: Path, jobs: int, beside: bool = False) -> dict[str, Any]:
    out = folder / mode
    command = [sys.executable, "-m", "benchmarks.probe_engine_runs", "--child", mode, "--seconds", str(seconds),
               "--out", str(out), "--jobs", str(jobs), *(["--beside"] if beside else [])]
    load = float(Path("/proc/loadavg").read_text().split()[0])
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"{mode}: exit {done.returncode}: {done.stderr[-600:]}")
    result = json.loads(lines[-1])
    result["load"] = load
    return result


def summary(rows: list[dict[str, Any]]) -> str:
    def med(key: str) -> float:
        return statistics.median(r[key] for r in rows)

    r0 = rows[0]
    return (f"wall {med('wall'):.3f} thread_cpu {med('thread_cpu'):.3f} proc-thread {med('proc_cpu') - med('thread_cpu'):.3f} "
            f"t_minflt {med('t_minflt'):.0f} p_minflt {med('p_minflt'):.0f} t_nvcsw {med('t_nvcsw'):.0f} "
            f"t_nivcsw {med('t_nivcsw'):.0f} p_nvcsw {med('p_nvcsw'):.0f} | main {r0['main_thread']} "
            f"trim {r0['trim_env']}/{r0['trim_start_env']} switch {r0['switch']} aff {r0['affinity']} "
            f"nice {r0['nice']} threads {r0['threads']}")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--modes", default="local,dask")
    parser.add_argument("--child")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--json", type=Path, help="append every round's rows here")
    parser.add_argument("--beside", action="store_true",
                        help="each mode's one worker beside one local-pool worker, the same runs at the same time")
    args = parser.parse_args()
    if args.child:
        child(args.child, args.seconds, args.out, args.jobs, args.beside)
        return
    modes = args.modes.split(",")
    folder = Path(tempfile.mkdtemp(prefix="sensnake_probe_"))
    try:
        if args.beside:
            side_by_side(args, modes, folder)
        else:
            rounds(args, modes, folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def side_by_side(args: argparse.Namespace, modes: list[str], folder: Path) -> None:
    """Each mode's worker against a local-pool worker running the same runs at the same time: per run, the ratio of
    the run thread's CPU and of the run's wall (median of the runs), and both sides' waits."""
    for k in range(args.rounds):
        for mode in modes:
            result = measure(mode, args.seconds, folder, 1, beside=True)
            local = {r["run"]: r for r in result["beside_rows"]}
            pairs = [(local[r["run"]], r) for r in result["rows"] if r.get("run") in local]
            cpu = statistics.median(b["thread_cpu"] / a["thread_cpu"] for a, b in pairs)
            wall = statistics.median(b["wall"] / a["wall"] for a, b in pairs)
            print(f"{k} {mode:<16} beside local, load {result['load']:.1f}: run CPU {cpu - 1:+.1%}, wall {wall - 1:+.1%}; "
                  f"waits {sum(b['t_nvcsw'] for _, b in pairs)} against {sum(a['t_nvcsw'] for a, _ in pairs)} "
                  f"({len(pairs)} runs)", flush=True)
            if args.json:
                with open(args.json, "a", encoding="utf-8") as f:
                    f.write(json.dumps({"round": k, "beside": True, "results": {mode: result}}) + "\n")


def rounds(args: argparse.Namespace, modes: list[str], folder: Path) -> None:
    by_mode: dict[str, list[float]] = {m: [] for m in modes}
    for k in range(args.rounds):
        order = modes if k % 2 == 0 else list(reversed(modes))
        results = {m: measure(m, args.seconds, folder, args.jobs) for m in order}
        base = {r["run"]: r for r in results[modes[0]]["rows"]}
        for m in order:
            rows = results[m]["rows"]
            ratio = statistics.median(r["thread_cpu"] / base[r["run"]]["thread_cpu"] for r in rows)
            by_mode[m].append(ratio)
            print(f"{k} {m:<14} load {results[m]['load']:.1f} cpu/{modes[0]} {ratio - 1:+.1%} "
                  f"parent {results[m]['parent_cpu']:.2f} s {summary(rows)}",
                  flush=True)
        if args.json:
            with open(args.json, "a", encoding="utf-8") as f:
                f.write(json.dumps({"round": k, "results": results}) + "\n")
    for m in modes:
        print(f"median over rounds: {m:<14} run thread CPU against {modes[0]}'s {statistics.median(by_mode[m]) - 1:+.1%}")


if __name__ == "__main__":
    main()
