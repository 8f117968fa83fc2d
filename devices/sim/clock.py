"""Simulated time: real time by default, or faster than real time for tests (``speed`` > 1)."""

from __future__ import annotations

import time


class SimClock:
    """Monotonic simulated seconds since creation, advancing ``speed`` times faster than the wall clock.

    Physical models (servo motion, creep, frame emission) run on this clock; byte timings on the wire are divided
    by ``speed`` too, so a test at ``speed=20`` sees the same packets twenty times sooner. Thread-safe (read-only).
    """

    def __init__(self, speed: float = 1.0, wall0: float | None = None) -> None:
        """``wall0``: the ``time.monotonic()`` reading that is simulated time 0 (default: now); another process's
        clock passes its own, so both run on the same simulated time."""
        if not speed > 0:
            raise ValueError(f"clock speed must be positive, got {speed}")
        self.speed = float(speed)
        self._wall0 = time.monotonic() if wall0 is None else float(wall0)

    @property
    def wall0(self) -> float:
        """The ``time.monotonic()`` reading of simulated time 0."""
        return self._wall0

    def now(self) -> float:
        """Simulated seconds since the clock was created."""
        return (time.monotonic() - self._wall0) * self.speed

    def sim_from_wall(self, wall_monotonic_s: float) -> float:
        """Simulated time at a given ``time.monotonic()`` reading."""
        return (wall_monotonic_s - self._wall0) * self.speed

    def wall_from_sim(self, sim_s: float) -> float:
        """``time.monotonic()`` reading at which simulated time ``sim_s`` is reached."""
        return self._wall0 + sim_s / self.speed
