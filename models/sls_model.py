"""The standard linear solid's parameters and result types (part of :mod:`models.sls`, which re-exports them).

``SLSParams`` (E0, E1, mu1; scalars or per-sensor arrays) and the paper's force-dependent ``SLSTrend``, the Eq. 6
conversions to and from (a, b, c), the typical sensor used by synthetic data, and the vocabulary of the inverse:
:class:`ForceStatus` codes and :class:`ForceResult`. Pure numerics, any thread.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.physics import explain_status

SLS_KEYS = ("E0_Pa", "E1_Pa", "mu1_Pa_s")


def _as_param_array(value: object, name: str) -> float | np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim > 1:
        raise ValueError(
            f"SLS parameter {name} must be a scalar or a 1-D per-sensor array, got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"SLS parameter {name} must be finite, got {value!r}")
    if not np.all(arr > 0.0):
        raise ValueError(f"SLS parameter {name} must be > 0, got {value!r}")
    return float(arr) if arr.ndim == 0 else arr


def _sls_section(data: Mapping[str, object], section: str) -> dict[str, Any]:
    """The E0_Pa/E1_Pa/mu1_Pa_s entries of a SPEC §3.3 ``section`` object; ValueError names any missing key."""
    missing = [key for key in SLS_KEYS if key not in data]
    if missing:
        raise ValueError(f"{section} is missing key(s) {', '.join(missing)} (need {', '.join(SLS_KEYS)})")
    return {key: data[key] for key in SLS_KEYS}


def sls_from_abc(a_s: float, b_pa: float, c_pa_s: float) -> tuple[float, float, float]:
    """Invert Eq. 6: ``E0 = c/a``, ``E1 = b·E0/(E0 − b)``, ``mu1 = a·(E0 + E1)``. NaN where not physical."""
    if not (a_s > 0 and b_pa > 0 and c_pa_s > 0):
        return math.nan, math.nan, math.nan
    e0 = c_pa_s / a_s
    if e0 <= b_pa:
        return math.nan, math.nan, math.nan
    e1 = b_pa * e0 / (e0 - b_pa)
    return e0, e1, a_s * (e0 + e1)


def abc_from_sls(e0_pa: float, e1_pa: float, mu1_pa_s: float) -> tuple[float, float, float]:
    """Eq. 6: ``a = mu1/(E0+E1)`` (s), ``b = E0·E1/(E0+E1)`` (Pa), ``c = mu1·E0/(E0+E1)`` (Pa·s)."""
    total = e0_pa + e1_pa
    return mu1_pa_s / total, e0_pa * e1_pa / total, mu1_pa_s * e0_pa / total


@dataclass(frozen=True)
class SLSParams:
    """SLS parameters: E0_Pa, E1_Pa (Pa), mu1_Pa_s (Pa·s); each a positive finite scalar or a (S,) per-sensor array.

    Derived (Eq. 6, 11): ``tau_s = mu1/E1`` (s), ``a = mu1/(E0+E1)`` (s), ``b = E0·E1/(E0+E1)`` (Pa),
    ``c = mu1·E0/(E0+E1)`` (Pa·s).
    """

    E0_Pa: float | np.ndarray
    E1_Pa: float | np.ndarray
    mu1_Pa_s: float | np.ndarray

    def __post_init__(self) -> None:
        for key in SLS_KEYS:
            object.__setattr__(self, key, _as_param_array(getattr(self, key), key))
        sizes = {np.size(getattr(self, key)) for key in SLS_KEYS if np.ndim(getattr(self, key)) == 1}
        if len(sizes) > 1:
            raise ValueError(
                f"SLS parameter arrays must have one length (one entry per sensor), got {sorted(sizes)}"
            )

    @property
    def n_sensors(self) -> int | None:
        """Length of the per-sensor arrays, or None when all three are scalars."""
        for key in SLS_KEYS:
            if np.ndim(getattr(self, key)) == 1:
                return int(np.size(getattr(self, key)))
        return None

    @property
    def tau_s(self) -> float | np.ndarray:
        return self.mu1_Pa_s / self.E1_Pa

    @property
    def a(self) -> float | np.ndarray:
        return self.mu1_Pa_s / (self.E0_Pa + self.E1_Pa)

    @property
    def b(self) -> float | np.ndarray:
        return self.E0_Pa * self.E1_Pa / (self.E0_Pa + self.E1_Pa)

    @property
    def c(self) -> float | np.ndarray:
        return self.mu1_Pa_s * self.E0_Pa / (self.E0_Pa + self.E1_Pa)

    @classmethod
    def from_abc(cls, a_s: float, b_Pa: float, c_Pa_s: float) -> SLSParams:
        """Invert Eq. 6: ``E0 = c/a``, ``E1 = b·E0/(E0 − b)``, ``mu1 = a·(E0 + E1)``. Needs a, b, c > 0 and
        ``c/a > b`` (instantaneous stiffer than long-run); raises ValueError otherwise (non-physical)."""
        a, b, c = (float(v) for v in (a_s, b_Pa, c_Pa_s))
        if not all(math.isfinite(v) and v > 0.0 for v in (a, b, c)):
            raise ValueError(
                f"a, b, c must be positive and finite for a physical SLS, got a={a}, b={b}, c={c}"
            )
        if c / a <= b:
            raise ValueError(
                f"non-physical SLS: E0 = c/a = {c / a:.6g} Pa must exceed b = {b:.6g} Pa (E1 would be < 0)"
            )
        return cls(*sls_from_abc(a, b, c))

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> SLSParams:
        """From SPEC §3.3 ``sls`` keys; ValueError names a missing or bad key."""
        return cls(**_sls_section(data, "sls"))

    def to_dict(self) -> dict[str, float]:
        """SPEC §3.3 ``sls`` object (scalar parameters only)."""
        if self.n_sensors is not None:
            raise ValueError(
                "to_dict needs scalar parameters; per-sensor arrays go one sensor at a time (sensor(i))"
            )
        return {key: float(getattr(self, key)) for key in SLS_KEYS}

    @classmethod
    def stack(cls, params: Sequence[SLSParams]) -> SLSParams:
        """Per-sensor arrays from a sequence of scalar parameter sets (one per sensor, in column order)."""
        if not params:
            raise ValueError("SLSParams.stack needs at least one parameter set")
        return cls(*(np.array([float(getattr(p, key)) for p in params]) for key in SLS_KEYS))

    def sensor(self, index: int) -> SLSParams:
        """The scalar parameters of sensor ``index`` (or self when scalar)."""
        if self.n_sensors is None:
            return self
        return SLSParams(
            *(float(np.broadcast_to(getattr(self, key), (self.n_sensors,))[index]) for key in SLS_KEYS)
        )


@dataclass(frozen=True)
class SLSTrend:
    """The paper's linear-in-force parameters (SPEC §3.3 ``sls_trend``): each entry ``(intercept, slope_per_N)``."""

    E0_Pa: tuple[float, float]
    E1_Pa: tuple[float, float]
    mu1_Pa_s: tuple[float, float]

    def __post_init__(self) -> None:
        for key in SLS_KEYS:
            try:
                pair = tuple(float(v) for v in getattr(self, key))
            except (TypeError, ValueError):
                raise ValueError(
                    f"sls_trend {key} must be [intercept, slope_per_N], got {getattr(self, key)!r}"
                ) from None
            if len(pair) != 2 or not all(math.isfinite(v) for v in pair):
                raise ValueError(
                    f"sls_trend {key} must be [intercept, slope_per_N] (finite), got {getattr(self, key)!r}"
                )
            object.__setattr__(self, key, pair)

    def at(self, force_n: float | np.ndarray) -> SLSParams:
        """Parameters evaluated at ``force_n`` (N); ValueError if any comes out ≤ 0 there."""
        force = np.asarray(force_n, dtype=np.float64)
        values = [getattr(self, key)[0] + getattr(self, key)[1] * force for key in SLS_KEYS]
        for key, value in zip(SLS_KEYS, values, strict=True):
            if not np.all(value > 0.0):
                raise ValueError(
                    f"sls_trend gives {key} ≤ 0 at force {force_n!r} N: outside the trend's valid range"
                )
        return SLSParams(*values)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> SLSTrend:
        """From the SPEC §3.3 ``sls_trend`` object; ValueError names a missing or bad key."""
        return cls(**_sls_section(data, "sls_trend"))

    def to_dict(self) -> dict[str, list[float]]:
        return {key: list(getattr(self, key)) for key in SLS_KEYS}


