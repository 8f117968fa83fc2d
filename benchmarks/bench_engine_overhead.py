"""What an engine costs: a 20-run sweep on the local process pool and on Dask against the same runs one after another.

The sweep: the paper obstacle, feedforward and feedback, run seeds 0-9 (20 runs), each ``--seconds`` of play after
a short settle, no wait for rest. Each configuration runs in its own process (``python -m
benchmarks.bench_engine_overhead --child MODE``), which prepares as the command does (one thread per numerical
library; for Dask, the forkserver its workers are forked from started first, as ``sensnake experiment sweep --engine
dask`` does, so its imports run beside the rest; the sweep's modules imported, its file read), then runs the sweep;
measured from outside (user + system CPU of it and every process under it, ``os.wait4``; the machine's busy CPU from
``/proc/stat``, so the cores other processes took during it are known) and from inside (the preparation's and the
sweep's wall; each run stamped inside the worker that ran it: when the call began and returned, the run's own
``wall_s``; every process under it sampled every 0.2 s from ``/proc``: its resident memory):

* ``serial``: the runs one after another in one process forked from the measured one (``app.core.sweep._one``,
  what a worker runs), no engine;
* ``bare``: the runs on J processes forked from the measured one, each doing every J-th run one after another: no
  pool, no queue, no scheduler — the machine's own parallel slowdown, without an engine;
* ``local``: ``run_sweep(..., jobs=J, engine="local")`` — the process pool, the folder's journal, the summary;
* ``dask``: ``run_sweep(..., jobs=J, engine="dask")`` — an embedded ``LocalCluster`` on 127.0.0.1 of J
  single-threaded workers, its start and stop inside the timing (what of its start ran beside the preparation counts
  too: the Dask preparation's excess over the serial one's is added to its wall).

Printed for each configuration, in each round:

* **literal** = wall / (serial wall / J) − 1: the criterion's measure, the sweep against the same runs one after
  another divided by the worker count. It carries the machine's parallel slowdown (two runs side by side each take
  longer than one alone: shared caches and memory bandwidth, and on a shared machine other processes), which no
  engine causes;
* **engine** = (J × wall − Σ the runs' own time) / Σ the runs' own time: the engine's own overhead (its start,
  dispatch, the results' way back, its stop, a worker idle at the tail while another finishes), each run timed inside
  its worker, so a run made slower by its neighbour is not counted against the engine;
* **slowdown** = Σ the runs' own time / Σ the serial runs' own time − 1: the parallel slowdown itself, as each mode
  met it (``bare``: with no engine at all);
* **runCPU** = Σ the CPU time of the threads that ran the runs / the serial runs' − 1, and **waits**, those threads'
  voluntary waits a second of run (for the disk; in a Dask worker also for the interpreter lock, which its event loop
  takes from the run each time it wakes): what a run costs inside its worker, apart from what it waits for;
* CPU against the serial's, where the workers' time went (start, between runs, inside the call but outside the run,
  idle at the tail, the stop: worker-seconds), each worker's peak resident memory and its growth from the sweep's
  middle to its end (bounded: a worker that held on to each run's memory would grow with every run), the 1-minute
  load average before and the cores other processes kept busy during it.

The modes run in turn, their order reversed every other round (serial, bare, local, dask, then dask, local, bare,
serial, …), so a change in the machine's load falls on all of them; the medians of the rounds close the table, with
(when both ran) the Dask runs' own time and CPU against the local pool's, round by round.

Run: ``python -m benchmarks.bench_engine_overhead [--seconds 8] [--jobs 2] [--repeats 4] [--modes bare,local,dask]
[--write]`` (``--write``: ``benchmarks/results/engine_overhead.txt``, ``engine_overhead_60s.txt`` for ``--seconds 60``);
``sensnake bench --quick`` uses 2 s plays.

Measured on the quiet 2-core machine (2026-12-05), median of the rounds: 60 s plays, 8 rounds — literal local +1.5 %,
Dask +4.0 % (+2.1 to +16.6); engine local +1.0 %, Dask +3.1 %; 8 s plays, 10 rounds — literal bare +0.7 %, local
+1.3 %, Dask +7.9 % (-1.2 to +17.8); engine local +1.0 %, Dask +5.2 %, mostly its workers' start. A single round
carries a few per cent of the machine's luck (decision 0030): read the median of several. Worker memory 94-100 MB
(local), 120-127 MB (Dask), <= 3 MB growth.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "engine_overhead.txt"
MODES = ("serial", "bare", "local", "dask")
SAMPLE_S = 0.2


def sweep_text(seconds: float) -> str:
    return ('scenes = ["paper_obstacle"]\ncontrollers = ["feedforward", "feedback"]\nseeds = [0, 1, 2, 3, 4, 5, 6, 7, '
            f'8, 9]\nseconds = {seconds!r}\nsettle_s = 1.0\nspeed_rad_s = 0.1\nrest_cap_s = 0.0\n')


# -- inside the measured process -------------------------------------------------------------------------------------
def _descendants(pid: int) -> list[int]:
    found, stack = [], [pid]
    while stack:
        parent = stack.pop()
        for task in Path(f"/proc/{parent}/task").glob("*"):
            try:
                children = [int(p) for p in (task / "children").read_text().split()]
            except OSError:
                continue
            found += children
            stack += children
    return found


def _rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _parent(pid: int) -> int | None:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


class MemoryWatch:
    """Resident memory of every process under this one, sampled; per pid a list of (seconds since start, MB)."""

    def __init__(self) -> None:
        self.samples: dict[int, list[tuple[float, float]]] = {}
        self.names: dict[int, str] = {}
        self.forkservers: set[int] = set()
        self._stop = threading.Event()
        self._start = time.monotonic()
        self._thread = threading.Thread(target=self._watch, daemon=True, name="memory-watch")

    def _watch(self) -> None:
        me = os.getpid()
        while not self._stop.is_set():
            now = time.monotonic() - self._start
            for pid in _descendants(me):
                mb = _rss_mb(pid)
                if mb is None:
                    continue
                if pid not in self.names:
                    self.names[pid] = _cmdline(pid)
                # Looked at again each time: a process sampled between its fork and its exec showed its parent's
                # command line.
                if pid not in self.forkservers and _parent(pid) == me and "forkserver import main" in _cmdline(pid):
                    self.forkservers.add(pid)
                self.samples.setdefault(pid, []).append((now, mb))
            self._stop.wait(SAMPLE_S)

    def __enter__(self) -> MemoryWatch:
        self._start = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2)

    def workers(self, wall: float) -> list[dict]:
        """Each process that ran runs: its peak MB and its growth from the sweep's middle to its last sample. The
        multiprocessing resource tracker and forkserver (which run nothing; the forkserver's own children, forked
        with its command line, are the embedded Dask cluster's workers) are left out; the cluster's scheduler and
        nannies live in this process, so the other processes under it are its workers."""
        out = []
        for pid, samples in self.samples.items():
            name = self.names.get(pid, "")
            if "resource_tracker" in name or "semaphore_tracker" in name or pid in self.forkservers:
                continue
            peak = max(mb for _, mb in samples)
            middle = [mb for t, mb in samples if t <= wall / 2] or [samples[0][1]]
            out.append({"pid": pid, "peak_mb": peak, "middle_mb": max(middle), "end_mb": samples[-1][1],
                        "samples": len(samples)})
        return out


_ORIGINAL_ONE: Any = None  # the sweep's run function before :func:`child` put :func:`timed_one` in its place


def timed_one(task: dict[str, Any]) -> dict[str, Any]:
    """What a worker runs here: the sweep's own run function, its call stamped (wall-clock seconds since the epoch,
    comparable between processes) with the process that ran it, the CPU time of the thread that ran it and the times
    that thread waited (voluntary context switches: for the interpreter lock, which a Dask worker's event loop takes
    from the run each time it wakes, or for the disk). The run's own time is the row's ``wall_s``."""
    run = _ORIGINAL_ONE
    if run is None:  # a worker that imported this module afresh (Dask's): the sweep module's function is the original
        from app.core import sweep

        run = sweep._one  # noqa: SLF001 - what a worker runs
    called = time.time()
    before, cpu = resource.getrusage(resource.RUSAGE_THREAD), time.thread_time()
    row = run(task)
    cpu, after = time.thread_time() - cpu, resource.getrusage(resource.RUSAGE_THREAD)
    return {**row, "bench_called": called, "bench_returned": time.time(), "bench_pid": os.getpid(),
            "bench_cpu_s": cpu, "bench_waits": after.ru_nvcsw - before.ru_nvcsw}


def _bare(tasks: list[dict[str, Any]], jobs: int, folder: Path) -> list[dict[str, Any]]:
    """The runs on ``jobs`` plain processes forked from this one, each doing every ``jobs``-th run one after another:
    no pool, no queue, no scheduler (the machine's own parallel slowdown, without an engine)."""
    pids = []
    for k in range(jobs):
        pid = os.fork()
        if pid == 0:  # the child: its share, its rows to a file, then out without running the parent's cleanup
            code = 1
            try:
                rows = [timed_one(task) for task in tasks[k::jobs]]
                (folder / f"bare_{k}.json").write_text(json.dumps(rows, default=str), encoding="utf-8")
                code = 0
            finally:
                os._exit(code)
        pids.append(pid)
    for pid in pids:
        _, status = os.waitpid(pid, 0)
        if os.waitstatus_to_exitcode(status) != 0:
            raise RuntimeError(f"bench_engine_overhead: a bare process exited {os.waitstatus_to_exitcode(status)}")
    return [row for k in range(jobs) for row in json.loads((folder / f"bare_{k}.json").read_text(encoding="utf-8"))]


def child(mode: str, plan_file: Path, out: Path, jobs: int) -> None:
    """One configuration, in the process being measured; prints one JSON line."""
    global _ORIGINAL_ONE
    # The command's preparation, as ``sensnake experiment sweep`` does it: for an embedded cluster, its workers'
    # forkserver started first (its imports overlap the rest), the sweep's modules imported (the physics lab), its
    # file read and checked.
    from app.cli.main import bound_numeric_threads

    bound_numeric_threads()  # as the command does first: one thread per numerical library, in every worker
    prepare = time.perf_counter()
    if mode == "dask":
        from app.core.engines import start_worker_server

        start_worker_server()
    from app.core import sweep

    plan = sweep.read_sweep(plan_file)
    out.mkdir(parents=True, exist_ok=True)
    prepare_s = time.perf_counter() - prepare
    _ORIGINAL_ONE = sweep._one  # noqa: SLF001
    sweep._one = timed_one  # type: ignore[assignment]  # noqa: SLF001 - the engines run its stamped call
    marks: dict[str, float] = {}
    open_engine = sweep.open_engine

    def stamped_open(*args: Any, **kwargs: Any) -> Any:
        marks["open_called"] = time.time()
        engine = open_engine(*args, **kwargs)
        marks["open_returned"] = time.time()
        close = engine.close

        def stamped_close() -> None:
            marks["close_called"] = time.time()
            close()
            marks["close_returned"] = time.time()

        engine.close = stamped_close  # type: ignore[method-assign]
        return engine

    sweep.open_engine = stamped_open
    # Every mode's runs run in processes under this one, away from its memory watch: a thread beside the runs (the
    # watch's, reading /proc five times a second) would take the interpreter lock from them at each wake-up, as a
    # Dask worker's event loop does.
    with MemoryWatch() as watch:
        started_epoch, start = time.time(), time.perf_counter()
        if mode == "serial":
            rows = _bare(sweep.sweep_tasks(plan, out), 1, out)
        elif mode == "bare":
            rows = _bare(sweep.sweep_tasks(plan, out), jobs, out)
        else:
            rows = sweep.run_sweep(plan, out, jobs=jobs, engine=mode)
        wall = time.perf_counter() - start
    workers = watch.workers(wall)
    failed = sum(1 for r in rows if str(r.get("file", "")).startswith("failed"))
    runs = [{"pid": r.get("bench_pid"), "called": r.get("bench_called"), "returned": r.get("bench_returned"),
             "wall_s": float(r.get("wall_s") or 0.0), "cpu_s": float(r.get("bench_cpu_s") or 0.0),
             "waits": int(r.get("bench_waits") or 0)} for r in rows]
    print(json.dumps({"mode": mode, "wall_s": wall, "prepare_s": prepare_s, "started": started_epoch, "runs": len(rows), "failed": failed,
                      "run_wall_s": sum(r["wall_s"] for r in runs), "run_cpu_s": sum(r["cpu_s"] for r in runs),
                      "run_waits": sum(r["waits"] for r in runs), "timeline": runs, "marks": marks,
                      "workers": workers}))


# -- the benchmark ---------------------------------------------------------------------------------------------------
def _busy_s() -> float:
    """CPU seconds the whole machine has spent busy (every core, every process), from ``/proc/stat``."""
    fields = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle and iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def measure(mode: str, plan_file: Path, folder: Path, jobs: int) -> dict:
    out = folder / mode
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, "-m", "benchmarks.bench_engine_overhead", "--child", mode, "--plan", str(plan_file),
               "--out", str(out), "--jobs", str(jobs)]
    load = float(Path("/proc/loadavg").read_text().split()[0])
    busy = _busy_s()
    start = time.perf_counter()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout_box: list[str] = []
    reader = threading.Thread(target=lambda: stdout_box.append(process.stdout.read()), daemon=True)  # type: ignore[union-attr]
    reader.start()
    _, status, usage = os.wait4(process.pid, 0)
    outside_wall = time.perf_counter() - start
    busy = _busy_s() - busy
    reader.join(timeout=10)
    err = process.stderr.read() if process.stderr is not None else ""
    code = os.waitstatus_to_exitcode(status)
    lines = [line for line in "".join(stdout_box).splitlines() if line.startswith("{")]
    if code != 0 or not lines:
        raise RuntimeError(f"bench_engine_overhead: {mode} exited {code}: {err.strip()[-400:]}")
    result = json.loads(lines[-1])
    cpu = usage.ru_utime + usage.ru_stime
    # Others' load: the machine's busy CPU over the measurement less this configuration's own, in cores.
    result.update({"cpu_s": cpu, "process_wall_s": outside_wall, "load_before": load,
                   "others_cores": max(0.0, busy - cpu) / outside_wall})
    return result


