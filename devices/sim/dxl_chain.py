"""A chain of simulated XM430-W350 servos on one Dynamixel Protocol 2.0 bus, emulated at the wire.

:class:`VirtualChain` is a :class:`devices.sim.transport.SimEndpoint`: the host's bytes go in, status packets come
back byte for byte with real timings (10 bits per byte at the bus baud rate in both directions, the Return Delay
Time before each reply, sync/bulk-read replies one after another), all divided by the clock's ``speed``. Packets
are decoded and encoded with :mod:`devices.dxl_wire`, which is independent of dynamixel-sdk, so the real driver and
this simulator are two implementations of the protocol meeting on the wire.

Each servo has the XM430-W350 control table (:mod:`devices.control_table`) with its access rules (EEPROM only with
torque off, read-only items, data range/length/limit errors), moves toward its goal with a velocity limit and a
finite acceleration, goes limp with torque off (a "hand" can then pose it with :meth:`VirtualChain.set_limp_position`),
draws a current proportional to its load and reports seeded noise in the last bits of current and position. Only
position control (Operating Mode 3) is emulated; other modes are stored but behave the same.

Faults for tests and demos: overload (Hardware Error Status bit 5, torque off, alert bit on every status until a
reboot), no reply from an ID, corrupt CRC on the next N replies, a pulled cable (every host read/write raises
``serial.SerialException`` until :meth:`VirtualChain.reconnect`).

Threads: the host side (``host_*``) is called from the thread that owns the port; the Python methods (faults, hand,
``present_positions_rad``) may be called from any thread. One lock serialises both. No thread of its own: physics
is advanced lazily to the simulated time of each event.
"""

from __future__ import annotations

import math
import struct
import threading
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import serial

from devices import control_table as ct
from devices import dxl_wire as wire
from devices.sim.clock import SimClock

BITS_PER_BYTE = 10  # start + 8 data + stop
MAX_ACCELERATION_RAD_S2 = 40.0  # used when Profile Acceleration is 0 ("infinite"): the motor's own limit
PHYSICS_STEP_S = 0.002
TORQUE_CONSTANT_NM_PER_A = 1.78  # XM430-W350 at 12 V: 4.1 N·m stall at 2.3 A
OVERLOAD_TORQUE_NM = 3.6
OVERLOAD_AFTER_S = 1.0  # a load above OVERLOAD_TORQUE_NM held this long trips the overload shutdown
BOOT_TIME_S = 0.05
INTER_BYTE_TIMEOUT_S = 0.02  # a partial packet older than this is dropped, as a servo's receive timeout does
SYNC_READ_LOG_SIZE = 4096
NOISE_BATCH = 4096  # encoder/current noise is drawn this many values at a time (a numpy call per value is slow)

# The items the physics reads and the present values it writes, packed straight into the table (hot path).
_U32 = struct.Struct("<I")
_I32 = struct.Struct("<i")
_MOTION_PROFILE = struct.Struct("<II")  # Profile Acceleration (108), Profile Velocity (112)
_PRESENT_STATE = struct.Struct("<hii")  # Present Current (126), Present Velocity (128), Present Position (132)
_TICK_AND_MOVING = struct.Struct("<HB")  # Realtime Tick (120), Moving (122)
_SUPPLY = struct.Struct("<HB")  # Present Input Voltage (144), Present Temperature (146)
_ADDR_MOVING_THRESHOLD = 24
_ADDR_REALTIME_TICK = 120


@dataclass
class _Servo:
    table: bytearray
    position_ticks: float
    velocity_ticks_s: float = 0.0
    load_nm: float = 0.0
    ambient_c: float = 32.0
    overload_time_s: float = 0.0
    no_reply: bool = False
    corrupt_replies: int = 0
    booting_until_s: float = -math.inf
    registered: tuple[int, bytes] | None = None
    last_accel_ticks_s2: float = 0.0
    counters: Counter = field(default_factory=Counter)

    def get(self, item: ct.Item) -> int:
        raw = int.from_bytes(self.table[item.address : item.address + item.size], "little", signed=False)
        return ct.to_signed(raw, item.size) if item.signed else raw

    def put(self, item: ct.Item, value: int) -> None:
        self.table[item.address : item.address + item.size] = int(value).to_bytes(
            item.size, "little", signed=item.signed or value < 0
        )

    @property
    def servo_id(self) -> int:
        return self.table[ct.ADDR_ID]

    @property
    def baud_bps(self) -> int:
        return ct.BAUD_RATES_BPS.get(self.table[ct.ADDR_BAUD_RATE], 0)

    @property
    def torque_on(self) -> bool:
        return bool(self.table[ct.ADDR_TORQUE_ENABLE])

    @property
    def hardware_error(self) -> int:
        return self.table[ct.ADDR_HARDWARE_ERROR_STATUS]


_ITEM = ct.ITEMS_BY_NAME


