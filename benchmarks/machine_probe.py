"""How late the machine itself wakes a real-time thread: a diagnosis aid for bench_servo_bus --trace.

    python -m benchmarks.machine_probe --cpu 0 --seconds 300 --out /tmp/probe0.jsonl

One thread pinned to ``--cpu`` at SCHED_FIFO ``PRIORITY`` (above the control loop's 20 and the emulator's 10, so
nothing of ours delays it) sleeps 1 ms over and over; every wake-up more than ``GAP_S`` late is written with the
CPU's steal time (jiffies a hypervisor ran something else on this virtual CPU) read just after it. A late tick of
the control loop that coincides with a gap here was the machine (a descheduled virtual CPU, the kernel), not the
loop: this thread shares nothing with the app but the CPU. Without the privilege it runs at normal priority and
says so (its gaps are then also other programs' work).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

PRIORITY = 50
SLEEP_S = 0.001
GAP_S = 0.002


def _steal(cpu: int) -> int:
    with open("/proc/stat", encoding="ascii") as stat:
        for line in stat:
            if line.startswith(f"cpu{cpu} "):
                return int(line.split()[8])
    return -1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.machine_probe", description=__doc__.split("\n")[0])
    parser.add_argument("--cpu", type=int, required=True)
    parser.add_argument("--seconds", type=float, required=True)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    os.sched_setaffinity(0, {args.cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
        scheduling = f"SCHED_FIFO {PRIORITY}"
    except OSError:
        scheduling = "normal scheduling (no privilege)"
    gaps = []
    steal0 = _steal(args.cpu)
    end = time.monotonic() + args.seconds
    before = time.monotonic()
    wakeups = 0
    while before < end:
        time.sleep(SLEEP_S)
        after = time.monotonic()
        wakeups += 1
        if after - before > SLEEP_S + GAP_S:
            gaps.append((round(before, 6), round((after - before - SLEEP_S) * 1e3, 3), _steal(args.cpu)))
        before = after
    with open(args.out, "w", encoding="utf-8") as out:
        out.write(json.dumps({"cpu": args.cpu, "scheduling": scheduling, "wakeups": wakeups,
                              "steal_jiffies": _steal(args.cpu) - steal0, "gaps": gaps}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
