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

With the loop in the app's process (port ``sim``, or ``--gui-loop app``) the trace is taken there and there is no
emulator log: a ``wake-up`` or ``unexplained`` late tick with no probe held off is then most likely the bus thread
waiting for the interpreter lock while the GUI thread held it (painting), which no mark can show directly.
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
    """(cause, one line) for one late tick: did the tick before it run past the slot (and which phase), or did the
    bus thread wake late from its wait for the slot (and was the machine holding the probes off meanwhile)?"""
    marks = record["marks"]
    bus = [m for m in marks if m[1].startswith("RobotController")]
    others = [m for m in marks if not m[1].startswith("RobotController")]
    start = record["start"]
    waits = [m for m in bus if m[2] == "wait" and m[0] < start]
    if not waits:
        return "unexplained", f"+{start - t0:8.2f} s: no marks before it"
    wait = waits[-1]
    ticks = [m for m in bus if m[2] == "tick" and m[0] < wait[0]]
    # This tick's own slot: the tick before's slot + one period (skipped slots move the loop's deadline past it).
    slot = ticks[-1][3] + record["period_ms"] / 1e3 if ticks else record["slot"]
    skipped = round((record["slot"] - slot) * 1e3 / record["period_ms"])
    head = f"+{start - t0:8.2f} s {(start - slot) * 1e3:5.1f} ms after its slot" + \
        (f" ({skipped} slot{'s' if skipped > 1 else ''} skipped)" if skipped > 0 else "")
    previous = [m for m in bus if (ticks[-1][0] if ticks else 0.0) <= m[0] <= wait[0]]
    notes: list[str] = []
    if wait[0] > slot - 0.0005:  # the tick before ran up to (or past) this tick's slot: where did its time go?
        # Each transaction of that tick (instruction written → the next phase mark), less what the wire needed
        # (the emulator's planned time of its last reply): the one with the most time beyond the wire.
        ends = ("tx", "read<", "goal<", "health<", "wait")
        worst = (0.0, None, 0.0, 0.0)
        for i, m in enumerate(previous):
            if m[2] != "tx":
                continue
            end = next((n[0] for n in previous[i + 1:] if n[2] in ends), wait[0])
            rows = [r for r in emulator if r[1] == m[3][0] and m[3][2] - 0.0005 <= r[0] <= m[3][2] + 0.2]
            wire = (rows[0][3][-1][0] - rows[0][0]) if rows and rows[0][3] else 0.0  # from when it was read there
            if end - m[0] - wire > worst[0]:
                worst = (end - m[0] - wire, m, m[0], end)
        excess, sent, ta, tb = worst
        kind = {SYNC_WRITE: "goal write", 3: "write (a command)"}.get(sent[3][0], "") if sent else ""
        if sent and sent[3][0] == SYNC_READ:
            kind = "feedback read" if sent[3][1] == 26 else "health read"
        where = (f"the tick before ran {(wait[0] - slot) * 1e3:+.1f} ms past the slot; its {kind or 'work'} took "
                 f"{excess * 1e3:.1f} ms beyond the wire")
        calls = [m[3] for m in others if m[2] == "call" and m[3] not in ("stats", "recent_periods_s")
                 and (ticks[-1][0] if ticks else 0.0) - 0.1 <= m[0] <= wait[0]]
        writes = [m for m in previous if m[2] == "tx" and m[3][0] == 3]
        pty = _pty_notes(sent, tb, bus, emulator) if sent else None
        if pty is not None:
            notes.append(pty[1])
        knock_on = bool(ticks) and ticks[-1][0] - ticks[-1][3] > 0.25 * record["period_ms"] / 1e3
        if knock_on:
            cause = "knock-on (the tick before started late itself)"
        elif writes or calls:
            cause = f"command ({', '.join(map(str, calls)) or 'bus writes'})"
        elif pty is not None and pty[0]:
            # The emulator or the pty late while the machine held the real-time probes off too: the machine.
            cause = _held(probes, ta, tb, excess, notes) or f"{pty[0]} in a {kind}"
        else:
            cause = _held(probes, ta, tb, excess, notes) or _gil(others + bus, ta, tb, notes)
            if not cause:  # the time went between the transactions: was the machine holding the probes off then?
                t_before = ticks[-1][0] if ticks else slot - record["period_ms"] / 1e3
                cause = _held(probes, t_before, wait[0], wait[0] - slot, notes) or "unexplained"
    else:  # the work ended in time; the wake-up for the slot came late
        late_s = start - slot
        where = f"woke {late_s * 1e3:.1f} ms after the slot (the tick before ended {(slot - wait[0]) * 1e3:.1f} ms early)"
        cause = _held(probes, slot, start, late_s, notes) or _gil(others + bus, slot, start, notes) or "wake-up"
    return cause.split(" (")[0] if cause.startswith(("command", "knock-on")) else cause, \
        f"{head}: {where}: {cause}" + (f" [{'; '.join(notes)}]" if notes else "")


