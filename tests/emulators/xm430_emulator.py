"""An independent emulator of a chain of Dynamixel XM430-W350 servos on one Protocol 2.0 bus, served on a
pseudo-terminal by its own process.

Written from the ROBOTIS Protocol 2.0 description and the XM430-W350 e-manual, NOT from this project's driver or
simulator: it imports nothing from ``devices`` (its own CRC, byte stuffing, packet parser and control table), so a
test that passes between the driver and this emulator says something about both.

    python -m tests.emulators.xm430_emulator [--ids 1-12] [--baud 1000000] [--return-delay 250]

(``--ids 1,1,3-12``: two servos set to ID 1, none to 2; their status packets collide on the wire, see ``collide``.)

The first line on stdout is the slave path to open (e.g. ``/dev/pts/7``). Then one command per line on stdin, one
answer line on stdout (``ok …`` or ``error …``); the process ends when stdin closes. Commands (the fault side
channel):

- ``state ID`` → ``ok torque=1 position=2048 goal=2048 hw_error=0 rdt=250 goal_writes=3``
- ``count`` → ``ok ping=… read=… write=… sync_read=… sync_write=… bulk_read=… bulk_write=… reboot=… reset=…``
- ``reboot ID [OFF_S] [JUMP_TICKS]``: the servo power-cycles: silent for ``OFF_S`` (default 0.05 s), back with torque
  off, RAM at its defaults (goal = present), hardware error cleared and its present position moved by
  ``JUMP_TICKS`` (default 700 ≈ 1.07 rad: the limp joint sagged).
- ``overload ID``: Hardware Error Status gets its overload bit; torque goes off (the default Shutdown, 52, includes
  overload); every status packet of that servo carries the alert bit until it is rebooted.
- ``silent ID`` / ``answer ID``: the servo stops / resumes answering (``all``: every servo at once, as when the bus
  loses power).
- ``push ID TICKS``: an external force moves the joint by TICKS (torque on: it returns towards its goal).
- ``stall SECONDS [ADDRESS [COUNT]]``: the replies to the next instruction start SECONDS late (the far end was
  descheduled once); with ``ADDRESS``, the replies to the next ``COUNT`` (default 1) reads (READ or SYNC READ) starting
  at that control-table address instead (e.g. 64, the host's health block), whatever comes between.
- ``hold SECONDS``: every reply made in the next SECONDS is held back and written at the end, all at once: what the
  host sees when its own kernel holds a port's received bytes (a tty worker waiting behind other programs); the
  servos answer on time meanwhile.
- ``kill``: close the pseudo-terminal (the host's next I/O fails, as when a USB adapter is pulled) and exit.

Wire timing: every instruction occupies the wire for its bytes at the configured baud (10 bits per byte); each
status packet starts Return Delay Time (2 µs per unit, factory 250 = 500 µs) after the end of the instruction or of
the previous servo's status packet (sync/bulk read), and is written to the pty whole when its last byte would have
arrived. Bytes sent at another baud rate (the slave's termios speed) are not understood, as on a real bus: each servo
listens at its own Baud Rate item, so a servo whose rate was changed answers only when the host switches to it (it
answers the write that changed it at the old rate, then listens at the new one — an assumption: the e-manual does not
say at which rate that status packet goes).

Motion: torque on drives to whatever Goal Position holds (it is set to the present position only at power-on); with
torque on, the present position moves towards the goal at up to the no-load speed (or Profile
Velocity where set); present velocity and current follow from it. Linux and macOS (``os.openpty``).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import select
import sys
import termios
import time
import tty
from dataclasses import dataclass, field

# -- Protocol 2.0 wire format (ROBOTIS e-manual, "Protocol 2.0") ---------------------------------------------------
HEADER = b"\xff\xff\xfd\x00"
BROADCAST = 0xFE
INST_PING, INST_READ, INST_WRITE, INST_REG_WRITE, INST_ACTION = 0x01, 0x02, 0x03, 0x04, 0x05
INST_FACTORY_RESET, INST_REBOOT, INST_CLEAR, INST_STATUS = 0x06, 0x08, 0x10, 0x55
INST_SYNC_READ, INST_SYNC_WRITE, INST_BULK_READ, INST_BULK_WRITE = 0x82, 0x83, 0x92, 0x93
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE, ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = range(1, 8)
ALERT = 0x80
COUNTED = {INST_PING: "ping", INST_READ: "read", INST_WRITE: "write", INST_SYNC_READ: "sync_read",
           INST_SYNC_WRITE: "sync_write", INST_BULK_READ: "bulk_read", INST_BULK_WRITE: "bulk_write",
           INST_REBOOT: "reboot", INST_FACTORY_RESET: "reset"}


def _crc_table() -> list[int]:
    # CRC-16 as given in the Protocol 2.0 page: polynomial x16 + x15 + x2 + 1 (0x8005), initial 0, MSB first.
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x8005) & 0xFFFF if c & 0x8000 else (c << 1) & 0xFFFF
        table.append(c)
    return table


_CRC = _crc_table()


def crc16(data: bytes) -> int:
    acc = 0
    for b in data:
        acc = ((acc << 8) ^ _CRC[((acc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return acc


def add_stuffing(body: bytes) -> bytes:
    """Protocol 2.0 byte stuffing: 0xFD is added after every FF FF FD inside instruction + parameters."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3:-1] == b"\xff\xff":
            out.append(0xFD)
    return bytes(out)


