"""The robot's servo chain: XM430-W350 servos on one Dynamixel Protocol 2.0 bus, driven through dynamixel-sdk.

Every control tick costs one ``GroupSyncWrite`` of the goal positions and one ``GroupSyncRead`` of the block
126…135 (present current, velocity, position). The port is opened through :func:`devices.factory.open_serial`, so
``sim`` (the simulated chain, emulated at the wire), a pseudo-terminal and a U2D2 adapter all run this same code.

Angles follow SPEC §2: ``angle_rad = (ticks − 2048)·2π/4096 · sign + zero_offset``, per joint, in the joint order of
``RobotConfig.joint_ids``. Goals are clamped to the configured joint limits before anything is sent.

Errors (``devices.errors``): a timeout is :class:`NoReplyError` naming the servo; a bad CRC is
:class:`CorruptPacketError`; a status packet with the alert bit leads to reading Hardware Error Status and raising
:class:`ServoHardwareError` naming the servo and the error; a pulled cable is :class:`LinkLostError`; a command the
servo refused (EEPROM write with torque on, value out of range, …) is :class:`ServoCommandError`.

Threads: a :class:`ServoChain` is NOT thread-safe. Only the thread that owns the port may call it (in the app that is
the :class:`devices.controller.RobotController` thread; use its ``submit``).
"""

from __future__ import annotations

import logging
import math
import os
import select
import sys
import termios
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_FAIL,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from devices import control_table as ct
from devices import tick_trace
from devices.config import RobotConfig
from devices.errors import (
    CorruptPacketError,
    DeadlinePassedError,
    DeviceError,
    DuplicateIdError,
    LinkLostError,
    ModelMismatchError,
    NoReplyError,
    PortOpenError,
    RateError,
    ServoCommandError,
    ServoHardwareError,
    StatusReturnLevelError,
    link_lost_words,
    status_return_level_words,
)
from devices.factory import is_sim, open_serial, sim_serial_path
from devices.reply_pacing import READ_POLL_S, ReplyPacing

log = logging.getLogger(__name__)

PROTOCOL_VERSION = 2.0
# dynamixel-sdk waits (bytes·10/baud + 2·16 ms + 2 ms) for a status packet: ~35 ms per silent servo.
PER_ID_PING_COST_S = 0.035
BROADCAST_PING_COST_S = 0.81  # the SDK always waits its full broadcast-ping window
REBOOT_TIMEOUT_S = 2.0
FACTORY_RESET_KEEP_ID_AND_BAUD = 0x02  # Protocol 2.0 factory reset option: everything but the ID and the baud rate
# Protocol 2.0 status packet layout (as dynamixel-sdk indexes it): the length field counts instruction, error,
# parameters and CRC.
_PKT_ID, _PKT_LENGTH_L, _PKT_LENGTH_H, _PKT_ERROR, _PKT_PARAMETER0 = 4, 5, 6, 8, 8
INST_PING = 0x01  # at index 7 of an instruction packet
_HEADER = b"\xff\xff\xfd\x00"  # every Protocol 2.0 packet starts so; a status packet has 0x55 at index 7
_INST_STATUS = 0x55
_STATUS_OVERHEAD = 4
PING_REPLY_BYTES = 14  # a ping's status packet: header 4, ID, length 2, instruction, error, model 2, firmware, CRC 2
SECOND_REPLY_SLACK_S = 0.002  # a pty's far end may write a little late
STALE_DRAINS = 5  # check_models first drops what still arrives from a port's last session, this many windows at most
COLLISION_TRIES = 2  # garbled replies in a row, after the first, that make an ID "collided" (two servos on it)
SELECT_SLACK_S = 0.0005  # missing bytes due sooner than this are waited for on the port itself, not slept for, s
# The wait rule for replies (the pacing constants with it): devices/reply_pacing.py.
RATE_REFUSE_FRACTION = 0.8  # a tick's bus time above this fraction of the period: the rate is refused
RATE_WARN_FRACTION = 0.5  # above this fraction: a warning
MIN_STATUS_BYTES = 11  # a status packet without parameters: header 4, ID, length 2, instruction, error, CRC 2
DEFAULT_BAUD_BPS = 1_000_000
PTY_EXTRA_TIMEOUT_MS = 250.0  # a pty (an emulator in a process) crosses the kernel's tty work queue: under load >100 ms
LATENCY_TIMER_DIR = Path("/sys/bus/usb-serial/devices")
# A read made while connecting (the model check's pings, the Return Delay Times, the timed cycles) that gets no reply
# is asked again, this many times in all, CONNECT_RETRY_PAUSE_S apart, before its servo is named: a reply held on this
# computer (the simulated lab's process, or the kernel's tty worker, waiting behind other programs: on a loaded test
# machine a reply came over 250 ms late while the app started) answers a later asking; a servo that is not there
# answers none. Costs an absent servo's verdict two more reply timeouts.
CONNECT_ATTEMPTS = 3
CONNECT_RETRY_PAUSE_S = 0.05

_T = TypeVar("_T")


@dataclass(frozen=True)
class ServoInfo:
    servo_id: int
    model_number: int
    model_name: str
    firmware: int
    baud: int
    collided: bool = False  # its replies arrive garbled or twice, every time: two servos answer to this ID
    # Its Status Return Level (0: answers PING only, 1: PING and READ, 2: every instruction), read when it pings;
    # 0 when a ping is answered and a read is not (a read that times out twice); None when not known.
    status_return_level: int | None = None


@dataclass(frozen=True)
class ChainState:
    """One feedback sample of the whole chain, in joint order (SPEC §2 signs and offsets applied)."""

    host_time_s: float  # time.monotonic() when the sync read was sent
    position_rad: np.ndarray
    velocity_rad_s: np.ndarray
    current_ma: np.ndarray
    alert_ids: tuple[int, ...] = ()  # servos whose status packet carried the alert bit (hardware error)
    goal_rad: np.ndarray | None = None  # the last goals sent (filled in by RobotController), joint order
    # what a controller other than feedforward added to those goals (rad, joint order; filled in by RobotController
    # from the running motion's progress), its name and its gains as JSON
    correction_rad: np.ndarray | None = None
    controller: str = ""
    controller_gains: str = ""


@dataclass(frozen=True)
class ServoHealth:
    servo_id: int
    hardware_error: int
    error_names: tuple[str, ...]
    temperature_c: float
    voltage_v: float
    torque_on: bool
    led_on: bool


