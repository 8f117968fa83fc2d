"""Streaming per-sensor health for the force-sensor board: pure numpy, no Qt, no I/O.

A :class:`HealthMonitor` keeps the last ``window_s`` seconds of every sensor's conductance in a preallocated ring and,
at most every ``eval_interval_s``, classifies each sensor:

- ``DISCONNECTED``: every sample in the window reads open (conductance ≤ ``open_s``) although the sensor's resting
  baseline is clearly above open: a cable is off. Needs a baseline (see below): an unloaded piezo-resistive sensor
  reads open too, so without one an open channel is not flagged.
- ``DROPOUT``: isolated samples read open between samples that read a clear load (``> loaded_s``) of about the same
  size, at least ``DROPOUT_MIN_COUNT`` times in the window: a loose contact dropping in and out. A released contact
  decays over several samples, or bounces once lightly, and is not counted; nor is one open sample alone, which a
  grazing contact gives (a segment's sheet touching at 0.02–0.04 N with its creep still in it reads 67–81 µS, and 0
  for the one frame it lets go: the physics lab's pitch walk over the obstacle at 0.1 rad/s).
- ``NOISY``: the sample-to-sample noise (what is left after a 3-sample median: a moving load is not noise) is far
  above the other loaded sensors' (the paper's loose sensor 10, 3R, 4B,
  11L).
- ``FLAT``: a loaded sensor whose reading has not changed by more than ``flat_tol_s`` in the whole window while most
  loaded sensors have: a stuck channel or a frozen multiplexer line.
- ``SATURATED``: the board flagged saturation (ADC counts = 0) at least once in the window.
- ``BELOW_BASELINE``: the window's median sits clearly below the sensor's resting baseline: the paper's "negative
  pressure" drift. The baseline is the resting conductance, set with :meth:`HealthMonitor.set_baseline` (the Forces
  tab's "rest baseline" button) or measured over the first ``baseline_s`` seconds when that is > 0; a baseline taken
  while the robot carries a load would flag every segment that later lifts, hence off by default.

Noise and flatness are judged against the population of loaded sensors because the absolute noise of a sensor depends
on its load and the readout; with fewer than four loaded sensors only the absolute thresholds apply.

Thread use: a monitor is not thread-safe; call it from one thread (the GUI thread in the Forces tab).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

# median |x − median of 3| of white noise is 0.3145 σ; the old estimate (median |second difference| / 1.95) read
# 0.848 σ, which the thresholds below were set for
NOISE_SCALE = 0.3145 / 0.848
DROPOUT_STEADY_RATIO = 0.5  # a dropout's neighbours read within this factor of each other
DROPOUT_MIN_COUNT = 2  # isolated open samples in one window before a sensor is called dropping out


class SensorHealth(enum.IntFlag):
    OK = 0
    FLAT = 1
    NOISY = 2
    DROPOUT = 4
    DISCONNECTED = 8
    SATURATED = 16
    BELOW_BASELINE = 32


_FLAG_WORDS = {
    SensorHealth.DISCONNECTED: "disconnected",
    SensorHealth.DROPOUT: "dropping out",
    SensorHealth.NOISY: "noisy (loose?)",
    SensorHealth.FLAT: "flat-lined",
    SensorHealth.SATURATED: "saturated",
    SensorHealth.BELOW_BASELINE: "below baseline",
}

# Flags that mean the reading cannot be trusted at all (shown in red); the others are warnings.
BAD_FLAGS = SensorHealth.DISCONNECTED | SensorHealth.DROPOUT | SensorHealth.NOISY | SensorHealth.FLAT


def trusted(flags: np.ndarray) -> np.ndarray:
    """Per sensor, whether its reading may be trusted (no flag of ``BAD_FLAGS``: a saturated or below-baseline
    sensor still reads, a disconnected, dropping-out, noisy or flat-lined one does not)."""
    return (np.asarray(flags).astype(int) & int(BAD_FLAGS)) == 0


def describe(flags: int) -> str:
    """Human words for a flag value, e.g. ``"noisy (loose?), saturated"``; ``"ok"`` for none."""
    words = [word for flag, word in _FLAG_WORDS.items() if flags & flag]
    return ", ".join(words) if words else "ok"


@dataclass(frozen=True)
class HealthThresholds:
    """Detection thresholds; conductances in siemens, times in seconds."""

    window_s: float = 2.0
    eval_interval_s: float = 0.25
    open_s: float = 1e-6              # at or below this a channel reads open circuit
    loaded_s: float = 5e-6            # above this a sensor clearly carries load
    flat_tol_s: float = 0.0           # range within which a window counts as "did not move"
    noisy_factor: float = 6.0         # × the loaded population's median noise
    noisy_min_s: float = 2e-6         # absolute floor for "noisy" (≈ 5 ADC steps of the default readout)
    baseline_s: float = 0.0           # > 0: measure the baseline over the first baseline_s seconds
    below_baseline_frac: float = 0.15  # median this fraction below the baseline


@dataclass(frozen=True)
class HealthReport:
    """One evaluation: ``flags`` (C,) uint8 of :class:`SensorHealth`; ``noise_s`` and ``level_s`` per sensor (S);
    ``changed`` the sensor indices whose flags differ from the previous evaluation."""

    t_s: float
    flags: np.ndarray
    noise_s: np.ndarray
    level_s: np.ndarray
    changed: np.ndarray


class HealthMonitor:
    """Streaming health classifier over ``n_sensors`` channels sampled at about ``rate_hz``."""

    def __init__(self, n_sensors: int, rate_hz: float, thresholds: HealthThresholds | None = None) -> None:
        if n_sensors < 1:
            raise ValueError(f"n_sensors must be ≥ 1, got {n_sensors}")
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.thresholds = thresholds or HealthThresholds()
        self.n_sensors = n_sensors
        self._capacity = max(8, int(round(self.thresholds.window_s * rate_hz)))
        self._values = np.zeros((self._capacity, n_sensors))
        self._saturated = np.zeros((self._capacity, n_sensors), dtype=bool)
        self._times = np.zeros(self._capacity)
        self._baseline_need = int(round(self.thresholds.baseline_s * rate_hz))
        self._baseline_sum = np.zeros(n_sensors)
        self._baseline_samples: list[np.ndarray] = []
        self._baseline_count = 0
        self.baseline_s: np.ndarray | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the window (e.g. after a reconnect); the baseline is kept."""
        self._write = 0
        self._filled = 0
        self._last_eval_t = -np.inf
        self.flags = np.zeros(self.n_sensors, dtype=np.uint8)
        self.report: HealthReport | None = None

    def set_baseline(self, baseline_s: np.ndarray) -> None:
        """Set the resting conductance (S) of every sensor instead of measuring it."""
        baseline_s = np.asarray(baseline_s, dtype=float)
        if baseline_s.shape != (self.n_sensors,):
            raise ValueError(f"baseline must have shape ({self.n_sensors},), got {baseline_s.shape}")
        self.baseline_s = baseline_s.copy()

    def update(self, t_s: np.ndarray, conductance_s: np.ndarray,
               saturated: np.ndarray | None = None) -> HealthReport | None:
        """Add samples: ``t_s`` (N,) seconds, ``conductance_s`` (N×C) siemens, ``saturated`` (N×C) bool.

        Returns a new :class:`HealthReport` when an evaluation was due (at most every ``eval_interval_s``), else
        ``None``; the latest flags are always in :attr:`flags`.
        """
        t_s = np.asarray(t_s, dtype=float)
        values = np.asarray(conductance_s, dtype=float)
        if values.ndim != 2 or values.shape[1] != self.n_sensors or values.shape[0] != t_s.shape[0]:
            raise ValueError(f"expected t (N,) and conductance (N×{self.n_sensors}), got {t_s.shape}, {values.shape}")
        n = values.shape[0]
        if n == 0:
            return None
        if saturated is None:
            saturated = np.zeros(values.shape, dtype=bool)
        self._collect_baseline(values)
        if n > self._capacity:
            t_s, values, saturated = t_s[-self._capacity:], values[-self._capacity:], saturated[-self._capacity:]
            n = self._capacity
        first = min(n, self._capacity - self._write)
        for src, dst in ((slice(0, first), slice(self._write, self._write + first)),
                         (slice(first, n), slice(0, n - first))):
            self._values[dst] = values[src]
            self._saturated[dst] = saturated[src]
            self._times[dst] = t_s[src]
        self._write = (self._write + n) % self._capacity
        self._filled = min(self._capacity, self._filled + n)
        now = float(t_s[-1])
        if now - self._last_eval_t < self.thresholds.eval_interval_s:
            return None
        self._last_eval_t = now
        return self._evaluate(now)

    # -- internals -------------------------------------------------------------------------------------------------
    def _collect_baseline(self, values: np.ndarray) -> None:
        if self.baseline_s is not None or self._baseline_need <= 0:
            return
        take = values[: self._baseline_need - self._baseline_count]
        self._baseline_samples.append(take.copy())
        self._baseline_count += take.shape[0]
        if self._baseline_count >= self._baseline_need:
            # Median, not mean: the baseline must not be dragged by a touch during start-up.
            self.baseline_s = np.median(np.concatenate(self._baseline_samples), axis=0)
            self._baseline_samples = []

    def _ordered(self) -> tuple[np.ndarray, np.ndarray]:
        if self._filled < self._capacity:
            return self._values[: self._filled], self._saturated[: self._filled]
        order = np.r_[self._write:self._capacity, 0:self._write]
        return self._values[order], self._saturated[order]

    def _evaluate(self, now_s: float) -> HealthReport:
        th = self.thresholds
        values, saturated = self._ordered()
        flags = np.zeros(self.n_sensors, dtype=np.uint8)
        is_open = values <= th.open_s
        open_count = is_open.sum(axis=0)
        level = np.median(values, axis=0)
        noise = np.zeros(self.n_sensors)
        if values.shape[0] >= 3:
            # Each sample's distance from the median of itself and its two neighbours: 0 wherever the signal is
            # locally monotone (a load rising or falling, however fast or curved, as under a moving robot), not for
            # chatter. Scaled so that white noise reads as the old |second difference| estimate did (0.85 σ).
            three = np.stack([values[:-2], values[1:-1], values[2:]])
            noise = np.median(np.abs(values[1:-1] - np.median(three, axis=0)), axis=0) / NOISE_SCALE
        full = self._filled >= self._capacity
        if full:
            all_open = open_count == values.shape[0]
            has_rest_level = (self.baseline_s > th.loaded_s) if self.baseline_s is not None else np.zeros_like(all_open)
            flags[all_open & has_rest_level] |= np.uint8(SensorHealth.DISCONNECTED)
            if values.shape[0] >= 3:
                loaded = values > th.loaded_s
                before, after = values[:-2], values[2:]
                # … between two samples of about the same load: a contact that is let go and touched again lightly
                # (a release's bounce: 99 µS, open, 8 µS) is not a loose wire dropping out of a steady reading
                steady = np.minimum(before, after) >= DROPOUT_STEADY_RATIO * np.maximum(before, after)
                isolated_drop = is_open[1:-1] & loaded[:-2] & loaded[2:] & steady
                flags[isolated_drop.sum(axis=0) >= DROPOUT_MIN_COUNT] |= np.uint8(SensorHealth.DROPOUT)
            reading = level > th.open_s
            value_range = np.ptp(values, axis=0)
            moving = value_range > th.flat_tol_s
            population_moves = reading.sum() < 4 or np.mean(moving[reading]) > 0.5
            pinned = saturated.all(axis=0)  # held at the readout's ceiling: saturated (below), not stuck
            if population_moves:
                flags[reading & ~moving & ~pinned] |= np.uint8(SensorHealth.FLAT)
            noisy = noise > th.noisy_min_s
            if reading.sum() >= 4:
                noisy &= noise > th.noisy_factor * np.median(noise[reading])
            # Dropouts do not hide noise: the median ignores sparse drops, so a loose sensor can be both.
            flags[noisy & ~all_open] |= np.uint8(SensorHealth.NOISY)
            if self.baseline_s is not None:
                below = level < self.baseline_s * (1.0 - th.below_baseline_frac)
                flags[below & (open_count == 0) & (self.baseline_s > th.loaded_s)] |= np.uint8(
                    SensorHealth.BELOW_BASELINE)
        flags[saturated.any(axis=0)] |= np.uint8(SensorHealth.SATURATED)
        changed = np.flatnonzero(flags != self.flags)
        self.flags = flags
        self.report = HealthReport(t_s=now_s, flags=flags, noise_s=noise, level_s=level, changed=changed)
        return self.report
