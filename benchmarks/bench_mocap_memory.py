"""Motion capture's memory while a take is recorded: the peak resident memory of a process recording a generated
960 Hz take (tests/mocap_takes.py: fed straight into the inlet, no Lab Streaming Layer, generated as fast as numpy
makes it, not in real time) against the take's length, each length in a fresh process (its ``ru_maxrss``), less
that of the same process recording a 1-second take (what importing and setting up cost).

    python -m benchmarks.bench_mocap_memory [--minutes 1 5 10]

Prints minutes, frames, peak RSS growth (MB), the CPU time of the run and the machine's load. ``run(quick)``
(``sensnake bench``): quick measures 0.5 and 1 minute.
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
    parser.add_argument("--minutes", type=float, nargs="+", default=[1.0, 5.0, 10.0])
    run(minutes=parser.parse_args().minutes)


if __name__ == "__main__":
    main()
