"""Motion sources the tests drive the robot with (the MotionSource protocol of devices/controller.py)."""

from __future__ import annotations

import numpy as np


class JointRamp:
    """Moves joint ``index`` away from where it started at ``speed_rad_s`` for ``duration_s``."""

    def __init__(self, index: int = 0, speed_rad_s: float = 0.5, duration_s: float = 30.0) -> None:
        self.index, self.speed_rad_s, self.duration_s = index, speed_rad_s, duration_s
        self.start: np.ndarray | None = None

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        if t_s > self.duration_s:
            return None
        if self.start is None:
            self.start = present_rad.copy()
        goal = self.start.copy()
        goal[self.index] += self.speed_rad_s * t_s
        return goal
