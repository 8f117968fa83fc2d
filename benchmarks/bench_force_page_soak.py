"""The shared force page under CPU load: a writer process publishing at the board's rate (30 Hz) and a reader process
reading at the control loop's rate (50 Hz), both at normal priority (SCHED_OTHER), beside busy processes (the load
generator: one ``while True`` process per ``--load``, so load 10 on 2 cores is ``--load 10``).

Prints reads, failed reads (a read that raised: must be 0), reads that went back to an older publication (must be 0),
torn reads (a read mixing two publications: must be 0), and how often the forces a tick got were older than the
feedback law's stale limit (100 ms) — the ticks that fall back to the feedforward because of the load, not a fault.

``python -m benchmarks.bench_force_page_soak [--seconds 600] [--load 10]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

WRITER = """
import sys, time, numpy as np
from app.core.force_control import ForcePage
page = ForcePage(sys.argv[1]); n = page.n_channels; end = time.monotonic() + float(sys.argv[2]); k = 0
next_t = time.monotonic()
while time.monotonic() < end:
    k += 1
    page.publish(time.monotonic(), np.full(n, float(k)), np.full(n, k % 2 == 0))
    next_t += 1 / 30
    time.sleep(max(next_t - time.monotonic(), 0.0))
"""

READER = """
import json, sys, time, numpy as np
from app.core.force_control import ForcePage, STALE_S
page = ForcePage(sys.argv[1]); end = time.monotonic() + float(sys.argv[2])
reads = failed = older = torn = stale = 0; last = -1.0; worst_age = 0.0; previous = 0
next_t = time.monotonic()
while time.monotonic() < end:
    try:
        arrival, forces, trusted = page.read()
    except Exception:
        failed += 1
    else:
        reads += 1
        publication = page.publication
        if publication < previous:
            older += 1
        previous = publication
        if publication and not (np.all(forces == forces[0]) and np.all(trusted == (int(forces[0]) % 2 == 0))):
            torn += 1
        if publication:
            age = time.monotonic() - arrival
            worst_age = max(worst_age, age)
            stale += age > STALE_S
    next_t += 1 / 50
    time.sleep(max(next_t - time.monotonic(), 0.0))
print(json.dumps(dict(reads=reads, failed=failed, older=older, torn=torn, stale=stale, worst_age_s=worst_age)))
"""


def run(seconds: float, load: int, channels: int = 36) -> dict[str, float]:
    from app.core.force_control import ForcePage

    env = dict(os.environ, PYTHONPATH=os.getcwd())
    page = ForcePage.create(channels, folder=tempfile.gettempdir())
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        writer = subprocess.Popen([sys.executable, "-c", WRITER, str(page.path), str(seconds)], env=env)
        out = subprocess.run([sys.executable, "-c", READER, str(page.path), str(seconds)], env=env,
                             capture_output=True, text=True, timeout=seconds + 60, check=True)
        writer.wait(timeout=60)
    finally:
        for process in busy:
            process.kill()
            process.wait()
        page.close()
    return dict(json.loads(out.stdout))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--load", type=int, default=10, help="busy processes beside writer and reader")
    args = parser.parse_args()
    result = run(args.seconds, args.load)
    print(f"force page soak: {args.seconds:.0f} s, {args.load} busy processes on {os.cpu_count()} cores")
    print(f"  reads {result['reads']}, failed {result['failed']} (target 0), older than the read before "
          f"{result['older']} (target 0), torn {result['torn']} (target 0)")
    print(f"  ticks with forces older than 100 ms (fall back to feedforward) {result['stale']} "
          f"({100 * result['stale'] / max(result['reads'], 1):.2f} %), oldest {1000 * result['worst_age_s']:.0f} ms")


if __name__ == "__main__":
    main()
