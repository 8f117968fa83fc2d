"""The main window: six tabs (Teach, Gait, Calibration, Forces, Hardware, 3-D lab), the menu, and the status bar with STOP.

Tabs are built from ``app/gui/tabs/<name>.py`` (``create_tab(lab) -> QWidget``) the first time they are shown, so start-up
only pays for the tab on screen. A tab whose module is not part of the build shows a placeholder saying what it will
do. STOP (the red button, or Esc anywhere in the window; in a dialog Esc closes the dialog and stops what moves) calls
``lab.emergency_stop()``: the robot halts and the calibration rig releases its load.

Every message the status bar shows, every warning and fault and every operator action also goes into the event log
(:mod:`app.core.event_log`, kept by the window across lab changes and handed to each lab as ``lab.event_log``), shown
in the **Event log** dock (View ▸ Event log, Ctrl+L): a click on the status bar's message opens the dock at that
message, whole.
The **Plots** dock (View ▸ Plots, Ctrl+P; :mod:`app.gui.plots_dock`) puts any live or recorded series on stacked
plots with linked time axes, or as X–Y.
The **Trials** dock (View ▸ Trials, Ctrl+T; :mod:`app.gui.trials_session`) runs a trial series on the robot; File ▸
Open recording… (:mod:`app.gui.catalog_browser`) finds any recording in the run catalog.
GUI thread only.
"""

from __future__ import annotations

