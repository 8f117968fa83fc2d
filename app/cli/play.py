"""``sensnake play SHAPE.json --robot PORT [--mode follow|keyframes] [--speed] [--time-scale] [--rate] [--shifts]
[--log LOG.csv]`` (SPEC §1, §5).

Plays a shape through :class:`devices.controller.RobotController` (the same code path as the Gait tab) with the
control loop ticking at ``--rate`` Hz (one synchronised write per tick), prints progress, writes the optional log
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

from app.cli._robot import BUS_TIMEOUT_S, robot_config, start_controller
from app.core.shapes import Shape, read_shape
from app.core.teach import TeachSession
from devices.config import RobotConfig
from models.trajectory import FollowTheLeader, Keyframes, PlannedMotion

PROGRESS_INTERVAL_S = 2.0
POLL_INTERVAL_S = 0.2


def build_source(shape: Shape, robot: RobotConfig, mode: str, speed_rad_s: float, time_scale: float,
                 shifts: int | None, repeat: int = 1) -> PlannedMotion:
    """The MotionSource for a shape, sampled at ``robot.control_rate_hz`` (raises ValueError with a clear message
    before anything moves). Shared by ``sensnake play`` and the Gait tab."""
    if shape.n_joints != robot.n_joints:
        raise ValueError(f"the shape has {shape.n_joints} joints but the robot has {robot.n_joints}")
    if tuple(shape.axes) != tuple(robot.axes):
        raise ValueError("the shape's joint axes differ from the robot's (robot.axes in the config): "
                         f"shape {list(shape.axes)}, robot {list(robot.axes)}")
    if not (math.isfinite(speed_rad_s) and 0 < speed_rad_s <= robot.max_joint_speed_rad_s):
        raise ValueError(f"--speed {speed_rad_s} rad/s must be positive and at most the robot's "
                         f"max_joint_speed_rad_s = {robot.max_joint_speed_rad_s} rad/s")
    if shifts is not None and shifts < 0:
        raise ValueError(f"--shifts must be 0 or more, got {shifts}")
    if mode == "follow":
        return FollowTheLeader(shape.angles_rad, shape.axes, speed_rad_s, shifts, repeat,
                               rate_hz=robot.control_rate_hz)
    if not shape.keyframes:
        raise ValueError("the shape has no keyframes: play it with --mode follow, or teach several poses")
    return Keyframes([k.t_s for k in shape.keyframes], [k.angles_rad for k in shape.keyframes],
                     time_scale=time_scale, approach_speed_rad_s=speed_rad_s,
                     velocity_limit_rad_s=robot.max_joint_speed_rad_s, joint_ids=robot.joint_ids,
                     names=[k.name or f"#{i + 1}" for i, k in enumerate(shape.keyframes)], repeat=repeat,
                     rate_hz=robot.control_rate_hz)


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
              f"max error {error_ms.max():.2f} ms, missed ticks {missed_ticks}")
    if args.log:
        print(f"wrote {Path(args.log)}")
    return 0 if outcome == "finished" else 1


def _play(controller: Any, source: PlannedMotion, state_log: StateLog, args: argparse.Namespace,
          shape: Shape) -> str:
    name = f"{args.mode} {shape.name or Path(args.shape).stem}"
    # Servos power up limp: torque on where they are (goals = present first, so nothing jumps) before moving.
    TeachSession(controller.submit, controller.robot, controller.set_torque).hold().result(timeout=BUS_TIMEOUT_S)
    state_log.missed_ticks_before = controller.stats().missed_ticks
    state_log.t0_s = time.monotonic()
    future = controller.run_motion(source, name)
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
