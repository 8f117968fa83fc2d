"""The paper's linear calibration (Eq. 1): ``C = m·F + d`` (C in siemens, F in newtons), pure numerics.

The paper fits one point per trial: the mean conductance over 225–300 s of a constant-force hold, against the applied
force. Optional "negative pressure" drift handling: the paper offsets each sensor's force by the absolute value of its
most negative reading (Fig. 6 caption, :func:`paper_negative_offset`); the alternative here is a per-trial baseline
(the conductance before loading) subtracted before fitting and, live, a per-sensor baseline subtracted before the
inverse, with readings below it clipped to 0 N and reported.

Everything here is pure and may be called from any thread.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

DEFAULT_WINDOW_S = (225.0, 300.0)
# A sample counts as "loaded" once the applied force exceeds this fraction of the trial's largest force.
LOADED_FRACTION = 0.05


@dataclass(frozen=True)
class LinearModel:
    """``C = m·F + d``: slope ``m_S_per_N`` (S/N) and intercept ``d_S`` (S), finite."""

    m_S_per_N: float
    d_S: float

    def __post_init__(self) -> None:
        for key in ("m_S_per_N", "d_S"):
            value = getattr(self, key)
            if isinstance(value, bool) or not math.isfinite(float(value)):
                raise ValueError(f"linear model {key} must be a finite number, got {value!r}")
            object.__setattr__(self, key, float(value))

    def conductance_from_force(self, force_n: np.ndarray) -> np.ndarray:
        """Conductance (S) for force (N)."""
        return self.m_S_per_N * np.asarray(force_n, dtype=np.float64) + self.d_S

    def force_from_conductance(self, conductance_s: np.ndarray) -> np.ndarray:
        """Force (N) for conductance (S); negative where C < d (not clipped here). ValueError if m ≤ 0."""
        if not self.m_S_per_N > 0.0:
            raise ValueError(
                f"linear model slope m_S_per_N = {self.m_S_per_N!r} must be > 0 to invert (refit the sensor)"
            )
        return (np.asarray(conductance_s, dtype=np.float64) - self.d_S) / self.m_S_per_N

    @staticmethod
    def fit(force_n: Sequence[float], conductance_s: Sequence[float]) -> LinearFit:
        """Same as :func:`fit_linear` (one point per trial)."""
        return fit_linear(force_n, conductance_s)

    @staticmethod
    def fit_trials(
        trials: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
        window_s: tuple[float, float] = DEFAULT_WINDOW_S,
        subtract_baseline: bool = False,
    ) -> LinearFit:
        """Same as :func:`fit_linear_trials` (whole trials, the paper's window means)."""
        return fit_linear_trials(trials, window_s, subtract_baseline)

    @classmethod
    def from_dict(cls, data: dict) -> LinearModel:
        missing = [key for key in ("m_S_per_N", "d_S") if key not in data]
        if missing:
            raise ValueError(f"linear is missing key(s) {', '.join(missing)}")
        return cls(data["m_S_per_N"], data["d_S"])

    def to_dict(self) -> dict[str, float]:
        return {"m_S_per_N": self.m_S_per_N, "d_S": self.d_S}


@dataclass(frozen=True)
class LinearFit:
    """Result of a linear calibration fit. ``force_n``/``conductance_s`` are the fitted points (one per trial,
    baseline-subtracted when ``baseline_s`` is given), ``residuals_S`` = measured − model, ``baseline_s`` per trial
    (NaN where a trial had no unloaded stretch) or None, ``warnings`` plain sentences."""

    model: LinearModel
    r_squared: float
    residuals_S: np.ndarray
    force_n: np.ndarray
    conductance_s: np.ndarray
    baseline_s: np.ndarray | None
    warnings: tuple[str, ...]

    @property
    def rmse_S(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_S**2)))


def fit_linear(force_n: Sequence[float], conductance_s: Sequence[float]) -> LinearFit:
    """Least-squares ``C = m·F + d`` through one point per trial (forces N, conductances S).

    ValueError if fewer than two distinct finite forces. Warns (in ``warnings``) on a non-positive slope or when the
    conductances are all equal (R² undefined, reported as NaN).
    """
    force = np.asarray(force_n, dtype=np.float64).reshape(-1)
    cond = np.asarray(conductance_s, dtype=np.float64).reshape(-1)
    if force.shape != cond.shape:
        raise ValueError(f"got {force.size} forces but {cond.size} conductances")
    finite = np.isfinite(force) & np.isfinite(cond)
    warnings = []
    if not finite.all():
        warnings.append(
            f"{int((~finite).sum())} trial(s) with a non-finite force or conductance were left out"
        )
    force, cond = force[finite], cond[finite]
    if np.unique(force).size < 2:
        raise ValueError(
            f"a linear fit needs trials at two or more distinct forces, got {np.unique(force).tolist()}"
        )
    design = np.column_stack([force, np.ones_like(force)])
    (m, d), *_ = np.linalg.lstsq(design, cond, rcond=None)
    residuals = cond - (m * force + d)
    total = float(np.sum((cond - cond.mean()) ** 2))
    if total > 0.0:
        r_squared = 1.0 - float(np.sum(residuals**2)) / total
    else:
        r_squared = float("nan")
        warnings.append(
            "all trial conductances are equal: R² is undefined (flat-lined or disconnected sensor?)"
        )
    if not m > 0.0:
        warnings.append(f"slope m = {m:.4g} S/N is not positive: the sensor does not respond to force")
    return LinearFit(LinearModel(m, d), r_squared, residuals, force, cond, None, tuple(warnings))