def _pty_notes(sent: list, end: float, bus: list, emulator: list) -> tuple[str, str] | None:
    """The emulator's side of the instruction ``sent`` (a tx mark; its transaction ended at ``end``): (cause or "",
    one note)."""
    inst, _n, t_tx = sent[3]
    rows = [r for r in emulator if r[1] == inst and t_tx - 0.0005 <= r[0] <= t_tx + 0.2]
    if not rows:
        return None
    t_read, _inst, _len, written = rows[0]
    into = t_read - t_tx
    note = f"emulator read the instruction {into * 1e3:.1f} ms after the host wrote it"
    if into > PTY_SLOW_S:
        return "pty → emulator (kernel)", note
    if not written:
        return "", note
    late = max(w[1] - w[0] for w in written)
    last_written = written[-1][1]
    worst = max(written, key=lambda w: w[1] - w[0])
    if late > EMULATOR_SLOW_S and len(worst) > 2:  # woke late from its sleep, or its write() blocked in the kernel
        woke_late, blocked = worst[2] - worst[0], worst[1] - worst[2]
        note += f", the emulator woke {woke_late * 1e3:.1f} ms late and its write took {blocked * 1e3:.1f} ms"
        if blocked > woke_late:
            return "emulator's write to the pty blocked (kernel)", note + (
                f", wrote its replies {late * 1e3:+.1f} ms vs the wire")
    rx_all = [m for m in bus if m[2] == "rx" and sent[0] <= m[0] <= end]  # the last: when it had them all
    out = rx_all[-1][0] - last_written if rx_all else None
    note += f", wrote its replies {late * 1e3:+.1f} ms vs the wire"
    if out is not None:
        note += f", the host had the last bytes {out * 1e3:.1f} ms after they were written"
    if late > EMULATOR_SLOW_S:
        return "emulator late", note
    if out is not None and out > PTY_SLOW_S:
        return "emulator → pty (kernel)", note
    return "", note


def _held(probes: list, ta: float, tb: float, excess_s: float, notes: list[str]) -> str:
    held = []
    for probe in probes:
        for g_start, g_ms, _steal in probe["gaps"]:
            overlap = min(g_start + 0.001 + g_ms / 1e3, tb) - max(g_start, ta)
            if overlap > 0:
                held.append((overlap, probe["cpu"], g_ms))
    if held:
        notes.append("machine probes held off: " + ", ".join(f"cpu{cpu} {g_ms:.1f} ms" for _o, cpu, g_ms in held))
        cpus = {cpu for _o, cpu, _g in held}
        if max(o for o, _c, _g in held) >= 0.5 * max(excess_s, 0.002):
            return f"machine ({'all CPUs' if len(cpus) == len(probes) else 'cpu' + '/'.join(map(str, sorted(cpus)))} " \
                   "held off a real-time probe too)"
    return ""


def _gil(marks: list, ta: float, tb: float, notes: list[str]) -> str:
    gc_ms = _spans(marks, "gc>", "gc<", ta, tb)
    send_ms = _spans(marks, "send", "sent", ta, tb)
    if gc_ms:
        notes.append(f"gc {gc_ms * 1e3:.1f} ms")
    if send_ms:
        notes.append(f"sender {send_ms * 1e3:.1f} ms")
    if gc_ms > 0.002:
        return "gc"
    if send_ms > 0.002:
        return "sender"
    return ""


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
