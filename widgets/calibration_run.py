"""Views for a calibration run on the rig: the protocol form with its controls and progress, and the live trial plot.

Passive: :class:`ProtocolForm` holds the protocol's fields and emits ``run_requested``, ``pause_toggled(bool)`` and
``abort_requested``; the owner validates the fields and drives the rig. :class:`LiveTrialPlot` draws the trial in
progress (applied force and the sensor's conductance against trial time) from samples appended one at a time into
preallocated arrays. GUI thread only.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

FORCE_COLOR = "#1f77b4"
CONDUCTANCE_COLOR = "#d62728"
CONDITION_LOAD_S = 10.0  # a conditioning cycle's load and unload times (s): ProtocolSettings' defaults
INITIAL_CAPACITY = 4096  # samples per trial before the arrays double (370 s at 6 Hz is 2220)
REDRAW_MS = 100  # the live trial's redraws: at most 10 a second, whatever the samples' rate


def format_duration(seconds: float) -> str:
    """``3725`` → ``"1 h 02 min"``, ``95`` → ``"1 min 35 s"``, ``7`` → ``"7 s"``."""
    if not math.isfinite(seconds) or seconds < 0:
        return "—"
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    if minutes:
        return f"{minutes} min {secs:02d} s"
    return f"{secs} s"


class ProtocolForm(QWidget):
    """The protocol's fields, Run / Pause / Abort, progress and a message line; see the module docstring."""

    run_requested = Signal()
    pause_toggled = Signal(bool)
    abort_requested = Signal()

    def __init__(self, forces_text: str, trials_per_force: int, hold_s: float, rest_s: float, baseline_s: float,
                 ramp_s: float, sample_rate_hz: float, folder: str, parent: QWidget | None = None, *,
                 conditioning_in_form: bool = True) -> None:
        super().__init__(parent)
        form = QFormLayout()
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.AllNonFixedFieldsGrow)
        self.forces_edit = QLineEdit(forces_text)
        self.forces_edit.setToolTip("Forces in newtons, comma-separated, in the order they run (paper: 1.75, 3, 4, "
                                    "5.25)")
        form.addRow("Forces (N)", self.forces_edit)
        self.trials_spin = QSpinBox()
        self.trials_spin.setRange(1, 50)
        self.trials_spin.setValue(trials_per_force)
        form.addRow("Trials per force", self.trials_spin)
        self.hold_spin = _seconds_spin(hold_s, 1.0, 24 * 3600.0,
                                       "How long each force is held and recorded (paper: 370 s); shorter for a "
                                       "quick check")
        form.addRow("Hold", self.hold_spin)
        self.rest_spin = _seconds_spin(rest_s, 0.0, 24 * 3600.0, "Unloaded rest before each trial, so the sensor "
                                       "recovers from the previous load (and from the contact search)")
        form.addRow("Rest before each", self.rest_spin)
        self.baseline_spin = _seconds_spin(baseline_s, 0.0, 600.0, "Recorded unloaded before each load: the trial "
                                           "holds the baseline and the loading ramp (identifies E0)")
        form.addRow("Baseline", self.baseline_spin)
        self.ramp_spin = _seconds_spin(ramp_s, 0.0, 600.0, "The force rises linearly over this time at the start of "
                                       "the hold, so the record sees the loading (identifies E0)")
        form.addRow("Loading ramp", self.ramp_spin)
        self.rate_spin = QDoubleSpinBox()
        self.rate_spin.setRange(0.5, 100.0)
        self.rate_spin.setDecimals(1)
        self.rate_spin.setSuffix(" Hz")
        self.rate_spin.setValue(sample_rate_hz)
        form.addRow("Sample rate", self.rate_spin)
        # The conditioning fields: a row of this form, or (conditioning_in_form=False) a widget the owner places.
        self.conditioning_box = QWidget()
        condition_row = QHBoxLayout(self.conditioning_box)
        condition_row.setContentsMargins(0, 0, 0, 0)
        self.condition_check = QCheckBox("Condition first:")
        self.condition_check.setToolTip("Load and unload the sensor a few times before the protocol (piezo-resistive "
                                        "sheets are conditioned before calibration); not recorded as trials, logged "
                                        "in the session's conditioning.json; a resumed session does not repeat it")
        self.condition_cycles_spin = QSpinBox()
        self.condition_cycles_spin.setRange(1, 100)
        self.condition_cycles_spin.setValue(5)
        self.condition_cycles_spin.setSuffix(" cycles")
        self.condition_force_spin = QDoubleSpinBox()
        self.condition_force_spin.setRange(0.0, 100.0)
        self.condition_force_spin.setDecimals(2)
        self.condition_force_spin.setSuffix(" N")
        self.condition_force_spin.setSpecialValueText("top force")  # 0: the protocol's top force
        self.condition_force_spin.setToolTip("The conditioning force; 'top force' = the largest protocol force")
        for widget in (self.condition_check, self.condition_cycles_spin, self.condition_force_spin):
            condition_row.addWidget(widget)
        self.condition_check.toggled.connect(self._condition_toggled)
        if conditioning_in_form:
            form.addRow("Conditioning", self.conditioning_box)
        folder_row = QHBoxLayout()
        self.folder_edit = QLineEdit(folder)
        self.folder_edit.setToolTip("Each run writes its trial CSVs and protocol.json into a new folder here")
        browse = QToolButton()
        browse.setText("…")
        browse.setToolTip("Choose the folder")
        browse.clicked.connect(self._browse)
        folder_row.addWidget(self.folder_edit, 1)
        folder_row.addWidget(browse)
        form.addRow("Save under", folder_row)
        self.duration_label = QLabel()
        self.duration_label.setWordWrap(True)
        self.duration_label.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")

        buttons = QHBoxLayout()
        self.run_button = QPushButton("Run protocol")
        self.run_button.setObjectName("run_protocol_button")
        self.run_button.setToolTip("Find the contact, then hold each force and record; the trial list is replaced "
                                   "by this run's trials")
        self.run_button.clicked.connect(self.run_requested)
        self.pause_button = QPushButton("Pause")
        self.pause_button.setCheckable(True)
        self.pause_button.setToolTip("Pause after the trial in progress (a creep hold cannot be interrupted and "
                                     "resumed); the rig stays unloaded until Resume")
        self.pause_button.toggled.connect(self._pause_toggled)
        self.abort_button = QPushButton("Abort")
        self.abort_button.setToolTip("Stop now and take the load off; finished trials are kept (Esc / STOP too)")
        self.abort_button.clicked.connect(self.abort_requested)
        for button in (self.run_button, self.pause_button, self.abort_button):
            buttons.addWidget(button)

        self.progress_bar = QProgressBar()
        self.progress_bar.setRange(0, 1000)
        self.progress_bar.setTextVisible(True)
        self.progress_bar.setFormat("idle")
        self.progress_label = QLabel("")
        self.progress_label.setWordWrap(True)
        self.message_label = QLabel("")
        self.message_label.setWordWrap(True)
        self.message_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addLayout(form)
        layout.addWidget(self.duration_label)
        layout.addLayout(buttons)
        layout.addWidget(self.progress_bar)
        layout.addWidget(self.progress_label)
        layout.addWidget(self.message_label)
        layout.addStretch(1)
        for spin in (self.hold_spin, self.rest_spin, self.baseline_spin, self.rate_spin, self.trials_spin,
                     self.condition_cycles_spin):
            spin.valueChanged.connect(self._update_duration)
        self.forces_edit.textChanged.connect(self._update_duration)
        self.set_running(False)
        self._update_duration()

    # -- values ----------------------------------------------------------------------------------------------------
    def forces_count(self) -> int:
        return len([p for p in self.forces_edit.text().replace(";", ",").split(",") if p.strip()])

    def estimated_duration_s(self) -> float:
        """Run time (s) of the fields as they stand, without the contact search: the conditioning (each cycle's ramp,
        load and unload, :data:`CONDITION_LOAD_S` each), each trial and its rest."""
        n = self.forces_count() * self.trials_spin.value()
        cycles = self.condition_cycles()
        return (cycles * (self.ramp_spin.value() + 2 * CONDITION_LOAD_S)
                + n * (self.baseline_spin.value() + self.hold_spin.value() + self.rest_spin.value()))

    def condition_cycles(self) -> int:
        """Conditioning cycles asked for (0: off)."""
        return self.condition_cycles_spin.value() if self.condition_check.isChecked() else 0

    def set_conditioning(self, cycles: int, force_n: float) -> None:
        """Show a protocol's conditioning (0 cycles: off; force 0: the top force)."""
        self.condition_check.setChecked(cycles > 0)
        if cycles > 0:
            self.condition_cycles_spin.setValue(cycles)
        self.condition_force_spin.setValue(force_n)

    # -- state shown -----------------------------------------------------------------------------------------------
    def set_running(self, running: bool) -> None:
        for field in (self.forces_edit, self.trials_spin, self.hold_spin, self.rest_spin, self.baseline_spin,
                      self.ramp_spin, self.rate_spin, self.folder_edit, self.condition_check):
            field.setEnabled(not running)
        for field in (self.condition_cycles_spin, self.condition_force_spin):
            field.setEnabled(not running and self.condition_check.isChecked())
        self.run_button.setEnabled(not running)
        self.pause_button.setEnabled(running)
        self.abort_button.setEnabled(running)
        if not running:
            self.pause_button.blockSignals(True)
            self.pause_button.setChecked(False)
            self.pause_button.setText("Pause")
            self.pause_button.blockSignals(False)

    def show_progress(self, done_fraction: float, bar_text: str, detail: str) -> None:
        """``done_fraction`` of the whole run (0…1), the bar's text, and a line under it."""
        self.progress_bar.setValue(int(round(1000 * min(max(done_fraction, 0.0), 1.0))))
        self.progress_bar.setFormat(bar_text)
        self.progress_label.setText(detail)

    def clear_progress(self) -> None:
        """No run's progress shown (a new run was refused, or is starting): nothing of the last one stays."""
        self.show_progress(0.0, "no run", "")

    def set_message(self, text: str, level: str) -> None:
        self.message_label.setText(text)
        self.message_label.setStyleSheet(theme.status_style(level))

    # -- internals -------------------------------------------------------------------------------------------------
    def _pause_toggled(self, paused: bool) -> None:
        self.pause_button.setText("Resume" if paused else "Pause")
        self.pause_toggled.emit(paused)

    def _condition_toggled(self, on: bool) -> None:
        for field in (self.condition_cycles_spin, self.condition_force_spin):
            field.setEnabled(on and self.run_button.isEnabled())
        self._update_duration()

    def _update_duration(self, *_args: object) -> None:
        n = self.forces_count() * self.trials_spin.value()
        self.duration_label.setText(f"{n} trial(s) · about {format_duration(self.estimated_duration_s())} "
                                    "(+ the contact search)")

    def _browse(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Save calibration runs under", self.folder_edit.text())
        if folder:
            self.folder_edit.setText(folder)


def _seconds_spin(value: float, low: float, high: float, tip: str) -> QDoubleSpinBox:
    spin = QDoubleSpinBox()
    spin.setRange(low, high)
    spin.setDecimals(1)
    spin.setSuffix(" s")
    spin.setValue(value)
    spin.setToolTip(tip)
    return spin


class LiveTrialPlot(QWidget):
    """Applied force (N, top) and conductance (µS, bottom) of the trial in progress against trial time (s)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.title = QLabel("No run yet: the trial in progress is drawn here.")
        self.title.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")
        self.force_plot = pg.PlotWidget(background="w")
        self.force_plot.setLabel("left", "force (N)")
        self.force_plot.showGrid(x=True, y=True, alpha=0.2)
        self.conductance_plot = pg.PlotWidget(background="w")
        # Fixed units: pyqtgraph's automatic SI prefix turned µS into "mµS" around 0.
        for plot, side in ((self.force_plot, "left"), (self.conductance_plot, "left"),
                           (self.conductance_plot, "bottom")):
            theme.no_si_prefix(plot.getPlotItem().getAxis(side))
        self.conductance_plot.setLabel("left", "conductance (µS)")
        self.conductance_plot.setLabel("bottom", "trial time (s)")
        self.conductance_plot.showGrid(x=True, y=True, alpha=0.2)
        self.conductance_plot.setXLink(self.force_plot)
        for plot in (self.force_plot, self.conductance_plot):
            plot.getPlotItem().getAxis("left").setWidth(64)  # both plots' data areas line up
        self.force_curve = self.force_plot.plot(pen=pg.mkPen(FORCE_COLOR, width=2))
        self.command_line = pg.InfiniteLine(angle=0, movable=False,
                                            pen=pg.mkPen("#888", width=1, style=Qt.PenStyle.DashLine))
        self.force_plot.addItem(self.command_line)
        self.command_line.setVisible(False)
        self.conductance_curve = self.conductance_plot.plot(pen=pg.mkPen(CONDUCTANCE_COLOR, width=2))
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.title)
        layout.addWidget(self.force_plot, 2)
        layout.addWidget(self.conductance_plot, 3)
        self._t = np.empty(INITIAL_CAPACITY)
        self._f = np.empty(INITIAL_CAPACITY)
        self._c = np.empty(INITIAL_CAPACITY)
        self._n = 0
        self.trial = -1
        # Redrawn from one timer, never once per sample (a simulated lab at 15× sends 90 samples a wall second: a
        # redraw each held the GUI thread and starved the board's reader on a busy machine).
        self._drawn = 0
        self._redraw_posted = False

    @property
    def n_samples(self) -> int:
        return self._n

    def start_trial(self, trial: int, title: str, commanded_n: float, duration_s: float) -> None:
        """Clear the plot for a new trial: its index, a title, the commanded force (N), the expected length (s)."""
        self.trial = trial
        self._n = self._drawn = 0
        self.title.setText(title)
        self.command_line.setValue(commanded_n)
        self.command_line.setVisible(True)
        self.force_plot.setXRange(0.0, max(duration_s, 1.0), padding=0.02)
        self.force_plot.setYRange(0.0, max(commanded_n * 1.15, 0.5), padding=0.0)
        self.force_curve.setData([], [])
        self.conductance_curve.setData([], [])

    def clear(self, title: str = "") -> None:
        """Nothing drawn (a new run starts: the last run's trial must not look like this one's)."""
        self.trial = -1
        self._n = self._drawn = 0
        self.title.setText(title)
        self.command_line.setVisible(False)
        self.force_curve.setData([], [])
        self.conductance_curve.setData([], [])

    def append(self, time_s: float, force_n: float, conductance_s: float) -> None:
        """Add one sample (s, N, S); drawn at the next redraw (at most every ``REDRAW_MS``)."""
        if self._n == self._t.size:
            self._t, self._f, self._c = (np.concatenate([a, np.empty_like(a)]) for a in (self._t, self._f, self._c))
        self._t[self._n], self._f[self._n], self._c[self._n] = time_s, force_n, conductance_s * 1e6
        self._n += 1
        if not self._redraw_posted:
            self._redraw_posted = True
            QTimer.singleShot(REDRAW_MS, self, self._posted_redraw)

    def _posted_redraw(self) -> None:
        self._redraw_posted = False
        self.redraw()

    def redraw(self) -> None:
        """Draw the samples added since the last redraw."""
        n = self._n
        if n == self._drawn:
            return
        self._drawn = n
        self.force_curve.setData(self._t[:n], self._f[:n])
        finite = np.isfinite(self._c[:n])
        self.conductance_curve.setData(self._t[:n][finite], self._c[:n][finite])

    def data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the drawn samples: time (s), force (N), conductance (µS)."""
        n = self._n
        return self._t[:n].copy(), self._f[:n].copy(), self._c[:n].copy()
