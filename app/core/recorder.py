"""A recording being written: board blocks, forces, robot states and events queued to a writer thread.

The caller (the CLI's main thread, the GUI thread) only enqueues — O(1), never waiting on the disk. A writer thread
owns the :class:`app.core.recording.RecordingWriter` from creation to close (it is not thread-safe) and flushes at
least every :data:`FLUSH_INTERVAL_S` even when no data arrives, so a pulled cable, ``kill -9`` or a crash loses at
most about half a second, and the file on disk always opens in plain h5py.

A write failure (disk full, file removed) stops the recorder cleanly: what was flushed stays readable, the queue is
dropped, :attr:`Recorder.error` says what happened and ``on_failed(message)`` is called (from the writer thread).
Nothing here imports Qt: :class:`app.gui.recording_session.RecordingSession` re-emits these as signals, and
``sensnake record`` uses the recorder as it is.

Public methods are for one controlling thread (the one that called :meth:`Recorder.start`), except
:attr:`error`, :attr:`backlog`, :meth:`size_bytes` which any thread may read, and :meth:`log_event` and
:meth:`add_mocap`, which the motion-capture reader thread calls (they only enqueue).
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.core.catalog import finish_run, index_quietly
from app.core.recording import DEFAULT_MIN_FREE_BYTES, RecordingWriter
from app.core.run_documents import live_run_start

FLUSH_INTERVAL_S = 0.5
_STOP = object()
LINK_STAT_FIELDS = ("out_of_range_frames", "channel_mismatches", "reconnects", "bad_headers", "duplicate_frames",
                    "clock_backsteps", "host_stalls")


class Recorder:
    """One recording file being written; see the module docstring."""

    def __init__(self, path: str | Path, config_text: str, channel_names: Sequence[str],
                 calibration_json: str | None = None, with_robot: bool = False, n_joints: int = 12,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES, t0_monotonic_s: float | None = None,
                 on_failed: Callable[[str], None] | None = None, run_start: Mapping[str, Any] | None = None) -> None:
        """``run_start``: the run's RunStart document (:mod:`app.core.run_documents`; a plan that knows its
        condition passes it), by default a ``record`` run with what a recording knows of its condition."""
        self.path = Path(path)
        self.run_start = dict(run_start) if run_start is not None else live_run_start(config_text, calibration_json)
        self._stop_status = ("success", "")
        self.channel_names = tuple(channel_names)
        self.with_robot = with_robot
        self.with_forces = calibration_json is not None
        self.t0_monotonic_s = time.monotonic() if t0_monotonic_s is None else t0_monotonic_s
        self._writer_args = dict(config_text=config_text, channel_names=self.channel_names,
                                 calibration_json=calibration_json, with_robot=with_robot, n_joints=n_joints,
                                 flush_interval_s=FLUSH_INTERVAL_S, t0_monotonic_s=self.t0_monotonic_s,
                                 min_free_bytes=min_free_bytes, run_start=self.run_start)
        self._on_failed = on_failed
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._writer: RecordingWriter | None = None
        self._active = False
        self.error: str | None = None
        self.kept = False  # the file at ``path`` holds this recording (set when the writer closes)
        self.n_daq_samples = 0
        self.n_robot_samples = 0
        self.stop_time_s: float | None = None

    # -- state -----------------------------------------------------------------------------------------------------
    @property
    def is_active(self) -> bool:
        return self._active and self.error is None

    @property
    def elapsed_s(self) -> float:
        end = self.stop_time_s if self.stop_time_s is not None else time.monotonic()
        return end - self.t0_monotonic_s

    def size_bytes(self) -> int:
        writer = self._writer
        if writer is not None:
            return writer.size_bytes()
        try:
            return self.path.stat().st_size if self.kept else 0
        except OSError:
            return 0

    @property
    def backlog(self) -> int:
        """Items waiting for the writer thread (grows only if the disk is slower than the data)."""
        return self._queue.qsize()

    # -- life cycle ------------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the writer thread, which creates the file; a failure to create it arrives as ``on_failed``."""
        if self._thread is not None:
            raise RuntimeError("recording already started")
        self._active = True
        self._thread = threading.Thread(target=self._run, name=f"recording:{self.path.name}", daemon=True)
        self._thread.start()

    def stop(self, exit_status: str = "success", reason: str = "") -> None:
        """Write what is queued, close the file and join the writer thread. Safe to call twice. ``exit_status``
        (``success``, ``abort``: stopped early, e.g. Ctrl-C) and ``reason`` go into the file's ``run_stop``."""
        thread = self._thread
        if thread is None:
            return
        self._stop_status = (exit_status, reason)
        self._active = False
        if self.stop_time_s is None:
            self.stop_time_s = time.monotonic()
        self._queue.put(_STOP)
        thread.join()
        self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    # -- data (controlling thread: enqueue only) -------------------------------------------------------------------
    def add_block(self, block: Any, force_n: np.ndarray | None = None, status: np.ndarray | None = None) -> None:
        """A board :class:`~devices.board.SampleBlock` and, when forces are recorded, its (N×C) forces in N and
        their (N×C) :class:`models.sls.ForceStatus` codes (None: all ok)."""
        if not self.is_active:
            return
        host = getattr(block, "host_time_s", None)
        if host is not None and len(host) and host[0] < self.t0_monotonic_s:
            # Frames that arrived before the recording started (the rest of the block the GUI was drawing, or
            # frames back-dated by their bytes' time on the wire) are not part of it: time_s never goes below 0.
            first = int(np.searchsorted(host, self.t0_monotonic_s, side="left"))
            if first >= len(host):
                return
            block = _frames_from(block, first)
            force_n = None if force_n is None else force_n[first:]
            status = None if status is None else status[first:]
        self.n_daq_samples += len(block.seq)
        forces = force_n if self.with_forces else None
        self._queue.put(lambda w: _append_daq(w, block, forces, status))

    def add_robot_states(self, states: Iterable[Any]) -> None:
        """``ChainState`` objects (host_time_s, position_rad, current_ma, and goal_rad when the chain has it)."""
        if not self.is_active or not self.with_robot:
            return
        states = [s for s in states if s.host_time_s >= self.t0_monotonic_s]  # none from before the start
        if not states:
            return
        self.n_robot_samples += len(states)
        self._queue.put(lambda w: _append_robot(w, states))

    def add_mocap(self, columns: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
        """Rows of ``/mocap`` (each column's rows on its first axis; ``attrs``: the group's attributes when it is
        made), appended to the file with the rest at the next flush. Any thread (the motion-capture reader's)."""
        if self.is_active:
            self._queue.put(lambda w: w.append_mocap(columns, attrs))

    def set_mocap_attrs(self, attrs: Mapping[str, Any]) -> None:
        """``/mocap`` attributes set (or replaced) at the next flush."""
        if self.is_active:
            self._queue.put(lambda w: w.set_mocap_attrs(attrs))

    def mark_gap(self, host_monotonic_s: float, reason: str) -> None:
        if self.is_active:
            self._queue.put(lambda w: w.mark_gap(host_monotonic_s, reason))

    def log_event(self, text: str, host_monotonic_s: float | None = None, kind: str = "event") -> None:
        if self.is_active:
            when = time.monotonic() if host_monotonic_s is None else host_monotonic_s
            self._queue.put(lambda w: w.log_event(text, when, kind))

    def update_stats(self, stats: Any) -> None:
        """The board link's cumulative counters (a :class:`~devices.board.BoardStats`), stored in the file."""
        if self.is_active:
            more = {name: int(getattr(stats, name)) for name in LINK_STAT_FIELDS if hasattr(stats, name)}
            self._queue.put(lambda w: w.update_stats(stats.crc_errors, stats.dropped_frames, stats.resyncs, **more))

    # -- writer thread ---------------------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            writer = RecordingWriter(self.path, **self._writer_args)  # type: ignore[arg-type]
        except (OSError, ValueError) as exc:
            text = str(exc)  # a RecordingError already says "cannot create recording PATH: why"
            self._failed(text if text.startswith("cannot create") else f"cannot start recording {self.path}: {text}")
            return
        self._writer = writer
        try:
            self._write_loop(writer)
        except (OSError, ValueError, RuntimeError) as exc:
            # RecordingError (disk full, file gone) lands here too: keep what is flushed, tell the user.
            text = str(exc)
            self._failed(text if text.startswith("recording") else f"recording stopped: {text}")
        finally:
            # A failed writer already released what it could; the flushed part stays readable.
            with contextlib.suppress(OSError, RuntimeError):
                writer.close()
            self.kept = writer.kept
            self._writer = None
            if self.kept and self.error:
                # Nothing more is written into a file whose write failed (a full disk, a quota): it stays exactly as
                # the last good flush left it, and its missing run_stop reads as a run cut short.
                index_quietly(self.path)
            elif self.kept:  # closed: the run's stop document, then the catalog (off the data path)
                finish_run(self.path, self.run_start, *self._stop_status)

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

    def _failed(self, message: str) -> None:
        self.error = message
        self._active = False
        if self.stop_time_s is None:
            self.stop_time_s = time.monotonic()
        if self._on_failed is not None:
            self._on_failed(message)


def _frames_from(block: Any, first: int) -> Any:
    """``block`` without its first ``first`` frames (a :class:`~devices.board.SampleBlock`)."""
    def cut(values: Any) -> Any:
        return None if values is None else values[first:]

    return dataclasses.replace(block, **{f.name: cut(getattr(block, f.name)) for f in dataclasses.fields(block)})


def _append_daq(writer: RecordingWriter, block: Any, force_n: np.ndarray | None,
                status: np.ndarray | None = None) -> None:
    writer.append_daq(block)
    if force_n is not None:
        writer.append_forces(force_n, status)


def _append_robot(writer: RecordingWriter, states: list[Any]) -> None:
    present = np.array([s.position_rad for s in states], dtype=float)
    goal = np.array([getattr(s, "goal_rad", None) if getattr(s, "goal_rad", None) is not None
                     else s.position_rad for s in states], dtype=float)
    current = np.array([s.current_ma for s in states], dtype=float)
    times = np.array([s.host_time_s for s in states], dtype=float)
    writer.append_robot(times, goal, present, current)
    control = [s for s in states if getattr(s, "correction_rad", None) is not None]
    if control:  # a controller other than feedforward ran (SPEC §3.5 /control)
        writer.append_control(np.array([s.host_time_s for s in control], dtype=float),
                              np.array([s.correction_rad for s in control], dtype=float),
                              str(getattr(control[0], "controller", "feedback")),
                              str(getattr(control[0], "controller_gains", "{}")))
