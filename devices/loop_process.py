"""The robot's control loop in its own process, for a robot on a real port (a serial device or a pty).

Why: in the app the GUI thread holds the Python interpreter lock for long stretches (pyqtgraph paints, the 3-D lab,
a tab's first show); a bus thread in the same process waits for it, however high its scheduling priority, and ticks
come late. A separate interpreter has its own lock. :class:`ControllerProcess` has the methods and callbacks of
:class:`devices.controller.RobotController` (the GUI's :class:`app.gui.robot_bridge.RobotBridge` uses either), and
runs a real ``RobotController`` in a child process:

- the child is a fresh interpreter (``python -m devices.loop_process``, what multiprocessing's "spawn" does, without
  re-importing the app's ``__main__``; never a fork of a process with Qt and threads), its own session, so a Ctrl-C
  in the terminal reaches the app, which closes it. It opens the port, checks the servo models and the rate, reads
  the timing warnings, and starts the loop; until then nothing is written;
- calls cross one socket pair as pickled messages: motion sources as data (their plans), bus commands as named
  commands (:mod:`devices.bus_commands`; a closure cannot cross and is refused with that reason), and
  pause/resume/stop/STOP as messages the child's main thread hands to its controller at once (STOP still acts on
  the next tick);
- back come, from a sender thread in the child (so a slow GUI never blocks a tick): once per tick the tick's states,
  the motion's name and progress (copied onto the caller's source object, where the Gait tab reads it) and whether
  the bus is connected; health polls, events, errors and the results of commands as they happen. An exception
  arrives as the same class with the same one-line message, and one exception object sent twice (the failed
  motion's Future and ``on_error``) is one object in this process too;
- a watcher thread here waits on the socket: a child that dies closes its end, so its death is seen at once (the
  end of file), not after a timeout; then every pending Future fails and ``on_error`` gets :class:`LoopDiedError`
  (what happened, what the servos are doing, what to do);
- a child alive but hung (stopped, deadlocked, stuck in a system call) is seen by its heartbeat: the bus thread
  writes its tick count and tick time into a page of memory shared with this process (not through the socket,
  so a busy sender thread there or a starved watcher here is never taken for a hung loop: the watcher judges by
  the child's own last tick time, whenever it runs). ``STALL_PERIODS`` periods without a tick → an event ("has not
  ticked for …"; "ticks again" when it does); ``HUNG_KILL_S`` → the child is killed and reported as
  :class:`LoopDiedError` naming the reason, so the user can reconnect. A command running on the bus thread (a scan,
  a reboot, a link check, a motion's start) is announced in the heartbeat: ticks wait for it, so it is judged
  against ``COMMAND_HUNG_S`` instead.

With port ``sim`` the loop runs in its own process when the simulated lab does (:mod:`devices.sim.lab_process`,
the app's default: the child opens the lab's robot pty), and stays in the app's process when the lab lives there
(tests, ``SENSNAKE_LAB_PROCESS=0``). Anything that keeps the child from starting (no interpreter, an import error, a timeout) raises
:class:`LoopProcessUnavailable`; the caller then runs the loop in-process and says why. Device errors (port, models,
rate) are raised as themselves, as an in-process start would.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import functools
import itertools
import logging
import math
import mmap
import os
import pickle
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from devices import process_messages as messages
from devices import tick_trace
from devices.child import child_setup, release_shared, spawn
from devices.config import RobotConfig
from devices.controller import (
    ControllerStats,
    MotionSource,
    RobotController,
    _lower_switch_interval,
    _raise_thread_priority,
    _switched_off,
)
from devices.errors import LinkLostError, LoopDiedError, LoopProcessUnavailable
from devices.servo_chain import ChainState, ServoChain, ServoHealth

log = logging.getLogger(__name__)

READY_TIMEOUT_S = 60.0  # a fresh interpreter imports numpy and pyserial; a loaded 2-core machine can take seconds
CLOSE_TIMEOUT_S = 10.0
QUERY_TIMEOUT_S = 1.0  # stats() / recent_periods_s(): answered between two receives of the child's main thread
STALL_PERIODS = 5  # a child that has not ticked for this many of its periods is reported (an event, once) ...
STALL_REPORT_MIN_S = 0.05  # ... but not before this (at 200 Hz five periods are only 25 ms)
HUNG_KILL_S = 5.0  # a child silent this long is ended and reported as dead (LoopDiedError): the user reconnects
COMMAND_HUNG_S = 60.0  # a bus command (scan, reboot, checks) running this long is a hung child too
HEARTBEAT_CHECK_S = 0.02  # how often the watcher looks at the heartbeat
HEARTBEAT = struct.Struct("<Qdd")  # tick count, time.monotonic() of the last tick, start of the running command or 0
EXCEPTIONS_KEPT = 64
CHILD_METHODS = frozenset({"run_motion", "play", "pause", "resume", "stop_motion", "emergency_stop", "submit",
                           "set_torque", "set_led", "reboot", "scan", "stats", "recent_periods_s"})
ENV_SWITCH = "SENSNAKE_LOOP_PROCESS"  # "0" keeps the loop in the app's process on every port


def _machine_load() -> str:
    """The machine's 1-minute load average against its cores, for a stall message ("load 9.8 on 2 cores")."""
    try:
        return f"load {os.getloadavg()[0]:.1f} on {os.cpu_count() or 1} cores"
    except OSError:
        return "load unknown"


