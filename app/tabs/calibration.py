"""The Calibration tab: load calibration trials, fit the sensor models, see measured against fitted conductance.

Trials are SPEC §3.1 CSVs (``time_s,force_N,conductance_S``), read with :mod:`app.calfiles`; the fit is
:func:`models.calibration.calibrate_sensor` (the same as ``sensnake fit``), run from a worker thread so the window never
waits for it, in a child process so it never starves the robot's control thread of the GIL. The plot overlays each
trial's measured conductance and the conductance the fitted SLS model predicts from its force — the model
``sensnake estimate`` and the Forces tab use. "Save" writes the sensor into a calibration
file (created, or updated keeping its other sensors).

Driving the rig through the 4-force × 3-trial protocol from this tab is not built yet; the rig's settings are shown.
GUI thread only, except :meth:`CalibrationTab._fit_worker`.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QAbstractItemView,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QListWidget,
    QPushButton,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from app import calfiles
from app.lab import LabContext
from devices.config import BoardConfig
from models.physics import PhysicsConstants
from widgets import theme

if TYPE_CHECKING:  # pragma: no cover
    from models.calibration import SensorCalibration

log = logging.getLogger(__name__)

DEFAULT_AREA_MM2 = 1400.0  # 1.4e-3 m², the paper's sensor pad
DESCRIPTION = (
    "Fit a sensor's models to its calibration trials: the rig holds a constant force on the sensor "
    "(F = k·r·(θ − θ_contact)) while its conductance is recorded — the paper's protocol is 4 forces × 3 trials. "
    "The fit gives the linear model and the creep-aware SLS model used by the Forces tab and `sensnake estimate`."
)
PLOT_MAX_POINTS = 4000  # per curve: trials are minutes at a few Hz; decimate anything longer for drawing


@dataclass(frozen=True)
class LoadedTrial:
    """A trial read from its CSV: name (file), time (s), applied force (N), measured conductance (S)."""

    name: str
    time_s: np.ndarray
    force_n: np.ndarray
    conductance_s: np.ndarray


@dataclass(frozen=True)
class FitResult:
    """A finished fit, with everything the tab shows and saves."""

    sensor: str
    calibration: SensorCalibration
    physics: PhysicsConstants
    trials: tuple[LoadedTrial, ...]
    fitted_s: tuple[np.ndarray, ...]  # SLS-predicted conductance per trial (S)


class CalibrationTab(QWidget):
    """Trials in, models out; see the module docstring."""

    fit_finished = Signal(object)  # FitResult
    fit_failed = Signal(str)

    def __init__(self, lab: LabContext, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        self.trials: list[LoadedTrial] = []
        self.physics = PhysicsConstants()
        self.physics_source = "paper defaults"
        self.result: FitResult | None = None
        self._fit_thread: threading.Thread | None = None
        self.fit_finished.connect(self._show_result)
        self.fit_failed.connect(self._show_failure)

        intro = QLabel(DESCRIPTION)
        intro.setWordWrap(True)
        rig = lab.config.rig
        rig_note = QLabel(f"Rig: port {rig.port}, servo {rig.servo_id}, wheel radius {rig.wheel_radius_m * 1e3:.0f} "
                          f"mm, spring {rig.spring_k_n_per_m:.0f} N/m, sensor {rig.sensor}. Driving the rig from "
                          "this tab is not built yet: load trials recorded with it.")
        rig_note.setWordWrap(True)
        rig_note.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")

        splitter = QSplitter(Qt.Orientation.Horizontal)
        splitter.addWidget(self._build_inputs())
        splitter.addWidget(self._build_results())
        splitter.setStretchFactor(0, 0)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([360, 900])

        layout = QVBoxLayout(self)
        layout.setContentsMargins(8, 8, 8, 8)
        layout.addWidget(intro)
        layout.addWidget(rig_note)
        layout.addWidget(splitter, 1)
        self._update_buttons()

    # -- construction ----------------------------------------------------------------------------------------------
    def _build_inputs(self) -> QWidget:
        column = QWidget()
        column.setMinimumWidth(320)
        layout = QVBoxLayout(column)
        layout.setContentsMargins(0, 0, 0, 0)

        trials_box = QGroupBox("Trials (time_s, force_N, conductance_S)")
        trials_layout = QVBoxLayout(trials_box)
        self.trial_list = QListWidget()
        self.trial_list.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        trials_layout.addWidget(self.trial_list, 1)
        row = QHBoxLayout()
        self.add_button = QPushButton("Add CSVs…")
        self.add_button.clicked.connect(self._choose_trials)
        self.remove_button = QPushButton("Remove")
        self.remove_button.clicked.connect(self._remove_selected)
        self.clear_button = QPushButton("Clear")
        self.clear_button.clicked.connect(self.clear_trials)
        for button in (self.add_button, self.remove_button, self.clear_button):
            row.addWidget(button)
        trials_layout.addLayout(row)
        layout.addWidget(trials_box, 1)

        sensor_box = QGroupBox("Sensor")
        form = QFormLayout(sensor_box)
        self.sensor_edit = QLineEdit(self.lab.config.rig.sensor)
        form.addRow("Name", self.sensor_edit)
        self.area_spin = QDoubleSpinBox()
        self.area_spin.setRange(1.0, 100_000.0)
        self.area_spin.setDecimals(1)
        self.area_spin.setSuffix(" mm²")
        self.area_spin.setValue(DEFAULT_AREA_MM2)
        form.addRow("Active area", self.area_spin)
        physics_row = QHBoxLayout()
        self.physics_label = QLabel(self.physics_source)
        self.physics_label.setToolTip("The paper's resistance–strain constants; K_contact is a placeholder until the "
                                      "lab measures ρ1, ρ2 and H. They are written into the calibration file.")
        physics_row.addWidget(self.physics_label, 1)
        self.physics_button = QPushButton("Load…")
        self.physics_button.setToolTip("Resistance–strain constants from a JSON file (a calibration file works)")
        self.physics_button.clicked.connect(self._choose_physics)
        physics_row.addWidget(self.physics_button)
        form.addRow("Physics", physics_row)
        layout.addWidget(sensor_box)

        row = QHBoxLayout()
        self.fit_button = QPushButton("Fit")
        self.fit_button.setObjectName("fit_button")
        self.fit_button.clicked.connect(self.start_fit)
        self.save_button = QPushButton("Save to calibration file…")
        self.save_button.clicked.connect(self._choose_save)
        row.addWidget(self.fit_button)
        row.addWidget(self.save_button)
        layout.addLayout(row)
        self.status_label = QLabel("Add trial CSVs, then Fit.")
        self.status_label.setWordWrap(True)
        layout.addWidget(self.status_label)
        return column

    def _build_results(self) -> QWidget:
        column = QWidget()
        layout = QVBoxLayout(column)
        layout.setContentsMargins(0, 0, 0, 0)
        self.plot = pg.PlotWidget(background="w")
        self.plot.setLabel("left", "conductance", units="S")
        self.plot.setLabel("bottom", "time", units="s")
        self.plot.showGrid(x=True, y=True, alpha=0.2)
        self.plot.setTitle("measured (solid) and SLS fit (dashed)", color="#444", size="10pt")
        self.legend = self.plot.addLegend(offset=(-10, 10))
        layout.addWidget(self.plot, 3)

        self.summary_label = QLabel("")
        self.summary_label.setWordWrap(True)
        self.summary_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        layout.addWidget(self.summary_label)

        self.trial_table = QTableWidget(0, 4)
        self.trial_table.setHorizontalHeaderLabels(["Trial", "Force (N)", "RMSE (S)", "Warnings"])
        self.trial_table.verticalHeader().setVisible(False)
        self.trial_table.verticalHeader().setDefaultSectionSize(22)
        self.trial_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        header = self.trial_table.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(3, QHeaderView.ResizeMode.Stretch)
        layout.addWidget(self.trial_table, 1)
        return column

    # -- trials and physics ----------------------------------------------------------------------------------------
    def add_trial_files(self, paths: list[str] | list[Path]) -> int:
        """Read trial CSVs; a bad file is reported (file:line) and skipped. Returns how many were added."""
        added = 0
        problems = []
        for path in paths:
            try:
                trial = calfiles.read_trial_csv(path)
            except (ValueError, OSError) as exc:
                problems.append(str(exc))
                continue
            name = Path(path).name
            self.trials.append(LoadedTrial(name, trial.time_s, trial.force_n, trial.conductance_s))
            self.trial_list.addItem(f"{name}  ({trial.time_s.size} samples, up to {np.max(trial.force_n):.2f} N)")
            added += 1
        if problems:
            self._set_status("; ".join(problems), theme.ERROR)
        elif added:
            self._set_status(f"{len(self.trials)} trial(s) loaded; Fit when ready.", theme.IDLE)
        self._plot_measured_only()
        self._update_buttons()
        return added

    def clear_trials(self) -> None:
        self.trials.clear()
        self.trial_list.clear()
        self.result = None
        self._plot_measured_only()
        self.trial_table.setRowCount(0)
        self.summary_label.clear()
        self._update_buttons()

    def load_physics(self, path: str | Path) -> bool:
        try:
            self.physics = calfiles.read_physics(path)
        except (ValueError, OSError) as exc:
            self._set_status(str(exc), theme.ERROR)
            return False
        self.physics_source = Path(path).name
        self.physics_label.setText(self.physics_source)
        return True

    def _remove_selected(self) -> None:
        rows = sorted((self.trial_list.row(item) for item in self.trial_list.selectedItems()), reverse=True)
        for row in rows:
            self.trial_list.takeItem(row)
            del self.trials[row]
        self._plot_measured_only()
        self._update_buttons()

    def _choose_trials(self) -> None:
        paths, _filter = QFileDialog.getOpenFileNames(self, "Calibration trials", str(Path.cwd()),
                                                      "Trial CSV (*.csv);;All files (*)")
        if paths:
            self.add_trial_files(paths)

    def _choose_physics(self) -> None:
        path, _filter = QFileDialog.getOpenFileName(self, "Physics constants", str(Path.cwd()),
                                                    "JSON (*.json);;All files (*)")
        if path:
            self.load_physics(path)

    # -- fitting ---------------------------------------------------------------------------------------------------
    @property
    def is_fitting(self) -> bool:
        return self._fit_thread is not None and self._fit_thread.is_alive()

    def start_fit(self) -> None:
        """Fit on a worker thread; ``fit_finished`` or ``fit_failed`` follows on the GUI thread."""
        sensor = self.sensor_edit.text().strip()
        if not sensor:
            self._set_status("name the sensor first (e.g. S06B)", theme.WARN)
            return
        if not self.trials or self.is_fitting:
            return
        area_m2 = self.area_spin.value() * 1e-6
        trials = tuple(self.trials)
        self._set_status(f"fitting {sensor} to {len(trials)} trial(s)…", theme.WARN)
        self._fit_thread = threading.Thread(target=self._fit_worker, args=(sensor, trials, area_m2, self.physics),
                                            name="calibration-fit", daemon=True)
        self._update_buttons(fitting=True)
        self._fit_thread.start()

    def _fit_worker(self, sensor: str, trials: tuple[LoadedTrial, ...], area_m2: float,
                    physics: PhysicsConstants) -> None:
        """Worker thread: the fit (in a child process) and the fitted curves; the outcome goes back through a
        queued signal."""
        # Imported here, off the GUI thread: the fitting stack takes seconds to load and the tab opens at once.
        from models.calibration import TrialInput, calibrate_sensor
        from models.sls import conductance_from_force

        saturation_s = 1.0 / BoardConfig().r_c_ohm  # the default readout's limit (SPEC §4), as `sensnake fit`
        inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
        try:
            # A fit is seconds of Python-level work: in this process it would hold the GIL against the robot's
            # control thread (missed ticks, a tripped feedback watchdog). A child process keeps the loop on time.
            with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
                cal = pool.submit(calibrate_sensor, inputs, area_m2, physics, saturation_s=saturation_s).result()
            fitted = tuple(np.asarray(conductance_from_force(t.time_s, t.force_n, cal.sls, area_m2, physics),
                                      dtype=np.float64) for t in trials)
        except (ValueError, ArithmeticError, LookupError, RuntimeError, OSError) as exc:
            # BrokenProcessPool (a RuntimeError) if the child died; the fit's own refusals are ValueErrors.
            self._deliver(self.fit_failed, f"fit refused: {exc}")
            return
        self._deliver(self.fit_finished, FitResult(sensor, cal, physics, trials, fitted))

    @staticmethod
    def _deliver(signal: Any, value: object) -> None:
        try:
            signal.emit(value)
        except RuntimeError:
            # The tab was closed while the fit ran: nobody is left to show the result.
            log.info("calibration fit finished after its tab was closed; result dropped")

    def _show_result(self, result: FitResult) -> None:
        self.result = result
        cal = result.calibration
        self._plot(result.trials, result.fitted_s)
        self.trial_table.setRowCount(len(cal.trials))
        for row, report in enumerate(cal.trials):
            cells = (report.name, f"{report.force_n:.3f}", f"{report.rmse_s:.3e}", "; ".join(report.warnings) or "—")
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setToolTip(text)
                if col in (1, 2):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.trial_table.setItem(row, col, item)
        sls = cal.sls
        lines = [f"<b>{result.sensor}</b> SLS: E0 = {float(sls.E0_Pa):.4g} Pa, E1 = {float(sls.E1_Pa):.4g} Pa, "
                 f"μ1 = {float(sls.mu1_Pa_s):.4g} Pa·s (τ = {float(sls.tau_s):.4g} s); RMSE {cal.rmse_s:.3e} S"]
        if cal.linear is not None:
            lines.append(f"linear: m = {cal.linear.model.m_S_per_N:.4e} S/N, d = {cal.linear.model.d_S:.4e} S")
        if cal.warnings:
            lines.append("warnings: " + "; ".join(cal.warnings))
        self.summary_label.setText("<br>".join(lines))
        self._set_status(f"fitted {result.sensor} to {len(cal.trials)} trial(s); Save to keep it.", theme.OK)
        self._update_buttons()

    def _show_failure(self, message: str) -> None:
        self._set_status(message, theme.ERROR)
        self._update_buttons()

    # -- saving ----------------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> bool:
        """Write the fitted sensor into a calibration file (other sensors kept); reports and returns success."""
        result = self.result
        if result is None:
            return False
        try:
            calfiles.update_calibration(path, result.sensor, result.calibration.to_dict(), result.physics)
        except (ValueError, OSError) as exc:
            self._set_status(f"not saved: {exc}", theme.ERROR)
            return False
        self._set_status(f"saved {result.sensor} to {path}", theme.OK)
        return True

    def _choose_save(self) -> None:
        path, _filter = QFileDialog.getSaveFileName(self, "Save calibration", str(Path.cwd() / "calibration.json"),
                                                    "Calibration (*.json)")
        if path:
            self.save(path)

    # -- drawing ---------------------------------------------------------------------------------------------------
    def _plot_measured_only(self) -> None:
        self._plot(tuple(self.trials), None)

    def _plot(self, trials: tuple[LoadedTrial, ...], fitted: tuple[np.ndarray, ...] | None) -> None:
        self.plot.clear()
        self.legend.clear()
        for index, trial in enumerate(trials):
            color = theme.series_color(index)
            step = max(1, trial.time_s.size // PLOT_MAX_POINTS)
            t = trial.time_s[::step]
            measured_pen = pg.mkPen(theme.qcolor(color, alpha=140), width=1)
            self.plot.plot(t, trial.conductance_s[::step], pen=measured_pen, name=trial.name)
            if fitted is not None:
                self.plot.plot(t, fitted[index][::step],
                               pen=pg.mkPen(color, width=2, style=Qt.PenStyle.DashLine))

    # -- helpers ---------------------------------------------------------------------------------------------------
    def _set_status(self, text: str, level: str) -> None:
        self.status_label.setText(text)
        self.status_label.setStyleSheet(theme.status_style(level))

    def _update_buttons(self, fitting: bool = False) -> None:
        fitting = fitting or self.is_fitting
        has_trials = bool(self.trials)
        self.fit_button.setEnabled(has_trials and not fitting)
        self.add_button.setEnabled(not fitting)
        self.remove_button.setEnabled(has_trials and not fitting)
        self.clear_button.setEnabled(has_trials and not fitting)
        self.save_button.setEnabled(self.result is not None and not fitting)

    def curves(self) -> list[Any]:
        """The plotted curves (measured and fitted), for tests and screenshots."""
        return self.plot.getPlotItem().listDataItems()


def create_tab(lab: LabContext) -> QWidget:
    return CalibrationTab(lab)