def trial_mean(
    t_s: np.ndarray, conductance_s: np.ndarray, window_s: tuple[float, float] = DEFAULT_WINDOW_S,
    counts: np.ndarray | None = None,
) -> float:
    """Mean conductance (S) over ``window_s`` (s, inclusive), ignoring NaN; ``counts``: the raw samples each sample
    stands for (a block-averaged record), its weight. ValueError if the window has no data."""
    t = np.asarray(t_s, dtype=np.float64)
    c = np.asarray(conductance_s, dtype=np.float64)
    lo, hi = window_s
    if not lo < hi:
        raise ValueError(f"window start must be before its end, got {window_s}")
    inside = (t >= lo) & (t <= hi) & np.isfinite(c)
    if not inside.any():
        span = f"{t.min():.6g}–{t.max():.6g} s" if t.size else "no samples"
        raise ValueError(f"no valid samples in the window {lo:g}–{hi:g} s (the trial covers {span})")
    if counts is None:
        return float(np.mean(c[inside]))
    return float(np.average(c[inside], weights=np.asarray(counts, dtype=np.float64)[inside]))


def trial_baseline(
    t_s: np.ndarray, force_n: np.ndarray, conductance_s: np.ndarray, loaded_fraction: float = LOADED_FRACTION
) -> float | None:
    """Unloaded baseline conductance (S) of a trial: the mean conductance before the applied force first exceeds
    ``loaded_fraction`` of its maximum. None when the trial starts already loaded (no unloaded samples)."""
    force = np.asarray(force_n, dtype=np.float64)
    c = np.asarray(conductance_s, dtype=np.float64)
    if force.size == 0 or not np.any(np.isfinite(force)):
        return None
    loaded = force > loaded_fraction * np.nanmax(force)
    first = int(np.argmax(loaded)) if loaded.any() else force.size
    before = c[:first]
    before = before[np.isfinite(before)]
    return float(np.mean(before)) if before.size else None


def fit_linear_trials(
    trials: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray | None]],
    window_s: tuple[float, float] = DEFAULT_WINDOW_S,
    subtract_baseline: bool = False,
) -> LinearFit:
    """The paper's calibration from whole trials ``(t_s, force_n, conductance_s)``: per trial the applied force is
    the mean force in the window and the conductance the mean conductance in the window, optionally minus that
    trial's unloaded baseline (trials without an unloaded stretch are then fitted unshifted and warned about). A
    fourth element, the raw samples each sample stands for (a block-averaged record), weighs the window means."""
    forces, conds, baselines = [], [], []
    extra = []
    for index, trial in enumerate(trials):
        t, force, cond = trial[:3]
        counts = trial[3] if len(trial) > 3 else None
        forces.append(trial_mean(t, force, window_s, counts))
        mean_c = trial_mean(t, cond, window_s, counts)
        if subtract_baseline:
            base = trial_baseline(t, force, cond)
            if base is None:
                extra.append(f"trial {index} starts loaded: no baseline, fitted without baseline subtraction")
                baselines.append(float("nan"))
            else:
                baselines.append(base)
                mean_c -= base
        conds.append(mean_c)
    fit = fit_linear(forces, conds)
    return LinearFit(
        fit.model,
        fit.r_squared,
        fit.residuals_S,
        fit.force_n,
        fit.conductance_s,
        np.asarray(baselines) if subtract_baseline else None,
        fit.warnings + tuple(extra),
    )


def paper_negative_offset(force_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's fix for "negative pressure" (Fig. 6): each column's force is offset by the absolute value of its
    most negative value. Returns (offset forces, offsets per column in N). NaN samples are ignored."""
    force = np.asarray(force_n, dtype=np.float64)
    # NaN → +∞ so an all-NaN column has no minimum to offset by (and no warning)
    lowest = np.where(np.isnan(force), np.inf, force).min(axis=0, initial=np.inf)
    offset = np.where(np.isfinite(lowest) & (lowest < 0.0), -lowest, 0.0)
    return force + offset, offset