def loop_process_wanted(port: str) -> tuple[bool, str]:
    """Whether a robot on ``port`` gets its loop in a child process, and if not, why (one line)."""
    from devices.factory import is_sim, sim_serial_path

    if is_sim(port) and sim_serial_path("robot") is None:
        return False, "port sim: the simulated lab lives in the app's process"
    if os.name != "posix":
        return False, "the loop's own process needs Linux or macOS (it inherits a socket)"
    if _switched_off(ENV_SWITCH):
        return False, f"{ENV_SWITCH}=0"
    return True, ""


# -- exceptions across the socket: devices.process_messages.ErrorPayload ----------------------------------------------


# -- the parent's side -------------------------------------------------------------------------------------------------
class ControllerProcess:
    """A :class:`RobotController` running in a child process; same methods, callbacks on a watcher thread here."""

    def __init__(self, robot: RobotConfig, on_state: Callable[[ChainState], None] | None = None,
                 on_health: Callable[[list[ServoHealth]], None] | None = None,
                 on_event: Callable[[str], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None,
                 on_motion_halted: Callable[[str], None] | None = None, *, simulated: bool = False) -> None:
        self.robot = robot
        self.simulated = simulated  # a simulated robot on a pty (devices.sim.lab_process): see RobotController
        self.period_s = 1.0 / robot.control_rate_hz
        self._on_state, self._on_health, self._on_event, self._on_error = on_state, on_health, on_event, on_error
        self._on_motion_halted = on_motion_halted
        self._process: subprocess.Popen | None = None
        self._conn: Connection | None = None
        self._send_lock = threading.Lock()
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._pending: dict[int, concurrent.futures.Future] = {}
        self._sources: dict[int, Any] = {}  # request id of a motion -> the caller's source object (progress)
        self._exceptions: collections.OrderedDict[int, BaseException] = collections.OrderedDict()
        self._watcher: threading.Thread | None = None
        self._closing = False
        self.died: LoopDiedError | None = None
        self.died_at_s: float | None = None
        self.watcher_scheduling = "not started"
        self.timing_warnings: list[str] = []
        self.scheduling = "not started"
        self._connected = False
        self._motion_name: str | None = None
        self._paused = False
        self._latest_state: ChainState | None = None
        self._last_stats: ControllerStats | None = None
        self._heartbeat_fd: int | None = None
        self._heartbeat: mmap.mmap | None = None
        self._started_s = 0.0
        self._stall_reported_s: float | None = None  # the child's last tick time when a stall was reported
        self._hung: str | None = None  # why the watcher ended the child (it did not tick)
        self._message_tick_s = 0.0  # the child's time of the newest tick whose message arrived
        self.stall_limit_s = max(STALL_PERIODS * self.period_s, STALL_REPORT_MIN_S)
        self.hung_after_s = HUNG_KILL_S
        self.ticks_seen = 0

    # -- lifecycle -------------------------------------------------------------------------------------------------
    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def start(self) -> None:
        """Start the child and wait until its loop runs. Raises the device error that stopped it (as an in-process
        start would) or :class:`LoopProcessUnavailable` (the child itself could not run)."""
        if self._process is not None:
            raise RuntimeError("the robot controller is already running")
        try:
            child = spawn("devices.loop_process", 1, "sensnake-heartbeat-")
        except (OSError, ValueError) as exc:  # ValueError: pass_fds/start_new_session where unsupported
            raise LoopProcessUnavailable(f"cannot start {sys.executable}: {exc}") from exc
        self._process, self._conn = child.process, child.conn
        self._heartbeat_fd, self._heartbeat = child.shared_fd, child.shared
        try:
            self._conn.send(messages.LoopStart(self.robot, self.simulated))
            reply = self._wait_ready()
        except BaseException:
            self._kill()
            self._close_heartbeat()
            raise
        self.timing_warnings = list(reply.timing_warnings)
        self.scheduling = reply.scheduling
        self._connected = True
        self._started_s = time.monotonic()
        self._watcher = threading.Thread(target=self._watch, name=f"loop-process-watcher[{self.pid}]", daemon=True)
        self._watcher.start()

    def _wait_ready(self) -> messages.LoopReady:
        conn, process = self._conn, self._process
        assert conn is not None and process is not None
        deadline = time.monotonic() + READY_TIMEOUT_S
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise LoopProcessUnavailable(f"the loop process did not start within {READY_TIMEOUT_S:g} s")
            try:
                if not conn.poll(min(left, 0.5)):
                    if process.poll() is not None:
                        raise LoopProcessUnavailable(f"the loop process exited at start ({_exit_words(process)})")
                    continue
                reply = conn.recv()
            except (EOFError, OSError) as exc:
                process.wait(timeout=5)
                raise LoopProcessUnavailable(f"the loop process exited at start ({_exit_words(process)})") from exc
            reply = messages.expect(reply, messages.LoopReady, messages.Failed, messages.Broken)
            if isinstance(reply, messages.LoopReady):
                return reply
            if isinstance(reply, messages.Failed):
                raise reply.error.rebuild()
            assert isinstance(reply, messages.Broken)
            raise LoopProcessUnavailable(reply.reason)

    def close(self) -> None:
        """End any motion ("stopped"), stop the loop, close the port, end the child. Idempotent."""
        process, conn = self._process, self._conn
        if process is None or self._closing:
            return
        self._closing = True
        if self.died is None:
            with contextlib.suppress(OSError, ValueError):
                self._send(messages.Close())
        try:
            process.wait(timeout=CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            log.warning("the loop process %d did not end in %g s: killing it", process.pid, CLOSE_TIMEOUT_S)
            self._kill()
        watcher = self._watcher
        if watcher is not None and watcher is not threading.current_thread():
            watcher.join(timeout=CLOSE_TIMEOUT_S)
        if conn is not None:
            conn.close()
        self._connected = False
        self._fail_pending(None)
        self._close_heartbeat()

    def _close_heartbeat(self) -> None:
        fd, beat = self._heartbeat_fd, self._heartbeat
        self._heartbeat_fd, self._heartbeat = None, None
        release_shared(fd, beat)

    def _kill(self) -> None:
        process = self._process
        if process is None:
            return
        if process.poll() is None:
            process.kill()
        try:
            process.wait(timeout=CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            log.error("the loop process %d did not exit after SIGKILL", process.pid)
        if self._conn is not None:
            self._conn.close()

    def __enter__(self) -> ControllerProcess:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- properties ------------------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._process is not None and self.died is None and not self._closing

    @property
    def connected(self) -> bool:
        return self._connected and self.running

    @property
    def motion_name(self) -> str | None:
        return self._motion_name

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def latest_state(self) -> ChainState | None:
        return self._latest_state

    def stats(self) -> ControllerStats:
        """The child loop's statistics (asked for; the last ones received if it does not answer in time)."""
        stats = self._query("stats")
        if stats is not None:
            self._last_stats = stats
            return stats
        if self._last_stats is not None:
            return self._last_stats
        nan = math.nan
        return ControllerStats(0, 0, nan, nan, nan, nan, nan, 0, 0, 0)

    def recent_periods_s(self, n: int) -> np.ndarray:
        periods = self._query("recent_periods_s", n)
        return np.asarray(periods if periods is not None else [], dtype=float)

    def _query(self, method: str, *args: Any) -> Any:
        if not self.running:
            return None
        try:
            return self._request(method, *args).result(QUERY_TIMEOUT_S)
        except Exception:  # noqa: BLE001 - a dead or busy child: the caller gets the last figures
            return None

    # -- commands --------------------------------------------------------------------------------------------------
    def run_motion(self, source: MotionSource, name: str) -> concurrent.futures.Future[str]:
        return self._start_motion("run_motion", source, name)

    def play(self, source: MotionSource, name: str, *, hold_first: bool = True) -> concurrent.futures.Future[str]:
        return self._start_motion("play", source, name, hold_first=hold_first)

    def _start_motion(self, method: str, source: MotionSource, name: str, **kwargs: Any) -> concurrent.futures.Future:
        future = self._request(method, source, name, **kwargs)
        request_id = getattr(future, "request_id", None)
        if request_id is not None:
            with self._lock:
                self._sources[request_id] = source
        return future

    def pause(self) -> None:
        self._message("pause")

    def resume(self) -> None:
        self._message("resume")

    def stop_motion(self) -> None:
        self._message("stop_motion")

    def emergency_stop(self) -> None:
        self._message("emergency_stop")

    def submit(self, fn: Callable[[Any], Any], holds_bus: bool = False) -> concurrent.futures.Future:
        """Run a named bus command (:mod:`devices.bus_commands`) on the child's bus thread (``holds_bus``: as
        :meth:`RobotController.submit`)."""
        return self._request("submit", fn, holds_bus=holds_bus)

    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> concurrent.futures.Future[None]:
        return self._request("set_torque", enabled, None if ids is None else list(ids))

    def set_led(self, servo_id: int, on: bool) -> concurrent.futures.Future[None]:
        return self._request("set_led", servo_id, on)

    def reboot(self, servo_id: int) -> concurrent.futures.Future[None]:
        return self._request("reboot", servo_id)

    def scan(self, ids: Iterable[int] = range(0, 253), bauds: Sequence[int] | None = None
             ) -> concurrent.futures.Future:
        return self._request("scan", list(ids), None if bauds is None else list(bauds))

    # -- plumbing ----------------------------------------------------------------------------------------------------
    def _request(self, method: str, *args: Any, **kwargs: Any) -> concurrent.futures.Future:
        future: concurrent.futures.Future = concurrent.futures.Future()
        if self.died is not None:
            future.set_exception(self.died)
            return future
        request_id = next(self._ids)
        future.request_id = request_id  # type: ignore[attr-defined]
        try:
            message = pickle.dumps(messages.Call(request_id, method, tuple(args), dict(kwargs)),
                                   protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - e.g. a lambda submitted as a bus command
            future.set_exception(TypeError(
                f"{method}: cannot be sent to the control loop's process ({' '.join(str(exc).split())}); use a named "
                "bus command (devices.bus_commands) or a motion source without lambdas"))
            return future
        with self._lock:
            self._pending[request_id] = future
        try:
            self._send_bytes(message)
        except (OSError, ValueError) as exc:
            with self._lock:
                self._pending.pop(request_id, None)
            if not future.done():
                future.set_exception(self.died or LinkLostError(f"the control loop's process is gone: {exc}"))
        return future

    def _message(self, method: str) -> None:
        if self.died is not None or self._closing:
            return
        try:
            self._send(messages.Call(None, method))
        except (OSError, ValueError):
            log.debug("%s not sent: the loop process is gone", method)

    def _send(self, message: messages.Message) -> None:
        self._send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))

    def _send_bytes(self, data: bytes) -> None:
        conn = self._conn
        if conn is None:
            raise ValueError("not started")
        with self._send_lock:
            conn.send_bytes(data)

    def _exception(self, payload: messages.ErrorPayload) -> BaseException:
        key = payload.key
        with self._lock:
            exc = self._exceptions.get(key)
            if exc is None:
                exc = payload.rebuild()
                self._exceptions[key] = exc
                while len(self._exceptions) > EXCEPTIONS_KEPT:
                    self._exceptions.popitem(last=False)
        return exc

    def _watch(self) -> None:
        """Watcher thread: deliver the child's messages; notice its death (end of file) or a stall. It asks for the
        bus thread's real-time priority and the 1 ms interpreter switch interval (devices.controller), so a busy
        machine or the GUI thread delays the news of a death less (it still needs the interpreter lock)."""
        _lower_switch_interval()
        self.watcher_scheduling = _raise_thread_priority()
        conn = self._conn
        assert conn is not None
        check_every_s = min(HEARTBEAT_CHECK_S, self.period_s)
        next_check_s = time.monotonic()
        while True:
            try:
                # Judged on a clock, not only when the socket is quiet: answers to queries keep it busy even while
                # the bus thread hangs.
                if time.monotonic() >= next_check_s:
                    self._check_heartbeat()
                    next_check_s = time.monotonic() + check_every_s
                if not conn.poll(check_every_s):
                    continue
                message = conn.recv()
            except (EOFError, OSError):
                break
            if isinstance(message, messages.Bye):
                break
            try:
                self._handle(message)
            except Exception:  # noqa: BLE001 - thread boundary: a broken subscriber must not stop the watcher
                log.exception("loop process message %s failed", type(message).__name__)
        if not self._closing:
            self._loop_died()

    def heartbeat(self) -> tuple[int, float, float]:
        """The child's (tick count, time.monotonic() of its last tick or 0.0, start of its running command or 0.0),
        read from the shared page (the bus thread writes it; a read that raced a write is read again)."""
        beat = self._heartbeat
        if beat is None:
            return 0, 0.0, 0.0
        first = HEARTBEAT.unpack_from(beat)
        for _ in range(8):
            second = HEARTBEAT.unpack_from(beat)
            if second == first:
                break
            first = second
        return first

    def _check_heartbeat(self) -> None:
        if self._closing or self.died is not None or self._hung is not None:
            return
        ticks, tick_s, command_s = self.heartbeat()
        now = time.monotonic()
        # The child's own time of its newest tick, from the heartbeat and from the newest tick message (two channels:
        # a backlog on the socket or a broken shared page alone is no stall); before its first tick, since ready.
        last_s = max(tick_s, self._message_tick_s, self._started_s)
        if command_s:
            if now - command_s > COMMAND_HUNG_S:
                self._end_hung(f"a bus command did not return for {now - command_s:.0f} s")
            return  # ticks wait for the command: no stall while it runs
        silent_s = now - last_s
        if silent_s >= self.hung_after_s:
            log.error("loop process %s: heartbeat (ticks %d, last tick %.3f, command %.3f), last tick message %.3f, "
                      "ready at %.3f, now %.3f", self.pid, ticks, tick_s, command_s, self._message_tick_s,
                      self._started_s, now)
            self._end_hung(f"did not tick for {silent_s:.1f} s")
        elif silent_s >= self.stall_limit_s and self._stall_reported_s is None:
            self._stall_reported_s = last_s
            self._emit(self._on_event, (
                f"control loop process (pid {self.pid}) has not ticked for {silent_s * 1e3:.0f} ms "
                f"({silent_s / self.period_s:.0f} periods at {self.robot.control_rate_hz:g} Hz): the loop was held "
                f"off the CPU, or its port's bytes in the kernel's tty worker ({_machine_load()}), not a servo; it "
                f"is ended if it stays silent for {self.hung_after_s:g} s"))
        elif self._stall_reported_s is not None and last_s > self._stall_reported_s:
            self._emit(self._on_event, (f"control loop process (pid {self.pid}) ticks again after "
                                        f"{(last_s - self._stall_reported_s) * 1e3:.0f} ms"))
            self._stall_reported_s = None

    def _end_hung(self, why: str) -> None:
        """The child is alive but does not run its loop: kill it; the end of file then reports it (LoopDiedError
        with ``why``)."""
        process = self._process
        self._hung = why
        log.error("the loop process %s %s: killing it", self.pid, why)
        if process is not None and process.poll() is None:
            with contextlib.suppress(OSError):
                process.kill()

    def _handle(self, message: object) -> None:
        message = messages.expect(message, messages.Tick, messages.Result, messages.Health, messages.Event,
                                  messages.ErrorReport, messages.MotionHalted)
        if isinstance(message, messages.Tick):
            self.ticks_seen += 1
            self._message_tick_s = max(self._message_tick_s, message.tick_s)
            self._connected, self._motion_name, self._paused, self.scheduling = (
                message.connected, message.motion_name, message.paused, message.scheduling)
            if message.progress is not None and message.motion_request is not None:
                source = self._sources.get(message.motion_request)
                if source is not None:
                    with contextlib.suppress(AttributeError):
                        source.progress = message.progress
            for state in message.states:
                self._latest_state = state
                self._emit(self._on_state, state)
        elif isinstance(message, messages.Result):
            with self._lock:
                future = self._pending.pop(message.request_id, None)
                self._sources.pop(message.request_id, None)  # a motion's result comes when it ends
            if future is None or future.done():
                return  # a request already given up (a query that timed out), or one this side never made
            if message.error is None:
                future.set_result(message.value)
            else:
                future.set_exception(self._exception(message.error))
        elif isinstance(message, messages.Health):
            self._emit(self._on_health, list(message.health))
        elif isinstance(message, messages.Event):
            self._emit(self._on_event, message.text)
        elif isinstance(message, messages.ErrorReport):
            self._emit(self._on_error, self._exception(message.error))
        elif isinstance(message, messages.MotionHalted):
            self._emit(self._on_motion_halted, message.name)

    def _loop_died(self) -> None:
        self.died_at_s = time.monotonic()  # when the end of file was read (bench_servo_bus measures it)
        process = self._process
        assert process is not None
        try:
            process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:  # closed its socket but lives on: end it, it no longer hears us
            process.kill()
            process.wait(timeout=CLOSE_TIMEOUT_S)
        motion = f"; motion {self._motion_name!r} stopped" if self._motion_name else ""
        what = (f"{self._hung}; ended it" if self._hung is not None
                else f"ended unexpectedly ({_exit_words(process)})")
        error = LoopDiedError(
            f"the control loop process (pid {process.pid}) {what}{motion}: "
            "the servos hold their last goal with torque on; what was recorded is kept. Reconnect the robot "
            "(Hardware tab → Connect) to control it again")
        self.died = error
        self._connected = False
        self._motion_name = None
        self._fail_pending(error)
        self._emit(self._on_error, error)

    def _fail_pending(self, error: BaseException | None) -> None:
        with self._lock:
            pending, self._pending = self._pending, {}
            self._sources.clear()
        for future in pending.values():
            if future.done():
                continue
            if error is None:
                future.cancel()
            else:
                future.set_exception(error)

    def _emit(self, callback: Callable | None, value: Any) -> None:
        if callback is None:
            return
        try:
            callback(value)
        except Exception:  # noqa: BLE001 - thread boundary: a broken subscriber must not stop the watcher
            log.exception("robot controller callback %r failed", callback)


def _exit_words(process: subprocess.Popen) -> str:
    code = process.poll()
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


# -- the child's side --------------------------------------------------------------------------------------------------
class _Child:
    """The child process: a RobotController whose callbacks queue messages, a sender thread, a receiver (main)."""

    def __init__(self, conn: Connection, heartbeat: mmap.mmap | None = None) -> None:
        self.conn = conn
        self.heartbeat = heartbeat
        self.ticks = 0
        self.last_tick_s = 0.0
        self.command_since_s = 0.0
        self.out: queue.SimpleQueue[messages.Message | None] = queue.SimpleQueue()
        self.states: list[ChainState] = []
        self.controller: RobotController | None = None
        self.motion_requests: dict[int, int] = {}  # id(source) -> request id (to send the progress with)
        self.recent_exceptions: collections.deque[BaseException] = collections.deque(maxlen=EXCEPTIONS_KEPT)

    def run(self) -> int:
        _raise_thread_priority()  # this (receiver) thread too: see _send_loop
        sender = threading.Thread(target=self._send_loop, name="loop-process-sender", daemon=True)
        sender.start()
        try:
            start = messages.expect(self.conn.recv(), messages.LoopStart)
            self.controller = self._open(start.robot, start.simulated)
        except Exception as exc:  # noqa: BLE001 - a device error reaches the parent as itself, raised there
            self.out.put(messages.Failed(self._payload(exc)))
            self.out.put(None)
            sender.join(timeout=5)
            return 1
        try:
            self._receive()
        finally:
            self.controller.close()
            self.out.put(messages.Bye())
            self.out.put(None)
            sender.join(timeout=5)
        return 0

    def _open(self, robot: RobotConfig, simulated: bool) -> RobotController:
        chain = ServoChain(robot, device="robot")
        chain.open()
        try:
            chain.check_models()
            chain.check_rate(robot.control_rate_hz)  # RateError (with the fix) before the loop starts
            warnings = list(chain.timing_warnings())
            controller = RobotController(chain, robot, on_state=self.states.append, on_health=self._health,
                                         on_event=self._event, on_error=self._error, on_tick=self._tick,
                                         on_command=self._command, on_motion_halted=self._halted,
                                         simulated=simulated)
        except BaseException:
            chain.close()
            raise
        controller.start()
        controller.wait_started(5.0)  # its scheduling is part of the answer
        self.out.put(messages.LoopReady(tuple(warnings), controller.scheduling))
        return controller

    def _receive(self) -> None:
        controller = self.controller
        assert controller is not None
        while True:
            try:
                message = self.conn.recv()
            except (EOFError, OSError):
                return  # the app is gone (closed or killed): stop the loop, close the port
            if isinstance(message, messages.Close):
                return
            call = messages.expect(message, messages.Call)
            request_id, method, args, kwargs = call.request_id, call.name, call.args, call.kwargs
            trace = tick_trace.TRACE
            if trace is not None:
                trace.mark("call", method)
            if method not in CHILD_METHODS:
                if request_id is not None:
                    self.out.put(messages.Result(request_id, error=self._payload(
                        ValueError(f"no such command {method!r}"))))
                continue
            try:
                result = getattr(controller, method)(*args, **kwargs)
            except Exception as exc:  # noqa: BLE001 - handed back through the request's Future
                if request_id is not None:
                    self.out.put(messages.Result(request_id, error=self._payload(exc)))
                continue
            if request_id is None:
                continue
            if isinstance(result, concurrent.futures.Future):
                if method in ("play", "run_motion"):
                    self.motion_requests[id(args[0])] = request_id
                result.add_done_callback(functools.partial(self._done, request_id))
            else:
                self.out.put(messages.Result(request_id, result))

    def _done(self, request_id: int, future: concurrent.futures.Future) -> None:
        for key in [k for k, rid in self.motion_requests.items() if rid == request_id]:
            del self.motion_requests[key]
        if future.cancelled():
            self.out.put(messages.Result(request_id, error=self._payload(
                concurrent.futures.CancelledError("the control loop stopped before the command ran"))))
            return
        exc = future.exception()
        if exc is not None:
            self.out.put(messages.Result(request_id, error=self._payload(exc)))
        else:
            self.out.put(messages.Result(request_id, future.result()))

    # -- controller callbacks (bus thread) ----------------------------------------------------------------------------
    def _beat(self) -> None:
        if self.heartbeat is not None:
            HEARTBEAT.pack_into(self.heartbeat, 0, self.ticks, self.last_tick_s, self.command_since_s)

    def _command(self, started_s: float | None) -> None:
        self.command_since_s = started_s or 0.0
        self.last_tick_s = time.monotonic()  # ticks wait for the command from now (or start again from now)
        self._beat()

    def _tick(self) -> None:
        self.ticks += 1
        self.last_tick_s = time.monotonic()
        self._beat()
        controller = self.controller
        if controller is None:
            return
        states, self.states[:] = list(self.states), []
        source = controller.motion_source
        request = self.motion_requests.get(id(source)) if source is not None else None
        progress = getattr(source, "progress", None) if source is not None else None
        self.out.put(messages.Tick(tuple(states), controller.connected, controller.motion_name, controller.paused,
                                   request, progress, controller.scheduling, self.last_tick_s))

    def _health(self, health: list[ServoHealth]) -> None:
        self.out.put(messages.Health(tuple(health)))

    def _event(self, text: str) -> None:
        self.out.put(messages.Event(str(text)))

    def _error(self, exc: BaseException) -> None:
        self.out.put(messages.ErrorReport(self._payload(exc)))

    def _halted(self, name: str) -> None:
        self.out.put(messages.MotionHalted(str(name)))

    def _payload(self, exc: BaseException) -> messages.ErrorPayload:
        self.recent_exceptions.append(exc)  # its id stays unique while the parent may still see it twice
        return messages.ErrorPayload.of(exc, "robot")

    def _send_loop(self) -> None:
        # Every thread of this process asks for the bus thread's priority: one preempted while it holds the
        # interpreter lock (pickling a tick's message) would make the bus thread wait behind the machine's load.
        _raise_thread_priority()
        while True:
            message = self.out.get()
            if message is None:
                return
            trace = tick_trace.TRACE
            if trace is not None:
                trace.mark("send", type(message).__name__.lower())
            try:
                self.conn.send(message)
                if trace is not None:
                    trace.mark("sent")
            except (OSError, ValueError):
                return  # the app is gone; the receiver sees it too and stops the loop
            except Exception as exc:  # noqa: BLE001 - a value that does not pickle: say so instead of hanging
                log.exception("loop process message %s not sent", type(message).__name__)
                if isinstance(message, messages.Result):
                    self.conn.send(messages.Result(message.request_id, error=messages.ErrorPayload.of(
                        TypeError(f"the result could not be sent back: {exc}"), "robot")))


def main(argv: Sequence[str] | None = None) -> int:
    conn, heartbeat = child_setup(argv, "python -m devices.loop_process",
                                  "The robot control loop's process (started by the app).",
                                  "a file shared with the app: the loop's heartbeat", "loop process")
    tick_trace.enable_from_env()  # a diagnosis of late ticks, when asked for (bench_servo_bus --trace)
    return _Child(conn, heartbeat).run()


if __name__ == "__main__":
    sys.exit(main())