import contextlib
import importlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtCore import QByteArray, QEvent, QObject, QSettings, Qt, QTimer
from PySide6.QtGui import QAction, QCloseEvent, QKeyEvent, QKeySequence, QShortcut, QWindow
from PySide6.QtWidgets import (
    QApplication,
    QDockWidget,
    QFileDialog,
    QMainWindow,
    QMessageBox,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from app.core import event_log, user_folders
from app.gui.catalog_browser import CatalogBrowser, show_catalog_browser
from app.gui.gui_gc import GuiThreadCollector
from app.gui.lab import LabContext, end_sim_lab_unless_it_simulates
from app.gui.plots_dock import PlotsDock
from app.gui.robot_bridge import (
    HALTED_TEXT,
    MOTION_FAULT,
    MOTION_HALTED,
    MOTION_PAUSED,
    MOTION_RUNNING,
    describe_error,
)
from app.gui.tab_loader import ModuleLoader
from app.gui.thread_bridge import ThreadBridge
from app.gui.trials_session import TrialsDock
from devices.config import load_config
from devices.errors import ConfigError
from devices.factory import is_sim
from widgets import theme
from widgets.event_log_view import EventLogView
from widgets.placeholder import PlaceholderPage
from widgets.status_bar import LabStatusBar

APP_NAME = "SenSnake Studio"
ORGANIZATION = "SenSnake"
DEFAULT_SIZE = (1280, 800)  # the lab's laptops; every tab is laid out for it (and for 1920×1080)
MINIMUM_SIZE = (960, 600)
EVENT_KEEPS_ERROR_S = 8.0  # an informational message does not hide an error younger than this
LOG_KINDS = {theme.ERROR: event_log.FAULT, theme.WARN: event_log.WARNING, theme.OK: event_log.INFO,
             theme.IDLE: event_log.INFO}


@dataclass(frozen=True)
class TabSpec:
    name: str  # module app/gui/tabs/<name>.py
    title: str
    description: str


TABS: tuple[TabSpec, ...] = (
    TabSpec("teach", "Teach", "Pose the robot by hand with torque off and capture shapes: live joint angles while "
            "you pose, a keyframe list, torque back on holding the captured pose, and a shape library."),
    TabSpec("gait", "Gait", "Replay a shape follow-the-leader, play keyframes, or run parametric gaits "
            "(serpenoid, sidewinding) with speed, rate and progress shown on the drawn body."),
    TabSpec("calibration", "Calibration", "Drive the calibration rig through the 4-force × 3-trial protocol and "
            "fit the sensor models (linear and creep-aware SLS) to the recorded trials."),
    TabSpec("forces", "Forces", "Live per-segment force plots, the body force map, sensor health, and recording "
            "to HDF5 with replay and trial overlay."),
    TabSpec("hardware", "Hardware", "Connect to the servo bus, scan for servos, watch each servo's position, "
            "current, temperature, voltage and errors, toggle torque and LEDs, reboot, and check the link."),
    TabSpec("scene", "3-D lab", "The simulated lab in 3-D (physics lab, [lab] physics = \"mujoco\"): the robot, the "
            "ground and the obstacle; the 2-D body drawing otherwise."),
)

DIALOG_STOP_DEBOUNCE_S = 0.2  # one Esc press in a dialog is one STOP, however many objects it passes

SHORTCUTS_TEXT = (
    "<table cellspacing=6>"
    "<tr><td><b>Esc</b></td><td>STOP: halt all motion within one control tick (torque stays on); in a dialog, Esc "
    "closes the dialog, and stops a gait or a calibration run that moves</td></tr>"
    "<tr><td><b>Ctrl+Enter</b></td><td>Teach: capture the present pose as a keyframe</td></tr>"
    "<tr><td><b>Ctrl+Z / Ctrl+Shift+Z</b></td><td>Teach: undo / redo a keyframe edit (Ctrl+Y also redoes)</td></tr>"
    "<tr><td><b>Space</b></td><td>Gait: pause / resume the motion &nbsp;·&nbsp; Forces: pause / follow the "
    "plots</td></tr>"
    "<tr><td><b>Ctrl+O</b></td><td>Open a lab configuration (TOML)</td></tr>"
    "<tr><td><b>Ctrl+L</b></td><td>Show / hide the event log (every message, warning, fault and action)</td></tr>"
    "<tr><td><b>Ctrl+P</b></td><td>Show / hide the plots (any live or recorded series)</td></tr>"
    "<tr><td><b>Ctrl+T</b></td><td>Show / hide the trials (a trial series on the robot)</td></tr>"
    "<tr><td><b>Ctrl+Shift+O</b></td><td>Open a recording from the run catalog (3-D replay, trial overlay)</td></tr>"
    "<tr><td><b>Ctrl+1 … Ctrl+5</b></td><td>Teach, Gait, Calibration, Forces, Hardware</td></tr>"
    "<tr><td><b>Ctrl+Q</b></td><td>Quit (devices are shut down cleanly)</td></tr>"
    "</table>"
)


def _tab_module(spec: TabSpec) -> str:
    return f"app.gui.tabs.{spec.name}"


def tab_index(name: str) -> int:
    """Position of tab ``name`` (``teach`` … ``hardware``)."""
    for index, spec in enumerate(TABS):
        if spec.name == name:
            return index
    raise LookupError(f"no tab named {name!r}; tabs are {', '.join(s.name for s in TABS)}")


def user_settings() -> QSettings:
    """The window's settings: ``settings.ini`` in the one per-user data folder (:mod:`app.core.user_folders`)."""
    path = user_folders.settings_path()
    with contextlib.suppress(OSError):  # an unwritable folder: Qt keeps the settings in memory and says nothing
        user_folders.ensure_folder(path.parent)
    return QSettings(str(path), QSettings.Format.IniFormat)


class MainWindow(QMainWindow):
    """SenSnake Studio's window around one :class:`LabContext` (which it closes when it closes)."""

    def __init__(self, lab: LabContext, settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        # Garbage collection on this (the GUI) thread only while the window is open: see app/gui/gui_gc.py.
        self._collector = GuiThreadCollector(self)
        self._collector.start()
        self.settings = settings if settings is not None else user_settings()
        self.config_path: Path | None = None
        self._last_error_s = -1e9
        self._built: dict[str, QWidget] = {}

        self.setWindowTitle(APP_NAME)
        self.setMinimumSize(*MINIMUM_SIZE)
        self.resize(*DEFAULT_SIZE)

        self.tabs = QTabWidget()
        self.tabs.setDocumentMode(True)
        self._containers: list[QWidget] = []
        self._container_layouts: list[QVBoxLayout] = []  # the page goes here when the tab is first shown
        for spec in TABS:
            container = QWidget()
            container.setObjectName(f"tab_{spec.name}")
            layout = QVBoxLayout(container)
            layout.setContentsMargins(0, 0, 0, 0)
            self._containers.append(container)
            self._container_layouts.append(layout)
            self.tabs.addTab(container, spec.title)
            self.tabs.setTabToolTip(len(self._containers) - 1, spec.description)
        self.setCentralWidget(self.tabs)

        self.status = LabStatusBar()
        self.setStatusBar(self.status)
        self.status.stop_requested.connect(self.emergency_stop)
        self.status.log_requested.connect(self.show_log)
        # The event log outlives any one lab (File ▸ Open config replaces the lab, not the history).
        self.event_log = event_log.EventLog()
        self._status_entry = 0  # number of the log entry the status bar shows (0: none)
        self._log_seen = 0  # entries up to this number were on screen in the log: not counted on the Log button
        self.log_view = EventLogView(event_log.KINDS)
        self.log_view.save_requested.connect(self._save_log)
        self.log_dock = QDockWidget("Event log", self)
        self.log_dock.setObjectName("event_log_dock")
        self.log_dock.setWidget(self.log_view)
        self.log_dock.setAllowedAreas(Qt.DockWidgetArea.BottomDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        self.addDockWidget(Qt.DockWidgetArea.BottomDockWidgetArea, self.log_dock)
        self.log_dock.hide()  # the tabs keep the height until the user asks for the log
        self.log_dock.visibilityChanged.connect(lambda _visible: self._update_log_badge())
        self.event_log.subscribe(self._log_changed)
        # View ▸ Plots (Ctrl+P): any live or recorded series on linked axes (app/gui/plots_dock.py), idle while hidden
        self.plots_dock = PlotsDock(self, self.settings, self)
        self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self.plots_dock)
        self.plots_dock.hide()
        # View ▸ Trials (Ctrl+T): a trial series on the robot (app/gui/trials_session.py); File ▸ Open recording…:
        # the run catalog's browser (app/gui/catalog_browser.py)
        self.trials_dock = TrialsDock(self, self)
        self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self.trials_dock)
        self.trials_dock.hide()
        self.catalog_browser: CatalogBrowser | None = None
        # Esc reaches STOP whatever has focus in this window (a table, a tab, a plot). In a dialog (a file chooser, a
        # question, a preview) Esc is first the dialog's own key: it closes that dialog, and stops only what is
        # moving (a gait, a calibration run) — a person dismissing a question while nothing moves is not told the
        # robot was stopped, yet a modal dialog never leaves a moving robot without its STOP (Qt blocks clicks on
        # the STOP button while one is up).
        self.stop_shortcut = QShortcut(QKeySequence(Qt.Key.Key_Escape), self)
        self.stop_shortcut.setContext(Qt.ShortcutContext.WindowShortcut)
        self.stop_shortcut.activated.connect(self.emergency_stop)
        # A dialog is a window of its own: the window's shortcut does not see its Esc. An application-wide filter
        # does, installed only while a dialog has the focus (every event of the application passes through a filter,
        # ~1200/s with the Forces tab live).
        self._app = QApplication.instance()
        self._filtering_dialog = False
        self._dialog_stop_s = -1.0  # time.monotonic() of the last STOP from Esc in a dialog
        self._watching_dialogs = isinstance(self._app, QApplication)
        if isinstance(self._app, QApplication):
            self._app.focusWindowChanged.connect(self._watch_dialogs)

        self._build_menus()
        self._attach_lab()
        self._restore_settings()
        # The other tabs' modules are imported on a worker thread once the window is up (app/gui/tab_loader.py): a
        # tab chosen before its module is there says "Opening…" and is built when it arrives; the window never
        # waits for an import (the Calibration tab's took 2-3 s).
        self._tab_bridge = ThreadBridge(self)
        self._opening: dict[int, QWidget] = {}  # "Opening…" labels of tabs waiting for their module
        # A tab module may build its page in steps (create_tab_in_steps): the user's click gets the page at once and
        # the rest follows one step per turn of the event loop; show_tab() (a caller that needs the whole page)
        # finishes the steps at once.
        self._steps: dict[str, Iterator[None]] = {}
        self._stepwise = False  # set while a tab the user chose is built
        self._step_timer = QTimer(self)
        self._step_timer.setInterval(0)
        self._step_timer.timeout.connect(self._run_step)
        self._tab_loader = ModuleLoader([_tab_module(spec) for spec in TABS],
                                        self._tab_bridge.emitter(self._tab_module_ready))
        self.tabs.currentChanged.connect(self._open_tab)
        self._ensure_tab(self.tabs.currentIndex())  # (settles the collector once the window is up)
        self._tab_loader.start()

    # -- tabs ------------------------------------------------------------------------------------------------------
    def tab_widget(self, name: str) -> QWidget | None:
        """The built page of tab ``name`` (None until it has been shown or :meth:`show_tab` was called)."""
        return self._built.get(name)

    def show_tab(self, name: str) -> QWidget:
        """Switch to tab ``name``, building it if needed; returns its page."""
        index = tab_index(name)
        self.tabs.setCurrentIndex(index)
        self._ensure_tab(index)
        self._finish_steps(name)
        return self._built[name]

    def build_tab(self, name: str) -> QWidget:
        """The page of tab ``name``, built now if it was not (without switching to it)."""
        self._ensure_tab(tab_index(name))
        self._finish_steps(name)
        return self._built[name]

    def tab_is_complete(self, name: str) -> bool:
        """Tab ``name`` is built, none of its steps left."""
        return name in self._built and name not in self._steps

    def _run_step(self) -> None:
        """One step of a tab being built in steps (the step timer, one per turn of the event loop)."""
        for name in list(self._steps)[:1]:
            self._next_step(name)
        if not self._steps:
            self._step_timer.stop()

    def _next_step(self, name: str) -> bool:
        """Run one step of tab ``name``; False when it has none left."""
        steps = self._steps.get(name)
        if steps is None:
            return False
        try:
            next(steps)
            return True
        except StopIteration:
            QTimer.singleShot(0, self._collector, self._collector.settle)  # the page is whole: settle it (gui_gc)
        except (ValueError, OSError, LookupError, RuntimeError) as exc:
            self.say(f"{name} tab: {exc}", theme.ERROR, name)
        del self._steps[name]
        return False

    def _finish_steps(self, name: str) -> None:
        while self._next_step(name):
            pass

    def _open_tab(self, index: int) -> None:
        """A tab the user chose: built now if its module is imported, else "Opening…" until it is."""
        if 0 <= index < len(TABS) and TABS[index].name not in self._built \
                and not self._tab_loader.is_ready(_tab_module(TABS[index])):
            if index not in self._opening:
                label = PlaceholderPage(TABS[index].title, TABS[index].description, "Opening…")
                self._opening[index] = label
                self._container_layouts[index].addWidget(label)
            return
        self._ensure_tab_stepwise(index)

    def _ensure_tab_stepwise(self, index: int) -> None:
        self._stepwise = True
        try:
            self._ensure_tab(index)
        finally:
            self._stepwise = False

    def _tab_module_ready(self, module: str) -> None:
        """The loader imported ``module`` (posted to the GUI thread): build its tab if the user is waiting for it."""
        index = self.tabs.currentIndex()
        if index in self._opening and _tab_module(TABS[index]) == module:
            self._ensure_tab_stepwise(index)

    def _ensure_tab(self, index: int) -> None:
        if index < 0:
            return
        spec = TABS[index]
        if spec.name in self._built:
            return
        page = self._create_page(spec)
        self._built[spec.name] = page
        opening = self._opening.pop(index, None)
        if opening is not None:
            # Hidden, not unparented: the layout's queued show of a just-added widget would make an unparented one a
            # window of its own (seen on screen over the app's corner when the module came at once).
            self._container_layouts[index].removeWidget(opening)
            opening.hide()
            opening.deleteLater()
        self._container_layouts[index].addWidget(page)
        # Once the page is up (the next turn of the event loop), its objects live as long as the window: later
        # garbage collections skip them (app/gui/gui_gc.py).
        QTimer.singleShot(0, self._collector, self._collector.settle)

    def _create_page(self, spec: TabSpec) -> QWidget:
        module_name = _tab_module(spec)
        self._tab_loader.wait(module_name)  # not imported on two threads at once
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                return PlaceholderPage(spec.title, spec.description,
                                       f"This tab could not be loaded: {exc}. Install the missing package.")
            return PlaceholderPage(spec.title, spec.description, "This tab is not part of this build yet.")
        except ImportError as exc:
            return PlaceholderPage(spec.title, spec.description, f"This tab could not be loaded: {exc}")
        in_steps = getattr(module, "create_tab_in_steps", None) if self._stepwise else None
        try:
            if callable(in_steps):
                page, self._steps[spec.name] = in_steps(self.lab)
                self._step_timer.start()
                return page
            return module.create_tab(self.lab)
        except (ValueError, OSError, LookupError, RuntimeError) as exc:
            # A tab failing to build (bad shape library file, missing resource) must not take the window down.
            self.say(f"{spec.title} tab: {exc}", theme.ERROR, spec.title)
            return PlaceholderPage(spec.title, spec.description, f"This tab failed to start: {exc}")

    def _shutdown_tabs(self) -> None:
        # A tab may own timers or worker threads; ``shutdown()`` (optional) stops them before the devices close.
        for page in self._built.values():
            shutdown = getattr(page, "shutdown", None)
            if callable(shutdown):
                shutdown()

    def _drop_tabs(self) -> None:
        self._steps.clear()
        self._shutdown_tabs()
        for name, page in list(self._built.items()):
            page.setParent(None)
            page.deleteLater()
            del self._built[name]

    # -- menus -----------------------------------------------------------------------------------------------------
    def _build_menus(self) -> None:
        file_menu = self.menuBar().addMenu("&File")
        self.open_config_action = QAction("&Open config…", self)
        self.open_config_action.setShortcut(QKeySequence.StandardKey.Open)
        self.open_config_action.triggered.connect(self._choose_config)
        file_menu.addAction(self.open_config_action)
        self.open_recording_action = QAction("Open &recording… (the run catalog)", self)
        self.open_recording_action.setShortcut(QKeySequence("Ctrl+Shift+O"))
        self.open_recording_action.triggered.connect(self.open_catalog)
        file_menu.addAction(self.open_recording_action)
        file_menu.addSeparator()
        self.quit_action = QAction("&Quit", self)
        self.quit_action.setShortcut(QKeySequence("Ctrl+Q"))
        self.quit_action.triggered.connect(self.close)
        file_menu.addAction(self.quit_action)

        lab_menu = self.menuBar().addMenu("&Lab")
        self.reset_lab_action = QAction("&Reset lab (simulated robot back at its scene's start)", self)
        self.reset_lab_action.setToolTip("Stops any motion, turns torque off and lays the simulated robot straight "
                                         "at the start of its scene to settle, as when the app starts")
        self.reset_lab_action.triggered.connect(self.reset_lab)
        lab_menu.addAction(self.reset_lab_action)

        view_menu = self.menuBar().addMenu("&View")
        self.log_action = self.log_dock.toggleViewAction()
        self.log_action.setText("&Event log")
        self.log_action.setShortcut(QKeySequence("Ctrl+L"))
        view_menu.addAction(self.log_action)
        self.plots_action = self.plots_dock.toggleViewAction()
        self.plots_action.setText("&Plots")
        self.plots_action.setShortcut(QKeySequence("Ctrl+P"))
        view_menu.addAction(self.plots_action)
        self.trials_action = self.trials_dock.toggleViewAction()
        self.trials_action.setText("&Trials")
        self.trials_action.setShortcut(QKeySequence("Ctrl+T"))
        view_menu.addAction(self.trials_action)

        help_menu = self.menuBar().addMenu("&Help")
        self.shortcuts_action = QAction("&Keyboard shortcuts", self)
        self.shortcuts_action.triggered.connect(self._show_shortcuts)
        help_menu.addAction(self.shortcuts_action)
        self.about_action = QAction(f"&About {APP_NAME}", self)
        self.about_action.triggered.connect(self._show_about)
        help_menu.addAction(self.about_action)

        for index in range(len(TABS)):
            shortcut = QShortcut(QKeySequence(f"Ctrl+{index + 1}"), self)
            shortcut.activated.connect(lambda i=index: self.tabs.setCurrentIndex(i))

    def _show_shortcuts(self) -> None:
        QMessageBox.information(self, "Keyboard shortcuts", SHORTCUTS_TEXT)

    def _show_about(self) -> None:
        QMessageBox.about(
            self, f"About {APP_NAME}",
            f"<b>{APP_NAME}</b><p>Teach the SenSnake robot shapes by hand, replay them as gaits, calibrate its "
            "piezo-resistive contact-force sensors and watch the forces live.</p>"
            "<p>12 Dynamixel XM430-W350 servos on one Protocol 2.0 bus, 36 force sensors on a multiplexing board. "
            "Every device can run on the built-in simulated lab (port <tt>sim</tt>).</p>")

    def _choose_config(self) -> None:
        path, _filter = QFileDialog.getOpenFileName(self, "Open lab configuration",
                                                    user_folders.dialog_folder(user_folders.data_dir()),
                                                    "Lab configuration (*.toml);;All files (*)")
        if path:
            self.open_config(path)

    def open_catalog(self) -> CatalogBrowser:
        """File ▸ Open recording…: the run catalog's browser (filters, the 3-D replay, the Forces tab's overlay)."""
        self.catalog_browser = show_catalog_browser(self, self.catalog_browser)
        return self.catalog_browser

    def open_config(self, path: str | Path) -> bool:
        """Load a lab config and restart the devices on it; a bad file is reported and the lab kept."""
        self.log_action_taken(f"open lab config {path}")
        try:
            config = load_config(path)
        except ConfigError as exc:
            self.say(str(exc), theme.ERROR, "config")
            QMessageBox.warning(self, "Configuration not loaded", str(exc))
            return False
        self.config_path = Path(path)
        lab_process = getattr(self.lab, "lab_process", False)
        self.lab.robot.stop_motion()  # nothing keeps moving while the lab changes under it
        index = self._close_lab()
        # The simulated lab is built from the config (its scene, its robot, board and rig): another one ends the
        # running lab and the new context starts one on it (a lab keeps the terrain it was built with).
        restarted = end_sim_lab_unless_it_simulates(config)
        lab = LabContext(config, lab_process=lab_process)
        lab.config_path = self.config_path
        self._adopt_lab(lab, index)
        self.lab.connect_all()
        if restarted:
            scene = config.lab.scene or "the built-in scene ([lab] obstacle keys)"
            self.show_event(f"simulated lab restarted for {self.config_path.name}: scene {scene}, "
                            f"{config.lab.physics} physics, running in {lab.lab_where}")
        return True

    def replace_lab(self, lab: LabContext) -> None:
        """Close the current lab's devices and rebuild every tab on ``lab``."""
        self._adopt_lab(lab, self._close_lab())

    def _close_lab(self) -> int:
        """Drop the tabs and close the lab's devices; returns the tab that was on screen."""
        index = self.tabs.currentIndex()
        self._drop_tabs()
        old = self.lab
        self.trials_dock.detach_lab()  # a trial being recorded closes as stopped before its lab goes
        old.close()
        old.deleteLater()
        return index

    def _adopt_lab(self, lab: LabContext, index: int) -> None:
        self.lab = lab
        self._attach_lab()
        self._ensure_tab(index)

    def reset_lab(self) -> None:
        """Lab ▸ Reset lab: the simulated robot back at its scene's start (motion stopped first, torque off, laid
        straight, servos with a latched error rebooted); the status bar says what was done or why not."""
        lab = self.lab
        self.log_action_taken("Lab ▸ Reset lab")
        self.say("resetting the simulated lab: motion stopped, torque off…", theme.IDLE, "lab")
        lab.robot.when_done(lab.reset_sim_robot(), lambda text: self.say(str(text), theme.OK, "lab"),
                            lambda exc: self.show_error(f"lab not reset: {describe_error(exc)}"))

    # -- status ----------------------------------------------------------------------------------------------------
    def _attach_lab(self) -> None:
        lab = self.lab
        lab.event_log = self.event_log  # tabs (built after this) log into the window's log
        robot = lab.robot
        robot.action.connect(lambda text: self.log_action_taken(text, "robot"))
        robot.connection_changed.connect(self._update_robot_status)
        robot.motion_changed.connect(self._update_robot_status)
        robot.error.connect(lambda text: self.show_error(text, "robot"))
        robot.event.connect(lambda text: self.show_event(text, "robot"))
        lab.sim_lab_died.connect(lambda text: self.show_error(text, "simulated lab"))
        lab.recording_changed.connect(self._update_recording_status)
        self._update_robot_status()
        self._update_recording_status(lab.recording)
        board = lab.board
        if board is None:
            self.status.set_board_state("Board: not available", theme.IDLE, lab.board_unavailable_reason)
        else:
            self.status.set_board_state(f"Board: {lab.config.board.port}", theme.IDLE)
            board.connected.connect(self._board_connected)
            board.status.connect(self._board_status)
            board.open_failed.connect(self._board_missing)
        self.reset_lab_action.setEnabled(lab.robot.is_sim)  # the scripted lab says why it has no scene
        source = f" — {self.config_path.name}" if self.config_path else (" — simulated lab" if lab.is_all_sim
                                                                       else "")
        self.setWindowTitle(f"{APP_NAME}{source}")
        self.plots_dock.attach_lab(lab)
        self.trials_dock.attach_lab(lab)

    def _update_robot_status(self, *_args: object) -> None:
        robot = self.lab.robot
        text = f"Robot: {robot.connection_text}"
        if robot.is_connected:
            level = theme.OK
            if robot.motion_state in (MOTION_RUNNING, MOTION_PAUSED):
                text += f" · {robot.motion_state} {robot.motion_name}".rstrip()
            elif robot.motion_state == MOTION_HALTED:
                level = theme.WARN
                text += f" · {robot.motion_name} {HALTED_TEXT}"
            elif robot.motion_state == MOTION_FAULT:
                level = theme.ERROR
                text += " · motion stopped by a fault"
            if robot.is_link_lost:
                level = theme.ERROR
        elif robot.is_connecting:
            level = theme.WARN
        else:
            level = theme.IDLE
        self.status.set_robot_state(text, level, f"port {robot.port}, {robot.baud} baud")

    def _board_connected(self, ok: bool) -> None:
        port = self.lab.config.board.port
        kind = "simulated" if is_sim(port) else "real"
        self.event_log.add(event_log.INFO if ok else event_log.WARNING,
                           f"board {'connected' if ok else 'not connected'} on {port} ({kind})", "board")
        if ok:
            self.status.set_board_state(f"Board: {self.lab.config.board.n_channels} ch on {port} ({kind})",
                                        theme.OK)
        else:
            self.status.set_board_state(f"Board: not connected ({port})", theme.WARN)

    def _board_status(self, text: str) -> None:
        self.status.board_label.setToolTip(text)

    def _board_missing(self, text: str) -> None:
        """The board's port cannot be opened (at start-up or after a pull): a warning, not a grey port name."""
        self.event_log.add(event_log.WARNING, f"board missing on {self.lab.config.board.port} (retrying): {text}",
                           "board")
        self.status.set_board_state(f"Board: missing on {self.lab.config.board.port} (retrying)", theme.WARN, text)

    def _update_recording_status(self, session: object) -> None:
        if session is None:
            if self.status.recording_label.level == theme.ERROR:
                self.event_log.add(event_log.INFO, "recording stopped", "recording")
            self.status.set_recording_state("Not recording", False)
            return
        path = getattr(session, "path", None)
        name = Path(str(path)).name if path is not None else "recording"
        self.event_log.add(event_log.INFO, f"recording to {path}", "recording")
        self.status.set_recording_state(f"● REC {name}", True)

    def say(self, text: str, level: str = theme.IDLE, source: str = "app") -> None:
        """Log ``text`` (a fault, warning or information by ``level``) and show it in the status bar."""
        entry = self.event_log.add(LOG_KINDS.get(level, event_log.INFO), text, source)
        self.status.show_message(text, level)
        self._status_entry = entry.number

    def log_action_taken(self, text: str, source: str = "operator") -> None:
        """An operator action, into the log (the status bar keeps its message)."""
        self.event_log.add(event_log.ACTION, text, source)

    def show_error(self, text: str, source: str = "app") -> None:
        """Show a device error in the message area (stays until replaced) and log it as a fault. Once the simulated
        lab's own process has ended, every later device error (its robot's link, its board) says that cause first."""
        self._last_error_s = time.monotonic()
        gone = getattr(self.lab, "sim_lab_gone", "")
        if gone and text != gone:
            text = f"{gone}. Then: {text}"
        self.say(text, theme.ERROR, source)

    def show_event(self, text: str, source: str = "app") -> None:
        """Log an informational message and show it, unless it would hide a fresh error (it is in the log)."""
        if (self.status.message_level == theme.ERROR
                and time.monotonic() - self._last_error_s < EVENT_KEEPS_ERROR_S):
            self.event_log.add(event_log.INFO, text, source)
            return
        self.say(text, theme.IDLE, source)

    # -- event log -------------------------------------------------------------------------------------------------
    def _log_changed(self, new: object, reset: bool) -> None:
        if reset:
            self.log_view.reset(self.event_log.entries)
        else:
            self.log_view.append(list(new))  # type: ignore[call-overload]  # a sequence of LogEntry
        self._update_log_badge()

    def _update_log_badge(self) -> None:
        if self.log_dock.isVisible():
            latest = self.event_log.latest()
            self._log_seen = latest.number if latest is not None else 0
        unseen = [e for e in self.event_log.entries[-200:] if e.number > self._log_seen]
        self.status.set_log_count(sum(e.kind == event_log.FAULT for e in unseen),
                                  sum(e.kind == event_log.WARNING for e in unseen))

    def show_log(self) -> None:
        """Open the event log at the message the status bar shows, else at the newest fault, else the newest
        entry: a fault's whole text is one click away."""
        self.log_dock.show()
        self.log_dock.raise_()
        shown = self._status_entry if self.status.message else 0
        for number in (shown, getattr(self.event_log.latest(event_log.FAULT), "number", 0),
                       getattr(self.event_log.latest(), "number", 0)):
            if number and self.log_view.select_number(number):
                break
        self._update_log_badge()

    def _save_log(self, entries: list[event_log.LogEntry]) -> None:
        folder = user_folders.dialog_folder(user_folders.data_dir())
        name = f"events-{time.strftime('%Y%m%d-%H%M%S')}.csv"
        path, _filter = QFileDialog.getSaveFileName(self, "Save the event log as CSV",
                                                    str(Path(folder) / name) if folder else name,
                                                    "CSV (*.csv);;All files (*)",
                                                    options=QFileDialog.Option.DontConfirmOverwrite)
        if path:
            self.save_log(path, entries)

    def save_log(self, path: str | Path, entries: list[event_log.LogEntry] | None = None) -> Path | None:
        """Write ``entries`` (default: the ones the log shows) to a new CSV file; an existing file is refused."""
        chosen = self.log_view.visible_entries() if entries is None else entries
        try:
            written = event_log.write_csv(chosen, path)
        except OSError as exc:
            self.say(f"event log not saved: {exc.strerror or exc}", theme.ERROR, "event log")
            return None
        self.say(f"event log saved: {len(chosen)} entries in {written}", theme.OK, "event log")
        return written

    # -- STOP ------------------------------------------------------------------------------------------------------
    def _watch_dialogs(self, *_window: object) -> None:
        """Filter the application's events while a dialog (a window other than this one) has the focus."""
        app = self._app
        if not isinstance(app, QApplication):
            return
        focus = app.focusWindow()
        wanted = focus is not None and focus is not self.windowHandle()
        if wanted != self._filtering_dialog:
            if wanted:
                app.installEventFilter(self)
            else:
                app.removeEventFilter(self)
            self._filtering_dialog = wanted

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt override
        if (event.type() == QEvent.Type.KeyPress and isinstance(event, QKeyEvent)
                and event.key() == Qt.Key.Key_Escape and not event.isAutoRepeat() and self._in_a_dialog(watched)
                and time.monotonic() - self._dialog_stop_s > DIALOG_STOP_DEBOUNCE_S and self.something_moves()):
            # one press reaches the filter once per object it passes (window, focus widget, its parents): one STOP
            self._dialog_stop_s = time.monotonic()
            self.emergency_stop()
        return False  # never consume: the dialog still gets its Esc and closes

    def _in_a_dialog(self, watched: QObject) -> bool:
        if isinstance(watched, QWindow):
            return watched is not self.windowHandle()
        return isinstance(watched, QWidget) and watched.window() is not self

    def something_moves(self) -> bool:
        """A gait is running or paused, or a calibration run holds the rig (what Esc in a dialog stops)."""
        if self.lab.robot.motion_state in (MOTION_RUNNING, MOTION_PAUSED):
            return True
        session = getattr(self._built.get("calibration"), "rig_session", None)
        return bool(getattr(session, "is_running", False))

    def emergency_stop(self) -> None:
        """STOP button / Esc: halt motion within one tick, torque stays on, goals frozen at present; the rig
        releases its load (``LabContext.emergency_stop``)."""
        self.lab.emergency_stop()

    # -- settings and shutdown -------------------------------------------------------------------------------------
    def _restore_settings(self) -> None:
        geometry = self.settings.value("main_window/geometry")
        if isinstance(geometry, QByteArray) and not geometry.isEmpty():
            self.restoreGeometry(geometry)
        stored = self.settings.value("main_window/tab", 0)
        try:
            index = int(stored)  # type: ignore[call-overload]  # QSettings gives str/int/None; the except handles the rest
        except (TypeError, ValueError):
            index = 0
        if 0 <= index < len(TABS):
            self.tabs.setCurrentIndex(index)

    def save_settings(self) -> None:
        self.settings.setValue("main_window/geometry", self.saveGeometry())
        self.settings.setValue("main_window/tab", self.tabs.currentIndex())
        self.settings.sync()

    def closeEvent(self, event: QCloseEvent) -> None:  # noqa: N802 - Qt override
        if isinstance(self._app, QApplication) and self._watching_dialogs:
            self._watching_dialogs = False
            self._app.focusWindowChanged.disconnect(self._watch_dialogs)
            self._app.removeEventFilter(self)
            self._filtering_dialog = False
        self.save_settings()
        self.event_log.unsubscribe(self._log_changed)
        self.plots_dock.shutdown()
        self.trials_dock.shutdown()
        if self.catalog_browser is not None:
            with contextlib.suppress(RuntimeError):  # its dialog was closed already
                self.catalog_browser.view.close()
        self._tab_loader.close()
        self._steps.clear()
        self._step_timer.stop()
        self._shutdown_tabs()
        self.status.shutdown()
        self.lab.close()
        self._collector.stop()  # the lab's threads are gone: automatic collection is safe again
        event.accept()
