"""Qt bridge around the robot's control loop (:class:`devices.controller.RobotController`).

The controller owns the servo bus on its own thread and calls plain Python callbacks from there. This bridge turns
them into Qt signals delivered on the GUI thread, so views never touch the port and never freeze:

- ``connected(bool)``, ``connection_changed(str)`` (human text: "connecting to sim…", "12 servos on sim", …)
- ``state(object)``: the latest :class:`ChainState`, delivered at ≤ 60 Hz (``latest_state`` may be read at any time);
  ``state_block(object)``: every ``ChainState`` since the previous delivery, in order (for recording)
- ``health(object)``: ``list[ServoHealth]`` as polled by the controller
- ``error(str)``: a readable message (what happened, which servo or port, what to do) — never a traceback
- ``event(str)``: informational messages; ``motion_changed(str)``: one of the ``MOTION_*`` states below (``halted``
  from the moment the loop's watchdog stops a motion on a quiet bus, ``fault`` once its cause is told)
- ``action(str)``: what the operator asked of the robot, in words, as it is asked (connect, torque, reboot, a motion
  started, paused, stopped, STOP): the event log's operator actions

Opening and closing the port happen on a worker thread. Bus operations return ``concurrent.futures.Future`` objects;
:meth:`RobotBridge.when_done` delivers their results on the GUI thread, and a failed future is reported through
``error`` unless the caller handles it. All public methods are for the GUI thread.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from enum import StrEnum
from typing import Any, TypeVar

from PySide6.QtCore import QObject, Signal

from app.gui.thread_bridge import Coalescer, ThreadBridge
from devices import bus_commands
from devices.bus_commands import bus_command
from devices.config import RobotConfig
from devices.errors import (
    BusQuietError,
    DeviceError,
    LinkLostError,
    LoopDiedError,
    LoopProcessUnavailable,
    NoReplyError,
    RepliesHeldError,
)
from devices.factory import is_sim, sim_serial_path
from devices.loop_process import ControllerProcess, loop_process_wanted

T = TypeVar("T")
log = logging.getLogger(__name__)

STATE_DELIVERY_INTERVAL_MS = 16  # ≤ 60 Hz to the GUI, whatever the control rate
STATE_BACKLOG_MAX = 4096  # states kept for ``state_block`` if the GUI stalls (≈ 20 s at 200 Hz)

class MotionState(StrEnum):
    """The robot's motion as the GUI shows it (equal to its plain string: ``MotionState.IDLE == "idle"``)."""

    IDLE = "idle"
    RUNNING = "running"
    PAUSED = "paused"
    FINISHED = "finished"
    STOPPED = "stopped"  # stopped by the user (Stop or STOP/Esc)
    # Stopped by the loop's watchdog on a bus that sent no byte; its cause (silent servos, or replies held on this
    # computer) is still being told: FAULT follows with it
    HALTED = "halted"
    FAULT = "fault"  # stopped by the controller: hardware error, watchdog, lost link


MOTION_IDLE, MOTION_RUNNING, MOTION_PAUSED = MotionState.IDLE, MotionState.RUNNING, MotionState.PAUSED
MOTION_FINISHED, MOTION_STOPPED, MOTION_FAULT = MotionState.FINISHED, MotionState.STOPPED, MotionState.FAULT
MOTION_HALTED = MotionState.HALTED
# What a halted motion is, in the words the tabs show (its verdict follows within seconds)
HALTED_TEXT = "stopped — checking whether the servos or this computer went quiet…"

# Errors a user can cause and fix; anything else reaching a thread boundary is a bug, reported and logged.
EXPECTED_DEVICE_ERRORS: tuple[type[BaseException], ...] = (DeviceError, OSError, ValueError, LookupError,
                                                             RuntimeError)

NOT_CONNECTED_MESSAGE = "the robot is not connected: connect it first (Hardware tab → Connect)"

# Timing findings that are no problem on the simulated lab: its servos start from factory settings at every start
# (Return Delay Time 500 µs) and it meets the control rate anyway — when it does not, the cycle-time finding says so
# and stays a warning. Said there as a note, never counted as a warning a user should act on.
SIMULATED_LAB_NOTES = ("Return Delay Time is up to",)
SIMULATED_NOTE_PREFIX = "simulated lab, nothing to do: "