def remove_stuffing(body: bytes) -> bytes:
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and i >= 2 and body[i - 2:i] == b"\xff\xff" and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1  # skip the stuffing byte
        i += 1
    return bytes(out)


def packet(dev_id: int, instruction: int, params: bytes) -> bytes:
    body = add_stuffing(bytes([instruction]) + params)
    length = len(body) + 2
    head = HEADER + bytes([dev_id, length & 0xFF, length >> 8]) + body
    crc = crc16(head)
    return head + bytes([crc & 0xFF, crc >> 8])


def status_packet(dev_id: int, error: int, data: bytes = b"") -> bytes:
    return packet(dev_id, INST_STATUS, bytes([error]) + data)


# -- XM430-W350 control table (e-manual, "Control Table of EEPROM/RAM Area") ------------------------------------------
@dataclass(frozen=True)
class Entry:
    address: int
    size: int
    access: str  # "R" or "RW"
    default: int
    low: int = 0
    high: int = 0


TABLE = {
    "model_number": Entry(0, 2, "R", 1020), "model_information": Entry(2, 4, "R", 0),
    "firmware_version": Entry(6, 1, "R", 48), "id": Entry(7, 1, "RW", 1, 0, 252),
    "baud_rate": Entry(8, 1, "RW", 1, 0, 7), "return_delay_time": Entry(9, 1, "RW", 250, 0, 254),
    "drive_mode": Entry(10, 1, "RW", 0, 0, 13), "operating_mode": Entry(11, 1, "RW", 3, 0, 16),
    "secondary_id": Entry(12, 1, "RW", 255, 0, 255), "protocol_type": Entry(13, 1, "RW", 2, 1, 2),
    "homing_offset": Entry(20, 4, "RW", 0, -1044479, 1044479), "moving_threshold": Entry(24, 4, "RW", 10, 0, 1023),
    "temperature_limit": Entry(31, 1, "RW", 80, 0, 100), "max_voltage_limit": Entry(32, 2, "RW", 160, 95, 160),
    "min_voltage_limit": Entry(34, 2, "RW", 95, 95, 160), "pwm_limit": Entry(36, 2, "RW", 885, 0, 885),
    "current_limit": Entry(38, 2, "RW", 1193, 0, 1193), "acceleration_limit": Entry(40, 4, "RW", 32767, 0, 32767),
    "velocity_limit": Entry(44, 4, "RW", 200, 0, 1023), "max_position_limit": Entry(48, 4, "RW", 4095, 0, 4095),
    "min_position_limit": Entry(52, 4, "RW", 0, 0, 4095), "startup_configuration": Entry(60, 1, "RW", 0, 0, 3),
    "shutdown": Entry(63, 1, "RW", 52, 0, 255),
    "torque_enable": Entry(64, 1, "RW", 0, 0, 1), "led": Entry(65, 1, "RW", 0, 0, 1),
    "status_return_level": Entry(68, 1, "RW", 2, 0, 2), "registered_instruction": Entry(69, 1, "R", 0),
    "hardware_error_status": Entry(70, 1, "R", 0), "velocity_i_gain": Entry(76, 2, "RW", 1920, 0, 16383),
    "velocity_p_gain": Entry(78, 2, "RW", 100, 0, 16383), "position_d_gain": Entry(80, 2, "RW", 0, 0, 16383),
    "position_i_gain": Entry(82, 2, "RW", 0, 0, 16383), "position_p_gain": Entry(84, 2, "RW", 800, 0, 16383),
    "feedforward_2nd_gain": Entry(88, 2, "RW", 0, 0, 16383), "feedforward_1st_gain": Entry(90, 2, "RW", 0, 0, 16383),
    "bus_watchdog": Entry(98, 1, "RW", 0, 0, 127), "goal_pwm": Entry(100, 2, "RW", 0, -885, 885),
    "goal_current": Entry(102, 2, "RW", 0, -1193, 1193), "goal_velocity": Entry(104, 4, "RW", 0, -1023, 1023),
    "profile_acceleration": Entry(108, 4, "RW", 0, 0, 32767), "profile_velocity": Entry(112, 4, "RW", 0, 0, 32767),
    "goal_position": Entry(116, 4, "RW", 2048, -1048575, 1048575), "realtime_tick": Entry(120, 2, "R", 0),
    "moving": Entry(122, 1, "R", 0), "moving_status": Entry(123, 1, "R", 0), "present_pwm": Entry(124, 2, "R", 0),
    "present_current": Entry(126, 2, "R", 0), "present_velocity": Entry(128, 4, "R", 0),
    "present_position": Entry(132, 4, "R", 2048), "velocity_trajectory": Entry(136, 4, "R", 0),
    "position_trajectory": Entry(140, 4, "R", 0), "present_input_voltage": Entry(144, 2, "R", 120),
    "present_temperature": Entry(146, 1, "R", 31), "backup_ready": Entry(147, 1, "R", 0),
}
BY_ADDRESS = {e.address: (name, e) for name, e in TABLE.items()}
TABLE_END = 148
EEPROM_END = 64
BAUD_BPS = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000, 7: 4_500_000}
OVERLOAD_BIT = 0x20
NO_LOAD_SPEED_RPM = 46.0  # XM430-W350 at 12 V
RPM_PER_VELOCITY_UNIT = 0.229
TICKS_PER_REV = 4096
MA_PER_CURRENT_UNIT = 2.69


