"""FrameParser and the readout circuit: SPEC §4 byte for byte, and fuzzed with hypothesis."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from devices.board import (
    HEADER_SIZE,
    SYNC,
    FrameParser,
    conductance_from_counts,
    counts_from_conductance,
    crc16_ccitt_false,
    crc16_ccitt_false_table,
    encode_frame,
    saturated_from_counts,
)
from devices.config import BoardConfig


def test_crc_matches_the_standard_check_value():
    # CRC-16/CCITT-FALSE of "123456789" is 0x29B1 (the catalogue's check value).
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc16_ccitt_false_table(b"123456789") == 0x29B1


@given(st.binary(max_size=300))
def test_fast_crc_equals_table_reference(data):
    assert crc16_ccitt_false(data) == crc16_ccitt_false_table(data)


def test_frame_layout_is_spec_section_4():
    frame = encode_frame(seq=0x01020304, t_us=0x0A0B0C0D, counts=np.array([1, 4095, 0]))
    assert frame[:2] == b"\xa5\x5a"
    assert frame[2] == 1  # version
    assert frame[3] == 1  # saturated flag: one count is 0
    assert frame[4:8] == bytes([4, 3, 2, 1])
    assert frame[8:12] == bytes([0x0D, 0x0C, 0x0B, 0x0A])
    assert frame[12:14] == bytes([3, 0])
    assert frame[14:20] == bytes([1, 0, 0xFF, 0x0F, 0, 0])
    assert int.from_bytes(frame[20:22], "little") == crc16_ccitt_false(frame[2:20])
    assert len(frame) == HEADER_SIZE + 2 * 3 + 2


def test_parser_delivers_frames_split_at_every_byte():
    frames = b"".join(encode_frame(s, 1000 * s, np.arange(5) + s) for s in range(4))
    parser = FrameParser()
    got = []
    for i in range(len(frames)):
        got += parser.feed(frames[i:i + 1])
    assert [f.seq for f in got] == [0, 1, 2, 3]
    assert np.array_equal(got[2].counts, np.arange(5) + 2)
    assert parser.crc_errors == parser.resyncs == parser.bytes_discarded == parser.seq_gaps == 0


def test_parser_counts_crc_error_and_resyncs_to_next_frame():
    good = [encode_frame(s, 0, np.full(8, 100 + s)) for s in range(3)]
    bad = bytearray(good[1])
    bad[20] ^= 0x10
    parser = FrameParser()
    got = parser.feed(good[0] + bytes(bad) + good[2])
    assert [f.seq for f in got] == [0, 2]
    assert parser.crc_errors == 1
    assert parser.resyncs == 1
    assert parser.seq_gaps == 1 and parser.dropped_frames == 1
    assert parser.bytes_discarded == len(bad)


def test_parser_rejects_bad_version_and_channel_count():
    bad_version = encode_frame(1, 0, np.ones(4), version=2)
    too_many = SYNC + bytes([1, 0]) + bytes(8) + (1025).to_bytes(2, "little")
    good = encode_frame(2, 0, np.ones(4))
    parser = FrameParser()
    got = parser.feed(bad_version + too_many + good)
    assert [f.seq for f in got] == [2]
    # A whole, CRC-valid frame of version 2 is a board speaking it (counted apart, its version kept), not noise.
    assert parser.bad_headers == 1 and parser.version_mismatches == 1 and parser.other_version == 2
    assert parser.crc_errors == 0
    assert parser.bytes_received == parser.bytes_in_frames + parser.bytes_discarded + parser.bytes_pending


def test_false_header_claiming_a_long_frame_does_not_hold_back_real_frames():
    false_header = SYNC + bytes([1, 0]) + bytes(8) + (1000).to_bytes(2, "little") + bytes(10)
    frames = [encode_frame(s, 0, np.full(36, 2000)) for s in range(3)]
    parser = FrameParser()
    got = parser.feed(false_header + b"".join(frames))
    # Delivered now, not after the 2 KB the false header claims.
    assert [f.seq for f in got] == [0, 1, 2]
    assert parser.bad_headers == 1 and parser.bytes_discarded == len(false_header)


def test_seq_gap_wraps_at_2_to_the_32():
    parser = FrameParser()
    frames = [encode_frame(s, 0, np.ones(2)) for s in (2**32 - 2, 2**32 - 1, 0, 1, 5)]
    got = parser.feed(b"".join(frames))
    assert [f.seq for f in got] == [2**32 - 2, 2**32 - 1, 0, 1, 5]
    assert parser.seq_gaps == 1
    assert parser.dropped_frames == 3


def test_conductance_from_counts_follows_the_readout_circuit():
    board = BoardConfig()
    counts = np.array([0, 1000, 3102, 4095], dtype=np.uint16)
    conductance = conductance_from_counts(counts, board)
    volts = counts / 4095 * 3.3
    expected = np.maximum((2.5 - volts) / (2.5 * 900.0), 0.0)
    assert np.allclose(conductance, expected, rtol=0, atol=1e-15)
    assert conductance[0] == pytest.approx(1 / 900.0)
    assert conductance[3] == 0.0  # above V_ref: open sensor reads 0, never negative
    assert saturated_from_counts(counts).tolist() == [True, False, False, False]
    # The forward circuit inverts it.
    assert np.allclose(counts_from_conductance(conductance[:2], board), counts[:2].astype(float))


# -- fuzzing -----------------------------------------------------------------------------------------------------
counts_strategy = st.lists(st.integers(0, 4095), min_size=1, max_size=40)
frame_strategy = st.tuples(st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1), counts_strategy)
# Garbage without 0xA5 cannot start a false frame, so every valid frame around it must come through.
clean_garbage = st.binary(max_size=60).map(lambda b: b.replace(b"\xa5", b"\x00"))


def _encode(spec) -> bytes:
    seq, t_us, counts = spec
    return encode_frame(seq, t_us, np.array(counts))


def _assert_counters_add_up(parser: FrameParser) -> None:
    assert parser.bytes_received == parser.bytes_in_frames + parser.bytes_discarded + parser.bytes_pending


def _feed_in_chunks(parser: FrameParser, data: bytes, cuts: list[int]) -> list:
    got = []
    points = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    for a, b in zip(points, points[1:]):
        got += parser.feed(data[a:b])
    return got


# Bytes with no 0xA5 that push out anything a false header inside a corrupted frame may still be waiting for.
FLUSH = bytes(2 * 1024 + 16)


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=2000), st.lists(st.integers(0, 10_000), max_size=8))
def test_random_bytes_never_crash_and_anything_delivered_was_a_valid_frame(data, cuts):
    parser = FrameParser()
    got = _feed_in_chunks(parser, data, cuts)
    for frame in got:
        assert _rebuild(frame) in data  # exactly a CRC-valid frame that was in the stream
    assert parser.frames == len(got)
    _assert_counters_add_up(parser)


def _rebuild(frame) -> bytes:
    return encode_frame(frame.seq, frame.t_us, frame.counts, flags=frame.flags)


def _specs(frames) -> list:
    return [(f.seq, f.t_us, f.counts.tolist()) for f in frames]


def _without_repeats(specs) -> list:
    """What the parser delivers of these frames: a frame repeating the previous delivered one's seq is dropped
    (counted in duplicate_frames: a board sending a frame twice must not store its sample twice)."""
    out: list = []
    for spec in specs:
        if not out or spec[0] != out[-1][0]:
            out.append(spec)
    return out


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(clean_garbage, frame_strategy), min_size=1, max_size=8), clean_garbage,
       st.lists(st.integers(0, 10_000), max_size=8))
def test_every_valid_frame_between_garbage_is_delivered_in_order(pieces, tail, cuts):
    stream = b"".join(garbage + _encode(spec) for garbage, spec in pieces) + tail
    parser = FrameParser()
    got = _feed_in_chunks(parser, stream, cuts)
    assert _specs(got) == _without_repeats([spec for _, spec in pieces])
    assert parser.crc_errors == 0
    assert parser.bytes_discarded == sum(len(g) for g, _ in pieces) + len(tail) - parser.bytes_pending
    _assert_counters_add_up(parser)


@settings(max_examples=150, deadline=None)
@given(st.lists(frame_strategy, min_size=2, max_size=6), st.data())
def test_bit_flips_are_counted_and_never_delivered(specs, data):
    frames = [bytearray(_encode(spec)) for spec in specs]
    victim = data.draw(st.integers(0, len(frames) - 1))
    # Any bit after the sync and outside the length field: the frame keeps its length, so only the checks catch it.
    position = data.draw(st.sampled_from([2, 3, *range(4, 12), *range(14, len(frames[victim]))]))
    frames[victim][position] ^= 1 << data.draw(st.integers(0, 7))
    parser = FrameParser()
    got = parser.feed(b"".join(bytes(f) for f in frames)) + parser.feed(FLUSH)
    assert _specs(got) == _without_repeats([spec for i, spec in enumerate(specs) if i != victim])
    if position == 2:
        assert parser.bad_headers >= 1  # the version byte
    else:
        assert parser.crc_errors >= 1
    assert parser.resyncs >= 1
    _assert_counters_add_up(parser)


@settings(max_examples=100, deadline=None)
@given(st.lists(frame_strategy, min_size=1, max_size=5, unique_by=lambda spec: spec[0]), st.integers(1, 200))
def test_truncated_frame_is_never_delivered_and_the_frames_after_it_are(specs, cut):
    # (distinct seqs: a repeated seq is a duplicate frame, dropped, which its own test covers)
    first = _encode(specs[0])
    truncated = first[:max(1, len(first) - cut)]
    rest = b"".join(_encode(s) for s in specs[1:])
    parser = FrameParser()
    got = parser.feed(truncated + rest) + parser.feed(FLUSH)
    # The truncated frame's header claims bytes of the next frame, so its CRC fails and the parser resyncs. By
    # coincidence the borrowed bytes can equal the cut-off ones (then the first frame is complete again, exact,
    # and the next one lost with its sync): either way nothing wrong is delivered and every later frame arrives.
    stream = truncated + rest + FLUSH
    for frame in got:
        assert _rebuild(frame) in stream
    got_specs = _specs(got)
    assert len(got_specs) >= len(specs) - 1
    if len(specs) > 2:
        assert got_specs[-(len(specs) - 2):] == specs[2:]
    if got_specs[:1] != specs[:1]:
        assert got_specs == specs[1:]
        if len(specs) > 1 and len(truncated) >= HEADER_SIZE:
            assert parser.crc_errors + parser.bad_headers >= 1
    _assert_counters_add_up(parser)


def test_a_repeated_frame_is_stored_once_counted_and_not_taken_for_a_gap():
    """A board (or an adapter) that sends every frame twice: each sample once, duplicate_frames counts the repeats,
    no seq gap and no dropped frame is invented."""
    from devices.board import FrameParser
    from devices.board_wire import encode_frame

    parser = FrameParser()
    stream = b"".join(encode_frame(seq, seq * 33_333, np.full(36, 100 + seq, np.uint16)) * 2 for seq in range(10))
    frames = parser.feed(stream)
    assert [f.seq for f in frames] == list(range(10))
    assert parser.duplicate_frames == 10
    assert parser.seq_gaps == 0 and parser.dropped_frames == 0
