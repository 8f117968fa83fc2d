"""A diagnostic trace of the control loop's ticks, kept only for the ticks that come late (off unless asked for).

``SENSNAKE_TICK_TRACE=/path/file.jsonl`` in the environment of the loop's process (``devices.loop_process``; the
benchmark ``bench_servo_bus --trace`` sets it, and turns it on in the app's own process when the loop runs there)
turns it on: the bus thread marks each phase of a tick (the wake-up, the feedback read's instruction, every wait for status bytes and the bytes it got, the goal write, the health poll,
the tick callback), the sender thread marks each message it pickles and sends, and ``gc.callbacks`` marks every
collection, all in one in-memory ring with ``time.monotonic()`` times and the thread. When a tick starts late (more
than ``LATE_FRACTION`` of a period after its slot), the marks since two ticks before it are appended to the file as
one JSON line, so a ten-minute run writes a few lines, not 30000. Off, a mark costs one global lookup.

This is a measuring instrument, not a feature: nothing reads the file but the benchmark.
"""

from __future__ import annotations

import collections
import gc
import json
import os
import queue
import threading
import time
from typing import Any

ENV = "SENSNAKE_TICK_TRACE"
RING = 8192  # marks kept (≈ 2-3 s of ticks at 50 Hz)


class TickTrace:
    def __init__(self, path: str) -> None:
        self.path = path
        self.marks: collections.deque[tuple[float, int, str, Any]] = collections.deque(maxlen=RING)
        self._starts: collections.deque[float] = collections.deque(maxlen=3)
        self._dump_after: dict | None = None
        self._records: queue.SimpleQueue[dict] = queue.SimpleQueue()
        self._writer: threading.Thread | None = None
        self.dumped = 0

    def mark(self, label: str, value: Any = None) -> None:
        self.marks.append((time.monotonic(), threading.get_ident(), label, value))

    def tick_start(self, start_s: float, slot_s: float, period_s: float, late: bool) -> None:
        """The bus thread starts a tick (``slot_s``: when it was due). A late one is written out at its end."""
        self.marks.append((start_s, threading.get_ident(), "tick", slot_s))
        self._starts.append(start_s)
        if late and self._dump_after is None:
            self._dump_after = {"start": start_s, "slot": slot_s, "late_ms": (start_s - slot_s) * 1e3,
                                "period_ms": period_s * 1e3, "from": self._starts[0] - period_s}

    def tick_end(self) -> None:
        """The late tick has ended: hand its marks to the writer thread (the bus thread only copies them)."""
        record, self._dump_after = self._dump_after, None
        if record is None:
            return
        t0 = record["from"]
        record["marks"] = [m for m in list(self.marks) if m[0] >= t0]
        if self._writer is None:
            self._writer = threading.Thread(target=self._write_loop, name="tick-trace-writer", daemon=True)
            self._writer.start()
        self._records.put(record)

    def _write_loop(self) -> None:
        while True:
            record = self._records.get()
            names = {t.ident: t.name for t in threading.enumerate()}
            record["marks"] = [(round(t, 6), names.get(ident, str(ident)), label, value)
                               for t, ident, label, value in record["marks"]]
            record["pid"] = os.getpid()
            with open(self.path, "a", encoding="utf-8") as out:
                out.write(json.dumps(record, default=str) + "\n")
            self.dumped += 1


TRACE: TickTrace | None = None


def _gc_callback(phase: str, info: dict) -> None:
    trace = TRACE
    if trace is not None:
        trace.mark("gc>" if phase == "start" else "gc<", info.get("generation"))


def enable_from_env() -> TickTrace | None:
    """Turn the trace on if ``SENSNAKE_TICK_TRACE`` names a file (the loop process calls this at its start)."""
    global TRACE
    path = os.environ.get(ENV, "").strip()
    if not path:
        return None
    TRACE = TickTrace(path)
    if _gc_callback not in gc.callbacks:
        gc.callbacks.append(_gc_callback)
    return TRACE


def disable() -> None:
    """Turn the trace off (a benchmark that traced a loop in its own process, the app's)."""
    global TRACE
    TRACE = None
    if _gc_callback in gc.callbacks:
        gc.callbacks.remove(_gc_callback)