@dataclass
class Servo:
    dev_id: int
    baud_index: int
    return_delay: int
    mem: bytearray = field(default_factory=lambda: bytearray(TABLE_END))
    position: float = 2048.0  # ticks (float: the motor moves continuously)
    velocity_tps: float = 0.0  # ticks per second
    boot_s: float = 0.0
    last_update_s: float = 0.0
    silent_until_s: float = 0.0
    silent: bool = False
    goal_writes: int = 0

    def __post_init__(self) -> None:
        self.factory_reset(keep_id=False, keep_baud=False)
        self.set("id", self.dev_id)
        self.set("baud_rate", self.baud_index)
        self.set("return_delay_time", self.return_delay)
        self.power_on(time.monotonic())

    # raw control-table access
    def get(self, name: str) -> int:
        e = TABLE[name]
        return int.from_bytes(self.mem[e.address:e.address + e.size], "little", signed=e.low < 0)

    def set(self, name: str, value: int) -> None:
        e = TABLE[name]
        self.mem[e.address:e.address + e.size] = int(value).to_bytes(e.size, "little", signed=value < 0)

    def factory_reset(self, keep_id: bool, keep_baud: bool) -> None:
        dev_id, baud = self.get("id") if keep_id else 1, self.get("baud_rate") if keep_baud else 1
        for name, e in TABLE.items():
            if e.address < EEPROM_END or e.access == "R":
                self.set(name, e.default)
        self.set("id", dev_id)
        self.set("baud_rate", baud)

    def power_on(self, now: float) -> None:
        """RAM back to its defaults (torque off, hardware error cleared); goal = present position."""
        for name, e in TABLE.items():
            if e.address >= EEPROM_END and e.access == "RW":
                self.set(name, e.default)
        self.set("hardware_error_status", 0)
        self.boot_s = now
        self.last_update_s = now
        self.velocity_tps = 0.0
        self.set("goal_position", round(self.position))

    @property
    def torque(self) -> bool:
        return bool(self.mem[TABLE["torque_enable"].address])

    def update(self, now: float) -> None:
        """Advance the motor to ``now``: towards the goal at up to the speed limit while torque is on."""
        dt = max(0.0, now - self.last_update_s)
        self.last_update_s = now
        if not self.torque or dt == 0.0:
            self.velocity_tps = 0.0
        else:
            profile = self.get("profile_velocity")
            rpm = profile * RPM_PER_VELOCITY_UNIT if profile else NO_LOAD_SPEED_RPM
            max_step = rpm / 60.0 * TICKS_PER_REV * dt
            error = self.get("goal_position") - self.position
            step = max(-max_step, min(max_step, error))
            self.position += step
            self.velocity_tps = step / dt
        velocity_units = round(self.velocity_tps / TICKS_PER_REV * 60.0 / RPM_PER_VELOCITY_UNIT)
        overloaded = self.get("hardware_error_status") & OVERLOAD_BIT
        current_units = 0 if not self.torque else round(30 + abs(velocity_units) * 0.5)
        self.set("present_position", round(self.position))
        self.set("present_velocity", velocity_units)
        self.set("present_current", 1193 if overloaded else current_units)
        self.set("moving", int(abs(velocity_units) > self.get("moving_threshold")))
        self.set("realtime_tick", int((now - self.boot_s) * 1000) % 32768)

    def status_error(self, errnum: int = 0) -> int:
        return errnum | (ALERT if self.get("hardware_error_status") else 0)

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        if length < 1 or address + length > TABLE_END:
            return ERR_DATA_RANGE, b""
        return 0, bytes(self.mem[address:address + length])

    def write(self, address: int, data: bytes) -> int:
        """Apply a write (all or nothing); the Protocol 2.0 error number (0 = accepted)."""
        end = address + len(data)
        if not data or end > TABLE_END:
            return ERR_DATA_RANGE
        touched = []
        a = address
        while a < end:
            if a not in BY_ADDRESS:
                return ERR_ACCESS  # a reserved address
            name, e = BY_ADDRESS[a]
            if e.access == "R":
                return ERR_ACCESS
            if e.address < EEPROM_END and self.torque:
                return ERR_ACCESS  # EEPROM is locked while torque is on
            if a + e.size > end:
                return ERR_DATA_LENGTH
            value = int.from_bytes(data[a - address:a - address + e.size], "little", signed=e.low < 0)
            if not e.low <= value <= e.high:
                return ERR_DATA_LIMIT
            touched.append((name, value))
            a += e.size
        for name, value in touched:
            if name == "goal_position":
                low, high = self.get("min_position_limit"), self.get("max_position_limit")
                if self.get("operating_mode") == 3 and not low <= value <= high:
                    return ERR_DATA_LIMIT
        for name, value in touched:
            if name == "torque_enable" and value == 1 and self.get("hardware_error_status"):
                continue  # a servo in error keeps its torque off until rebooted (the alert bit says why)
            # Torque on drives to whatever Goal Position holds (written while limp, or left from before): the
            # conservative reading of the e-manual; a host must set the goal to the present position first.
            if name == "goal_position":
                self.goal_writes += 1
            self.set(name, value)
        return 0


