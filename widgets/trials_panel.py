"""The Trials panel: a trial series on the robot as the operator sees it — the series' options, the one thing to do
next in large type ("Place the robot, then Start trial 2 of 3"), the buttons for it, the outcome to mark, and every
trial's row.

A passive view: it shows what it is given (:meth:`TrialsPanel.set_phase`, :meth:`TrialsPanel.set_rows`, …) and emits
what the operator asks for; the series itself runs in app/gui/trials_session.py. What each phase lets the operator
do:

- ``idle``: fill the form, Start series or Resume series…;
- ``moving``: the robot goes to the start pose (nothing but STOP);
- ``ready``: Go to start pose (after a STOP, a fault or a resume: the robot moves only when asked);
- ``waiting``: Start trial k of N (the robot is at the start pose; the operator places it), Go to start pose again;
- ``recording``: nothing but STOP (Esc, or the status bar's button: the trial is kept, marked aborted);
- ``marking``: Traversed / Failed / Aborted, with a note;
- ``complete``: Add a trial, or End series.

GUI thread only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QFont, QKeyEvent
from PySide6.QtWidgets import (
    QAbstractItemView,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QPushButton,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

PHASES = ("idle", "moving", "ready", "waiting", "recording", "marking", "complete")
OUTCOMES = ("traversed", "failed", "aborted")
OUTCOME_LEVELS = {"traversed": theme.OK, "failed": theme.WARN, "aborted": theme.ERROR}
COLUMNS = ("Trial", "Outcome", "Status", "Duration s", "File", "Note")
STRAIGHT = "straight (every joint 0)"
MAX_NOTE_CHARS = 500  # a note fits the recording's run_stop room with the rest


@dataclass(frozen=True)
class SeriesForm:
    """What the form asks for a new series (the face turns names into files)."""

    shape: str
    start: str  # "" for straight, else a shape name
    mode: str
    speed_rad_s: float
    trials: int
    scene: str
    tail_load_n: float
    note: str
    folder: str


class TrialsPanel(QWidget):
    """See the module docstring."""

    start_series_requested = Signal(object)  # SeriesForm
    resume_requested = Signal()
    browse_folder_requested = Signal()
    open_shape_requested = Signal()
    go_to_start_requested = Signal()
    start_trial_requested = Signal()
    outcome_marked = Signal(str, str)  # outcome, note
    add_trial_requested = Signal()
    end_series_requested = Signal()

    def __init__(self, max_speed_rad_s: float = 1.0, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.phase = "idle"
        layout = QVBoxLayout(self)

        self.form_box = QGroupBox("Series: one condition, N trials, each its own recording")
        form = QFormLayout(self.form_box)
        shape_row = QHBoxLayout()
        self.shape_combo = QComboBox()
        self.shape_combo.setToolTip("The shape every trial plays (the Teach tab's library, or a file)")
        shape_row.addWidget(self.shape_combo, 1)
        self.shape_file_button = QToolButton()
        self.shape_file_button.setText("…")
        self.shape_file_button.setToolTip("A shape file outside the library")
        self.shape_file_button.clicked.connect(self.open_shape_requested)
        shape_row.addWidget(self.shape_file_button)
        form.addRow("Shape", shape_row)
        self.start_combo = QComboBox()
        self.start_combo.setToolTip("The pose the robot goes to before each trial, for the operator to place it")
        form.addRow("Start pose", self.start_combo)
        self.mode_combo = QComboBox()
        self.mode_combo.addItems(["follow", "keyframes"])
        form.addRow("Mode", self.mode_combo)
        self.speed_spin = QDoubleSpinBox()
        self.speed_spin.setRange(0.001, max_speed_rad_s)
        self.speed_spin.setDecimals(3)
        self.speed_spin.setSingleStep(0.01)
        self.speed_spin.setValue(min(0.034, max_speed_rad_s))
        self.speed_spin.setSuffix(" rad/s")
        form.addRow("Speed", self.speed_spin)
        self.trials_spin = QSpinBox()
        self.trials_spin.setRange(1, 1000)
        self.trials_spin.setValue(3)
        form.addRow("Trials", self.trials_spin)
        self.scene_edit = QLineEdit()
        self.scene_edit.setPlaceholderText("what the robot runs on: paper_obstacle, flat, …")
        form.addRow("Scene", self.scene_edit)
        self.tail_spin = QDoubleSpinBox()
        self.tail_spin.setRange(0.0, 100.0)
        self.tail_spin.setSuffix(" N")
        form.addRow("Tail load", self.tail_spin)
        self.note_edit = QLineEdit()
        self.note_edit.setMaxLength(MAX_NOTE_CHARS)
        self.note_edit.setPlaceholderText("kept in every trial's run_start")
        form.addRow("Note", self.note_edit)
        folder_row = QHBoxLayout()
        self.folder_edit = QLineEdit()
        folder_row.addWidget(self.folder_edit, 1)
        self.folder_button = QToolButton()
        self.folder_button.setText("…")
        self.folder_button.clicked.connect(self.browse_folder_requested)
        folder_row.addWidget(self.folder_button)
        form.addRow("Folder", folder_row)
        series_buttons = QHBoxLayout()
        self.start_series_button = QPushButton("Start series")
        self.start_series_button.setToolTip("The robot goes to the start pose, then waits for you to place it")
        self.start_series_button.clicked.connect(self._start_series)
        series_buttons.addWidget(self.start_series_button)
        self.resume_button = QPushButton("Resume series…")
        self.resume_button.setToolTip("Open a series folder: finished trials are kept, it goes on at the next one")
        self.resume_button.clicked.connect(self.resume_requested)
        series_buttons.addWidget(self.resume_button)
        series_buttons.addStretch(1)
        form.addRow(series_buttons)
        layout.addWidget(self.form_box)

        self.prompt_label = QLabel("Start a series, or resume one")
        font = QFont(self.prompt_label.font())
        font.setPointSizeF(font.pointSizeF() * 1.5)
        font.setBold(True)
        self.prompt_label.setFont(font)
        self.prompt_label.setWordWrap(True)
        self.prompt_label.setObjectName("trials_prompt")
        layout.addWidget(self.prompt_label)
        self.detail_label = QLabel("")
        self.detail_label.setWordWrap(True)
        layout.addWidget(self.detail_label)
        self.stop_hint = QLabel("Esc or STOP halts the robot at once; a trial stopped is kept, marked aborted")
        self.stop_hint.setStyleSheet(f"color: {theme.STOP_RED};")
        layout.addWidget(self.stop_hint)

        actions = QHBoxLayout()
        self.go_start_button = QPushButton("Go to start pose")
        self.go_start_button.clicked.connect(self.go_to_start_requested)
        actions.addWidget(self.go_start_button)
        self.start_trial_button = QPushButton("Start trial")
        self.start_trial_button.setDefault(True)
        self.start_trial_button.clicked.connect(self.start_trial_requested)
        actions.addWidget(self.start_trial_button)
        self.add_trial_button = QPushButton("Add a trial")
        self.add_trial_button.setToolTip("One more trial of this condition (to make up for an aborted one)")
        self.add_trial_button.clicked.connect(self.add_trial_requested)
        actions.addWidget(self.add_trial_button)
        actions.addStretch(1)
        self.end_button = QPushButton("End series")
        self.end_button.setToolTip("Close the series here; Resume series… goes on with it later")
        self.end_button.clicked.connect(self.end_series_requested)
        actions.addWidget(self.end_button)
        layout.addLayout(actions)

        outcome_row = QHBoxLayout()
        outcome_row.addWidget(QLabel("Outcome:"))
        self.outcome_buttons: dict[str, QPushButton] = {}
        for outcome in OUTCOMES:
            button = QPushButton(outcome.capitalize())
            button.setObjectName(f"outcome_{outcome}")
            button.clicked.connect(lambda _checked=False, o=outcome: self._mark(o))
            outcome_row.addWidget(button)
            self.outcome_buttons[outcome] = button
        self.outcome_note = QLineEdit()
        self.outcome_note.setMaxLength(MAX_NOTE_CHARS)
        self.outcome_note.setPlaceholderText("note on this trial (optional)")
        outcome_row.addWidget(self.outcome_note, 1)
        layout.addLayout(outcome_row)

        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setObjectName("trials_table")
        self.table.setHorizontalHeaderLabels(list(COLUMNS))
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.NoSelection)
        self.table.verticalHeader().setVisible(False)
        self.table.horizontalHeader().setSectionResizeMode(len(COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)
        layout.addWidget(self.table, 1)
        self.status_label = QLabel("")
        self.status_label.setWordWrap(True)
        self.status_label.setVisible(False)
        layout.addWidget(self.status_label)
        self.set_phase("idle", "Start a series, or resume one")

    # -- what the face shows ----------------------------------------------------------------------------------------
    def set_shapes(self, names: Sequence[str], current: str = "") -> None:
        """The shapes offered (for the motion, and as start poses)."""
        keep = current or self.shape_combo.currentText()
        self.shape_combo.clear()
        self.shape_combo.addItems(list(names))
        if keep and keep in names:
            self.shape_combo.setCurrentText(keep)
        start = self.start_combo.currentText()
        self.start_combo.clear()
        self.start_combo.addItems([STRAIGHT, *names])
        if start and start in names:
            self.start_combo.setCurrentText(start)

    def set_phase(self, phase: str, prompt: str, detail: str = "", trial_label: str = "Start trial") -> None:
        """Show ``phase`` (see the module docstring): the prompt in large type, what is possible enabled."""
        if phase not in PHASES:
            raise ValueError(f"phase must be one of {', '.join(PHASES)}, got {phase!r}")
        self.phase = phase
        self.prompt_label.setText(prompt)
        self.detail_label.setText(detail)
        self.detail_label.setVisible(bool(detail))
        self.form_box.setEnabled(phase == "idle")
        self.start_trial_button.setText(trial_label)
        self.go_start_button.setEnabled(phase in ("ready", "waiting"))
        self.start_trial_button.setEnabled(phase == "waiting")
        self.add_trial_button.setEnabled(phase in ("ready", "waiting", "complete"))
        self.end_button.setEnabled(phase in ("ready", "waiting", "marking", "complete"))
        marking = phase == "marking"
        for button in self.outcome_buttons.values():
            button.setEnabled(marking)
        self.outcome_note.setEnabled(marking)
        if not marking:
            self.outcome_note.clear()
        level = {"recording": theme.ERROR, "marking": theme.WARN, "waiting": theme.OK, "complete": theme.OK}
        self.prompt_label.setStyleSheet(theme.status_style(level.get(phase, theme.IDLE)))
        if phase == "waiting":
            self.start_trial_button.setFocus()

    def set_rows(self, rows: Sequence[tuple[str, str, str, str, str, str]]) -> None:
        """One row per trial: (trial, outcome, status, duration, file, note), as text."""
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for c, text in enumerate(row):
                item = self.table.item(r, c)
                if item is None:
                    item = QTableWidgetItem()
                    self.table.setItem(r, c, item)
                item.setText(text)
                if c == 1:
                    level = OUTCOME_LEVELS.get(text)
                    item.setForeground(theme.qcolor(theme.STATUS_COLORS[level]) if level else
                                       theme.qcolor(theme.STATUS_COLORS[theme.IDLE]))
                    item.setBackground(theme.qcolor(theme.STATUS_BACKGROUNDS[level]) if level else
                                       theme.qcolor("#FFFFFF", 0))
        self.table.resizeColumnsToContents()
        self.table.horizontalHeader().setSectionResizeMode(len(COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)

    def set_status(self, text: str, level: str = theme.IDLE) -> None:
        self.status_label.setText(text)
        self.status_label.setVisible(bool(text))
        self.status_label.setStyleSheet(theme.status_style(level) if text else "")

    def set_form(self, form: SeriesForm) -> None:
        """Show a series' options in the form (a resumed series: what it runs)."""
        for combo, name in ((self.shape_combo, form.shape), (self.start_combo, form.start or STRAIGHT)):
            if name and combo.findText(name) < 0:
                combo.addItem(name)
            combo.setCurrentText(name)
        self.mode_combo.setCurrentText(form.mode)
        self.speed_spin.setValue(form.speed_rad_s)
        self.trials_spin.setValue(form.trials)
        self.scene_edit.setText(form.scene)
        self.tail_spin.setValue(form.tail_load_n)
        self.note_edit.setText(form.note)
        self.folder_edit.setText(form.folder)

    def set_folder(self, folder: str) -> None:
        self.folder_edit.setText(folder)

    def form(self) -> SeriesForm:
        start = self.start_combo.currentText()
        return SeriesForm(shape=self.shape_combo.currentText(), start="" if start == STRAIGHT else start,
                          mode=self.mode_combo.currentText(), speed_rad_s=self.speed_spin.value(),
                          trials=self.trials_spin.value(), scene=self.scene_edit.text().strip(),
                          tail_load_n=self.tail_spin.value(), note=self.note_edit.text().strip(),
                          folder=self.folder_edit.text().strip())

    # -- the operator's requests ------------------------------------------------------------------------------------
    def _start_series(self) -> None:
        self.start_series_requested.emit(self.form())

    def _mark(self, outcome: str) -> None:
        if self.phase == "marking":
            self.outcome_marked.emit(outcome, self.outcome_note.text().strip())

    def keyPressEvent(self, event: QKeyEvent) -> None:  # noqa: N802 - Qt override
        """Enter starts the trial while the panel waits for it (Esc stays the window's STOP)."""
        if self.phase == "waiting" and event.key() in (Qt.Key.Key_Return, Qt.Key.Key_Enter):
            self.start_trial_requested.emit()
            return
        super().keyPressEvent(event)
