"""The Forces tab's controls: view options, recording, past recordings, and the board's status line.

Passive view: it emits what the user asked for and shows what it is told; the tab (``app/gui/tabs/forces.py``) decides.
Space toggles Pause while the controls are on screen. GUI thread only.
"""

from __future__ import annotations

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QMenu,
    QPushButton,
    QSpinBox,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

try:
    from widgets.theme import SIDE_COLORS, SIDE_LABELS, status_style
except ImportError:  # pragma: no cover - only while widgets/theme.py is absent
    SIDE_COLORS = {"L": "#0072B2", "R": "#D55E00", "B": "#009E73"}
    SIDE_LABELS = {"L": "left", "R": "right", "B": "bottom"}

    def status_style(level: str) -> str:
        return {"ok": "color: #1B7F3B;", "warn": "color: #B36B00;", "error": "color: #C62828;",
                "idle": "color: #6B6B6B;"}.get(level, "")

WINDOW_CHOICES_S: tuple[tuple[str, float], ...] = (
    ("5 s", 5.0), ("10 s", 10.0), ("30 s", 30.0), ("1 min", 60.0), ("2 min", 120.0), ("5 min", 300.0),
    ("10 min", 600.0),
)
DEFAULT_WINDOW_S = 30.0
QUANTITIES = (("force", "Force (N if calibrated)"), ("conductance", "Raw conductance (µS)"))
RECORD_TEXT = "● Record"
STOP_RECORDING_TEXT = "■ Stop recording"  # not just "Stop": the status bar's STOP halts the robot
RECORD_TIP = "Record the board (and the robot when connected) to an HDF5 file"
EXPORT_TIP = ("Write the recording shown to CSV, the visible time range or all of it: time_s, each sensor in N (µS "
              "when it has no force), each joint's present and goal angle (rad) and current (mA)")
EXPORT_DISABLED_TIP = "Open a recording first (Open recording…): Export writes the recording shown"
ESTIMATORS = (("sls", "Creep-aware (SLS)"), ("linear", "Linear"))


def format_bytes(n_bytes: int) -> str:
    value = float(n_bytes)
    for unit in ("B", "kB", "MB", "GB"):
        if value < 1000 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1000
    return f"{value:.1f} GB"  # pragma: no cover


def format_elapsed(seconds: float) -> str:
    seconds = max(0, int(seconds))
    return f"{seconds // 3600:d}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