TWIN_SKEW_BITS = 3  # how far (bit times) a duplicate ID's status packet lags its twin's: a few µs at 1 Mbps


def _bits(data: bytes) -> list[int]:
    """A UART line's levels for ``data``: start bit 0, 8 data bits LSB first, stop bit 1, per byte."""
    levels: list[int] = []
    for byte in data:
        levels += [0, *((byte >> k) & 1 for k in range(8)), 1]
    return levels


def collide(first: bytes, second: bytes, skew_bits: int) -> bytes:
    """What a UART receives when two transmitters drive the half-duplex line at once, ``second`` starting
    ``skew_bits`` bit times after ``first``. Assumed (not measured): the line reads low when either drives it low
    (a low driver wins over a high one — TTL outputs fighting, the low side stronger), idle high. The receiver waits
    for a start bit, samples 8 data bits and the stop bit, and hands over the byte even on a framing error, as a
    USB adapter's UART does."""
    a = _bits(first)
    b = [1] * skew_bits + _bits(second)
    n = max(len(a), len(b))
    a += [1] * (n - len(a))
    b += [1] * (n - len(b))
    line = [x & y for x, y in zip(a, b)]
    out = bytearray()
    k = 0
    while k < n:
        if line[k] == 1:  # idle
            k += 1
            continue
        bits = line[k + 1:k + 9] + [1] * max(0, k + 9 - n)
        out.append(sum(bit << i for i, bit in enumerate(bits)))
        k += 10
    return bytes(out)


