"""The lab as the GUI sees it: the configuration, the robot bridge, the force-sensor board bridge, the recording.

One :class:`LabContext` is created by ``sensnake gui`` and handed to every tab (``create_tab(lab)``). Ports named
``sim`` reach the simulated lab; :mod:`devices.factory` makes that decision, not this module.
GUI thread only.
"""

from __future__ import annotations

import importlib
import logging
from concurrent.futures import Future
from dataclasses import replace
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, Signal

from app.core.event_log import EventLog
from app.gui.robot_bridge import RobotBridge
from app.gui.thread_bridge import ThreadBridge
from devices.config import SIM_PORT, LabConfig
from devices.errors import LabProcessUnavailable
from devices.factory import is_sim

BOARD_BRIDGE_MODULE = "app.gui.board_bridge"
log = logging.getLogger(__name__)


def _simulated_part(config: LabConfig, wanted: LabConfig) -> tuple:
    """What of ``config`` a simulated lab for ``wanted`` is built from: its [lab] section, and the robot, board and
    rig that ``wanted`` puts on port ``sim`` (ports aside: a real robot's baud does not change the simulated rig)."""
    sections = (("robot", config.robot, wanted.robot), ("board", config.board, wanted.board),
                ("rig", config.rig, wanted.rig))
    return (config.lab, *(replace(section, port=SIM_PORT) for _, section, want in sections if is_sim(want.port)))


def end_sim_lab_unless_it_simulates(config: LabConfig) -> bool:
    """Before a :class:`LabContext` on ``config`` is made (GUI thread; the previous context closed): end the running
    simulated lab if it simulates another lab (another ``[lab] scene`` or physics, another robot, board or rig), so
    the new context starts one on ``config`` — a lab keeps the terrain it was built with. Returns True if it ended.
    A config with no ``sim`` port leaves it alone (nothing will use it)."""
    from devices import factory

    running = factory.installed_sim_lab()
    built_on = getattr(running, "config", None)
    if running is None or not isinstance(built_on, LabConfig) or not _uses_sim(config):
        return False
    if _simulated_part(built_on, config) == _simulated_part(config, config):
        return False
    factory.install_sim_lab(None)
    close = getattr(running, "close", None)
    if callable(close):
        close()
    return True


def _uses_sim(config: LabConfig) -> bool:
    return any(is_sim(port) for port in (config.robot.port, config.board.port, config.rig.port))


def _make_sim_lab(config: LabConfig, in_own_process: bool) -> str:
    """Make the process-wide simulated lab if there is none yet (it then follows this config: ``[lab] physics``, the
    channel list) — in its own process when asked and possible (``sensnake gui``: the GUI then delays neither the
    simulated devices nor the control loop); returns where it runs, in words."""
    from devices import factory

    if factory.sim_serial_path("robot") is not None:
        return "its own process"
    if in_own_process and factory.installed_sim_lab() is None:
        wanted, why_not = factory.lab_process_wanted()
        if wanted:
            try:
                lab = factory.start_lab_process(config)
            except LabProcessUnavailable as exc:
                why_not = str(exc)
                log.warning("the simulated lab runs in the app's process: %s", exc)
            else:
                return f"its own process (pid {lab.pid})"
        factory.sim_lab(config)
        return f"the app's process ({why_not})"
    factory.sim_lab(config)
    return "the app's process"


def _call_sim_lab(name: str) -> Any:
    """Call ``name`` (a dotted path such as ``physics.world.place``) on the running simulated lab, in this process
    or in its own."""
    from devices import factory

    lab = factory.installed_sim_lab()
    if lab is None:
        raise RuntimeError("no simulated lab is running")
    call = getattr(lab, "call", None)  # the lab's own process (LabProcess)
    if callable(call):
        return call(name)
    target: Any = lab
    for part in name.split("."):
        target = getattr(target, part)
    return target()