def breakdown(r: dict, width: int) -> dict[str, float]:
    """Where the workers' time went, in worker-seconds (``width`` workers for the sweep's wall):

    * ``runs``: the runs' own time (each row's ``wall_s``, timed inside the worker);
    * ``start``: from the sweep's start to each worker's first run (the engine's start, the task's way to it);
    * ``between``: between a worker's runs (a result's way back, the next task's way out);
    * ``call``: inside a worker's call but outside the run (unpickling, imports the run does first, the row's way);
    * ``tail``: from each worker's last run to the last run's end (a worker idle while another finishes);
    * ``stop``: from the last run's end to the sweep's end (results gathered, summary written, engine stopped), for
      every worker;
    * ``engine``: all but ``runs`` — the engine's overhead, ``width × wall − runs``.
    A worker that ran nothing counts its whole wall as ``start``."""
    timeline = [t for t in r["timeline"] if t["called"] is not None]
    started, ended = r["started"], r["started"] + r["wall_s"]
    last = max((t["returned"] for t in timeline), default=ended)
    parts = {"runs": sum(t["wall_s"] for t in timeline), "start": 0.0, "between": 0.0, "call": 0.0, "tail": 0.0,
             "stop": width * (ended - last)}
    by_pid: dict[Any, list[dict]] = {}
    for t in timeline:
        by_pid.setdefault(t["pid"], []).append(t)
    for runs in by_pid.values():
        runs.sort(key=lambda t: t["called"])
        parts["start"] += runs[0]["called"] - started
        parts["between"] += sum(b["called"] - a["returned"] for a, b in zip(runs, runs[1:]))
        parts["call"] += sum(t["returned"] - t["called"] - t["wall_s"] for t in runs)
        parts["tail"] += last - runs[-1]["returned"]
    parts["start"] += max(0, width - len(by_pid)) * r["wall_s"]
    parts["engine"] = width * r["wall_s"] - parts["runs"]
    return parts


