"""What an engine costs: a 20-run sweep on the local process pool and on Dask against the same runs one after another.

The sweep: the paper obstacle, feedforward and feedback, run seeds 0-9 (20 runs), each ``--seconds`` of play after
a short settle, no wait for rest. Each configuration runs in its own process (``python -m
benchmarks.bench_engine_overhead --child MODE``), measured from outside (wall seconds; user + system CPU of it and
every process under it, ``os.wait4``) and from inside (every process under it sampled every 0.2 s from ``/proc``:
its resident memory):

* ``serial``: the runs one after another in one process (``app.core.sweep._one``, what a worker runs), no engine;
* ``local``: ``run_sweep(..., jobs=J, engine="local")`` — the process pool, the folder's journal, the summary;
* ``dask``: ``run_sweep(..., jobs=J, engine="dask")`` — an embedded ``LocalCluster`` on 127.0.0.1 of J
  single-threaded workers, started and stopped inside the timing.

Printed for each engine: wall, and **overhead = wall / (serial wall / J) − 1** (the target's measure: the sweep against
the same runs one after another divided by the worker count); **CPU overhead** = its CPU / serial CPU − 1 (what the
engine adds in work, which other processes on a shared machine slow less than they slow the wall clock); the time
spent outside the runs (wall − Σ run wall / J, the runs' own ``wall_s``); and the **memory per worker**: each worker
process's peak resident memory, and how much its resident memory grew between the middle and the end of the sweep
(bounded: a worker that held on to each run's memory would grow with every run). The machine's 1-minute load average
before and after is printed too (other engineers share the cores; ``--repeats`` takes each configuration's fastest).

Run: ``python -m benchmarks.bench_engine_overhead [--seconds 8] [--jobs 2] [--repeats 1] [--write]`` (``--write``:
``benchmarks/results/engine_overhead.txt``); ``sensnake bench --quick`` uses 2 s plays.

Measured on the 2-core machine with no other work (load average 0.3 before, 2.0-2.5 during), overhead local / Dask:
30 s plays +13.5 % / +18.5 %, 8 s plays (fastest of 3) +26.6 % / +47.5 %, 4 s plays +29.9 % / +55.5 %; both engines'
runs were slower side by side than one after another, so these carry the machine's parallel slowdown. Dask's own
part, timed run by run on the 8 s sweep: the cluster's start 0.56-0.75 s, each worker's first run 0.03-0.4 s longer,
1-3 ms between runs, the stop 0.14-0.15 s: about 1 s, 12 % of a worker's share of an 8 s sweep (the <= 10 % target
missed on short sweeps). Worker memory 91-98 MB (local), 119-126 MB (Dask), <= 4 MB growth (docs/PHYSICS_LAB.md).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "engine_overhead.txt"
MODES = ("serial", "local", "dask")
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
    """Resident memory of this process (``serial``) or of every process under it, sampled; per pid a list of
    (seconds since start, MB)."""

    def __init__(self, own: bool) -> None:
        self.own = own
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
            for pid in [me] if self.own else _descendants(me):
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


def child(mode: str, plan_file: Path, out: Path, jobs: int) -> None:
    """One configuration, in the process being measured; prints one JSON line."""
    from app.core import sweep

    plan = sweep.read_sweep(plan_file)
    out.mkdir(parents=True, exist_ok=True)
    with MemoryWatch(own=mode == "serial") as watch:
        start = time.perf_counter()
        if mode == "serial":
            rows = [sweep._one(task) for task in sweep.sweep_tasks(plan, out)]  # noqa: SLF001 - what a worker runs
        else:
            rows = sweep.run_sweep(plan, out, jobs=jobs, engine=mode)
        wall = time.perf_counter() - start
    workers = watch.workers(wall)  # serial: this process; local and dask: the worker processes under it
    failed = sum(1 for r in rows if str(r.get("file", "")).startswith("failed"))
    print(json.dumps({"mode": mode, "wall_s": wall, "runs": len(rows), "failed": failed,
                      "run_wall_s": sum(float(r.get("wall_s") or 0.0) for r in rows), "workers": workers}))


# -- the benchmark ---------------------------------------------------------------------------------------------------
def measure(mode: str, plan_file: Path, folder: Path, jobs: int) -> dict:
    out = folder / mode
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, "-m", "benchmarks.bench_engine_overhead", "--child", mode, "--plan", str(plan_file),
               "--out", str(out), "--jobs", str(jobs)]
    start = time.perf_counter()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout_box: list[str] = []
    reader = threading.Thread(target=lambda: stdout_box.append(process.stdout.read()), daemon=True)  # type: ignore[union-attr]
    reader.start()
    _, status, usage = os.wait4(process.pid, 0)
    outside_wall = time.perf_counter() - start
    reader.join(timeout=10)
    err = process.stderr.read() if process.stderr is not None else ""
    code = os.waitstatus_to_exitcode(status)
    lines = [line for line in "".join(stdout_box).splitlines() if line.startswith("{")]
    if code != 0 or not lines:
        raise RuntimeError(f"bench_engine_overhead: {mode} exited {code}: {err.strip()[-400:]}")
    result = json.loads(lines[-1])
    result.update({"cpu_s": usage.ru_utime + usage.ru_stime, "process_wall_s": outside_wall})
    return result


def table(results: dict[str, dict], jobs: int) -> list[str]:
    serial = results["serial"]
    lines = [f"{'engine':<7} {'runs':>4} {'wall s':>7} {'overhead':>9} {'CPU s':>7} {'CPU overhead':>12} "
             f"{'outside runs s':>14} {'worker peak MB':>15} {'growth middle→end MB':>21}"]
    for mode in MODES:
        r = results.get(mode)
        if r is None:
            continue
        ideal = serial["wall_s"] / (1 if mode == "serial" else jobs)
        width = 1 if mode == "serial" else jobs
        overhead = r["wall_s"] / ideal - 1.0
        cpu_over = r["cpu_s"] / serial["cpu_s"] - 1.0
        outside = r["wall_s"] - r["run_wall_s"] / width
        peaks = [w["peak_mb"] for w in r["workers"]] or [float("nan")]
        growth = [w["end_mb"] - w["middle_mb"] for w in r["workers"]] or [float("nan")]
        count = len(r["workers"])
        lines.append(f"{mode:<7} {r['runs']:>4} {r['wall_s']:>7.1f} "
                     f"{'—' if mode == 'serial' else f'{overhead:+.1%}':>9} {r['cpu_s']:>7.1f} "
                     f"{'—' if mode == 'serial' else f'{cpu_over:+.1%}':>12} {outside:>14.1f} "
                     f"{f'{min(peaks):.0f}-{max(peaks):.0f} ({count})':>15} "
                     f"{f'{min(growth):+.0f} to {max(growth):+.0f}':>21}")
    return lines


def bench(seconds: float, jobs: int, repeats: int) -> list[str]:
    folder = Path(tempfile.mkdtemp(prefix="sensnake_bench_engine_"))
    try:
        plan_file = folder / "sweep.toml"
        plan_file.write_text(sweep_text(seconds), encoding="utf-8")
        load_before = Path("/proc/loadavg").read_text().split()[:3]
        started = time.strftime("%Y-%m-%d %H:%M:%S %z")
        best: dict[str, dict] = {}
        walls: dict[str, list[float]] = {m: [] for m in MODES}
        for _ in range(repeats):
            for mode in MODES:
                r = measure(mode, plan_file, folder, jobs)
                walls[mode].append(r["wall_s"])
                if mode not in best or r["wall_s"] < best[mode]["wall_s"]:
                    best[mode] = r
        load_after = Path("/proc/loadavg").read_text().split()[:3]
        lines = [f"# bench_engine_overhead: 20 runs (paper obstacle, feedforward and feedback, seeds 0-9, {seconds:g} s "
                 f"play, 1 s settle), --jobs {jobs}, {os.cpu_count()} cores; started {started}",
                 f"load average before {' '.join(load_before)}, after {' '.join(load_after)}; fastest of {repeats} "
                 f"(walls: " + "; ".join(f"{m} {', '.join(f'{w:.1f}' for w in ws)} s" for m, ws in walls.items()) +
                 ")",
                 f"overhead = wall / (serial wall / {jobs}) - 1; CPU overhead = CPU / serial CPU - 1; outside runs = "
                 f"wall - sum of the runs' own wall / {jobs}",
                 *table(best, jobs)]
        failed = sum(r["failed"] for r in best.values())
        if failed:
            lines.append(f"{failed} run(s) failed")
        return lines
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run(quick: bool = False) -> None:
    print("\n".join(bench(2.0 if quick else 8.0, 2, 1)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="each run's play (s of simulated time)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--write", action="store_true", help=f"write the table to {RESULTS.relative_to(ROOT)}")
    parser.add_argument("--child", choices=MODES, help=argparse.SUPPRESS)
    parser.add_argument("--plan", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.plan, args.out, args.jobs)
        return
    lines = bench(args.seconds, args.jobs, args.repeats)
    print("\n".join(lines), flush=True)
    if args.write:
        RESULTS.write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
