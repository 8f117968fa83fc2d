"""A recording started from the GUI: board blocks, robot states, live forces and events written on a writer thread.

The GUI thread only enqueues (O(1), never waits on the disk); a writer thread owns the
:class:`app.core.recording.RecordingWriter` from creation to close (it is not thread-safe) and flushes at least every
``FLUSH_INTERVAL_S`` even when no data arrives, so a pulled cable or a crash loses at most about a second.

A write failure (disk full, file removed) stops the session cleanly: what was flushed stays readable, the queue is
dropped, and ``failed(str)`` says what happened and what to do. ``stopped(str)`` is emitted once, with a summary,
after :meth:`RecordingSession.stop` or a failure.

Public methods are for the GUI thread; signals are delivered on the GUI thread.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from app.core.recording import DEFAULT_MIN_FREE_BYTES, RecordingWriter

FLUSH_INTERVAL_S = 0.5
_STOP = object()


class RecordingSession(QObject):
    """One recording file being written; see the module docstring."""

    started = Signal(str)
    stopped = Signal(str)
    failed = Signal(str)
    _posted = Signal(object)  # writer thread → GUI thread

    def __init__(self, path: str | Path, config_text: str, channel_names: Sequence[str],
                 calibration_json: str | None = None, with_robot: bool = False, n_joints: int = 12,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.path = Path(path)
        self.channel_names = tuple(channel_names)
        self.with_robot = with_robot
        self.with_forces = calibration_json is not None
        self.t0_monotonic_s = time.monotonic()
        self._writer_args = dict(config_text=config_text, channel_names=self.channel_names,
                                 calibration_json=calibration_json, with_robot=with_robot, n_joints=n_joints,
                                 flush_interval_s=FLUSH_INTERVAL_S, t0_monotonic_s=self.t0_monotonic_s,
                                 min_free_bytes=min_free_bytes)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._active = False
        self._finished = False
        self.error: str | None = None
        self.n_daq_samples = 0
        self.n_robot_samples = 0
        self.stop_time_s: float | None = None
        self._posted.connect(self._run_posted)

    # -- state -----------------------------------------------------------------------------------------------------
    @property
    def is_active(self) -> bool:
        return self._active

    @property
    def elapsed_s(self) -> float:
        end = self.stop_time_s if self.stop_time_s is not None else time.monotonic()
        return end - self.t0_monotonic_s

    def size_bytes(self) -> int:
        try:
            return self.path.stat().st_size
        except OSError:
            return 0

    @property
    def backlog(self) -> int:
        """Items waiting for the writer thread (grows only if the disk is slower than the data)."""
        return self._queue.qsize()

    # -- life cycle ------------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Create the file and start writing (on the writer thread); ``failed`` if the file cannot be created."""
        if self._thread is not None:
            raise RuntimeError("recording already started")
        self._active = True
        self._thread = threading.Thread(target=self._run, name=f"recording:{self.path.name}", daemon=True)
        self._thread.start()
        self.started.emit(str(self.path))

    def stop(self) -> None:
        """Write what is queued, close the file and join the writer thread. Safe to call twice."""
        if self._thread is None:
            return
        self._active = False
        if self.stop_time_s is None:
            self.stop_time_s = time.monotonic()
        self._queue.put(_STOP)
        self._thread.join()
        self._thread = None
        self._finish()

    # -- data (GUI thread: enqueue only) ---------------------------------------------------------------------------
    def add_block(self, block: Any, force_n: np.ndarray | None = None) -> None:
        """A board :class:`SampleBlock` and, when forces are recorded, its (N×C) forces in N."""
        if not self._active:
            return
        self.n_daq_samples += len(block.seq)
        forces = force_n if self.with_forces else None
        self._queue.put(lambda w: _append_daq(w, block, forces))

    def add_robot_states(self, states: Iterable[Any]) -> None:
        """``ChainState`` objects (host_time_s, position_rad, current_ma, and goal_rad when the chain has it)."""
        if not self._active or not self.with_robot:
            return
        states = list(states)
        if not states:
            return
        self.n_robot_samples += len(states)
        self._queue.put(lambda w: _append_robot(w, states))

    def mark_gap(self, host_monotonic_s: float, reason: str) -> None:
        if self._active:
            self._queue.put(lambda w: w.mark_gap(host_monotonic_s, reason))

    def log_event(self, text: str, host_monotonic_s: float | None = None, kind: str = "event") -> None:
        if self._active:
            when = time.monotonic() if host_monotonic_s is None else host_monotonic_s
            self._queue.put(lambda w: w.log_event(text, when, kind))

    def update_stats(self, crc_errors: int, dropped_frames: int, resyncs: int) -> None:
        if self._active:
            self._queue.put(lambda w: w.update_stats(crc_errors, dropped_frames, resyncs))

    # -- writer thread ---------------------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            writer = RecordingWriter(self.path, **self._writer_args)
        except (OSError, ValueError) as exc:
            self.error = f"cannot start recording: {exc}"
            self._posted.emit(self._fail)
            return
        try:
            self._write_loop(writer)
        except (OSError, ValueError, RuntimeError) as exc:
            # RecordingError (disk full, file gone) lands here too: keep what is flushed, tell the user.
            text = str(exc)
            message = text if text.startswith("recording") else f"recording stopped: {text}"
            self.error = message  # set here, not in the GUI thread, so a stop() racing the failure sees it
            self._posted.emit(self._fail)
        finally:
            # A failed writer already released what it could; the flushed part stays readable.
            with contextlib.suppress(OSError):
                writer.close()

    def _write_loop(self, writer: RecordingWriter) -> None:
        last_flush = time.monotonic()
        while True:
            try:
                item = self._queue.get(timeout=FLUSH_INTERVAL_S)
            except queue.Empty:
                item = None
            if item is _STOP:
                return
            if item is not None:
                item(writer)
            if time.monotonic() - last_flush >= FLUSH_INTERVAL_S:
                writer.flush()
                last_flush = time.monotonic()

    # -- GUI thread ------------------------------------------------------------------------------------------------
    def _run_posted(self, fn: Callable[[], None]) -> None:
        fn()

    def _fail(self) -> None:
        message = self.error or "recording failed"
        self._active = False
        if self.stop_time_s is None:
            self.stop_time_s = time.monotonic()
        self.failed.emit(message)
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self._finish()

    def _finish(self) -> None:
        if self._finished:
            return
        self._finished = True
        state = "failed" if self.error else "saved"
        self.stopped.emit(f"recording {state}: {self.path} ({self.n_daq_samples} board samples, "
                          f"{self.elapsed_s:.1f} s)")


def _append_daq(writer: RecordingWriter, block: Any, force_n: np.ndarray | None) -> None:
    writer.append_daq(block)
    if force_n is not None:
        writer.append_forces(force_n)


def _append_robot(writer: RecordingWriter, states: list[Any]) -> None:
    present = np.array([s.position_rad for s in states], dtype=float)
    goal = np.array([getattr(s, "goal_rad", None) if getattr(s, "goal_rad", None) is not None
                     else s.position_rad for s in states], dtype=float)
    current = np.array([s.current_ma for s in states], dtype=float)
    times = np.array([s.host_time_s for s in states], dtype=float)
    writer.append_robot(times, goal, present, current)