def figures(r: dict, serial: dict, jobs: int) -> dict[str, float]:
    """The three overheads of one configuration against the serial runs of the same round. The command's preparation
    (its imports, the file read) is the same whatever runs the runs and is left out, but what an engine adds to it
    (``prepare``: this configuration's preparation less the serial one's, e.g. a cluster started beside it slowing
    it) is the engine's and counted in its wall."""
    width = 1 if r["mode"] == "serial" else jobs
    parts = breakdown(r, width)
    # Only Dask does anything before its sweep (its forkserver starts beside the preparation); the other modes'
    # differences from the serial preparation are the machine's noise, not theirs.
    added = r["prepare_s"] - serial["prepare_s"] if r["mode"] == "dask" else 0.0
    wall = r["wall_s"] + added
    parts["prepare"] = width * added
    parts["engine"] += width * added
    return {"literal": wall / (serial["wall_s"] / width) - 1.0,  # the criterion's: wall / (serial / workers)
            "engine": parts["engine"] / parts["runs"],  # the engine's own: (workers x wall - runs) / runs
            "slowdown": parts["runs"] / serial["run_wall_s"] - 1.0,  # each run's slowdown against the serial's
            "run_cpu": r["run_cpu_s"] / serial["run_cpu_s"] - 1.0,  # the runs' threads' CPU against the serial's
            "waits_per_s": r["run_waits"] / parts["runs"],  # the run threads' waits a second of run
            "cpu": r["cpu_s"] / serial["cpu_s"] - 1.0, **{f"{k}_s": v for k, v in parts.items()}}


