"""Qt bridge for a calibration run: owns the rig's I/O thread, feeds it the board stream, reports to the GUI.

One :class:`RigSession` per Calibration tab. :meth:`RigSession.start` opens the rig (``lab.config.rig``: its own servo
bus, device kind ``rig``) on a worker thread that then runs :class:`app.core.rig_protocol.ProtocolRunner`; the GUI thread
never touches the rig's port. The sensor's conductance comes from the lab's board bridge (``lab.board``, started if
it is not running): every drained block's column for the sensor is pushed into the runner's
:class:`~app.core.rig_protocol.ConductanceFeed`.

STOP: the main window's STOP (button or Esc) calls ``lab.emergency_stop()``, which emits ``lab.stop_requested``; the
session listens for it and aborts the run, which takes the load off the sensor (the rig's release is not
interruptible).

Clock: with the rig and the board both on the simulated lab (port ``sim``), the protocol runs on the lab's clock
(accelerated in tests) and each board sample is placed at its frame's lab time; with hardware, on the host clock
through the board's own (see :mod:`app.core.rig_protocol`).

Signals (GUI thread): ``progress(Progress)``, ``sample(Sample)`` at the protocol's sampling rate (6 Hz by default),
``trial_saved(TrialRecord)``, ``finished(Outcome)``, ``running_changed(bool)``. All public methods: GUI thread.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, Signal

from app.core.rig_protocol import (
    BOARD_STALE_S,
    FAILED,
    ConductanceFeed,
    Outcome,
    ProtocolRunner,
    ProtocolSettings,
    finished_trials,
    lab_times_from_seq,
    read_session,
    session_folder,
)
from app.gui.lab import LabContext
from app.gui.thread_bridge import ThreadBridge
from devices import factory
from devices.errors import DeviceError
from devices.rig import CalibrationRig

log = logging.getLogger(__name__)


class RigSession(QObject):
    """A calibration run on the rig, seen from the GUI; see the module docstring."""

    progress = Signal(object)
    sample = Signal(object)
    trial_saved = Signal(object)
    finished = Signal(object)
    running_changed = Signal(bool)

    def __init__(self, lab: LabContext, parent: QObject | None = None, *, rig_factory: Any = CalibrationRig,
                 board_stale_s: float = BOARD_STALE_S) -> None:
        super().__init__(parent)
        self.lab = lab
        self.board_stale_s = board_stale_s
        self._rig_factory = rig_factory
        self._runner: ProtocolRunner | None = None
        self._thread: threading.Thread | None = None
        self._feed: ConductanceFeed | None = None
        self._channel: int | None = None
        self._lab_rate_hz: float | None = None  # board frame rate when samples go on the simulated lab's clock
        self.time_scale = 1.0  # lab seconds per wall second of the run in progress (> 1 on an accelerated sim)
        self._board: Any = None
        self.outcome: Outcome | None = None
        self._bridge = ThreadBridge(self)  # rig thread → GUI thread: public signals are emitted on the GUI thread
        lab.stop_requested.connect(self._on_stop_requested)
        self._listening_for_stop = True

    # -- state -----------------------------------------------------------------------------------------------------
    @property
    def is_running(self) -> bool:
        return self._runner is not None

    @property
    def is_paused(self) -> bool:
        return self._runner is not None and self._runner.paused

    @property
    def folder(self) -> Path | None:
        return self._runner.folder if self._runner is not None else None

    # -- control ---------------------------------------------------------------------------------------------------
    def start(self, settings: ProtocolSettings, base_folder: str | Path, *, resume: str | Path | None = None,
              contact_only: bool = False) -> Path:
        """Start a run; returns its session folder. ``resume``: a session folder of the same protocol whose finished
        trials are kept (the run continues with the first missing one). ``contact_only``: only find the contact and
        release (nothing is written; the outcome's message says where the contact is). Raises ValueError (a run is
        going, the sensor is not a board channel, no board, a folder of another protocol) with a sentence for the
        user; everything after this is reported through ``finished``."""
        if resume is not None and read_session(resume) != settings:
            raise ValueError(f"{resume} holds a session of another protocol: resume it with its own settings")
        if self.is_running:
            raise ValueError("a calibration run is already going: abort it first")
        board = self.lab.board
        if board is None:
            raise ValueError(f"no force-sensor board: {self.lab.board_unavailable_reason}")
        names = tuple(board.channel_names)
        if settings.sensor not in names:
            raise ValueError(f"sensor {settings.sensor} is not a channel of the board ({names[0]} … {names[-1]}); "
                             "check the name or the board's channel map")
        self._channel = names.index(settings.sensor)
        config = self.lab.config
        clock, time_scale, self._lab_rate_hz = None, 1.0, None
        if factory.is_sim(config.rig.port) and factory.is_sim(config.board.port):
            # The simulated rig presses the sensor chosen here (the config's [rig] sensor is only where it starts).
            factory.move_simulated_probe(settings.sensor)
            sim_clock = factory.sim_lab().clock
            clock, time_scale, self._lab_rate_hz = sim_clock.now, sim_clock.speed, config.board.rate_hz
        self.time_scale = time_scale
        self._feed = ConductanceFeed(source_alive_s=getattr(board, "newest_frame_host_s", None))
        self._board = board
        board.block.connect(self._on_block)
        if not board.is_running:
            board.start()
        folder = Path(resume) if resume is not None else session_folder(Path(base_folder), settings.sensor)
        done = finished_trials(folder, settings) if resume is not None else {}
        runner = ProtocolRunner(settings, self._feed, folder,
                                on_progress=self._bridge.emitter(self.progress),
                                on_sample=self._bridge.emitter(self.sample),
                                on_trial=self._bridge.emitter(self.trial_saved),
                                board_stale_s=self.board_stale_s, clock=clock, time_scale=time_scale, done=done,
                                contact_only=contact_only, simulated_board=factory.is_sim(config.board.port))
        self._runner = runner
        self.outcome = None
        self._thread = threading.Thread(target=self._worker, args=(runner,), name="calibration-rig", daemon=True)
        self._thread.start()
        self.running_changed.emit(True)
        return folder

    def abort(self, reason: str = "aborted by the user") -> None:
        if self._runner is not None:
            self._runner.abort(reason)

    def emergency_stop(self) -> None:
        """STOP: abort now; the load comes off the sensor."""
        self.abort("STOP pressed")

    def pause(self) -> None:
        if self._runner is not None:
            self._runner.pause()

    def resume(self) -> None:
        if self._runner is not None:
            self._runner.resume()

    def shutdown(self) -> None:
        """Abort a run and wait for the rig to be released and closed (blocks up to a few seconds)."""
        self.abort("the window closed")
        thread = self._thread
        if thread is not None:
            thread.join()
        self._disconnect_board()
        if self._listening_for_stop:
            self._listening_for_stop = False
            with contextlib.suppress(RuntimeError, TypeError):  # the bridge is already gone
                self.lab.stop_requested.disconnect(self._on_stop_requested)

    # -- worker thread ---------------------------------------------------------------------------------------------
    def _worker(self, runner: ProtocolRunner) -> None:
        """Rig thread: open the rig, run, close; the outcome goes to the GUI through ``finished`` (queued)."""
        rig = self._rig_factory(self.lab.config.rig, interrupt=runner.stop_requested)
        try:
            rig.open()
        except (DeviceError, OSError, ValueError) as exc:
            outcome = Outcome(FAILED, f"cannot open the calibration rig on {self.lab.config.rig.port}: {exc}",
                              runner.folder)
        else:
            try:
                outcome = runner.run(rig)
            finally:
                try:
                    rig.close()
                except (DeviceError, OSError) as exc:
                    log.warning("closing the rig: %s", exc)
        # If the session was deleted meanwhile (window closed; shutdown() is joining this thread) the bridge drops it.
        self._bridge.post(self._on_finished, outcome)

    # -- GUI thread ------------------------------------------------------------------------------------------------
    def _on_block(self, block: Any) -> None:
        if self._feed is not None and self._channel is not None and len(block):
            if self._lab_rate_hz is not None:
                times = lab_times_from_seq(block.seq, self._lab_rate_hz)
                self._feed.push(times, block.conductance_s[:, self._channel], times)
            else:
                self._feed.push(block.host_time_s, block.conductance_s[:, self._channel], block.board_time_s)

    def _on_stop_requested(self) -> None:
        if self.is_running:
            self.emergency_stop()

    def _on_finished(self, outcome: Outcome) -> None:
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join()
        self._runner = None
        self._disconnect_board()
        self.outcome = outcome
        self.running_changed.emit(False)
        self.finished.emit(outcome)

    def _disconnect_board(self) -> None:
        board, self._board = self._board, None
        if board is not None:
            with contextlib.suppress(RuntimeError, TypeError):  # already disconnected
                board.block.disconnect(self._on_block)

