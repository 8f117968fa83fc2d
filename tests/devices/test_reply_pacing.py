"""devices/reply_pacing.py: the servo port's wait rule as a pure policy, on a trace recorded against the independent
XM430 emulator (tests/data/reply_trace_xm430_emulator.json: 60 sync reads of 12 servos at 1 Mbps, Return Delay Time
500 µs) and on constructed cases (a device faster than the wire, replies of a given-up read, a silent servo)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from devices import reply_pacing as rp

TRACE = Path(__file__).resolve().parents[1] / "data" / "reply_trace_xm430_emulator.json"
BYTE_S = 10e-6  # 1 Mbps


def _replay(pacing: rp.ReplyPacing, events: list) -> list[tuple[float, float]]:
    """Feed a recorded trace; per transaction (when the first wait would have ended, when the reply was all in)."""
    rows = []
    first_wait_end = None
    for event in events:
        kind, t = event[0], event[1]
        if kind == "sent":
            pacing.sent(t, event[2])
            wait, _due = pacing.wait_s(t, 0, 252, 12 * 500e-6, None, probe=False)
            first_wait_end = t + wait
        elif kind == "received":
            pacing.received(event[2])
            pacing.judge_early(t)
        elif kind == "complete":
            pacing.complete(t, event[2], event[3])
            rows.append((first_wait_end, t))
    return rows


def test_on_the_emulators_trace_the_first_wait_never_outlasts_the_reply_and_the_wire_is_never_taken_for_fast():
    document = json.loads(TRACE.read_text())
    pacing = rp.ReplyPacing(document["byte_s"])
    rows = np.array(_replay(pacing, document["events"]))
    assert len(rows) == 60
    assert not pacing.faster_than_wire and not any(pacing.verdicts)  # the emulator keeps the wire's pace
    slack = rows[:, 1] - rows[:, 0]  # how long after the first wait the reply was all in
    assert np.all(slack >= -1e-4), "the wire's bound woke the port after the reply was already in"
    assert np.median(slack) < 0.003, f"the bound is loose: median {np.median(slack) * 1e3:.2f} ms"


def test_a_device_faster_than_the_wire_is_taken_up_on_repeated_evidence_and_dropped_again():
    pacing = rp.ReplyPacing(BYTE_S)
    wire_s = 26 * BYTE_S + 252 * BYTE_S + 12 * 500e-6  # the least the wire needs for a sync read
    t = 0.0
    for k in range(rp.PACE_FAST_VOTES):
        assert not pacing.faster_than_wire, k
        pacing.sent(t, 26)
        pacing.complete(t + 0.05 * wire_s, 252, 12 * 500e-6)  # a simulator at 20x
        t += 0.02
    assert pacing.faster_than_wire
    # Now replies are awaited at the observed pace, never past the wire's bound.
    pacing.sent(t, 26)
    wait, _ = pacing.wait_s(t + 0.0002, 100, 152, 0.004, None, probe=False)
    assert wait == pytest.approx(152 * 0.0002 / 100) and wait < wire_s
    wait_no_bytes, _ = pacing.wait_s(t + 0.0002, 0, 252, 0.006, None, probe=False)
    assert wait_no_bytes == rp.READ_POLL_S
    for _ in range(rp.PACE_SLOW_VOTES):  # the device slows down to the wire (or was never fast): back to the wire
        assert pacing.faster_than_wire
        pacing.sent(t, 26)
        pacing.complete(t + 1.2 * wire_s, 252, 12 * 500e-6)
        t += 0.02
    assert not pacing.faster_than_wire and not pacing.verdicts


def test_one_fast_reply_is_not_enough_and_replies_of_a_given_up_read_are_never_judged():
    pacing = rp.ReplyPacing(BYTE_S)
    pacing.sent(0.0, 26)
    pacing.complete(0.0001, 252, 0.006)
    assert not pacing.faster_than_wire  # one vote
    pacing.sent(0.02, 26)
    pacing.gave_up(0.03, 120, 0.003)  # a read given up at its deadline with 120 bytes (and 6 replies) missing
    assert pacing.stale_until_s == pytest.approx(0.03 + 120 * BYTE_S + 0.003 + rp.STALE_SLACK_S)
    for k in range(4):  # instructions sent while those replies may still cross: their quick bytes are not judged
        pacing.sent(0.035 + 0.005 * k, 26)
        assert pacing.stale_possible
        pacing.received(252)
        pacing.judge_early(0.0351 + 0.005 * k)
        pacing.complete(0.0352 + 0.005 * k, 252, 0.006)
    assert not pacing.faster_than_wire and list(pacing.verdicts) == [True]
    pacing.sent(1.0, 26)  # long after: judged again
    assert not pacing.stale_possible


def test_bytes_beyond_what_the_wire_could_carry_are_judged_early_as_fast():
    pacing = rp.ReplyPacing(BYTE_S)
    pacing.sent(0.0, 26)  # the instruction leaves the wire at 0.26 ms
    pacing.received(200)
    pacing.judge_early(0.0003)  # 0.04 ms after: the wire could have carried 4 bytes, 200 came
    assert pacing.judged and list(pacing.verdicts) == [True]
    other = rp.ReplyPacing(BYTE_S)
    other.sent(0.0, 26)
    other.received(200)
    other.judge_early(0.0026 + 0.002)  # 2 ms after: 200 bytes fit the wire
    assert not other.judged and not other.verdicts


def test_the_first_wait_is_the_wires_bound_an_early_look_is_a_quarter_of_it_and_an_overdue_reply_backs_off():
    pacing = rp.ReplyPacing(BYTE_S)
    pacing.sent(0.0, 26)
    wire_s = 26 * BYTE_S + 252 * BYTE_S + 0.006
    wait, due = pacing.wait_s(0.0, 0, 252, 0.006, None, probe=False)
    assert wait == pytest.approx(wire_s) and due == pytest.approx(wire_s)
    assert pacing.probes()  # the first reads of a port look early
    early, due_early = pacing.wait_s(0.0, 0, 252, 0.006, None, probe=True)
    assert early == pytest.approx(rp.PACE_PROBE_FRACTION * wire_s) and due_early == pytest.approx(wire_s)
    # Overdue by 4 ms with 15 bytes missing: wait max(wire time of 15 bytes, min(2 ms, a quarter of the lateness)).
    late, _ = pacing.wait_s(wire_s + 0.004, 237, 15, 0.0, due, probe=False)
    assert late == pytest.approx(min(rp.MAX_LATE_POLL_S, rp.LATE_POLL_FRACTION * 0.004))
    very_late, _ = pacing.wait_s(wire_s + 0.5, 237, 15, 0.0, due, probe=False)
    assert very_late == pytest.approx(rp.MAX_LATE_POLL_S)  # never more than 2 ms between looks
    for _ in range(rp.PACE_PROBE_FIRST + 1):
        pacing.sent(1.0, 26)
    assert not pacing.probes() or pacing.transactions % rp.PACE_PROBE_EVERY == 0
