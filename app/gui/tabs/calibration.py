"""The Calibration tab: load calibration trials, fit the sensor models, see measured against fitted conductance.

Trials are SPEC §3.1 CSVs (``time_s,force_N,conductance_S``), read with :mod:`app.core.calfiles`; the fit is
:func:`models.calibration.calibrate_with_drift` (the same as ``sensnake fit``: a baseline drift separated), run from a worker thread so the window never
waits for it, in a child process so it never starves the robot's control thread of the GIL. The plot overlays each
trial's measured conductance and the conductance the fitted SLS model predicts from its force — the model
``sensnake estimate`` and the Forces tab use. "Save" writes the sensor into a calibration
file (created, or updated keeping its other sensors).

"Run on the rig" drives the calibration rig through the paper's protocol (forces × trials, each held while the rig's
applied force and the sensor's conductance are sampled; :mod:`app.core.rig_protocol`) on the rig's own thread
(:mod:`app.gui.rig_session`). Each finished trial is written as a CSV into the run's folder and joins the trial list; a
completed run is fitted at once, with the linear model's window scaled to the hold. Abort, STOP (Esc) or a rig error
take the load off and keep the finished trials.
GUI thread only, except :meth:`CalibrationTab._fit_worker`.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, QTimer, Signal
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
    QMessageBox,
    QPushButton,
    QSplitter,
    QStackedWidget,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from app.core import calfiles, calibration_fit, user_folders
from app.core.calibration_wizard import CalibrationWizard, Facts, Step
from app.core.rig_protocol import (
    ABORTED,
    COMPLETED,
    Outcome,
    Progress,
    ProtocolSettings,
    Sample,
    TrialRecord,
    check_protocol,
    finished_trials,
    format_forces,
    parse_forces,
    read_session,
    readout_ceiling_s,
    reject_trial,
    unfinished_sessions,
)
from app.gui.lab import LabContext
from app.gui.rig_session import RigSession
from app.gui.thread_bridge import ThreadBridge
from devices.factory import is_sim
from models.physics import PhysicsConstants
from widgets import theme
from widgets.calibration_run import LiveTrialPlot, ProtocolForm, format_duration
from widgets.sensor_picker import SensorPicker

if TYPE_CHECKING:  # pragma: no cover
    from app.core.calibration_fit import SessionFit
    from models.calibration import SensorCalibration


DEFAULT_AREA_MM2 = 1400.0  # 1.4e-3 m², the paper's sensor pad
DESCRIPTION = (
    "Fit a sensor's models to its calibration trials: the rig holds a constant force on the sensor "
    "(F = k·r·(θ − θ_contact)) while its conductance is recorded — the paper's protocol is 4 forces × 3 trials. "
    "The fit gives the linear model and the creep-aware SLS model used by the Forces tab and `sensnake estimate`."
)
PLOT_MAX_POINTS = 4000  # per curve: trials are minutes at a few Hz; decimate anything longer for drawing
PARAM_LABELS = (("E0_Pa", "E0", "Pa"), ("E1_Pa", "E1", "Pa"), ("mu1_Pa_s", "μ1", "Pa·s"))
# The wizard's steps (pages of CalibrationTab.steps, in this order): app.core.calibration_wizard.
SETUP, RIG_CHECK, CONTACT, PROTOCOL, REVIEW, SAVE = Step
BOARD_CHECK_S = 5.0  # the rig check waits this long (wall s) for a sample of the sensor from the board
BOARD_CHECK_PATIENCE = 6  # … or up to this many times longer while the board's reader receives frames (a busy GUI)
PHASE_WORDS = {"contact": "finding the contact", "conditioning": "conditioning", "baseline": "baseline", "loading": "loading", "hold": "holding",
               "release": "releasing", "rest": "resting", "paused": "paused", "redo": "to run again",
               "done": "done"}


@dataclass(frozen=True)
class LoadedTrial:
    """A trial read from its CSV: name (file), time (s), applied force (N), measured conductance (S)."""

    name: str
    time_s: np.ndarray
    force_n: np.ndarray
    conductance_s: np.ndarray
    path: Path | None = None  # the CSV it came from


@dataclass(frozen=True)
class FitResult:
    """A finished fit, with everything the tab shows and saves."""

    sensor: str
    calibration: SensorCalibration
    physics: PhysicsConstants
    trials: tuple[LoadedTrial, ...]
    fitted_s: tuple[np.ndarray, ...]  # SLS-predicted conductance per trial (S)
    window_s: tuple[float, float] | None = None  # the linear model's window (s), None for the paper's default
    session: SessionFit | None = None  # what the trials showed + refusal reasons (app.core.calibration_fit)

    @property
    def problems(self) -> tuple[str, ...]:
        return self.session.problems if self.session is not None else ()


class CalibrationTab(QWidget):
    """Trials in, models out; see the module docstring."""

    fit_finished = Signal(object)  # FitResult
    fit_failed = Signal(str)
    rig_check_finished = Signal(bool)  # every line passed
    # A fit of the trials so far runs after a trial when the next one takes at least this long (wall s).
    LIVE_FIT_MIN_WALL_S = 30.0

    def __init__(self, lab: LabContext, parent: QWidget | None = None, views_in_steps: bool = False) -> None:
        """``views_in_steps``: the review views not shown at first (Live trial, Mean vs force, Parameters vs force,
        History) are built later, one a step (:func:`create_tab_in_steps`)."""
        super().__init__(parent)
        self.lab = lab
        self._views_in_steps = views_in_steps
        self.trials: list[LoadedTrial] = []
        self.physics = PhysicsConstants()
        self.physics_source = "paper defaults"
        self.result: FitResult | None = None
        self.fit_window_s: tuple[float, float] | None = None  # set by a rig run (window scaled to its hold)
        self.last_fit_window_s: tuple[float, float] | None = None  # the window the latest fit was started with
        self._fit_thread: threading.Thread | None = None
        self._bridge = ThreadBridge(self)  # fit worker → GUI thread: the tab updates, then the public signal goes out
        self.rig_session = RigSession(lab, self)
        self.run_settings: ProtocolSettings | None = None
        self.session_folder: Path | None = None  # the rig session the trial list comes from (redo, resume)
        # Asked before saving a fit with refusal reasons; tests replace it. Returns True to save anyway.
        self.confirm_save = self._ask_save_anyway
        self.rig_session.progress.connect(self._show_progress)
        self.rig_session.sample.connect(self._show_sample)
        self.rig_session.trial_saved.connect(self._trial_saved)
        self.rig_session.finished.connect(self._run_finished)

        intro = QLabel(DESCRIPTION)
        intro.setWordWrap(True)
        rig = lab.config.rig
        placed = "the simulated probe moves to it" if is_sim(rig.port) else "put its segment under the probe"
        rig_note = QLabel(f"Rig: port {rig.port}, servo {rig.servo_id}, wheel radius {rig.wheel_radius_m * 1e3:.0f} "
                          f"mm, spring {rig.spring_k_n_per_m:.0f} N/m (k·r = "
                          f"{rig.spring_k_n_per_m * rig.wheel_radius_m:.2f} N/rad), presses the sensor picked "
                          f"above ({placed}), "
                          f"at most {rig.max_force_n:g} N; board on {lab.config.board.port}, readout "
                          f"R_C = {lab.config.board.r_c_ohm:g} Ω, V_ref = {lab.config.board.v_ref_v:g} V: "
                          f"ceiling {readout_ceiling_s(lab.config.board) * 1e6:.0f} µS (saturated samples are not "
                          "fitted, as in `sensnake fit --config`).")
        rig_note.setWordWrap(True)
        rig_note.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")
        self.rig_note = rig_note
        defaults = ProtocolSettings()
        self.protocol_form = ProtocolForm(format_forces(defaults.forces_n), defaults.trials_per_force,
                                          defaults.hold_s, defaults.rest_s, defaults.baseline_s, defaults.ramp_s,
                                          defaults.sample_rate_hz, str(user_folders.calibrations_dir()),
                                          conditioning_in_form=False)
        self.protocol_form.run_requested.connect(self.start_run)
        self.protocol_form.pause_toggled.connect(self._pause_toggled)
        self.protocol_form.abort_requested.connect(self.rig_session.abort)
        # The wizard's step and what its steps found (Qt-free: app.core.calibration_wizard); the tab draws it.
        self.wizard = CalibrationWizard()
        self._check_rig_lines: list[Any] | None = None
        self._check_board_line: tuple[bool, str] | None = None
        self._live_fit_thread: threading.Thread | None = None
        self._live_fit_again = False
        self.live_fits_shown = 0  # fits of the trials so far shown during runs
        self._check_board: Any = None
        self._check_channel = 0

        splitter = QSplitter(Qt.Orientation.Horizontal)
        splitter.addWidget(self._build_inputs())
        splitter.addWidget(self._build_results())
        splitter.setStretchFactor(0, 0)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([440, 900])

        layout = QVBoxLayout(self)
        layout.setContentsMargins(8, 8, 8, 8)
        layout.addWidget(intro)
        layout.addWidget(splitter, 1)
        self.wizard.subscribe(self._show_wizard)
        self._show_wizard()
        self.show_unfinished_sessions()

    # -- construction ----------------------------------------------------------------------------------------------
    def _build_inputs(self) -> QWidget:
        """The wizard's column: the step's title, its page (a QStackedWidget), Back / Next and the status line."""
        column = QWidget()
        column.setMinimumWidth(340)
        layout = QVBoxLayout(column)
        layout.setContentsMargins(0, 0, 0, 0)
        self.step_label = QLabel()
        self.step_label.setStyleSheet("font-weight: bold;")
        layout.addWidget(self.step_label)
        self.steps = QStackedWidget()
        pages = {SETUP: self._build_setup_page, RIG_CHECK: self._build_check_page, CONTACT: self._build_contact_page,
                 PROTOCOL: self._build_protocol_page, REVIEW: self._build_review_page, SAVE: self._build_save_page}
        for step in Step:
            self.steps.addWidget(pages[step]())
        layout.addWidget(self.steps, 1)
        self.step_hint = QLabel("")
        self.step_hint.setWordWrap(True)
        layout.addWidget(self.step_hint)
        nav = QHBoxLayout()
        self.back_button = QPushButton("◀ Back")
        self.back_button.clicked.connect(lambda: self.go_to_step(self.wizard.step - 1))
        self.next_button = QPushButton("Next ▶")
        self.next_button.setObjectName("wizard_next_button")
        self.next_button.clicked.connect(lambda: self.go_to_step(self.wizard.step + 1))
        nav.addWidget(self.back_button)
        nav.addStretch(1)
        nav.addWidget(self.next_button)
        layout.addLayout(nav)
        self.status_label = QLabel("Pick the sensor, check the rig, run the protocol — or fit trial CSVs you have.")
        self.status_label.setWordWrap(True)
        self.status_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        layout.addWidget(self.status_label)
        return column

    @staticmethod
    def _wizard_page(note_text: str = "") -> tuple[QWidget, QVBoxLayout]:
        """A wizard page (no margins: the step frame has them), optionally opening with a wrapped note."""
        page = QWidget()
        layout = QVBoxLayout(page)
        layout.setContentsMargins(0, 0, 0, 0)
        if note_text:
            note = QLabel(note_text)
            note.setWordWrap(True)
            layout.addWidget(note)
        return page, layout

    def _build_setup_page(self) -> QWidget:
        page, layout = self._wizard_page()
        sensor_box = QGroupBox("Sensor")
        form = QFormLayout(sensor_box)
        self.sensor_edit = QLineEdit(self.lab.config.rig.sensor)
        self.sensor_edit.setToolTip("The sensor's name in the calibration file; a rig run reads the board channel "
                                    "of this name")
        form.addRow("Name", self.sensor_edit)
        self.sensor_picker = SensorPicker(self.lab.config.board.channel_names)
        self.sensor_picker.setToolTip("Click a sensor on the body to calibrate it (the rig presses the sensor named "
                                      "here)")
        self.sensor_picker.select(self.sensor_edit.text().strip())
        self.sensor_picker.picked.connect(self.sensor_edit.setText)
        self.sensor_edit.textChanged.connect(lambda text: self.sensor_picker.select(text.strip()))
        self.sensor_edit.textChanged.connect(self._sensor_changed)
        form.addRow("On the body", self.sensor_picker)
        self.area_spin = QDoubleSpinBox()
        self.area_spin.setRange(1.0, 100_000.0)
        self.area_spin.setDecimals(1)
        self.area_spin.setSuffix(" mm²")
        self.area_spin.setValue(self.lab.config.rig.area_m2 * 1e6 or DEFAULT_AREA_MM2)
        self.area_spin.setToolTip("The sensor's active area under the probe (the large flat probe covers it all)")
        form.addRow("Area under the probe", self.area_spin)
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
        layout.addWidget(self._rig_note_box())
        self.files_route_button = QPushButton("Fit trial CSVs you already have instead…")
        self.files_route_button.setToolTip("Skip the rig: go to Review, add trial CSVs and fit them")
        self.files_route_button.clicked.connect(lambda: self.go_to_step(REVIEW))
        layout.addWidget(self.files_route_button)
        layout.addStretch(1)
        return page

    def _rig_note_box(self) -> QWidget:
        box = QGroupBox("Rig and readout")
        box_layout = QVBoxLayout(box)
        box_layout.addWidget(self.rig_note)
        return box

    def _build_check_page(self) -> QWidget:
        page, layout = self._wizard_page(
            "Before anything moves: the rig servo answers and is an XM430-W350, its torque can be enabled, its "
            "position and current at rest are sane, and the board streams the chosen sensor. Next stays off until "
            "every line passes.")
        self.check_button = QPushButton("Check the rig")
        self.check_button.setObjectName("rig_check_button")
        self.check_button.clicked.connect(self.start_rig_check)
        layout.addWidget(self.check_button)
        self.check_table = QTableWidget(0, 3)
        self.check_table.setHorizontalHeaderLabels(["", "Check", "Seen / reason"])
        self.check_table.verticalHeader().setVisible(False)
        self.check_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.check_table.setWordWrap(True)
        header = self.check_table.horizontalHeader()
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(1, QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(2, QHeaderView.ResizeMode.Stretch)
        layout.addWidget(self.check_table, 1)
        return page

    def _build_contact_page(self) -> QWidget:
        page, layout = self._wizard_page()
        contact = QGroupBox("Find contact")
        contact_layout = QVBoxLayout(contact)
        text = QLabel("Where the probe touches the sensor: the servo winds in small steps from a slack cable while "
                      "its current is averaged at rest (the current rises with the cable's tension), then, from a "
                      "little before that angle, one encoder tick at a time until the sensor's own reading rises; "
                      "then the load comes off. Make sure the probe sits over the sensor and the cable is slack. "
                      "The run finds it again at its start (the cable may move in between).")
        text.setWordWrap(True)
        contact_layout.addWidget(text)
        self.contact_button = QPushButton("Find contact")
        self.contact_button.setObjectName("find_contact_button")
        self.contact_button.clicked.connect(self.find_contact)
        contact_layout.addWidget(self.contact_button)
        self.contact_label = QLabel("")
        self.contact_label.setWordWrap(True)
        self.contact_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        contact_layout.addWidget(self.contact_label)
        layout.addWidget(contact)
        conditioning = QGroupBox("Conditioning (optional)")
        conditioning_layout = QVBoxLayout(conditioning)
        text = QLabel("Piezo-resistive sheets are conditioned before calibration: N load/unload cycles at a chosen "
                      "force after the contact search, before the first trial. They are not recorded as trials; "
                      "each cycle is logged in the session's conditioning.json, and resuming a session does not "
                      "repeat a conditioning that finished.")
        text.setWordWrap(True)
        conditioning_layout.addWidget(text)
        conditioning_layout.addWidget(self.protocol_form.conditioning_box)
        layout.addWidget(conditioning)
        layout.addStretch(1)
        return page

    def _build_protocol_page(self) -> QWidget:
        rig_page = QWidget()
        rig_layout = QVBoxLayout(rig_page)
        rig_layout.setContentsMargins(0, 0, 0, 0)
        rig_layout.addWidget(self.protocol_form, 1)
        self.live_fit_label = QLabel("")
        self.live_fit_label.setWordWrap(True)
        self.live_fit_label.setToolTip("The trials recorded so far, fitted after each trial (the Fit view shows it)")
        rig_layout.addWidget(self.live_fit_label)
        resume_row = QHBoxLayout()
        self.resume_button = QPushButton("Resume a session…")
        self.resume_button.setToolTip("Continue a run cut short (abort, crash, closed app): its finished trials are "
                                      "kept and the rest run with its own protocol")
        self.resume_button.clicked.connect(self._choose_resume)
        resume_row.addWidget(self.resume_button)
        rig_layout.addLayout(resume_row)
        self.unfinished_label = QLabel("")
        self.unfinished_label.setWordWrap(True)
        rig_layout.addWidget(self.unfinished_label)
        return rig_page

    def _build_review_page(self) -> QWidget:
        page, layout = self._wizard_page(
            "The fit starts by itself when a run completes. Views on the right: Fit (Fig. 8B), Mean vs force "
            "(Fig. 9ii), Parameters vs force (Fig. 9iii). Redo a trial that went wrong.")
        layout.addWidget(self._build_trial_files(), 1)
        row = QHBoxLayout()
        self.fit_button = QPushButton("Fit")
        self.fit_button.setObjectName("fit_button")
        self.fit_button.clicked.connect(self.start_fit)
        self.redo_button = QPushButton("Redo selected trial")
        self.redo_button.setToolTip("Reject the selected trial (its CSV moves to the session's rejected/ folder) "
                                    "and run it again on the rig")
        self.redo_button.clicked.connect(self._redo_selected)
        row.addWidget(self.fit_button)
        row.addWidget(self.redo_button)
        layout.addLayout(row)
        return page

    def _build_save_page(self) -> QWidget:
        page, layout = self._wizard_page(
            "Save writes the sensor into a calibration file (its other sensors are kept); the Forces tab uses it at "
            "once, and the sensor's History view gets a row (drift of E0 between calibrations). A fit that is not "
            "fit to use asks for confirmation first.")
        self.save_button = QPushButton("Save to calibration file…")
        self.save_button.setToolTip("Write this sensor into a calibration file; other sensors in it are kept")
        self.save_button.clicked.connect(self._choose_save)
        layout.addWidget(self.save_button)
        layout.addStretch(1)
        return page

    def _build_trial_files(self) -> QWidget:
        page = QWidget()
        trials_layout = QVBoxLayout(page)
        trials_layout.setContentsMargins(4, 4, 4, 4)
        hint = QLabel("CSV files with columns time_s, force_N, conductance_S (one trial each)")
        hint.setWordWrap(True)
        hint.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")
        trials_layout.addWidget(hint)
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
        return page

    def _build_results(self) -> QWidget:
        self.view_tabs = QTabWidget()
        fit_page = QWidget()
        layout = QVBoxLayout(fit_page)
        layout.setContentsMargins(4, 4, 4, 4)
        self.plot = pg.PlotWidget(background="w")
        # Fixed µS (the unit of every other conductance on screen): pyqtgraph's automatic SI prefix switched this
        # axis between µS and mS by itself as trials were added.
        theme.no_si_prefix(self.plot.getPlotItem().getAxis("left"))
        self.plot.setLabel("left", "conductance (µS)")
        theme.no_si_prefix(self.plot.getPlotItem().getAxis("bottom"))
        self.plot.setLabel("bottom", "time (s)")
        self.plot.showGrid(x=True, y=True, alpha=0.2)
        self.plot.setTitle("measured (solid) and SLS fit (dashed)", color="#444", size="10pt")
        # Small text, two columns once there are many trials (_plot): a 12-trial legend ran off the plot. Bottom
        # right: trials rise from the baseline to a plateau, so the top right is where the traces are.
        self.legend = self.plot.addLegend(offset=(-10, -10), labelTextSize="8pt", verSpacing=-6,
                                          brush=pg.mkBrush(255, 255, 255, 200))
        layout.addWidget(self.plot, 3)

        self.summary_label = QLabel("")
        self.summary_label.setWordWrap(True)
        self.summary_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        layout.addWidget(self.summary_label)

        headers = ["Trial", "Force (N)", "E0 (Pa)", "E1 (Pa)", "μ1 (Pa·s)", "τ (s)", "RMSE (µS)", "Warnings"]
        self.trial_table = QTableWidget(0, len(headers))
        self.trial_table.setHorizontalHeaderLabels(headers)
        self.trial_table.verticalHeader().setVisible(False)
        self.trial_table.verticalHeader().setDefaultSectionSize(22)
        self.trial_table.setWordWrap(True)  # long warnings wrap in their row instead of being cut
        # A row of wrapped warnings can be taller than the view: scroll by pixel, so such a row starts at its top and the
        # next rows stay reachable (per-item scrolling showed one tall row bottom-aligned and nothing else).
        self.trial_table.setVerticalScrollMode(QAbstractItemView.ScrollMode.ScrollPerPixel)
        self.trial_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        header = self.trial_table.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(len(headers) - 1, QHeaderView.ResizeMode.Stretch)
        layout.addWidget(self.trial_table, 2)
        self.view_tabs.addTab(fit_page, "Fit")
        self._pending_views = self.review_view_steps()
        if not self._views_in_steps:
            self.build_pending_views()
        return self.view_tabs

    def build_next_view(self) -> bool:
        """Build the next review view still to be built; returns whether one was."""
        if not self._pending_views:
            return False
        self._pending_views.pop(0)()
        return True

    def build_pending_views(self) -> None:
        """Every review view not built yet, now (whatever needs one calls this first)."""
        while self.build_next_view():
            pass

    def review_view_steps(self) -> list[Callable[[], None]]:
        """The views after Fit, each a step (~10-30 ms: a plot each): built at once, or one per turn of the event
        loop when the tab opens in steps (nothing reaches them before a run or a fit, seconds later)."""

        def live() -> None:
            self.live_plot = LiveTrialPlot()
            self.view_tabs.addTab(self.live_plot, "Live trial")

        def means() -> None:
            self.mean_plot = _review_plot("force (N)", "mean conductance (µS)",
                                          "window mean vs force, linear fit dashed (paper Fig. 9ii)")
            self.view_tabs.addTab(self.mean_plot, "Mean vs force")

        def params() -> None:
            self.param_plot = _review_plot("force (N)", "parameter (Pa, Pa·s)",
                                           "E0, E1, μ1 per trial vs force, trend dashed (paper Fig. 9iii)")
            self.param_plot.setLogMode(y=True)
            self.param_plot.addLegend(offset=(-10, 10), labelTextSize="8pt")
            self.view_tabs.addTab(self.param_plot, "Parameters vs force")

        def history() -> None:
            headers = ["Saved", "E0 (Pa)", "E1 (Pa)", "μ1 (Pa·s)", "τ (s)", "m (µS/N)", "unloaded (µS)",
                       "Δ E0 vs previous"]
            self.history_table = QTableWidget(0, len(headers))
            self.history_table.setHorizontalHeaderLabels(headers)
            self.history_table.verticalHeader().setVisible(False)
            self.history_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
            self.history_table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
            self.view_tabs.addTab(self.history_table, "History")

        return [live, means, params, history]

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
            self.trials.append(LoadedTrial(name, trial.time_s, trial.force_n, trial.conductance_s, Path(path)))
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
        self.fit_window_s = None
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
        paths, _filter = QFileDialog.getOpenFileNames(self, "Calibration trials",
                                                      user_folders.dialog_folder(user_folders.calibrations_dir()),
                                                      "Trial CSV (*.csv);;All files (*)")
        if paths:
            self.add_trial_files(paths)

    def _choose_physics(self) -> None:
        path, _filter = QFileDialog.getOpenFileName(self, "Physics constants",
                                                    user_folders.dialog_folder(user_folders.calibrations_dir()),
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
        self.last_fit_window_s = self.fit_window_s
        self._fit_thread = threading.Thread(target=self._fit_worker,
                                            args=(sensor, trials, area_m2, self.physics, self.fit_window_s,
                                                  self.lab.config.board),
                                            name="calibration-fit", daemon=True)
        self._update_buttons(fitting=True)
        self._fit_thread.start()

    def _fit_worker(self, sensor: str, trials: tuple[LoadedTrial, ...], area_m2: float,
                    physics: PhysicsConstants, window_s: tuple[float, float] | None = None,
                    board: Any = None, live: bool = False) -> None:
        """Worker thread: the fit (in a child process) and the fitted curves; the outcome goes back through a
        queued signal. ``window_s``: the linear model's averaging window (s), None for the paper's 225–300 s;
        ``board``: the lab's readout circuit (its ceiling 1/R_C is not fitted), the same as ``sensnake fit
        --config`` and ``sensnake calibrate`` use, so the tab and the CLI agree on the same files. ``live``: a fit of
        the trials so far during a run (shown, never saved: :meth:`_on_live_fit`)."""
        deliver = (lambda outcome: self._bridge.post(self._on_live_fit, outcome)) if live else self._deliver
        # Imported here, off the GUI thread: the fitting stack takes seconds to load and the tab opens at once.
        from models.calibration import TrialInput
        from models.linear import DEFAULT_WINDOW_S

        board = board if board is not None else self.lab.config.board
        inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
        try:
            # A fit is seconds of Python-level work: in this process it would hold the GIL against the robot's
            # control thread (missed ticks, a tripped feedback watchdog). A child process keeps the loop on time.
            # …and at a lower CPU priority: the fit (with its drift search, seconds of CPU) must not take the cores
            # the robot's loop and the simulated lab need (it cost 88 of 252 ticks at 50 Hz on 2 cores without it).
            with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=calibration_fit.yield_cpu) as pool:
                session, fitted = pool.submit(calibration_fit.fit_trials_with_curves, inputs, sensor, area_m2,
                                              physics, board, window_s or DEFAULT_WINDOW_S).result()
            cal = session.calibration
        except (ValueError, ArithmeticError, LookupError, RuntimeError, OSError) as exc:
            # BrokenProcessPool (a RuntimeError) if the child died; the fit's own refusals are ValueErrors.
            deliver(f"fit refused: {exc}")
            return
        deliver(FitResult(sensor, cal, physics, trials, fitted, window_s, session))

    def _deliver(self, outcome: FitResult | str) -> None:
        """Worker thread: hand the outcome (a result, or the refusal's message) to the GUI thread. Dropped by the
        bridge if the tab was closed while the fit ran: nobody is left to show it."""
        self._bridge.post(self._on_fit_outcome, outcome)

    def _fit_done(self) -> None:
        """The worker's last act is the signal that brought us here: wait for it to exit so ``is_fitting`` is False
        (without this the buttons could stay disabled when the signal is handled before the thread has ended)."""
        thread, self._fit_thread = self._fit_thread, None
        if thread is not None:
            thread.join()

    def _on_fit_outcome(self, outcome: FitResult | str) -> None:
        """GUI thread: show the outcome, then tell listeners (so they see the tab already updated)."""
        self._fit_done()
        if isinstance(outcome, FitResult):
            self._show_result(outcome)
            self.fit_finished.emit(outcome)
        else:
            self._show_failure(outcome)
            self.fit_failed.emit(outcome)

    def _show_result(self, result: FitResult) -> None:
        self.build_pending_views()
        self.result = result
        cal = result.calibration
        self._plot(result.trials, result.fitted_s)
        self._fill_table(cal)
        self.summary_label.setText(summary_html(result))
        n_warn = len(cal.warnings)
        level = theme.WARN if n_warn else theme.OK
        note = f" with {n_warn} warning(s) — read them before saving" if n_warn else ""
        if result.problems:
            self._set_status(f"fitted {result.sensor}, but NOT fit to use: {'; '.join(result.problems)}. Saving "
                             "asks for confirmation; redo trials or run again.", theme.ERROR)
        else:
            self._set_status(f"fitted {result.sensor} to {len(cal.trials)} trial(s){note}; Save to keep it.", level)
        self._plot_review(result)
        self.go_to_step(REVIEW)
        self.view_tabs.setCurrentIndex(0)
        self._update_buttons()

    def _fill_table(self, cal: SensorCalibration) -> None:
        self.trial_table.setRowCount(len(cal.trials))
        for row, report in enumerate(cal.trials):
            params = report.params
            cells = (report.name, f"{report.force_n:.3f}", f"{float(params.E0_Pa):.4g}", f"{float(params.E1_Pa):.4g}",
                     f"{float(params.mu1_Pa_s):.4g}", f"{float(params.tau_s):.4g}", f"{report.rmse_s * 1e6:.4g}",
                     "; ".join(report.warnings) or "—")
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setToolTip(text if col in (0, len(cells) - 1) else _interval_tip(report.ci95, col))
                # Top-aligned: a row grown by wrapped warnings reads from its first line, not from its middle.
                horizontal = Qt.AlignmentFlag.AlignRight if 0 < col < len(cells) - 1 else Qt.AlignmentFlag.AlignLeft
                item.setTextAlignment(horizontal | Qt.AlignmentFlag.AlignTop)
                if col == len(cells) - 1 and report.warnings:
                    item.setForeground(theme.qcolor(theme.STATUS_COLORS[theme.WARN]))
                self.trial_table.setItem(row, col, item)
        self.trial_table.resizeRowsToContents()
        self.trial_table.scrollToTop()

    # -- the fit of the trials so far, during a run ----------------------------------------------------------------
    def _maybe_live_fit(self) -> None:
        """After a trial of a run: fit the trials so far in the background (Fit view, table, summary and the protocol
        page's line update; nothing can be saved from it). Only when the next trial takes at least
        :attr:`LIVE_FIT_MIN_WALL_S` of wall time — on the paper's protocol ~12 min, on an accelerated sim seconds,
        where a fit per trial would only compete with the rig's thread — and not for the last trial (the run's own
        fit follows it). A trial that ends while a live fit runs asks for another one after it."""
        settings = self.run_settings
        if settings is None or not self.rig_session.is_running or len(self.trials) >= settings.n_trials:
            return
        next_trial_wall_s = (settings.trial_duration_s() + settings.rest_s) / max(self.rig_session.time_scale, 1e-9)
        if next_trial_wall_s < self.LIVE_FIT_MIN_WALL_S:
            return
        if self._live_fit_thread is not None and self._live_fit_thread.is_alive():
            self._live_fit_again = True
            return
        self._live_fit_again = False
        self._live_fit_thread = threading.Thread(
            target=self._fit_worker, args=(settings.sensor, tuple(self.trials), settings.area_m2, self.physics,
                                           self.fit_window_s, self.lab.config.board, True),
            name="calibration-live-fit", daemon=True)
        self._live_fit_thread.start()

    def _on_live_fit(self, outcome: FitResult | str) -> None:
        """GUI thread: show the fit of the trials so far, if the run is still going (else the run's own fit, or its
        abort, has the last word)."""
        thread, self._live_fit_thread = self._live_fit_thread, None
        if thread is not None:
            thread.join()
        if not self.rig_session.is_running:
            return
        if isinstance(outcome, FitResult):
            cal = outcome.calibration
            self._plot(outcome.trials, outcome.fitted_s)
            self._fill_table(cal)
            self.summary_label.setText(f"<i>Fit of the {len(cal.trials)} trial(s) so far — it updates after each "
                                       "trial; the run's own fit follows its last trial.</i><br>"
                                       + summary_html(outcome))
            line = (f"fit so far ({len(cal.trials)} trial(s)): τ = {float(cal.sls.tau_s):.4g} s, E0 = "
                    f"{float(cal.sls.E0_Pa):.4g} Pa, RMSE {cal.rmse_s * 1e6:.3g} µS")
        else:
            line = f"fit so far: {outcome}"
        self.live_fit_label.setText(line)
        self.live_fits_shown += 1
        if self._live_fit_again:
            self._maybe_live_fit()

    def _show_failure(self, message: str) -> None:
        self._set_status(message, theme.ERROR)
        self._update_buttons()

    # -- running the protocol on the rig ---------------------------------------------------------------------------
    def protocol_settings(self) -> ProtocolSettings:
        """The protocol from the form and the sensor box; ValueError naming the field that is wrong."""
        form = self.protocol_form
        return ProtocolSettings(
            forces_n=parse_forces(form.forces_edit.text()), trials_per_force=form.trials_spin.value(),
            hold_s=form.hold_spin.value(), sample_rate_hz=form.rate_spin.value(), rest_s=form.rest_spin.value(),
            baseline_s=form.baseline_spin.value(), ramp_s=form.ramp_spin.value(), sensor=self.sensor_edit.text().strip(),
            area_m2=self.area_spin.value() * 1e-6, condition_cycles=form.condition_cycles(),
            condition_force_n=form.condition_force_spin.value() if form.condition_cycles() else 0.0)

    def start_run(self, resume: Path | None = None) -> bool:
        """Start the protocol on the rig (Run button); False, with the reason shown, if it cannot start. ``resume``:
        a session folder whose protocol the form already shows (:meth:`resume_run`)."""
        if self.rig_session.is_running or self.is_fitting:
            return False
        self.build_pending_views()
        try:
            settings = self.protocol_settings()
            check = check_protocol(settings, self.lab.config.rig, self.lab.config.board,
                                   expected_sls=self.last_calibration(settings.sensor, settings.area_m2))
            if not check.ok:
                raise ValueError("protocol refused: " + "; ".join(check.errors))
            folder = self.rig_session.start(settings, self.protocol_form.folder_edit.text().strip()
                                                 or user_folders.calibrations_dir(), resume=resume)
        except ValueError as exc:
            self.protocol_form.set_message(str(exc), theme.ERROR)
            self.protocol_form.clear_progress()  # the last run's progress would read as this one's
            return False
        self.run_settings = settings
        self.session_folder = folder
        self.live_plot.clear(f"{settings.sensor}: waiting for the first trial…")
        self.live_fit_label.setText("")
        self.clear_trials()
        if resume is not None:
            self.add_trial_files([p for _, p in sorted(finished_trials(folder, settings).items())])
        self.fit_window_s = settings.fit_window_s()
        self.protocol_form.set_running(True)
        warnings = "".join(f"; warning: {w}" for w in check.warnings)
        self.protocol_form.set_message(f"running; trials go to {folder}{warnings}", theme.WARN)
        self.protocol_form.show_progress(0.0, f"0/{settings.n_trials} trials", "opening the rig…")
        self.go_to_step(PROTOCOL)
        self.view_tabs.setCurrentWidget(self.live_plot)
        self._set_status(f"rig run on {settings.sensor}: {settings.n_trials} trial(s)", theme.WARN)
        self._update_buttons()
        return True

    def last_calibration(self, sensor: str, area_m2: float) -> tuple[Any, float, PhysicsConstants] | None:
        """This sensor's last saved calibration (the calibration history), as the protocol check's prediction of
        its reading: (SLS parameters, area, physics); None when it has none."""
        from models.sls_model import SLSParams

        for record in reversed(calibration_fit.read_history(user_folders.calibrations_dir(), sensor)):
            sls = record.get("sls") or {}
            if record.get("refusal_reasons"):
                continue  # a calibration saved despite its problems predicts nothing
            try:
                return SLSParams.from_dict(sls), area_m2, self.physics
            except (KeyError, TypeError, ValueError):
                continue
        return None

    def resume_run(self, folder: str | Path) -> bool:
        """Continue the session in ``folder`` (after an abort, a crash or an app restart): its protocol goes into the
        form, its finished trials into the list, and the run continues with the first missing trial."""
        if self.rig_session.is_running or self.is_fitting:
            return False
        try:
            settings = read_session(folder)
        except ValueError as exc:
            self.protocol_form.set_message(str(exc), theme.ERROR)
            return False
        form = self.protocol_form
        form.forces_edit.setText(format_forces(settings.forces_n))
        form.trials_spin.setValue(settings.trials_per_force)
        for spin, value in ((form.hold_spin, settings.hold_s), (form.rest_spin, settings.rest_s),
                            (form.baseline_spin, settings.baseline_s), (form.ramp_spin, settings.ramp_s),
                            (form.rate_spin, settings.sample_rate_hz)):
            spin.setValue(value)
        form.set_conditioning(settings.condition_cycles, settings.condition_force_n)
        self.sensor_edit.setText(settings.sensor)
        self.area_spin.setValue(settings.area_m2 * 1e6)
        form.folder_edit.setText(str(Path(folder).parent))
        self.go_to_step(PROTOCOL)
        return self.start_run(resume=Path(folder))

    def redo_trial(self, row: int) -> bool:
        """Reject trial ``row`` of the list (its CSV moves to the session's ``rejected/``) and run it again."""
        folder = self.session_folder
        path = self.trials[row].path if 0 <= row < len(self.trials) else None
        if folder is None or path is None:
            self._set_status("only a trial of a rig session can be redone (run the protocol first)", theme.WARN)
            return False
        moved = reject_trial(path)
        if not self.resume_run(folder):
            self._set_status(f"rejected {moved.name} (kept in {moved.parent}); resume the session to run it again",
                             theme.WARN)
            return False
        # After start_run's own status line, which would hide what happened to the trial.
        self._set_status(f"rejected {moved.name} (kept in {moved.parent}); running it again", theme.WARN)
        return True

    def _redo_selected(self) -> None:
        rows = sorted(self.trial_list.row(item) for item in self.trial_list.selectedItems())
        if len(rows) == 1:
            self.redo_trial(rows[0])
        else:
            self._set_status("select one trial in the Trial files list to redo", theme.WARN)

    def _choose_resume(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Resume a calibration session",
                                                  user_folders.dialog_folder(user_folders.calibrations_dir()))
        if folder:
            self.resume_run(folder)

    def show_unfinished_sessions(self) -> None:
        """Name the newest unfinished session under the run folder (offered after an app restart)."""
        base = self.protocol_form.folder_edit.text().strip() or user_folders.calibrations_dir()
        found = unfinished_sessions(base)
        if not found:
            self.unfinished_label.setText("")
            return
        folder, settings, done = found[0]
        self.unfinished_label.setText(f"Unfinished session {folder.name}: {done}/{settings.n_trials} trials of "
                                      f"{settings.sensor}; Resume a session… to finish it.")
        self.unfinished_label.setStyleSheet(theme.status_style(theme.WARN))

    def _pause_toggled(self, paused: bool) -> None:
        if paused:
            self.rig_session.pause()
            self.protocol_form.set_message("pause requested: the run waits, unloaded, after the trial in progress",
                                           theme.WARN)
        else:
            self.rig_session.resume()
            self.protocol_form.set_message("resumed", theme.WARN)

    def _show_progress(self, progress: Progress) -> None:
        if self.wizard.contact_running:
            if progress.phase != "done":
                self._show_contact(progress.message, theme.WARN)
            return
        settings = self.run_settings
        if settings is None:
            return
        total = max(settings.total_duration_s(), 1e-9)
        done = 1.0 - progress.time_left_s / total if progress.phase != "contact" else 0.0
        finished = max(0, progress.trial + (1 if progress.phase in ("release", "done") else 0))
        bar = f"{finished}/{progress.n_trials} trials"
        if progress.phase == "done":
            self.protocol_form.show_progress(1.0 if finished == progress.n_trials else done, bar, progress.message)
            return
        phase = PHASE_WORDS.get(progress.phase, progress.phase)
        left_s = progress.time_left_s / max(self.rig_session.time_scale, 1e-9)  # wall time (the sim may run fast)
        if progress.trial >= 0 and progress.phase not in ("rest", "paused", "redo"):
            detail = (f"trial {progress.trial + 1}/{progress.n_trials} · {progress.force_n:g} N, repeat "
                      f"{progress.repeat} · {phase} {progress.elapsed_s:.0f}/{settings.trial_duration_s():.0f} s · "
                      f"about {format_duration(left_s)} left")
        else:
            detail = f"{progress.message} · about {format_duration(left_s)} left"
        self.protocol_form.show_progress(done, bar, detail)

    def _show_sample(self, sample: Sample) -> None:
        settings = self.run_settings
        if settings is None:
            return
        if sample.trial != self.live_plot.trial:
            force, repeat = settings.plan[sample.trial]
            self.live_plot.start_trial(sample.trial, f"{settings.sensor} · trial {sample.trial + 1}/"
                                       f"{settings.n_trials} · {force:g} N, repeat {repeat}", force,
                                       settings.trial_duration_s())
        self.live_plot.append(sample.time_s, sample.force_n, sample.conductance_s)

    def _trial_saved(self, record: TrialRecord) -> None:
        self.add_trial_files([record.path])
        settings = self.run_settings
        total = settings.n_trials if settings is not None else "?"
        self._set_status(f"trial {record.index + 1}/{total} saved: {record.path.name}", theme.WARN)
        self._maybe_live_fit()

    def _run_finished(self, outcome: Outcome) -> None:
        if self.wizard.contact_running:
            self._contact_finished(outcome)
            return
        self.protocol_form.set_running(False)
        self.show_unfinished_sessions()
        self.live_plot.trial = -1
        level = {COMPLETED: theme.OK, ABORTED: theme.WARN}.get(outcome.status, theme.ERROR)
        self.protocol_form.set_message(outcome.message, level)
        self._update_buttons()
        if outcome.status == COMPLETED:
            self._set_status(f"run complete: {len(outcome.trials)} trial(s) in {outcome.folder}; fitting…", theme.OK)
            self.start_fit()
        elif outcome.trials:
            self._set_status(f"run {outcome.status}: {len(outcome.trials)} trial(s) kept in the list; Fit them if "
                             "they cover what you need, or run again", level)
        else:
            self._set_status(f"run {outcome.status}: no trial was recorded", level)

    def shutdown(self) -> None:
        """The window is closing: abort a run and wait until the rig has released the load and closed."""
        self._stop_board_check()
        self.rig_session.shutdown()

    # -- saving ----------------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> bool:
        """Write the fitted sensor into a calibration file (other sensors kept); reports and returns success."""
        result = self.result
        if result is None:
            return False
        if result.problems and not self.confirm_save(result.problems):
            self._set_status(f"not saved: {result.sensor}'s fit is not fit to use ({'; '.join(result.problems)})",
                             theme.WARN)
            return False
        try:
            if result.session is not None:
                calibration_fit.save(path, result.session, result.physics, self.lab.config.board)
            else:
                calfiles.update_calibration(path, result.sensor, result.calibration.to_dict(), result.physics,
                                            calfiles.readout_of(self.lab.config.board))
        except (ValueError, OSError) as exc:
            self._set_status(f"not saved: {exc}", theme.ERROR)
            return False
        history_note = ""
        if result.session is not None:
            try:
                calibration_fit.append_history(user_folders.calibrations_dir(), result.session, path)
            except OSError as exc:
                history_note = f"; its history was not kept: {exc}"
        self.show_history(result.sensor)
        note = " (confirmed despite: " + "; ".join(result.problems) + ")" if result.problems else ""
        self._set_status(f"saved {result.sensor} to {path}; the Forces tab uses it now{note}{history_note}",
                         theme.WARN if history_note else theme.OK)
        self.lab.calibration_saved.emit(str(path))
        return True

    def _ask_save_anyway(self, problems: tuple[str, ...]) -> bool:
        answer = QMessageBox.warning(
            self, "Save a calibration that is not fit to use?",
            "This fit should not be used as it is:\n\n" + "\n".join(f"• {p}" for p in problems)
            + "\n\nSave it anyway (it is marked in the file)?",
            QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Cancel)
        return answer == QMessageBox.StandardButton.Save

    def show_history(self, sensor: str) -> None:
        """The saved calibrations of ``sensor`` (History view): parameters and the change of E0 between them."""
        self.build_pending_views()
        records = calibration_fit.read_history(user_folders.calibrations_dir(), sensor)
        self.history_table.setRowCount(len(records))
        previous = None
        for row, record in enumerate(records):
            sls = record.get("sls", {})
            linear = record.get("linear") or {}
            e0 = sls.get("E0_Pa")
            drift = (f"{100 * (e0 / previous - 1):+.1f} %" if isinstance(e0, (int, float)) and previous else "—")
            unloaded = record.get("unloaded_conductance_S")
            cells = (record.get("saved", "?"), _num(e0), _num(sls.get("E1_Pa")), _num(sls.get("mu1_Pa_s")),
                     _num(record.get("tau_s")), _num(linear.get("m_S_per_N"), 1e6),
                     _num(unloaded, 1e6), drift)
            for col, text in enumerate(cells):
                self.history_table.setItem(row, col, QTableWidgetItem(text))
            previous = e0 if isinstance(e0, (int, float)) else previous

    def _choose_save(self) -> None:
        start = Path(user_folders.dialog_folder(user_folders.calibrations_dir())) / "calibration.json"
        path, _filter = QFileDialog.getSaveFileName(self, "Save calibration", str(start), "Calibration (*.json)")
        if path:
            self.save(path)

    # -- drawing ---------------------------------------------------------------------------------------------------
    def _plot_measured_only(self) -> None:
        self._plot(tuple(self.trials), None)

    def _plot(self, trials: tuple[LoadedTrial, ...], fitted: tuple[np.ndarray, ...] | None) -> None:
        self.plot.clear()
        self.legend.clear()
        self.legend.setColumnCount(2 if len(trials) > 6 else 1)
        for index, trial in enumerate(trials):
            color = theme.series_color(index)
            step = max(1, trial.time_s.size // PLOT_MAX_POINTS)
            t = trial.time_s[::step]
            measured_pen = pg.mkPen(theme.qcolor(color, alpha=140), width=1)
            self.plot.plot(t, trial.conductance_s[::step] * 1e6, pen=measured_pen, name=trial.name)
            if fitted is not None:
                self.plot.plot(t, fitted[index][::step] * 1e6,
                               pen=pg.mkPen(color, width=2, style=Qt.PenStyle.DashLine))

    def _plot_review(self, result: FitResult) -> None:
        """Fig. 9ii (window mean vs force with the linear fit) and Fig. 9iii (E0, E1, μ1 per trial vs force with
        the fitted trends)."""
        self.mean_plot.clear()
        self.param_plot.clear()
        session = result.session
        cal = result.calibration
        if session is not None:
            forces = np.array(session.forces_n)
            means = np.array(session.mean_conductance_s) * 1e6
            self.mean_plot.plot(forces, means, pen=None, symbol="o", symbolBrush=theme.series_color(0))
            if cal.linear is not None and forces.size:
                span = np.array([0.0, float(np.max(forces)) * 1.1])
                line = (cal.linear.model.m_S_per_N * span + cal.linear.model.d_S) * 1e6
                self.mean_plot.plot(span, line, pen=pg.mkPen(theme.series_color(1), width=2,
                                                             style=Qt.PenStyle.DashLine))
        for k, (key, label, _unit) in enumerate(PARAM_LABELS):
            rows = [(t.force_n, float(getattr(t.params, key))) for t in cal.trials if t.refused is None]
            if not rows:
                continue
            f, v = np.array(rows).T
            ok = v > 0
            color = theme.series_color(k)
            self.param_plot.plot(f[ok], v[ok], pen=None, symbol="o", symbolBrush=color, name=label)
            if cal.sls_trend is not None and key in cal.sls_trend:
                intercept, slope = cal.sls_trend[key]
                span = np.linspace(float(np.min(f)), float(np.max(f)), 20)
                trend = intercept + slope * span
                good = trend > 0
                self.param_plot.plot(span[good], trend[good], pen=pg.mkPen(color, width=2,
                                                                            style=Qt.PenStyle.DashLine))

    # -- helpers ---------------------------------------------------------------------------------------------------
    def _set_status(self, text: str, level: str) -> None:
        self.status_label.setText(text)
        self.status_label.setStyleSheet(theme.status_style(level))

    def facts(self, fitting: bool = False) -> Facts:
        """What the tab holds that the wizard's rules read, now."""
        return Facts(sensor=self.sensor_edit.text().strip(), channels=tuple(self.lab.config.board.channel_names),
                     trials=len(self.trials), fitting=fitting or self.is_fitting,
                     rig_running=self.rig_session.is_running, fitted=self.result is not None,
                     session=self.session_folder is not None)

    def _update_buttons(self, fitting: bool = False) -> None:
        on = self.wizard.controls(self.facts(fitting))
        for widget, enabled in ((self.fit_button, on.fit), (self.add_button, on.add_trials),
                                (self.remove_button, on.remove_trials), (self.clear_button, on.clear_trials),
                                (self.save_button, on.save), (self.sensor_edit, on.sensor),
                                (self.sensor_picker, on.sensor), (self.area_spin, on.sensor),
                                (self.protocol_form.run_button, on.run), (self.resume_button, on.resume),
                                (self.redo_button, on.redo), (self.check_button, on.rig_check),
                                (self.contact_button, on.find_contact)):
            widget.setEnabled(enabled)
        self._update_nav(fitting)

    # -- the wizard's steps ----------------------------------------------------------------------------------------
    def go_to_step(self, step: int) -> None:
        """Show step ``step`` (SETUP … SAVE, clamped) and the view that goes with it."""
        self.build_pending_views()
        self.wizard.go_to(step)
        step = self.wizard.step
        view = {PROTOCOL: self.live_plot, REVIEW: self.view_tabs.widget(0), SAVE: self.history_table}.get(step)
        if view is not None:
            self.view_tabs.setCurrentWidget(view)
        if step == SAVE and self.result is not None:
            self.show_history(self.result.sensor)

    def next_blocked(self) -> str:
        """Why Next is off on the current step ("" when it is on)."""
        return self.wizard.next_blocked(self.facts())

    def _show_wizard(self) -> None:
        """The wizard's state changed: its page, and every control that follows it."""
        self.steps.setCurrentIndex(self.wizard.step)
        self._update_buttons()

    def _update_nav(self, fitting: bool = False) -> None:
        nav = self.wizard.nav(self.facts(fitting))
        self.step_label.setText(nav.title)
        self.next_button.setEnabled(nav.next)
        self.back_button.setEnabled(nav.back)
        self.step_hint.setText(nav.hint)
        self.step_hint.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")

    def _sensor_changed(self, _text: str) -> None:
        self._update_nav()

    def start_rig_check(self) -> bool:
        """Check the rig (on a worker thread: its port is opened, checked, closed) and that the board streams the
        chosen sensor (its next samples); the lines show as they are known, Next follows the verdict."""
        sensor = self.sensor_edit.text().strip()
        if self.rig_session.is_running or not self.wizard.check_started(sensor):
            return False
        self._check_rig_lines, self._check_board_line = None, None
        self.check_table.setRowCount(0)
        self._set_status(f"checking the rig on {self.lab.config.rig.port} and the board's {sensor}…", theme.WARN)
        threading.Thread(target=self._rig_check_worker, name="calibration-rig-check", daemon=True).start()
        board = self.lab.board
        names = self.lab.config.board.channel_names
        if board is None:
            self._check_board_line = (False, f"no force-sensor board: {self.lab.board_unavailable_reason}")
        elif sensor not in names:
            self._check_board_line = (False, f"{sensor or 'no sensor'} is not a channel of the board "
                                             f"({names[0]} … {names[-1]})")
        else:
            self._check_channel = names.index(sensor)
            self._check_board = board
            board.block.connect(self._check_block)
            if not board.is_running:
                board.start()
            self._board_check_started_s = time.monotonic()
            QTimer.singleShot(int(BOARD_CHECK_S * 1000), self._board_check_timeout)
        self._finish_check_if_done()
        return True

    def find_contact(self) -> bool:
        """The wizard's "Find contact" step: the rig finds where the probe touches the sensor (current, then the
        sensor's reading) and releases; nothing is recorded. The outcome shows under the button; Next follows it."""
        if self.rig_session.is_running or self.is_fitting:
            return False
        try:
            settings = self.protocol_settings()
            self.rig_session.start(settings, self.protocol_form.folder_edit.text().strip()
                                   or user_folders.calibrations_dir(), contact_only=True)
        except ValueError as exc:
            self._show_contact(str(exc), theme.ERROR)
            return False
        self._show_contact("finding where the probe touches the sensor…", theme.WARN)
        self.wizard.contact_started()
        return True

    def _show_contact(self, text: str, level: str) -> None:
        self.contact_label.setText(text)
        self.contact_label.setStyleSheet(theme.status_style(level))

    def _contact_finished(self, outcome: Outcome) -> None:
        found = outcome.status == COMPLETED
        if found:
            self._show_contact(outcome.message, theme.OK)
            self._set_status("contact found: Next", theme.OK)
        else:
            self._show_contact(f"contact not found: {outcome.message}", theme.ERROR)
            self._set_status("contact not found — see the step's message", theme.ERROR)
        self.wizard.contact_finished(found, self.sensor_edit.text().strip())

    def _rig_check_worker(self) -> None:
        """Worker thread: the rig's own check (devices.rig.CalibrationRig.check)."""
        from devices.rig import CalibrationRig, RigCheckLine

        try:
            lines = CalibrationRig(self.lab.config.rig).check()
        except Exception as exc:  # noqa: BLE001 - the check must answer whatever the rig does
            lines = [RigCheckLine("rig", False, f"{type(exc).__name__}: {exc}")]
        self._bridge.post(self._on_rig_checked, lines)

    def _on_rig_checked(self, lines: list[Any]) -> None:
        self._check_rig_lines = lines
        self._finish_check_if_done()

    def _check_block(self, block: Any) -> None:
        if self._check_board_line is not None or not len(block):
            return
        column = np.asarray(block.conductance_s)[:, self._check_channel]
        finite = column[np.isfinite(column)]
        if finite.size:
            self._check_board_line = (True, f"{finite.size} sample(s) of {self.wizard.checking_sensor}, now "
                                            f"{float(finite[-1]) * 1e6:.1f} µS")
            self._stop_board_check()
            self._finish_check_if_done()

    def _board_check_timeout(self) -> None:
        if self._check_board_line is None and self.wizard.checking:
            board = self._check_board
            newest = getattr(board, "newest_frame_host_s", None)
            started = getattr(self, "_board_check_started_s", 0.0)
            if (callable(newest) and newest() > started
                    and time.monotonic() - started < BOARD_CHECK_PATIENCE * BOARD_CHECK_S):
                # frames are arriving; this thread (busy machine) has not handed them over yet: wait a while more
                QTimer.singleShot(int(BOARD_CHECK_S * 1000), self._board_check_timeout)
                return
            source = ("the simulated lab's board" if is_sim(self.lab.config.board.port) else "the board")
            todo = ("check that the simulated board streams (Forces tab)" if is_sim(self.lab.config.board.port)
                    else "check the board's cable and that it streams (Forces tab)")
            self._check_board_line = (False, f"no sample of {self.wizard.checking_sensor} from {source} in "
                                             f"{BOARD_CHECK_S:g} s: {todo}")
            self._stop_board_check()
            self._finish_check_if_done()

    def _stop_board_check(self) -> None:
        board, self._check_board = self._check_board, None
        if board is not None:
            with contextlib.suppress(RuntimeError, TypeError):
                board.block.disconnect(self._check_block)

    def _finish_check_if_done(self) -> None:
        if self._check_rig_lines is None or self._check_board_line is None:
            return
        lines = [(line.ok, line.name, line.detail) for line in self._check_rig_lines]
        ok, detail = self._check_board_line
        lines.append((ok, f"board streams {self.wizard.checking_sensor}", detail))
        self.check_table.setRowCount(len(lines))
        for row, (passed, name, seen) in enumerate(lines):
            mark = QTableWidgetItem("✔ pass" if passed else "✘ FAIL")
            mark.setForeground(theme.qcolor(theme.STATUS_COLORS[theme.OK if passed else theme.ERROR]))
            self.check_table.setItem(row, 0, mark)
            self.check_table.setItem(row, 1, QTableWidgetItem(name))
            item = QTableWidgetItem(seen)
            item.setToolTip(seen)
            self.check_table.setItem(row, 2, item)
        self.check_table.resizeRowsToContents()
        passed = all(p for p, _, _ in lines)
        if passed:
            self._set_status("rig check passed: Next", theme.OK)
        else:
            failed = [f"{name}: {seen}" for p, name, seen in lines if not p]
            self._set_status("rig check FAILED — " + failed[0], theme.ERROR)
        self.wizard.check_finished(passed)
        self.rig_check_finished.emit(passed)

    def check_lines(self) -> list[tuple[str, str, str]]:
        """The rig check's table as text (mark, check, seen/reason), for tests and screenshots."""
        def text(row: int, col: int) -> str:
            item = self.check_table.item(row, col)
            return item.text() if item is not None else ""

        return [(text(r, 0), text(r, 1), text(r, 2)) for r in range(self.check_table.rowCount())]

    def curves(self) -> list[Any]:
        """The plotted curves (measured and fitted), for tests and screenshots."""
        return self.plot.getPlotItem().listDataItems()


def _review_plot(x_label: str, y_label: str, title: str) -> pg.PlotWidget:
    plot = pg.PlotWidget(background="w")
    for side, label in (("left", y_label), ("bottom", x_label)):
        theme.no_si_prefix(plot.getPlotItem().getAxis(side))
        plot.setLabel(side, label)
    plot.showGrid(x=True, y=True, alpha=0.2)
    plot.setTitle(title, color="#444", size="10pt")
    return plot


def _num(value: object, scale: float = 1.0) -> str:
    return f"{float(value) * scale:.4g}" if isinstance(value, (int, float)) else "—"


def _interval_tip(ci95: dict[str, tuple[float, float]], column: int) -> str:
    """Tooltip of a per-trial table cell: the parameter's 95 % interval, where the fit gave one."""
    names = {2: "E0_Pa", 3: "E1_Pa", 4: "mu1_Pa_s"}
    name = names.get(column)
    if name is None or name not in ci95:
        return ""
    lo, hi = ci95[name]
    return f"95 % interval {lo:.4g} … {hi:.4g}"


def summary_html(result: FitResult) -> str:
    """The fitted parameters with their 95 % intervals, the linear model, and the warnings, as rich text."""
    cal = result.calibration
    sls = cal.sls
    parts = []
    for key, label, unit in PARAM_LABELS:
        value = float(getattr(sls, key))
        interval = cal.sls_ci95.get(key)
        ci = f" <span style='color:#666'>(95 %: {interval[0]:.4g} … {interval[1]:.4g})</span>" if interval else ""
        parts.append(f"{label} = {value:.4g} {unit}{ci}")
    lines = [f"<b>{result.sensor}</b> SLS, one set for all forces (used by estimate): " + ", ".join(parts)
             + f"; τ = {float(sls.tau_s):.4g} s; RMSE {cal.rmse_s * 1e6:.4g} µS; forces {cal.force_range_n[0]:.3g}–"
             f"{cal.force_range_n[1]:.3g} N"]
    if cal.linear is not None:
        lines.append(f"linear: m = {cal.linear.model.m_S_per_N * 1e6:.4g} µS/N, d = {cal.linear.model.d_S * 1e6:.4g} µS"
                     + (f" (window {result.window_s[0]:.0f}–{result.window_s[1]:.0f} s)" if result.window_s else ""))
    if cal.sls_trend is not None:
        lines.append("force trend (sls_trend) fitted: the parameters vary with force")
    if result.problems:
        color = theme.STATUS_COLORS[theme.ERROR]
        items = "".join(f"<li>{_escape(w)}</li>" for w in result.problems)
        lines.append(f"<span style='color:{color}'><b>not fit to use</b></span><ul style='margin:0'>{items}</ul>")
    if result.session is not None and result.session.unloaded_conductance_s is not None:
        lines.append(f"unloaded level {result.session.unloaded_conductance_s * 1e6:.2f} µS; readout ceiling "
                     f"{result.session.readout_ceiling_s * 1e6:.0f} µS")
    if cal.warnings:
        color = theme.STATUS_COLORS[theme.WARN]
        items = "".join(f"<li>{_escape(w)}</li>" for w in cal.warnings)
        lines.append(f"<span style='color:{color}'><b>warnings</b></span><ul style='margin:0'>{items}</ul>")
    return "<br>".join(lines)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def create_tab(lab: LabContext) -> QWidget:
    return CalibrationTab(lab)


def create_tab_in_steps(lab: LabContext) -> tuple[QWidget, Iterator[None]]:
    """The tab with its wizard and Fit view, and the steps that add the other views (the main window runs one per
    turn of the event loop, so opening the tab holds the window for none of them)."""
    tab = CalibrationTab(lab, views_in_steps=True)

    def steps() -> Iterator[None]:
        while tab.build_next_view():
            yield

    return tab, steps()
