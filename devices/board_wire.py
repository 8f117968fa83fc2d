"""The force-sensor board's wire format (SPEC §4) and its readout circuit: bytes and numbers only, no I/O.

Frame layout, CRC-16/CCITT-FALSE, the encoder (used by the simulated board and tests: a host never sends frames) and
the counts ↔ conductance conversion of the readout circuit. Both the board driver (:mod:`devices.board`) and the
simulated board (:mod:`devices.sim.board`) build on this module, which imports neither of them: that is what keeps
the driver → port factory → simulated lab → driver circle from existing (see the devices layers contract).
Everything here may be called from any thread.
"""

from __future__ import annotations

import binascii
import struct

import numpy as np

from devices.config import BoardConfig

SYNC = b"\xa5\x5a"
PROTOCOL_VERSION = 1
HEADER_SIZE = 14  # sync(2) version(1) flags(1) seq(4) t_us(4) n(2)
CRC_SIZE = 2
MAX_CHANNELS = 1024
BITS_PER_BYTE = 10  # start + 8 data + stop
FLAG_SATURATED = 0x01
SEQ_MODULUS = 1 << 32
T_US_MODULUS = 1 << 32
HEADER_STRUCT = struct.Struct("<BBIIH")  # version, flags, seq, t_us, n — starts after the sync bytes
CRC_STRUCT = struct.Struct("<H")


# -- CRC ---------------------------------------------------------------------------------------------------------
def crc16_ccitt_false(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor). Any thread.

    ``binascii.crc_hqx`` is exactly this CRC with a caller-chosen init (CPython's table-driven C loop), so the hot
    path costs about a nanosecond per byte; :func:`crc16_ccitt_false_table` is the pure-Python reference it is tested
    against.
    """
    return binascii.crc_hqx(data, crc)


def _make_crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def crc16_ccitt_false_table(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """The same CRC, table-driven in pure Python: the readable reference (≈100× slower). Any thread."""
    table = _CRC_TABLE
    for byte in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


def encode_frame(seq: int, t_us: int, counts: np.ndarray, flags: int | None = None,
                 version: int = PROTOCOL_VERSION) -> bytes:
    """One SPEC §4 frame. ``flags=None`` sets the saturated bit when any count is 0. Any thread.

    Used by the simulated board and by tests; a host never sends frames.
    """
    counts16 = np.asarray(counts, dtype="<u2")
    if flags is None:
        flags = FLAG_SATURATED if bool((counts16 == 0).any()) else 0
    body = HEADER_STRUCT.pack(version, flags, seq % SEQ_MODULUS, t_us % T_US_MODULUS, counts16.size) + counts16.tobytes()
    return SYNC + body + CRC_STRUCT.pack(crc16_ccitt_false(body))


# -- readout circuit ---------------------------------------------------------------------------------------------
def conductance_from_counts(counts: np.ndarray, board: BoardConfig) -> np.ndarray:
    """Sensor conductance in siemens from ADC counts (SPEC §4). Any thread; any array shape.

    ``V = counts/adc_max · V_supply``, ``C = (V_ref − V)/(V_ref · R_C)``; a negative ``C`` (open sensor) reads 0.
    ``counts == 0`` is saturated: the value is the circuit's ceiling ``1/R_C`` and callers flag it (see
    :func:`saturated_from_counts`).
    """
    volts = np.asarray(counts, dtype=np.float64) * (board.v_supply_v / board.adc_max_counts)
    conductance = (board.v_ref_v - volts) * (1.0 / (board.v_ref_v * board.r_c_ohm))
    np.maximum(conductance, 0.0, out=conductance)
    return conductance


def counts_from_conductance(conductance_s: np.ndarray, board: BoardConfig) -> np.ndarray:
    """The readout circuit run forwards, unquantised (float counts, not clipped). Any thread."""
    volts = board.v_ref_v * (1.0 - np.asarray(conductance_s, dtype=np.float64) * board.r_c_ohm)
    return volts * (board.adc_max_counts / board.v_supply_v)


def saturated_from_counts(counts: np.ndarray) -> np.ndarray:
    """True where the ADC reads 0 (the sensor's conductance is beyond the circuit's range)."""
    return np.asarray(counts) == 0
