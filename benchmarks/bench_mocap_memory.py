"""Motion capture's memory against the take's length, each length in a fresh process.

Recording: the peak resident memory of a process recording a generated 960 Hz take (tests/mocap_takes.py: fed
straight into the inlet, no Lab Streaming Layer, generated as fast as numpy makes it, not in real time), less that
of the same process recording a 1-second take (what importing and setting up cost); its ``ru_maxrss``.

Importing (``--import``): ``sensnake mocap import TAKE.c3d --rec REC.h5 --out NEW.h5`` of a generated 960 Hz C3D
take of 48 markers (tests/mocap_c3d_takes.py: written a block at a time, a smooth random walk of the joints that the
recording's servo angles match, the offset found from the motion; made in a process of its own), its peak resident
memory (the importing process's ``VmHWM``: its ``ru_maxrss`` would carry the peak of the process that spawned it
across ``exec``), wall and CPU time, and the peak's growth over the same import of a 10,000-frame take. Files under the system's temporary folder,
removed after each length. ``--code DIR`` runs another checkout's import (its ``app``, ``devices``, ``models``).

    python -m benchmarks.bench_mocap_memory [--minutes 1 5 10]
    python -m benchmarks.bench_mocap_memory --import [--minutes 1 5 30] [--code DIR]

Prints minutes, frames, peak RSS (growth, MB), the time of the run and the machine's load. ``run(quick)``
(``sensnake bench``): quick measures 0.5 and 1 minute of recording.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

CHILD = """
import json, resource, sys, time
from tests.mocap_takes import record_generated_take
start = time.process_time()
line = record_generated_take(sys.argv[1], float(sys.argv[2]))
print(json.dumps({"rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "cpu_s": time.process_time() - start, "line": line}))
"""


def measure(seconds: float) -> dict:
    """One recording of a ``seconds`` take in a fresh process: its peak RSS (MB) and CPU time."""
    with tempfile.TemporaryDirectory(prefix="bench-mocap-memory-") as tmp:
        out = subprocess.run([sys.executable, "-c", CHILD, os.path.join(tmp, "take.h5"), str(seconds)],
                             capture_output=True, text=True, check=True, cwd=os.path.dirname(os.path.dirname(
                                 os.path.abspath(__file__))))
    return json.loads(out.stdout.strip().splitlines()[-1])


IMPORT_CHILD = """
import json, resource, sys, time
from app.cli.main import main
start, wall = time.process_time(), time.perf_counter()
code = main(["mocap", "import", sys.argv[1], "--rec", sys.argv[2], "--out", sys.argv[3]])
try:  # this process image's own peak: ru_maxrss keeps the spawning process's peak across exec (Linux)
    peak = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM:")) / 1024
except OSError:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"rss_mb": peak, "code": code, "cpu_s": time.process_time() - start,
                  "wall_s": time.perf_counter() - wall}))
"""
MAKE_CHILD = """
import sys
from tests.mocap_c3d_takes import RATE_HZ, write_c3d, write_recording
frames, lead_s = int(sys.argv[3]), float(sys.argv[4])
motion = write_c3d(sys.argv[1], frames)
write_recording(sys.argv[2], motion, max(frames / RATE_HZ - 2 * lead_s, 1.0), -lead_s)
"""


BASE_FRAMES = 10_000  # the baseline take: 10.4 s, long enough for the offset from the motion


def measure_import(frames: int, code_dir: str | None = None, lead_s: float = 1.5) -> dict:
    """One ``mocap import`` of a generated ``frames``-frame take in a fresh process (``code_dir``'s import, else
    this checkout's): its peak RSS (MB), CPU and wall time (s). The take and recording are made first."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with tempfile.TemporaryDirectory(prefix="bench-mocap-import-") as tmp:
        take, rec, out = (os.path.join(tmp, name) for name in ("take.c3d", "rec.h5", "new.h5"))
        subprocess.run([sys.executable, "-c", MAKE_CHILD, take, rec, str(frames), str(lead_s)], check=True, cwd=here)
        done = subprocess.run([sys.executable, "-c", IMPORT_CHILD, take, rec, out], capture_output=True, text=True,
                              check=True, cwd=code_dir or here)
        result = json.loads(done.stdout.strip().splitlines()[-1])
        if result["code"] != 0:
            raise RuntimeError(f"the import failed: {done.stderr.strip()[-400:]}")
        result["line"] = next((x for x in done.stdout.splitlines() if x.startswith("take start")), "")
        result["take_mb"] = os.path.getsize(take) / 1e6
    return result


def run_import(minutes: list[float], code_dir: str | None = None) -> list[dict]:
    base = measure_import(BASE_FRAMES, code_dir)
    print(f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; {code_dir or 'this checkout'}; importing a "
          f"{BASE_FRAMES:,}-frame take peaks at {base['rss_mb']:.0f} MB (the baseline)")
    print(f"{'minutes':>8} {'frames':>9} {'take MB':>8} {'peak RSS MB':>12} {'growth MB':>10} {'wall s':>7} "
          f"{'CPU s':>7}")
    rows = []
    for m in minutes:
        frames = int(60 * m * 960)
        r = measure_import(frames, code_dir)
        growth = r["rss_mb"] - base["rss_mb"]
        print(f"{m:8g} {frames:9d} {r['take_mb']:8.0f} {r['rss_mb']:12.0f} {growth:10.0f} {r['wall_s']:7.1f} "
              f"{r['cpu_s']:7.1f}   load {os.getloadavg()[0]:.1f}", flush=True)
        print(f"         {r['line'][:150]}", flush=True)
        rows.append({"minutes": m, "rss_mb": r["rss_mb"], "growth_mb": growth, "wall_s": r["wall_s"],
                     "cpu_s": r["cpu_s"]})
    print(f"load {os.getloadavg()[0]:.1f} at the end")
    return rows


def run(quick: bool = False, minutes: list[float] | None = None) -> list[dict]:
    lengths = minutes or ([0.5, 1.0] if quick else [1.0, 5.0, 10.0])
    base = measure(1.0)
    print(f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; a 1 s take's process peaks at "
          f"{base['rss_mb']:.0f} MB (the baseline)")
    print(f"{'minutes':>8} {'frames':>9} {'peak RSS growth MB':>19} {'CPU s':>7}")
    rows = []
    for m in lengths:
        r = measure(60.0 * m)
        growth = r["rss_mb"] - base["rss_mb"]
        print(f"{m:8g} {int(60 * m * 960):9d} {growth:19.0f} {r['cpu_s']:7.1f}", flush=True)
        rows.append({"minutes": m, "growth_mb": growth, "cpu_s": r["cpu_s"]})
    print(f"load {os.getloadavg()[0]:.1f} at the end")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=None)
    parser.add_argument("--import", dest="importing", action="store_true", help="measure mocap import of a C3D take")
    parser.add_argument("--code", default=None, help="with --import: another checkout whose import to run")
    args = parser.parse_args()
    if args.importing:
        run_import(args.minutes or [1.0, 5.0, 30.0], args.code)
    else:
        run(minutes=args.minutes or [1.0, 5.0, 10.0])


if __name__ == "__main__":
    main()
