"""Dynamixel Protocol 2.0 packet codec: CRC-16, byte stuffing, instruction and status packets.

Written from the protocol description, independently of dynamixel-sdk, because the simulated servos
(:mod:`devices.sim.dxl_chain`) use it: the driver (on dynamixel-sdk) and the simulator (on this module) are two
separate implementations of the wire format, so a test that passes between them says something about both.

Packet layout (all multi-byte fields little-endian)::

    FF FF FD 00 | ID | LEN_L LEN_H | INSTRUCTION | PARAMETERS… | CRC_L CRC_H
    status packets: INSTRUCTION = 0x55 and the first parameter is the error byte.

``LEN`` counts the bytes after it (instruction, stuffed parameters, CRC). The CRC is CRC-16 with polynomial
0x8005, initial value 0, no reflection, over everything from the first header byte to the last parameter byte.
Byte stuffing: wherever ``FF FF FD`` occurs in the instruction/parameter field, an extra ``FD`` follows it, so the
header pattern never appears inside a packet. Pure functions and a stateful parser; a parser instance belongs to
one thread.
"""

from __future__ import annotations

from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
HEADER_PATTERN = b"\xff\xff\xfd"
STUFF_BYTE = 0xFD
BROADCAST_ID = 0xFE
MAX_PACKET_BYTES = 1024
MIN_LENGTH_FIELD = 3  # instruction + CRC

PING = 0x01
READ = 0x02
WRITE = 0x03
REG_WRITE = 0x04
ACTION = 0x05
FACTORY_RESET = 0x06
REBOOT = 0x08
CLEAR = 0x10
STATUS = 0x55
SYNC_READ = 0x82
SYNC_WRITE = 0x83
FAST_SYNC_READ = 0x8A
BULK_READ = 0x92
BULK_WRITE = 0x93

INSTRUCTION_NAMES = {
    PING: "PING", READ: "READ", WRITE: "WRITE", REG_WRITE: "REG_WRITE", ACTION: "ACTION",
    FACTORY_RESET: "FACTORY_RESET", REBOOT: "REBOOT", CLEAR: "CLEAR", STATUS: "STATUS",
    SYNC_READ: "SYNC_READ", SYNC_WRITE: "SYNC_WRITE", FAST_SYNC_READ: "FAST_SYNC_READ",
    BULK_READ: "BULK_READ", BULK_WRITE: "BULK_WRITE",
}


def _make_crc_table(poly: int = 0x8005) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ poly) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16/IBM as Dynamixel uses it (poly 0x8005, init 0, MSB first, no final xor)."""
    table = CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ byte) & 0xFF]
    return crc


def stuff(field: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in the instruction/parameter field."""
    if HEADER_PATTERN not in field:
        return bytes(field)
    out = bytearray()
    for byte in field:
        out.append(byte)
        if byte == STUFF_BYTE and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            # out[-3:] is the pattern only if it came from the input, not from a previous stuffing byte:
            # a stuffing FD is always preceded by FD, never by FF FF, so this test is exact.
            out.append(STUFF_BYTE)
    return bytes(out)


def unstuff(field: bytes) -> bytes:
    """Remove the ``FD`` that follows each ``FF FF FD`` (inverse of :func:`stuff`)."""
    if HEADER_PATTERN not in field:
        return bytes(field)
    out = bytearray()
    i = 0
    n = len(field)
    while i < n:
        byte = field[i]
        out.append(byte)
        if byte == STUFF_BYTE and i >= 2 and field[i - 2] == 0xFF and field[i - 1] == 0xFF \
                and i + 1 < n and field[i + 1] == STUFF_BYTE:
            i += 2
            continue
        i += 1
    return bytes(out)


def build_packet(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete, stuffed, CRC-terminated packet (instruction packets and status packets alike)."""
    if not 0 <= servo_id <= 0xFE:
        raise ValueError(f"servo ID {servo_id} outside 0…254")
    field = stuff(bytes([instruction]) + bytes(params))
    length = len(field) + 2  # LEN counts the (stuffed) field and the CRC
    if 7 + length > MAX_PACKET_BYTES:
        raise ValueError(f"packet of {7 + length} bytes exceeds {MAX_PACKET_BYTES}")
    head = HEADER + bytes([servo_id, length & 0xFF, length >> 8])
    body = head + field
    crc = crc16(body)
    return body + bytes([crc & 0xFF, crc >> 8])


def build_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (the servo's reply): error byte then parameters."""
    return build_packet(servo_id, STATUS, bytes([error & 0xFF]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """A packet whose CRC checked out; ``params`` are unstuffed. For status packets ``params[0]`` is the error."""

    servo_id: int
    instruction: int
    params: bytes

    @property
    def error(self) -> int:
        """The status error byte (status packets only)."""
        return self.params[0] if self.instruction == STATUS and self.params else 0

    @property
    def data(self) -> bytes:
        """Status parameters after the error byte (status packets only)."""
        return self.params[1:] if self.instruction == STATUS else self.params


@dataclass(frozen=True)
class CorruptPacket:
    """A complete packet with a valid-looking header whose CRC did not match."""

    servo_id: int
    instruction: int


class PacketParser:
    """Incremental parser: feed raw bytes, get whole packets back; resynchronises on garbage.

    Counters: ``packets``, ``crc_errors``, ``bytes_discarded``. One thread only.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.packets = 0
        self.crc_errors = 0
        self.bytes_discarded = 0

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a packet."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop a partial packet (e.g. after an inter-byte timeout)."""
        self.bytes_discarded += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes) -> list[Packet | CorruptPacket]:
        self._buf += data
        out: list[Packet | CorruptPacket] = []
        buf = self._buf
        while True:
            start = buf.find(HEADER_PATTERN)
            if start < 0:
                # Keep a trailing FF or FF FF: it may be the start of the next header.
                keep = 2 if buf.endswith(b"\xff\xff") else 1 if buf.endswith(b"\xff") else 0
                self._discard(len(buf) - keep)
                break
            if start:
                self._discard(start)
            if len(buf) < 7:
                break
            length = buf[5] | (buf[6] << 8)
            if buf[3] != 0x00 or buf[4] == 0xFF or length < MIN_LENGTH_FIELD or length + 7 > MAX_PACKET_BYTES:
                self._discard(1)
                continue
            total = 7 + length
            if len(buf) < total:
                break
            crc = buf[total - 2] | (buf[total - 1] << 8)
            if crc16(memoryview(buf)[: total - 2]) != crc:
                self.crc_errors += 1
                out.append(CorruptPacket(buf[4], buf[7]))
                # Only skip the header: stuffing guarantees no header inside a good packet, so a packet that
                # follows a spurious header is still found.
                self._discard(3)
                continue
            field = unstuff(bytes(buf[7 : total - 2]))
            out.append(Packet(buf[4], field[0], field[1:]))
            self.packets += 1
            del buf[:total]
        return out

    def _discard(self, n: int) -> None:
        if n > 0:
            self.bytes_discarded += n
            del self._buf[:n]