class Bus:
    """The servos on one bus; turns instruction packets into timed status packets."""

    def __init__(self, ids: list[int], baud_index: int, return_delay: int) -> None:
        self.servos = {i: Servo(i, baud_index, return_delay) for i in ids}
        # A second servo set to an ID already on the bus (``--ids 1,1,3-12``): it answers with its twin, and the two
        # status packets collide on the wire (see collide()).
        self.twins: dict[int, Servo] = {}
        self.twin_skew_bits = TWIN_SKEW_BITS
        for i in ids:
            if ids.count(i) > 1:
                self.twins[i] = Servo(i, baud_index, return_delay)
        self.baud_index = baud_index
        self.counts = dict.fromkeys(COUNTED.values(), 0)
        self.crc_errors = 0
        self.stall_s = 0.0  # one-off extra delay before the next instruction's replies
        self.stall_address: int | None = None  # stall only the replies to reads starting at this address
        self.stall_count = 0  # how many such reads are still to stall
        self.hold_until_s = 0.0  # replies made before then are held back and written together then

    @property
    def byte_s(self) -> float:
        return 10.0 / BAUD_BPS[self.baud_index]

    def take_stall_s(self, inst: int, params: bytes) -> float:
        """The extra delay (s) before the replies to this instruction (see the ``stall`` command); used up."""
        if not self.stall_s:
            return 0.0
        if self.stall_address is not None:
            address = int.from_bytes(params[0:2], "little") if len(params) >= 2 else -1
            if inst not in (INST_READ, INST_SYNC_READ) or address != self.stall_address:
                return 0.0
            self.stall_count -= 1
            stall_s = self.stall_s
            if self.stall_count <= 0:
                self.stall_s, self.stall_address = 0.0, None
            return stall_s
        stall_s, self.stall_s = self.stall_s, 0.0
        return stall_s

    def answering(self, dev_id: int, now: float) -> Servo | None:
        servo = self.servos.get(dev_id)
        if servo is None or servo.silent or now < servo.silent_until_s:
            return None
        if servo.get("baud_rate") != self.baud_index:
            return None  # it listens at another rate: the host's bytes are noise to it
        return servo

    def handle(self, dev_id: int, inst: int, params: bytes, now: float) -> list[tuple[Servo, bytes]]:
        """The status packets (with the servo sending each, in wire order) that answer one instruction; where two
        servos share an ID, the bytes the host receives from their colliding packets."""
        replies = self._handle(dev_id, inst, params, now)
        if not self.twins:
            return replies
        out = []
        for servo, reply in replies:
            twin = self.twins.get(servo.dev_id)
            if twin is not None and reply[4] == servo.dev_id:
                twin.update(now)
                twin_reply = bytearray(reply)
                # The twin's own state (a different position, say) would differ; even the same bytes collide
                # out of step: it starts TWIN_SKEW_BITS bit times later (its own clock and return delay).
                out.append((servo, collide(bytes(reply), bytes(twin_reply), self.twin_skew_bits)))
            else:
                out.append((servo, reply))
        return out

    def _handle(self, dev_id: int, inst: int, params: bytes, now: float) -> list[tuple[Servo, bytes]]:
        if inst in COUNTED:
            self.counts[COUNTED[inst]] += 1
        for servo in self.servos.values():
            servo.update(now)
        if inst == INST_PING:
            ids = sorted(self.servos) if dev_id == BROADCAST else [dev_id]
            out = []
            for i in ids:
                s = self.answering(i, now)
                if s is not None:
                    out.append((s, status_packet(i, s.status_error(), bytes(s.mem[0:2] + s.mem[6:7]))))
            return out
        if inst in (INST_SYNC_READ, INST_BULK_READ):
            return self._group_read(inst, params, now)
        if inst in (INST_SYNC_WRITE, INST_BULK_WRITE):
            self._group_write(inst, params, now)
            return []
        if dev_id == BROADCAST:
            for s in self.servos.values():
                if self.answering(s.dev_id, now):
                    self._single(s, inst, params, now)
            return []
        s = self.answering(dev_id, now)
        if s is None:
            return []
        return self._single(s, inst, params, now)

    def _single(self, s: Servo, inst: int, params: bytes, now: float) -> list[tuple[Servo, bytes]]:
        level = s.get("status_return_level")
        if inst == INST_READ:
            if len(params) != 4:
                return [(s, status_packet(s.dev_id, s.status_error(ERR_DATA_LENGTH)))] if level >= 1 else []
            address, length = int.from_bytes(params[0:2], "little"), int.from_bytes(params[2:4], "little")
            err, data = s.read(address, length)
            return [(s, status_packet(s.dev_id, s.status_error(err), data))] if level >= 1 else []
        if inst == INST_WRITE:
            if len(params) < 3:
                err = ERR_DATA_LENGTH
            else:
                err = s.write(int.from_bytes(params[0:2], "little"), params[2:])
            reply = [(s, status_packet(s.dev_id, s.status_error(err)))] if level >= 2 else []
            if s.get("id") != s.dev_id:  # a new ID: answered under the old one, from now on the new one
                self.servos.pop(s.dev_id, None)
                s.dev_id = s.get("id")
                if s.dev_id in self.servos:
                    self.twins[s.dev_id] = s  # set to an ID already taken: the two now collide
                else:
                    self.servos[s.dev_id] = s
            return reply
        if inst == INST_REBOOT:
            reply = [(s, status_packet(s.dev_id, s.status_error()))] if level >= 2 else []
            s.silent_until_s = now + 0.05
            s.power_on(now + 0.05)
            return reply
        if inst == INST_FACTORY_RESET:
            option = params[0] if params else 0xFF
            reply = [(s, status_packet(s.dev_id, s.status_error()))] if level >= 2 else []
            s.factory_reset(keep_id=option in (0x01, 0x02), keep_baud=option == 0x02)
            s.silent_until_s = now + 0.05
            s.power_on(now + 0.05)
            return reply
        # REG_WRITE/ACTION/CLEAR are not emulated: answered as an unknown instruction.
        return [(s, status_packet(s.dev_id, s.status_error(ERR_INSTRUCTION)))] if level >= 1 else []

    def _group_read(self, inst: int, params: bytes, now: float) -> list[tuple[Servo, bytes]]:
        requests: list[tuple[int, int, int]] = []
        if inst == INST_SYNC_READ:
            address, length = int.from_bytes(params[0:2], "little"), int.from_bytes(params[2:4], "little")
            requests = [(i, address, length) for i in params[4:]]
        else:
            for k in range(0, len(params) - 4, 5):
                requests.append((params[k], int.from_bytes(params[k + 1:k + 3], "little"),
                                 int.from_bytes(params[k + 3:k + 5], "little")))
        out = []
        for dev_id, address, length in requests:
            s = self.answering(dev_id, now)
            if s is None:
                continue
            err, data = s.read(address, length)
            out.append((s, status_packet(dev_id, s.status_error(err), data)))
        return out

    def _group_write(self, inst: int, params: bytes, now: float) -> None:
        if inst == INST_SYNC_WRITE:
            address, length = int.from_bytes(params[0:2], "little"), int.from_bytes(params[2:4], "little")
            for k in range(4, len(params) - length, length + 1):
                s = self.answering(params[k], now)
                if s is not None:
                    s.write(address, params[k + 1:k + 1 + length])
            return
        k = 0
        while k + 5 <= len(params):
            dev_id = params[k]
            address, length = int.from_bytes(params[k + 1:k + 3], "little"), int.from_bytes(params[k + 3:k + 5],
                                                                                         "little")
            s = self.answering(dev_id, now)
            if s is not None:
                s.write(address, params[k + 5:k + 5 + length])
            k += 5 + length

    # -- the fault side channel ---------------------------------------------------------------------------------
    def command(self, line: str, now: float) -> str:
        words = line.split()
        if not words:
            return "error empty command"
        verb, args = words[0], words[1:]
        try:
            if verb == "count":
                return "ok " + " ".join(f"{k}={v}" for k, v in self.counts.items()) + f" crc_errors={self.crc_errors}"
            if verb == "stall":
                self.stall_s = float(args[0])
                self.stall_address = int(args[1]) if len(args) > 1 else None
                self.stall_count = int(args[2]) if len(args) > 2 else 1
                which = "next" if self.stall_address is None else \
                    f"next {self.stall_count} read(s) at address {self.stall_address}:"
                return f"ok {which} replies {self.stall_s:g} s late"
            if verb in ("silent", "answer") and args == ["all"]:
                for each in self.servos.values():
                    each.silent = verb == "silent"
                return f"ok every servo {verb}"
            if verb == "hold":
                self.hold_until_s = now + float(args[0])
                return f"ok replies held for {float(args[0]):g} s"
            servo = self.servos[int(args[0])]
            servo.update(now)
            if verb == "state":
                return (f"ok torque={int(servo.torque)} position={round(servo.position)} "
                        f"goal={servo.get('goal_position')} hw_error={servo.get('hardware_error_status')} "
                        f"rdt={servo.get('return_delay_time')} goal_writes={servo.goal_writes}")
            if verb == "reboot":
                off_s = float(args[1]) if len(args) > 1 else 0.05
                jump = int(args[2]) if len(args) > 2 else 700
                servo.position = min(4095.0, max(0.0, servo.position + jump))
                servo.silent_until_s = now + off_s
                servo.power_on(now + off_s)
                return f"ok servo {servo.dev_id} power-cycled"
            if verb == "overload":
                servo.set("hardware_error_status", servo.get("hardware_error_status") | OVERLOAD_BIT)
                servo.set("torque_enable", 0)
                return f"ok servo {servo.dev_id} overloaded"
            if verb in ("silent", "answer"):
                servo.silent = verb == "silent"
                return f"ok servo {servo.dev_id} {verb}"
            if verb == "push":
                servo.position = min(4095.0, max(0.0, servo.position + int(args[1])))
                return f"ok servo {servo.dev_id} pushed"
        except (IndexError, ValueError, KeyError) as exc:
            return f"error {line!r}: {exc!r}"
        return f"error unknown command {verb!r}"