def _median(values: list[float]) -> float:
    ordered = sorted(values)
    n = len(ordered)
    return float("nan") if n == 0 else (ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2)


def round_lines(k: int, results: dict[str, dict], jobs: int) -> list[str]:
    serial = results["serial"]
    lines = []
    for mode in (m for m in MODES if m in results):
        r = results[mode]
        f = figures(r, serial, jobs)
        peaks = [w["peak_mb"] for w in r["workers"]] or [float("nan")]
        growth = [w["end_mb"] - w["middle_mb"] for w in r["workers"]] or [float("nan")]
        lines.append(f"{k:>5} {mode:<9} {r['wall_s']:>6.1f} {f['literal']:>+8.1%} {f['engine']:>+7.1%} "
                     f"{f['slowdown']:>+8.1%} {f['run_cpu']:>+7.1%} {f['waits_per_s']:>6.1f} {f['cpu']:>+7.1%} "
                     f"{r['prepare_s']:>5.2f} {f['start_s']:>6.2f} "
                     f"{f['between_s']:>6.2f} "
                     f"{f['call_s']:>5.2f} {f['tail_s']:>5.2f} {f['stop_s']:>5.2f} "
                     f"{f'{min(peaks):.0f}-{max(peaks):.0f}':>8} {f'{min(growth):+.0f}/{max(growth):+.0f}':>6} "
                     f"{r['load_before']:>5.1f} {r['others_cores']:>6.2f}")
    return lines