def _default_table(servo_id: int, baud_index: int, model_number: int) -> bytearray:
    table = bytearray(ct.CONTROL_TABLE_SIZE)
    servo = _Servo(table, 0.0)
    for item in ct.XM430_W350_ITEMS:
        servo.put(item, item.default)
    servo.put(_ITEM["Model Number"], model_number)
    servo.put(_ITEM["ID"], servo_id)
    servo.put(_ITEM["Baud Rate"], baud_index)
    return table


@dataclass
class _Chunk:
    """Reply bytes on the wire: byte ``i`` has fully arrived at the host at ``start + (i+1)·byte_s`` (wall)."""

    start_wall_s: float
    byte_s: float
    data: bytes
    delivered: int = 0

    @property
    def end_wall_s(self) -> float:
        return self.start_wall_s + len(self.data) * self.byte_s


class JointPhysics(Protocol):
    """A physics simulation that moves the joints instead of the chain's own servo model
    (``devices.sim.physics.backend.PhysicsBackend``): per joint in ID order, torque enable, goal (rad) and profile
    speed (rad/s) in; angle (rad), velocity (rad/s), motor torque (N·m) and time spent saturated (s) out."""

    def command(self, torque_on: np.ndarray, goal_rad: np.ndarray, speed_rad_s: np.ndarray) -> None: ...
    def advance_to(self, sim_s: float) -> None: ...
    def joint_state(self) -> Any: ...
    def set_joint_angle(self, joint: int, angle_rad: float) -> None: ...
    def set_external_torque(self, joint: int, torque_nm: float) -> None: ...
    def release_hand(self, joint: int | None = None) -> None: ...


