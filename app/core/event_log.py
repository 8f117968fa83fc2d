"""The event log: every status message, warning, fault and operator action with its time, in order of arrival.

The app's messages used to replace each other in a one-line status bar that cut them short; the log keeps them all
(up to :data:`DEFAULT_CAPACITY`, the oldest dropped first) so a fault's whole text can always be read again, filtered
by kind, searched, copied and saved as CSV. A recording's own ``/events`` (gaps, sensor health, link warnings,
motion-capture dropouts) are added as kind ``recorded`` when the recording is opened, stamped with the wall-clock time
they happened (the recording's start plus their ``time_s``) and replaced, not repeated, when it is opened again.

Qt-free: the GUI's dock (:mod:`widgets.event_log_view`) subscribes to it. :meth:`EventLog.add` may be called from any
thread (a lock guards the entries); subscribers are called on the thread that added the entry, so the GUI adds from
the GUI thread only (its bridges deliver device messages there).
"""

from __future__ import annotations

import csv
import io
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from app.core.outputs import write_new_file

INFO = "info"
WARNING = "warning"
FAULT = "fault"
ACTION = "action"
RECORDED = "recorded"
KINDS: tuple[str, ...] = (INFO, WARNING, FAULT, ACTION, RECORDED)
DEFAULT_CAPACITY = 10_000  # a day of a busy lab's messages; the oldest go first
CSV_COLUMNS = ("number", "time", "kind", "source", "recording_time_s", "text")


@dataclass(frozen=True)
class LogEntry:
    """One line of the log.

    ``number``: 1, 2, … in order of arrival (never reused, also after the oldest are dropped); ``wall_time_s``: when
    it happened, seconds since the Unix epoch (``time.time()``); ``kind``: one of :data:`KINDS`; ``source``: what
    said it ("robot", "board", "Forces", "operator", a recording's file name); ``text``: the whole message;
    ``origin``: for a ``recorded`` entry the recording's path, else ""; ``recording_time_s``: for a recorded entry
    its time on the recording's clock (s since the recording's start), else None."""

    number: int
    wall_time_s: float
    kind: str
    source: str
    text: str
    origin: str = ""
    recording_time_s: float | None = None

    def time_text(self, with_date: bool = False) -> str:
        """Local time, to the millisecond ("14:03:07.125"; with the date: "2026-03-02 14:03:07.125")."""
        moment = datetime.fromtimestamp(self.wall_time_s)
        text = moment.strftime("%Y-%m-%d %H:%M:%S" if with_date else "%H:%M:%S")
        return f"{text}.{int(moment.microsecond / 1000):03d}"

    def line(self) -> str:
        """The entry as one tab-separated line (what Copy puts on the clipboard)."""
        when = self.time_text(with_date=True)
        at = f"\tt={self.recording_time_s:.3f} s" if self.recording_time_s is not None else ""
        return f"{when}\t{self.kind}\t{self.source}{at}\t{self.text}"


Listener = Callable[[Sequence[LogEntry], bool], None]


