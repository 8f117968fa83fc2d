"""How long the servo port waits for reply bytes: the wait rule of :class:`devices.servo_chain._FactoryPortHandler`
as a small policy with explicit inputs (times in ``time.monotonic()`` seconds, byte counts, the wire's byte time, the
servos' Return Delay Times) and outputs (seconds to wait, and what the port learns), with no I/O and no clock of its
own — so it is unit-tested on traces (``tests/devices/test_reply_pacing.py``) and the port handler only feeds it
and sleeps.

The rule (measured, see ``benchmarks/bench_servo_bus.py``):

- **Wait for the wire, once.** The replies' bytes cannot all be in before the instruction has left the wire, the
  replies have crossed it at the baud rate and each replying servo's Return Delay Time has passed: sleep until then,
  in one wake-up (every wake-up of the bus thread has to win the interpreter lock back from the GUI).
- **Then wait for the bytes themselves** until the SDK's deadline; an overdue reply (a silent servo) is looked for
  every quarter of its lateness (at most 2 ms apart), so waiting out a timeout costs a few dozen wake-ups.
- **One fact is learned, on repeated evidence: a device faster than the wire** (the simulator on an accelerated
  clock). Whole replies in under half the wire's time are "fast", over 0.8 of it "slow"; two fast among the last
  four → replies are awaited at their observed pace (never past the wire's bound); three slow in a row → back to the
  wire's pace. The first 8 reads of a port and every 16th look once early (at a quarter of the wire's time), since a
  faster device is only seen before its replies are all in.
- **Replies of a read given up** (its deadline passed) may still cross during the next instructions: no transaction
  begun before they could all have arrived (at the wire's pace, plus 50 ms of lateness) is judged for pace.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

READ_POLL_S = 0.0001  # shortest wait while bytes are awaited
MAX_LATE_POLL_S = 0.002  # longest wait between looks for an overdue reply
LATE_POLL_FRACTION = 0.25  # an overdue reply is looked for every quarter of its lateness (≤ MAX_LATE_POLL_S)
FAST_FRACTION = 0.5
SLOW_FRACTION = 0.8
PACE_WINDOW = 4
PACE_FAST_VOTES = 2
PACE_SLOW_VOTES = 3
PACE_PROBE_FIRST = 8
PACE_PROBE_EVERY = 16
PACE_PROBE_FRACTION = 0.25
STALE_SLACK_S = 0.05
EARLY_BYTES_FACTOR = 2.0  # more bytes than this × what the wire could carry (+ EARLY_BYTES_SLACK): a faster device
EARLY_BYTES_SLACK = 4


@dataclass
class ReplyPacing:
    """The port's pacing state; the port calls :meth:`sent` when it writes an instruction, :meth:`received` when
    it takes bytes off the port, :meth:`judge_early` while it waits, :meth:`wait_s` for how long to wait for the
    rest, :meth:`gave_up` at a deadline and :meth:`complete` when a whole reply is in. One per port, on the thread
    that owns it."""

    byte_s: float  # one byte on the wire (10 bits) at the port's baud rate
    faster_than_wire: bool = False
    verdicts: deque[bool] = field(default_factory=lambda: deque(maxlen=PACE_WINDOW))
    slow_run: int = 0  # slow verdicts in a row
    stale_until_s: float = -math.inf  # until when replies of a read given up may still arrive
    stale_possible: bool = False  # the transaction in flight began before then
    judged: bool = False  # the transaction in flight has had its verdict
    transactions: int = 0
    rx_since_tx: int = 0  # bytes taken off the port since the last instruction
    wire_free_s: float = -math.inf  # when the bytes written have left the wire
    tx_start_s: float = -math.inf  # when the last instruction was handed to the port

    # -- events ------------------------------------------------------------------------------------------------------
    def sent(self, now_s: float, n_bytes: int) -> None:
        """An instruction of ``n_bytes`` was handed to the port at ``now_s``."""
        self.tx_start_s = now_s
        self.wire_free_s = max(now_s, self.wire_free_s) + n_bytes * self.byte_s
        self.stale_possible = now_s < self.stale_until_s
        self.judged = False
        self.transactions += 1
        self.rx_since_tx = 0

    def received(self, n_bytes: int) -> None:
        """``n_bytes`` were taken off the port."""
        self.rx_since_tx += n_bytes

    def judge_early(self, now_s: float) -> None:
        """Before the replies are all in: more bytes than the wire could have carried since the instruction left it
        came from a device faster than the wire -- or from a read given up before, whose replies cross now (those
        are not judged)."""
        if self.judged or self.stale_possible or not self.rx_since_tx:
            return
        capacity = max(0.0, now_s - self.wire_free_s) / self.byte_s
        if self.rx_since_tx > EARLY_BYTES_FACTOR * capacity + EARLY_BYTES_SLACK:
            self.judged = True
            self.verdict(True)

    def complete(self, now_s: float, n_bytes: int, delays_s: float) -> None:
        """The whole reply (``n_bytes`` from servos whose Return Delay Times add up to ``delays_s``) is in: how long
        it took against the least the wire needs for it."""
        if self.judged or self.stale_possible:
            return
        self.judged = True
        wire_s = self.wire_free_s - self.tx_start_s + n_bytes * self.byte_s + delays_s
        took_s = now_s - self.tx_start_s
        if took_s < FAST_FRACTION * wire_s:
            self.verdict(True)
        elif took_s > SLOW_FRACTION * wire_s:
            self.verdict(False)

    def verdict(self, fast: bool) -> None:
        """One transaction's pace: device pacing is taken up on repeated fast verdicts and dropped on slow ones."""
        self.verdicts.append(fast)
        self.slow_run = 0 if fast else self.slow_run + 1
        if not self.faster_than_wire and sum(self.verdicts) >= PACE_FAST_VOTES:
            self.faster_than_wire = True
        elif self.faster_than_wire and self.slow_run >= PACE_SLOW_VOTES:
            self.faster_than_wire = False
            self.verdicts.clear()

    def gave_up(self, now_s: float, missing_bytes: int, delays_s: float) -> None:
        """A read was given up at ``now_s`` with ``missing_bytes`` not in: they may cross during the next
        transactions, which are then not judged for pace."""
        missing_s = missing_bytes * self.byte_s + delays_s
        self.stale_until_s = max(self.stale_until_s, now_s + missing_s + STALE_SLACK_S)

    # -- the rule -----------------------------------------------------------------------------------------------------
    def probes(self) -> bool:
        """Whether this read looks once early (while replies are awaited at the wire's pace)."""
        return (not self.faster_than_wire and not self.judged and not self.stale_possible
                and (self.transactions <= PACE_PROBE_FIRST or self.transactions % PACE_PROBE_EVERY == 0))

    def wait_s(self, now_s: float, have_bytes: int, missing_bytes: int, delays_left_s: float,
               due_s: float | None, probe: bool) -> tuple[float, float | None]:
        """How long to wait now for ``missing_bytes`` more (``have_bytes`` already in; the servos still to answer
        have Return Delay Times adding up to ``delays_left_s``), and when the bytes were first due (``due_s``:
        None until this read's first wait, then what this returned). A look early (``probe``) on the first wait."""
        earliest_s = max(now_s, self.wire_free_s) if not have_bytes else now_s
        wire_wait_s = earliest_s - now_s + missing_bytes * self.byte_s + delays_left_s
        if self.faster_than_wire:
            elapsed_s = now_s - self.tx_start_s
            # Never past the wire's own bound: a device that is not faster after all costs wake-ups, not time.
            wait = min(missing_bytes * elapsed_s / have_bytes, wire_wait_s) if have_bytes else READ_POLL_S
            return wait, due_s
        wait = wire_wait_s
        if due_s is None:
            due_s = now_s + wait
            if probe:
                wait *= PACE_PROBE_FRACTION
        elif now_s > due_s:
            wait = max(wait, min(MAX_LATE_POLL_S, LATE_POLL_FRACTION * (now_s - due_s)))
        return wait, due_s