class LabContext(QObject):
    """Holds the lab's devices for the GUI.

    ``robot`` is a :class:`RobotBridge`; ``board`` is the BoardBridge from ``app/gui/board_bridge.py`` created on first
    use (``None`` while that module is not part of the build: ``board_unavailable_reason`` says so); ``recording``
    is the active recording session (set by the Forces tab; ``recording_changed`` is emitted when it changes).
    """

    recording_changed = Signal(object)
    board_created = Signal(object)
    stop_requested = Signal()  # STOP / Esc: every device that can move or load something halts (robot, rig)
    calibration_saved = Signal(str)  # a calibration file was written (Calibration tab): the Forces tab loads it
    sim_lab_died = Signal(str)  # the simulated lab's own process ended unasked (the text says what and what to do)

    def __init__(self, config: LabConfig, parent: QObject | None = None, *, lab_process: bool = False) -> None:
        super().__init__(parent)
        self.config = config
        self.lab_process = lab_process
        self.lab_where = ""  # where the simulated lab runs, in words ("" without one)
        self.sim_lab_gone = ""  # set (GUI thread) when the simulated lab's own process has ended unasked
        self._bridge = ThreadBridge(self)
        self._watched: Any = None
        self.robot = RobotBridge(config.robot, self)
        self.robot.servo_profile = config.servos
        self.config_path: Path | None = None  # the lab config file the app was opened with (None: the packaged one)
        self._board: Any = None
        self._board_loaded = False
        self.board_unavailable_reason = ""
        self._recording: Any = None
        self._force_page: Any = None
        self._mocap: Any = None
        self._closed = False
        # Messages, faults and actions of this lab's tabs; the main window puts its own log here (it outlives labs).
        self.event_log = EventLog()
        if _uses_sim(config):
            self.lab_where = _make_sim_lab(config, lab_process)
            from devices.factory import installed_sim_lab

            watched = installed_sim_lab()
            listen = getattr(watched, "add_died_listener", None)  # the lab's own process (LabProcess)
            if listen is not None:
                self._watched = watched
                listen(self._sim_lab_died_elsewhere)

    def _sim_lab_died_elsewhere(self, text: str) -> None:  # the lab process's watcher thread
        self._bridge.post(self._on_sim_lab_died, text)

    def _on_sim_lab_died(self, text: str) -> None:
        self.sim_lab_gone = text
        self.sim_lab_died.emit(text)

    # -- board (created lazily so the app starts even before the board bridge exists) ------------------------------
    @property
    def board(self) -> Any:
        """The BoardBridge (``BoardBridge(config.board, parent)``), or None if ``app/gui/board_bridge.py`` is missing."""
        if not self._board_loaded and not self._closed:
            self._board_loaded = True
            try:
                module = importlib.import_module(BOARD_BRIDGE_MODULE)
            except ModuleNotFoundError as exc:
                if exc.name != BOARD_BRIDGE_MODULE:
                    raise
                self.board_unavailable_reason = "board support is not built yet (app/gui/board_bridge.py missing)"
                return None
            self._board = module.BoardBridge(self.config.board, self)
            self.board_created.emit(self._board)
        return self._board

    @property
    def board_if_created(self) -> Any:
        """The board bridge if something already asked for it, without creating it."""
        return self._board

    # -- forces for the controller --------------------------------------------------------------------------------
    @property
    def force_page(self) -> Any:
        """The shared page (:class:`app.core.force_control.ForcePage`) where the Forces tab publishes every board
        block's estimated forces, read by a feedback motion on the control loop's thread (in its own process or
        this one). Made on first use; removed on :meth:`close`."""
        if self._force_page is None and not self._closed:
            from app.core.force_control import ForcePage

            self._force_page = ForcePage.create(len(self.config.board.channel_names))
        return self._force_page

    # -- motion capture ------------------------------------------------------------------------------------------
    @property
    def mocap(self) -> Any:
        """The motion capture and LSL streams (:class:`app.gui.mocap_link.MocapLink`): made on first use (the
        Forces tab's picker, the 3-D tab), following ``[lab] mocap`` from then on; closed on :meth:`close`."""
        if self._mocap is None and not self._closed:
            from app.gui.mocap_link import MocapLink

            self._mocap = MocapLink(self, self)
        return self._mocap

    # -- recording -------------------------------------------------------------------------------------------------
    @property
    def recording(self) -> Any:
        """The active recording session or None."""
        return self._recording

    @recording.setter
    def recording(self, session: Any) -> None:
        self._recording = session
        self.recording_changed.emit(session)

    # -- life cycle ------------------------------------------------------------------------------------------------
    def simulated_sensors_calibration(self) -> dict | None:
        """The simulated board's sensors' true calibration (a SPEC §3.3 document marked as the simulation's truth);
        None when the board is not simulated."""
        if not is_sim(self.config.board.port):
            return None
        from devices import factory

        # The running lab's own sensors when it can say (in this process or its own); else the same lab's, computed
        truth = getattr(getattr(factory.installed_sim_lab(), "board", None), "ground_truth_calibration", None)
        if not callable(truth):
            return factory.simulated_sensors_calibration(self.config)
        return {**truth(), "source": factory.SIMULATED_TRUTH_NOTE}

    @property
    def is_all_sim(self) -> bool:
        return all(is_sim(port) for port in (self.config.robot.port, self.config.board.port, self.config.rig.port))

    def connect_all(self) -> None:
        """Connect the robot and start the board (each on its own worker; returns at once)."""
        self.robot.connect_robot()
        board = self.board
        if board is not None:
            board.start()

    def reset_sim_robot(self) -> Future:
        """Put the simulated robot back where the lab starts it: any motion stopped, torque off on every joint (limp,
        as at start-up), the physics world's robot laid straight at its scene's start to settle there, servos that
        latched a hardware error (an overload when it fell) rebooted. GUI thread; the Future gives one line saying
        what was done, or fails with why not (a real robot, the scripted lab)."""
        from devices import bus_commands
        from devices.bus_commands import bus_command

        done: Future = Future()
        if not is_sim(self.config.robot.port):
            done.set_exception(ValueError("Reset lab re-settles the simulated robot; this robot is real"))
            return done
        if self.config.lab.physics != "mujoco":
            done.set_exception(ValueError("the scripted simulated lab has no scene to settle the robot on "
                                          "([lab] physics = \"scripted\")"))
            return done
        robot = self.robot
        robot.stop_motion()  # first: nothing drives the joints while the robot is put back
        in_error = [h.servo_id for h in robot.latest_health if h.error_names]
        torque_off = robot.run_on_bus(bus_command(bus_commands.set_torque, False), report_errors=False)

        def place(_result: object) -> None:
            try:
                _call_sim_lab("physics.world.place")
            except (RuntimeError, AttributeError, OSError) as exc:
                done.set_exception(RuntimeError(f"the simulated lab could not be reset: {exc}"))
                return
            for servo_id in in_error if robot.is_connected else ():
                robot.reboot(servo_id)
            scene = self.config.lab.scene or "the built-in scene ([lab] obstacle keys)"
            rebooted = f"; servo(s) {', '.join(map(str, in_error))} rebooted" if in_error else ""
            done.set_result(f"lab reset: the simulated robot was laid straight at the start of {scene} and settles "
                            f"there, torque off (limp) as at start-up{rebooted}")

        robot.when_done(torque_off, place, done.set_exception)
        return done

    def emergency_stop(self) -> None:
        """STOP (button or Esc, GUI thread): the robot halts within one control tick (torque stays on, goals frozen
        at present) and ``stop_requested`` tells every other moving device (the calibration rig) to halt too."""
        self.robot.emergency_stop()
        self.stop_requested.emit()

    def close(self) -> None:
        """Stop recording, stop every device and join their threads. Blocks briefly; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._watched is not None:
            self._watched.remove_died_listener(self._sim_lab_died_elsewhere)
        self._bridge.close()
        recording = self._recording
        if recording is not None and hasattr(recording, "stop"):
            recording.stop()
        if self._mocap is not None:
            self._mocap.close()
        self.robot.close()
        if self._force_page is not None:
            self._force_page.close()
        if self._board is not None:
            self._board.stop()
            close = getattr(self._board, "close", None)
            if close is not None:
                close()