class Parser:
    """Finds instruction packets in the bytes from the host; drops garbage and packets with a bad CRC."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.crc_errors = 0

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        self.buf += data
        out: list[tuple[int, int, bytes]] = []
        while True:
            start = self.buf.find(HEADER)
            if start < 0:
                del self.buf[:max(0, len(self.buf) - 3)]
                return out
            del self.buf[:start]
            if len(self.buf) < 7:
                return out
            length = self.buf[5] | self.buf[6] << 8
            if length < 3 or length > 1000:
                del self.buf[:1]
                continue
            if len(self.buf) < 7 + length:
                return out
            pkt = bytes(self.buf[:7 + length])
            del self.buf[:7 + length]
            if crc16(pkt[:-2]) != (pkt[-2] | pkt[-1] << 8):
                self.crc_errors += 1
                continue
            body = remove_stuffing(pkt[7:-2])
            out.append((pkt[4], body[0], body[1:]))


def _termios_speeds() -> dict[int, int]:
    speeds = {}
    for bps in BAUD_BPS.values():
        const = getattr(termios, f"B{bps}", None)
        if const is not None:
            speeds[const] = bps
    return speeds


def host_baud(slave_fd: int) -> int | None:
    """The baud rate the host set on its end of the pty (None when termios cannot say, e.g. 4.5 Mbps)."""
    try:
        return _termios_speeds().get(termios.tcgetattr(slave_fd)[5])
    except termios.error:
        return None


def _sleep_until(t: float) -> None:
    delay = t - time.monotonic()
    if delay > 0:
        time.sleep(delay)


HARDWARE_RT_PRIORITY = 30


def _run_like_hardware() -> str:
    """Ask for a real-time scheduling class: servos answer on time whatever else the host runs, and a shared,
    loaded machine would otherwise make the emulator, not the driver under test, late. Best effort (needs the
    privilege); returns what was obtained, for the log line. Its priority is above any thread of the app under test
    (whose control loop asks for 20), as hardware does not wait for the host's threads: a reply late because the
    host's own real-time threads held the emulator off would be the emulator's lateness charged to the host."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(HARDWARE_RT_PRIORITY))
        return "SCHED_FIFO"
    except (AttributeError, PermissionError, OSError):
        return "normal scheduling (no privilege for SCHED_FIFO: replies may be late on a loaded machine)"


