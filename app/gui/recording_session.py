"""The GUI's face of a recording: :class:`app.core.recorder.Recorder` (the same writer-thread recorder ``sensnake
record`` uses) with Qt signals.

The Forces tab hands :attr:`RecordingSession.recorder` to its :class:`app.core.live_session.LiveSession`, which feeds
it every board block, its forces, robot states, gaps, segments, health changes and link counters — the data never
passes through this class. This class only starts and stops the recorder and turns its failure (reported on the
writer thread) into signals on the GUI thread through the one :class:`app.gui.thread_bridge.ThreadBridge`.

Signals: ``started(str)`` the path; ``failed(str)`` what went wrong and what to do (disk full, file removed; what
was flushed stays readable); ``stopped(str)`` once, with a summary, after :meth:`RecordingSession.stop` or a failure.

With ``mocap`` (the lab's :class:`app.gui.mocap_link.MocapLink`) the motion capture followed meanwhile is collected
from start to stop and written into the closed file as ``/mocap`` on a worker thread (fitting a minute of 960 Hz
takes seconds); ``stopped`` follows once it is written, its summary saying so.
The data methods (:meth:`add_block` …) forward to the recorder, for callers without a live session (tests, tools).

Public methods are for the GUI thread; signals are delivered on the GUI thread.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from app.core.errors import MocapFileError
from app.core.recorder import Recorder
from app.core.recording import DEFAULT_MIN_FREE_BYTES
from app.core.run_documents import live_run_start
from app.gui.thread_bridge import ThreadBridge


def describe_recording(recording: Any) -> tuple[str, str]:
    """(a few words, a sentence) naming a recording of the live data that another part of the app started: a trial
    of the Trials dock by its number and file, any other by its plan and file. ``recording``: a
    :class:`app.core.recorder.Recorder` or a :class:`RecordingSession`."""
    recorder = getattr(recording, "recorder", recording)
    path = Path(str(getattr(recorder, "path", "") or "recording"))
    run_start = getattr(recorder, "run_start", None) or {}
    trial = run_start.get("trial")
    if run_start.get("plan_name") == "robot trials" and isinstance(trial, int):
        return (f"● trial {trial + 1} recording (Trials)",
                f"Trial {trial + 1} of the series in {path.parent.name} is recording the board and the robot to "
                f"{path.name} (Trials dock)")
    plan = run_start.get("plan_name") or "another recording"
    return f"● {plan} recording", f"{plan} is recording the board to {path}"


class RecordingSession(QObject):
    """One recording file being written; see the module docstring."""

    started = Signal(str)
    stopped = Signal(str)
    failed = Signal(str)

    def __init__(self, path: str | Path, config_text: str, channel_names: Sequence[str],
                 calibration_json: str | None = None, with_robot: bool = False, n_joints: int = 12,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES, t0_monotonic_s: float | None = None,
                 mocap: Any = None, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._bridge = ThreadBridge(self)
        self.recorder = Recorder(path, config_text, channel_names, calibration_json=calibration_json,
                                 with_robot=with_robot, n_joints=n_joints, min_free_bytes=min_free_bytes,
                                 t0_monotonic_s=t0_monotonic_s,
                                 on_failed=lambda message: self._bridge.post(self._fail, message),
                                 run_start=live_run_start(config_text, calibration_json, plan_name="forces tab"))
        self.path = self.recorder.path
        self.channel_names = self.recorder.channel_names
        self.with_robot = with_robot
        self.with_forces = calibration_json is not None
        self.t0_monotonic_s = self.recorder.t0_monotonic_s
        self._finished = False
        self.mocap = mocap
        self.mocap_summary = ""  # what the motion capture came to (written, or why not)
        self._mocap_writer: threading.Thread | None = None

    # -- state -----------------------------------------------------------------------------------------------------
    @property
    def is_active(self) -> bool:
        return self.recorder.is_active

    @property
    def error(self) -> str | None:
        return self.recorder.error

    @property
    def elapsed_s(self) -> float:
        return self.recorder.elapsed_s

    @property
    def n_daq_samples(self) -> int:
        return self.recorder.n_daq_samples

    @property
    def n_robot_samples(self) -> int:
        return self.recorder.n_robot_samples

    @property
    def stop_time_s(self) -> float | None:
        return self.recorder.stop_time_s

    def size_bytes(self) -> int:
        return self.recorder.size_bytes()

    @property
    def backlog(self) -> int:
        return self.recorder.backlog

    # -- life cycle ------------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the recorder (its writer thread creates the file; ``failed`` if it cannot)."""
        self.recorder.start()
        if self.mocap is not None:
            self.mocap.recording_started(self.recorder)
        self.started.emit(str(self.path))

    def stop(self) -> None:
        """Write what is queued, close the file and join the writer thread; the motion capture is then written on a
        worker. Safe to call twice: a second call waits for that worker."""
        if not self.recorder.running:
            if self._mocap_writer is not None:
                self._mocap_writer.join()
            return
        take = self.mocap.recording_stopping(self.recorder) if self.mocap is not None else None
        self.recorder.stop()
        if take is None or not self.recorder.kept or self.recorder.error:
            self._finish()
            return
        self._mocap_writer = threading.Thread(target=self._write_mocap, args=(take,), name="recording-mocap")
        self._mocap_writer.start()

    def _write_mocap(self, take: Any) -> None:  # worker thread
        try:
            summary = self.mocap.write_take(take, self.path, self.t0_monotonic_s)
        except (MocapFileError, OSError, ValueError) as exc:
            summary = f"mocap not written: {exc}"
        self._bridge.post(self._mocap_written, summary)

    def _mocap_written(self, summary: str) -> None:
        self.mocap_summary = summary
        self._finish()

    # -- data (forwarded; the Forces tab's live session feeds the recorder directly) -------------------------------
    def add_block(self, block: Any, force_n: np.ndarray | None = None, status: np.ndarray | None = None) -> None:
        self.recorder.add_block(block, force_n, status)

    def add_robot_states(self, states: Iterable[Any]) -> None:
        self.recorder.add_robot_states(states)

    def mark_gap(self, host_monotonic_s: float, reason: str) -> None:
        self.recorder.mark_gap(host_monotonic_s, reason)

    def log_event(self, text: str, host_monotonic_s: float | None = None, kind: str = "event") -> None:
        self.recorder.log_event(text, host_monotonic_s, kind)

    def update_stats(self, stats: Any) -> None:
        self.recorder.update_stats(stats)

    # -- GUI thread ------------------------------------------------------------------------------------------------
    def _fail(self, message: str) -> None:
        self.failed.emit(message)
        if self.mocap is not None and self.recorder.running:
            self.mocap.recording_stopping(self.recorder)  # the take ends with the file; nothing to write it into
        self.recorder.stop()
        self._finish()

    def _finish(self) -> None:
        if self._finished:
            return
        self._finished = True
        recorder = self.recorder
        if recorder.error:
            state = "failed"
        elif not recorder.kept:
            state = "empty (no data arrived; nothing written)"
        else:
            state = "saved"
        mocap = f"; {self.mocap_summary}" if self.mocap_summary else ""
        self.stopped.emit(f"recording {state}: {self.path} ({recorder.n_daq_samples} board samples, "
                          f"{recorder.elapsed_s:.1f} s){mocap}")