def split_timing(findings: Sequence[str], simulated: bool) -> tuple[list[str], list[str]]:
    """(warnings a user can act on, notes) of the timing findings (``ServoChain.timing_warnings``)."""
    if not simulated:
        return list(findings), []
    notes = [f for f in findings if f.startswith(SIMULATED_LAB_NOTES)]
    return [f for f in findings if f not in notes], [SIMULATED_NOTE_PREFIX + f for f in notes]


def describe_error(exc: BaseException) -> str:
    """One readable line for ``exc``; unexpected exception types are logged with their traceback."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, EXPECTED_DEVICE_ERRORS):
        return text
    log.error("unexpected error from the robot", exc_info=exc)
    return f"unexpected {type(exc).__name__}: {text} (details in the log; please report it)"


class RobotBridge(QObject):
    """Qt signals and futures around one :class:`RobotController`; lives on the GUI thread."""

    connected = Signal(bool)
    connection_changed = Signal(str)
    state = Signal(object)
    state_block = Signal(object)
    health = Signal(object)
    error = Signal(str)
    # Shadows QObject.event() for Python callers (Qt's own event dispatch still reaches QObject.event); the name is
    # kept because every subscriber uses it.
    event = Signal(str)  # type: ignore[assignment]
    motion_changed = Signal(str)
    action = Signal(str)
    profile_applied = Signal(object)  # list[servo_settings.Change]: the lab's [servos] profile, applied on connect

    def __init__(self, config: RobotConfig, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._config = config
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="robot-connect")
        self._controller: Any = None
        self._pending_connect: Future | None = None
        self._connecting = False
        self._closed = False
        # Controller thread → GUI thread: callbacks through the one bridge, states coalesced to ≤ 60 Hz.
        self._bridge = ThreadBridge(self)
        self._states: Coalescer = Coalescer(self._deliver_states, self, STATE_DELIVERY_INTERVAL_MS,
                                            STATE_BACKLOG_MAX)
        self._health_by_id: dict[int, Any] = {}
        self._motion_state = MOTION_IDLE
        self._motion_name = ""
        self._motion_token = 0
        self.timing_warnings: list[str] = []  # timing problems a user can act on, each with its fix
        self.timing_notes: list[str] = []  # findings said but not counted (the simulated lab's factory settings)
        self._link_lost_at_s: float | None = None  # monotonic time the link was reported lost
        self._silent_at_s: float | None = None  # monotonic time a servo was reported silent (no valid feedback)
        self._silent_ids: set[int] = set()
        self._last_reported: BaseException | None = None
        self.connection_text = "not connected"
        self.connected_at_s: float | None = None
        # Where the control loop runs, in words ("its own process (pid …)" / "the app's process (why)").
        self.loop_where = "not connected"
        # The lab config's [servos] items (LabContext sets them), applied on every connect; what the last one did.
        self.servo_profile: tuple[tuple[str, int], ...] = ()
        self.last_profile_changes: list[Any] = []

    # -- properties (GUI thread; latest_state from any thread) ------------------------------------------------------
    @property
    def config(self) -> RobotConfig:
        """The robot configuration in use (port and baud as last connected or requested)."""
        return self._config

    @property
    def port(self) -> str:
        return self._config.port

    @property
    def baud(self) -> int:
        return self._config.baud

    @property
    def is_sim(self) -> bool:
        return is_sim(self._config.port)

    @property
    def is_connected(self) -> bool:
        return self._controller is not None

    @property
    def is_connecting(self) -> bool:
        """A connect is under way (until its outcome has been handled on the GUI thread)."""
        return self._connecting

    @property
    def is_link_lost(self) -> bool:
        """Connected, but the controller reported the link lost and no feedback has arrived since."""
        return self._link_lost_at_s is not None

    @property
    def silent_ids(self) -> frozenset[int]:
        """Servos the controller reported silent (no valid feedback) with no feedback read since; empty otherwise."""
        return frozenset(self._silent_ids)

    def feedback_age_s(self) -> float | None:
        """Seconds since the newest state was read (None before the first). GUI thread."""
        state = self._states.latest
        return None if state is None else time.monotonic() - float(state.host_time_s)

    @property
    def n_servos(self) -> int:
        return self._config.n_joints

    @property
    def controller(self) -> Any:
        """The running RobotController, or None; for app code that needs its own ``submit`` calls."""
        return self._controller

    @property
    def latest_state(self) -> Any:
        """The newest ChainState from the controller thread (None before the first); any thread may read it."""
        return self._states.latest

    def loop_stats(self) -> Any:
        """The control loop's ControllerStats (ticks, missed ticks, period percentiles), or None when disconnected."""
        controller = self._controller
        return None if controller is None else controller.stats()

    @property
    def latest_health(self) -> list:
        """The newest ServoHealth of every servo polled so far, in ID order."""
        return [self._health_by_id[i] for i in sorted(self._health_by_id)]

    @property
    def motion_state(self) -> str:
        return self._motion_state

    @property
    def motion_name(self) -> str:
        return self._motion_name

    # -- connection ------------------------------------------------------------------------------------------------
    def connect_robot(self, port: str | None = None, baud: int | None = None) -> Future:
        """Open the port on a worker thread, check the servo models, start the control loop.

        ``port``/``baud`` override the configured ones. Returns the connect future; the outcome also arrives as
        ``connected(bool)`` and, on failure, ``error(str)`` saying why and what to do.
        """
        if self._closed:
            raise RuntimeError("the robot bridge is closed")
        if self._controller is not None or self.is_connecting:
            if self.is_connecting and self._pending_connect is not None:
                return self._pending_connect
            return _done_future((self._controller, self.timing_warnings))
        self._config = replace(self._config, port=(port or self._config.port).strip(),
                               baud=int(baud or self._config.baud))
        config = self._config
        self.action.emit(f"connect the robot on {config.port} at {config.baud} baud")
        self._set_connection(f"connecting to {config.port} at {config.baud} baud…")
        future = self._executor.submit(self._open_controller, config)
        self._pending_connect = future
        self._connecting = True
        self.when_done(future, self._adopt_controller, self._connect_failed)
        return future

    # ``connect`` is the name in the contract; QObject.connect is static in PySide6, so the instance method is a
    # thin alias that keeps ``bridge.connect()`` working for app code.
    def connect(self, port: str | None = None, baud: int | None = None) -> Future:  # type: ignore[override]
        return self.connect_robot(port, baud)

    def disconnect_robot(self) -> Future:
        """Stop the control loop and close the port on the worker thread; ``connected(False)`` follows."""
        controller, self._controller = self._controller, None
        self._states.stop()
        if controller is None:
            return _done_future(None)
        self.action.emit(f"disconnect the robot ({self.port})")
        self._motion_token += 1
        self._set_motion(MOTION_IDLE, "")
        self._set_connection("disconnecting…")
        future = self._executor.submit(controller.close)
        self.when_done(future, lambda _result: self._after_disconnect(), self._disconnect_failed)
        return future

    def disconnect(self, *args: Any) -> Any:  # type: ignore[override]
        """``bridge.disconnect()`` closes the robot; with arguments it is QObject.disconnect (signal plumbing)."""
        if args:
            return super().disconnect(*args)
        return self.disconnect_robot()

    def close(self) -> None:
        """Stop the control loop, close the port and join every thread this bridge started. GUI thread; blocks."""
        if self._closed:
            return
        self._closed = True
        self._states.stop()
        controller, self._controller = self._controller, None
        if controller is not None:
            controller.close()
        self._executor.shutdown(wait=True, cancel_futures=True)
        # A connect that finished while we were shutting down delivered its controller to a queued slot that will
        # never run now: close it here so its thread does not outlive the bridge.
        pending = self._pending_connect
        if pending is not None and pending.done() and not pending.cancelled() and pending.exception() is None:
            orphan, _warnings = pending.result()
            if orphan is not controller:
                orphan.close()
        self._set_connection("not connected")

    # -- bus operations (each returns a Future; errors are reported via ``error``) ----------------------------------
    def run_on_bus(self, fn: Callable[[Any], T], report_errors: bool = True, holds_bus: bool = False) -> Future:
        """Run ``fn(chain)`` on the thread owning the bus: the controller thread when connected, else the worker
        thread on a temporary connection (opened and closed around the call). ``holds_bus``: ``fn`` holds the bus
        for whole control periods on purpose (the ticks it skips are not blamed on the control rate)."""
        if self._closed:
            return _failed_future(RuntimeError("the robot bridge is closed"))
        if self._controller is None and self._connecting:
            return self._after_connect(lambda: self.run_on_bus(fn, report_errors, holds_bus))
        if self._controller is not None:
            future = self._controller.submit(fn, holds_bus=holds_bus)
        else:
            future = self._executor.submit(_with_temporary_chain, replace(self._config), fn)
        if report_errors:
            self.when_done(future, None)
        return future

    def scan(self, bauds: Sequence[int] | None = None, ids: Sequence[int] = range(0, 253),
             port: str | None = None, report_errors: bool = True) -> Future:
        """Find servos (IDs × baud rates); the future's result is ``list[ServoInfo]``.

        ``port`` overrides the configured port when disconnected (scan a bus before connecting to it).
        """
        bauds = list(bauds) if bauds is not None else None
        ids = list(ids)
        if self._controller is None and self._connecting:
            return self._after_connect(lambda: self.scan(bauds, ids, None, report_errors))
        if port and self._controller is None:
            self._config = replace(self._config, port=port.strip())
        controller = self._controller
        if controller is not None:  # the controller refuses a scan while a motion plays, and says why
            future = controller.scan(ids, bauds)
            if report_errors:
                self.when_done(future, None)
            return future
        return self.run_on_bus(bus_command(bus_commands.scan, ids, bauds), report_errors)

    def _after_connect(self, start: Callable[[], Future]) -> Future:
        """A bus call asked for while the connect is under way runs once it is done: on the new control loop (a scan
        there holds the bus on purpose, its skipped ticks not counted as missed), or on a connection of its own if
        the connect failed — never on a second connection to the port beside the starting loop's, which fought it
        for the bus (the loop lost most of its ticks and its servos' replies)."""
        outer: Future = Future()

        def relay(_outcome: object) -> None:
            inner = start()
            inner.add_done_callback(lambda done: _copy_outcome(done, outer))

        pending = self._pending_connect
        assert pending is not None
        self.when_done(pending, relay, relay)
        return outer

    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> Future:
        """Torque on/off for ``ids`` (default all joints)."""
        controller = self._controller
        if controller is None:
            return self._not_connected()
        which = "every joint" if ids is None else "servo " + ", ".join(str(i) for i in ids)
        self.action.emit(f"torque {'on' if enabled else 'off'}: {which}")
        future = controller.set_torque(enabled, None if ids is None else list(ids))
        self.when_done(future, None)
        return future

    def set_led(self, servo_id: int, on: bool) -> Future:
        controller = self._controller
        if controller is None:
            return self._not_connected()
        self.action.emit(f"LED {'on' if on else 'off'}: servo {servo_id}")
        future = controller.set_led(servo_id, on)
        self.when_done(future, None)
        return future

    def reboot(self, servo_id: int) -> Future:
        """Reboot one servo (clears a latched hardware error; the servo comes back with torque off)."""
        controller = self._controller
        if controller is None:
            return self._not_connected()
        self.action.emit(f"reboot servo {servo_id}")
        future = controller.reboot(servo_id)
        self.when_done(future, lambda _r: self.event.emit(f"servo {servo_id} rebooted (torque is off)"))
        return future

    # -- motion ----------------------------------------------------------------------------------------------------
    def run_motion(self, source: Any, name: str, *, play: bool = False) -> Future:
        """Start a MotionSource on the controller (replacing any running motion); ``motion_changed`` follows.

        Returns the controller's Future: ``"finished"`` or ``"stopped"``, or the error that stopped the motion
        (already reported through ``error``).
        """
        controller = self._controller
        if controller is None:
            self.error.emit(f"cannot start {name}: {NOT_CONNECTED_MESSAGE}")
            return _failed_future(ConnectionError(NOT_CONNECTED_MESSAGE))
        self.action.emit(f"start {name}")
        self._motion_token += 1
        token = self._motion_token
        future = controller.play(source, name) if play else controller.run_motion(source, name)
        self._set_motion(MOTION_RUNNING, name)
        self.when_done(future, lambda outcome: self._motion_ended(token, outcome),
                       lambda exc: self._motion_failed(token, exc))
        return future

    def play(self, source: Any, name: str) -> Future:
        """Hold the limp joints, check the plan (joint limits, speed) and start ``source``: ONE command on the bus
        thread (:meth:`devices.controller.RobotController.play`, what ``sensnake play`` runs). Otherwise as
        :meth:`run_motion`; a refusal arrives through ``error`` and the Future, before any goal is written."""
        return self.run_motion(source, name, play=True)

    def pause_motion(self) -> None:
        if self._controller is not None and self._motion_state == MOTION_RUNNING:
            self.action.emit(f"pause {self._motion_name}".rstrip())
            self._controller.pause()
            self._set_motion(MOTION_PAUSED, self._motion_name)

    def resume_motion(self) -> None:
        if self._controller is not None and self._motion_state == MOTION_PAUSED:
            self.action.emit(f"resume {self._motion_name}".rstrip())
            self._controller.resume()
            self._set_motion(MOTION_RUNNING, self._motion_name)

    def stop_motion(self) -> None:
        if self._motion_state in (MOTION_RUNNING, MOTION_PAUSED):
            self.action.emit(f"stop {self._motion_name}".rstrip())
        if self._controller is not None:
            self._controller.stop_motion()
        if self._motion_state in (MOTION_RUNNING, MOTION_PAUSED):
            self._motion_token += 1
            self._set_motion(MOTION_STOPPED, self._motion_name)

    # Short names used by the tabs (contract: pause/resume/stop_motion).
    pause = pause_motion
    resume = resume_motion

    def emergency_stop(self) -> None:
        """STOP: within one control tick the goals freeze at the present position; torque stays on."""
        self.action.emit("STOP (button or Esc)")
        controller = self._controller
        if controller is None:
            self.event.emit("STOP: the robot is not connected, nothing is moving")
            return
        controller.emergency_stop()
        self._motion_token += 1
        self._set_motion(MOTION_STOPPED, self._motion_name)
        self.event.emit("STOP: motion halted; torque stays on, every joint holds its present position")

    # -- delivering results on the GUI thread -----------------------------------------------------------------------
    def when_done(self, future: Future, on_result: Callable[[Any], None] | None,
                  on_error: Callable[[BaseException], None] | None = None) -> None:
        """Call ``on_result(result)`` or ``on_error(exc)`` on the GUI thread when ``future`` completes.

        Without ``on_error`` a failure is reported through ``error``. Cancelled futures are ignored.
        """
        self._bridge.when_done(future, on_result, on_error if on_error is not None else self._report_error)

    def _report_error(self, exc: BaseException) -> None:
        self.error.emit(describe_error(exc))

    # -- controller callbacks (controller thread) -------------------------------------------------------------------
    def _on_state(self, chain_state: Any) -> None:
        self._states.push(chain_state)

    def _on_health(self, health: list) -> None:
        self._bridge.post(self._deliver_health, list(health))

    def _on_event(self, text: str) -> None:
        self._bridge.post(self.event.emit, str(text))

    def _on_error(self, exc: BaseException) -> None:
        self._bridge.post(self._device_error, exc, time.monotonic())

    def _on_motion_halted(self, name: str) -> None:
        self._bridge.post(self._motion_halted, str(name))

    # -- GUI-thread handlers ----------------------------------------------------------------------------------------
    def _open_controller(self, config: RobotConfig) -> tuple[Any, list[str]]:
        """Worker thread: open the chain, check it, start the controller; returns it and the timing warnings."""
        from devices.controller import RobotController
        from devices.servo_chain import ServoChain

        wanted, why_not = loop_process_wanted(config.port)
        if wanted:
            path = sim_serial_path("robot") if is_sim(config.port) else None
            child_config = replace(config, port=path) if path is not None else config  # the lab's own process: a pty
            process = ControllerProcess(child_config, on_state=self._on_state, on_health=self._on_health,
                                        on_event=self._on_event, on_error=self._on_error,
                                        on_motion_halted=self._on_motion_halted, simulated=path is not None)
            try:
                process.start()  # a device error (port, models, rate) is raised as itself, as below
            except LoopProcessUnavailable as exc:
                why_not = str(exc)
                log.warning("control loop runs in the app's process: %s", exc)
            else:
                self.loop_where = f"its own process (pid {process.pid})"
                return process, process.timing_warnings
        self.loop_where = f"the app's process ({why_not})"
        chain = ServoChain(config, device="robot")
        chain.open()
        try:
            chain.check_models()
            chain.check_rate(config.control_rate_hz)  # RateError (with the fix) before the loop starts
            warnings = list(chain.timing_warnings())
            controller = RobotController(chain, config, on_state=self._on_state, on_health=self._on_health,
                                         on_event=self._on_event, on_error=self._on_error,
                                         on_motion_halted=self._on_motion_halted)
        except BaseException:
            chain.close()
            raise
        controller.start()
        return controller, warnings

    def _adopt_controller(self, opened: tuple[Any, list[str]]) -> None:
        controller, warnings = opened
        self._connecting = False
        if self._closed:
            controller.close()
            return
        self._controller = controller
        self.set_timing_findings(warnings)
        self.connected_at_s = time.monotonic()
        kind = "simulated" if self.is_sim else "real"
        self._set_connection(self._connected_text())
        self._states.start()
        self.connected.emit(True)
        n_warnings = len(self.timing_warnings)
        timing = (f"; {n_warnings} timing warning{'' if n_warnings == 1 else 's'}, see the Hardware tab"
                  if n_warnings else "")
        scheduling = getattr(controller, "scheduling", "")
        how = f" ({scheduling})" if not self.is_sim and scheduling and scheduling != "not started" else ""
        self.event.emit(f"robot connected: {self.n_servos} servos on {self.port} at {self.baud} baud ({kind}){timing}; "
                        f"control loop in {self.loop_where}{how}")
        if self.servo_profile:
            self.apply_profile()

    def set_timing_findings(self, findings: Sequence[str]) -> None:
        """The latest timing check's findings (GUI thread): warnings and, on the simulated lab, notes."""
        self.timing_warnings, self.timing_notes = split_timing(findings, self.is_sim)

    def apply_profile(self) -> None:
        """The lab's ``[servos]`` items onto every joint, where a servo differs (read-compare, then write)."""
        from app.core import servo_settings

        future = self.run_on_bus(bus_command(servo_settings.apply_profile, list(self.config.joint_ids),
                                             list(self.servo_profile)), report_errors=False, holds_bus=True)

        def done(changes: list) -> None:
            self.last_profile_changes = list(changes)
            self.event.emit(f"servo settings from the lab config's [servos]: {servo_settings.describe_changes(changes)}")
            self.profile_applied.emit(self.last_profile_changes)

        def failed(exc: BaseException) -> None:
            self.event.emit(f"could not apply the lab config's [servos] settings: {describe_error(exc)}")

        self.when_done(future, done, failed)

    def _connected_text(self) -> str:
        return f"{self.n_servos} servos on {self.port} ({'simulated' if self.is_sim else 'real'})"

    def _connect_failed(self, exc: BaseException) -> None:
        self._connecting = False
        self._set_connection("not connected")
        reason = describe_error(exc)
        hint = "" if isinstance(exc, DeviceError) else (
            " Check the port name and that the servos are powered, or use port 'sim' for the simulated lab.")
        self.error.emit(f"robot: could not connect on {self.port} at {self.baud} baud: {reason}{hint}")
        self.connected.emit(False)

    def _after_disconnect(self) -> None:
        self.loop_where = "not connected"
        self._link_lost_at_s = self._silent_at_s = None
        self._silent_ids.clear()
        self._set_connection("not connected")
        self.connected.emit(False)
        self.event.emit("robot disconnected")

    def _disconnect_failed(self, exc: BaseException) -> None:
        self.error.emit(f"robot: closing {self.port} failed: {describe_error(exc)}")
        self._after_disconnect()

    def _deliver_states(self, block: list) -> None:
        silent_at_s = self._silent_at_s
        if silent_at_s is not None and block[-1].host_time_s > silent_at_s:
            self._silent_at_s = None  # every servo answered the sync read again
            self._silent_ids.clear()
        lost_at_s = self._link_lost_at_s
        if lost_at_s is not None and block[-1].host_time_s > lost_at_s:
            # Feedback read after the loss: the controller has reopened the port.
            self._link_lost_at_s = None
            self._set_connection(self._connected_text())
            self.event.emit(f"robot link on {self.port} is back")
        self.state_block.emit(block)
        self.state.emit(block[-1])

    def _deliver_health(self, health: list) -> None:
        for item in health:
            self._health_by_id[item.servo_id] = item
        self.health.emit(health)

    def _device_error(self, exc: BaseException, at_s: float) -> None:
        if isinstance(exc, LoopDiedError):
            self._loop_died(exc)
            return
        if isinstance(exc, LinkLostError) and self._controller is not None:
            self._link_lost_at_s = at_s
            self._set_connection(f"link lost on {self.port}: reconnecting…")
        if isinstance(exc, NoReplyError) and not isinstance(exc, BusQuietError) and self._controller is not None:
            # (a quiet bus names no servo silent for sure: the rows say no feedback, not which servo is silent)
            self._silent_at_s = at_s
            self._silent_ids.add(int(exc.servo_id))
        if isinstance(exc, RepliesHeldError):
            self._silent_at_s = None  # the servos had answered: none of them is silent
            self._silent_ids.clear()
        if isinstance(exc, (LinkLostError, NoReplyError)) and self._controller is not None:
            self._health_by_id.clear()  # torque, LED, errors as last polled are not what the servos hold now
        self._report_once(exc)

    def _loop_died(self, exc: LoopDiedError) -> None:
        """The control loop's process ended by itself: say so (what happened, what to do), keep everything received
        (states already delivered stay with their subscribers, e.g. a recording), and show the robot disconnected;
        the app stays up and Connect starts a new loop."""
        controller = self._controller
        if controller is None or getattr(controller, "died", None) is not exc:
            self._report_once(exc)
            return
        self._controller = None
        self._states.flush()
        self._states.stop()
        self._link_lost_at_s = None
        self._silent_at_s = None
        self._silent_ids.clear()
        self.loop_where = "not connected"
        self._report_once(exc)
        self._motion_token += 1
        if self._motion_state in (MOTION_RUNNING, MOTION_PAUSED):
            self._set_motion(MOTION_FAULT, self._motion_name)
        self._set_connection(f"control loop stopped on {self.port}: reconnect (Hardware tab → Connect)")
        self.connected.emit(False)
        self._executor.submit(controller.close)  # reaps the dead process on the worker thread

    def _report_once(self, exc: BaseException) -> None:
        # The controller both fails the motion's future and calls on_error with the same exception object.
        if exc is self._last_reported:
            return
        self._last_reported = exc
        self.error.emit(describe_error(exc))

    def _motion_failed(self, token: int, exc: BaseException) -> None:
        self._report_once(exc)
        self._motion_ended(token, MOTION_FAULT)

    def _motion_halted(self, name: str) -> None:
        """The loop's watchdog stopped the motion ``name`` (no goals from now on); its Future fails later with the
        cause. Shown as stopped from now, not as running until the cause is known."""
        if self._motion_state in (MOTION_RUNNING, MOTION_PAUSED) and name == self._motion_name:
            self._set_motion(MOTION_HALTED, name)

    def _motion_ended(self, token: int, outcome: str) -> None:
        # A later run_motion / stop / STOP already moved the state on; an old motion's ending is not news.
        if token != self._motion_token:
            return
        self._motion_token += 1
        state = MotionState(outcome) if outcome in (MOTION_FINISHED, MOTION_STOPPED, MOTION_FAULT) else MOTION_STOPPED
        self._set_motion(state, self._motion_name)

    def _set_motion(self, state: MotionState, name: str) -> None:
        self._motion_state, self._motion_name = state, name
        self.motion_changed.emit(state)

    def _set_connection(self, text: str) -> None:
        self.connection_text = text
        self.connection_changed.emit(text)

    def _not_connected(self) -> Future:
        self.error.emit(NOT_CONNECTED_MESSAGE)
        return _failed_future(ConnectionError(NOT_CONNECTED_MESSAGE))


def _with_temporary_chain(config: RobotConfig, fn: Callable[[Any], T]) -> T:
    """Worker thread: open a chain just for ``fn`` (e.g. a scan before connecting), then close it."""
    from devices.servo_chain import ServoChain

    chain = ServoChain(config, device="robot")
    chain.open()
    try:
        return fn(chain)
    finally:
        chain.close()


def _copy_outcome(done: Future, into: Future) -> None:
    """``into`` gets ``done``'s result, exception or cancellation."""
    if done.cancelled():
        into.cancel()
        return
    exc = done.exception()
    if exc is not None:
        into.set_exception(exc)
    else:
        into.set_result(done.result())


def _done_future(result: Any) -> Future:
    future: Future = Future()
    future.set_result(result)
    return future


def _failed_future(exc: BaseException) -> Future:
    future: Future = Future()
    future.set_exception(exc)
    return future
