"""``sensnake play SHAPE.json --robot PORT [--mode follow|keyframes] [--speed] [--time-scale] [--rate] [--shifts]
[--log LOG.csv] [--strict] [--config LAB.toml]`` (SPEC §1, §5; without ``--robot`` the port is the config's).

Plays a shape through :meth:`devices.controller.RobotController.play` with the source from
:func:`app.core.play.build_source` (the same code path as the Gait tab): one command on the bus thread holds the
limp joints, checks the plan against the joint limits and speed, then starts the motion, with the control loop ticking at ``--rate`` Hz (one synchronised write per tick), prints progress, writes the optional log
(``time_s, goal_rad_1..n, present_rad_1..n, current_mA_1..n``, one row per tick) and reports the control period's
p99 error at the end. A servo error or a lost link ends it with one clear line and a non-zero exit; a servo in
hardware error found before anything moved is said so (never "motion stopped"), and every hardware error names the
command that clears it (``sensnake servo reboot --id N``).

When more than :data:`MISSED_TICKS_LIMIT` of the control ticks were missed, the command measures why (a bus cycle
timed on the bus thread, the USB adapter's latency timer, each servo's Return Delay Time, the longest tick) and says
the cause and its fix on stderr: a warning (exit 0, the SPEC's contract: the motion finished), or with ``--strict``
the error line and exit 1.
Runs on the main thread; the controller thread only appends states to a list the main thread drains.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import csv
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from app.cli._robot import BUS_TIMEOUT_S, reworded, robot_config, start_controller
from app.core.outputs import check_output, create_temporary, move_into_place
from app.core.play import build_source
from app.core.shapes import read_shape
from devices.errors import DeviceError, ServoHardwareError
from models.trajectory import PlannedMotion

PROGRESS_INTERVAL_S = 2.0
POLL_INTERVAL_S = 0.2
MISSED_TICKS_LIMIT = 0.01  # a share of the control ticks: more missed, and the cause is measured and said
BUS_SHARE_LIMIT = 0.5  # a bus cycle filling more of a tick leaves no room for the host's latency and the health poll
CYCLES_MEASURED = 5


class StateLog:
    """States appended by the controller thread, drained (and optionally written to CSV) by the main thread."""

    def __init__(self, n_joints: int, out: TextIO | None) -> None:
        self._lock = threading.Lock()
        self._pending: list[Any] = []
        self._times: list[float] = []
        self._writer = csv.writer(out) if out is not None else None
        self.t0_s: float | None = None  # time.monotonic() when the motion started; states before it are skipped
        self.missed_ticks_before = 0  # the controller's missed ticks before the motion (start-up, torque on)
        self.late_reads_before = 0  # and its feedback reads given up (replies late) before it
        if self._writer is not None:
            header = ["time_s"] + [f"goal_rad_{i}" for i in range(1, n_joints + 1)] + \
                [f"present_rad_{i}" for i in range(1, n_joints + 1)] + \
                [f"current_mA_{i}" for i in range(1, n_joints + 1)]
            self._writer.writerow(header)

    def on_state(self, state: Any) -> None:  # controller thread: keep it short
        with self._lock:
            self._pending.append(state)

    def drain(self) -> None:
        with self._lock:
            states, self._pending = self._pending, []
        if self.t0_s is None:
            return
        for s in states:
            if s.host_time_s < self.t0_s:
                continue
            self._times.append(s.host_time_s)
            if self._writer is not None:
                goal = s.goal_rad if s.goal_rad is not None else np.full(len(s.position_rad), np.nan)
                self._writer.writerow([f"{s.host_time_s - self.t0_s:.4f}", *(f"{v:.5f}" for v in goal),
                                       *(f"{v:.5f}" for v in s.position_rad), *(f"{v:.1f}" for v in s.current_ma)])

    def periods_s(self) -> np.ndarray:
        return np.diff(np.asarray(self._times))

    @property
    def ticks(self) -> int:
        """Control ticks read since the motion started."""
        return len(self._times)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.rate) and 0 < args.rate <= 1000):
        raise ValueError(f"--rate must be in (0, 1000] Hz, got {args.rate}")
    if not (math.isfinite(args.time_scale) and args.time_scale > 0):
        raise ValueError(f"--time-scale must be positive, got {args.time_scale}")
    robot = replace(robot_config(args), control_rate_hz=float(args.rate))  # a usage error first, as argparse's
    shape = read_shape(args.shape)
    source = build_source(shape, robot, args.mode, args.speed, args.time_scale, args.shifts)
    name = f"{args.mode} {shape.name or Path(args.shape).stem}"
    started = threading.Event()  # set on the controller thread once the motion has started (torque on)

    def on_event(text: str) -> None:  # controller thread
        if text == f"motion {name!r} started":
            started.set()

    log_file, log_work = _open_log(args.log)
    log_target = Path(args.log) if args.log else None
    diagnosis = None
    try:
        state_log = StateLog(robot.n_joints, log_file)
        controller = start_controller(robot, on_state=state_log.on_state, on_event=on_event)
        try:
            outcome = _play(controller, source, state_log, args, name, started)
            stats = controller.stats()
            missed_ticks = stats.missed_ticks - state_log.missed_ticks_before
            blind_ticks = stats.late_reads - state_log.late_reads_before
            state_log.drain()
            slots = state_log.ticks + blind_ticks + missed_ticks
            if slots and missed_ticks + blind_ticks > MISSED_TICKS_LIMIT * slots:
                diagnosis = missed_ticks_cause(controller, missed_ticks, slots, state_log.periods_s(), args.rate,
                                               blind_ticks)
        finally:
            scheduling = controller.scheduling
            controller.close()
            state_log.drain()
    finally:
        if log_file is not None and log_work is not None and log_target is not None:
            log_file.close()
            _keep_log(log_work, log_target, keep=started.is_set())
    periods = state_log.periods_s()
    if periods.size:
        error_ms = np.abs(periods - 1.0 / args.rate) * 1000.0
        print(f"control period at {args.rate:g} Hz over {periods.size} ticks read: "
              f"p50 {np.median(periods) * 1000:.2f} ms, p99 error {np.percentile(error_ms, 99):.2f} ms, "
              f"max error {error_ms.max():.2f} ms, missed ticks {missed_ticks}, ticks without feedback "
              f"{blind_ticks}; bus thread: {scheduling}")
    if args.log and started.is_set():
        print(f"wrote {Path(args.log)}")
    if diagnosis is not None:
        if args.strict:
            raise RuntimeError(diagnosis)
        print(f"sensnake play: warning: {diagnosis} (--strict makes this an error)", file=sys.stderr)
    return 0 if outcome == "finished" else 1


def _open_log(log: str | None) -> tuple[TextIO | None, Path | None]:
    """The ``--log`` CSV's hidden temporary beside it (:mod:`app.core.outputs`: only a regular file is ever
    replaced; a FIFO, whose open would wait for a reader, or a device is refused before the bus is opened), open
    for writing, and its path; (None, None) without ``--log``."""
    if not log:
        return None, None
    target = check_output(log)
    try:
        fd, work = create_temporary(target)
    except OSError as exc:  # the user's path in the message, never the hidden temporary's
        raise OSError(exc.errno, f"cannot write {target}: {exc.strerror or exc}") from None
    return os.fdopen(fd, "w", newline="", encoding="utf-8"), work


def _keep_log(work: Path, target: Path, keep: bool) -> None:
    """Move the finished log into place, also after a motion that stopped (what it logged tells why); a motion that
    never started logged nothing: the temporary is removed and a file at ``target`` left as it was."""
    if not keep:
        work.unlink(missing_ok=True)
        return
    try:
        move_into_place(work, target)
    except BaseException:
        work.unlink(missing_ok=True)
        raise


@dataclass(frozen=True)
class BusTiming:
    """What the bus thread measured of the bus, for :func:`describe_missed_ticks`."""

    cycle_s: float  # median sync read, plus the goals' sync write on the wire
    latency_timer_ms: int | None  # the USB adapter's (Linux), None where there is none (pty, sim)
    latency_fix: str | None  # how to set it to 1 ms, when it is above
    return_delays_s: dict[int, float]  # each servo's Return Delay Time


def missed_ticks_cause(controller: Any, missed: int, slots: int, periods_s: np.ndarray, rate_hz: float,
                       blind: int = 0) -> str:
    """Measure the bus on the bus thread (between ticks; the motion is over) and describe the missed ticks and
    those that ran without feedback (``blind``: their read given up, the replies late)."""
    def measure(chain: Any) -> BusTiming:
        return BusTiming(chain.measure_cycle_s(CYCLES_MEASURED), chain.latency_timer_ms(), chain.latency_warning(),
                         chain.return_delays_s)

    try:
        timing = controller.submit(measure).result(timeout=BUS_TIMEOUT_S)
    except (DeviceError, TimeoutError):  # the bus is gone or busy: say what the ticks alone tell
        timing = BusTiming(math.nan, None, None, {})
    longest_s = float(periods_s.max()) if periods_s.size else math.nan
    return describe_missed_ticks(missed, slots, rate_hz, timing, longest_s, controller.scheduling, blind)


def describe_missed_ticks(missed: int, slots: int, rate_hz: float, timing: BusTiming, longest_period_s: float,
                          scheduling: str, blind: int = 0) -> str:
    """One line: how many ticks were missed (and ran without feedback: ``blind``), what was measured, each cause
    found with its fix."""
    period_s = 1.0 / rate_hz
    causes = []
    if timing.latency_timer_ms is not None and timing.latency_timer_ms > 1:
        causes.append(f"the USB adapter's latency timer is {timing.latency_timer_ms} ms (16 ms is the adapters' "
                      f"default; a servo bus needs 1 ms: each reply waits up to that long) — {timing.latency_fix}")
    delays = {sid: d for sid, d in timing.return_delays_s.items() if d > 0}
    if delays:
        worst_us = max(delays.values()) * 1e6
        cost_ms = sum(delays.values()) * 1e3
        causes.append(f"Return Delay Time up to {worst_us:.0f} µs on servo(s) {_ids(sorted(delays))} adds "
                      f"{cost_ms:.1f} ms to every tick's read — fix: sensnake servo set --id N \"Return Delay Time\" 0 "
                      "on each")
    if timing.cycle_s > BUS_SHARE_LIMIT * period_s:
        fastest_hz = math.floor(BUS_SHARE_LIMIT / timing.cycle_s)
        causes.append(f"the bus cycle fills {timing.cycle_s / period_s:.0%} of a tick — fix: --rate {fastest_hz} "
                      "or lower, or a faster baud rate")
    cycle_s = timing.cycle_s if math.isfinite(timing.cycle_s) else 0.0
    if math.isfinite(longest_period_s) and longest_period_s > max(2 * period_s, 3 * cycle_s):
        priority = "" if scheduling.startswith("real-time") else ", give the loop real-time priority (docs/REALTIME.md)"
        causes.append(f"the longest time between two ticks' readings was {longest_period_s * 1e3:.0f} ms, "
                      f"{longest_period_s / max(cycle_s, period_s):.0f}× a tick's period: replies came late or this "
                      f"machine held the loop back (bus thread: {scheduling}) — fix: close other busy programs"
                      f"{priority}, or lower --rate")
    if not causes:
        causes.append(f"no single cause stands out (bus thread: {scheduling}) — fix: lower --rate")
    cycle = f"a bus cycle measured {timing.cycle_s * 1e3:.1f} ms" if math.isfinite(timing.cycle_s) else \
        "the bus cycle could not be measured"
    short = missed + blind
    what = f"{missed} of {slots} control ticks missed" if not blind else (
        f"{short} of {slots} control ticks missed or run without feedback ({missed} missed, {blind} whose servo "
        "replies came too late for the tick: it wrote its goal from the last angles read)")
    return (f"{what} ({short / slots:.1%}, more than "
            f"{MISSED_TICKS_LIMIT:.0%}) at {rate_hz:g} Hz ({period_s * 1e3:.1f} ms a tick; {cycle}): "
            + "; ".join(causes))


def _ids(ids: list[int]) -> str:
    return ", ".join(str(i) for i in ids)


def _play(controller: Any, source: PlannedMotion, state_log: StateLog, args: argparse.Namespace, name: str,
          started: threading.Event) -> str:
    before = controller.stats()
    state_log.missed_ticks_before, state_log.late_reads_before = before.missed_ticks, before.late_reads
    state_log.t0_s = time.monotonic()
    # One command: servos power up limp, so torque on where they are, check the plan, then move.
    future = controller.play(source, name)
    print(f"playing {name} at {args.speed:g} rad/s, {args.rate:g} Hz")
    last_print = -math.inf
    last_index = -1
    try:
        while True:
            done, _ = concurrent.futures.wait([future], timeout=POLL_INTERVAL_S)
            state_log.drain()
            progress = source.progress
            now = time.monotonic()
            if progress.index != last_index or now - last_print >= PROGRESS_INTERVAL_S:
                print(progress.describe(), flush=True)
                last_print, last_index = now, progress.index
            if done:
                break
    except KeyboardInterrupt:
        controller.stop_motion()
        raise
    try:
        outcome = future.result()  # raises the servo error / lost link that stopped the motion
    except ServoHardwareError as exc:
        when = "motion stopped" if started.is_set() else "found before the motion started, nothing moved"
        raise reworded(exc, when) from None
    if outcome == "finished":
        print(f"{source.progress.describe()}\nfinished")
    else:
        print(f"motion {outcome}")
    return outcome
