"""GaitPanel: the Gait tab's view — mode, shape, parameters, play/pause/resume/stop, progress, body drawing.

Passive: emits :class:`GaitRequest` on Play and plain signals for the transport buttons; the owner
(``app/gui/tabs/gait.py``) builds the motion and feeds back progress, angles and errors. Angles in rad, speeds in rad/s,
rates in Hz. GUI thread only.
Play is enabled only when it can work (robot connected, a shape chosen for the shape modes); its tooltip says what is
missing. Space pauses and resumes a running gait while the panel is on screen (Esc is STOP, app-wide).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QAbstractItemView,
    QAbstractScrollArea,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QFrame,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QSpinBox,
    QStackedWidget,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from models.force_feedback import FeedbackGains
from widgets import theme
from widgets.body_view import BodyView
from widgets.tables import cell_item

JOINT_ROW_PX = 18
# Where the window is short (the event log open below the tab), the joint table scrolls down to this many rows
# before the drawing gives up more height than its own minimum (BodyView.MIN_HEIGHT_PX).
JOINT_ROWS_AT_LEAST = 4
MODES = ("follow", "keyframes", "serpenoid", "sidewinding")
MODE_TITLES = {
    "follow": "Follow-the-leader (shape slides head → tail)",
    "keyframes": "Keyframes (replay taught poses in time)",
    "serpenoid": "Serpenoid lateral undulation",
    "sidewinding": "Sidewinding",
}


@dataclass(frozen=True)
class GaitRequest:
    """Everything Play needs. Shape-based modes use ``shape_name``; parametric ones the wave parameters."""

    mode: str
    shape_name: str
    speed_rad_s: float
    rate_hz: float
    shifts: int | None  # None = default (K = m)
    time_scale: float
    repeat: int
    amplitude_rad: float
    spatial_rad: float
    frequency_hz: float
    offset_rad: float
    cycles: float
    pitch_amplitude_rad: float
    phase_rad: float
    controller: str = "feedforward"  # or "feedback": force-feedback body bending (follow and keyframes)
    gains: dict[str, float] | None = None  # the feedback gains shown in the panel (conform, push, target)


def _spin(lo: float, hi: float, value: float, step: float, decimals: int, suffix: str) -> QDoubleSpinBox:
    spin = QDoubleSpinBox()
    spin.setRange(lo, hi)
    spin.setDecimals(decimals)
    spin.setSingleStep(step)
    spin.setValue(value)
    spin.setSuffix(suffix)
    return spin


# The feedback gains the panel lets a user adjust, live, within these ranges (the law's safe ranges may be wider);
# each starts at the law's default (FeedbackGains).
FEEDBACK_SPINS = (
    ("conform_gain", "conform", 0.0, 0.5, 0.01, 2, " rad/s",
     "How fast a node the shape wraps reaches for contact it lost, and yields per unit of overload"),
    ("push_gain", "push", 0.0, 0.5, 0.01, 2, " rad/s",
     "How fast a node in contact presses down when it carries less than the target force"),
    ("target_n", "target", 0.5, 20.0, 0.5, 1, " N",
     "The load a node (two segments' bottom sheets) should push with"),
    ("lead_gain", "lead", -0.5, 0.5, 0.01, 2, " rad/s",
     "How fast joint 3 bends the front while its bottom sheets feel nothing: positive turns it up and forward, out "
     "of the taught bend; negative turns it down toward the terrain. The bend travels back with the shape (0: off)"),
    ("lead_reach", "lead reach", 0.0, 12.0, 1.0, 0, " joints",
     "How many pitch joints behind joint 3 the lead's bend travels with the shape (12: all, the default; 2 stops "
     "it at joint 7, which also holds the body on the crest under heavy tail loads but traverses less; "
     "docs/FORCE_FEEDBACK.md)"),
    ("tail_guard_n", "tail guard", 0.0, 5.0, 0.1, 1, " N",
     "While the two tail segments' bottom sheets carry less than this, the lead closes back toward the taught shape "
     "instead of opening it: the tail has left the floor and the body is balancing on the terrain (0: off)"),
    ("tail_guard_back", "guard back", 0.0, 3.0, 0.1, 1, " × lead",
     "While the tail guard acts, the lead's bend already carried back toward the lifted tail closes too, at this part "
     "of the lead's rate (0: only joint 3 closes). 0.3, the default, stopped the body sliding back off the crest "
     "under heavy tail loads (docs/FORCE_FEEDBACK.md)"),
)


class GaitPanel(QWidget):
    play_requested = Signal(object)  # GaitRequest
    gains_changed = Signal(object)  # dict of the feedback gains, while a feedback motion may be running
    pause_requested = Signal()
    resume_requested = Signal()
    stop_requested = Signal()
    refresh_shapes_requested = Signal()
    open_file_requested = Signal()
    shape_selected = Signal(str)

    def __init__(self, axes: Sequence[str], segment_length_m: float = 0.08, max_speed_rad_s: float = 1.0,
                 rate_hz: float = 50.0, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        controls = QWidget()
        controls.setMaximumWidth(380)
        column = QVBoxLayout(controls)
        column.setContentsMargins(0, 0, 0, 0)

        mode_box = QGroupBox("Gait")
        mode_form = QFormLayout(mode_box)
        self.mode_combo = QComboBox()
        for mode in MODES:
            self.mode_combo.addItem(MODE_TITLES[mode], mode)
        self.mode_combo.setToolTip("Follow-the-leader and keyframes replay a shape taught in the Teach tab; "
                                   "serpenoid and sidewinding are travelling waves set by the parameters below")
        mode_form.addRow("mode", self.mode_combo)
        shape_row = QHBoxLayout()
        self.shape_combo = QComboBox()
        self.shape_combo.setMinimumContentsLength(12)
        self.shape_combo.setPlaceholderText("none saved yet: see Teach")
        self.refresh_button = QPushButton("↻")
        self.refresh_button.setFixedWidth(30)
        self.refresh_button.setToolTip("re-read the shape library")
        self.open_button = QPushButton("File…")
        self.open_button.setToolTip("Play a shape file (.json) from outside the library")
        self.shape_combo.setToolTip("Shapes in the library (save them in the Teach tab)")
        shape_row.addWidget(self.shape_combo, 1)
        shape_row.addWidget(self.refresh_button)
        shape_row.addWidget(self.open_button)
        self._shape_label = QLabel("shape")
        mode_form.addRow(self._shape_label, shape_row)
        self.rate_spin = _spin(1, rate_hz, rate_hz, 5, 0, " Hz")
        self.rate_spin.setToolTip(f"how often the goal advances along the line (at most the control loop's "
                                  f"{rate_hz:g} Hz, robot.control_rate_hz in the lab config; every control tick "
                                  "still sends one synchronised write)")
        mode_form.addRow("rate", self.rate_spin)
        self.repeat_spin = QSpinBox()
        self.repeat_spin.setRange(1, 1000)
        self.repeat_spin.setToolTip("How many times the whole motion is played")
        mode_form.addRow("repeat", self.repeat_spin)
        column.addWidget(mode_box)

        self.params = QStackedWidget()
        # follow
        follow = QWidget()
        f = QFormLayout(follow)
        self.speed_spin = _spin(0.001, max_speed_rad_s, min(0.034, max_speed_rad_s), 0.005, 3, " rad/s")
        self.shifts_spin = QSpinBox()
        self.shifts_spin.setRange(-1, 99)
        self.shifts_spin.setValue(-1)
        self.shifts_spin.setSpecialValueText("default (K = m)")
        self.speed_spin.setToolTip("Speed of the fastest joint in each move; the others are slower so all arrive "
                                   "together (sensnake play --speed; the lab's default is 0.034 rad/s)")
        self.shifts_spin.setToolTip("How far the shape slides: shift k moves it k joints of each axis toward the "
                                    "tail; default K = the number of joints per axis (the shape leaves the body)")
        f.addRow("speed", self.speed_spin)
        f.addRow("shifts K", self.shifts_spin)
        self.params.addWidget(follow)
        # keyframes
        keys = QWidget()
        k = QFormLayout(keys)
        self.time_scale_spin = _spin(0.05, 100, 1.0, 0.1, 2, " ×")
        self.approach_spin = _spin(0.001, max_speed_rad_s, min(0.1, max_speed_rad_s), 0.01, 3, " rad/s")
        self.time_scale_spin.setToolTip("Stretch the keyframe times: 2 × plays twice as slowly (refused if a step "
                                        "would need a joint faster than the servo's velocity limit)")
        self.approach_spin.setToolTip("Speed of the fastest joint while moving from the present pose to the first "
                                      "keyframe")
        k.addRow("time scale", self.time_scale_spin)
        k.addRow("approach speed", self.approach_spin)
        self.params.addWidget(keys)
        # serpenoid / sidewinding share one form; the pitch rows only show for sidewinding
        wave = QWidget()
        w = QFormLayout(wave)
        self.amplitude_spin = _spin(0, 1.5, 0.5, 0.05, 2, " rad")
        self.spatial_spin = _spin(0, math.pi, math.pi / 3, 0.05, 2, " rad/joint")
        self.frequency_spin = _spin(0.01, 2, 0.2, 0.05, 2, " Hz")
        self.offset_spin = _spin(-0.8, 0.8, 0.0, 0.05, 2, " rad")
        self.cycles_spin = _spin(0.5, 1000, 3, 1, 1, " cycles")
        self.pitch_amplitude_spin = _spin(0, 1.5, 0.3, 0.05, 2, " rad")
        self.phase_spin = _spin(-math.pi, math.pi, math.pi / 2, 0.1, 2, " rad")
        self.amplitude_spin.setToolTip("Peak yaw angle of the wave (rad)")
        self.spatial_spin.setToolTip("Phase difference between consecutive joints of an axis: smaller = longer "
                                     "wave along the body")
        self.frequency_spin.setToolTip("Wave frequency; amplitude × 2π × frequency must stay below the servo's "
                                       "max joint speed")
        self.offset_spin.setToolTip("Constant yaw added to every yaw joint: the robot turns (positive: left)")
        self.cycles_spin.setToolTip("How many wave periods to play (the first is blended in from the present pose)")
        self.pitch_amplitude_spin.setToolTip("Peak pitch angle: lifts segments off the ground for sidewinding")
        self.phase_spin.setToolTip("Phase of the pitch wave relative to the yaw wave (π/2 for classic sidewinding)")
        w.addRow("amplitude (yaw)", self.amplitude_spin)
        w.addRow("phase lag / joint", self.spatial_spin)
        w.addRow("frequency", self.frequency_spin)
        w.addRow("turn offset", self.offset_spin)
        w.addRow("duration", self.cycles_spin)
        self._pitch_label = QLabel("amplitude (pitch)")
        self._phase_label = QLabel("pitch phase")
        w.addRow(self._pitch_label, self.pitch_amplitude_spin)
        w.addRow(self._phase_label, self.phase_spin)
        self.params.addWidget(wave)
        params_box = QGroupBox("Parameters")
        QVBoxLayout(params_box).addWidget(self.params)
        column.addWidget(params_box)

        self.controller_box = QGroupBox("Controller")
        controller_form = QFormLayout(self.controller_box)
        self.controller_combo = QComboBox()
        self.controller_combo.addItem("feedforward (the shape as taught)", "feedforward")
        self.controller_combo.addItem("feedback (bending from the bottom forces)", "feedback")
        self.controller_combo.setToolTip(
            "Feedback corrects the pitch goals from the estimated bottom forces: where the shape wraps the "
            "terrain it presses nodes that carry less than the target and reaches for lost contact; anywhere it "
            "yields to an overload. Needs calibrated bottom sensors (Forces tab); a stale, flagged or "
            "uncalibrated sensor leaves its node on feedforward.")
        controller_form.addRow("mode", self.controller_combo)
        self.gain_spins: dict[str, QDoubleSpinBox] = {}
        defaults = FeedbackGains()
        for key, label, lo, hi, step, decimals, suffix, tip in FEEDBACK_SPINS:
            spin = _spin(lo, hi, getattr(defaults, key), step, decimals, suffix)
            spin.setToolTip(tip + " (adjustable while playing)")
            spin.valueChanged.connect(lambda _v: self.gains_changed.emit(self.gains()))
            self.gain_spins[key] = spin
            controller_form.addRow(label, spin)
        self.controller_combo.currentIndexChanged.connect(lambda _i: self._controller_changed())
        column.addWidget(self.controller_box)
        column.addStretch(1)
        # A safety net for windows smaller than 1280×800 (down to the 960×600 minimum): at 1280×800 every mode's
        # settings fit without scrolling.
        scroll = QScrollArea()
        scroll.setWidget(controls)
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setMaximumWidth(controls.maximumWidth() + scroll.verticalScrollBar().sizeHint().width() + 2)
        self.settings_scroll = scroll

        # -- the motion: transport, progress and what happened, above the drawing ----------------------------------
        # Nothing the settings column shows or hides (a mode's form, the feedback gains) moves Play or the progress
        # line: they head the drawing's column, and what grows (the status line, the readouts) grows below them.
        transport = QHBoxLayout()
        self.play_button = QPushButton("▶ Play")
        self.play_button.setStyleSheet("font-weight: bold;")
        self.pause_button = QPushButton("❚❚ Pause")
        self.resume_button = QPushButton("▶ Resume")
        self.stop_button = QPushButton("■ Stop")
        self.pause_button.setToolTip("Hold the motion where it is (Space); Resume continues from there")
        self.resume_button.setToolTip("Continue the paused motion (Space)")
        self.stop_button.setToolTip("End the motion; the robot holds its last goal. Esc (STOP) halts at once from "
                                    "any tab")
        for b in (self.play_button, self.pause_button, self.resume_button, self.stop_button):
            transport.addWidget(b)
        self.progress_bar = QProgressBar()
        self.progress_bar.setRange(0, 1000)
        self.progress_bar.setTextVisible(False)
        transport.addWidget(self.progress_bar, 1)
        self.progress_label = QLabel("idle")
        self.progress_label.setStyleSheet(f"font-family: {theme.MONOSPACE_FAMILY};")
        # The column's width decides, not the text (a long motion's line would widen the column to the window's
        # edge); set_progress shortens the line to what fits and the tooltip holds all of it.
        self.progress_label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        self.status_label = QLabel("")
        self.status_label.setWordWrap(True)
        self.status_label.setVisible(False)  # no blank line while there is nothing to say

        self.body_view = BodyView(axes, segment_length_m)
        legend = QLabel(f"drawing: <span style='color:{theme.PRESENT_COLOR}'>━ present</span> &nbsp; "
                        f"<span style='color:{theme.GOAL_COLOR}'>╌ goal</span>")
        legend.setToolTip("Solid: where the robot is. Dashed: where it is told to go (the chosen shape before "
                          "Play). Esc is STOP from any tab.")
        self.joint_table = QTableWidget(len(axes), 3)
        self.joint_table.setHorizontalHeaderLabels(["goal (rad)", "present (rad)", "current (mA)"])
        self.joint_table.setVerticalHeaderLabels([f"J{i + 1}" for i in range(len(axes))])
        self.joint_table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.joint_table.verticalHeader().setDefaultSectionSize(JOINT_ROW_PX)
        self.joint_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.joint_table.setSelectionMode(QAbstractItemView.SelectionMode.NoSelection)
        self.joint_table.setStyleSheet(f"font-family: {theme.MONOSPACE_FAMILY};")
        for r in range(len(axes)):
            for c in range(3):
                item = QTableWidgetItem("")
                item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.joint_table.setItem(r, c, item)
        header_px = self.joint_table.horizontalHeader().sizeHint().height()
        whole_px = header_px + JOINT_ROW_PX * len(axes) + 4
        self.joint_table.setMaximumHeight(whole_px)  # every row when there is room; scrolls when the window is short
        self.joint_table.setMinimumHeight(header_px + JOINT_ROW_PX * min(JOINT_ROWS_AT_LEAST, len(axes)) + 4)
        self.joint_table.setSizeAdjustPolicy(QAbstractScrollArea.SizeAdjustPolicy.AdjustToContents)
        self.joint_table.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Maximum)
        self.joint_table.setMaximumWidth(420)
        self.feedback_box = QGroupBox("Feedback per node")
        feedback_layout = QVBoxLayout(self.feedback_box)
        self.feedback_label = QLabel("")
        self.feedback_label.setStyleSheet(f"font-family: {theme.MONOSPACE_FAMILY};")
        self.feedback_label.setWordWrap(True)
        self.feedback_label.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop)
        self.feedback_label.setToolTip("Per node (the pitch joint between two segments): the force it should push "
                                       "with, the force measured on its two bottom sheets, and the correction "
                                       "applied to that joint; 'ff' where it is on feedforward, and why")
        feedback_layout.addWidget(self.feedback_label, 1)
        self.feedback_box.setMinimumHeight(self.joint_table.minimumHeight())
        self.feedback_box.setMaximumHeight(whole_px)
        self.feedback_box.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Maximum)
        readouts = QHBoxLayout()
        readouts.addWidget(self.joint_table, 1)
        readouts.addWidget(self.feedback_box, 1)

        motion = QVBoxLayout()
        motion.setContentsMargins(0, 0, 0, 0)
        motion.addLayout(transport)
        motion.addWidget(self.progress_label)
        motion.addWidget(self.status_label)
        motion.addWidget(self.body_view, 1)
        motion.addWidget(legend)
        motion.addLayout(readouts)

        layout = QHBoxLayout(self)
        layout.setContentsMargins(6, 6, 6, 6)
        layout.addWidget(scroll)
        layout.addLayout(motion, 1)

        self.mode_combo.currentIndexChanged.connect(self._mode_changed)
        self.play_button.clicked.connect(lambda: self.play_requested.emit(self.request()))
        self.pause_button.clicked.connect(self.pause_requested)
        self.resume_button.clicked.connect(self.resume_requested)
        self.stop_button.clicked.connect(self.stop_requested)
        self.refresh_button.clicked.connect(self.refresh_shapes_requested)
        self.open_button.clicked.connect(self.open_file_requested)
        self.shape_combo.currentTextChanged.connect(self.shape_selected)
        self.shape_combo.currentTextChanged.connect(lambda _text: self._update_play())
        # Application-wide so focus does not matter, yet only while this panel is visible (Qt ignores shortcuts of
        # hidden widgets) and never while a modal dialog is up.
        self.pause_shortcut = QShortcut(QKeySequence(Qt.Key.Key_Space), self)
        self.pause_shortcut.setContext(Qt.ShortcutContext.ApplicationShortcut)
        self.pause_shortcut.activated.connect(self.toggle_pause)
        self._connected = True  # until the owner says otherwise (a panel on its own can play)
        self._state = "idle"
        self._mode_changed()
        self.set_motion_state("idle")

    # -- API ---------------------------------------------------------------------------------------------------------
    @property
    def mode(self) -> str:
        return str(self.mode_combo.currentData())

    def set_mode(self, mode: str) -> None:
        self.mode_combo.setCurrentIndex(MODES.index(mode))

    def request(self) -> GaitRequest:
        shifts = self.shifts_spin.value()
        return GaitRequest(
            mode=self.mode, shape_name=self.shape_combo.currentText(),
            speed_rad_s=self.approach_spin.value() if self.mode == "keyframes" else self.speed_spin.value(),
            rate_hz=self.rate_spin.value(), shifts=None if shifts < 0 else shifts,
            time_scale=self.time_scale_spin.value(), repeat=self.repeat_spin.value(),
            amplitude_rad=self.amplitude_spin.value(), spatial_rad=self.spatial_spin.value(),
            frequency_hz=self.frequency_spin.value(), offset_rad=self.offset_spin.value(),
            cycles=self.cycles_spin.value(), pitch_amplitude_rad=self.pitch_amplitude_spin.value(),
            phase_rad=self.phase_spin.value(), controller=self.controller, gains=self.gains())

    @property
    def controller(self) -> str:
        return str(self.controller_combo.currentData()) if self.mode in ("follow", "keyframes") else "feedforward"

    def gains(self) -> dict[str, float]:
        """The feedback gains set in the panel."""
        return {key: spin.value() for key, spin in self.gain_spins.items()}

    def set_feedback_readout(self, rows: Sequence[tuple[str, float, float, float, str]],
                             lead: tuple[float, float] | None = None) -> None:
        """Per node: (name, target N, measured N or NaN, correction rad, why it is on feedforward or ''); ``lead``:
        (the front's bottom load N or NaN, the lead's bend rad) when the lead is on."""
        lines = ["node target  measured  correction"] if rows else []
        for name, target, measured, correction, why in rows:
            load = f"{measured:5.1f} N" if math.isfinite(measured) else "   —   "
            lines.append(f"{name:<4} {target:4.1f} N  {load}  {correction:+.3f} rad" + (f"\n     ff: {why}" if why else ""))
        if rows and lead is not None:
            front, bend = lead
            load = f"{front:5.1f} N" if math.isfinite(front) else "   —   "
            lines.append(f"lead front   {load}  {bend:+.3f} rad")
        text = "\n".join(lines)
        if self.feedback_label.text() != text:
            self.feedback_label.setText(text)

    def set_shapes(self, names: Sequence[str], current: str = "") -> None:
        keep = current or self.shape_combo.currentText()
        self.shape_combo.blockSignals(True)
        self.shape_combo.clear()
        self.shape_combo.addItems(list(names))
        if keep:
            index = self.shape_combo.findText(keep)
            if index < 0:
                self.shape_combo.addItem(keep)
                index = self.shape_combo.count() - 1
            self.shape_combo.setCurrentIndex(index)
        elif names:
            self.shape_combo.setCurrentIndex(0)  # with a placeholder text set, Qt would leave none chosen
        self.shape_combo.blockSignals(False)
        self._update_play()

    def set_connected(self, connected: bool) -> None:
        """Whether the robot is connected (Play needs it)."""
        self._connected = bool(connected)
        self._update_play()

    def toggle_pause(self) -> None:
        """Pause a running motion or resume a paused one (the Space key); nothing otherwise."""
        if self.pause_button.isEnabled():
            self.pause_button.click()
        elif self.resume_button.isEnabled():
            self.resume_button.click()

    def set_motion_state(self, state: str) -> None:
        """Enable the transport buttons for ``idle``/``running``/``paused``/``finished``/``stopped``/``fault``, and
        ``halted`` (stopped by the loop's watchdog, its cause still being told: nothing to stop, Play waits)."""
        self._state = state
        running, paused = state == "running", state == "paused"
        self._update_play()
        self.pause_button.setEnabled(running)
        self.resume_button.setEnabled(paused)
        self.stop_button.setEnabled(running or paused)
        idle = not running and not paused
        for w in (self.mode_combo, self.params, self.shape_combo, self.rate_spin, self.repeat_spin,
                  self.refresh_button, self.open_button, self.controller_combo):
            w.setEnabled(idle)

    def set_progress(self, text: str, fraction: float) -> None:
        """``text``: the progress line (``where   elapsed / total s   time left``). When it does not fit the column,
        the spacing tightens, then the elapsed / total part goes (the bar shows it); never cut off mid-text."""
        label = self.progress_label
        metrics = label.fontMetrics()
        room = label.contentsRect().width()
        shown = text
        if room > 0 and metrics.horizontalAdvance(shown) > room:
            parts = [p for p in text.split("   ") if p]
            shown = " ".join(" ".join(p.split()) for p in parts)
            if metrics.horizontalAdvance(shown) > room and len(parts) >= 3:
                shown = " ".join(" ".join(p.split()) for p in (parts[:-2] + parts[-1:]))
        if label.text() != shown:
            label.setText(shown)
        if label.toolTip() != text:
            label.setToolTip(text)
        self.progress_bar.setValue(int(round(min(max(fraction, 0.0), 1.0) * 1000)))

    def set_status(self, text: str, level: str = theme.IDLE) -> None:
        self.status_label.setText(text)
        self.status_label.setVisible(bool(text))
        self.status_label.setStyleSheet(theme.status_style(level) if text else "")

    def set_joint_readout(self, goal_rad: Sequence[float] | None, present_rad: Sequence[float] | None,
                          current_ma: Sequence[float] | None) -> None:
        """Per-joint goal and present angle (rad) and current (mA); ``None`` columns show blank."""
        for c, values, fmt in ((0, goal_rad, "{:+.3f}"), (1, present_rad, "{:+.3f}"), (2, current_ma, "{:+.0f}")):
            for r in range(self.joint_table.rowCount()):
                text = "" if values is None else fmt.format(float(values[r]))
                item = cell_item(self.joint_table, r, c)
                if item.text() != text:
                    item.setText(text)

    def set_rate(self, rate_hz: float) -> None:
        """The controller's rate: the most the goal can be advanced per second."""
        self.rate_spin.setMaximum(rate_hz)
        self.rate_spin.setValue(rate_hz)

    # -- internals ---------------------------------------------------------------------------------------------------
    def _controller_changed(self) -> None:
        feedback = self.controller == "feedback"
        for spin in self.gain_spins.values():
            spin.setEnabled(feedback)
        # Always there (the readouts below the drawing keep their places); in use with the feedback controller only
        self.feedback_box.setEnabled(feedback)
        self.feedback_box.setTitle("Feedback per node" if feedback else "Feedback per node (Controller → feedback)")

    def _play_blocker(self) -> str:
        """Why Play cannot work now ('' if it can)."""
        if self._state in ("running", "paused"):
            return "A motion is playing: Stop it first"
        if self._state == "halted":
            return ("The motion was stopped on a quiet servo bus: wait for the verdict (silent servos, or replies "
                    "held on this computer)")
        if not self._connected:
            return "The robot is not connected: connect it in the Hardware tab"
        if self.mode in ("follow", "keyframes") and not self.shape_combo.currentText():
            return "No shape chosen: save one in the Teach tab, or open a shape file (File…)"
        return ""

    def _update_play(self) -> None:
        blocker = self._play_blocker()
        self.play_button.setEnabled(not blocker)
        self.play_button.setToolTip(blocker or "Play the motion (torque goes on first; Esc is STOP)")

    def _mode_changed(self) -> None:
        mode = self.mode
        self.params.setCurrentIndex({"follow": 0, "keyframes": 1}.get(mode, 2))
        uses_shape = mode in ("follow", "keyframes")
        widget: QWidget
        for widget in (self.shape_combo, self.refresh_button, self.open_button, self._shape_label):
            widget.setVisible(uses_shape)
        self.controller_box.setVisible(uses_shape)  # feedback corrects a shape's pitch bending
        self._controller_changed()
        side = mode == "sidewinding"
        for widget in (self._pitch_label, self.pitch_amplitude_spin, self._phase_label, self.phase_spin):
            widget.setVisible(side)
        self._update_play()
        page = self.params.currentWidget()
        if page is not None:
            self.params.setMaximumHeight(page.sizeHint().height() + 8)