class ForcesControls(QWidget):
    """Two rows of controls above the plots and a status line.

    Signals: ``window_changed(float)`` seconds, ``pause_toggled(bool)``, ``side_toggled(str, bool)``,
    ``quantity_changed(str)`` (``force``/``conductance``), ``estimator_changed(str)`` (``sls``/``linear``),
    ``record_toggled(bool)`` (True = start), ``browse_requested()``, ``load_calibration_requested()``,
    ``truth_calibration_requested()`` (the simulated lab's true calibration: its button shows on a simulated board),
    ``open_requested()``, ``overlay_requested()``, ``export_requested(bool)`` (True: only the time range the plots
    show), ``live_requested()`` (back to the board).
    """

    window_changed = Signal(float)
    pause_toggled = Signal(bool)
    side_toggled = Signal(str, bool)
    quantity_changed = Signal(str)
    estimator_changed = Signal(str)
    record_toggled = Signal(bool)
    browse_requested = Signal()
    load_calibration_requested = Signal()
    truth_calibration_requested = Signal()
    open_requested = Signal()
    overlay_requested = Signal()
    export_requested = Signal(bool)
    live_requested = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        outer = QVBoxLayout(self)
        outer.setContentsMargins(4, 4, 4, 0)
        outer.setSpacing(3)

        view_row = QHBoxLayout()
        view_row.addWidget(QLabel("Show"))
        self.quantity = QComboBox(self)
        for key, text in QUANTITIES:
            self.quantity.addItem(text, key)
        self.quantity.setToolTip("Force estimated from each sensor's calibration (a sensor without one stays in µS, "
                                 "labelled), or the raw conductance the board measures")
        self.quantity.currentIndexChanged.connect(lambda _i: self.quantity_changed.emit(self.quantity.currentData()))
        view_row.addWidget(self.quantity)
        view_row.addWidget(QLabel("Estimator"))
        self.estimator = QComboBox(self)
        for key, text in ESTIMATORS:
            self.estimator.addItem(text, key)
        self.estimator.setToolTip("How conductance becomes force, applied live to new samples: creep-aware "
                                  "(SLS) follows the sensor's slow relaxation, linear is a straight-line fit")
        self.estimator.currentIndexChanged.connect(
            lambda _i: self.estimator_changed.emit(self.estimator.currentData()))
        view_row.addWidget(self.estimator)
        self.load_calibration = QPushButton("Calibration…", self)
        self.load_calibration.setToolTip("Load a calibration JSON (sensnake fit output)")
        self.load_calibration.clicked.connect(self.load_calibration_requested)
        view_row.addWidget(self.load_calibration)
        self.truth_calibration = QToolButton(self)
        self.truth_calibration.setText("Simulated truth")
        self.truth_calibration.setToolTip("Use the simulated lab's every sensor's true calibration: the simulation's "
                                          "truth, not a measurement (on the robot, calibrate on the rig)")
        self.truth_calibration.clicked.connect(self.truth_calibration_requested)
        self.truth_calibration.setVisible(False)
        view_row.addWidget(self.truth_calibration)
        self.calibration_label = QLabel("no calibration", self)
        self.calibration_label.setStyleSheet(status_style("idle"))
        # May be cut short in a narrow window (the tooltip keeps the whole text) rather than push the plots' side
        # panel off screen at the minimum window width.
        self.calibration_label.setMinimumWidth(80)
        view_row.addWidget(self.calibration_label)
        view_row.addSpacing(12)
        view_row.addWidget(QLabel("Window"))
        self.window_combo = QComboBox(self)
        for text, seconds in WINDOW_CHOICES_S:
            self.window_combo.addItem(text, seconds)
        self.window_combo.setCurrentIndex([s for _t, s in WINDOW_CHOICES_S].index(DEFAULT_WINDOW_S))
        self.window_combo.setToolTip("Time span shown in the live plots")
        self.window_combo.currentIndexChanged.connect(lambda _i: self.window_changed.emit(float(self.window_combo.currentData())))
        view_row.addWidget(self.window_combo)
        self.pause = QToolButton(self)
        self.pause.setText("Pause")
        self.pause.setCheckable(True)
        self.pause.setToolTip("Stop following the newest data to look back (Space); acquisition and recording "
                              "continue")
        self.pause.toggled.connect(self._on_pause)
        view_row.addWidget(self.pause)
        # Application-wide so focus does not matter, yet only while these controls are visible (Qt ignores
        # shortcuts of hidden widgets) and never while a modal dialog is up.
        self.pause_shortcut = QShortcut(QKeySequence(Qt.Key.Key_Space), self)
        self.pause_shortcut.setContext(Qt.ShortcutContext.ApplicationShortcut)
        self.pause_shortcut.activated.connect(self.pause.toggle)
        self.side_boxes: dict[str, QCheckBox] = {}
        for side, color in SIDE_COLORS.items():
            box = QCheckBox(SIDE_LABELS.get(side, side), self)
            box.setChecked(True)
            box.setStyleSheet(f"QCheckBox {{ color: {color}; font-weight: bold; }}")
            box.toggled.connect(lambda on, s=side: self.side_toggled.emit(s, on))
            self.side_boxes[side] = box
            view_row.addWidget(box)
        view_row.addStretch(1)
        outer.addLayout(view_row)

        record_row = QHBoxLayout()
        self.record = QPushButton(RECORD_TEXT, self)
        self.record.setCheckable(True)
        self.record.setToolTip(RECORD_TIP)
        self.recording_elsewhere: str | None = None  # another recording of this data is on (a trial): whose
        self.record.toggled.connect(self._on_record)
        record_row.addWidget(self.record)
        self.duration = QSpinBox(self)
        self.duration.setRange(0, 24 * 3600)
        self.duration.setSingleStep(5)
        self.duration.setSuffix(" s")
        self.duration.setSpecialValueText("until stopped")
        self.duration.setToolTip("Stop the recording by itself after this many seconds (a timed trial); "
                                 "'until stopped' records until you click Stop recording")
        record_row.addWidget(self.duration)
        self.path = QLineEdit(self)
        self.path.setPlaceholderText("recording file (.h5)")
        self.path.setMinimumWidth(160)  # the row must fit the 960 px minimum window width
        record_row.addWidget(self.path, 1)
        self.browse = QToolButton(self)
        self.browse.setText("…")
        self.browse.setToolTip("Choose where to save the recording")
        self.browse.clicked.connect(self.browse_requested)
        record_row.addWidget(self.browse)
        self.record_info = QLabel("not recording", self)
        self.record_info.setMinimumWidth(140)
        record_row.addWidget(self.record_info)
        record_row.addSpacing(12)
        self.open = QPushButton("Open recording…", self)
        self.open.setToolTip("Show a past recording in the plots (Back to live returns)")
        self.open.clicked.connect(self.open_requested)
        record_row.addWidget(self.open)
        self.overlay = QPushButton("Overlay trials…", self)
        self.overlay.setToolTip("Several recordings of one sensor on a common time zero")
        self.overlay.clicked.connect(self.overlay_requested)
        record_row.addWidget(self.overlay)
        self.export = QPushButton("Export CSV…", self)
        export_menu = QMenu(self.export)
        self.export_visible_action = export_menu.addAction("Visible time range…")
        self.export_visible_action.triggered.connect(lambda: self.export_requested.emit(True))
        self.export_all_action = export_menu.addAction("Whole recording…")
        self.export_all_action.triggered.connect(lambda: self.export_requested.emit(False))
        self.export.setMenu(export_menu)
        self.export.setEnabled(False)
        self.export.setToolTip(EXPORT_DISABLED_TIP)
        record_row.addWidget(self.export)
        self.live = QPushButton("Back to live", self)
        self.live.clicked.connect(self.live_requested)
        self.live.setToolTip("Leave the recording and show the live board again")
        self.live.setVisible(False)
        record_row.addWidget(self.live)
        outer.addLayout(record_row)
        self._record_row = record_row

        status_row = QHBoxLayout()
        self.board_status = QLabel("board: not started", self)
        self.counters = QLabel("", self)
        self.message = QLabel("", self)
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        status_row.addWidget(self.board_status)
        status_row.addWidget(self.counters)
        status_row.addWidget(self.message, 1)
        outer.addLayout(status_row)

    # -- user actions ----------------------------------------------------------------------------------------------
    def _on_pause(self, paused: bool) -> None:
        self.pause.setText("Resume" if paused else "Pause")
        self.pause_toggled.emit(paused)

    def _on_record(self, start: bool) -> None:
        self.record.setText(STOP_RECORDING_TEXT if start else RECORD_TEXT)
        self.record_toggled.emit(start)

    def add_beside_record(self, widget: QWidget) -> None:
        """Put ``widget`` (the motion-capture source) right after the Record button."""
        self._record_row.insertWidget(self._record_row.indexOf(self.record) + 1, widget)

    # -- state shown ----------------------------------------------------------------------------------------------
    def set_paused(self, paused: bool) -> None:
        """Reflect a pause that came from the plots (drag, zoom, scroll-back) without re-emitting."""
        self.pause.blockSignals(True)
        self.pause.setChecked(paused)
        self.pause.setText("Resume" if paused else "Pause")
        self.pause.blockSignals(False)

    @property
    def duration_s(self) -> float | None:
        """The chosen recording length in s, or None to record until stopped."""
        return float(self.duration.value()) or None

    def set_recording(self, recording: bool, text: str) -> None:
        if not recording and self.recording_elsewhere is not None:
            text = self.record_info.text()  # the other recording stays named beside the disabled button
        self.record.blockSignals(True)
        self.record.setChecked(recording)
        self.record.setText(STOP_RECORDING_TEXT if recording else RECORD_TEXT)
        self.record.blockSignals(False)
        self.record_info.setText(text)
        self.path.setEnabled(not recording)
        self.browse.setEnabled(not recording)
        self.duration.setEnabled(not recording)

    def set_recording_elsewhere(self, short: str | None, whose: str = "") -> None:
        """Another recording of this data is on (a trial of the Trials dock records the board and the robot): Record
        is off and disabled, the line beside it says ``short`` and its tooltip ``whose``; None: Record is free."""
        was, self.recording_elsewhere = self.recording_elsewhere, short
        self.record.setEnabled(short is None)
        self.record.setToolTip(RECORD_TIP if short is None else f"{whose}\nRecord is free again when it ends")
        if short is not None:
            self.record_info.setText(short)
            self.record_info.setToolTip(whose)
            self.set_recording(False, short)
        elif was is not None:
            self.record_info.setToolTip("")
            self.set_recording(False, "not recording")

    def set_board_status(self, text: str, level: str) -> None:
        _show(self.board_status, text, status_style(level))

    def set_counters(self, text: str, level: str) -> None:
        _show(self.counters, text, status_style(level) if text else "")

    def set_message(self, text: str, level: str = "warn") -> None:
        _show(self.message, text, status_style(level) if text else "")

    def set_calibration(self, text: str, level: str, hint: str = "") -> None:
        """The calibration label; its tooltip is ``hint`` (what to do about it) after the text."""
        _show(self.calibration_label, text, status_style(level))
        self.calibration_label.setToolTip(f"{text}\n{hint}" if hint else text)

    def set_viewing_file(self, name: str | None) -> None:
        """Showing a past recording (``name``) instead of the live board, or live (None)."""
        self.live.setVisible(name is not None)
        self.export.setEnabled(name is not None)
        self.export.setToolTip(EXPORT_TIP if name is not None else EXPORT_DISABLED_TIP)
        if name is not None:
            self.set_message(f"showing recording {name}", "ok")


def _show(label: QLabel, text: str, style: str) -> None:
    """Set a status label's text and style only when they change: setStyleSheet re-polishes the label and, through
    the layout, repaints the window around it even when the style is the same (these arrive several times a
    second while streaming)."""
    if label.text() != text:
        label.setText(text)
    if label.styleSheet() != style:
        label.setStyleSheet(style)
