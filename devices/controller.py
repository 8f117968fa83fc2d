"""The robot's control loop: one thread owns the servo bus and ticks at ``robot.control_rate_hz``.

Every tick, on a deadline schedule (one slot per period; the thread sleeps until the next slot)::

    ONE GroupSyncRead → on_state(ChainState)           (read first, so a fresh alert bit blocks the write)
    motion goal → joint-limit clamp → max-speed limit (max_joint_speed_rad_s × period) → ONE GroupSyncWrite
    a chunk of the health poll, if the time left before the next slot allows it

Timing: a tick that overruns into the next slot is followed at once by the next, late (``late_ticks`` counts ticks
starting more than ``LATE_FRACTION`` of a period after their slot); slots that pass entirely without a tick are
skipped, not caught up in a burst, and counted in ``missed_ticks``. Periods (start to start) are kept for the p50/
p99/max figures. The loop lowers the GIL switch interval to ``GIL_SWITCH_INTERVAL_S`` (see
:func:`_lower_switch_interval`), and the port sleeps through each reply's expected wire time instead of polling
(``devices.servo_chain``), so a tick costs two or three wake-ups of this thread.

``ChainState.goal_rad`` carries the goals the servos were tracking when read: the last ones written through the
chain (by a motion, STOP, or a command run through ``submit``), ``None`` after a torque toggle or reboot. A motion's
first goal is speed-limited from the present pose read in that tick, never from an earlier motion's last goal, and
so is a resumed motion's if the goals were moved behind it meanwhile (torque toggled, joints posed by hand).
Health (hardware error, torque, LED; voltage and temperature on every 5th poll) is polled at
``robot.status_rate_hz``, in chunks of servos that fit the slack after the tick's sync cycle (a poll overdue by
``HEALTH_OVERDUE_S`` reads one servo per tick regardless), only in ticks whose feedback read was answered, each
read given up at the next slot when its replies are late and made again later; ``on_health`` gets the whole poll
once complete. It is read at once, all servos, when a status packet carries the alert bit. A hardware error stops
the motion before anything else is sent and reports :class:`ServoHardwareError` naming the servo; nothing is written
until the servo is rebooted. If feedback goes stale (consecutive failed reads over ``WATCHDOG_S`` of polling — time
the loop itself was held off the CPU does not count), the motion stops; ``on_error`` names the servo that stopped
answering when other servos' bytes still came, and when not a byte came it waits up to ``SILENCE_VERDICT_WAIT_S``
for the replies given up on: arriving late and together they were held by this computer (:class:`RepliesHeldError`,
with the hold), else the servo is named. A pulled cable reports :class:`LinkLostError` and the loop tries to reopen
the port every ``RECONNECT_INTERVAL_S``.

With no motion running the loop still reads the state every tick and sends nothing. ``run_motion`` returns a Future
resolved when the motion finishes or stops (or failed with the error that stopped it). ``emergency_stop`` freezes
the goals at the present position on the next tick (torque stays on). Anything else that needs the bus (scan,
torque, LED, reboot, a teach capture) goes through :meth:`RobotController.submit`, which runs it on the bus thread
between ticks (ticks wait while it runs) and returns a :class:`concurrent.futures.Future`.

Threads: the public methods may be called from any thread. The callbacks ``on_state``, ``on_health``, ``on_event``
(a human-readable ``str``) and ``on_error`` (an exception whose message names the servo and the recovery) are
called from the controller thread; keep them short (queue to Qt, etc.). The same exception object goes to
``on_error`` and to the failed motion's Future.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import gc
import logging
import math
import os
import queue
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Protocol, TypeVar

import numpy as np

from devices import control_table as ct
from devices import tick_trace
from devices.config import RobotConfig
from devices.errors import (
    BusBusyError,
    BusQuietError,
    CorruptPacketError,
    DeadlinePassedError,
    DeviceError,
    JointLimitError,
    LinkLostError,
    NoReplyError,
    PortOpenError,
    RepliesHeldError,
    ServoHardwareError,
    ServoLostError,
)
from devices.factory import is_sim
from devices.realtime import (  # noqa: F401 - GIL_SWITCH_INTERVAL_S, BUS_THREAD_RT_PRIORITY: part of this module's face
    BUS_THREAD_RT_PRIORITY,
    GIL_SWITCH_INTERVAL_S,
    _lower_switch_interval,
    _raise_thread_priority,
    _switched_off,
)
from devices.servo_chain import ChainState, ServoChain, ServoHealth, ServoInfo

log = logging.getLogger(__name__)

T = TypeVar("T")

WATCHDOG_S = 0.2
WATCHDOG_MIN_FAILED_READS = 2
RECONNECT_INTERVAL_S = 0.5
PERIOD_HISTORY = 4096
TIMING_WINDOW_S = 5.0
SUPPLY_EVERY_N_POLLS = 5  # voltage and temperature change slowly: read them on every 5th health poll
LATE_FRACTION = 0.25  # a tick starting this fraction of a period after its slot counts as late
HEALTH_MARGIN_S = 0.003  # a health read is started only if it should end this long before the next deadline
HEALTH_DEADLINE_MARGIN_S = 0.0005  # a health read in the slack is given up this long before the next slot
# The feedback read is given up this long (plus the goals' sync write on the wire) before the next slot when its
# replies are late, so the tick still writes its goal and the next tick starts on time (see _read_feedback).
FEEDBACK_DEADLINE_MARGIN_S = 0.002
HEALTH_OVERDUE_S = 1.0  # a poll this late reads one servo per tick even without slack, so health never stalls
# An overdue poll given up this many times at the next slot (replies late every time) is dropped, as a failed poll
# is: the next one falls due on schedule. About a second of ticks at 50 Hz: a poll is never retried forever.
HEALTH_MAX_GIVE_UPS = 50
# After the watchdog has stopped a motion on a bus that sent no byte at all, how long the loop waits for the replies
# it gave up on before it names a servo silent: bytes that then arrive (late, together) show the servos answered and
# this computer held them. Rests on the longest hold seen (2.3 s, the kernel's tty worker at load 10 on 2 cores).
SILENCE_VERDICT_WAIT_S = 3.0
TIMING_WARN_FRACTION = 0.05

LIMIT_TOLERANCE_RAD = ct.RAD_PER_TICK  # one tick of slack: a goal on its limit may round just past it
# A servo tracking its goals lags by a few hundredths of a radian (goals move at most max_joint_speed_rad_s); one that
# rebooted, lost power or was forced away is far off (1.05 rad after a power cycle in the lab's fault runs).
TRACKING_ERROR_BOUND_RAD = 0.5
SPEED_TOLERANCE = 1.001  # plans are built at exactly the speed limit: allow rounding

class MotionEnd(StrEnum):
    """How a motion's Future resolves (equal to its plain string: ``MotionEnd.FINISHED == "finished"``)."""

    FINISHED = "finished"
    STOPPED = "stopped"


MOTION_FINISHED = MotionEnd.FINISHED
MOTION_STOPPED = MotionEnd.STOPPED


CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"  # Linux PM QoS: the largest wake-up latency the CPUs may take (µs)


