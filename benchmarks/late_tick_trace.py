"""Why each late tick was late: bench_servo_bus ``--trace DIR`` (gui case, robot on the pty emulator, loop in its
own process).

Three independent records on one clock (``time.monotonic()``, CLOCK_MONOTONIC, the same in every process):

- the loop process's tick trace (``devices.tick_trace``): for each late tick, the marks of the ticks before it on
  the bus thread (instruction written, waits for status bytes, bytes taken, goal written, health poll, tick
  callback, the wait for the next slot and the wake-up), the sender thread's messages and every GC collection;
- the emulator's instruction log (``XM430_TRACE``): when it read each instruction off the pty, when each reply was
  due on the simulated wire and when it was written;
- one real-time probe thread per CPU (``benchmarks.machine_probe``): when the machine itself held a SCHED_FIFO 50
  thread off its CPU, and the CPU's steal time.

For every late tick :func:`report` finds the longest stretch of the bus thread between two of its marks in the
ticks before it (where the time went) and says what else happened in that stretch, then names the cause:

- ``machine``: a probe was held off its CPU at the same time for at least half the stretch (a descheduled virtual
  CPU or the kernel: nothing of the app, which the probes outrank);
- ``pty → emulator`` / ``emulator → pty``: the bytes took that long through the kernel's pseudo-terminal (the
  emulator read the instruction late, or the host got bytes late that the emulator had written on time), with no
  probe gap;
- ``emulator``: the emulator wrote its replies late;
- ``gc`` / ``sender`` / ``command``: a collection, the sender thread pickling a message, or a command from the app
  held the loop process's interpreter through the stretch;
- ``wake-up``: the bus thread's wait for its slot ended late with nothing else seen;
- ``unexplained``: none of these.
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

PTY_SLOW_S = 0.003
EMULATOR_SLOW_S = 0.002
SYNC_READ, SYNC_WRITE = 0x82, 0x83


@dataclass
class Tracing:
    directory: Path
    probes: list[subprocess.Popen] = field(default_factory=list)

    @property
    def ticks(self) -> Path:
        return self.directory / "ticks.jsonl"

    @property
    def emulator(self) -> Path:
        return self.directory / "emulator.jsonl"

    def probe(self, cpu: int) -> Path:
        return self.directory / f"probe{cpu}.json"


def start(directory: str) -> Tracing:
    """Set the environment the loop process and the emulator read (before they start)."""
    tracing = Tracing(Path(directory))
    tracing.directory.mkdir(parents=True, exist_ok=True)
    for path in (tracing.ticks, tracing.emulator):
        path.unlink(missing_ok=True)
    os.environ["SENSNAKE_TICK_TRACE"] = str(tracing.ticks)
    os.environ["XM430_TRACE"] = str(tracing.emulator)
    return tracing


def start_probes(tracing: Tracing, seconds: float) -> None:
    """One machine probe per CPU for ``seconds`` (the measured window)."""
    for cpu in sorted(os.sched_getaffinity(0)):
        tracing.probe(cpu).unlink(missing_ok=True)
        tracing.probes.append(subprocess.Popen(
            [sys.executable, "-m", "benchmarks.machine_probe", "--cpu", str(cpu), "--seconds", f"{seconds:g}",
             "--out", str(tracing.probe(cpu))]))


def stop(tracing: Tracing) -> None:
    os.environ.pop("SENSNAKE_TICK_TRACE", None)
    os.environ.pop("XM430_TRACE", None)
    for probe in tracing.probes:
        try:
            probe.wait(timeout=60)
        except subprocess.TimeoutExpired:
            probe.kill()
            probe.wait()
    tracing.probes.clear()


def _load_jsonl(path: Path) -> list:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def report(tracing: Tracing, t0: float, t1: float) -> None:
    """Print one line per late tick of the window [t0, t1] (times relative to ``t0``) and a count per cause."""
    records = [r for r in _load_jsonl(tracing.ticks) if t0 <= r["start"] <= t1]
    emulator = _load_jsonl(tracing.emulator)
    probes = []
    for path in sorted(tracing.directory.glob("probe*.json")):
        probes.extend(_load_jsonl(path))
    print(f"    late-tick trace ({tracing.directory}): {len(records)} late ticks traced; emulator instructions "
          f"logged: {len(emulator)}; machine probes: " + ", ".join(
              f"cpu{p['cpu']} {p['scheduling']} {len(p['gaps'])} gaps > 2 ms (max "
              f"{max((g[1] for g in p['gaps']), default=0):.1f} ms), steal {p['steal_jiffies']} jiffies"
              for p in probes))
    causes: collections.Counter[str] = collections.Counter()
    for record in records:
        cause, line = _explain(record, emulator, probes, t0)
        causes[cause] += 1
        print(f"      {line}")
    if records:
        print("    causes: " + ", ".join(f"{cause} {n}" for cause, n in causes.most_common()))


def _explain(record: dict, emulator: list, probes: list, t0: float) -> tuple[str, str]:
    marks = record["marks"]
    bus = [m for m in marks if m[1].startswith("RobotController")]
    others = [m for m in marks if not m[1].startswith("RobotController")]
    start = record["start"]
    # The bus thread's marks up to the late tick's start; the longest stretch between two of them.
    before = [m for m in bus if m[0] <= start]
    gaps = [(b[0] - a[0], a, b) for a, b in zip(before, before[1:])]
    if not gaps:
        return "unexplained", f"+{start - t0:8.2f} s late {record['late_ms']:.1f} ms: no marks before it"
    length, a, b = max(gaps, key=lambda g: g[0])
    ta, tb = a[0], b[0]
    head = (f"+{start - t0:8.2f} s late {record['late_ms']:5.1f} ms; longest stretch {a[2]}→{b[2]} "
            f"{length * 1e3:5.1f} ms")
    notes = []
    # What the machine did meanwhile.
    held = []
    for probe in probes:
        for g_start, g_ms, _steal in probe["gaps"]:
            g_end = g_start + 0.001 + g_ms / 1e3
            overlap = min(g_end, tb) - max(g_start, ta)
            if overlap > 0:
                held.append((overlap, probe["cpu"], g_ms))
    if held:
        notes.append("probe held off " + ", ".join(f"cpu{cpu} {g_ms:.1f} ms" for _o, cpu, g_ms in held))
    # The emulator's side of the instruction in flight.
    tx = [m for m in bus if m[2] == "tx" and m[0] <= tb]
    emu_in = emu_late = emu_out = None
    if tx and a[2] in ("tx", "select", "sleep", "selected", "slept", "rx"):
        sent = tx[-1]
        inst, _n, t_tx = sent[3]
        rows = [r for r in emulator if r[1] == inst and t_tx - 0.0005 <= r[0] <= t_tx + 0.2]
        if rows:
            t_read, _inst, _len, written = rows[0]
            emu_in = t_read - t_tx
            notes.append(f"emulator read it {emu_in * 1e3:.1f} ms after it was written")
            if written:
                emu_late = max(actual - due for due, actual in written)
                last_written = written[-1][1]
                rx_after = [m for m in bus if m[2] == "rx" and m[0] >= last_written - 0.0005]
                if rx_after:
                    emu_out = rx_after[0][0] - last_written
                notes.append(f"replies written {emu_late * 1e3:+.1f} ms vs the wire"
                             + (f", host had the last bytes {emu_out * 1e3:.1f} ms later" if emu_out is not None
                                else ""))
    # The loop process's other threads and the collector in the stretch.
    gc_ms = _spans(others + bus, "gc>", "gc<", ta, tb)
    send_ms = _spans(others, "send", "sent", ta, tb)
    calls = [m[3] for m in others if m[2] == "call" and ta <= m[0] <= tb]
    if gc_ms:
        notes.append(f"gc {gc_ms * 1e3:.1f} ms")
    if send_ms:
        notes.append(f"sender sending {send_ms * 1e3:.1f} ms")
    if calls:
        notes.append("commands " + ",".join(map(str, calls)))
    excess = length - 0.012  # more than a normal read's wait (~10 ms at the factory return delay)
    if held and max(o for o, _c, _g in held) >= 0.5 * max(excess, 0.002):
        cause = "machine"
    elif emu_in is not None and emu_in > PTY_SLOW_S:
        cause = "pty → emulator"
    elif emu_late is not None and emu_late > EMULATOR_SLOW_S:
        cause = "emulator"
    elif emu_out is not None and emu_out > PTY_SLOW_S:
        cause = "emulator → pty"
    elif gc_ms > 0.5 * max(excess, 0.002):
        cause = "gc"
    elif send_ms > 0.5 * max(excess, 0.002):
        cause = "sender"
    elif calls:
        cause = "command"
    elif a[2] == "wait":
        cause = "wake-up"
    else:
        cause = "unexplained"
    return cause, f"{head}: {cause}" + (f" ({'; '.join(notes)})" if notes else "")


def _spans(marks: list, open_label: str, close_label: str, ta: float, tb: float) -> float:
    """Total time within [ta, tb] covered by open…close pairs of marks (per thread)."""
    total = 0.0
    opened: dict[str, float] = {}
    for t, thread, label, _value in sorted(marks, key=lambda m: m[0]):
        if label == open_label:
            opened[thread] = t
        elif label == close_label and thread in opened:
            s = opened.pop(thread)
            total += max(0.0, min(t, tb) - max(s, ta))
    return total