def serve(bus: Bus, out=sys.stdout) -> int:
    # A servo has no garbage collector: the emulator's objects are a fixed set and reference counting frees the rest,
    # so the cyclic collector only costs pauses. With XM430_TRACE its in-memory log grows to ~10^5 rows (~10^6
    # tracked objects) and a full collection then held replies 8-82 ms late, which the late-tick trace charged to
    # the "emulator" (10 minutes at 50 Hz: 5 late feedback reads, 6 missed ticks).
    gc.disable()
    master_fd, slave_fd = os.openpty()
    tty.setraw(master_fd)
    tty.setraw(slave_fd)  # kept open: the master then never reads EIO while the host reopens the port
    out.write(os.ttyname(slave_fd) + "\n")
    out.flush()
    parser = Parser()
    stdin_fd = sys.stdin.fileno()
    stdin_buf = b""
    wire_free_s = 0.0
    # XM430_TRACE=file: every instruction's times (read off the pty; each reply's planned and actual write), written
    # as JSON lines at exit, for bench_servo_bus --trace (a diagnosis of late ticks; same monotonic clock as the host).
    trace_path = os.environ.get("XM430_TRACE", "").strip()
    trace: list[tuple] | None = [] if trace_path else None
    held = bytearray()  # replies held back (the ``hold`` command), written together when the hold ends
    try:
        while True:
            wait_s = 0.5 if not held else min(0.5, max(0.0, bus.hold_until_s - time.monotonic()))
            readable, _, _ = select.select([master_fd, stdin_fd], [], [], wait_s)
            if held and time.monotonic() >= bus.hold_until_s:
                os.write(master_fd, bytes(held))
                held.clear()
            if master_fd in readable:
                try:
                    data = os.read(master_fd, 4096)
                except OSError:
                    data = b""
                now = time.monotonic()
                own = BAUD_BPS[bus.baud_index]
                rate = host_baud(slave_fd)
                if rate is not None and rate in BAUD_BPS.values():
                    # The wire runs at the host's rate; each servo hears it only at its own Baud Rate (answering).
                    bus.baud_index = next(k for k, bps in BAUD_BPS.items() if bps == rate)
                    understood = True
                else:
                    understood = rate == own if rate is not None else own not in _termios_speeds().values()
                if data and understood:
                    # The host wrote at once; on a real wire its bytes arrive over len·10/baud.
                    wire_free_s = max(now, wire_free_s) + len(data) * bus.byte_s
                    for dev_id, inst, params in parser.feed(data):
                        replies = bus.handle(dev_id, inst, params, now)
                        if replies:
                            wire_free_s += bus.take_stall_s(inst, params)
                        written: list[tuple[float, float, float]] = []
                        for servo, reply in replies:
                            start = wire_free_s + servo.get("return_delay_time") * 2e-6
                            wire_free_s = start + len(reply) * bus.byte_s
                            _sleep_until(wire_free_s)
                            woke = time.monotonic()
                            if woke < bus.hold_until_s:
                                held += reply
                                continue
                            if held:
                                os.write(master_fd, bytes(held))
                                held.clear()
                            os.write(master_fd, reply)
                            if trace is not None:  # due on the wire, woke from the sleep for it, write returned
                                written.append((round(wire_free_s, 6), round(time.monotonic(), 6), round(woke, 6)))
                        if trace is not None:
                            trace.append((round(now, 6), inst, len(data), written))
                    bus.crc_errors = parser.crc_errors
            if stdin_fd in readable:
                chunk = os.read(stdin_fd, 4096)
                if not chunk:
                    return 0
                stdin_buf += chunk
                while b"\n" in stdin_buf:
                    raw, stdin_buf = stdin_buf.split(b"\n", 1)
                    line = raw.decode(errors="replace").strip()
                    if line == "kill":
                        out.write("ok killed\n")
                        out.flush()
                        return 0
                    out.write(bus.command(line, time.monotonic()) + "\n")
                    out.flush()
    finally:
        os.close(master_fd)
        os.close(slave_fd)
        if trace_path and trace:
            with open(trace_path, "w", encoding="utf-8") as file:
                for row in trace:
                    file.write(json.dumps(row) + "\n")


