"""The Gait tab: replay a shape follow-the-leader or as keyframes, or run a parametric gait, on ``lab.robot``.

A shape can be played with force feedback (:class:`app.core.force_control.ForceFeedbackMotion`): its pitch goals are
corrected from the bottom forces the Forces tab estimates and publishes on ``lab.force_page``; the gains are
adjustable while it plays (through the same page), and the panel shows per node the target and measured force and
the correction.

Wires :class:`widgets.gait_panel.GaitPanel` to the robot bridge. Motions are the MotionSources of
:mod:`models.trajectory`, built by :func:`app.core.play.build_source` — the code ``sensnake play`` runs — and
sampled at the controller's rate (``robot.control_rate_hz``). Progress (shift / keyframe / cycle index and fraction)
is read from the running source; the drawing shows the present pose with the goal overlaid, so the shape can be
seen sliding along the body. Refreshed by a 20 Hz timer while the tab is visible. GUI thread only.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QTimer
from PySide6.QtGui import QHideEvent, QShowEvent
from PySide6.QtWidgets import QFileDialog, QVBoxLayout, QWidget

from app.core import user_folders
from app.core.force_control import FeedbackProgress, ForceFeedbackMotion
from app.core.play import build_source
from app.core.shapes import Shape, ShapeLibrary, read_shape
from app.core.teach import TeachSession
from app.gui.lab import LabContext
from app.gui.robot_bridge import (
    HALTED_TEXT,
    MOTION_FAULT,
    MOTION_FINISHED,
    MOTION_HALTED,
    MOTION_IDLE,
    MOTION_PAUSED,
    MOTION_RUNNING,
    MOTION_STOPPED,
    describe_error,
)
from models.errors import GainsError, TrajectoryError
from models.force_feedback import FeedbackGains
from models.trajectory import SerpenoidParams, SidewindingParams, serpenoid, sidewinding
from widgets import theme
from widgets.gait_panel import GaitPanel, GaitRequest

REFRESH_INTERVAL_MS = 50


class GaitTab(QWidget):
    def __init__(self, lab: LabContext, library: ShapeLibrary | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        self.robot = lab.robot
        self.config = lab.config.robot
        self.library = library or ShapeLibrary()
        self._files: dict[str, Path] = {}  # shapes opened from files, by display name
        self.source: Any = None
        self._preview: np.ndarray | None = None
        self.teach = TeachSession(self.robot.run_on_bus, self.config, self._set_torque)

        self.panel = GaitPanel(self.config.axes, self.config.segment_length_m, self.config.max_joint_speed_rad_s,
                               self.config.control_rate_hz)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.panel)
        p = self.panel
        p.play_requested.connect(self.play)
        p.pause_requested.connect(self.robot.pause_motion)
        p.resume_requested.connect(self.robot.resume_motion)
        p.stop_requested.connect(self.robot.stop_motion)
        p.refresh_shapes_requested.connect(self.refresh_shapes)
        p.open_file_requested.connect(self._open_file)
        p.shape_selected.connect(self._preview_shape)
        p.gains_changed.connect(self._gains_changed)
        self.robot.motion_changed.connect(self._motion_changed)
        self.robot.error.connect(self._robot_error)
        self.robot.connected.connect(p.set_connected)
        p.set_connected(self.robot.is_connected)
        self._lead_on: tuple[str, bool] = ("", False)  # (gains JSON, lead on?) parsed once per change, not per refresh
        self._timer = QTimer(self)
        self._timer.setInterval(REFRESH_INTERVAL_MS)
        self._timer.timeout.connect(self.refresh)
        self.refresh_shapes()

    # -- shapes ------------------------------------------------------------------------------------------------------
    def refresh_shapes(self) -> None:
        names = self.library.names() + sorted(self._files)
        self.panel.set_shapes(names)
        self._preview_shape(self.panel.shape_combo.currentText())

    def add_shape_file(self, path: str | Path) -> str:
        """Offer a shape file outside the library; returns its display name."""
        path = Path(path)
        name = f"{path.stem} (file)"
        self._files[name] = path
        self.panel.set_shapes(self.library.names() + sorted(self._files), current=name)
        self._preview_shape(name)
        return name

    def _open_file(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open shape", user_folders.dialog_folder(self.library.root),
                                              "Shapes (*.json)")
        if path:
            self.add_shape_file(path)

    def load_shape(self, name: str) -> Shape:
        if not name:
            raise ValueError("no shape chosen: save one in the Teach tab or open a shape file")
        if name in self._files:
            return read_shape(self._files[name])
        return self.library.load(name)

    def _preview_shape(self, name: str) -> None:
        try:
            shape = self.load_shape(name) if name else None
        except (OSError, ValueError):
            shape = None
        ok = shape is not None and len(shape.angles_rad) == self.config.n_joints
        self._preview = np.asarray(shape.angles_rad) if ok and shape is not None else None
        self.refresh()

    # -- motion ------------------------------------------------------------------------------------------------------
    def build(self, request: GaitRequest) -> tuple[Any, str]:
        """The MotionSource and its name for a request (ValueError with a readable message if it can't be made)."""
        robot = self.config
        if request.mode in ("follow", "keyframes"):
            shape = self.load_shape(request.shape_name)
            if not 0 < request.rate_hz <= robot.control_rate_hz:
                raise ValueError(f"rate must be in (0, {robot.control_rate_hz:g}] Hz, the control loop's rate")
            # A source sampled slower than the loop advances every few ticks; faster is impossible (one goal
            # per tick), which is why the panel caps the rate at the loop's.
            sampled = replace(robot, control_rate_hz=request.rate_hz)
            source = build_source(shape, sampled, request.mode, request.speed_rad_s, request.time_scale,
                                  request.shifts, request.repeat)
            if request.controller == "feedback":
                return self._with_feedback(source, request), f"{request.mode} {request.shape_name} (feedback)"
            return source, f"{request.mode} {request.shape_name}"
        wave = SerpenoidParams(amplitude_rad=request.amplitude_rad, spatial_rad=request.spatial_rad,
                               frequency_hz=request.frequency_hz, offset_rad=request.offset_rad,
                               cycles=request.cycles * request.repeat,
                               ramp_s=min(2.0, 1.0 / request.frequency_hz))
        amplitude = max(request.amplitude_rad + abs(request.offset_rad),
                        request.pitch_amplitude_rad if request.mode == "sidewinding" else 0.0)
        peak_speed = amplitude * 2 * math.pi * request.frequency_hz
        if peak_speed > robot.max_joint_speed_rad_s:
            raise TrajectoryError(
                f"amplitude × 2π × frequency = {peak_speed:.2f} rad/s exceeds the robot's max joint speed "
                f"{robot.max_joint_speed_rad_s:g} rad/s: lower the amplitude or the frequency")
        limit = min(max(robot.joint_max_rad), -min(robot.joint_min_rad))
        if amplitude > limit:
            raise TrajectoryError(f"amplitude {amplitude:.2f} rad exceeds the joint limits (±{limit:.2f} rad)")
        if request.mode == "serpenoid":
            return serpenoid(robot.axes, wave), "serpenoid"
        params = SidewindingParams(yaw=wave, pitch_amplitude_rad=request.pitch_amplitude_rad,
                                   pitch_spatial_rad=request.spatial_rad, phase_rad=request.phase_rad)
        return sidewinding(robot.axes, params), "sidewinding"

    def _with_feedback(self, source: Any, request: GaitRequest) -> ForceFeedbackMotion:
        """``source`` corrected from the bottom forces the Forces tab publishes (the page crosses to the control
        loop's process by its path); the panel's gains go onto the page first, so the loop starts with them."""
        robot = self.config
        gains = replace(FeedbackGains(), **(request.gains or {}))
        page = self.lab.force_page
        page.set_gains(gains)
        return ForceFeedbackMotion(source, tuple(robot.axes), tuple(self.lab.config.board.channel_names), gains,
                                   page_path=str(page.path), rate_hz=robot.control_rate_hz,
                                   joint_min_rad=tuple(robot.joint_min_rad), joint_max_rad=tuple(robot.joint_max_rad))

    def _gains_changed(self, values: dict) -> None:
        """Live adjustment: the running feedback motion reads the page's gains at its next tick."""
        if not isinstance(self.source, ForceFeedbackMotion):
            return
        try:
            gains = replace(self.source.gains, **values)
        except GainsError as exc:
            self.panel.set_status(f"gains not changed: {exc}", theme.ERROR)
            return
        self.source.gains = gains
        self.lab.force_page.set_gains(gains)

    def play(self, request: GaitRequest) -> None:
        if not self.robot.is_connected:
            self.panel.set_status("the robot is not connected: connect it first (Hardware tab → Connect)",
                                  theme.ERROR)
            return
        try:
            source, name = self.build(request)
        except (OSError, ValueError) as exc:
            self.panel.set_status(str(exc), theme.ERROR)
            if self.robot.motion_state not in (MOTION_RUNNING, MOTION_PAUSED):
                self.source = None  # the previous run's progress is not this (refused) one's
                self.panel.set_progress("idle", 0.0)
                self.panel.set_feedback_readout([])
            return
        self.source = source
        self.panel.set_status(f"torque on, then playing {name}", theme.OK)

        def failed(exc: BaseException) -> None:
            self.panel.set_motion_state(self.robot.motion_state)
            # One Future carries both a refusal before the first goal and a fault (overload, lost link, a silent
            # servo) after the motion ran: said apart, by whether the motion got anywhere.
            if motion_started(source):
                self.panel.set_status(f"{name} stopped: {describe_error(exc)}", theme.ERROR)
            else:
                self.panel.set_status(f"cannot start {name}: {describe_error(exc)}", theme.ERROR)
            self.refresh()

        # One bus-thread command: limp joints (after teaching) hold where they are, the plan from the present pose
        # is checked against the joint limits and speed, then the motion starts.
        self.robot.when_done(self.robot.play(source, name), None, failed)

    def _set_torque(self, enabled: bool, ids: list[int] | None) -> Any:
        controller = self.robot.controller
        if controller is None:
            raise ConnectionError("the robot is not connected: connect it first (Hardware tab → Connect)")
        return controller.set_torque(enabled, ids)

    def _motion_changed(self, state: str) -> None:
        self.panel.set_motion_state(state)
        name = self.robot.motion_name
        if state == MOTION_FINISHED:
            self.panel.set_status(f"{name}: finished", theme.OK)
        elif state == MOTION_STOPPED:
            self.panel.set_status(f"{name}: stopped; the robot holds its last goal", theme.WARN)
        elif state == MOTION_PAUSED:
            self.panel.set_status(f"{name}: paused (Resume continues from here)", theme.WARN)
        elif state == MOTION_RUNNING:
            self.panel.set_status(f"playing {name}", theme.OK)
        elif state == MOTION_HALTED:
            self.panel.set_status(f"{name}: {HALTED_TEXT}", theme.WARN)
        self.refresh()

    def _robot_error(self, text: str) -> None:
        if self.source is not None and self.robot.motion_state in (MOTION_FAULT, MOTION_RUNNING, MOTION_PAUSED,
                                                                   MOTION_STOPPED):
            self.panel.set_status(text, theme.ERROR)

    # -- live view ---------------------------------------------------------------------------------------------------
    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt override
        super().showEvent(event)
        self.refresh_shapes()  # shapes saved in the Teach tab meanwhile appear without a click
        self._timer.start()
        self.refresh()

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt override
        self._timer.stop()
        super().hideEvent(event)

    def refresh(self) -> None:
        state = self.robot.latest_state
        present = None if state is None else np.asarray(state.position_rad)
        active = self.robot.motion_state in (MOTION_RUNNING, MOTION_PAUSED)
        goal: np.ndarray | None
        if active and state is not None and state.goal_rad is not None:
            goal = np.asarray(state.goal_rad)
        else:
            goal = self._preview if self.panel.mode in ("follow", "keyframes") else None
        self.panel.body_view.set_angles(present, goal)
        if state is not None:
            self.panel.set_joint_readout(state.goal_rad, state.position_rad, state.current_ma)
        source = self.source
        if source is not None and hasattr(source, "progress"):
            p = source.progress
            ended = ENDED_TEXT.get(self.robot.motion_state, "")
            if ended and not motion_started(source):
                ended = "not started"
            self.panel.set_progress(progress_text(p, ended), p.fraction)
            if isinstance(p, FeedbackProgress) and p.node_joints:
                why = dict(p.fallback)
                if p.gains_json != self._lead_on[0]:
                    self._lead_on = (p.gains_json, json.loads(p.gains_json or "{}").get("lead_gain", 0.0) != 0.0)
                lead_on = self._lead_on[1]
                self.panel.set_feedback_readout([
                    (f"J{j + 1}", p.target_n, load, p.correction_rad[j], why.get(j, ""))
                    for j, load in zip(p.node_joints, p.node_load_n)],
                    lead=(p.front_load_n, p.lead_rad) if lead_on else None)


# How the progress line ends once the motion has ended without finishing (by motion state): never a time left.
ENDED_TEXT: dict[str, str] = {MOTION_STOPPED: "stopped", MOTION_FAULT: "stopped by a fault", MOTION_IDLE: "stopped",
                              MOTION_HALTED: "stopped (checking why)"}


def motion_started(source: Any) -> bool:
    """Whether ``source`` has been played from at all (its progress moved past the start)."""
    p = getattr(source, "progress", None)
    return p is not None and (p.elapsed_s > 0.0 or p.index > 0 or p.fraction > 0.0)


def progress_text(p: Any, ended: str = "") -> str:
    """One line for a :class:`models.trajectory.Progress`: where the motion is, and the time left (s).

    Shifts count k = 0 … K as SPEC §5 numbers them (shift 0 is the approach to the first pose); keyframes and
    cycles count from 1, as a person counts them. ``ended``: how a motion that ended before its end did (STOP,
    Stop, a fault), said instead of the time that was left.
    """
    if p.kind == "shift":
        where = f"shift {p.index}/{max(p.count - 1, 0)}   move {p.move_fraction * 100:3.0f}%"
    elif p.kind == "cycle":
        where = f"cycle {min(p.index + 1, p.count)}/{p.count}"
    else:
        where = f"{p.kind} {min(p.index + 1, max(p.count, 1))}/{max(p.count, 1)}"
    left_s = max(p.total_s - p.elapsed_s, 0.0)
    tail = "done" if p.done else f"{left_s:.1f} s left"
    if getattr(p, "handing_back", False):
        tail = "easing the correction back to the taught pose"
    if ended and not p.done:
        tail = ended
    return f"{where}   {p.elapsed_s:.1f} / {p.total_s:.1f} s   {tail}"


def create_tab(lab: LabContext) -> QWidget:
    return GaitTab(lab)
