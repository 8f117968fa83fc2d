"""Motion sources the benchmarks play. In an importable module (not a benchmark's ``__main__``) so that they can be
pickled to the control loop's own process (devices.loop_process)."""

from __future__ import annotations

import numpy as np


class Wave:
    """Every joint follows a travelling sine wave (0.4 rad, 0.3 Hz): goals change every tick."""

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray:
        return 0.4 * np.sin(2 * np.pi * 0.3 * t_s + 0.6 * np.arange(present_rad.size))