# A typical sensor for synthetic data, tests and benchmarks: strains ~4e-3 … 2e-2 for 1.75–5.25 N, τ = 100 s.
TYPICAL_AREA_M2 = 1.4e-3
TYPICAL_SLS = SLSParams(E0_Pa=3.0e5, E1_Pa=5.0e5, mu1_Pa_s=5.0e7)
TYPICAL_FORCES_N = (1.75, 3.0, 4.0, 5.25)


class ForceStatus(enum.IntEnum):
    """Per-sample outcome of the inverse (conductance → force)."""

    OK = 0
    NAN_INPUT = 1  # conductance NaN: force NaN, the state holds the last force over the gap
    OPEN_CIRCUIT = 2  # C = 0: no contact, force 0 N
    NEGATIVE_CONDUCTANCE = 3  # C < 0 is not a reading: force 0 N
    BELOW_BASELINE = (
        4  # the model needs a negative force (reading below the unloaded baseline): clipped to 0 N
    )
    SATURATED = 5  # reading at or beyond ε → 1 (or C = ∞): force at that limit, far outside the model's range
    NOT_CONVERGED = 6  # the per-step solve hit its iteration cap (should not happen); last iterate kept
    EXTRAPOLATED = 7  # force outside the calibrated range given to the estimator; value kept
    # The sample-validation rule (models.validation) adds these; the inverse itself never sets them.
    ABOVE_CEILING = 8  # reading above the readout's ceiling 1/R_C: impossible, rejected (gap, force NaN)
    FLAT = 9  # the same reading for flat_s seconds: a stuck channel, rejected (gap, force NaN)
    READOUT_SATURATED = 10  # reading at the ceiling 1/R_C (counts = 0): the force is a lower bound
    UNCHANGED = 11  # identical for flat_max_s on a sensor too quiet to tell a stuck line from a still one: kept
    OPEN_UNDER_LOAD = 12  # 0 S straight after a clear load (an open circuit, not a release): rejected (gap)