class VirtualChain:
    """Simulated XM430-W350 servos sharing one Protocol 2.0 bus. See the module docstring.

    With ``physics`` the joints are bodies in a physics simulation (:class:`JointPhysics`): the servo's present
    position, velocity and current come from it, its goals and torque enable drive it, and a demanded torque above
    the stall torque for ``OVERLOAD_AFTER_S`` trips the overload error, as the firmware does."""

    def __init__(self, ids: Sequence[int], baud: int, clock: SimClock, seed: int,
                 model_number: int = ct.MODEL_NUMBER_XM430_W350, *, return_delay_time: int = 250,
                 firmware: int = 46, physics: JointPhysics | None = None) -> None:
        if baud not in ct.BAUD_INDEX_FROM_BPS:
            raise ValueError(f"{baud} bps is not a Dynamixel baud rate ({sorted(ct.BAUD_INDEX_FROM_BPS)})")
        if len(set(ids)) != len(ids) or not all(0 <= i <= ct.MAX_ID for i in ids):
            raise ValueError(f"servo IDs must be distinct and within 0…{ct.MAX_ID}, got {list(ids)}")
        self._clock = clock
        self._physics = physics
        self._physics_state: Any = None  # the last JointState copied into the servos
        self._rng = np.random.default_rng(seed)
        self._position_noise: list[int] = []  # ticks, −1…1, drawn NOISE_BATCH at a time
        self._current_noise: list[int] = []  # LSB, −2…2
        self._lock = threading.RLock()
        self._order = tuple(ids)  # joint order for present_positions_rad
        self._model_number = model_number
        self._baud_index = ct.BAUD_INDEX_FROM_BPS[baud]
        self._servos: list[_Servo] = []
        for sid in ids:
            table = _default_table(sid, self._baud_index, model_number)
            table[ct.ADDR_FIRMWARE_VERSION] = firmware
            table[ct.ADDR_RETURN_DELAY_TIME] = return_delay_time
            self._servos.append(_Servo(table, float(ct.CENTER_TICKS)))
        self._sim_time_s = clock.now()
        self._parser = wire.PacketParser()
        self._last_rx_wall_s = -math.inf
        self._outgoing: list[_Chunk] = []
        self._bus_free_wall_s = -math.inf
        self._host_baud = 0
        self._host_open = False
        self._connected = True
        self._corrupt_any = 0
        self._supply_v = 12.0
        self.instruction_counts: Counter[int] = Counter()
        self._sync_read_log: deque[tuple[int, int, tuple[int, ...]]] = deque(maxlen=SYNC_READ_LOG_SIZE)
        self.crc_errors_from_host = 0

    # -- SimEndpoint -------------------------------------------------------------------------------------------------
    def host_opened(self, baud: int) -> None:
        with self._lock:
            self._require_connected()
            self._host_open = True
            self._host_baud = int(baud)
            self._parser.reset()

    def host_closed(self) -> None:
        with self._lock:
            self._host_open = False
            self._outgoing.clear()
            self._parser.reset()

    def host_write(self, data: bytes, now_s: float) -> None:
        with self._lock:
            self._require_connected()
            if not data:
                return
            if self._parser.pending and now_s - self._last_rx_wall_s > INTER_BYTE_TIMEOUT_S / self._clock.speed:
                self._parser.reset()
            self._last_rx_wall_s = now_s
            byte_s = self._byte_time_s(self._host_baud)
            # The host's bytes occupy the wire after anything still being sent (half duplex).
            end_wall_s = max(now_s, self._bus_free_wall_s) + len(data) * byte_s
            self._bus_free_wall_s = end_wall_s
            for packet in self._parser.feed(bytes(data)):
                self._handle(packet, end_wall_s)

    def host_read(self, now_s: float) -> bytes:
        with self._lock:
            self._require_connected()
            if not self._outgoing:
                return b""
            out = bytearray()
            keep: list[_Chunk] = []
            for chunk in self._outgoing:
                if now_s >= chunk.start_wall_s:
                    arrived = min(len(chunk.data), int((now_s - chunk.start_wall_s) / chunk.byte_s))
                    if arrived > chunk.delivered:
                        out += chunk.data[chunk.delivered : arrived]
                        chunk.delivered = arrived
                if chunk.delivered < len(chunk.data):
                    keep.append(chunk)
            self._outgoing = keep
            return bytes(out)

    @property
    def clock(self) -> SimClock:
        return self._clock

    @property
    def host_baud(self) -> int:
        """The baud rate the host's port runs at (bps); servos at another rate hear only noise."""
        return self._host_baud

    def next_delivery_wall_s(self) -> float | None:
        """Wall time at which the next queued status packet will have fully arrived, or None if none is queued.

        Lets a server that forwards the replies onto a real port (the pty server) sleep until then.
        """
        with self._lock:
            pending = [c.end_wall_s for c in self._outgoing if c.delivered < len(c.data)]
            return min(pending) if pending else None

    # -- Python-side hand and fault injection (any thread) ---------------------------------------------------------
    @property
    def servo_ids(self) -> tuple[int, ...]:
        with self._lock:
            return tuple(s.servo_id for s in self._servos)

    def present_positions_rad(self) -> np.ndarray:
        """Present angles in rad, ``(ticks − 2048)·2π/4096``, in the constructor's ID order (no config signs)."""
        return self.present_positions_at_rad(math.inf)

    def present_positions_at_rad(self, sim_s: float) -> np.ndarray:
        """Present angles in rad at simulated time ``sim_s`` (at most now): the chain advanced to it. Its state only
        moves forward: a time before the chain's own is read at the chain's own."""
        with self._lock:
            self._advance(min(sim_s, self._clock.now()))
            return np.array([(s.position_ticks - ct.CENTER_TICKS) * ct.RAD_PER_TICK for s in self._servos])

    def set_limp_position(self, servo_id: int, ticks: float) -> None:
        """Pose a limp joint by hand (torque off), in ticks 0…4095. Raises ValueError if the servo holds torque."""
        with self._lock:
            servo = self._servo(servo_id)
            self._advance(self._clock.now())
            if servo.torque_on:
                raise ValueError(f"servo {servo_id} has torque on and holds its position; turn torque off to pose it")
            servo.position_ticks = float(min(max(ticks, 0.0), 4095.0))
            servo.velocity_ticks_s = 0.0
            if self._physics is not None:
                joint = self._servos.index(servo)
                self._physics.set_joint_angle(joint, (servo.position_ticks - ct.CENTER_TICKS) * ct.RAD_PER_TICK)

    def release_limp_hold(self, servo_id: int | None = None) -> None:
        """Let go of a joint posed by :meth:`set_limp_position` (default: all). The scripted servos keep a limp joint
        where it was put anyway; in the physics lab the hand held it against gravity until now."""
        with self._lock:
            self._advance(self._clock.now())
            if self._physics is not None:
                joint = None if servo_id is None else self._servos.index(self._servo(servo_id))
                self._physics.release_hand(joint)

    def set_load(self, servo_id: int, torque_nm: float) -> None:
        """External load torque on a joint (N·m); the current follows it, and a large one trips the overload."""
        with self._lock:
            self._advance(self._clock.now())
            if self._physics is not None:
                self._physics.set_external_torque(self._servos.index(self._servo(servo_id)), float(torque_nm))
                return
            self._servo(servo_id).load_nm = float(torque_nm)

    def set_temperature(self, servo_id: int, celsius: float) -> None:
        """Motor temperature (°C) before load heating; above the Temperature Limit (80 °C) it trips overheating."""
        with self._lock:
            self._advance(self._clock.now())
            servo = self._servo(servo_id)
            servo.ambient_c = float(celsius)
            self._check_supply_and_heat(servo)

    def set_supply_voltage(self, volts: float) -> None:
        """The bus supply (V) every servo sees; outside its voltage limits (9.5…16 V) it flags an input-voltage
        error (alert bit; torque stays on, as the default Shutdown setting leaves that bit out)."""
        with self._lock:
            self._advance(self._clock.now())
            self._supply_v = float(volts)
            for servo in self._servos:
                self._check_supply_and_heat(servo)

    def inject_overload(self, servo_id: int) -> None:
        """Trip the overload shutdown now: Hardware Error Status bit 5, torque off, alert bit until reboot."""
        with self._lock:
            self._advance(self._clock.now())
            self._raise_hardware_error(self._servo(servo_id), ct.OVERLOAD_BIT)

    def set_no_reply(self, servo_id: int, silent: bool = True) -> None:
        """Make a servo deaf and mute (as if its cable were cut after the previous servo)."""
        with self._lock:
            self._servo(servo_id).no_reply = silent

    def corrupt_next_replies(self, n: int, servo_id: int | None = None) -> None:
        """Corrupt the CRC of the next ``n`` status packets (from ``servo_id``, or from any servo)."""
        with self._lock:
            if servo_id is None:
                self._corrupt_any += n
            else:
                self._servo(servo_id).corrupt_replies += n

    def disconnect(self) -> None:
        """Pull the cable: host reads and writes raise ``serial.SerialException`` until :meth:`reconnect`."""
        with self._lock:
            self._connected = False
            self._outgoing.clear()
            self._parser.reset()

    def reconnect(self) -> None:
        with self._lock:
            self._connected = True

    def register(self, servo_id: int, name: str) -> int:
        """A control-table item's current value, by its e-manual name (for tests and the GUI's sim hooks)."""
        with self._lock:
            self._advance(self._clock.now())
            servo = self._servo(servo_id)
            self._refresh_present(servo)
            return servo.get(_ITEM[name])

    def goal_positions_ticks(self) -> np.ndarray:
        with self._lock:
            return np.array([s.get(_ITEM["Goal Position"]) for s in self._servos])

    def sync_reads(self) -> list[tuple[int, int, tuple[int, ...]]]:
        """(start address, data length, IDs asked) of the latest sync reads received (up to
        ``SYNC_READ_LOG_SIZE``), oldest first: which items a driver polls, and how many servos at a time."""
        with self._lock:
            return list(self._sync_read_log)

    def count(self, instruction: int) -> int:
        """How many packets with this instruction code the chain has received intact (e.g. ``dxl_wire.SYNC_WRITE``)."""
        with self._lock:
            return self.instruction_counts[instruction]

    # -- internals ---------------------------------------------------------------------------------------------------
    def _require_connected(self) -> None:
        if not self._connected:
            raise serial.SerialException("simulated servo bus disconnected (cable pulled)")

    def _servo(self, servo_id: int) -> _Servo:
        for servo in self._servos:
            if servo.servo_id == servo_id:
                return servo
        raise KeyError(f"the simulated chain has no servo {servo_id} (IDs: {list(self.servo_ids)})")

    def _byte_time_s(self, baud: int) -> float:
        return BITS_PER_BYTE / max(baud, 1) / self._clock.speed

    def _listening(self, servo: _Servo, sim_s: float) -> bool:
        return (not servo.no_reply and servo.baud_bps == self._host_baud and sim_s >= servo.booting_until_s)

    def _handle(self, packet: wire.Packet | wire.CorruptPacket, end_wall_s: float) -> None:
        sim_s = self._clock.sim_from_wall(end_wall_s)
        self._advance(sim_s)
        if isinstance(packet, wire.CorruptPacket):
            self.crc_errors_from_host += 1
            if packet.servo_id != wire.BROADCAST_ID:
                for servo in self._servos:
                    if servo.servo_id == packet.servo_id and self._listening(servo, sim_s):
                        self._reply(servo, ct.ERRNUM_CRC, b"", end_wall_s)
            return
        if packet.instruction == wire.STATUS:
            return  # another device's status packet on the bus
        self.instruction_counts[packet.instruction] += 1
        handler = _HANDLERS.get(packet.instruction)
        listeners = [s for s in self._servos if self._listening(s, sim_s)]
        if handler is None:
            for servo in listeners:
                if servo.servo_id == packet.servo_id:
                    self._reply(servo, ct.ERRNUM_INSTRUCTION, b"", end_wall_s)
            return
        handler(self, packet, listeners, end_wall_s, sim_s)

    def _reply(self, servo: _Servo, errnum: int, data: bytes, after_wall_s: float, *, always: bool = False,
               read: bool = False) -> float:
        """Queue a status packet; returns the wall time its last byte leaves the servo."""
        level = servo.table[ct.ADDR_STATUS_RETURN_LEVEL]
        if not always and not (level >= 2 or (read and level >= 1)):
            return after_wall_s
        error = errnum | (ct.ERROR_ALERT_BIT if servo.hardware_error else 0)
        packet = wire.build_status(servo.servo_id, error, data)
        if servo.corrupt_replies > 0 or self._corrupt_any > 0:
            if servo.corrupt_replies > 0:
                servo.corrupt_replies -= 1
            else:
                self._corrupt_any -= 1
            packet = packet[:-2] + bytes([packet[-2] ^ 0x5A, packet[-1]])
        delay_s = servo.table[ct.ADDR_RETURN_DELAY_TIME] * ct.RETURN_DELAY_S_PER_LSB / self._clock.speed
        byte_s = self._byte_time_s(servo.baud_bps)
        start = max(after_wall_s + delay_s, self._bus_free_wall_s)
        chunk = _Chunk(start, byte_s, packet)
        self._outgoing.append(chunk)
        self._bus_free_wall_s = chunk.end_wall_s
        servo.counters["replies"] += 1
        return chunk.end_wall_s

    # instruction handlers -----------------------------------------------------------------------------------------
    def _on_ping(self, packet, listeners, end_wall_s, sim_s) -> None:
        after = end_wall_s
        for servo in sorted(listeners, key=lambda s: s.servo_id):
            if packet.servo_id in (servo.servo_id, wire.BROADCAST_ID):
                info = servo.table[0:2] + bytes([servo.table[ct.ADDR_FIRMWARE_VERSION]])
                # Broadcast replies follow each other in ID order, each after its own return delay.
                after = self._reply(servo, 0, bytes(info), after, always=True)

    def _on_read(self, packet, listeners, end_wall_s, sim_s) -> None:
        for servo in listeners:
            if servo.servo_id == packet.servo_id:
                if len(packet.params) != 4:
                    self._reply(servo, ct.ERRNUM_DATA_LENGTH, b"", end_wall_s, read=True)
                    return
                address, length = _u16(packet.params, 0), _u16(packet.params, 2)
                errnum, data = self._read(servo, address, length)
                self._reply(servo, errnum, data, end_wall_s, read=True)

    def _on_write(self, packet, listeners, end_wall_s, sim_s, *, registered: bool = False) -> None:
        for servo in listeners:
            if packet.servo_id not in (servo.servo_id, wire.BROADCAST_ID):
                continue
            if len(packet.params) < 3:
                errnum = ct.ERRNUM_DATA_LENGTH
                apply = None
            else:
                address, data = _u16(packet.params, 0), packet.params[2:]
                errnum, apply = self._check_write(servo, address, data)
                if registered and apply is not None:
                    servo.registered = (address, bytes(data))
                    servo.table[69] = 1
                    apply = None
            if packet.servo_id != wire.BROADCAST_ID:
                self._reply(servo, errnum, b"", end_wall_s)
            if apply is not None:
                apply()

    def _on_reg_write(self, packet, listeners, end_wall_s, sim_s) -> None:
        self._on_write(packet, listeners, end_wall_s, sim_s, registered=True)

    def _on_action(self, packet, listeners, end_wall_s, sim_s) -> None:
        for servo in listeners:
            if packet.servo_id in (servo.servo_id, wire.BROADCAST_ID):
                if servo.registered is not None:
                    errnum, apply = self._check_write(servo, *servo.registered)
                    servo.registered = None
                    servo.table[69] = 0
                    if apply is not None:
                        apply()
                if packet.servo_id != wire.BROADCAST_ID:
                    self._reply(servo, 0, b"", end_wall_s)

    def _on_reboot(self, packet, listeners, end_wall_s, sim_s) -> None:
        for servo in listeners:
            if packet.servo_id in (servo.servo_id, wire.BROADCAST_ID):
                if packet.servo_id != wire.BROADCAST_ID:
                    self._reply(servo, 0, b"", end_wall_s)
                self._reboot(servo, sim_s)

    def _on_factory_reset(self, packet, listeners, end_wall_s, sim_s) -> None:
        option = packet.params[0] if packet.params else 0xFF
        for servo in listeners:
            if packet.servo_id != servo.servo_id:
                continue  # a real servo refuses a broadcast factory reset
            if servo.torque_on:
                self._reply(servo, ct.ERRNUM_ACCESS, b"", end_wall_s)
                continue
            self._reply(servo, 0, b"", end_wall_s)
            keep_id, keep_baud = servo.table[ct.ADDR_ID], servo.table[ct.ADDR_BAUD_RATE]
            firmware = servo.table[ct.ADDR_FIRMWARE_VERSION]
            servo.table[:] = _default_table(1, 1, self._model_number)
            servo.table[ct.ADDR_FIRMWARE_VERSION] = firmware
            if option in (0x01, 0x02):
                servo.table[ct.ADDR_ID] = keep_id
            if option == 0x02:
                servo.table[ct.ADDR_BAUD_RATE] = keep_baud
            servo.booting_until_s = sim_s + BOOT_TIME_S

    def _on_clear(self, packet, listeners, end_wall_s, sim_s) -> None:
        for servo in listeners:
            if servo.servo_id == packet.servo_id:
                self._reply(servo, 0, b"", end_wall_s)

    def _on_sync_read(self, packet, listeners, end_wall_s, sim_s) -> None:
        if packet.servo_id != wire.BROADCAST_ID or len(packet.params) < 5:
            return
        address, length = _u16(packet.params, 0), _u16(packet.params, 2)
        self._sync_read_log.append((address, length, tuple(packet.params[4:])))
        by_id = {s.servo_id: s for s in listeners}
        after = end_wall_s
        for sid in packet.params[4:]:
            servo = by_id.get(sid)
            if servo is not None:
                errnum, data = self._read(servo, address, length)
                after = self._reply(servo, errnum, data, after, read=True)

    def _on_sync_write(self, packet, listeners, end_wall_s, sim_s) -> None:
        if packet.servo_id != wire.BROADCAST_ID or len(packet.params) < 4:
            return
        address, length = _u16(packet.params, 0), _u16(packet.params, 2)
        by_id = {s.servo_id: s for s in listeners}
        body = packet.params[4:]
        step = 1 + length
        for i in range(0, len(body) - step + 1, step):
            servo = by_id.get(body[i])
            if servo is not None:
                _, apply = self._check_write(servo, address, body[i + 1 : i + step])
                if apply is not None:
                    apply()

    def _on_bulk_read(self, packet, listeners, end_wall_s, sim_s) -> None:
        if packet.servo_id != wire.BROADCAST_ID:
            return
        by_id = {s.servo_id: s for s in listeners}
        after = end_wall_s
        body = packet.params
        for i in range(0, len(body) - 4, 5):
            servo = by_id.get(body[i])
            if servo is not None:
                errnum, data = self._read(servo, _u16(body, i + 1), _u16(body, i + 3))
                after = self._reply(servo, errnum, data, after, read=True)

    def _on_bulk_write(self, packet, listeners, end_wall_s, sim_s) -> None:
        if packet.servo_id != wire.BROADCAST_ID:
            return
        by_id = {s.servo_id: s for s in listeners}
        body = packet.params
        i = 0
        while i + 5 <= len(body):
            sid, address, length = body[i], _u16(body, i + 1), _u16(body, i + 3)
            data = body[i + 5 : i + 5 + length]
            i += 5 + length
            servo = by_id.get(sid)
            if servo is not None and len(data) == length:
                _, apply = self._check_write(servo, address, data)
                if apply is not None:
                    apply()

    # control table ------------------------------------------------------------------------------------------------
    def _read(self, servo: _Servo, address: int, length: int) -> tuple[int, bytes]:
        if length == 0:
            return ct.ERRNUM_DATA_LENGTH, b""
        if address + length > ct.CONTROL_TABLE_SIZE:
            return ct.ERRNUM_DATA_RANGE, b""
        self._refresh_present(servo)
        return 0, bytes(servo.table[address : address + length])

    def _check_write(self, servo: _Servo, address: int, data: bytes):
        """Validate a write as the servo firmware does; returns (error number, callable applying it or None)."""
        end = address + len(data)
        if not data or end > ct.CONTROL_TABLE_SIZE:
            return ct.ERRNUM_DATA_RANGE, None
        updates: list[tuple[ct.Item, int]] = []
        a = address
        while a < end:
            item = ct.ITEMS_BY_ADDRESS.get(a)
            if item is None:
                inside = any(i.address < a < i.address + i.size for i in ct.XM430_W350_ITEMS)
                return (ct.ERRNUM_DATA_LENGTH if inside else ct.ERRNUM_ACCESS), None
            if a + item.size > end:
                return ct.ERRNUM_DATA_LENGTH, None
            if not item.writable:
                return ct.ERRNUM_ACCESS, None
            if item.eeprom and servo.torque_on:
                return ct.ERRNUM_ACCESS, None
            value = int.from_bytes(data[a - address : a - address + item.size], "little", signed=item.signed)
            if not item.minimum <= value <= item.maximum:
                return ct.ERRNUM_DATA_RANGE, None
            updates.append((item, value))
            a += item.size
        for item, value in updates:
            if item.name == "Goal Position":
                low, high = servo.get(_ITEM["Min Position Limit"]), servo.get(_ITEM["Max Position Limit"])
                if not low <= value <= high:
                    return ct.ERRNUM_DATA_LIMIT, None
            if item.name == "Torque Enable" and value == 1 and servo.hardware_error:
                return ct.ERRNUM_RESULT_FAIL, None
            if item.name == "ID" and value != servo.servo_id and value in self.servo_ids:
                return ct.ERRNUM_DATA_RANGE, None

        def apply() -> None:
            for item, value in updates:
                if item.name == "Torque Enable" and value == 1 and not servo.torque_on:
                    # The firmware sets Goal Position to Present Position on torque-on, so the joint does not jump.
                    servo.put(_ITEM["Goal Position"], int(round(servo.position_ticks)))
                    servo.velocity_ticks_s = 0.0
                servo.put(item, value)

        return 0, apply

    def _refresh_present(self, servo: _Servo) -> None:
        table = servo.table
        torque_on = bool(table[ct.ADDR_TORQUE_ENABLE])
        position = int(round(servo.position_ticks)) + (self._noise(self._position_noise, 1) if torque_on else 0)
        velocity = int(round(servo.velocity_ticks_s * ct.RAD_PER_TICK / ct.RAD_S_PER_VELOCITY_LSB))
        if torque_on:
            inertia_nm = 0.002 * servo.last_accel_ticks_s2 * ct.RAD_PER_TICK
            current_ma = (servo.load_nm + inertia_nm) / TORQUE_CONSTANT_NM_PER_A * 1000.0
            current = int(round(current_ma / ct.CURRENT_MA_PER_LSB)) + self._noise(self._current_noise, 2)
            current = max(-1193, min(1193, current))
        else:
            current = 0
        goal = _I32.unpack_from(table, ct.ADDR_GOAL_POSITION)[0]
        threshold = _U32.unpack_from(table, _ADDR_MOVING_THRESHOLD)[0]
        moving = torque_on and (velocity != 0 or abs(goal - position) > threshold)
        _PRESENT_STATE.pack_into(table, ct.ADDR_PRESENT_CURRENT, current, velocity, position)
        _TICK_AND_MOVING.pack_into(table, _ADDR_REALTIME_TICK, int(self._sim_time_s * 1000) % 32768, int(moving))
        _SUPPLY.pack_into(table, ct.ADDR_PRESENT_INPUT_VOLTAGE, int(round(self._supply_v / ct.VOLTAGE_V_PER_LSB)),
                          self._temperature_c(servo, current))

    def _noise(self, buffer: list[int], amplitude: int) -> int:
        """One uniform integer in −amplitude…amplitude from ``buffer`` (refilled from the seeded generator)."""
        if not buffer:
            buffer.extend(self._rng.integers(-amplitude, amplitude + 1, NOISE_BATCH).tolist())
        return buffer.pop()

    def _temperature_c(self, servo: _Servo, current_lsb: int) -> int:
        return int(round(servo.ambient_c + min(abs(current_lsb) * ct.CURRENT_MA_PER_LSB / 200.0, 40.0)))

    def _check_supply_and_heat(self, servo: _Servo) -> None:
        voltage = self._supply_v / ct.VOLTAGE_V_PER_LSB
        if not servo.get(_ITEM["Min Voltage Limit"]) <= voltage <= servo.get(_ITEM["Max Voltage Limit"]):
            self._raise_hardware_error(servo, 0)
        if self._temperature_c(servo, 0) > servo.get(_ITEM["Temperature Limit"]):
            self._raise_hardware_error(servo, 2)

    def _raise_hardware_error(self, servo: _Servo, bit: int) -> None:
        servo.table[ct.ADDR_HARDWARE_ERROR_STATUS] |= 1 << bit
        if servo.get(_ITEM["Shutdown"]) & (1 << bit):
            servo.table[ct.ADDR_TORQUE_ENABLE] = 0
            servo.velocity_ticks_s = 0.0

    def _reboot(self, servo: _Servo, sim_s: float) -> None:
        defaults = _default_table(servo.servo_id, servo.table[ct.ADDR_BAUD_RATE], self._model_number)
        # RAM (64 and up) returns to its defaults; EEPROM is kept.
        servo.table[ct.EEPROM_END :] = defaults[ct.EEPROM_END :]
        servo.velocity_ticks_s = 0.0
        servo.overload_time_s = 0.0
        servo.registered = None
        servo.booting_until_s = sim_s + BOOT_TIME_S
        self._check_supply_and_heat(servo)  # a cause that is still there trips the error again

    # physics ------------------------------------------------------------------------------------------------------
    def _advance(self, sim_s: float) -> None:
        dt_total = sim_s - self._sim_time_s
        if dt_total <= 0:
            return
        if self._physics is not None:
            self._sim_time_s = sim_s
            self._advance_physics(sim_s)
            return
        self._sim_time_s = sim_s
        steps = max(1, min(2000, int(math.ceil(dt_total / PHYSICS_STEP_S))))
        dt = dt_total / steps
        for servo in self._servos:
            if not servo.torque_on:
                servo.velocity_ticks_s = 0.0
                servo.last_accel_ticks_s2 = 0.0
                continue
            self._step_servo(servo, dt, steps)

    def _advance_physics(self, sim_s: float) -> None:
        assert self._physics is not None
        on = np.array([servo.torque_on for servo in self._servos])
        goal = np.array([(_I32.unpack_from(s.table, ct.ADDR_GOAL_POSITION)[0] - ct.CENTER_TICKS) * ct.RAD_PER_TICK
                         for s in self._servos])
        speed = np.empty(len(self._servos))
        for j, servo in enumerate(self._servos):
            limit = _U32.unpack_from(servo.table, ct.ADDR_VELOCITY_LIMIT)[0]
            profile = _MOTION_PROFILE.unpack_from(servo.table, ct.ADDR_PROFILE_ACCELERATION)[1]
            speed[j] = (min(profile, limit) if profile > 0 else limit) * ct.RAD_S_PER_VELOCITY_LSB
        self._physics.command(on, goal, speed)
        self._physics.advance_to(sim_s)
        state = self._physics.joint_state()
        if state is self._physics_state:  # the world rests: the same state as last time, nothing to copy
            return
        self._physics_state = state
        for j, servo in enumerate(self._servos):
            servo.position_ticks = min(max(ct.CENTER_TICKS + float(state.position_rad[j]) / ct.RAD_PER_TICK, 0.0),
                                       4095.0)
            servo.velocity_ticks_s = float(state.velocity_rad_s[j]) / ct.RAD_PER_TICK
            servo.load_nm = float(state.torque_nm[j])  # the current follows the motor's torque
            servo.last_accel_ticks_s2 = 0.0
            if servo.torque_on and state.saturated_s[j] >= OVERLOAD_AFTER_S:
                self._raise_hardware_error(servo, ct.OVERLOAD_BIT)

    def _step_servo(self, servo: _Servo, dt: float, steps: int) -> None:
        table = servo.table
        goal = float(_I32.unpack_from(table, ct.ADDR_GOAL_POSITION)[0])
        pos, vel = servo.position_ticks, servo.velocity_ticks_s
        # A load beyond the motor's strength stalls the joint; held long enough it trips the overload shutdown.
        stalled = abs(servo.load_nm) >= OVERLOAD_TORQUE_NM
        if not stalled and vel == 0.0 and pos == goal:
            servo.overload_time_s = 0.0
            servo.last_accel_ticks_s2 = 0.0
            return  # holding still at the goal: nothing to integrate
        limit = _U32.unpack_from(table, ct.ADDR_VELOCITY_LIMIT)[0]
        acc_lsb, profile = _MOTION_PROFILE.unpack_from(table, ct.ADDR_PROFILE_ACCELERATION)
        v_lsb = min(profile, limit) if profile > 0 else limit
        vmax = v_lsb * ct.RAD_S_PER_VELOCITY_LSB / ct.RAD_PER_TICK
        acc_rad = acc_lsb * ct.RAD_S2_PER_ACCELERATION_LSB if acc_lsb > 0 else MAX_ACCELERATION_RAD_S2
        amax = min(acc_rad, MAX_ACCELERATION_RAD_S2) / ct.RAD_PER_TICK
        for _ in range(steps):
            if stalled:
                vel = 0.0
                servo.overload_time_s += dt
                if servo.overload_time_s >= OVERLOAD_AFTER_S:
                    servo.position_ticks, servo.velocity_ticks_s = pos, 0.0
                    self._raise_hardware_error(servo, ct.OVERLOAD_BIT)
                    return
                continue
            error = goal - pos
            # Time-optimal approach: the fastest speed from which the joint can still stop at the goal.
            # The |error|/dt term lands the last step exactly on the goal instead of dithering around it.
            v_target = math.copysign(min(vmax, math.sqrt(2.0 * amax * abs(error)), abs(error) / dt), error)
            dv = max(-amax * dt, min(amax * dt, v_target - vel))
            vel += dv
            servo.last_accel_ticks_s2 = dv / dt
            pos += vel * dt
            if abs(goal - pos) < 0.05 and abs(vel) <= amax * dt:
                pos, vel = goal, 0.0
        if not stalled:
            servo.overload_time_s = 0.0
        servo.position_ticks = min(max(pos, 0.0), 4095.0)
        servo.velocity_ticks_s = vel


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)