HEADER = (f"{'round':>5} {'mode':<9} {'wall s':>6} {'literal':>8} {'engine':>7} {'slowdown':>8} {'runCPU':>7} "
          f"{'waits':>6} {'CPU':>7} "
          f"{'prep':>5} {'start':>6} {'betw.':>6} {'call':>5} {'tail':>5} {'stop':>5} {'peak MB':>8} {'growth':>6} {'load':>5} "
          f"{'others':>6}")
LEGEND = ("literal = wall / (serial wall / workers) - 1 (the criterion's measure; serial: 0); engine = (workers x wall"
          " - the runs' own time, timed inside each worker) / the runs' own time; slowdown = the runs' own time / the "
          "serial runs' own time - 1 (the machine's parallel slowdown; bare: two forked processes each doing half the "
          "runs, no engine); runCPU = the CPU time of the threads that ran the runs / the serial runs' - 1; waits = their "
          "voluntary waits a second of run (for the disk, and in a Dask worker for the interpreter lock its event loop "
          "takes when it wakes); CPU = all the processes' CPU / serial CPU - 1; prep: the command's preparation, s (what an engine adds to the serial one's counts in its wall); start, betw., call, tail, stop: worker-seconds (see "
          "breakdown()); peak MB and growth (middle to end of the sweep) per worker; load: 1-min load average before; "
          "others: cores busy with other processes during it")