class _WakeupLatencyHold:
    """Ask Linux to keep every CPU's idle state shallow (wake-up latency 0 µs) while the control loop needs its beat:
    on a real port for as long as the bus thread runs, on ``sim`` while a motion plays.

    Why: a bus thread that sleeps between ticks lets its CPU go idle; waking from a deep idle state (or, in a virtual
    machine, getting the halted virtual CPU back from the host) can take milliseconds. Measured on the 2-core
    development VM (KVM, haltpoll idle driver), the loop in its own process on the pty emulator, 10 minutes at 50 Hz
    with the app on every tab: 1415 missed / 6702 late ticks and jitter p99 9.6 ms without this request (652 / 3352 /
    7.0 ms in a second run), against the figures in the README with it; on the simulated lab in the app's process at
    100 Hz, 2 minutes: jitter p99 1.47-2.19 ms (3.4 ms traced) without it, 0.40-1.53 ms in 15 of 16 runs with it.
    It is what cyclictest does, and needs the same privilege as real-time priority (root, or write access to the
    device); an idle CPU then polls instead of sleeping (more power), so on ``sim`` it is held only while a motion
    plays (the simulated lab runs whenever the app is open), and ``SENSNAKE_CPU_LATENCY=0`` or ``SENSNAKE_REALTIME=0``
    turns it off. The request lasts while the file is open. Used by the bus thread only."""

    def __init__(self, port: str, simulated: bool = False) -> None:
        self.only_while_moving = simulated or is_sim(port)
        self._fd: int | None = None
        self._refused: str | None = None  # why it cannot be held (asked once: a failed open is not retried)
        for switch in ("SENSNAKE_REALTIME", "SENSNAKE_CPU_LATENCY"):
            if self._refused is None and _switched_off(switch):
                self._refused = f"CPU idle states not held ({switch}=0)"
        if self._refused is None and not sys.platform.startswith("linux"):
            self._refused = ""

    @property
    def held(self) -> bool:
        return self._fd is not None

    def start(self) -> str:
        """At the bus thread's start; returns what was obtained, in words ("" when there is nothing to say)."""
        if self.only_while_moving:
            if self._refused is not None:
                return ""
            # Say now whether it will be obtained: the device is opened once to see, then let go.
            try:
                os.close(os.open(CPU_LATENCY_DEVICE, os.O_WRONLY))
            except OSError as exc:
                self._refused = f"CPU idle states not held (cannot open {CPU_LATENCY_DEVICE}: {exc.strerror})"
                return self._refused
            return (f"CPU idle states to be held shallow while a motion plays (write access to {CPU_LATENCY_DEVICE} "
                    "checked)")
        return self._hold()

    def follow(self, moving: bool) -> None:
        """After each tick on ``sim``: hold while a motion plays, let go when it ends (a no-op on a real port)."""
        if not self.only_while_moving or moving == self.held or self._refused is not None:
            return
        if moving:
            reason = self._hold()
            if self._fd is None:
                log.info("robot bus thread: %s", reason)
        else:
            self.release()

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def _hold(self) -> str:
        if self._refused is not None:
            return self._refused
        try:
            fd = os.open(CPU_LATENCY_DEVICE, os.O_WRONLY)
        except OSError as exc:
            self._refused = f"CPU idle states not held (cannot open {CPU_LATENCY_DEVICE}: {exc.strerror})"
            return self._refused
        try:
            os.write(fd, struct.pack("i", 0))
        except OSError as exc:
            os.close(fd)
            self._refused = f"CPU idle states not held ({CPU_LATENCY_DEVICE}: {exc.strerror})"
            return self._refused
        self._fd = fd
        return "CPU idle states held shallow"