FORCE_STATUS_TEXT = {
    ForceStatus.OK: "ok",
    ForceStatus.NAN_INPUT: "conductance is not finite (dropped sample, empty cell): gap, force NaN, last force "
    "held over the gap",
    ForceStatus.OPEN_CIRCUIT: "conductance 0 (open circuit, no contact): force 0 N",
    ForceStatus.NEGATIVE_CONDUCTANCE: "negative conductance is not a reading: rejected (gap, force NaN)",
    ForceStatus.BELOW_BASELINE: "reading below the unloaded baseline (negative force): clipped to 0 N",
    ForceStatus.SATURATED: "reading beyond the model's strain limit ε → 1: force at that limit (check for a short "
    "or a wrong calibration)",
    ForceStatus.NOT_CONVERGED: "per-step force solve did not converge",
    ForceStatus.EXTRAPOLATED: "force outside the calibrated range: extrapolated",
    ForceStatus.ABOVE_CEILING: "reading above the readout's ceiling 1/R_C is impossible: rejected (gap, force NaN)",
    ForceStatus.FLAT: "reading frozen (flat-lined channel): rejected, no force claimed (gap, force NaN)",
    ForceStatus.READOUT_SATURATED: "readout saturated (at 1/R_C): force is a lower bound",
    ForceStatus.UNCHANGED: "reading unchanged for over a minute on a sensor too quiet to tell a stuck line from a "
    "still one: force kept, check the channel",
    ForceStatus.OPEN_UNDER_LOAD: "reading 0 S straight after a clear load (open circuit, loose wire): rejected (gap, "
    "force NaN, last force held)",
}


def explain_force_status(status: np.ndarray) -> list[str]:
    """One line per non-OK :class:`ForceStatus` present: '<count> sample(s) NAME: explanation'."""
    return explain_status(status, FORCE_STATUS_TEXT)


@dataclass(frozen=True)
class ForceResult:
    """Force (N) and a :class:`ForceStatus` code (int8) per sample, same shape."""

    force_n: np.ndarray
    status: np.ndarray

    def explain(self) -> list[str]:
        return explain_force_status(self.status)
