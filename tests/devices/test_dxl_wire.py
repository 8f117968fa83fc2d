"""The simulator's Protocol 2.0 codec, checked against the protocol's rules and against dynamixel-sdk's own code."""

from __future__ import annotations

import pytest
from dynamixel_sdk import PacketHandler
from hypothesis import given, settings
from hypothesis import strategies as st

from devices import dxl_wire as wire

SDK = PacketHandler(2.0)

# Bytes rich in the header pattern, so stuffing is exercised on almost every example.
pattern_bytes = st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x55, 0xFE]) | st.integers(0, 255),
                         max_size=120).map(bytes)


def test_crc_matches_the_manual_example():
    # ROBOTIS e-manual, Protocol 2.0: ping to ID 1 is FF FF FD 00 01 03 00 01 19 4E.
    assert wire.build_packet(1, wire.PING) == bytes.fromhex("FFFFFD0001030001194E")
    # Its status reply (model 1030 in the manual's example, firmware 38): FF FF FD 00 01 07 00 55 00 06 04 26 65 5D
    assert wire.build_status(1, 0, bytes([0x06, 0x04, 0x26])) == bytes.fromhex("FFFFFD00010700550006042665 5D")


@settings(max_examples=50)
@given(pattern_bytes)
def test_crc_agrees_with_dynamixel_sdk(data):
    assert wire.crc16(data) == SDK.updateCRC(0, list(data), len(data))


@settings(max_examples=50)
@given(pattern_bytes)
def test_unstuff_inverts_stuff_and_no_header_survives(field):
    stuffed = wire.stuff(field)
    assert wire.unstuff(stuffed) == field
    # After stuffing, every FF FF FD is followed by FD, so a receiver never mistakes data for a header.
    for i in range(len(stuffed) - 2):
        if stuffed[i : i + 3] == wire.HEADER_PATTERN:
            assert stuffed[i + 3] == wire.STUFF_BYTE


@settings(max_examples=80)
@given(st.integers(0, 252), st.integers(1, 0x93), pattern_bytes)
def test_stuffed_packet_is_byte_identical_to_the_sdk(servo_id, instruction, params):
    """Build the same packet with dynamixel-sdk's txPacket logic (addStuffing + CRC) and with our codec."""
    n = len(params)
    sdk = [0] * (n + 10)
    sdk[4] = servo_id
    sdk[5], sdk[6] = (n + 3) & 0xFF, (n + 3) >> 8
    sdk[7] = instruction
    sdk[8 : 8 + n] = list(params)
    sdk = SDK.addStuffing(sdk)
    total = (sdk[5] | (sdk[6] << 8)) + 7
    sdk[0:4] = [0xFF, 0xFF, 0xFD, 0x00]
    crc = SDK.updateCRC(0, sdk, total - 2)
    sdk[total - 2], sdk[total - 1] = crc & 0xFF, crc >> 8
    assert wire.build_packet(servo_id, instruction, params) == bytes(sdk[:total])


@settings(max_examples=40)
@given(st.lists(st.tuples(st.integers(0, 252), st.integers(1, 0x93), pattern_bytes), min_size=1, max_size=5),
       st.lists(pattern_bytes, min_size=6, max_size=6), st.integers(1, 17))
def test_parser_finds_every_packet_between_garbage_in_any_chunking(packets, garbage, chunk):
    stream = bytearray()
    for k, (sid, instr, params) in enumerate(packets):
        # Garbage never ends in a partial header that would swallow the next packet's first bytes.
        stream += garbage[k].replace(b"\xff", b"\x01") + wire.build_packet(sid, instr, params)
    stream += garbage[-1].replace(b"\xff", b"\x01")
    parser = wire.PacketParser()
    out = []
    for i in range(0, len(stream), chunk):
        out += parser.feed(bytes(stream[i : i + chunk]))
    good = [(p.servo_id, p.instruction, p.params) for p in out if isinstance(p, wire.Packet)]
    assert good == [(sid, instr, bytes(params)) for sid, instr, params in packets]


@settings(max_examples=50)
@given(st.integers(0, 252), pattern_bytes, st.data())
def test_a_flipped_bit_is_reported_as_corrupt_never_delivered(servo_id, params, data):
    packet = bytearray(wire.build_packet(servo_id, wire.WRITE, params))
    # Flip one bit after the header and length (a flip there changes framing rather than content).
    index = data.draw(st.integers(7, len(packet) - 1))
    packet[index] ^= 1 << data.draw(st.integers(0, 7))
    out = wire.PacketParser().feed(bytes(packet))
    assert not any(isinstance(p, wire.Packet) and p.params == params and p.servo_id == servo_id
                   and p.instruction == wire.WRITE for p in out)


def test_status_error_and_data_fields():
    packet = wire.PacketParser().feed(wire.build_status(7, 0x87, b"\x01\x02"))[0]
    assert packet.instruction == wire.STATUS
    assert packet.error == 0x87
    assert packet.data == b"\x01\x02"


def test_oversized_packet_is_refused():
    assert len(wire.build_packet(1, wire.WRITE, bytes(1024 - 10))) == 1024
    with pytest.raises(ValueError, match="exceeds 1024"):
        wire.build_packet(1, wire.WRITE, bytes(1024 - 9))
