"""The joint-direction check: move one joint a little the positive way and back, and ask the user whether
it went the way the app's convention says; a "no" flips that joint's sign in the lab config.

The convention (:mod:`models.kinematics`): a positive pitch angle lifts what is behind the joint (toward the tail); a
positive yaw angle swings it to the robot's right. A joint whose ``[robot] signs`` entry is wrong moves the other way
on every command — a gait would bend the body backwards there, and the forces it feels would be read mirrored.

Qt-free: :class:`JointNudge` is a motion source the controller plays (it pickles, so it runs in the control loop's own
process too); the Hardware tab asks the question and writes the answer.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from app.core import servo_settings

NUDGE_RAD = 0.15  # ≈ 9°: visible at a glance, small enough to be safe on a robot lying on the floor
RAMP_S = 1.0
HOLD_S = 1.0


class JointNudge:
    """From where the robot is: joint ``joint`` goes +``amplitude_rad`` over ``ramp_s`` (smoothly), stays ``hold_s``,
    and comes back over ``ramp_s``; every other joint holds its angle. Ends (``None``) back where it started."""

    def __init__(self, joint: int, amplitude_rad: float = NUDGE_RAD, ramp_s: float = RAMP_S,
                 hold_s: float = HOLD_S) -> None:
        if not 0 < abs(amplitude_rad) <= 0.5:
            raise ValueError(f"a direction check moves a joint by at most 0.5 rad, not {amplitude_rad}")
        self.joint = int(joint)
        self.amplitude_rad = float(amplitude_rad)
        self.ramp_s = float(ramp_s)
        self.hold_s = float(hold_s)
        self.start_rad: np.ndarray | None = None

    @property
    def duration_s(self) -> float:
        return 2 * self.ramp_s + self.hold_s

    def fraction(self, t_s: float) -> float:
        """How far out the joint is at ``t_s`` (0 … 1 … 0; a half-cosine ramp each way)."""
        if t_s <= 0 or t_s >= self.duration_s:
            return 0.0
        if t_s < self.ramp_s:
            return 0.5 - 0.5 * math.cos(math.pi * t_s / self.ramp_s)
        if t_s <= self.ramp_s + self.hold_s:
            return 1.0
        back = (t_s - self.ramp_s - self.hold_s) / self.ramp_s
        return 0.5 + 0.5 * math.cos(math.pi * back)

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        if self.start_rad is None:
            self.start_rad = np.array(present_rad, dtype=float)
        if t_s > self.duration_s:
            return None
        goal = self.start_rad.copy()
        goal[self.joint] += self.amplitude_rad * self.fraction(t_s)
        return goal


def question(joint: int, servo_id: int, axis: str) -> str:
    """What the user is asked after the nudge."""
    where = (f"joint {joint + 1} (servo {servo_id}, {axis})")
    if axis == "pitch":
        seen = "the part of the body behind it (toward the tail) LIFTED UP off the floor, then came back down"
    else:
        seen = ("the part of the body behind it (toward the tail) swung to the robot's RIGHT (seen from above, head "
                "pointing away from you), then came back")
    return (f"Did {where} move this way: {seen}?\n\nYes: its sign is right. No: it moved the other way, and its "
            "sign is flipped in your lab config.")


def flipped_signs(signs: Sequence[int], joint: int) -> list[int]:
    """``signs`` with joint ``joint``'s entry reversed."""
    out = [int(s) for s in signs]
    out[joint] = -out[joint]
    return out


def write_signs(config_path: str | os.PathLike[str], signs: Sequence[int]) -> Path:
    """Set ``[robot] signs`` in the lab config (every other line kept; the file before kept as ``.bak-N``, returned)."""
    return servo_settings.write_robot_key(config_path, "signs", [str(int(s)) for s in signs])