def bench(seconds: float, jobs: int, repeats: int, modes: tuple[str, ...] = MODES) -> list[str]:
    folder = Path(tempfile.mkdtemp(prefix="sensnake_bench_engine_"))
    try:
        plan_file = folder / "sweep.toml"
        plan_file.write_text(sweep_text(seconds), encoding="utf-8")
        started = time.strftime("%Y-%m-%d %H:%M:%S %z")
        rounds: list[dict[str, dict]] = []
        lines = [f"# bench_engine_overhead: 20 runs (paper obstacle, feedforward and feedback, seeds 0-9, {seconds:g} s "
                 f"play, 1 s settle), --jobs {jobs}, {os.cpu_count()} cores; started {started}; {repeats} round(s), "
                 "the modes' order reversed every other round", LEGEND, HEADER]
        print(*lines, sep="\n", flush=True)
        for k in range(repeats):
            order = modes if k % 2 == 0 else tuple(reversed(modes))
            results = {mode: measure(mode, plan_file, folder, jobs) for mode in order}
            rounds.append(results)
            lines += round_lines(k, results, jobs)
            print(*lines[-len(modes):], sep="\n", flush=True)
        lines.append("median of the rounds:")
        for mode in modes:
            per = [figures(r[mode], r["serial"], jobs) for r in rounds]
            lines.append(f"  {mode:<9} wall {_median([r[mode]['wall_s'] for r in rounds]):.1f} s, literal "
                         f"{_median([f['literal'] for f in per]):+.1%}, engine {_median([f['engine'] for f in per]):+.1%}, "
                         f"slowdown {_median([f['slowdown'] for f in per]):+.1%}, run CPU "
                         f"{_median([f['run_cpu'] for f in per]):+.1%}, waits {_median([f['waits_per_s'] for f in per]):.1f}"
                         f"/s, CPU {_median([f['cpu'] for f in per]):+.1%}")
        if "local" in modes and "dask" in modes:  # the runs themselves, Dask's against the local pool's, round by round
            wall = [r["dask"]["run_wall_s"] / r["local"]["run_wall_s"] - 1.0 for r in rounds]
            cpu = [r["dask"]["run_cpu_s"] / r["local"]["run_cpu_s"] - 1.0 for r in rounds]
            lines.append(f"  the Dask runs against the local pool's in the same round: own time {_median(wall):+.1%} "
                         f"({min(wall):+.1%} to {max(wall):+.1%}), CPU {_median(cpu):+.1%} ({min(cpu):+.1%} to "
                         f"{max(cpu):+.1%})")
        failed = sum(r[m]["failed"] for r in rounds for m in modes)
        if failed:
            lines.append(f"{failed} run(s) failed")
        print(*lines[lines.index("median of the rounds:"):], sep="\n", flush=True)
        return lines
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run(quick: bool = False) -> None:
    bench(2.0 if quick else 8.0, 2, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="each run's play (s of simulated time)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1, help="rounds (each measures every mode once)")
    parser.add_argument("--modes", default="bare,local,dask",
                        help="besides serial, always measured: a comma list of bare, local, dask")
    parser.add_argument("--write", action="store_true",
                        help=f"write the table to {RESULTS.relative_to(ROOT)} (8 s plays) or engine_overhead_<S>s.txt")
    parser.add_argument("--child", choices=MODES, help=argparse.SUPPRESS)
    parser.add_argument("--plan", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.plan, args.out, args.jobs)
        return
    modes = tuple(m for m in MODES if m == "serial" or m in args.modes.split(","))
    lines = bench(args.seconds, args.jobs, args.repeats, modes)
    if args.write:
        results_file(args.seconds).write_text("\n".join(lines) + "\n", encoding="utf-8")


def results_file(seconds: float) -> Path:
    """Where ``--write`` puts the table: :data:`RESULTS` for the default 8 s plays, beside it with the play's length
    in its name for any other."""
    return RESULTS if seconds == 8.0 else RESULTS.with_name(f"{RESULTS.stem}_{seconds:g}s{RESULTS.suffix}")


if __name__ == "__main__":
    main()