class ChainLab:
    """A simulated lab holding only a servo chain: what ``devices.factory.install_sim_lab`` needs for ``robot``/``rig``.

    Used by the pty server and by driver tests that do not need the board or the rig.
    """

    def __init__(self, chain: VirtualChain) -> None:
        self.chain = chain
        self.clock = chain.clock

    def endpoint(self, device: str) -> VirtualChain:
        if device in ("robot", "rig"):
            return self.chain
        raise ValueError(f"this simulated lab only has a servo chain, not a {device!r}")


# The class's own dispatch table, defined beside it: its handlers are private to it and to this module.
_HANDLERS = {
    wire.PING: VirtualChain._on_ping,  # noqa: SLF001
    wire.READ: VirtualChain._on_read,  # noqa: SLF001
    wire.WRITE: VirtualChain._on_write,  # noqa: SLF001
    wire.REG_WRITE: VirtualChain._on_reg_write,  # noqa: SLF001
    wire.ACTION: VirtualChain._on_action,  # noqa: SLF001
    wire.REBOOT: VirtualChain._on_reboot,  # noqa: SLF001
    wire.FACTORY_RESET: VirtualChain._on_factory_reset,  # noqa: SLF001
    wire.CLEAR: VirtualChain._on_clear,  # noqa: SLF001
    wire.SYNC_READ: VirtualChain._on_sync_read,  # noqa: SLF001
    wire.SYNC_WRITE: VirtualChain._on_sync_write,  # noqa: SLF001
    wire.BULK_READ: VirtualChain._on_bulk_read,  # noqa: SLF001
    wire.BULK_WRITE: VirtualChain._on_bulk_write,  # noqa: SLF001
}
