"""Playing a taught shape: the MotionSource for a shape, built and checked the same way for ``sensnake play`` and
the Gait tab (SPEC §5). Qt-free; any thread may call.

Where each limit is checked (once, not three times):
- here, before the robot is touched: the request's own arguments (``--speed`` positive and at most the robot's
  ``max_joint_speed_rad_s``, ``--shifts``, joint count and axes) and every angle of the shape and its keyframes
  against its joint's limits (:func:`devices.controller.joint_limit_error`, the one limit check);
- on the bus thread, in :meth:`devices.controller.RobotController.play`, one command: the plan made from the
  present pose (every target within the limits, no move above the max joint speed) before any goal is written;
  each tick's goal passes the same limit check (refused, never clamped) and the per-tick speed rail.
"""

from __future__ import annotations

import math

import numpy as np

from app.core.shapes import Shape
from devices.config import RobotConfig
from devices.controller import joint_limit_error
from models.trajectory import FollowTheLeader, Keyframes, PlannedMotion


def check_shape_limits(shape: Shape, robot: RobotConfig) -> None:
    """JointLimitError (a ValueError) naming joint, value and limit if the shape or a keyframe lies beyond a joint
    limit; nothing is clamped."""
    error = joint_limit_error(robot, np.asarray(shape.angles_rad), f"shape {shape.name!r}")
    if error is not None:
        raise error
    for i, key in enumerate(shape.keyframes):
        error = joint_limit_error(robot, np.asarray(key.angles_rad), f"shape {shape.name!r}, keyframe {key.name or f'#{i + 1}'}")
        if error is not None:
            raise error


def check_shape_fits(shape: Shape, robot: RobotConfig) -> None:
    """ValueError naming the mismatch if ``shape`` is not one this robot can play: another joint count, other joint
    axes, or an angle (of the shape or a keyframe) beyond a joint limit. Shared by ``play``, the Gait tab and
    ``experiment run``."""
    if shape.n_joints != robot.n_joints:
        raise ValueError(f"the shape has {shape.n_joints} joints but the robot has {robot.n_joints}")
    if tuple(shape.axes) != tuple(robot.axes):
        raise ValueError("the shape's joint axes differ from the robot's (robot.axes in the config): "
                         f"shape {list(shape.axes)}, robot {list(robot.axes)}")
    check_shape_limits(shape, robot)


def build_source(shape: Shape, robot: RobotConfig, mode: str, speed_rad_s: float, time_scale: float,
                 shifts: int | None, repeat: int = 1) -> PlannedMotion:
    """The MotionSource for a shape, sampled at ``robot.control_rate_hz`` (raises ValueError with a clear message
    before anything moves). Shared by ``sensnake play`` and the Gait tab; start it with
    :meth:`devices.controller.RobotController.play`."""
    check_shape_fits(shape, robot)
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
