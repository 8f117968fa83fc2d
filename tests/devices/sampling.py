"""Reading a quantity as fast as it answers for a while, and the rate it changed at: for tests of a ramp a device
paces on its own (the rig's servo), against the host's clock."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np


def sampled_rate(read: Callable[[], float], seconds: float, window_s: tuple[float, float] = (0.2, 0.8)
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """``read()`` as often as it answers for ``seconds``: (times from the start (s), values, the least-squares rate
    of change per second over ``window_s``, clear of the start and the end)."""
    t0 = time.monotonic()
    samples = []
    while time.monotonic() - t0 < seconds:
        samples.append((time.monotonic() - t0, read()))
    t, values = np.array(samples).T
    inside = (t > window_s[0]) & (t < window_s[1])
    return t, values, float(np.polyfit(t[inside], values[inside], 1)[0])