class EventLog:
    """The log. ``subscribe(listener)``: ``listener(new_entries, reset)`` after every change (``reset`` True when
    entries were removed or replaced: read :attr:`entries` again)."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"an event log holds at least one entry, not {capacity}")
        self.capacity = capacity
        self._entries: deque[LogEntry] = deque(maxlen=capacity)
        self._lock = threading.Lock()
        self._next_number = 1
        self._listeners: list[Listener] = []

    # -- reading ---------------------------------------------------------------------------------------------------
    @property
    def entries(self) -> tuple[LogEntry, ...]:
        """Every entry kept, oldest first (a copy)."""
        with self._lock:
            return tuple(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def latest(self, kind: str | None = None) -> LogEntry | None:
        """The newest entry (of ``kind``), or None."""
        with self._lock:
            for entry in reversed(self._entries):
                if kind is None or entry.kind == kind:
                    return entry
        return None

    def count(self, kind: str) -> int:
        with self._lock:
            return sum(1 for entry in self._entries if entry.kind == kind)

    # -- adding ----------------------------------------------------------------------------------------------------
    def add(self, kind: str, text: str, source: str = "", wall_time_s: float | None = None) -> LogEntry:
        """Log ``text`` (kept whole, however long) as ``kind`` from ``source``; returns the entry. Any thread."""
        if kind not in KINDS:
            raise ValueError(f"event kind {kind!r} is not one of {', '.join(KINDS)}")
        with self._lock:
            entry = LogEntry(self._next_number, time.time() if wall_time_s is None else float(wall_time_s), kind,
                             source, str(text))
            self._next_number += 1
            dropped = len(self._entries) == self.capacity
            self._entries.append(entry)
        self._notify((entry,), dropped)
        return entry

    def add_recorded(self, origin: str | os.PathLike[str], started_iso: str,
                     events: Iterable[Any]) -> list[LogEntry]:
        """A recording's ``/events`` (objects with ``time_s``, ``kind`` and ``text``, as
        :class:`app.core.recording.RecordingEvent`), as ``recorded`` entries at ``started_iso`` (the recording's
        ``started``, ISO 8601) plus their time; entries of the same ``origin`` added before are replaced."""
        origin_text = str(origin)
        name = Path(origin_text).name
        start_s = parse_started(started_iso)
        with self._lock:
            kept = [e for e in self._entries if e.origin != origin_text]
            new = []
            for event in events:
                at_s = float(event.time_s)
                new.append(LogEntry(self._next_number, start_s + at_s, RECORDED, f"{name} ({event.kind})",
                                    str(event.text), origin_text, at_s))
                self._next_number += 1
            self._entries = deque(kept + new, maxlen=self.capacity)
        self._notify(tuple(new), True)
        return new

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
        self._notify((), True)

    # -- subscribers -----------------------------------------------------------------------------------------------
    def subscribe(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def unsubscribe(self, listener: Listener) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    def _notify(self, new: Sequence[LogEntry], reset: bool) -> None:
        for listener in list(self._listeners):
            listener(new, reset)


def parse_started(started_iso: str) -> float:
    """A recording's ``started`` (ISO 8601; UTC when it names no zone) as seconds since the epoch; 0.0 when it is
    missing or unreadable (the entries then keep their order and recording times)."""
    try:
        moment = datetime.fromisoformat(started_iso.strip().replace("Z", "+00:00"))
    except (ValueError, AttributeError):
        return 0.0
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=timezone.utc)
    return moment.timestamp()


def matches(entry: LogEntry, kinds: Iterable[str] | None = None, search: str = "") -> bool:
    """``entry`` is of one of ``kinds`` (all when None) and holds ``search`` (case-insensitive) in its text, source
    or time."""
    if kinds is not None and entry.kind not in set(kinds):
        return False
    needle = search.strip().lower()
    if not needle:
        return True
    return needle in entry.text.lower() or needle in entry.source.lower() or needle in entry.time_text()


def csv_text(entries: Iterable[LogEntry]) -> str:
    """The entries as CSV (header :data:`CSV_COLUMNS`; time in ISO 8601 with the local offset, to the ms)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for entry in entries:
        when = datetime.fromtimestamp(entry.wall_time_s).astimezone().isoformat(timespec="milliseconds")
        at = "" if entry.recording_time_s is None else f"{entry.recording_time_s:.6f}"
        writer.writerow((entry.number, when, entry.kind, entry.source, at, entry.text))
    return out.getvalue()


def write_csv(entries: Iterable[LogEntry], path: str | os.PathLike[str]) -> Path:
    """Save ``entries`` as CSV at ``path``, a new file, whole or not at all: an existing file (or anything else at
    that name, a link included) is never written over (:class:`FileExistsError` naming it). Any thread."""
    return write_new_file(path, csv_text(entries).encode("utf-8"), "the log is saved to a new file, never over one")