def _parse_ids(text: str) -> list[int]:
    ids: list[int] = []
    for part in text.split(","):
        if "-" in part:
            lo, hi = part.split("-")
            ids.extend(range(int(lo), int(hi) + 1))
        else:
            ids.append(int(part))
    return ids


class EmulatorProcess:
    """The emulator in its own process, for tests: ``path`` is the pty to open, ``command`` the side channel.

    Any thread may construct it; ``command`` belongs to one thread at a time."""

    def __init__(self, *args: str) -> None:
        import subprocess

        self.proc = subprocess.Popen([sys.executable, "-m", "tests.emulators.xm430_emulator", *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None and self.proc.stdin is not None
        self.path = self.proc.stdout.readline().strip()
        if not self.path.startswith("/dev/"):
            self.proc.kill()
            raise RuntimeError(f"the XM430 emulator did not start: {self.path!r}")

    def command(self, line: str) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline().strip()

    def state(self, servo_id: int) -> dict[str, int]:
        """``state ID`` parsed: torque, position, goal, hw_error, rdt, goal_writes."""
        answer = self.command(f"state {servo_id}")
        if not answer.startswith("ok "):
            raise RuntimeError(answer)
        return {k: int(v) for k, v in (word.split("=") for word in answer[3:].split())}

    def counts(self) -> dict[str, int]:
        answer = self.command("count")
        return {k: int(v) for k, v in (word.split("=") for word in answer[3:].split())}

    def close(self) -> int:
        """End the process (closing its stdin) and return its exit code."""
        if self.proc.stdin is not None:  # also after a 'kill' ended the process: the pipe is still ours to close
            with contextlib.suppress(BrokenPipeError):
                self.proc.stdin.close()
        try:
            return self.proc.wait(timeout=10)
        finally:
            if self.proc.stdout is not None:
                self.proc.stdout.close()  # the answer pipe (left open, it is a ResourceWarning at collection)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.emulators.xm430_emulator",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--ids", default="1-12", help="servo IDs, e.g. 1-12 or 1,2,5 (default 1-12); an ID given "
                        "twice is two servos set to it, whose replies collide (1,1,3-12: the second servo's ID was "
                        "changed to 1)")
    parser.add_argument("--baud", type=int, default=1_000_000, help="bus baud rate in bps (default 1000000)")
    parser.add_argument("--twin-skew-bits", type=int, default=TWIN_SKEW_BITS,
                        help="bit times a duplicate ID's reply lags its twin's (default 3: they collide; past the "
                        "packet's length, e.g. 400, the two replies arrive whole one after the other)")
    parser.add_argument("--return-delay", type=int, default=250,
                        help="Return Delay Time register, 2 µs units (default 250 = 500 µs, the factory value)")
    parser.add_argument("--no-realtime", action="store_true",
                        help="do not ask for SCHED_FIFO (by default the emulator tries to answer on time like hardware)")
    args = parser.parse_args(argv)
    index = {bps: i for i, bps in BAUD_BPS.items()}.get(args.baud)
    if index is None:
        parser.error(f"--baud {args.baud} is not a Dynamixel rate ({sorted(BAUD_BPS.values())})")
    if not hasattr(os, "openpty"):
        print("the emulator needs os.openpty (Linux or macOS)", file=sys.stderr)
        return 2
    scheduling = "normal scheduling" if args.no_realtime else _run_like_hardware()
    print(f"xm430 emulator: {args.ids} at {args.baud} bps, Return Delay Time {args.return_delay}, {scheduling}",
          file=sys.stderr)
    bus = Bus(_parse_ids(args.ids), index, args.return_delay)
    bus.twin_skew_bits = args.twin_skew_bits
    return serve(bus)


if __name__ == "__main__":
    sys.exit(main())
