"""Reading a long motion-capture take back: peak memory and time of each reader of ``/mocap`` on a generated 960 Hz
take (tests/mocap_long_takes.py: every dataset written, uncompressed, as the recorder writes a live take) added to a
synthetic trial recording, each reader in a fresh process.

    python -m benchmarks.bench_mocap_read [--minutes 10 30] [--code DIR]

Readers: ``figure`` — the segments' positions for the kinematics figure (``segment_positions``); ``record`` — the
``/mocap`` group (``read_mocap``, default arguments); ``align`` — a repeatability trial loaded and aligned on the
head's position (``load_trial`` + ``event_time``, the crossing in the take's middle). Prints the Python heap's peak
(tracemalloc: numpy's arrays are traced), the process's peak resident memory and the wall time. ``--code DIR`` reads
with the app of another checkout (DIR holds ``app``, ``models``, ``devices``): how a change is measured against the
code before it. ``run(quick)`` (``sensnake bench``): quick measures 2 minutes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
READERS = ("figure", "record", "align")

CHILD = """
import json, resource, sys, time, tracemalloc
import h5py, numpy
from app.core import mocap, repeatability
what, path, level = sys.argv[1], sys.argv[2], float(sys.argv[3])
tracemalloc.start()
start = time.perf_counter()
if what == "figure":
    time_s, centers, words = mocap.segment_positions(path, "mocap")
    shape = list(centers.shape)
elif what == "record":
    record = mocap.read_mocap(path)
    words, shape = "", list(record.markers_m.shape)
else:
    trial = repeatability.load_trial(path)
    when = repeatability.event_time(trial, repeatability.AlignOptions("mocap", position_x_m=level))
    words, shape = f"crossing at {when:.6f} s", list(numpy.shape(trial.segment_x_m))
wall = time.perf_counter() - start
print(json.dumps({"heap_mb": tracemalloc.get_traced_memory()[1] / 2**20, "wall_s": wall, "shape": shape,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "words": words}))
"""


def make_take(folder: str, minutes: float) -> tuple[str, int]:
    """A synthetic trial recording with a generated take of ``minutes`` at 960 Hz; its path and frame count."""
    sys.path.insert(0, ROOT)
    from pathlib import Path

    from tests.app.synthetic_trials import write_trial
    from tests.mocap_long_takes import RATE_HZ, add_long_take

    frames = int(round(minutes * 60 * RATE_HZ))
    path = write_trial(Path(folder) / "long.h5")
    add_long_take(path, frames, whole=True)
    return str(path), frames


def measure(reader: str, path: str, level_m: float, code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, reader, path, repr(level_m)], capture_output=True, text=True,
                         cwd=code)
    if out.returncode:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"exit {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool = False, minutes: list[float] | None = None, code: str = ROOT) -> list[dict]:
    from tests.mocap_long_takes import RATE_HZ, SPEED_M_S

    rows = []
    print(f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; code from {code}")
    print(f"{'minutes':>8} {'frames':>9} {'reader':>7} {'heap peak MB':>13} {'peak RSS MB':>12} {'wall s':>7}  result")
    for m in minutes or ([2.0] if quick else [10.0, 30.0]):
        with tempfile.TemporaryDirectory(prefix="bench-mocap-read-") as tmp:
            path, frames = make_take(tmp, m)
            level = SPEED_M_S * (frames // 2 + 0.5) / RATE_HZ  # the head passes it between two frames mid-take
            for reader in READERS:
                r = measure(reader, path, level, code)
                if "error" in r:
                    print(f"{m:8g} {frames:9d} {reader:>7}  failed: {r['error']}", flush=True)
                    continue
                print(f"{m:8g} {frames:9d} {reader:>7} {r['heap_mb']:13.1f} {r['rss_mb']:12.0f} {r['wall_s']:7.2f}  "
                      f"{r['shape']} {r['words']}", flush=True)
                rows.append({"minutes": m, "reader": reader, **r})
    print(f"load {os.getloadavg()[0]:.1f} at the end")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[10.0, 30.0])
    parser.add_argument("--code", default=ROOT, help="the checkout whose app reads the take (default: this one)")
    args = parser.parse_args()
    run(minutes=args.minutes, code=os.path.abspath(args.code))


if __name__ == "__main__":
    main()
