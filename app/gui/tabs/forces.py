"""The Forces tab: live per-segment force plots, the body force map, sensor health, recording and past recordings.

Wiring (GUI thread): ``lab.board`` (:class:`app.gui.board_bridge.BoardBridge`) delivers verified blocks at ≤ 60 Hz
to :class:`app.core.live_session.LiveSession` — the same Qt-free data path ``sensnake record`` uses: the force
pipeline, the sensor health monitor and, while recording, the core :class:`app.core.recorder.Recorder` (inside
:class:`app.gui.recording_session.RecordingSession`, which only adds signals) with the robot's states
(``lab.robot.state_block``), gaps, clock segments and link counters. This tab subscribes to the session and draws:
a bounded force history that the plots redraw from their own timer (drawing only; nothing a recording needs lives in
it), the health list, the link counters. The body map redraws at ``BODY_REFRESH_HZ`` from the newest forces and the
robot's newest angles, only when something changed.

Past recordings open in the same plots (``Back to live`` returns); several can be overlaid for one sensor on a
common time zero; the one shown can be exported to CSV.

GUI thread only.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from datetime import datetime
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QCloseEvent, QCursor
from PySide6.QtWidgets import (
    QApplication,
    QComboBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QListWidget,
    QMenu,
    QPushButton,
    QSplitter,
    QTabWidget,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from app.core import user_folders
from app.core.calfiles import write_atomically
from app.core.forces_pipeline import NO_CALIBRATION_HINT, UNCALIBRATED, ForcesPipeline
from app.core.live_session import LiveSession, LiveUpdate
from app.core.outputs import check_new_file, check_output
from app.core.recording import DEFAULT_MIN_FREE_BYTES, Recording, open_recording
from app.core.view_export import export_view_csv
from app.gui.figure_png import write_beside
from app.gui.forces_history import RESET, Reestimation, joined, snapshot
from app.gui.mocap_link import install_mocap_picker
from app.gui.recording_session import RecordingSession, describe_recording
from app.gui.thread_bridge import ThreadBridge
from devices.factory import SIMULATED_TRUTH_NOTE, is_sim
from models.health import BAD_FLAGS, HealthMonitor, describe
from widgets.body_view import BodyView
from widgets.force_plots import ForcePlotGrid, TrialOverlayPlot
from widgets.forces_panel import ForcesControls, format_bytes, format_elapsed
from widgets.image_export import image_kind, save_widget_image
from widgets.ring_plot import TraceHistory, append_with_gaps

FORCE_HISTORY_BUDGET_BYTES = 96_000_000
RECORDING_VIEW_BUDGET_BYTES = 256_000_000
BODY_REFRESH_HZ = 10.0
STATUS_REFRESH_HZ = 2.0
CRC_STORM_PER_S = 5.0
SAID_AGAIN_AFTER_S = 10.0  # the same message said again within this goes to the message line, not the event log
OVERLAY, BODY_MAP = -1, -2  # image export targets besides the segment plots (0 …)
BODY_FORCE_STEP_N = 0.1  # forces compared at this resolution (3 % of the colour ramp) to skip body-map redraws
ONSET_FRACTION = 0.1
BODY_FULL_SCALE_N = 3.0  # darkest sensor colour; one segment's share of the robot's weight is ≈ 2 N

# An export's save dialog asks before it replaces a file; asked for without the dialog, an export keeps one.
_CONFIRM_REPLACE = "choose a new name (a file is replaced only when you confirm it in the save dialog)"


@contextmanager
def busy_cursor() -> Iterator[None]:
    """Wait cursor around a file read or write done on the GUI thread (an hour-long recording takes seconds).

    GUI thread only.
    """
    QApplication.setOverrideCursor(QCursor(Qt.CursorShape.WaitCursor))
    try:
        yield
    finally:
        QApplication.restoreOverrideCursor()


def recordings_dir() -> Path:
    """Where recordings go by default: ``recordings/`` in the one user data folder (:mod:`app.core.user_folders`)."""
    return user_folders.recordings_dir()


def default_recording_path(now: datetime | None = None) -> Path:
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    return recordings_dir() / f"forces-{stamp}.h5"


def onset_time_s(t_s: np.ndarray, values: np.ndarray, fraction: float = ONSET_FRACTION) -> float:
    """First time the trace rises by ``fraction`` of its range above its starting level (load onset)."""
    values = np.asarray(values, dtype=float)
    finite = np.isfinite(values)
    if not finite.any():
        return float(t_s[0]) if t_s.size else 0.0
    start = float(values[finite][0])
    peak = float(np.nanmax(values))
    if peak <= start:
        return float(t_s[0])
    above = np.flatnonzero(finite & (values >= start + fraction * (peak - start)))
    return float(t_s[above[0]]) if above.size else float(t_s[0])


class ForcesTab(QWidget):
    """The tab; ``create_tab(lab)`` builds one."""

    calibration_applied = Signal(str)  # a calibration (its file) or estimator is in force, the history re-estimated

    def __init__(self, lab: Any, parent: QWidget | None = None, plots_in_steps: bool = False) -> None:
        """``plots_in_steps``: the body map and the segment plots are built later, one a step
        (:func:`create_tab_in_steps`)."""
        super().__init__(parent)
        self.lab = lab
        self._said: tuple[str, str, float] | None = None  # the last message said (text, level, when)
        # A calibration or estimator being applied: the history is estimated again on a worker thread
        # (app/gui/forces_history.py); until it is done the live view goes on with the one in force.
        self._reestimation: Reestimation | None = None
        self._bridge = ThreadBridge(self)
        config = lab.config
        saved = getattr(lab, "calibration_saved", None)
        if saved is not None:  # a calibration saved by the Calibration tab is used here at once
            saved.connect(self.load_calibration)
        self.board = lab.board
        self.channel_names = tuple(config.board.channel_names)
        n_channels = len(self.channel_names)
        self.pipeline = ForcesPipeline(self.channel_names)
        self.force_history = TraceHistory.for_budget(n_channels, FORCE_HISTORY_BUDGET_BYTES)
        self.health = HealthMonitor(n_channels, config.board.rate_hz)
        # The data path (pipeline → health → recording) is the core's, the same one ``sensnake record`` runs; this
        # tab subscribes to it and draws.
        self.live = LiveSession(config.board, pipeline=self.pipeline, health=self.health,
                                t0_monotonic_s=self.board.t0_monotonic_s if self.board is not None else None,
                                force_page=getattr(lab, "force_page", None))
        self.live.subscribe(self._draw_update)
        self._backfill()
        self.quantity = "force"
        self.session: RecordingSession | None = None
        self.viewed: Recording | None = None
        self.overlay_recordings: list[Recording] = []
        self.overlay_zero_s: dict[Path, float] = {}  # each overlaid recording's time zero (its clock), by path
        self._last_stats: Any = None
        self._last_stats_s = time.monotonic()
        self._body_key: tuple | None = None
        self._replay_cursor_s: float | None = None  # replay time under the cursor
        self._warnings: list[str] = [""] * n_channels
        self.min_free_bytes = DEFAULT_MIN_FREE_BYTES  # a recording stops cleanly before the disk is this full
        self.last_recording_path: Path | None = None  # Open recording… starts here: reopening is one click
        self._replace_confirmed: Path | None = None  # an existing file the Record to… dialog confirmed replacing
        self._overlay_sensor_chosen = False
        self._planned_s: float | None = None  # length of a timed recording (s)  # until the user picks one, the overlay shows the liveliest sensor

        self.controls = ForcesControls(self)
        self.plots = ForcePlotGrid(self.channel_names, parent=self, build_plots=not plots_in_steps)
        self.overlay = TrialOverlayPlot(self)
        self.body: BodyView | None = None
        self._has_body_map = n_channels == 3 * config.robot.n_joints
        self._build_layout()
        if not plots_in_steps:
            self.build_body_map()
        self._connect()
        self.mocap_picker = install_mocap_picker(self)  # beside Record: the motion capture recorded with the forces
        self._apply_calibration_labels()
        self.controls.path.setText(str(default_recording_path()))
        self._show_live()
        if self.health.report is not None:  # what the backfilled past already showed about the sensors
            self._apply_health(np.arange(n_channels))

        self._body_timer = QTimer(self)
        self._body_timer.setInterval(int(1000 / BODY_REFRESH_HZ))
        self._body_timer.timeout.connect(self.refresh_body)
        self._status_timer = QTimer(self)
        self._status_timer.setInterval(int(1000 / STATUS_REFRESH_HZ))
        self._status_timer.timeout.connect(self._refresh_status)
        self._auto_stop_timer = QTimer(self)  # a timed recording (the duration box) stops itself
        self._auto_stop_timer.setSingleShot(True)
        self._auto_stop_timer.timeout.connect(self.stop_recording)
        self._body_timer.start()
        self._status_timer.start()
        self.plots.start()
        if self.board is None:
            reason = getattr(lab, "board_unavailable_reason", "") or "no board bridge"
            self.controls.set_board_status(f"board: {reason}", "error")
        else:
            self._on_board_connected(self.board.is_connected)

    def say(self, text: str, level: str = "warn") -> None:
        """Show ``text`` on the tab's message line and put it in the event log (a fault when ``level`` is
        "error", a warning when "warn", information otherwise)."""
        self.controls.set_message(text, level)
        log = getattr(self.lab, "event_log", None)
        now = time.monotonic()
        said, self._said = self._said, (text, level, now)
        if said is not None and said[:2] == (text, level) and now - said[2] < SAID_AGAIN_AFTER_S:
            return  # the same words again (each re-estimation pass says how it ended): logged once
        if log is not None and text:
            log.add({"error": "fault", "warn": "warning"}.get(level, "info"), text, "Forces")

    # -- layout ----------------------------------------------------------------------------------------------------
    def _build_layout(self) -> None:
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addWidget(self.controls)
        splitter = QSplitter(Qt.Orientation.Horizontal, self)
        self.views = QTabWidget(splitter)
        self.views.addTab(self.plots, "Segments")
        overlay_page = QWidget(self.views)
        overlay_layout = QVBoxLayout(overlay_page)
        overlay_bar = QHBoxLayout()
        overlay_bar.addWidget(QLabel("Sensor"))
        self.overlay_sensor = QComboBox(overlay_page)
        self.overlay_sensor.addItems(self.channel_names)
        overlay_bar.addWidget(self.overlay_sensor)
        overlay_bar.addWidget(QLabel("Time zero"))
        self.overlay_align = QComboBox(overlay_page)
        self.overlay_align.addItem("load onset", "onset")
        self.overlay_align.addItem("recording start", "start")
        overlay_bar.addWidget(self.overlay_align)
        self.overlay_clear = QPushButton("Clear", overlay_page)
        overlay_bar.addWidget(self.overlay_clear)
        self.overlay_image = QToolButton(overlay_page)
        self.overlay_image.setText("Image…")
        self.overlay_image.setToolTip("Save the trial overlay as an image: PNG, or SVG (vector)")
        self.overlay_image.setPopupMode(QToolButton.ToolButtonPopupMode.InstantPopup)
        overlay_menu = QMenu(self.overlay_image)
        for kind in ("png", "svg"):
            overlay_menu.addAction(f"Save as {kind.upper()}…", partial(self._choose_image, OVERLAY, kind))
        self.overlay_image.setMenu(overlay_menu)
        overlay_bar.addWidget(self.overlay_image)
        overlay_bar.addStretch(1)
        overlay_layout.addLayout(overlay_bar)
        overlay_layout.addWidget(self.overlay, 1)
        self.views.addTab(overlay_page, "Trial overlay")
        side = QWidget(splitter)
        side_layout = QVBoxLayout(side)
        side_layout.setContentsMargins(2, 0, 2, 0)
        if self._has_body_map:  # its place; the map itself is built by build_body_map (~20-40 ms of the GUI thread)
            self._body_place = QVBoxLayout()
            self._body_place.setContentsMargins(0, 0, 0, 0)
            side_layout.addLayout(self._body_place, 3)
        else:
            side_layout.addWidget(QLabel("Body map needs widgets/body_view.py and 3 sensors per joint"))
        health_bar = QHBoxLayout()
        health_bar.addWidget(QLabel("Sensor health"))
        health_bar.addStretch(1)
        self.baseline_button = QPushButton("Set rest baseline", side)
        self.baseline_button.setToolTip("Take the present readings as each sensor's resting level: later readings "
                                        "well below it are flagged as drift, and a resting sensor that goes open "
                                        "as disconnected")
        health_bar.addWidget(self.baseline_button)
        self.body_image = None
        if self._has_body_map:
            self.body_image = QToolButton(side)
            self.body_image.setText("Map image…")
            self.body_image.setToolTip("Save the body force map as an image: PNG, or SVG (vector)")
            self.body_image.setPopupMode(QToolButton.ToolButtonPopupMode.InstantPopup)
            body_menu = QMenu(self.body_image)
            for kind in ("png", "svg"):
                body_menu.addAction(f"Save as {kind.upper()}…", partial(self._choose_image, BODY_MAP, kind))
            self.body_image.setMenu(body_menu)
            health_bar.insertWidget(1, self.body_image)
        side_layout.addLayout(health_bar)
        self.health_list = QListWidget(side)
        self.health_list.setMaximumHeight(140)
        self.health_list.addItem("no sensor problems seen (yet)")
        side_layout.addWidget(self.health_list, 1)
        splitter.addWidget(self.views)
        splitter.addWidget(side)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([900, 330])
        layout.addWidget(splitter, 1)

    def build_body_map(self) -> BodyView | None:
        """The body force map, built now if it was not (None when this lab's sensors do not map onto its body)."""
        if self.body is None and self._has_body_map:
            robot = self.lab.config.robot
            self.body = BodyView(robot.axes, robot.segment_length_m, self)
            self._body_place.addWidget(self.body)
            self._body_key = None  # drawn at the next refresh
        return self.body

    def _connect(self) -> None:
        c = self.controls
        c.window_changed.connect(self.plots.set_window_s)
        c.pause_toggled.connect(self.plots.set_paused)
        self.plots.paused_changed.connect(c.set_paused)
        self.plots.cursor_moved.connect(self._on_cursor_moved)
        self.plots.image_requested.connect(self._choose_image)
        c.side_toggled.connect(self.plots.set_side_visible)
        c.quantity_changed.connect(self.set_quantity)
        c.estimator_changed.connect(self.set_estimator)
        c.record_toggled.connect(self._on_record_toggled)
        c.browse_requested.connect(self._browse_recording_path)
        c.load_calibration_requested.connect(self._choose_calibration)
        c.truth_calibration_requested.connect(self.load_simulated_truth)
        c.truth_calibration.setVisible(callable(getattr(self.lab, "simulated_sensors_calibration", None))
                                       and is_sim(self.lab.config.board.port))
        c.open_requested.connect(self._choose_recording)
        c.overlay_requested.connect(self._choose_overlay)
        c.export_requested.connect(self._choose_export)
        c.live_requested.connect(self.show_live)
        self.overlay_sensor.currentIndexChanged.connect(lambda _i: self.redraw_overlay())
        self.overlay_sensor.activated.connect(self._overlay_sensor_picked)
        self.overlay_align.currentIndexChanged.connect(lambda _i: self.redraw_overlay())
        self.overlay_clear.clicked.connect(self.clear_overlay)
        self.baseline_button.clicked.connect(self.set_rest_baseline)
        if self.board is not None:
            self.board.block.connect(self.on_block)
            self.board.status.connect(self._on_board_message)
            self.board.connected.connect(self._on_board_connected)
            self.board.board_status.connect(self._on_board_status)
            self.board.stats_changed.connect(self._on_stats)
        robot = getattr(self.lab, "robot", None)
        if robot is not None and hasattr(robot, "state_block"):
            robot.state_block.connect(self._on_robot_states)
        changed = getattr(self.lab, "recording_changed", None)
        if changed is not None:  # a trial of the Trials dock records this data: Record shows it is on
            changed.connect(self._on_lab_recording)
            self._on_lab_recording(getattr(self.lab, "recording", None))

    # -- live data -------------------------------------------------------------------------------------------------
    def _backfill(self, health: bool = True) -> None:
        """Start with the recent past: the blocks the board delivered before this tab was built (it is built when
        first shown) go through the same estimator (and, with ``health``, health monitor) as live ones, so the plots
        open full, not empty. Nothing is recorded or sent to the controller from them: they are history."""
        recent = getattr(self.board, "recent_blocks", None)
        # One block of the whole past, not one call per block: ~1 ms a call, 600-1800 blocks a minute.
        block = joined(recent()) if recent is not None else None
        if block is not None:
            forces = self.pipeline.process(block.board_time_s, block.conductance_s, block.saturated)
            if health:
                self.health.update(self.live.session_time_s(block.host_time_s), block.conductance_s,
                                   block.saturated)
            if forces is not None:
                append_with_gaps(self.force_history, self.live.session_time_s(block.host_time_s), forces.display,
                                 block.gap_before)

    def on_block(self, block: Any) -> None:
        """A board block (GUI thread, ≤ 60 Hz): through the core's live session (estimate, classify, record)."""
        self.live.process_block(block)
        if self._reestimation is not None:
            self._reestimation.pending.append(block)  # for the calibration being applied, once its past is done

    def _draw_update(self, update: LiveUpdate) -> None:
        """The live session's subscriber: keep the forces for the plots and show health changes (GUI thread)."""
        block = update.block
        if update.problem:
            self.say(update.problem, "warn")
        if update.forces is not None:
            append_with_gaps(self.force_history, self.live.session_time_s(block.host_time_s), update.forces.display,
                             block.gap_before)
        if self.viewed is None:
            self.plots.data_arrived()  # drawn as it arrives (conductance too: the board's history has it already)
        if update.health_changed.size:
            self._apply_health(update.health_changed)

    def _on_robot_states(self, states: Any) -> None:
        self.live.add_robot_states(states)

    def _apply_health(self, changed: np.ndarray) -> None:
        flags = self.health.flags
        for i in changed:
            word = describe(int(flags[i])) if flags[i] else ""
            self._warnings[i] = word
        self.plots.set_channel_warnings(self._warnings)
        self.health_list.clear()
        bad = [(self.channel_names[i], w) for i, w in enumerate(self._warnings) if w]
        self.health_list.addItems([f"{name}: {word}" for name, word in bad] or ["all sensors look healthy"])
        self._body_key = None

    def set_rest_baseline(self) -> None:
        """Use the present window's median conductance as every sensor's resting level (the robot at rest)."""
        report = self.health.report
        if report is None:
            self.say("no data yet to take a baseline from: wait until the board status above "
                                      "says it is connected and readings arrive", "warn")
            return
        self.health.set_baseline(report.level_s)
        self.say("rest baseline set from the last readings", "ok")

    def refresh_body(self) -> None:
        """Redraw the body map if the shape, the forces or the health changed (timer, ≤ 10 Hz). Live it shows the
        robot and the newest forces; with a recording shown, the recorded joints and forces at the replay time."""
        if self.body is None or not self.isVisible():
            return
        if self.viewed is not None:
            angles, forces = self.recorded_body(self.replay_time_s())
            flags = np.zeros(len(self.channel_names), dtype=np.uint8)  # the live health says nothing about it
        else:
            robot = getattr(self.lab, "robot", None)
            state = getattr(robot, "latest_state", None) if robot is not None else None
            angles = None if state is None else np.asarray(state.position_rad, dtype=float)
            latest = self.force_history.latest()
            forces = None
            if latest is not None and self.quantity == "force":
                # A sensor without a force (uncalibrated, or a rejected sample) is NaN: drawn "no estimate", never
                # as 0 N.
                forces = np.where(self.pipeline.estimated, latest[1].astype(float), np.nan)
            flags = self.health.flags
        key = (None if angles is None else np.round(angles, 3).tobytes(),
               None if forces is None else np.round(forces / BODY_FORCE_STEP_N).tobytes(), flags.tobytes())
        if key == self._body_key:
            return
        self._body_key = key
        self.body.set_angles(angles)
        self.body.set_sensor_forces(forces, (flags & np.uint8(BAD_FLAGS)) != 0 if forces is not None else None,
                                    full_scale_n=BODY_FULL_SCALE_N)

    def replay_time_s(self) -> float:
        """The time of the recording shown that the body map draws: under the cursor while it is over a plot,
        otherwise the right-hand edge of the plots' view (the newest sample shown)."""
        if self._replay_cursor_s is not None:
            return self._replay_cursor_s
        return self.plots.visible_range()[1]

    def recorded_body(self, t_s: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(joint angles rad, sensor forces N) of the recording shown at ``t_s``: its newest robot sample and board
        row at or before ``t_s``. Angles None when the recording has no robot (the map is then drawn straight);
        forces None when it holds no forces or conductance is plotted; a sensor without a force is drawn at 0."""
        recording = self.viewed
        if recording is None:
            return None, None
        angles = None
        robot = recording.robot
        if robot is not None and robot.time_s.size:
            i = int(np.searchsorted(robot.time_s, t_s, side="right")) - 1
            angles = np.asarray(robot.present_rad[max(i, 0)], dtype=float)
        forces = None
        in_newtons = recording.force_channels
        if self.quantity == "force" and recording.forces_n is not None and in_newtons.any() and recording.n_samples:
            n = min(recording.forces_n.shape[0], recording.n_samples)
            i = int(np.searchsorted(recording.time_s[:n], t_s, side="right")) - 1
            # A channel without a force (uncalibrated when recorded, a rejected sample) is NaN: drawn hollow.
            forces = np.full(len(self.channel_names), np.nan)
            row = np.asarray(recording.forces_n[max(i, 0)], dtype=float)
            columns = min(row.size, forces.size)
            forces[:columns] = np.where(in_newtons[:columns], row[:columns], np.nan)
        return angles, forces

    def _on_cursor_moved(self, t_s: float) -> None:
        if self.viewed is not None:
            self._replay_cursor_s = t_s
            self.refresh_body()

    def put_cursor(self, t_s: float | None) -> None:
        """Another view's time cursor on the recording shown here (the Plots dock's): the plots' cursor line and the
        body map go to ``t_s``; the mouse over a plot moves it on (``plots.cursor_s``). None: the shared cursor off."""
        self.plots.set_cursor(t_s if self.viewed is not None else None)
        if self.viewed is not None and t_s is not None:
            self._on_cursor_moved(t_s)

    # -- view options ----------------------------------------------------------------------------------------------
    def set_quantity(self, quantity: str) -> None:
        """``force`` (N; uncalibrated sensors in µS, labelled) or ``conductance`` (µS, raw)."""
        self.quantity = quantity
        if self.viewed is not None:
            self._show_recording(self.viewed)
        else:
            self._show_live()
        self._body_key = None

    def set_estimator(self, kind: str) -> None:
        """``sls`` or ``linear``: applied once the history is estimated again with it (:meth:`_reestimate_history`)."""
        self._reestimate_history(self._wanted_pipeline().fresh_copy(kind))

    @property
    def is_loading_calibration(self) -> bool:
        """A calibration or estimator is being applied (its history estimated on a worker thread)."""
        return self._reestimation is not None

    def _wanted_pipeline(self) -> ForcesPipeline:
        """The pipeline being applied, else the one in force: what the next change starts from."""
        return self._reestimation.pipeline if self._reestimation is not None else self.pipeline

    def _reestimate_history(self, pipeline: ForcesPipeline, note: str = "") -> None:
        """A new calibration or estimator (``pipeline``, a fresh copy holding it): the force history so far was in
        the old units (a sensor's µS before it was calibrated would be drawn on its new N axis) and the creep-aware
        estimate of now needs the sensor's past. The whole history the board holds at full rate is estimated again
        with it on a worker thread (app/gui/forces_history.py); then it is in force (:meth:`_reestimated`). A
        change asked for meanwhile replaces this one."""
        if self._reestimation is not None:
            self._reestimation.cancel()
        source = snapshot(self.board, 1.0 / self.lab.config.board.r_c_ohm)
        job = Reestimation(pipeline, source, FORCE_HISTORY_BUDGET_BYTES, note, post=self._bridge.post)
        self._reestimation = job
        self._apply_calibration_labels()
        job.start(lambda done: self._bridge.post(self._reestimated, done))

    def _reestimated(self, job: Reestimation) -> None:
        """GUI thread: the worker is done; catch up with the blocks that came meanwhile and switch over."""
        if job is not self._reestimation:
            return  # replaced by a later change
        self._reestimation = None
        history = job.finish(self.live.session_time_s)
        self.pipeline.adopt(job.pipeline)
        self.force_history = history
        if self.quantity == "force" and self.viewed is None:
            self.plots.set_history(history)
        self._apply_calibration_labels()
        self._body_key = None
        source = job.source
        older = (f"; {format_elapsed(source.older_s)} older kept only as conductance in the board's history"
                 if source is not None and source.older_s > 1.0 else "")
        problems = "; ".join([job.error, *self.pipeline.problems]).strip("; ")
        span = format_elapsed(source.span_s) if source is not None else "no"
        if problems:
            self.say(f"{job.note or self.pipeline.summary()[0]} — {problems}", "warn")
        else:
            self.say(job.note or f"{self.pipeline.summary()[0]} ({self.pipeline.estimator_kind}); {span} of "
                     f"history estimated again{older}", "warn" if job.note else "ok")
        self.calibration_applied.emit(self.pipeline.calibration_source)

    def load_calibration(self, path: str | os.PathLike, note: str = "") -> bool:
        """Load a calibration JSON: read and checked here, then in force once the history is estimated again with
        it (:attr:`is_loading_calibration` until then; ``calibration_applied`` follows, and the tab says ``note``
        or what was done). A bad file leaves the current one and says why. Returns whether the file is usable."""
        candidate = self._wanted_pipeline().fresh_copy()
        try:
            candidate.load_calibration(path)
        except (OSError, ValueError) as exc:
            self.say(f"calibration not loaded: {exc}", "error")
            return False
        self._reestimate_history(candidate, note)
        return True

    def _apply_calibration_labels(self) -> None:
        text, level = self.pipeline.summary()
        if self._reestimation is not None:
            wanted = self._reestimation.pipeline
            source = self._reestimation.source
            span = f" {format_elapsed(source.span_s)} of" if source is not None else ""
            text = (f"applying {os.path.basename(wanted.calibration_source) or 'no calibration'} "
                    f"({wanted.estimator_kind}): estimating{span} history again… (until then: {text})")
            level = "warn"
        self.controls.set_calibration(text, level, NO_CALIBRATION_HINT if self.pipeline.calibration is None else "")
        self.plots.set_channel_notes([f"{status} ({self.pipeline.estimator_kind})" if status != "uncalibrated"
                                      else "uncalibrated: shown as conductance (µS)"
                                      for status in self.pipeline.status])
        if self.quantity == "force" and self.viewed is None:
            self.plots.set_channel_labels([self.pipeline.label(i) for i in range(len(self.channel_names))])
            # An uncalibrated sensor's µS go on each plot's own right-hand axis, never on the axis labelled N; with
            # no sensor calibrated there is no N axis at all.
            units = ["µS" if status == UNCALIBRATED else "N" for status in self.pipeline.status]
            plot_units = "N" if "N" in units else "µS"
            if self.plots.units != plot_units:
                self.plots.set_units(plot_units)
            self.plots.set_channel_units(units if plot_units == "N" else None)
        else:
            self.plots.set_channel_labels(list(self.channel_names))
            self.plots.set_channel_units(None)

    def _show_live(self) -> None:
        if self.quantity == "force":
            self.plots.set_history(self.force_history)  # N, or µS with no sensor calibrated: set just below
        else:
            self.plots.set_history(self.board.history if self.board is not None else None, "µS")
        self._apply_calibration_labels()

    def show_live(self) -> None:
        """Back from a past recording to the live board."""
        self.viewed = None
        self._replay_cursor_s = None
        self.plots.set_cursor(None)
        self._body_key = None
        self.controls.set_viewing_file(None)
        self.say("")
        self._show_live()
        self.plots.set_paused(False)

    # -- recording -------------------------------------------------------------------------------------------------
    def start_recording(self, path: str | os.PathLike | None = None,
                        duration_s: float | None = None) -> RecordingSession | None:
        """Start recording to ``path`` (default: the path field) for ``duration_s`` seconds (default: the duration
        box; None records until stopped). Returns the session or None if refused."""
        if self.session is not None and self.session.is_active:
            return self.session
        other = self.live.recorder
        if other is not None and other.running:  # a trial's recording: never a second one of the same data
            self.say(f"not recorded: {describe_recording(other)[1]}; Record is free again when it ends", "warn")
            self.controls.set_recording(False, "not recording")
            return None
        path = Path(path or self.controls.path.text().strip() or default_recording_path())
        if path.suffix.lower() not in (".h5", ".hdf5"):
            path = path.with_suffix(".h5")
        if os.path.lexists(path) and path != self._replace_confirmed:  # typed, not confirmed in the … dialog
            self.say(f"not recorded: {path} exists and is kept; type another name, or pick it with … beside the "
                     "name to replace it", "warn")
            self.controls.set_recording(False, "not recording")
            return None
        self._replace_confirmed = None  # confirmed for this recording only
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            self.say(f"cannot create folder {path.parent}: {exc.strerror or exc}; choose another "
                                      "place with … beside the file name", "error")
            self.controls.set_recording(False, "not recording")
            return None
        robot = getattr(self.lab, "robot", None)
        with_robot = bool(robot is not None and getattr(robot, "is_connected", False))
        session = RecordingSession(path, self.lab.config.source_text, self.channel_names,
                                   calibration_json=self.live.recording_calibration_json(), with_robot=with_robot,
                                   n_joints=self.lab.config.robot.n_joints, min_free_bytes=self.min_free_bytes,
                                   mocap=getattr(self.lab, "mocap", None), parent=self)
        session.failed.connect(self._on_recording_failed)
        session.stopped.connect(self._on_recording_stopped)
        self.session = session
        session.start()
        if self.board is not None and not self.board.is_connected and self.live.last_status is None:
            self.live.handle_status(self.board.last_status)
        self.live.attach_recorder(session.recorder)
        self.lab.recording = session
        self.controls.path.setText(str(path))
        self.controls.set_recording(True, "recording…")
        duration_s = self.controls.duration_s if duration_s is None else duration_s
        self._planned_s = duration_s
        if duration_s:
            self._auto_stop_timer.start(int(round(duration_s * 1000)))
        return session

    def stop_recording(self) -> None:
        self._auto_stop_timer.stop()
        session = self.session
        if session is not None:
            session.stop()

    def _on_lab_recording(self, recording: Any) -> None:
        """The lab's recording changed: one this tab did not start (a trial's) disables Record, naming it."""
        other = recording is not None and recording is not self.session
        self.controls.set_recording_elsewhere(*(describe_recording(recording) if other else (None, "")))

    def _on_record_toggled(self, start: bool) -> None:
        if start:
            self.start_recording()
        else:
            self.stop_recording()

    def _on_recording_failed(self, message: str) -> None:
        self.say(message, "error")

    def _on_recording_stopped(self, summary: str) -> None:
        session = self.session
        self.controls.set_recording(False, "not recording")
        if session is not None and session.error:
            self.say(session.error + f" (kept: {session.path})", "error")
        else:
            self.say(f"{summary} · Open recording… shows it", "ok")
        if self.lab.recording is session:
            self.lab.recording = None
        if session is not None:
            self.last_recording_path = Path(session.path)
        self.controls.path.setText(str(default_recording_path()))

    # -- board status ----------------------------------------------------------------------------------------------
    def _on_board_message(self, text: str) -> None:
        level = "ok" if self.board is not None and self.board.is_connected else "warn"
        self.controls.set_board_status(text, level)

    def _on_board_connected(self, connected: bool) -> None:
        if connected:
            self.controls.set_board_status(f"board: {len(self.channel_names)} channels on "
                                           f"{self.lab.config.board.port}", "ok")

    def _on_board_status(self, status: Any) -> None:
        self.live.handle_status(status)  # gaps, reconnects and segments go into the recording there
        if status.state == "reconnected" and self._reestimation is not None:
            self._reestimation.pending.append(RESET)  # the pipeline being applied restarts there too
        if status.state == "stall":  # an event: the board goes on; said once, and logged in a recording
            self.say(status.message, "warn")
            return
        level = {"connected": "ok", "reconnected": "ok", "closed": "idle"}.get(status.state, "error")
        self.controls.set_board_status(status.message, level)
        if status.state in ("disconnected", "mismatch", "error"):
            self.say(status.message, "error")
        elif status.state == "reconnected":
            self.say(f"{status.message} (plots and recording)", "warn")

    def _on_stats(self, stats: Any) -> None:
        warning = self.live.handle_stats(stats)  # counted into the recording; never stops it
        now = time.monotonic()
        previous, self._last_stats = self._last_stats, stats
        elapsed = max(now - self._last_stats_s, 1e-3)
        self._last_stats_s = now
        crc_rate = 0.0 if previous is None else (stats.crc_errors - previous.crc_errors) / elapsed
        simulated = is_sim(self.lab.config.board.port)
        # The simulated lab throws away frames the app did not read within a quarter second (as a closed port's
        # adapter does), e.g. while the app starts: an expected gap of the simulation, not a link losing frames.
        dropped = (f"skipped frames {stats.dropped_frames} (simulated lab: read late)" if simulated
                   else f"lost frames {stats.dropped_frames}")
        text = f"CRC {stats.crc_errors} · resync {stats.resyncs} · {dropped} · reconnects {stats.reconnects}"
        if getattr(stats, "out_of_range_frames", 0):
            text += f" · out of range {stats.out_of_range_frames}"
        since = getattr(stats, "disconnected_since_s", None)
        if since is not None:
            text += f" · BOARD MISSING {now - since:.0f} s"
        level = self.live.link.level
        if simulated and level == "warn" and not stats.crc_errors:
            level = "ok"  # only skipped frames: nothing to act on
        if crc_rate > CRC_STORM_PER_S:
            level = "error"
            text += f" — CRC storm ({crc_rate:.0f}/s): check the board cable and baud rate"
        elif since is not None:
            level = "error"
        self.controls.set_counters(text, level)
        if warning:
            self.say(warning, "error")

    def _refresh_status(self) -> None:
        session = self.session
        if session is not None and session.is_active:
            backlog = f" · queue {session.backlog}" if session.backlog > 50 else ""
            planned = f" / {format_elapsed(self._planned_s)}" if self._planned_s else ""
            self.controls.set_recording(True, f"{format_elapsed(session.elapsed_s)}{planned} · "
                                              f"{format_bytes(session.size_bytes())}{backlog}")

    # -- past recordings -------------------------------------------------------------------------------------------
    def open_recording_file(self, path: str | os.PathLike) -> Recording | None:
        """Show a recording in the plots (paused, whole length); None and a message if it cannot be read."""
        try:
            with busy_cursor():
                recording = open_recording(Path(path), recover=True)
        except (OSError, ValueError) as exc:
            self.say(f"cannot open recording: {exc}", "error")
            return None
        if recording.channels != self.channel_names:
            self.say(
                f"{Path(path).name} has {len(recording.channels)} channels "
                f"({', '.join(recording.channels[:3])}…), this lab {len(self.channel_names)}: open it with the "
                "matching config", "error")
            return None
        self.viewed = recording
        log = getattr(self.lab, "event_log", None)
        if log is not None:  # the recording's own /events (gaps, health, link warnings) join the event log
            log.add("action", f"open recording {path}", "Forces")
            log.add_recorded(recording.path, recording.started, recording.events)
        self._replay_cursor_s = None
        self.plots.set_cursor(None)
        self._body_key = None
        with busy_cursor():
            self._show_recording(recording)
        self.controls.set_viewing_file(Path(path).name)
        gaps = len(recording.gaps)
        if recording.recovery:
            self.say(f"{recording.recovery} — showing what survives; 'sensnake repair' writes a "
                                      "clean copy", "warn")
        elif recording.forces_from_defaults:
            self.say(f"{Path(path).name}: its forces were estimated without a calibration "
                                      "(typical-sensor defaults of an older version): shown as conductance (µS)", "warn")
        elif gaps:
            self.say(f"showing {Path(path).name}: {gaps} gap(s) marked", "warn")
        return recording

    def _show_recording(self, recording: Recording) -> None:
        values, units = self._recording_values(recording)
        n_channels = len(self.channel_names)
        if recording.n_samples * n_channels * 4 * 2.5 <= RECORDING_VIEW_BUDGET_BYTES:
            history = TraceHistory(n_channels, max(16, recording.n_samples))  # every sample at full resolution
        else:  # a long, wide recording: the newest part at full rate, the rest as min/max buckets
            history = TraceHistory.for_budget(n_channels, RECORDING_VIEW_BUDGET_BYTES)
        if recording.n_samples:
            history.append(recording.time_s, values)
        self.plots.set_history(history, "N" if "N" in units else "µS")
        # As live: a channel without forces (uncalibrated when recorded) is µS on each plot's right-hand axis,
        # labelled, never on the axis labelled N.
        self.plots.set_channel_units(units if "N" in units else None)
        self.plots.set_channel_labels([name if unit == "N" or "N" not in units else f"{name} (µS, uncal.)"
                                       for name, unit in zip(self.channel_names, units)])
        if recording.n_samples:
            self.plots.show_range(float(recording.time_s[0]), float(recording.time_s[-1]))

    def _recording_values(self, recording: Recording) -> tuple[np.ndarray, list[str]]:
        """The values shown for ``recording`` and each channel's unit: with Force (N), the stored forces of the
        channels that have them (a rejected sample stays a gap, NaN), conductance (µS) for the others."""
        conductance_us = np.asarray(recording.conductance_s, dtype=float) * 1e6
        in_newtons = recording.force_channels if self.quantity == "force" else np.zeros(len(recording.channels), bool)
        if recording.forces_n is None or not in_newtons.any():
            return conductance_us, ["µS"] * len(self.channel_names)
        n = min(recording.forces_n.shape[0], recording.n_samples)
        values = np.array(conductance_us)
        values[:, in_newtons] = np.nan
        values[:n, in_newtons] = np.asarray(recording.forces_n[:n], dtype=float)[:, in_newtons]
        return values, ["N" if in_newtons[c] else "µS" for c in range(len(self.channel_names))]

    def export_viewed_csv(self, out: str | os.PathLike, visible_only: bool = False,
                          replace: bool = False) -> Path | None:
        """The recording shown to CSV (app.core.view_export: units in the header, the robot beside the forces), all
        of it or only the time range the plots show; a file there is replaced only when ``replace`` (the user
        confirmed it in the save dialog). None and a message when it cannot be written."""
        if self.viewed is None:
            self.say("open a recording first, then export it", "warn")
            return None
        t0, t1 = self.plots.visible_range() if visible_only else (None, None)
        try:
            if not replace:
                check_new_file(out, _CONFIRM_REPLACE)
            with busy_cursor():
                written, rows = export_view_csv(self.viewed, Path(out), t0, t1, list(self.lab.config.robot.joint_ids))
        except (OSError, ValueError) as exc:
            self.say(f"not exported: {getattr(exc, 'strerror', None) or exc}", "error")
            return None
        span = f" ({t0:.1f}–{t1:.1f} s)" if visible_only else ""
        self.say(f"exported {rows} rows{span} to {written}", "ok")
        return written

    def add_overlay_files(self, paths: Sequence[str | os.PathLike]) -> int:
        """Add recordings to the trial overlay; returns how many were added."""
        added = 0
        for path in paths:
            try:
                with busy_cursor():
                    recording = open_recording(Path(path))
            except (OSError, ValueError) as exc:
                self.say(f"cannot open {path}: {exc}", "error")
                continue
            self.overlay_recordings.append(recording)
            added += 1
        if added and not self._overlay_sensor_chosen:
            self._select_liveliest_overlay_sensor()
        self.views.setCurrentIndex(1)
        self.redraw_overlay()
        return added

    def _overlay_sensor_picked(self, _index: int) -> None:
        self._overlay_sensor_chosen = True

    def _select_liveliest_overlay_sensor(self) -> None:
        """Show the sensor whose load changes most in the first overlaid recording (not S01L, often at rest or
        flat-lined), so the overlay says something before the user picks a sensor."""
        recording = self.overlay_recordings[0]
        if recording.n_samples < 2:
            return
        values, _units = self._recording_values(recording)
        with np.errstate(all="ignore"):
            spread = np.nanmax(values, axis=0) - np.nanmin(values, axis=0)
        healthy = [i for i, name in enumerate(recording.channels)
                   if name in self.channel_names and not self._warnings[self.channel_names.index(name)]]
        candidates = [i for i in healthy if np.isfinite(spread[i])]
        if candidates:
            best = max(candidates, key=lambda i: spread[i])
            self.overlay_sensor.setCurrentText(recording.channels[best])

    def clear_overlay(self) -> None:
        self.overlay_recordings = []
        self.redraw_overlay()

    def redraw_overlay(self) -> None:
        name = self.overlay_sensor.currentText()
        align = self.overlay_align.currentData()
        picked = []
        for recording in self.overlay_recordings:
            if name not in recording.channels or recording.n_samples == 0:
                continue
            index = recording.channels.index(name)
            values, units = self._recording_values(recording)
            picked.append((recording, index, values[:, index], units[index]))
        # One axis, one unit: newtons only when every trial has this sensor's forces, else all in µS.
        unit = "N" if picked and all(u == "N" for *_rest, u in picked) else "µS"
        trials = []
        self.overlay_zero_s = {}
        for recording, index, trace, trace_unit in picked:
            if trace_unit != unit:
                trace = np.asarray(recording.conductance_s[:, index], dtype=float) * 1e6
            zero = onset_time_s(recording.time_s, trace) if align == "onset" else float(recording.time_s[0])
            self.overlay_zero_s[recording.path.resolve()] = zero
            trials.append((recording.path.stem, recording.time_s - zero, trace))
        self.overlay.set_trials(trials, unit)

    # -- dialogs ---------------------------------------------------------------------------------------------------
    def _browse_recording_path(self) -> None:
        folder = user_folders.dialog_folder(recordings_dir())
        path, _ = QFileDialog.getSaveFileName(self, "Record to", str(Path(folder) / default_recording_path().name),
                                              "Recordings (*.h5)")
        if path:
            self.controls.path.setText(path)
            self._replace_confirmed = Path(path)  # the dialog asked before naming an existing file

    def load_simulated_truth(self) -> bool:
        """The simulated lab's true calibration of every sensor, saved in the calibrations folder (a file already
        there with the same content is reused, another is never overwritten) and loaded, said to be the simulation's
        truth. Returns success."""
        document = self.lab.simulated_sensors_calibration()
        if document is None:
            self.say("the board is not simulated: calibrate its sensors on the rig", "error")
            return False
        text = json.dumps(document, indent=1)
        folder = user_folders.calibrations_dir()
        path = folder / "simulated-lab-truth.json"
        stamp = 1
        while path.exists() and path.read_text(errors="replace") != text:
            stamp += 1
            path = folder / f"simulated-lab-truth-{stamp}.json"
        if not path.exists():
            try:
                folder.mkdir(parents=True, exist_ok=True)
                write_atomically(path, lambda handle: handle.write(text))
            except (OSError, ValueError) as exc:
                self.say(f"simulated calibration not saved: {exc}", "error")
                return False
        note = f"{path.name}: {len(document['sensors'])} sensors, {SIMULATED_TRUTH_NOTE}"
        if not self.load_calibration(path, note):
            return False
        self.say(note, "warn")
        return True

    def _choose_calibration(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Calibration file",
                                              user_folders.dialog_folder(user_folders.calibrations_dir()),
                                              "Calibration (*.json)")
        if path:
            self.load_calibration(path)

    def _choose_recording(self) -> None:
        start = (str(self.last_recording_path) if self.last_recording_path is not None
                 else user_folders.dialog_folder(recordings_dir()))
        path, _ = QFileDialog.getOpenFileName(self, "Open recording", start, "Recordings (*.h5)")
        if path:
            self.open_recording_file(path)

    def _choose_overlay(self) -> None:
        paths, _ = QFileDialog.getOpenFileNames(self, "Recordings to overlay",
                                                user_folders.dialog_folder(recordings_dir()),
                                                "Recordings (*.h5)")
        if paths:
            self.add_overlay_files(paths)

    def _choose_export(self, visible_only: bool = False) -> None:
        if self.viewed is None:
            return
        stem = self.viewed.path.stem + ("-view" if visible_only else "")
        default = Path(user_folders.dialog_folder(self.viewed.path.parent)) / f"{stem}.csv"
        title = "Export the visible time range to CSV" if visible_only else "Export the recording to CSV"
        path, _ = QFileDialog.getSaveFileName(self, title, str(default), "CSV (*.csv)")
        if path:  # the dialog asked before offering a file that is there
            self.export_viewed_csv(path, visible_only, replace=True)

    def export_plot_image(self, index: int, path: str | os.PathLike, replace: bool = False) -> Path | None:
        """Save plot ``index`` (``OVERLAY``: the trial overlay, ``BODY_MAP``: the body force map) as a PNG or SVG
        image (by the suffix), whole or not at all; a file there is replaced only when ``replace`` (the user
        confirmed it in the save dialog). None and a message when it cannot be."""
        try:
            out = check_output(path)
            kind = image_kind(out)
            if not replace:
                check_new_file(out, _CONFIRM_REPLACE)
            if index == BODY_MAP:
                body = self.build_body_map()
                if body is None:
                    raise ValueError("this lab has no body map")
                when = (f"recording {self.viewed.path.name} at t = {self.replay_time_s():.2f} s"
                        if self.viewed is not None else "live")
                title = f"Body force map · {when} · full scale {BODY_FULL_SCALE_N:g} N"
                write_beside(out, lambda work: bool(save_widget_image(body, work, title, kind)))
            elif index < 0:
                title = f"Trial overlay · {self.overlay_sensor.currentText()} · {self.overlay_align.currentText()}"
                write_beside(out, lambda work: bool(save_widget_image(self.overlay.plot_widget, work, title, kind)))
            else:
                write_beside(out, lambda work: bool(self.plots.export_image(index, work, kind)))
        except (OSError, ValueError) as exc:
            self.say(f"image not saved: {getattr(exc, 'strerror', None) or exc}", "error")
            return None
        self.say(f"saved {out}", "ok")
        return out

    def _choose_image(self, index: int, kind: str) -> None:
        title = {BODY_MAP: "body-map", OVERLAY: "overlay"}.get(index) or self.plots.groups[index].title
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        default = Path(user_folders.dialog_folder(recordings_dir())) / f"{title}-{stamp}.{kind}"
        path, _ = QFileDialog.getSaveFileName(self, f"Save {title} as {kind.upper()}", str(default),
                                              f"{kind.upper()} image (*.{kind})")
        if path:
            # The dialog asked before offering a file that is there; a suffix added here names a file it never saw.
            confirmed = bool(Path(path).suffix)
            self.export_plot_image(index, path if confirmed else f"{path}.{kind}", replace=confirmed)

    # -- life cycle ------------------------------------------------------------------------------------------------
    def shutdown(self) -> None:
        """Stop timers, a re-estimation and the recording (joins their threads)."""
        job, self._reestimation = self._reestimation, None
        if job is not None:
            job.cancel()
            job.join()
        self.plots.stop()
        self._body_timer.stop()
        self._status_timer.stop()
        self.stop_recording()

    def closeEvent(self, event: QCloseEvent) -> None:  # noqa: N802 - Qt override
        self.shutdown()
        super().closeEvent(event)


def create_tab(lab: Any) -> QWidget:
    """The main window's entry point (``app/gui/tabs/<name>.py`` contract)."""
    # LabContext.close() stops lab.recording, so a running recording is closed cleanly with the window.
    return ForcesTab(lab)


def create_tab_in_steps(lab: Any) -> tuple[QWidget, Iterator[None]]:
    """The tab, and the steps that finish it: its body map, then its 12 segment plots, one per step (15-40 ms of the
    GUI thread each; the main window runs one per turn of the event loop, so opening the tab never holds the window
    for the whole page)."""
    tab = ForcesTab(lab, plots_in_steps=True)

    # An empty step after each piece: the main window's step timer (interval 0) could fire twice before the window's
    # other timers had a turn (the benchmark's 5 ms tick saw two plots built between two of its ticks), so each
    # piece is followed by a turn that builds nothing.
    def steps() -> Iterator[None]:
        tab.build_body_map()
        yield
        yield
        while tab.plots.add_next_plot():
            yield
            yield

    return tab, steps()