class _FactoryPortHandler(PortHandler):
    """dynamixel-sdk's PortHandler, opening its port through ``devices.factory`` (``sim``, pty or serial device),
    whose reads wait for bytes instead of polling for them or sleeping through a learned worst case.

    The SDK reads a non-blocking port in a tight loop while a reply is on the wire. Every wake-up of the bus thread
    has to win the GIL back from the GUI thread, so the number of wake-ups per transaction, not their length, decides
    how long a control tick takes. This handler sleeps until the replies' bytes can first all have arrived -- a lower
    bound from the wire alone: the instruction's and the replies' bytes at the baud rate plus each servo's Return
    Delay Time as read from (or written to) its control table (``return_delays_s``; 0 until known) -- and, if they
    have not all arrived by then, waits for the missing bytes themselves (``select`` on the port; a sleep of the
    missing bytes' wire time where the port has no file descriptor, or in a real-time thread: see
    :func:`_real_time_thread`), until the SDK's packet deadline.

    Nothing is learned from the timing of earlier transactions but one fact, on repeated evidence: whether the device
    answers faster than the wire (the simulator on an accelerated clock; :class:`devices.reply_pacing.ReplyPacing`), whose replies are
    then awaited at their observed pace, never past the wire's bound. One reply that is late (the far end
    descheduled, or this thread's time stamp of its instruction delayed) costs that transaction only. The previous
    design learned a per-reply gap from arrival times, capped at 2 ms and halved only every 32 transactions, so one late reply made
    the next ~32 sync reads sleep 12 × 2 ms (the ~1 s bursts of ~28 ms ticks measured in the app; see
    ``benchmarks/bench_servo_bus.py`` (e)).

    Bytes taken off the port while waiting are kept in ``_rx`` and handed to the SDK by :meth:`readPort`. Times are
    ``time.monotonic()`` seconds. Owned by the thread that owns the port.
    """

    def __init__(self, port_name: str, device: str, extra_timeout_ms: float = 0.0) -> None:
        super().__init__(port_name)
        self._device = device
        self._extra_timeout_ms = extra_timeout_ms
        self.byte_s = 10.0 / DEFAULT_BAUD_BPS  # one byte on the wire (start + 8 data + stop bits), s
        self.return_delays_s: dict[int, float] = {}  # servo ID -> Return Delay Time (s) read from its table
        self.wakeups = 0  # sleeps and waits for bytes (a cost figure for tests and benchmarks)
        self.pacing = ReplyPacing(self.byte_s)  # the wait rule (devices/reply_pacing.py); this class does the I/O
        self._rx = bytearray()  # bytes read off the port while waiting, not yet handed to the SDK
        self._reply_ids: tuple[int, ...] = ()  # the servos expected to answer the instruction in flight
        self.deadline_s: float | None = None  # time.monotonic() after which the read in flight is given up
        self.late_bytes_discarded = 0  # bytes found waiting before an instruction (late replies; see clearPort)
        self.late_replies_discarded = 0  # status packets among them
        self.late_replies_found = 0  # status packets found at the last such find (replies to how many reads at once)
        self.late_bytes_found_s = -math.inf  # time.monotonic() when such bytes were last found
        self.instructions_sent = 0  # instructions written since open (a read kept in flight ends at the next one)

    def setPacketTimeout(self, packet_length):  # noqa: N802 - dynamixel-sdk's name
        super().setPacketTimeout(packet_length)
        self.packet_timeout += self._extra_timeout_ms

    def setupPort(self, cflag_baud):  # noqa: N802 - dynamixel-sdk's name
        if self.is_open and self.ser is not None:
            # Change the rate in place: reopening a USB adapter can take tens of milliseconds.
            self.ser.baudrate = self.baudrate
        else:
            self.ser = open_serial(self.port_name, self.baudrate, self._device, timeout_s=0.0)
            self.is_open = True
        self.clearPort()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        self.byte_s = 10.0 / self.baudrate
        self.pacing.byte_s = self.byte_s
        return True

    def clearPort(self):  # noqa: N802 - dynamixel-sdk's name
        # The SDK calls this before every instruction: bytes still here are late replies to an earlier read that was
        # given up (its deadline, or its timeout). Counted, and the status packets among them (noise on a bus
        # powering up is bytes, not packets): they show the servos did answer, only late.
        waiting = self.ser.in_waiting
        if self._rx or waiting:
            stale = bytes(self._rx) + (self.ser.read(waiting) if waiting else b"")
            self.late_replies_found = _status_packets_in(stale)
            self.late_bytes_discarded += len(stale)
            self.late_replies_discarded += self.late_replies_found
            self.late_bytes_found_s = time.monotonic()
        self._rx.clear()
        self.ser.reset_input_buffer()

    def getCFlagBaud(self, baudrate):  # noqa: N802 - dynamixel-sdk's name
        # The SDK's list lacks 4.5 Mbps; pyserial (and the simulator) accept any positive rate.
        return baudrate if baudrate > 0 else -1

    def getBytesAvailable(self):  # noqa: N802 - dynamixel-sdk's name
        return len(self._rx) + self.ser.in_waiting

    @property
    def faster_than_wire(self) -> bool:
        """The device answers faster than the wire allows (an accelerated simulator): see ReplyPacing."""
        return self.pacing.faster_than_wire

    @faster_than_wire.setter
    def faster_than_wire(self, value: bool) -> None:
        self.pacing.faster_than_wire = value

    def writePort(self, packet):  # noqa: N802 - dynamixel-sdk's name
        tx_start_s = time.monotonic()
        written = self._write_now(bytes(packet))
        self.instructions_sent += 1
        trace = tick_trace.TRACE
        if trace is not None:
            trace.mark("tx", (packet[7] if len(packet) > 7 else None, len(packet), round(tx_start_s, 6)))
        # The bytes start leaving when handed over (write returns later: a simulated device answers inside it).
        self.pacing.sent(tx_start_s, len(packet))
        self._reply_ids = (packet[4],) if len(packet) > 4 else ()
        return written

    def _write_now(self, data: bytes) -> int:
        """Hand ``data`` to the kernel and return; never wait for the port to become writable again.

        pyserial's ``write`` (no write timeout) follows every ``os.write`` with a ``select`` until the port is
        writable. On a pseudo-terminal that waits for the kernel's tty worker (normal priority) to move the bytes to
        the far end: measured on a busy PC, goal writes of the control tick held 15-400 ms there. An instruction of
        a few dozen bytes fits the tty's buffer whole, so one non-blocking write (the port is opened non-blocking)
        hands it over; only a short write falls back to pyserial's waiting write for the rest."""
        fd = getattr(self.ser, "fd", None)
        if not isinstance(fd, int):  # the in-process simulator's port delivers at once
            return self.ser.write(data)
        try:
            n = os.write(fd, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:  # as pyserial words it (a pulled adapter: the link-lost path reads this)
            raise serial.SerialException(f"write failed: {exc}") from exc
        if n < len(data):
            n += self.ser.write(data[n:])
        return n

    def readPort(self, length):  # noqa: N802 - dynamixel-sdk's name
        """Up to ``length`` bytes; waits for them (not past the SDK's packet deadline) if fewer have arrived."""
        if len(self._rx) < length:
            self._take_waiting()
            if len(self._rx) < length:
                self._wait_for_bytes(length, self._reply_ids[:1])
        data = bytes(self._rx[:length])
        del self._rx[:length]
        return data

    def wait_for_replies(self, reply_ids: Sequence[int], n_bytes: int) -> None:
        """Wait until ``n_bytes`` of status packets from ``reply_ids`` (in wire order) have arrived, or the SDK's
        packet deadline has passed; the bytes stay buffered for :meth:`readPort`."""
        self._take_waiting()
        if len(self._rx) < n_bytes:
            self._wait_for_bytes(n_bytes, tuple(reply_ids))
        if len(self._rx) >= n_bytes:
            self.pacing.complete(time.monotonic(), n_bytes, self._delays_s(reply_ids))

    def _wait_for_bytes(self, n_bytes: int, reply_ids: tuple[int, ...]) -> None:
        """Wait (sleep, or select on the port) as ReplyPacing says until ``n_bytes`` are in or the deadline."""
        pacing = self.pacing
        reply_bytes = n_bytes / max(len(reply_ids), 1)
        now = time.monotonic()
        pacing.judge_early(now)
        probe = pacing.probes()
        due_s: float | None = None  # when the bytes were first due (a lower bound passed without them)
        while len(self._rx) < n_bytes:
            time_left_s = self._time_left_s()
            if time_left_s <= 0.0:
                # Given up with bytes missing: they may still come, after our next instructions.
                pacing.gave_up(now, n_bytes - len(self._rx), self._delays_s(reply_ids))
                return
            replies_left = reply_ids[int(len(self._rx) // reply_bytes):] if reply_ids else ()
            wait_s, due_s = pacing.wait_s(now, len(self._rx), n_bytes - len(self._rx), self._delays_s(replies_left),
                                          due_s, probe)
            if wait_s > SELECT_SLACK_S or not self._can_select() or _real_time_thread():
                self._sleep(min(max(wait_s, READ_POLL_S), time_left_s))
            else:
                self._select(time_left_s)
            self._take_waiting()
            now = time.monotonic()
            pacing.judge_early(now)

    def _delays_s(self, servo_ids: Sequence[int]) -> float:
        """The known Return Delay Times of ``servo_ids`` together (0 for a servo whose delay is not known), s."""
        return sum(self.return_delays_s.get(sid, 0.0) for sid in servo_ids)

    def _take_waiting(self) -> None:
        waiting = self.ser.in_waiting
        if waiting:
            self._rx += self.ser.read(waiting)
            self.pacing.received(waiting)
            trace = tick_trace.TRACE
            if trace is not None:
                trace.mark("rx", len(self._rx))

    def _can_select(self) -> bool:
        return isinstance(getattr(self.ser, "fd", None), int)  # a real port or pty; the simulator's has none

    def _select(self, timeout_s: float) -> None:
        """Block until the port has bytes (it has none buffered: they were all taken) or ``timeout_s`` passes."""
        self.wakeups += 1
        trace = tick_trace.TRACE
        if trace is not None:
            trace.mark("select", round(timeout_s, 6))
        readable, _, _ = select.select([self.ser.fd], [], [], timeout_s)
        if trace is not None:
            trace.mark("selected", bool(readable))
        if readable and not self.ser.in_waiting:
            # Readable with nothing to read: the far end hung up. pyserial's read says so (SerialException, a
            # lost link), where looking again would spin until the deadline.
            self._rx += self.ser.read(1)

    def _time_left_s(self) -> float:
        """Seconds until the SDK's packet timeout (the SDK keeps it in ms of time.time()) or ``deadline_s``."""
        left_s = (self.packet_timeout - self.getTimeSinceStart()) / 1000.0
        if self.deadline_s is not None:
            left_s = min(left_s, self.deadline_s - time.monotonic())
        return left_s

    def isPacketTimeout(self):  # noqa: N802 - dynamixel-sdk's name
        if self.deadline_passed():
            return True
        return super().isPacketTimeout()

    def reply_timeout_passed(self) -> bool:
        """The SDK's packet timeout of the last instruction has passed (or fired: it zeroes it then)."""
        return self.getTimeSinceStart() > self.packet_timeout

    def deadline_passed(self) -> bool:
        """The caller's deadline for the read in flight has passed (its reply timeout may not have)."""
        return self.deadline_s is not None and time.monotonic() >= self.deadline_s

    def unread(self, data: bytes | list[int]) -> None:
        """Put bytes taken for a packet back in front of the buffer (a read given up mid-packet at its deadline
        and resumed later parses them again)."""
        if data:
            self._rx[:0] = bytes(data)

    def _sleep(self, seconds: float) -> None:
        self.wakeups += 1
        trace = tick_trace.TRACE
        if trace is not None:
            trace.mark("sleep", round(seconds, 6))
        time.sleep(max(seconds, READ_POLL_S))
        if trace is not None:
            trace.mark("slept")

    def closePort(self):  # noqa: N802 - dynamixel-sdk's name
        self._rx.clear()
        if self.ser is not None:
            try:
                self.ser.close()
            except (serial.SerialException, OSError, termios.error) as exc:
                log.debug("closing %s: %s", self.port_name, exc)
        self.is_open = False
        self.is_using = False


class _TrackingSyncRead(GroupSyncRead):
    """GroupSyncRead that keeps each servo's status error byte and names the servo that failed.

    The SDK's ``rxPacket`` drops the error byte (so the alert bit would be lost) and does not say which ID timed out.
    Its ``readRx`` also takes the first status packet of the right ID whatever its length: a late reply to an
    earlier read that was given up (a health read at the tick's deadline, a timeout) would be read as this one's
    data, short or wrong. Here a packet of another ID (skipped by the SDK too) or whose parameter count is not this
    read's data length is skipped, and counted in ``stale_packets``.
    """

    def __init__(self, port, ph, start_address, data_length) -> None:
        super().__init__(port, ph, start_address, data_length)
        self.errors: dict[int, int] = {}
        self.failed_id: int | None = None
        self.stale_packets = 0
        self._parsed: set[int] = set()  # servos whose reply to the instruction in flight has been parsed

    def rxPacket(self):  # noqa: N802 - dynamixel-sdk's name
        self.errors = {}
        self._parsed = set()
        return self.resume()

    def resume(self) -> int:
        """Receive the replies still missing to the instruction already sent: after :meth:`rxPacket`, or again
        after a read given up at the caller's deadline (the packet timeout still runs from the instruction; bytes
        of a packet cut off at the deadline were put back, see :meth:`_read_reply`)."""
        self.last_result = False
        self.failed_id = None
        result = COMM_RX_FAIL
        pending = [dxl_id for dxl_id in self.data_dict if dxl_id not in self._parsed]
        # One sleep through all the replies (see _FactoryPortHandler), then the SDK parses them from the buffer.
        self.port.wait_for_replies(tuple(pending), len(pending) * (MIN_STATUS_BYTES + self.data_length))
        for dxl_id in pending:
            data, result, error = self._read_reply(dxl_id)
            if result != COMM_SUCCESS:
                self.failed_id = dxl_id
                return result
            self.data_dict[dxl_id] = data
            self.errors[dxl_id] = error
            self._parsed.add(dxl_id)
        self.last_result = True
        return COMM_SUCCESS

    def _read_reply(self, dxl_id: int) -> tuple[list[int], int, int]:
        """The SDK's readRx, skipping status packets of another ID or another length (see the class docstring)."""
        while True:
            packet, result = self.ph.rxPacket(self.port, False)
            if result != COMM_SUCCESS:
                if self.port.deadline_passed():  # cut off by the caller's deadline: kept for a resumed read
                    self.port.unread(packet)
                return [], result, 0
            n_params = (packet[_PKT_LENGTH_L] | packet[_PKT_LENGTH_H] << 8) - _STATUS_OVERHEAD
            if packet[_PKT_ID] != dxl_id or n_params != self.data_length:
                self.stale_packets += 1
                continue
            return list(packet[_PKT_PARAMETER0 + 1:_PKT_PARAMETER0 + 1 + n_params]), result, packet[_PKT_ERROR]


class ServoChain:
    """The servos of ``robot`` on its port. See the module docstring; one thread only."""

    def __init__(self, robot: RobotConfig, device: str = "robot") -> None:
        self.robot = robot
        self.device = device
        self.ids = tuple(robot.joint_ids)
        self._signs = np.asarray(robot.signs, dtype=float)
        self._offsets = np.asarray(robot.zero_offsets_rad, dtype=float)
        self._min_rad = np.asarray(robot.joint_min_rad, dtype=float)
        self._max_rad = np.asarray(robot.joint_max_rad, dtype=float)
        t_lo = self._ticks_float(self._min_rad)
        t_hi = self._ticks_float(self._max_rad)
        # Tick limits inside the angle limits, so a clamped goal never exceeds a limit after rounding.
        self._min_ticks = np.clip(np.ceil(np.minimum(t_lo, t_hi) - 1e-9), 0, 4095).astype(np.int64)
        self._max_ticks = np.clip(np.floor(np.maximum(t_lo, t_hi) + 1e-9), 0, 4095).astype(np.int64)
        self._baud = robot.baud
        self._port: _FactoryPortHandler | None = None
        self._ph = PacketHandler(PROTOCOL_VERSION)
        self._goal_writer: GroupSyncWrite | None = None
        self._state_reader: _TrackingSyncRead | None = None
        # A feedback read given up at its deadline but kept (``read_state(keep_in_flight=True)``): when its
        # instruction went out (time.monotonic()) and the port's instruction count then; None when there is none.
        self._state_in_flight: tuple[float, int] | None = None
        self._supply_cache: dict[int, tuple[float, float]] = {}  # servo ID -> (voltage V, temperature °C)
        self._last_goal_rad: np.ndarray | None = None
        self._return_delays_s: dict[int, float] = {}  # shared with each port opened (survives a reconnect)
        self._torque_commanded: set[int] = set()  # servos this chain last turned torque on (and not off since)

    # -- lifecycle -----------------------------------------------------------------------------------------------
    @property
    def port_name(self) -> str:
        return self.robot.port

    @property
    def baud(self) -> int:
        return self._baud

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.is_open

    @property
    def is_simulated(self) -> bool:
        return is_sim(self.robot.port)

    @property
    def reply_wakeups(self) -> int:
        """How many times the bus thread has slept waiting for replies since the port was opened (a cost figure:
        each wake-up must win the GIL back). 0 when closed."""
        return self._port.wakeups if self._port is not None else 0

    @property
    def replies_paced_by_device(self) -> bool:
        """True once the port has seen replies arrive faster than the wire allows (an accelerated simulator): its
        reads then wait at the pace observed, not at the baud rate and Return Delay Time. A diagnostic."""
        return self._port is not None and self._port.faster_than_wire

    @property
    def return_delays_s(self) -> dict[int, float]:
        """Each servo's Return Delay Time (s) as last read from or written to its control table (a copy; servos not
        read yet are missing). The reads wait for replies on this, never on timings learned from earlier replies."""
        return dict(self._return_delays_s)

    def sync_read_time_s(self, n_servos: int, data_length: int) -> float:
        """Bus time (s) of a sync read of ``data_length`` bytes from ``n_servos``: the instruction, then each reply's
        Return Delay Time (the largest known; 0 if none is known) and bytes. This machine's wake-up latency comes on
        top."""
        byte_s = 10.0 / self._baud
        instruction_bytes = 14 + n_servos
        delay_s = max(self.return_delays_s.values(), default=0.0)
        return (instruction_bytes + n_servos * (MIN_STATUS_BYTES + data_length)) * byte_s + n_servos * delay_s

    def sync_write_time_s(self, n_servos: int, data_length: int = 4) -> float:
        """Wire time (s) of a sync write of ``data_length`` bytes to each of ``n_servos`` (no reply)."""
        return (14 + n_servos * (1 + data_length)) * 10.0 / self._baud

    def read_return_delays(self) -> dict[int, int]:
        """Read every configured servo's Return Delay Time (µs) and remember it for the reads' waits."""
        return {sid: self._asked_again(self.read_item, sid, "Return Delay Time") * 2 for sid in self.ids}

    def _asked_again(self, read: Callable[..., _T], *args: object) -> _T:
        """``read(*args)``, asked again while it gets no reply, :data:`CONNECT_ATTEMPTS` times in all (for the reads
        made while connecting; a late reply still arriving is discarded at the next instruction)."""
        for attempt in range(1, CONNECT_ATTEMPTS):
            try:
                return read(*args)
            except NoReplyError as exc:
                log.info("%s: asked again (%d of %d)", exc, attempt + 1, CONNECT_ATTEMPTS)
                time.sleep(CONNECT_RETRY_PAUSE_S)
        return read(*args)  # the last asking: its NoReplyError names the servo

    def open(self) -> None:
        """Open the port at the configured baud rate (raises :class:`PortOpenError`)."""
        if self.is_open:
            return
        # A pty's far end is a process that may wait for the scheduler; give its replies more time than USB's.
        extra_ms = PTY_EXTRA_TIMEOUT_MS if _is_pty(self.robot.port, self.device) else 0.0
        port = _FactoryPortHandler(self.robot.port, self.device, extra_ms)
        port.baudrate = self._baud
        try:
            ok = port.openPort()
        except (serial.SerialException, OSError) as exc:
            if isinstance(exc, PortOpenError):
                raise
            raise PortOpenError(f"cannot open {self.device} port {self.robot.port}: {exc}") from exc
        if not ok:
            raise PortOpenError(f"cannot open {self.device} port {self.robot.port} at {self._baud} bps")
        port.return_delays_s = self._return_delays_s
        self._port = port
        self._goal_writer = GroupSyncWrite(port, self._ph, ct.ADDR_GOAL_POSITION, 4)
        for sid in self.ids:
            self._goal_writer.addParam(sid, [0, 8, 0, 0])
        self._state_reader = _TrackingSyncRead(port, self._ph, ct.STATE_BLOCK_ADDRESS, ct.STATE_BLOCK_SIZE)
        for sid in self.ids:
            self._state_reader.addParam(sid)

    def close(self) -> None:
        if self._port is not None:
            self._port.closePort()
        self._last_goal_rad = None
        self._torque_commanded.clear()  # whatever the servos do while we are away is not ours to judge
        self._port = None
        self._goal_writer = None
        self._state_reader = None
        self._state_in_flight = None

    def __enter__(self) -> ServoChain:
        self.open()
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # -- discovery -----------------------------------------------------------------------------------------------
    def scan(self, ids: Iterable[int] = range(0, 253), bauds: Sequence[int] | None = None) -> list[ServoInfo]:
        """Servos answering on any of ``bauds`` (default: the configured one), sorted by baud then ID.

        For a short ID list each ID is pinged; otherwise one broadcast ping per baud rate (≈ 0.8 s at 1 Mbps).
        dynamixel-sdk only reports a corrupt broadcast reply when it was the last one, so if some servos answered
        at the configured rate but a configured joint was heard at no rate, the configured rate gets a second
        broadcast and then a ping per missing joint.
        The port is left at the configured baud rate.
        """
        wanted = [i for i in ids if 0 <= i <= ct.MAX_ID]
        bauds = list(bauds) if bauds else [self._baud]
        found: list[ServoInfo] = []
        try:
            for baud in bauds:
                self._set_port_baud(baud)
                found.extend(self._scan_at(wanted, baud))
            heard = {info.servo_id for info in found}
            missing = [i for i in self.ids if i in wanted and i not in heard]
            heard_at_configured = any(info.baud == self._baud for info in found)
            if missing and heard_at_configured and not self._per_id_is_cheaper(wanted):
                self._set_port_baud(self._baud)
                data, _ = self._io(self._ph.broadcastPing, self._require_port())
                found.extend(self._infos(data, missing, self._baud))
                heard |= set(data)
                found.extend(self._ping_each([i for i in missing if i not in heard], self._baud))
        finally:
            self._set_port_baud(self._baud)
        return sorted(found, key=lambda info: (info.baud, info.servo_id))

    def scan_time_s(self, ids: Iterable[int] = range(0, 253), bauds: Sequence[int] | None = None) -> float:
        """About how long (s) :meth:`scan` holds the bus when nobody answers (its worst case)."""
        wanted = [i for i in ids if 0 <= i <= ct.MAX_ID]
        per_baud = len(wanted) * PER_ID_PING_COST_S if self._per_id_is_cheaper(wanted) else BROADCAST_PING_COST_S
        return per_baud * len(list(bauds) if bauds else [self._baud])

    @staticmethod
    def _per_id_is_cheaper(wanted: list[int]) -> bool:
        return len(wanted) * PER_ID_PING_COST_S < BROADCAST_PING_COST_S

    def _scan_at(self, wanted: list[int], baud: int) -> list[ServoInfo]:
        if self._per_id_is_cheaper(wanted):
            return self._ping_each(wanted, baud)
        data, result = self._io(self._ph.broadcastPing, self._require_port())
        infos = self._infos(data, wanted, baud)
        if infos:
            # A broadcast reply per ID hides a second servo on the same ID: ask each one found on its own (a few ms
            # each), which also checks for a second reply.
            infos = self._ping_each([info.servo_id for info in infos], baud)
        if result == COMM_RX_CORRUPT:
            # The last reply was garbled: someone else may be there; ask every other ID on its own.
            infos += self._ping_each([i for i in wanted if i not in data], baud)
        return sorted(infos, key=lambda info: info.servo_id)

    @staticmethod
    def _infos(seen: dict[int, tuple[int, int]], wanted: list[int], baud: int) -> list[ServoInfo]:
        return [ServoInfo(sid, model, ct.model_name(model), firmware, baud)
                for sid, (model, firmware) in sorted(seen.items()) if sid in wanted]

    def _ping_each(self, ids: Iterable[int], baud: int) -> list[ServoInfo]:
        infos = []
        for sid in ids:
            try:
                infos.append(self._ping_at(sid, baud))
            except NoReplyError:
                continue
            except CorruptPacketError:
                if self._collides(sid):
                    infos.append(ServoInfo(sid, 0, "two servos answer (garbled replies)", 0, baud, True))
        return infos

    def _collides(self, servo_id: int, tries: int = COLLISION_TRIES) -> bool:
        """True when ``servo_id``'s replies arrive garbled ``tries`` times running (one garbled reply is noise; two
        servos set to one ID garble every reply, their packets colliding on the wire)."""
        for _ in range(tries):
            try:
                self._ping_at(servo_id, self._port_baud())
            except CorruptPacketError:
                continue
            except NoReplyError:
                return False
            return False
        return True

    def _port_baud(self) -> int:
        port = self._require_port()
        return int(getattr(port, "baudrate", self._baud) or self._baud)

    def ping(self, servo_id: int) -> ServoInfo:
        """Model and firmware of one servo (raises :class:`NoReplyError` naming it)."""
        return self._ping_at(servo_id, self._baud)

    def _ping_at(self, servo_id: int, baud: int) -> ServoInfo:
        """One PING (a servo answers it whatever its Status Return Level: model and firmware come in the reply), a
        check for a second reply, then a read of the Status Return Level: a servo whose reads go unanswered after an
        answered ping (twice) answers pings only, level 0 (it is listed so, not hidden)."""
        port = self._require_port()
        model, firmware, result = self._ping_reply(port, servo_id)
        self._check_comm(result, servo_id, "ping")
        twice = self._second_reply(port) and self._ping_reply(port, servo_id)[2] == COMM_SUCCESS \
            and self._second_reply(port)
        level: int | None = None
        for _ in range(2):  # one lost reply is noise, not a level
            value, result, _error = self._io(self._ph.read1ByteTxRx, port, servo_id, ct.ADDR_STATUS_RETURN_LEVEL)
            if result == COMM_SUCCESS:
                level = value
                break
            if result != COMM_RX_TIMEOUT:
                self._check_comm(result, servo_id, "reading the Status Return Level")
            if self._ping_reply(port, servo_id)[2] != COMM_SUCCESS:  # gone altogether: silent, not level 0
                self._check_comm(COMM_RX_TIMEOUT, servo_id, "ping")
        else:
            level = 0
        return ServoInfo(servo_id, model, ct.model_name(model), firmware, baud, collided=twice,
                         status_return_level=level)

    def _ping_reply(self, port: _FactoryPortHandler, servo_id: int) -> tuple[int, int, int]:
        """(model number, firmware version, SDK result) of one PING: dynamixel-sdk's ``ping`` drops the firmware
        byte of the reply, so the packet is sent here as the SDK sends it."""
        packet = [0] * 10
        packet[_PKT_ID], packet[_PKT_LENGTH_L], packet[_PKT_LENGTH_H], packet[7] = servo_id, 3, 0, INST_PING
        reply, result, _error = self._io(self._ph.txRxPacket, port, packet)
        if result != COMM_SUCCESS:
            return 0, 0, result
        p0 = _PKT_PARAMETER0 + 1
        return reply[p0] | reply[p0 + 1] << 8, reply[p0 + 2], result

    def _second_reply(self, port: _FactoryPortHandler) -> bool:
        """After a ping's reply: did a second one follow (two servos on one ID, the second answering after its own
        Return Delay Time instead of colliding with the first)? Waits the longest Return Delay Time and a ping
        reply's wire time (plus slack for a pty), then discards whatever came."""
        window_s = ct.MAX_RETURN_DELAY_S + PING_REPLY_BYTES * port.byte_s + SECOND_REPLY_SLACK_S
        deadline = time.monotonic() + window_s
        while time.monotonic() < deadline:
            if self._io(port.getBytesAvailable):
                break
            time.sleep(min(0.0005, max(0.0, deadline - time.monotonic())))
        extra = self._io(port.getBytesAvailable) > 0
        if extra:
            self._io(port.clearPort)
        return extra

    def check_models(self) -> None:
        """Every configured joint answers, once, and is an XM430-W350 (raises DuplicateIdError when two servos
        answer to one ID, ModelMismatchError / NoReplyError); their Return Delay Times are read too (the reads'
        waits and the rate checks need them)."""
        infos: dict[int, ServoInfo] = {}
        collided: list[int] = []
        missing: list[int] = []
        port = self._require_port()
        for _ in range(STALE_DRAINS):  # a reply of the port's last session still arriving is no servo's answer now
            if not self._second_reply(port):
                break
        for sid in self.ids:
            try:
                infos[sid] = self._asked_again(self.ping, sid)
            except NoReplyError:
                missing.append(sid)
                continue
            except CorruptPacketError:
                if not self._collides(sid):
                    raise
                collided.append(sid)
                continue
            if infos[sid].collided:  # a clean reply, and a second one after it: two servos on this ID
                collided.append(sid)
                del infos[sid]
        if collided and infos:  # others answer cleanly: not the wiring, a shared ID
            raise DuplicateIdError(collided, missing)
        if collided:
            raise CorruptPacketError(collided[0], "no servo answers cleanly")
        if missing:
            raise NoReplyError(missing[0], "ping")
        for sid, info in infos.items():
            if info.status_return_level is not None and info.status_return_level < ct.STATUS_RETURN_ALL:
                # It answered the ping: its cable, power, ID and baud rate are fine, it only keeps quiet.
                raise StatusReturnLevelError(sid, info.status_return_level)
        for sid, info in infos.items():
            if info.model_number != ct.MODEL_NUMBER_XM430_W350:
                # Asked once more before refusing: a stale status packet from this servo (CI once read "model 120",
                # a read's two data bytes, as a reopened port's first ping reply) is not its model; a servo of
                # another model answers the same twice.
                self._io(port.clearPort)
                info = infos[sid] = self.ping(sid)
            if info.model_number != ct.MODEL_NUMBER_XM430_W350:
                raise ModelMismatchError(
                    f"servo {sid} is a {info.model_name} (model {info.model_number}), but this driver is written "
                    f"for the XM430-W350 (model {ct.MODEL_NUMBER_XM430_W350}): check robot.joint_ids in the config"
                )
        self.read_return_delays()

    # -- commands --------------------------------------------------------------------------------------------------
    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> None:
        """Torque on or off, servo by servo (each write acknowledged). Torque-on fails on a servo in error.

        Forgets :attr:`last_goal_rad`: a servo turning torque on takes its present position as its goal, and a limp
        one can be moved by hand away from the goal it was sent.
        """
        self._last_goal_rad = None
        chosen = self._ids_or_all(ids)
        if enabled:
            self._goals_to_present(chosen)
        for sid in chosen:
            self._torque_commanded.discard(sid)
            self.write_item(sid, "Torque Enable", int(bool(enabled)), hardware_error_fails=bool(enabled))
            if enabled:
                self._torque_commanded.add(sid)

    def torque_on_holding(self, present_rad: np.ndarray) -> None:
        """Every servo holds ``present_rad`` with torque on, in TWO sync writes and no reply: Goal Position :=
        ``present_rad``, then Torque Enable := 1 on all. For the control loop's play command, which has just read
        the present pose and each servo's status (a servo in hardware error is refused before this): twelve
        acknowledged writes cost 12 status packets (~12 ms at the factory Return Delay Time, one USB latency
        timer each on an adapter), more than a 50 Hz tick has left. A servo that did not take it shows up in the
        next health poll as one whose torque is off while commanded on.
        """
        self.write_goals(present_rad)
        writer = GroupSyncWrite(self._require_port(), self._ph, ct.ADDR_TORQUE_ENABLE, 1)
        for sid in self.ids:
            writer.addParam(sid, [1])
        result = self._io(writer.txPacket)
        if result != COMM_SUCCESS:
            raise DeviceError(f"sync write of torque enable failed on {self.robot.port}: "
                              f"{self._ph.getTxRxResult(result)}")
        self._torque_commanded.update(self.ids)

    def _goals_to_present(self, ids: list[int]) -> None:
        """Goal Position := Present Position on ``ids`` (one sync read, one sync write), so torque coming on
        holds each joint where it is: after an overload and reboot, or posing by hand, the goal register may still
        hold a goal from before, and the joint would jump to it."""
        present = self._sync_read_blocks(ids, ct.ADDR_PRESENT_POSITION, 4)
        writer = GroupSyncWrite(self._require_port(), self._ph, ct.ADDR_GOAL_POSITION, 4)
        for sid in ids:
            writer.addParam(sid, list(present[sid]))
        result = self._io(writer.txPacket)
        if result != COMM_SUCCESS:
            raise DeviceError(f"sync write of goal positions failed on {self.robot.port}: "
                              f"{self._ph.getTxRxResult(result)}")

    def set_led(self, servo_id: int, on: bool) -> None:
        self.write_item(servo_id, "LED", int(bool(on)))

    def factory_reset(self, servo_id: int) -> None:
        """Factory reset of one servo's control table, keeping its ID and baud rate (the instruction's option 0x02,
        as Dynamixel Wizard offers it), then wait until it answers again (it restarts, torque off)."""
        port = self._require_port()
        self._last_goal_rad = None
        self._torque_commanded.discard(servo_id)
        result, error = self._io(self._ph.factoryReset, port, servo_id, FACTORY_RESET_KEEP_ID_AND_BAUD)
        self._check_comm(result, servo_id, "factory reset")
        self._check_error(error, servo_id, "factory reset")
        port.return_delays_s.pop(servo_id, None)  # back at the factory value: read again when needed
        self._wait_until_back(servo_id, "a factory reset")

    def reboot(self, servo_id: int) -> None:
        """Reboot a servo (clears a hardware error; torque comes back off) and wait until it answers again."""
        port = self._require_port()
        self._last_goal_rad = None  # the servo comes back with torque off and its goal at its present position
        self._torque_commanded.discard(servo_id)
        result, error = self._io(self._ph.reboot, port, servo_id)
        self._check_comm(result, servo_id, "reboot")
        self._wait_until_back(servo_id, "a reboot")

    def change_baud(self, servo_id: int, index: int) -> None:
        """Baud Rate := ``index`` (0…7, e-manual) on one servo whose torque is off (an EEPROM item), then find it at
        its new rate: the port switches to it, pings until the servo answers, reads the item back, and switches back
        to the bus's rate. The write's own status packet is not relied on (the servo may send it at either rate, or
        lose it switching). :class:`NoReplyError` if it does not answer at the new rate."""
        if index not in ct.BAUD_RATES_BPS:
            raise ValueError(f"Baud Rate {index} is not one of the servo's rates (0…7)")
        port = self._require_port()
        item = ct.ITEMS_BY_NAME["Baud Rate"]
        bus_bps = port.getBaudRate()
        new_bps = ct.BAUD_RATES_BPS[index]
        self._io(self._ph.writeTxRx, port, servo_id, item.address, item.size, [index])
        self._set_port_baud(new_bps)
        try:
            self._wait_until_back(servo_id, f"its Baud Rate was set to {new_bps} bps")
            now = self.read_item(servo_id, "Baud Rate")
            if now != index:
                raise DeviceError(f"servo {servo_id} answers at {new_bps} bps but reads Baud Rate {now}")
        finally:
            self._set_port_baud(bus_bps)
            port.return_delays_s.pop(servo_id, None)

    def _wait_until_back(self, servo_id: int, after: str) -> None:
        """Ping ``servo_id`` until it answers again (it restarts after a reboot or a factory reset), at most
        ``REBOOT_TIMEOUT_S``; NoReplyError saying after what."""
        port = self._require_port()
        deadline = time.monotonic() + REBOOT_TIMEOUT_S
        while True:
            _model, result, _error = self._io(self._ph.ping, port, servo_id)
            if result == COMM_SUCCESS:
                return
            if time.monotonic() > deadline:
                raise NoReplyError(servo_id, f"did not come back within {REBOOT_TIMEOUT_S:.0f} s of {after}")

    def set_return_delay(self, delay_us: int = 0, ids: Sequence[int] | None = None) -> None:
        """Set Return Delay Time (µs, even, 0…508) with torque off; 0 makes every sync read faster."""
        value = int(delay_us) // 2
        for sid in self._ids_or_all(ids):
            self.write_item(sid, "Return Delay Time", value)

    def read_item(self, servo_id: int, name: str) -> int:
        """One control-table item by its e-manual name, e.g. ``"Present Temperature"`` (signed where it is)."""
        item = ct.ITEMS_BY_NAME[name]
        port = self._require_port()
        data, result, error = self._io(self._ph.readTxRx, port, servo_id, item.address, item.size)
        self._check_comm(result, servo_id, f"reading {name}")
        self._check_error(error, servo_id, f"reading {name}")
        raw = int.from_bytes(bytes(data), "little")
        if item.address == ct.ADDR_RETURN_DELAY_TIME:
            port.return_delays_s[servo_id] = raw * ct.RETURN_DELAY_S_PER_LSB
        return ct.to_signed(raw, item.size) if item.signed else raw

    def read_block(self, servo_id: int, address: int, length: int) -> bytes:
        """``length`` raw bytes of the control table from ``address`` in ONE read (the whole table: 0, 148)."""
        if address < 0 or length <= 0 or address + length > ct.CONTROL_TABLE_SIZE:
            raise ValueError(f"bytes {address}…{address + length - 1} are outside the control table "
                             f"(0…{ct.CONTROL_TABLE_SIZE - 1})")
        port = self._require_port()
        data, result, error = self._io(self._ph.readTxRx, port, servo_id, address, length)
        self._check_comm(result, servo_id, f"reading {length} bytes of its control table")
        self._check_error(error, servo_id, "reading its control table")
        return bytes(data)

    def write_item(self, servo_id: int, name: str, value: int, *, hardware_error_fails: bool = False) -> None:
        """Write one control-table item (acknowledged); raises :class:`ServoCommandError` if the servo refuses."""
        item = ct.ITEMS_BY_NAME[name]
        port = self._require_port()
        data = list(int(value).to_bytes(item.size, "little", signed=value < 0))
        result, error = self._io(self._ph.writeTxRx, port, servo_id, item.address, item.size, data)
        self._check_comm(result, servo_id, f"writing {name}")
        if error & ct.ERROR_ALERT_BIT and (error & 0x7F or hardware_error_fails):
            raise self._hardware_error(servo_id)
        self._check_error(error, servo_id, f"writing {name} = {value}")
        if item.address == ct.ADDR_RETURN_DELAY_TIME:
            port.return_delays_s[servo_id] = int(value) * ct.RETURN_DELAY_S_PER_LSB

    @property
    def torque_commanded(self) -> frozenset[int]:
        """Servos whose torque this chain turned on (and has not turned off or rebooted since): one of them found
        with torque off has rebooted or lost power."""
        return frozenset(self._torque_commanded)

    # -- the control tick ------------------------------------------------------------------------------------------
    @property
    def late_bytes_discarded(self) -> int:
        """Bytes of late replies (to reads given up earlier) discarded before later instructions, since open."""
        return 0 if self._port is None else self._port.late_bytes_discarded

    @property
    def late_replies_discarded(self) -> int:
        """Status packets among :attr:`late_bytes_discarded` (headers of replies found late), since open."""
        return 0 if self._port is None else self._port.late_replies_discarded

    @property
    def late_bytes_found_s(self) -> float:
        """``time.monotonic()`` when late reply bytes were last found before an instruction (-inf: never)."""
        return -math.inf if self._port is None else self._port.late_bytes_found_s

    @property
    def late_replies_found(self) -> int:
        """Status packets among the late bytes found at :attr:`late_bytes_found_s` (more than one read's replies:
        the replies to several instructions came together)."""
        return 0 if self._port is None else self._port.late_replies_found

    @property
    def bytes_since_instruction(self) -> int:
        """Bytes received since the last instruction was sent (after a failed read: did anything answer at all)."""
        return 0 if self._port is None else self._port.pacing.rx_since_tx

    @property
    def last_goal_rad(self) -> np.ndarray | None:
        """The goals of the last :meth:`write_goals` (rad, joint order; a copy), whoever called it; ``None`` before
        the first and after anything that moves the servos' goals behind it (torque on/off, reboot, reopen)."""
        return None if self._last_goal_rad is None else self._last_goal_rad.copy()

    def clamp_to_limits(self, angles_rad: np.ndarray) -> np.ndarray:
        angles = np.asarray(angles_rad, dtype=float)
        if angles.shape != (len(self.ids),):
            raise ValueError(f"expected {len(self.ids)} joint angles, got shape {angles.shape}")
        bad = np.flatnonzero(~np.isfinite(angles))
        if bad.size:
            raise ValueError(f"goal for joint {self.ids[bad[0]]} is {angles[bad[0]]}: not a finite angle")
        return np.clip(angles, self._min_rad, self._max_rad)

    def write_goals(self, angles_rad: np.ndarray) -> np.ndarray:
        """Clamp to the joint limits and send all goals in ONE GroupSyncWrite; returns the angles sent (rad)."""
        angles = self.clamp_to_limits(angles_rad)
        ticks = np.clip(self.ticks_from_angles(angles), self._min_ticks, self._max_ticks)
        writer = self._require(self._goal_writer)
        for sid, tick in zip(self.ids, ticks):
            writer.changeParam(sid, list(int(tick).to_bytes(4, "little", signed=True)))
        result = self._io(writer.txPacket)
        if result != COMM_SUCCESS:
            raise DeviceError(f"sync write of goal positions failed on {self.robot.port}: "
                              f"{self._ph.getTxRxResult(result)}")
        sent = self.angles_from_ticks(ticks)
        self._last_goal_rad = sent
        return sent.copy()

    @property
    def state_read_in_flight(self) -> bool:
        """A feedback read given up at its deadline with ``keep_in_flight`` can still be resumed: no instruction
        has gone out since (one would have discarded its replies)."""
        kept = self._state_in_flight
        return kept is not None and self._port is not None and self._port.instructions_sent == kept[1]

    def read_state(self, *, raise_on_alert: bool = True, deadline_s: float | None = None,
                   keep_in_flight: bool = False) -> ChainState:
        """ONE GroupSyncRead of present current, velocity and position of every joint.

        A status packet with the alert bit raises :class:`ServoHardwareError` naming the servo and its error; with
        ``raise_on_alert=False`` the state is returned with ``alert_ids`` set instead (the controller's way).
        ``deadline_s`` (time.monotonic()): replies not in by then are not waited for (:class:`DeadlinePassedError`),
        so the control tick keeps its slot when the kernel hands the replies over late (on a busy PC the tty layer's
        worker runs at normal priority; see docs/REALTIME.md). Late replies still in the port at the next instruction
        are discarded there and counted (``late_bytes_discarded``).
        """
        reader = self._require(self._state_reader)
        port = self._require_port()
        t0 = time.monotonic()
        self._state_in_flight = None
        try:
            self._sync_transfer(reader, port, deadline_s, self.ids[0],
                                "sync read of present position/velocity/current",
                                "given up at the control tick's deadline (replies late)")
        except DeadlinePassedError:
            if keep_in_flight:
                self._state_in_flight = (t0, port.instructions_sent)
            raise
        return self._state_from(reader, t0, raise_on_alert)

    def resume_state_read(self, *, deadline_s: float, raise_on_alert: bool = True) -> ChainState:
        """Go on waiting for the replies of the feedback read kept in flight (:attr:`state_read_in_flight`), until
        ``deadline_s`` or their reply timeout, counted from its instruction, whichever comes first: the same read
        and the same evidence as one that waited its whole timeout, spread over several control ticks' slack.
        Returns its state (``host_time_s``: when its instruction went out); raises :class:`DeadlinePassedError`
        while its timeout has not passed (still in flight), :class:`NoReplyError` naming the servo when it has.
        A read no longer in flight raises :class:`DeadlinePassedError` at once (not in flight: read anew)."""
        kept = self._state_in_flight
        if not self.state_read_in_flight or kept is None:
            self._state_in_flight = None
            raise DeadlinePassedError("no feedback read in flight to resume (an instruction went out since)")
        reader = self._require(self._state_reader)
        port = self._require_port()
        port.deadline_s = deadline_s
        try:
            result = self._io(reader.resume)
        finally:
            port.deadline_s = None
        if result != COMM_SUCCESS:
            if time.monotonic() >= deadline_s and not port.reply_timeout_passed():
                raise DeadlinePassedError("sync read of present position/velocity/current given up at the control "
                                          "tick's deadline again (replies late, within their timeout)")
            self._state_in_flight = None
            self._check_comm(result, reader.failed_id if reader.failed_id is not None else self.ids[0],
                             "sync read of present position/velocity/current")
        self._state_in_flight = None
        return self._state_from(reader, kept[0], raise_on_alert)

    def _state_from(self, reader: _TrackingSyncRead, t0: float, raise_on_alert: bool) -> ChainState:
        """The ChainState of a completed feedback read whose instruction went out at ``t0``."""
        n = len(self.ids)
        current = np.empty(n)
        velocity = np.empty(n)
        position = np.empty(n)
        for k, sid in enumerate(self.ids):
            block = bytes(reader.data_dict[sid])
            current[k] = int.from_bytes(block[0:2], "little", signed=True)
            velocity[k] = int.from_bytes(block[2:6], "little", signed=True)
            position[k] = int.from_bytes(block[6:10], "little", signed=True)
        alerts = tuple(sid for sid in self.ids if reader.errors.get(sid, 0) & ct.ERROR_ALERT_BIT)
        if alerts and raise_on_alert:
            raise self._hardware_error(alerts[0])
        return ChainState(
            host_time_s=t0,
            position_rad=self.angles_from_ticks(position),
            velocity_rad_s=velocity * ct.RAD_S_PER_VELOCITY_LSB * self._signs,
            current_ma=current * ct.CURRENT_MA_PER_LSB * self._signs,
            alert_ids=alerts,
        )

    def read_health(self, ids: Sequence[int] | None = None, *, supply: bool = True,
                    deadline_s: float | None = None) -> list[ServoHealth]:
        """Hardware error, torque and LED (one sync read of 64…70) and, with ``supply``, input voltage (V) and
        temperature (°C) (a second sync read of 144…146). Without ``supply`` the last values read are reported
        (NaN before the first), which halves the cost of a frequent poll: temperature and voltage change slowly.
        ``deadline_s`` (time.monotonic()): replies not in by then are not waited for (:class:`DeadlinePassedError`),
        so a read fitted into a control tick's slack never holds the next tick however late its replies come.
        """
        ids = self._ids_or_all(ids)
        status = self._sync_read_blocks(ids, ct.HEALTH_BLOCK_ADDRESS, ct.HEALTH_BLOCK_SIZE, deadline_s)
        if supply:
            for sid, block in self._sync_read_blocks(ids, ct.SUPPLY_BLOCK_ADDRESS, ct.SUPPLY_BLOCK_SIZE,
                                                     deadline_s).items():
                self._supply_cache[sid] = (int.from_bytes(block[0:2], "little") * ct.VOLTAGE_V_PER_LSB,
                                           float(block[2]))
        health = []
        for sid in ids:
            block = status[sid]
            error = block[ct.ADDR_HARDWARE_ERROR_STATUS - ct.HEALTH_BLOCK_ADDRESS]
            voltage_v, temperature_c = self._supply_cache.get(sid, (math.nan, math.nan))
            health.append(ServoHealth(
                servo_id=sid,
                hardware_error=error,
                error_names=ct.hardware_error_names(error),
                temperature_c=temperature_c,
                voltage_v=voltage_v,
                torque_on=bool(block[0]),
                led_on=bool(block[1]),
            ))
        return health

    def _sync_read_blocks(self, ids: list[int], address: int, size: int,
                          deadline_s: float | None = None) -> dict[int, bytes]:
        port = self._require_port()
        reader = _TrackingSyncRead(port, self._ph, address, size)
        for sid in ids:
            reader.addParam(sid)
        self._sync_transfer(reader, port, deadline_s, ids[0], "sync read of hardware status",
                            "given up at the next control tick's slot", f" of servos {_id_list(ids)}")
        return {sid: bytes(reader.data_dict[sid]) for sid in ids}

    def _sync_transfer(self, reader: _TrackingSyncRead, port: _FactoryPortHandler, deadline_s: float | None,
                       first_id: int, what: str, given_up: str, whose: str = "") -> None:
        """One sync read's exchange: replies not in by ``deadline_s`` raise :class:`DeadlinePassedError` (``what``,
        ``whose``, ``given_up``); any other failure is named by the servo that failed (else ``first_id``)."""
        port.deadline_s = deadline_s
        try:
            result = self._io(reader.txRxPacket)
        finally:
            port.deadline_s = None
        if result == COMM_SUCCESS:
            return
        if deadline_s is not None and time.monotonic() >= deadline_s:
            raise DeadlinePassedError(f"{what}{whose} {given_up}")
        self._check_comm(result, reader.failed_id if reader.failed_id is not None else first_id, what)

    # -- timing checks ---------------------------------------------------------------------------------------------
    def cycle_time_s(self) -> float:
        """Bus time (s) of one control tick from the configuration alone: the goals' sync write and the feedback
        sync read at this baud rate, each servo's Return Delay Time (as read by :meth:`check_models` or
        :meth:`read_return_delays`; 0 for servos not read) and, on a USB adapter, its latency timer once per read.
        This machine's wake-up latency comes on top; see :meth:`measure_cycle_s` for a measured figure."""
        n = len(self.ids)
        latency_s = (self.latency_timer_ms() or 0) / 1000.0
        return self.sync_write_time_s(n) + self.sync_read_time_s(n, ct.STATE_BLOCK_SIZE) + latency_s

    def check_rate(self, rate_hz: float) -> str | None:
        """Before a loop starts at ``rate_hz``: raise :class:`RateError` if the bus cannot keep it, return the
        warning if it barely can (both say the fix), else None. Needs the Return Delay Times (``check_models``)."""
        problem = self.rate_problem(rate_hz)
        if problem is None:
            return None
        verdict, message = problem
        if verdict == "refuse":
            raise RateError(message)
        return message

    def rate_problem(self, rate_hz: float) -> tuple[str, str] | None:
        """``("refuse" | "warn", message with the fix)`` if ``rate_hz`` cannot (or can only barely) be kept on this
        bus: refused when a tick's bus time exceeds ``RATE_REFUSE_FRACTION`` of the period (a tick then has no room
        for the host's own latency and the health poll), a warning past ``RATE_WARN_FRACTION``; None if it fits."""
        cycle_s = self.cycle_time_s()
        period_s = 1.0 / rate_hz
        if cycle_s <= RATE_WARN_FRACTION * period_s:
            return None
        delays_us = sorted({round(d * 1e6) for d in self._return_delays_s.values()})
        fixes = []
        if any(delays_us):
            fixes.append("set Return Delay Time to 0 (Hardware tab → Return Delay Time → 0, torque off)")
        if (self.latency_timer_ms() or 0) > 1:
            fixes.append(f"set the USB latency timer to 1 ms (`echo 1 | sudo tee {self._latency_timer_path()}`)")
        if self._baud < 4_000_000:
            fixes.append("raise the baud rate")
        max_rate_hz = RATE_REFUSE_FRACTION / cycle_s
        fixes.append(f"or run at ≤ {math.floor(max_rate_hz):d} Hz")
        delay_text = "/".join(str(d) for d in delays_us) if delays_us else "unknown"
        verdict = "refuse" if cycle_s > RATE_REFUSE_FRACTION * period_s else "warn"
        what = "cannot be kept" if verdict == "refuse" else "leaves little room"
        return verdict, (
            f"{rate_hz:g} Hz {what}: a tick has {period_s * 1e3:.1f} ms, and the sync write + sync read of "
            f"{len(self.ids)} servos at {self._baud} bps with Return Delay Time {delay_text} µs take "
            f"{cycle_s * 1e3:.1f} ms on the bus. Fix: " + "; ".join(fixes))

    def timing_warnings(self, control_rate_hz: float | None = None, n_cycles: int = 5) -> list[str]:
        """Latency-timer, Return Delay Time and cycle-time checks; each warning says how to fix it.

        The latency timer only exists for USB serial adapters on Linux (not for ``sim`` or a pty). The cycle check
        times ``n_cycles`` sync reads (nothing is written) and adds the sync write's wire time.
        """
        warnings: list[str] = []
        latency = self.latency_warning()
        if latency:
            warnings.append(latency)
        delays = self.read_return_delays()
        slow = [sid for sid, us in delays.items() if us > 0]
        if slow:
            worst = max(delays[sid] for sid in slow)
            warnings.append(
                f"Return Delay Time is up to {worst} µs on servo(s) {_id_list(slow)}: every sync read waits that "
                "long per servo. Fix: set it to 0 — turn torque off (Hardware tab, All torque off), then press \"Set "
                "return delay to 0 µs\" in the Timing box"
            )
        rate_hz = control_rate_hz or self.robot.control_rate_hz
        problem = self.rate_problem(rate_hz)
        if problem is not None:
            warnings.append(problem[1])
        cycle_s = self.measure_cycle_s(n_cycles)
        period_s = 1.0 / rate_hz
        if cycle_s > 0.8 * period_s:
            warnings.append(
                f"a sync write + sync read cycle takes {cycle_s * 1e3:.1f} ms but {rate_hz:g} Hz leaves "
                f"{period_s * 1e3:.1f} ms per tick: lower robot.control_rate_hz, set Return Delay Time to 0, "
                "set the latency timer to 1 ms or raise the baud rate"
            )
        return warnings

    def measure_cycle_s(self, n_cycles: int = 5) -> float:
        """Median time of a sync read plus the wire time of a goal sync write (s); sends no goals. A read that got no
        reply and was answered when asked again counts with the answered one's time."""
        def timed_read() -> float:
            t0 = time.perf_counter()
            self.read_state(raise_on_alert=False)
            return time.perf_counter() - t0

        times = [self._asked_again(timed_read) for _ in range(max(1, n_cycles))]
        write_bytes = 14 + 5 * len(self.ids)
        return float(np.median(times)) + write_bytes * 10.0 / self._baud

    def latency_warning(self) -> str | None:
        """A warning with its fix if the USB adapter's latency timer is above 1 ms (Linux); needs no open port."""
        latency_ms = self.latency_timer_ms()
        if latency_ms is None or latency_ms <= 1:
            return None
        return (f"USB latency timer of {self.robot.port} is {latency_ms} ms (each reply waits up to that long): "
                f"fix with `echo 1 | sudo tee {self._latency_timer_path()}`")

    def latency_timer_ms(self) -> int | None:
        """The USB adapter's latency timer (Linux), or None where there is none (sim, pty, other OS)."""
        path = self._latency_timer_path()
        if path is None:
            return None
        try:
            return int(path.read_text().strip())
        except (OSError, ValueError):
            return None

    def _latency_timer_path(self) -> Path | None:
        if self.is_simulated or not sys.platform.startswith("linux"):
            return None
        tty = os.path.basename(os.path.realpath(self.robot.port))
        path = LATENCY_TIMER_DIR / tty / "latency_timer"
        return path if path.exists() else None

    # -- units -----------------------------------------------------------------------------------------------------
    def angles_from_ticks(self, ticks: np.ndarray) -> np.ndarray:
        """Joint angles (rad) from position ticks, SPEC §2: (ticks − 2048)·2π/4096 · sign + zero offset."""
        return (np.asarray(ticks, dtype=float) - ct.CENTER_TICKS) * ct.RAD_PER_TICK * self._signs + self._offsets

    def ticks_from_angles(self, angles_rad: np.ndarray) -> np.ndarray:
        """Position ticks (int64, rounded) for joint angles in rad; the inverse of :meth:`angles_from_ticks`."""
        return np.rint(self._ticks_float(np.asarray(angles_rad, dtype=float))).astype(np.int64)

    def _ticks_float(self, angles_rad: np.ndarray) -> np.ndarray:
        return (angles_rad - self._offsets) * self._signs / ct.RAD_PER_TICK + ct.CENTER_TICKS

    # -- internals -------------------------------------------------------------------------------------------------
    def _ids_or_all(self, ids: Sequence[int] | None) -> list[int]:
        return list(self.ids if ids is None else ids)

    def _require_port(self) -> _FactoryPortHandler:
        if self._port is None or not self._port.is_open:
            raise DeviceError(f"the {self.device} port {self.robot.port} is not open")
        return self._port

    def _require(self, obj):
        self._require_port()
        return obj

    def _set_port_baud(self, baud: int) -> None:
        port = self._require_port()
        if port.getBaudRate() != baud:
            ok = self._io(port.setBaudRate, baud)
            if not ok:
                raise PortOpenError(f"{self.robot.port} cannot run at {baud} bps")

    def _io(self, fn, *args):
        """Run one SDK call; a vanished port becomes LinkLostError (and the SDK's busy flag is released)."""
        try:
            return fn(*args)
        except (serial.SerialException, OSError, termios.error) as exc:
            # termios.error (e.g. EIO from tcflush when the adapter or pty vanishes) is no OSError.
            if self._port is not None:
                self._port.is_using = False
            raise LinkLostError(
                f"lost the link to the servo bus on {self.robot.port}: {link_lost_words(exc)}. Check the USB cable "
                "and the servo power; the controller reconnects when the port is back"
            ) from exc

    def _check_comm(self, result: int, servo_id: int, what: str) -> None:
        if result == COMM_SUCCESS:
            return
        if result == COMM_RX_TIMEOUT:
            raise NoReplyError(servo_id, what)
        if result == COMM_RX_CORRUPT:
            raise CorruptPacketError(servo_id, what)
        raise DeviceError(f"{what} on servo {servo_id} failed: {self._ph.getTxRxResult(result)}")

    def _check_error(self, error: int, servo_id: int, what: str) -> None:
        errnum = error & 0x7F
        if errnum:
            raise ServoCommandError(servo_id, errnum, what)

    def _hardware_error(self, servo_id: int) -> ServoHardwareError:
        port = self._require_port()
        status, result, _ = self._io(self._ph.read1ByteTxRx, port, servo_id, ct.ADDR_HARDWARE_ERROR_STATUS)
        self._check_comm(result, servo_id, "reading Hardware Error Status")
        return ServoHardwareError(servo_id, ct.hardware_error_names(status) or ("hardware error",))


def scan_problems(found: Sequence[ServoInfo], expected: Iterable[int], scanned: Iterable[int]) -> list[str]:
    """What a scan's result says is wrong with the IDs, one sentence each: an ID two servos answer to (its replies
    collide), configured joints (``expected``) among the ``scanned`` IDs that did not answer, and servos that answer
    pings but not every instruction (Status Return Level below 2: what it means and the fix)."""
    scanned = set(scanned)
    collided = sorted({info.servo_id for info in found if info.collided})
    heard = {info.servo_id for info in found if not info.collided}
    missing = [i for i in expected if i in scanned and i not in heard and i not in collided]
    problems = []
    if collided:
        problems.append(str(DuplicateIdError(collided, missing)))
    elif missing:
        problems.append(f"configured joint ID(s) {_id_list(missing)} did not answer: check their cables and power, "
                        "or whether one was set to another ID")
    for info in found:
        if not info.collided and info.status_return_level is not None \
                and info.status_return_level < ct.STATUS_RETURN_ALL:
            problems.append(status_return_level_words(info.servo_id, info.status_return_level) +
                            "; the app refuses to connect until then")
    return problems


def _real_time_thread() -> bool:
    """The calling thread runs at real-time priority (Linux SCHED_FIFO or SCHED_RR): it then never waits on a tty
    with select/poll, which first waits for the kernel's tty worker to hand over the bytes it holds (``n_tty_poll``
    flushes the port's buffer) — a worker at normal priority, so a real-time thread waits behind the busy programs
    (a 3.7 ms select returned 125 ms later beside two). Such a thread sleeps and looks at the port's count of bytes
    in (``TIOCINQ``, pyserial's ``in_waiting``), which does not wait for the worker. A thread at normal priority waits
    behind the same programs either way, and one select costs it fewer wake-ups than sleeps (10-minute gaits beside two
    busy programs: 101 missed ticks with select, 211 with sleeps)."""
    getter = getattr(os, "sched_getscheduler", None)
    if getter is None:
        return False
    try:
        return getter(0) in (os.SCHED_FIFO, os.SCHED_RR)
    except OSError:
        return False


def _status_packets_in(data: bytes) -> int:
    """How many Protocol 2.0 status packet headers ``data`` holds (whole or cut off after the instruction byte)."""
    count, at = 0, data.find(_HEADER)
    while at >= 0:
        count += at + 7 < len(data) and data[at + 7] == _INST_STATUS
        at = data.find(_HEADER, at + 1)
    return count


def _id_list(ids: Sequence[int]) -> str:
    return ", ".join(str(i) for i in ids)


def _is_pty(port: str, device: str = "robot") -> bool:
    """A pseudo-terminal (Linux /dev/pts/N, macOS /dev/ttysNNN), e.g. ``devices.sim.pty_server`` — or port ``sim``
    when the simulated lab serves ``device`` on one (its own process, ``devices.sim.lab_process``)."""
    if is_sim(port):
        path = sim_serial_path(device)
        if path is None:
            return False
        port = path
    real = os.path.realpath(port)
    return real.startswith("/dev/pts/") or (real.startswith("/dev/ttys") and real[9:].isdigit())