class _LongLivedObjects:
    """``gc.freeze()`` while any bus thread runs, ``gc.unfreeze()`` when the last one stops.

    The cyclic garbage collector runs in whichever thread allocates and holds the interpreter throughout: in the
    running app (tens of thousands of Qt, pyqtgraph and model objects) a full collection took 190-350 ms, and the
    bus thread waited that long for its tick (measured with gc.callbacks in bench_servo_bus (d)). Objects alive when
    the loop starts (the app, its windows, loaded models) live as long as the loop, so later collections can skip
    them: frozen, the full collections took ≤ 40 ms. Reference counting still frees non-cyclic garbage at once;
    only cycles that were alive at the start and die while the loop runs wait for the unfreeze."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0

    def acquire(self) -> None:
        with self._lock:
            self._users += 1
            gc.freeze()  # cheap (moves the generations' lists); again on every start: the newest objects too

    def refreeze(self) -> None:
        """A motion starts: what is alive now (tabs built since the loop started, the motion's plan) is long-lived
        too."""
        with self._lock:
            if self._users:
                gc.freeze()

    def release(self) -> None:
        with self._lock:
            self._users -= 1
            if self._users == 0:
                gc.unfreeze()


_long_lived = _LongLivedObjects()


def joint_limit_error(robot: RobotConfig, angles_rad: np.ndarray, what: str) -> JointLimitError | None:
    """The one joint-limit check of every goal (a shape before play, a plan's targets, each tick's goal): the first
    joint beyond its limit (more than ``LIMIT_TOLERANCE_RAD``) as an error naming joint, value and limit, else None.
    Pure; any thread."""
    angles = np.asarray(angles_rad, dtype=float)
    lo, hi = np.asarray(robot.joint_min_rad, dtype=float), np.asarray(robot.joint_max_rad, dtype=float)
    bad = np.flatnonzero(~np.isfinite(angles) | (angles < lo - LIMIT_TOLERANCE_RAD) | (angles > hi + LIMIT_TOLERANCE_RAD))
    if not bad.size:
        return None
    j = int(bad[0])
    limit = hi[j] if angles[j] > hi[j] else lo[j]
    return JointLimitError(f"{what}: joint {robot.joint_ids[j]} (index {j}) = {angles[j]:.3f} rad is beyond its limit "
                           f"{limit:+.3f} rad (robot.joint_min_rad/joint_max_rad): nothing was sent")


class MotionSource(Protocol):
    """Where the robot should be: called once per tick on the controller thread."""

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        """Goal angles (rad, joint order) at ``t_s`` seconds since the motion started; ``None`` when done."""


class HoldPose:
    """Hold the given joint angles (rad), forever or for ``duration_s``."""

    def __init__(self, angles_rad: Sequence[float] | np.ndarray, duration_s: float | None = None) -> None:
        self.angles_rad = np.array(angles_rad, dtype=float)
        self.duration_s = duration_s

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        if self.duration_s is not None and t_s > self.duration_s:
            return None
        return self.angles_rad.copy()


@dataclass(frozen=True)
class ControllerStats:
    """Loop timing and bus counters since start (periods in seconds, between consecutive tick starts)."""

    ticks: int
    missed_ticks: int
    period_p50_s: float
    period_p99_s: float
    period_max_s: float
    jitter_p50_s: float  # |period − nominal period|
    jitter_p99_s: float
    sync_writes: int
    failed_reads: int
    late_ticks: int = 0  # ticks that started more than LATE_FRACTION of a period after their slot
    # Slots skipped while a command held the bus on purpose (a scan, a reboot, a link check: submit(holds_bus=True));
    # counted apart from missed_ticks, kept out of the periods and of the timing warning: not the control rate's fault
    held_ticks: int = 0
    # Feedback reads given up at the tick's deadline because the replies were late (the tick then kept its slot and
    # used the last state read); also counted in failed_reads
    late_reads: int = 0
    # Health reads given up at the next slot (replies late), read again in a later tick
    health_reads_given_up: int = 0


@dataclass
class _SilenceVerdict:
    """The watchdog fired on a bus that sent no byte at all: a silent bus or replies held on this computer. The
    motion is stopped (no goals); its Future and ``on_error`` get the cause once it is known."""

    servo_id: int  # the servo named if the bus stays quiet
    fired_s: float  # time.monotonic() when the watchdog fired
    quiet_since_s: float  # when the first unanswered read was sent
    polls: int  # reads unanswered when it fired
    motion: _Motion | None  # the motion it stopped (its Future still open)
    late_found_s: float  # the chain's late_bytes_found_s when it fired, then at the last find looked at
    answered_s: float | None = None  # a read answered since (the next instruction shows whether late bytes came)
    # The verdict given after SILENCE_VERDICT_WAIT_S with not a byte come (BusQuietError): the watch goes on, so
    # replies that arrive later, together, still correct it (RepliesHeldError), until the bus answers again.
    given: DeviceError | None = None
    stopped: str = ""  # what the verdict given said of the motion ("motion stopped" / "no motion was running")


@dataclass
class _Motion:
    source: MotionSource
    name: str
    future: concurrent.futures.Future
    started_s: float
    paused_at_s: float | None = None
    paused_total_s: float = 0.0
    has_written: bool = False  # this motion has sent goals (its speed limit then runs from the last of them)

    def t_s(self, now_s: float) -> float:
        end = self.paused_at_s if self.paused_at_s is not None else now_s
        return end - self.started_s - self.paused_total_s


class RobotController:
    """The control loop around a :class:`ServoChain`; see the module docstring."""

    def __init__(self, chain: ServoChain, robot: RobotConfig, on_state: Callable[[ChainState], None] | None = None,
                 on_health: Callable[[list[ServoHealth]], None] | None = None,
                 on_event: Callable[[str], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None,
                 on_tick: Callable[[], None] | None = None,
                 on_command: Callable[[float | None], None] | None = None,
                 on_motion_halted: Callable[[str], None] | None = None, *, simulated: bool = False) -> None:
        """``simulated``: the port is a simulated robot's even if not named ``sim`` (the simulated lab's own
        process serves it on a pty): CPU idle states are then held shallow only while a motion plays.
        ``on_tick()`` (optional) is called on the bus thread at the end of every tick, after that tick's
        ``on_state``: the control loop's heartbeat (``devices.loop_process`` sends the tick's states from it).
        ``on_command(started_s)`` (optional) is called on the bus thread with ``time.monotonic()`` just before a
        command (``submit``, a motion's start) runs between ticks, and with ``None`` after it: ticks legitimately
        wait for it (``devices.loop_process`` tells a long command from a hung loop by it).
        ``on_motion_halted(name)`` (optional) is called on the bus thread when the watchdog has stopped the motion
        ``name`` on a bus that sent no byte and its cause is not known yet (the motion's Future fails later, with the
        cause): from then on no goal is sent, so the GUI shows the motion stopped, not running, while the cause is
        told."""
        self.chain = chain
        self.robot = robot
        self.period_s = 1.0 / robot.control_rate_hz
        self.health_period_s = 1.0 / robot.status_rate_hz
        self._on_state = on_state
        self._on_health = on_health
        self._on_event = on_event
        self._on_error = on_error
        self._on_tick = on_tick
        self._on_command = on_command
        self._on_motion_halted = on_motion_halted
        self._thread_started = threading.Event()  # set once the bus thread has its scheduling (see wait_started)
        # (command, its Future or None): run on the bus thread between ticks; cancelled on close.
        self._commands: queue.SimpleQueue[tuple[Callable[[], None], concurrent.futures.Future | None]] = \
            queue.SimpleQueue()
        self._stop = threading.Event()
        self._estop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        # Bus-thread state.
        self._motion: _Motion | None = None
        self._wakeup_latency = _WakeupLatencyHold(robot.port, simulated)  # held from the bus thread (see _run)
        # Play commands wait here from the start of a tick to just after its read (bus thread only): they start
        # from the pose just read instead of reading it again, and send their first goal in that tick.
        self._plays_after_read: list[tuple[Callable[[bool], None], concurrent.futures.Future]] = []
        self._last_state: ChainState | None = None
        self._connected = False
        self._last_good_read_s = 0.0
        self._consecutive_failed_reads = 0
        self._silent_polled_s = 0.0  # time polled without a valid reply in the current run of failed reads (s)
        self._last_failed_read_s = 0.0
        self._stale_reported = False
        # The next feedback read waits its whole reply timeout (no deadline): set when reads given up at the tick's
        # deadline add up to the watchdog's silence, so a servo is named silent only after a read that waited for it.
        self._confirm_silence = False
        self._feedback_given_up = False  # this tick's feedback read was given up at its deadline
        self._unanswered_since_s: float | None = None  # when the first read of the current run of failed reads was sent
        self._failed_reads_got_bytes = False  # a failed read that waited its timeout received bytes (this run)
        self._verdict: _SilenceVerdict | None = None  # the watchdog's cause, while it is not known yet
        self._servos_in_error: dict[int, tuple[str, ...]] = {}
        # Servos whose status packets carried the alert bit, their error not named yet: the health read that names
        # it is given up at the next slot when its replies are late and made again in the next answered tick.
        self._alerts_to_name: list[int] = []
        self._alert_give_ups = 0  # such reads given up in a row
        self._torque_lost: set[int] = set()  # servos reported for dropping their torque (until it is on again)
        self._next_health_s = 0.0
        self._health_polls = 0
        self._health_due_s = 0.0  # when the poll in progress fell due
        self._health_pending: list[int] = []  # servos the poll in progress has still to read
        self._health_supply = False  # the poll in progress reads voltage and temperature too
        self._health_results: dict[int, ServoHealth] = {}
        self._health_overhead_s = 0.0  # learned time a health sync read takes beyond its bus time (s)
        self._health_give_ups = 0  # reads of the poll in progress given up at the next slot
        self._next_reconnect_s = 0.0
        self._timing_window_start_s: float | None = None
        self._timing_window_ticks = 0
        self._timing_window_missed = 0
        # Statistics (read from any thread under _lock).
        self._periods = np.zeros(PERIOD_HISTORY)
        self._n_periods = 0
        self._ticks = 0
        self._missed = 0
        self._held = 0  # slots skipped while a command held the bus on purpose (ControllerStats.held_ticks)
        self._holding_bus = False  # set by such a command during the tick that runs it
        self._late = 0
        self._writes = 0
        self._failed_reads = 0
        self._late_reads = 0
        self._health_reads_given_up = 0  # health reads in the slack given up at the next slot (replies late)
        self._latest_state: ChainState | None = None
        self.scheduling = "not started"  # the bus thread's scheduling, in words (set when it starts)

    # -- lifecycle (any thread) ------------------------------------------------------------------------------------
    def start(self) -> None:
        """Open the port (raises :class:`PortOpenError` now if it cannot) and start the bus thread."""
        if self._thread is not None:
            raise RuntimeError("the robot controller is already running")
        if not self.chain.is_open:
            self.chain.open()
        self._connected = True
        self._last_good_read_s = time.monotonic()  # the watchdog counts from now, not from the epoch
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"RobotController[{self.chain.port_name}]",
                                        daemon=True)
        _long_lived.acquire()
        self._thread.start()

    def wait_started(self, timeout_s: float) -> bool:
        """Wait until the bus thread runs and ``scheduling`` says what it got; False if not within ``timeout_s``."""
        return self._thread_started.wait(timeout_s)

    def close(self) -> None:
        """Stop the thread (ending any motion as "stopped") and close the port. Idempotent."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            _long_lived.release()
        if thread is not None and thread is not threading.current_thread():
            thread.join()
        self._drain_commands(cancel=True)
        plays, self._plays_after_read = self._plays_after_read, []
        for _, future in plays:
            future.cancel()
        if self._verdict is not None:
            self._settle_silence(time.monotonic(), held=False, closing=True)
        if self._motion is not None:
            self._end_motion(MOTION_STOPPED)
        self.chain.close()
        self._connected = False

    def __enter__(self) -> RobotController:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- properties (any thread) -----------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def motion_name(self) -> str | None:
        motion = self._motion
        return motion.name if motion is not None else None

    @property
    def motion_source(self) -> MotionSource | None:
        """The running motion's source (its ``progress`` is what the GUI shows), or None."""
        motion = self._motion
        return motion.source if motion is not None else None

    @property
    def paused(self) -> bool:
        motion = self._motion
        return motion is not None and motion.paused_at_s is not None

    @property
    def latest_state(self) -> ChainState | None:
        with self._lock:
            return self._latest_state

    def stats(self) -> ControllerStats:
        with self._lock:
            n = min(self._n_periods, PERIOD_HISTORY)
            periods = self._periods[:n].copy()
            ticks, missed, writes, failed = self._ticks, self._missed, self._writes, self._failed_reads
            late, held, late_reads = self._late, self._held, self._late_reads
            health_given_up = self._health_reads_given_up
        if n == 0:
            nan = math.nan
            return ControllerStats(ticks, missed, nan, nan, nan, nan, nan, writes, failed, late, held, late_reads,
                                   health_given_up)
        p50, p99 = np.percentile(periods, [50, 99])
        j50, j99 = np.percentile(np.abs(periods - self.period_s), [50, 99])
        return ControllerStats(ticks, missed, float(p50), float(p99), float(periods.max()), float(j50), float(j99),
                               writes, failed, late, held, late_reads, health_given_up)

    def recent_periods_s(self, n: int) -> np.ndarray:
        """The last ``n`` tick periods (s, start to start, oldest first; at most the history kept). Any thread."""
        with self._lock:
            total = self._n_periods
            n = max(0, min(n, total, PERIOD_HISTORY))
            idx = (np.arange(total - n, total) % PERIOD_HISTORY)
            return self._periods[idx].copy()

    # -- commands (any thread) -------------------------------------------------------------------------------------
    def run_motion(self, source: MotionSource, name: str) -> concurrent.futures.Future[str]:
        """Start ``source`` on the next tick (replacing any running motion, which ends "stopped").

        Returns a Future resolved with ``"finished"`` or ``"stopped"``, or failed with the error that stopped it.
        """
        future: concurrent.futures.Future[str] = concurrent.futures.Future()
        _long_lived.refreeze()
        self._commands.put((lambda: self._begin_motion(source, name, future), future))
        return future

    def play(self, source: MotionSource, name: str, *, hold_first: bool = True) -> concurrent.futures.Future[str]:
        """Start ``source`` in ONE command on the bus thread (what ``sensnake play`` and the Gait tab run).

        In that command: read the present pose; with ``hold_first`` torque on holding it (goals = present first,
        so limp joints do not jump); let the source plan from it and check the plan -- every target within the
        joint limits, no move faster than ``max_joint_speed_rad_s`` -- before any goal is written; then start the
        motion (replacing any running one). A refusal fails the Future with :class:`JointLimitError` naming the
        joint, its value and the limit. Otherwise as :meth:`run_motion`.
        """
        future: concurrent.futures.Future[str] = concurrent.futures.Future()
        _long_lived.refreeze()
        self._commands.put((lambda: self._plays_after_read.append(
            (lambda fresh: self._begin_play(source, name, future, hold_first, fresh), future)), future))
        return future

    def pause(self) -> None:
        self._commands.put((self._pause, None))

    def resume(self) -> None:
        self._commands.put((self._resume, None))

    def stop_motion(self) -> None:
        """End the motion; the servos keep the last goal sent."""
        self._commands.put((lambda: self._end_motion(MOTION_STOPPED), None))

    def emergency_stop(self) -> None:
        """Within one tick: motion ended and goals frozen at the present positions; torque stays on."""
        self._estop.set()

    def submit(self, fn: Callable[[ServoChain], T], holds_bus: bool = False) -> concurrent.futures.Future[T]:
        """Run ``fn(chain)`` on the bus thread between ticks; the Future carries its result or exception.
        ``holds_bus``: ``fn`` holds the bus for whole periods on purpose (a scan, a reboot, a link check, a read of
        every setting): the slots it skips are counted in ``held_ticks``, not ``missed_ticks``, and never blamed on
        the control rate."""
        future: concurrent.futures.Future[T] = concurrent.futures.Future()

        def call() -> None:
            if not future.set_running_or_notify_cancel():
                return
            if holds_bus:
                self._holding_bus = True
            try:
                future.set_result(fn(self.chain))
            except Exception as exc:  # noqa: BLE001 - thread boundary: handed to the caller through the Future
                future.set_exception(exc)

        self._commands.put((call, future))
        return future

    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> concurrent.futures.Future[None]:
        return self.submit(lambda chain: chain.set_torque(enabled, ids))

    def set_led(self, servo_id: int, on: bool) -> concurrent.futures.Future[None]:
        return self.submit(lambda chain: chain.set_led(servo_id, on))

    def reboot(self, servo_id: int) -> concurrent.futures.Future[None]:
        def reboot(chain: ServoChain) -> None:
            chain.reboot(servo_id)
            self._next_health_s = 0.0  # re-read health now so the cleared error shows at once
            self._health_pending = []
        return self.submit(reboot, holds_bus=True)  # a reboot waits for the servo to come back

    def scan(self, ids: Iterable[int] = range(0, 253), bauds: Sequence[int] | None = None
             ) -> concurrent.futures.Future[list[ServoInfo]]:
        """Scan on the bus thread between ticks; refused (:class:`BusBusyError`) while a motion plays: a scan holds
        the bus for whole periods (a broadcast ping waits its full ~0.8 s window, a silent ID ~35 ms), which no tick
        slack can carry, and a motion starved of ticks is a motion that stalls mid-gait."""
        def scan(chain: ServoChain) -> list[ServoInfo]:
            motion = self._motion
            if motion is not None:
                raise BusBusyError(
                    f"scan refused while motion {motion.name!r} plays: a scan holds the bus for "
                    f"~{chain.scan_time_s(ids, bauds):.1f} s ({chain.scan_time_s(ids, bauds) / self.period_s:.0f} "
                    f"control ticks at {self.robot.control_rate_hz:g} Hz); stop the motion, then scan")
            return chain.scan(ids, bauds)
        return self.submit(scan, holds_bus=True)

    # -- the bus thread ----------------------------------------------------------------------------------------------
    def _run(self) -> None:
        _lower_switch_interval()
        self.scheduling = _raise_thread_priority()
        latency = self._wakeup_latency.start()
        if latency:
            self.scheduling += f"; {latency}"
        self._thread_started.set()
        log.info("robot bus thread: %s", self.scheduling)
        try:
            self._loop()
        finally:
            self._wakeup_latency.release()  # the request ends with the loop

    def _loop(self) -> None:
        deadline = time.monotonic()  # the slot of the tick about to run
        last_start: float | None = None
        held = False  # the last tick ran a command that held the bus on purpose
        while not self._stop.is_set():
            start = time.monotonic()
            late = start - deadline > LATE_FRACTION * self.period_s
            # The period that carried a deliberate hold says nothing of the loop's timing: not kept.
            self._record_period(start, None if held else last_start, late=late and not held)
            trace = tick_trace.TRACE  # None unless SENSNAKE_TICK_TRACE (diagnosis of late ticks)
            if trace is not None:  # a late tick, or one after skipped slots (its period is long, it is not late)
                long_period = last_start is not None and start - last_start > (1 + LATE_FRACTION) * self.period_s
                trace.tick_start(start, deadline, self.period_s, late or long_period)
            last_start = start
            try:
                self._tick(start, deadline + self.period_s)
            except Exception as exc:  # noqa: BLE001 - thread boundary: a bug must not kill the bus thread silently
                log.exception("robot controller tick failed")
                self._stop_motion_with(exc)
                self._emit(self._on_error, exc)
            self._wakeup_latency.follow(self._motion is not None)
            held, self._holding_bus = self._holding_bus, False
            deadline += self.period_s
            now = time.monotonic()
            missed = 0
            if now >= deadline + self.period_s:
                # Whole slots went by without a tick: skip them (no burst of catch-up ticks) and count them, apart
                # when a command held the bus on purpose.
                missed = int((now - deadline) / self.period_s)
                deadline += missed * self.period_s
                with self._lock:
                    if held:
                        self._held += missed
                    else:
                        self._missed += missed
            # A tick that overran into the next slot runs at once, late (counted in late_ticks and the periods).
            self._watch_timing(now, 0 if held else missed)
            if self._on_tick is not None:
                try:
                    self._on_tick()
                except Exception:  # noqa: BLE001 - thread boundary: a broken subscriber must not stop the loop
                    log.exception("robot controller tick callback failed")
            if trace is not None:
                trace.mark("wait", deadline)
                trace.tick_end()
            self._stop.wait(max(0.0, deadline - time.monotonic()))
            if trace is not None:
                trace.mark("woke")

    def _watch_timing(self, now: float, missed: int) -> None:
        """Warn (on_event, at most once per window) when the bus cannot keep the control rate."""
        if self._timing_window_start_s is None:
            self._timing_window_start_s = now
        self._timing_window_ticks += 1
        self._timing_window_missed += missed
        if now - self._timing_window_start_s < TIMING_WINDOW_S:
            return
        ticks, lost = self._timing_window_ticks, self._timing_window_missed
        self._timing_window_start_s, self._timing_window_ticks, self._timing_window_missed = now, 0, 0
        if lost > TIMING_WARN_FRACTION * (ticks + lost):
            self._emit(self._on_event, (
                f"timing: {lost} of {ticks + lost} ticks missed at {self.robot.control_rate_hz:g} Hz in the last "
                f"{TIMING_WINDOW_S:g} s: see the Hardware tab's Timing box (Return Delay Time 0, USB latency "
                "timer 1 ms); if those are fine, lower robot.control_rate_hz in the lab config"))

    def _record_period(self, start: float, last_start: float | None, late: bool) -> None:
        with self._lock:
            self._ticks += 1
            self._late += late
            if last_start is not None:
                self._periods[self._n_periods % PERIOD_HISTORY] = start - last_start
                self._n_periods += 1

    def _tick(self, now: float, next_deadline: float) -> None:
        """One control tick; ``next_deadline`` (monotonic s) is when the next one is due: health reads use only
        the time left before it."""
        if not self._connected:
            self._try_reconnect(now)
            if not self._connected:
                self._drain_commands(cancel=False)
                self._start_plays(fresh=False)  # each refuses: not connected
                return
        self._drain_commands(cancel=False)
        if not self._connected:
            self._start_plays(fresh=False)
            return
        trace = tick_trace.TRACE
        try:
            # Read first: a hardware error seen in this read stops the motion before anything is written.
            fresh = self._read_feedback(now, next_deadline)
            if trace is not None:
                trace.mark("read<")
            self._start_plays(fresh)
            if self._estop.is_set():
                self._estop.clear()
                self._freeze_at_present()
            elif (self._motion is not None and self._motion.paused_at_s is None
                  and not self.chain.state_read_in_flight):  # (an instruction would discard that read's replies)
                self._send_motion_goal(now)
            if trace is not None:
                trace.mark("goal<")
            # Health is read only in a tick whose feedback read was answered: after one given up (replies late: the
            # kernel's tty worker, a busy PC) it would wait on the same late bytes (measured: the largest remaining
            # cause of missed ticks at load 10-14 on 2 cores), after one that waited its timeout the slot is gone,
            # and while the watchdog's cause is being told its late replies would be taken for the held ones.
            if fresh and self._verdict is None and not self._alerts_to_name:
                self._health_in_slack(now, next_deadline)
            if trace is not None:
                trace.mark("health<")
        except LinkLostError as exc:
            self._link_lost(exc)

    def _send_motion_goal(self, now: float) -> None:
        motion = self._motion
        state = self._last_state
        if motion is None or state is None:
            return
        try:
            goal = motion.source.goal_at(motion.t_s(now), state.position_rad.copy())
        except Exception as exc:  # noqa: BLE001 - a faulty motion source ends its motion, reported to the caller
            log.exception("motion source %r failed", motion.name)
            self._end_motion(MOTION_STOPPED, exc)
            self._emit(self._on_error, exc)
            return
        if goal is None:
            self._end_motion(MOTION_FINISHED)
            return
        error = joint_limit_error(self.robot, goal, f"motion {motion.name!r}")
        if error is not None:  # refused, never clamped: a clamped goal is a silently different motion
            self._stop_motion_with(error)
            self._emit(self._on_error, error)
            return
        goal = self.chain.clamp_to_limits(goal)  # within LIMIT_TOLERANCE_RAD: rounding only
        # The speed limit runs from the goal this motion sent last. A motion's first goal starts from the present
        # pose (read this tick), as does one after anything that moved the goals behind it (a torque toggle, a hand
        # pose): never from another motion's last goal, or the joints would jump.
        previous = self.chain.last_goal_rad if motion.has_written else None
        if previous is None:
            previous = state.position_rad
        step = self.robot.max_joint_speed_rad_s * self.period_s
        goal = previous + np.clip(goal - previous, -step, step)
        self._write(goal)

    def _freeze_at_present(self) -> None:
        name = self.motion_name
        state = self._last_state
        if state is not None:
            self._write(self.chain.clamp_to_limits(state.position_rad))
            # Whoever learns of the stop (the motion's Future, just below) finds the frozen goals in the latest state,
            # not the goals of the tick's read, a tick before the next read publishes them.
            goal = self.chain.last_goal_rad
            if goal is not None:
                with self._lock:
                    self._latest_state = dataclasses.replace(state, goal_rad=goal, correction_rad=None,
                                                             controller="", controller_gains="")
        if self._motion is not None:
            self._end_motion(MOTION_STOPPED)
        what = f" (motion {name!r} stopped)" if name else ""
        self._emit(self._on_event, f"emergency stop: goals frozen at the present pose, torque stays on{what}")

    def _write(self, goal: np.ndarray) -> None:
        if self._servos_in_error:
            return  # nothing is sent while a servo reports a hardware error
        self.chain.write_goals(goal)
        if self._motion is not None:
            self._motion.has_written = True
        with self._lock:
            self._writes += 1

    def _start_plays(self, fresh: bool) -> None:
        """Bus thread: the play commands of this tick, from the pose just read (``fresh``; else each reads it)."""
        plays, self._plays_after_read = self._plays_after_read, []
        for begin, _ in plays:
            begin(fresh)

    def _read_feedback(self, now: float, next_deadline: float) -> bool:
        """Read the servos' state; True if it was read (False: no valid reply this tick).

        The read is given up shortly before ``next_deadline`` (the next tick's slot) if its replies are late: the
        tick then writes its goal from the last state read and the next tick starts on time, instead of waiting for
        bytes the kernel hands over late (on a busy PC the tty layer's worker, at normal priority, held replies
        20-40 ms; docs/REALTIME.md). Such reads count as polls without an answer; once they add up to the watchdog's
        silence, reads wait their whole reply timeout again (``_confirm_silence``) and a servo is named silent only
        on those, as without deadlines -- but in the slack of the ticks that follow, not inside one: such a read is
        given up at the tick's deadline too, kept in flight (no instruction goes out meanwhile, so no goal is
        written: the servos hold the last) and resumed in the next ticks until its replies are in or its reply
        timeout, counted from its instruction, has passed (docs/decisions/0025)."""
        sent_s = time.monotonic()
        confirm = self._confirm_silence
        deadline = self._feedback_deadline_s(sent_s, next_deadline)
        self._feedback_given_up = False
        try:
            if confirm and self.chain.state_read_in_flight:
                state = self.chain.resume_state_read(raise_on_alert=False, deadline_s=deadline)
            else:
                state = self.chain.read_state(raise_on_alert=False, deadline_s=deadline, keep_in_flight=confirm)
        except (NoReplyError, CorruptPacketError, DeadlinePassedError) as exc:
            if confirm and isinstance(exc, DeadlinePassedError):
                # Within its reply timeout still: waited for in the next tick's slack, not an unanswered poll yet
                # (nor one if it is no longer in flight: an instruction went out since; the next tick reads anew).
                # The tick did go without its feedback: counted as a read given up at its deadline.
                self._feedback_given_up = True
                with self._lock:
                    self._failed_reads += 1
                    self._late_reads += 1
                trace = tick_trace.TRACE
                if trace is not None:
                    trace.mark("read-in-flight", self.chain.state_read_in_flight)
                return False
            given_up = isinstance(exc, DeadlinePassedError)
            self._feedback_given_up = given_up
            if self._unanswered_since_s is None:
                self._unanswered_since_s = sent_s
            if not given_up and self.chain.bytes_since_instruction > 0:
                self._failed_reads_got_bytes = True  # the bus delivers bytes: the servo that failed is silent
            self._consecutive_failed_reads += 1
            with self._lock:
                self._failed_reads += 1
                self._late_reads += given_up
            trace = tick_trace.TRACE
            if given_up and trace is not None:
                trace.mark("read-given-up", round(time.monotonic() - now, 6))
            # Silence is counted over time the bus was actually polled: from the first unanswered poll, each gap
            # between polls counted at most two periods. A loop held off the CPU (a busy machine) polls nobody
            # while it waits; that wait is the loop's stall (reported as such), not the servo's silence.
            failed_at = time.monotonic()
            if self._consecutive_failed_reads == 1:
                self._silent_polled_s = 0.0
            else:
                self._silent_polled_s += min(failed_at - self._last_failed_read_s, 2.0 * self.period_s)
            self._last_failed_read_s = failed_at
            stale_s = failed_at - self._last_good_read_s
            silent = self._consecutive_failed_reads >= WATCHDOG_MIN_FAILED_READS and self._silent_polled_s >= WATCHDOG_S
            if silent and given_up:
                # From now on reads wait their whole reply timeout, and silence is counted afresh over those only:
                # a servo is named on the same evidence as without deadlines (the kernel has held a pty's bytes for
                # over a second on a busy PC; the servos had answered).
                self._confirm_silence = True
                self._consecutive_failed_reads = 0
                self._silent_polled_s = 0.0
                self._failed_reads_got_bytes = False
            elif silent and not self._stale_reported:
                self._stale_reported = True
                sid = getattr(exc, "servo_id", None)
                if sid is None:
                    sid = self.chain.ids[0]
                if self._failed_reads_got_bytes:
                    # Other servos' bytes came in the reads that waited: the bus delivers, this servo does not answer.
                    what = "motion stopped" if self._motion is not None else "no motion was running"
                    error = NoReplyError(sid, f"no valid feedback for {stale_s:.2f} s "
                                              f"({self._consecutive_failed_reads} polls unanswered); {what}")
                    self._stop_motion_with(error)
                    self._emit(self._on_error, error)
                else:
                    self._await_silence_verdict(sid, failed_at)
            self._watch_silence_verdict(failed_at)
            return False
        answered_s = time.monotonic()
        self._last_good_read_s = answered_s
        self._consecutive_failed_reads = 0
        self._confirm_silence = False
        self._stale_reported = False
        self._unanswered_since_s = None
        self._failed_reads_got_bytes = False
        if self._verdict is not None and self._verdict.answered_s is None:
            self._verdict.answered_s = answered_s
        self._watch_silence_verdict(answered_s)
        # The goals the servos were tracking: whoever wrote them (a motion, STOP, a teach hold through submit).
        last_goal = self.chain.last_goal_rad
        if last_goal is not None:
            state = dataclasses.replace(state, goal_rad=last_goal)
            motion = self._motion
            progress = getattr(motion.source, "progress", None) if motion is not None else None
            correction = getattr(progress, "correction_rad", None)
            if correction is not None and len(correction) == len(last_goal):  # a feedback motion's, duck-typed
                state = dataclasses.replace(state, correction_rad=np.asarray(correction, dtype=float),
                                            controller=str(getattr(progress, "controller", "feedback")),
                                            controller_gains=str(getattr(progress, "gains_json", "")))
        self._last_state = state
        with self._lock:
            self._latest_state = state
        if state.alert_ids:
            new = [sid for sid in state.alert_ids if sid not in self._servos_in_error]
            if new:
                # Marking the servos blocks every write at once; the health read (reads only) names the error.
                for sid in new:
                    self._servos_in_error[sid] = ("hardware error",)
                self._alerts_to_name.extend(new)
        if self._alerts_to_name:
            self._poll_alerted(next_deadline)
        self._check_tracking(state)
        self._emit(self._on_state, state)
        return True

    def _await_silence_verdict(self, servo_id: int, now_s: float) -> None:
        """The watchdog fired and not a byte came in the reads that waited their whole timeout: the bus is quiet
        (power, cable) or this computer holds its bytes (measured: the kernel's tty worker held a pty's for 2.3 s at
        load 10 on 2 cores). The motion stops now (no more goals; the servos hold the last); what stopped it is told
        by the replies given up on: arriving later, together, they were held here (:class:`RepliesHeldError` with
        the measured hold), else the servo is named silent after ``SILENCE_VERDICT_WAIT_S``
        (:meth:`_watch_silence_verdict`)."""
        motion, self._motion = self._motion, None
        quiet_since_s = self._unanswered_since_s if self._unanswered_since_s is not None else now_s
        self._verdict = _SilenceVerdict(servo_id, now_s, quiet_since_s, self._consecutive_failed_reads, motion,
                                        self.chain.late_bytes_found_s)
        stopped = f"motion {motion.name!r} stopped" if motion is not None else "no motion was running"
        if motion is not None:
            self._emit(self._on_motion_halted, motion.name)
        self._emit(self._on_event, (
            f"no reply byte on the servo bus for {now_s - quiet_since_s:.2f} s ({stopped}): waiting up to "
            f"{SILENCE_VERDICT_WAIT_S:g} s for the replies given up on, to tell replies held on this computer from a "
            "silent bus"))

    def _watch_silence_verdict(self, now_s: float) -> None:
        """Bus thread, after each feedback read while the watchdog's cause is open: the replies to several reads
        found together before an instruction since it fired (more status packets than one read has, not noise)
        mean the servos had answered and this computer held them; a read answered with none found before the next
        instruction, or no byte for ``SILENCE_VERDICT_WAIT_S``, mean the bus was quiet: the servo is named. One
        read's replies found late is no hold of the quiet before: a bus back from a power cut whose replies this
        busy computer hands over after their timeout."""
        verdict = self._verdict
        if verdict is None:
            return
        found_s = self.chain.late_bytes_found_s
        together = found_s > verdict.late_found_s and self.chain.late_replies_found > len(self.chain.ids)
        verdict.late_found_s = found_s
        if together:
            # The replies were in by the time they were found before an instruction, or by a read they answered.
            arrived_s = self.chain.late_bytes_found_s
            if verdict.answered_s is not None:
                arrived_s = min(arrived_s, verdict.answered_s)
            self._settle_silence(now_s, held=True, held_s=arrived_s - verdict.quiet_since_s)
        else:
            answered_again = verdict.answered_s is not None and now_s > verdict.answered_s
            if verdict.given is not None:
                if answered_again:  # the bus is back without the replies: the verdict given stands
                    self._verdict = None
                    self._emit(self._on_event, "the servo bus answers again (the replies given up on never came: "
                                               "the bus was quiet, not held on this computer)")
            elif answered_again or now_s - verdict.fired_s >= SILENCE_VERDICT_WAIT_S:
                self._settle_silence(now_s, held=False)

    def _settle_silence(self, now_s: float, held: bool, held_s: float = math.nan, closing: bool = False) -> None:
        """Name the watchdog's cause: to the stopped motion's Future (if one was stopped) and ``on_error``.

        After ``SILENCE_VERDICT_WAIT_S`` with not a byte come, what is known is said (:class:`BusQuietError`: the
        servos went quiet, or this computer holds the port's bytes) and the watch goes on: replies that arrive
        later, together, correct it (:class:`RepliesHeldError` naming the earlier verdict), a bus that answers again
        without them ends the watch. A hold is never left named only as a silent servo's cable."""
        verdict, self._verdict = self._verdict, None
        if verdict is None:
            return
        stopped = "motion stopped" if verdict.motion is not None else "no motion was running"
        error: DeviceError
        if verdict.given is not None:
            if not held:  # closing, or the link lost: the verdict given stands
                return
            error = RepliesHeldError(held_s, verdict.stopped,
                                     corrects=f'"no reply from servo {verdict.servo_id} nor any other" verdict')
            self._emit(self._on_error, error)
            return
        if held:
            error = RepliesHeldError(held_s, stopped)
        elif verdict.answered_s is not None:
            quiet_s = verdict.answered_s - verdict.quiet_since_s
            error = NoReplyError(verdict.servo_id, f"no valid feedback for {quiet_s:.2f} s, not a byte on the bus "
                                                   f"({verdict.polls} polls unanswered; the bus answers again); "
                                                   f"{stopped}")
        elif closing:
            error = BusQuietError(verdict.servo_id, now_s - verdict.quiet_since_s, verdict.polls,
                                  f"{stopped}; the loop was closed")
        else:
            error = BusQuietError(verdict.servo_id, now_s - verdict.quiet_since_s, verdict.polls, stopped)
            verdict.given, verdict.stopped = error, stopped
            verdict.motion, motion = None, verdict.motion
            self._verdict = verdict  # watched on: see _watch_silence_verdict
            if motion is not None:
                motion.future.set_exception(error)
                self._emit(self._on_event, f"motion {motion.name!r} stopped by an error")
            self._emit(self._on_error, error)
            return
        if verdict.motion is not None:
            verdict.motion.future.set_exception(error)
            self._emit(self._on_event, f"motion {verdict.motion.name!r} stopped by an error")
        self._emit(self._on_error, error)

    def _feedback_deadline_s(self, now_s: float, next_deadline_s: float) -> float:
        """When a feedback read starting at ``now_s`` is given up (monotonic s): in time for the tick to write its
        goals before ``next_deadline_s``, but never sooner than twice the read's own bus time: on a bus whose sync
        cycle nearly fills the period (a rate that only just fits) replies on time would otherwise be given up
        every tick."""
        n = len(self.chain.ids)
        return max(next_deadline_s - FEEDBACK_DEADLINE_MARGIN_S - self.chain.sync_write_time_s(n),
                   now_s + 2.0 * self.chain.sync_read_time_s(n, ct.STATE_BLOCK_SIZE))

    def _check_tracking(self, state: ChainState) -> None:
        """A motion whose servo is far from the goal it was sent (it rebooted and sagged, lost power, was forced
        away) stops at once, naming the servo: every tick, from the state just read."""
        motion = self._motion
        if motion is None or not motion.has_written or state.goal_rad is None:
            return
        error_rad = np.abs(state.position_rad - state.goal_rad)
        j = int(np.argmax(error_rad))
        if error_rad[j] > TRACKING_ERROR_BOUND_RAD:
            error = ServoLostError(self.chain.ids[j], f"is {error_rad[j]:.2f} rad from its goal (more than "
                                                        f"{TRACKING_ERROR_BOUND_RAD:g} rad: did it reboot?)")
            self._stop_motion_with(error)
            self._emit(self._on_error, error)

    def _health_in_slack(self, now: float, next_deadline: float) -> None:
        """Scheduled health polling, spread over ticks: every ``health_period_s`` a poll of all servos falls due; it
        is read in chunks of servos, each only when the chunk's expected time (bus time from the learned reply delay, plus
        a learned overhead per read) fits before ``next_deadline``
        (minus ``HEALTH_MARGIN_S``), so a tick never carries a health read it has no time for. A poll overdue by
        ``HEALTH_OVERDUE_S`` reads one servo per tick regardless. Every read is given up at the next slot if its
        replies are late (an overdue one without slack no sooner than twice its bus time), and read again in a later
        tick (at most ``HEALTH_MAX_GIVE_UPS`` times per poll). ``on_health`` gets the whole poll at its end."""
        if not self._health_pending:
            if now < self._next_health_s:
                return
            self._health_due_s = now
            self._next_health_s = now + self.health_period_s
            self._health_pending = list(self.chain.ids)
            self._health_results = {}
            self._health_supply = self._health_polls % SUPPLY_EVERY_N_POLLS == 0
            self._health_polls += 1
            self._health_give_ups = 0
        start = time.monotonic()
        # Every health read is given up at the next slot if its replies are late (a USB adapter's or the kernel's
        # delay: on a pty, bytes were measured crossing ~40 ms after they were written, and the tty worker has held
        # them for seconds on a busy PC), and read again later: the tick keeps its slot, overdue poll or not.
        deadline = next_deadline - HEALTH_DEADLINE_MARGIN_S
        budget_s = next_deadline - start - HEALTH_MARGIN_S
        n = len(self._health_pending)
        while n > 0 and self._health_read_estimate_s(n) > budget_s:
            n -= 1
        overdue = start - self._health_due_s >= HEALTH_OVERDUE_S
        if n < 1:
            if not overdue:
                return
            # An overdue poll reads one servo even without slack; on a bus whose sync cycle fills the tick that
            # read cannot end before the slot, so, like the feedback read, it is given up no sooner than twice its
            # own bus time: the next tick then starts a little late (~2 bus times of one servo), never a slot later.
            n = 1
            bus_s = self._health_read_estimate_s(1, with_overhead=False)
            deadline = max(deadline, start + 2.0 * bus_s)
        chunk, self._health_pending = self._health_pending[:n], self._health_pending[n:]
        try:
            health = self._read_health(chunk, supply=self._health_supply, deadline_s=deadline)
        except DeadlinePassedError:
            self._health_pending = chunk + self._health_pending
            self._health_give_ups += 1
            with self._lock:
                self._health_reads_given_up += 1
            trace = tick_trace.TRACE
            if trace is not None:
                trace.mark("health-given-up", len(chunk))
            log.debug("health read of servos %s given up at the next slot (late replies); read again later", chunk)
            if self._health_give_ups >= HEALTH_MAX_GIVE_UPS:
                # Dropped as a failed poll is (no servo is blamed for replies that came late): the next falls due
                # on schedule, so a servo that never answers a health read is not retried forever.
                log.debug("health poll dropped after %d reads given up at the next slot", self._health_give_ups)
                self._health_pending = []
            return
        if health is None:
            self._health_pending = []  # a failed poll is not retried servo by servo; the next one is due soon
            return
        # What the bus time does not explain is this machine's cost of a read (wake-ups, GIL, Python): learn it.
        overhead_s = max(0.0, time.monotonic() - start - self._health_read_estimate_s(n, with_overhead=False))
        overhead_s /= 2 if self._health_supply else 1  # per sync read
        self._health_overhead_s = 0.7 * self._health_overhead_s + 0.3 * overhead_s
        for h in health:
            self._health_results[h.servo_id] = h
        self._check_health(health, newly_alerted=())
        if not self._health_pending:
            self._emit(self._on_health, [self._health_results[sid] for sid in self.chain.ids
                                         if sid in self._health_results])

    def _health_read_estimate_s(self, n_servos: int, with_overhead: bool = True) -> float:
        """Expected duration (s) of a health read of ``n_servos`` in the poll in progress. Before the Return Delay
        Times are read, each reply may wait the largest one: a chunk is never fitted into the slack on a guess that
        its replies come at once (they were given up at the slot, over and over, on a bus with the factory delay)."""
        bus_s = self.chain.sync_read_time_s(n_servos, ct.HEALTH_BLOCK_SIZE)
        if self._health_supply:
            bus_s += self.chain.sync_read_time_s(n_servos, ct.SUPPLY_BLOCK_SIZE)
        if not self.chain.return_delays_s:  # not read yet: a reply may wait the largest Return Delay Time
            bus_s += ct.MAX_RETURN_DELAY_S * n_servos * (2 if self._health_supply else 1)
        return bus_s + (self._health_overhead_s * (2 if self._health_supply else 1) if with_overhead else 0.0)

    def _poll_alerted(self, next_deadline: float) -> None:
        """A status packet carried the alert bit: read every servo's health at once to name the error.

        Like the health reads in the slack, the read is given up at the next slot when its replies are late (where
        the bus cycle fills the tick, no sooner than twice its own bus time), counted in ``health_reads_given_up``
        and made again in the next tick whose feedback read is answered: a port whose bytes are held never holds a
        tick here. Meanwhile the servos stay marked in error, so nothing is written. A read that fails, or one given
        up ``HEALTH_MAX_GIVE_UPS`` times in a row, stops the motion naming the servo's (unnamed) hardware error."""
        newly_alerted = list(self._alerts_to_name)
        ids = list(self.chain.ids)
        start = time.monotonic()
        bus_s = self.chain.sync_read_time_s(len(ids), ct.HEALTH_BLOCK_SIZE)
        if not self.chain.return_delays_s:  # not read yet: each reply may wait the largest Return Delay Time
            bus_s += ct.MAX_RETURN_DELAY_S * len(ids)
        deadline = max(next_deadline - HEALTH_DEADLINE_MARGIN_S, start + 2.0 * bus_s)
        try:
            health = self._read_health(ids, supply=False, deadline_s=deadline)
        except DeadlinePassedError:
            self._alert_give_ups += 1
            with self._lock:
                self._health_reads_given_up += 1
            trace = tick_trace.TRACE
            if trace is not None:
                trace.mark("health-given-up", len(ids))
            if self._alert_give_ups < HEALTH_MAX_GIVE_UPS:
                log.debug("alert health read of servos %s given up at the next slot (late replies); read again in "
                          "the next tick", newly_alerted)
                return
            health = None
        self._alerts_to_name = []
        self._alert_give_ups = 0
        if health is None:
            for sid in newly_alerted:
                error = ServoHardwareError(sid, ("hardware error",))
                self._stop_motion_with(error)
                self._emit(self._on_error, error)
            return
        self._check_health(health, newly_alerted)
        self._emit(self._on_health, health)

    def _read_health(self, ids: list[int], supply: bool, deadline_s: float | None = None) -> list[ServoHealth] | None:
        try:
            return self.chain.read_health(ids, supply=supply, deadline_s=deadline_s)
        except (NoReplyError, CorruptPacketError) as exc:
            log.debug("health poll failed: %s", exc)
            return None

    def _check_health(self, health: list[ServoHealth], newly_alerted: Sequence[int]) -> None:
        """Stop the motion on a new hardware error (reported once per servo); note errors that were cleared."""
        reported = set()
        commanded = self.chain.torque_commanded
        for h in health:
            if not h.torque_on and h.servo_id in commanded and not h.hardware_error:
                if h.servo_id not in self._torque_lost:
                    self._torque_lost.add(h.servo_id)
                    lost = ServoLostError(h.servo_id, "dropped its torque (it rebooted or lost power)")
                    self._stop_motion_with(lost)
                    self._emit(self._on_error, lost)
            elif h.torque_on:
                self._torque_lost.discard(h.servo_id)
            if h.hardware_error:
                names = h.error_names or ("hardware error",)
                first_time = h.servo_id in newly_alerted or h.servo_id not in self._servos_in_error
                self._servos_in_error[h.servo_id] = names
                if first_time:
                    error = ServoHardwareError(h.servo_id, names)
                    self._stop_motion_with(error)
                    self._emit(self._on_error, error)
                    reported.add(h.servo_id)
            elif h.servo_id in self._servos_in_error:
                del self._servos_in_error[h.servo_id]
                self._emit(self._on_event, f"servo {h.servo_id} hardware error cleared")
        for sid in newly_alerted:
            if sid not in reported and sid in self._servos_in_error:
                error = ServoHardwareError(sid, self._servos_in_error[sid])
                self._stop_motion_with(error)
                self._emit(self._on_error, error)

    def _link_lost(self, exc: LinkLostError) -> None:
        self._connected = False
        verdict, self._verdict = self._verdict, None
        if verdict is not None and verdict.motion is not None:  # the quiet bus was the port going away
            verdict.motion.future.set_exception(exc)
        self._stop_motion_with(exc)
        self.chain.close()
        self._last_state = None  # (closing the chain forgot its last goals too)
        self._next_reconnect_s = time.monotonic() + RECONNECT_INTERVAL_S
        self._emit(self._on_error, exc)
        self._emit(self._on_event, f"link lost on {self.chain.port_name}; reconnecting")

    def _try_reconnect(self, now: float) -> None:
        if now < self._next_reconnect_s:
            return
        self._next_reconnect_s = now + RECONNECT_INTERVAL_S
        try:
            self.chain.open()
            self.chain.read_state(raise_on_alert=False)
        except (PortOpenError, LinkLostError, NoReplyError, CorruptPacketError, DeviceError) as exc:
            log.debug("reconnect to %s failed: %s", self.chain.port_name, exc)
            self.chain.close()
            return
        self._connected = True
        self._consecutive_failed_reads = 0
        self._unanswered_since_s = None
        self._failed_reads_got_bytes = False
        self._last_good_read_s = time.monotonic()
        self._estop.clear()  # the link loss already ended any motion; there is nothing left to freeze
        self._emit(self._on_event, f"reconnected to {self.chain.port_name}")

    # -- motion bookkeeping (bus thread) -----------------------------------------------------------------------------
    def _begin_motion(self, source: MotionSource, name: str, future: concurrent.futures.Future) -> None:
        if not future.set_running_or_notify_cancel():
            return
        if self._motion is not None:
            self._end_motion(MOTION_STOPPED)
        if self._servos_in_error:
            sid, names = next(iter(self._servos_in_error.items()))
            error = ServoHardwareError(sid, names)
            future.set_exception(error)
            self._emit(self._on_error, error)
            return
        if not self._connected:
            future.set_exception(LinkLostError(f"the servo bus on {self.chain.port_name} is not connected"))
            return
        # Its first goal is speed-limited from the present pose of that tick (see _send_motion_goal).
        self._motion = _Motion(source, name, future, time.monotonic())
        self._emit(self._on_event, f"motion {name!r} started")

    def _begin_play(self, source: MotionSource, name: str, future: concurrent.futures.Future,
                    hold_first: bool, fresh: bool) -> None:
        """Bus thread, right after the tick's read (``fresh``: it succeeded): see :meth:`play`. Nothing is
        written before every check has passed. Starts from the pose just read and turns torque on in two sync
        writes, so the play command fits in the tick's slack: read twice and torque on servo by servo (12
        acknowledged writes) it took ~30 ms at the factory Return Delay Time and cost every play a missed tick."""
        if not future.set_running_or_notify_cancel():
            return
        try:
            if not self._connected:
                raise LinkLostError(f"the servo bus on {self.chain.port_name} is not connected")
            if self._servos_in_error:
                sid, names = next(iter(self._servos_in_error.items()))
                raise ServoHardwareError(sid, names)
            state = self._last_state if fresh else None
            present = (state if state is not None else self.chain.read_state()).position_rad
            error = joint_limit_error(self.robot, present, "cannot hold the present pose")
            if hold_first and error is not None:
                raise error
            self._check_plan(source, name, present)
            if self._motion is not None:
                self._end_motion(MOTION_STOPPED)
            if hold_first:
                self.chain.torque_on_holding(present)
                with self._lock:
                    self._writes += 1
        except Exception as exc:  # noqa: BLE001 - handed to the caller through the Future (and on_error)
            future.set_exception(exc)
            self._emit(self._on_error, exc)
            return
        self._motion = _Motion(source, name, future, time.monotonic())
        self._emit(self._on_event, f"motion {name!r} started")

    def _check_plan(self, source: MotionSource, name: str, present: np.ndarray) -> None:
        """Let a planning source fix its plan from ``present`` and refuse it if any target lies beyond a joint
        limit or any move is faster than the robot's max joint speed (a source without a plan is checked tick by
        tick instead)."""
        first = source.goal_at(0.0, present.copy())
        if first is not None:
            error = joint_limit_error(self.robot, first, f"{name}: the first goal")
            if error is not None:
                raise error
        plan = getattr(source, "plan", None)
        if plan is None:
            return
        targets = np.asarray(plan.targets_rad, dtype=float)
        for m, target in enumerate(targets):
            error = joint_limit_error(self.robot, target, f"{name}: target {m + 1} of {len(targets)}")
            if error is not None:
                raise error
        starts = np.vstack([np.asarray(plan.start_rad, dtype=float)[None, :], targets[:-1]])
        durations = np.asarray(plan.durations_s, dtype=float)
        moving = durations > 0
        if np.any(moving):
            speeds = np.abs(targets[moving] - starts[moving]) / durations[moving, None]
            m, j = (int(k) for k in np.unravel_index(int(np.argmax(speeds)), speeds.shape))
            if speeds[m, j] > self.robot.max_joint_speed_rad_s * SPEED_TOLERANCE:
                raise JointLimitError(
                    f"{name}: joint {self.robot.joint_ids[j]} would move at {speeds[m, j]:.2f} rad/s, above the "
                    f"robot's max_joint_speed_rad_s = {self.robot.max_joint_speed_rad_s:g} rad/s: nothing was sent")

    def _pause(self) -> None:
        motion = self._motion
        if motion is not None and motion.paused_at_s is None:
            motion.paused_at_s = time.monotonic()
            self._emit(self._on_event, f"motion {motion.name!r} paused")

    def _resume(self) -> None:
        motion = self._motion
        if motion is not None and motion.paused_at_s is not None:
            motion.paused_total_s += time.monotonic() - motion.paused_at_s
            motion.paused_at_s = None
            self._emit(self._on_event, f"motion {motion.name!r} resumed")

    def _end_motion(self, outcome: str, error: BaseException | None = None) -> None:
        motion, self._motion = self._motion, None
        if motion is None:
            return
        if error is not None:
            motion.future.set_exception(error)
        else:
            motion.future.set_result(outcome)
        self._emit(self._on_event, f"motion {motion.name!r} {outcome if error is None else 'stopped by an error'}")

    def _stop_motion_with(self, error: BaseException) -> None:
        if self._motion is not None:
            self._end_motion(MOTION_STOPPED, error)

    def _drain_commands(self, cancel: bool) -> None:
        while True:
            try:
                command, future = self._commands.get_nowait()
            except queue.Empty:
                return
            if not cancel:
                if self._on_command is None:
                    command()
                    continue
                self._emit(self._on_command, time.monotonic())
                try:
                    command()
                finally:
                    self._emit(self._on_command, None)
            elif future is not None:
                future.cancel()

    def _emit(self, callback: Callable | None, value: Any) -> None:
        if callback is None:
            return
        try:
            callback(value)
        except Exception:  # noqa: BLE001 - thread boundary: a broken subscriber must not stop the robot loop
            log.exception("robot controller callback %r failed", callback)
