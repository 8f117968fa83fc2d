"""``sensnake play SHAPE.json --robot PORT [--mode follow|keyframes] [--speed] [--time-scale] [--rate] [--shifts]
[--log LOG.csv]`` (SPEC §1, §5).

Plays a shape through :meth:`devices.controller.RobotController.play` with the source from
:func:`app.core.play.build_source` (the same code path as the Gait tab): one command on the bus thread holds the
limp joints, checks the plan against the joint limits and speed, then starts the motion, with the control loop ticking at ``--rate`` Hz (one synchronised write per tick), prints progress, writes the optional log
(``time_s, goal_rad_1..n, present_rad_1..n, current_mA_1..n``, one row per tick) and reports the control period's
p99 error at the end. A servo error or a lost link ends it with one clear line and a non-zero exit.
Runs on the main thread; the controller thread only appends states to a list the main thread drains.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import csv
import math
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from app.cli._robot import robot_config, start_controller
from app.core.play import build_source
from app.core.shapes import Shape, read_shape
from models.trajectory import PlannedMotion

PROGRESS_INTERVAL_S = 2.0
POLL_INTERVAL_S = 0.2


class StateLog:
    """States appended by the controller thread, drained (and optionally written to CSV) by the main thread."""

    def __init__(self, n_joints: int, out: TextIO | None) -> None:
        self._lock = threading.Lock()
        self._pending: list[Any] = []
        self._times: list[float] = []
        self._writer = csv.writer(out) if out is not None else None
        self.t0_s: float | None = None  # time.monotonic() when the motion started; states before it are skipped
        self.missed_ticks_before = 0  # the controller's missed ticks before the motion (start-up, torque on)
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


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.rate) and 0 < args.rate <= 1000):
        raise ValueError(f"--rate must be in (0, 1000] Hz, got {args.rate}")
    if not (math.isfinite(args.time_scale) and args.time_scale > 0):
        raise ValueError(f"--time-scale must be positive, got {args.time_scale}")
    shape = read_shape(args.shape)
    robot = replace(robot_config(args), control_rate_hz=float(args.rate))
    source = build_source(shape, robot, args.mode, args.speed, args.time_scale, args.shifts)
    log_file = open(args.log, "w", newline="", encoding="utf-8") if args.log else None  # noqa: SIM115
    try:
        state_log = StateLog(robot.n_joints, log_file)
        controller = start_controller(robot, on_state=state_log.on_state)
        try:
            outcome = _play(controller, source, state_log, args, shape)
        finally:
            missed_ticks = controller.stats().missed_ticks - state_log.missed_ticks_before
            scheduling = controller.scheduling
            controller.close()
            state_log.drain()
    finally:
        if log_file is not None:
            log_file.close()
    periods = state_log.periods_s()
    if periods.size:
        error_ms = np.abs(periods - 1.0 / args.rate) * 1000.0
        print(f"control period at {args.rate:g} Hz over {periods.size} ticks: "
              f"p50 {np.median(periods) * 1000:.2f} ms, p99 error {np.percentile(error_ms, 99):.2f} ms, "
              f"max error {error_ms.max():.2f} ms, missed ticks {missed_ticks}; bus thread: {scheduling}")
    if args.log:
        print(f"wrote {Path(args.log)}")
    return 0 if outcome == "finished" else 1


def _play(controller: Any, source: PlannedMotion, state_log: StateLog, args: argparse.Namespace,
          shape: Shape) -> str:
    name = f"{args.mode} {shape.name or Path(args.shape).stem}"
    state_log.missed_ticks_before = controller.stats().missed_ticks
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
    outcome = future.result()  # raises the servo error / lost link that stopped the motion
    if outcome == "finished":
        print(f"{source.progress.describe()}\nfinished")
    else:
        print(f"motion {outcome}")
    return outcome
