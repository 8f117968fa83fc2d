"""Streaming force estimators for live use: conductance blocks in, force blocks out, state carried between blocks.

Both estimators take ``update(t_s (N,), conductance_s (N, S)) -> force_n (N, S)`` and keep the per-sample status
codes of the last block in ``last_status`` (:class:`models.sls.ForceStatus`). Every block first passes the one
sample-validation rule of :mod:`models.validation`: non-finite, negative, above-ceiling and flat-lined readings are
rejected (NaN force, flagged) and never reach the inverse; a gap lets time pass with the last force held. Timestamps must never go backwards, also across
blocks (ValueError); duplicates are zero-length steps.

An estimator is not thread-safe: create it and call ``update``/``reset`` from one thread (e.g. the thread that
receives the board's blocks), then hand the arrays on.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from models.linear import LinearModel
from models.physics import PhysicsConstants
from models.sls import ForceStatus, SLSInverse, SLSParams, check_timestamps, explain_force_status
from models.validation import SampleValidator, ValidationRule

# The estimators do not know the readout: no ceiling (the board already clamps at 1/R_C and reports saturation in
# its ``saturated`` mask); non-finite, negative and flat-lined readings are still rejected. Callers that know R_C
# (``sensnake estimate``) pass ``ValidationRule.for_readout(r_c_ohm)``.
ESTIMATOR_RULE = ValidationRule(ceiling_s=None)


def _validated(
    validator: SampleValidator | None, rule: ValidationRule, t: np.ndarray, cond: np.ndarray,
    saturated: np.ndarray | None,
) -> tuple[SampleValidator, np.ndarray, np.ndarray]:
    """Run the sample-validation rule (models.validation) on a block: (validator, cleaned conductance, codes)."""
    if validator is None or validator.n_sensors != cond.shape[1]:
        validator = SampleValidator(cond.shape[1], rule)
    checked = validator.check(t, cond, saturated)
    return validator, checked.conductance_s, checked.status


def _merge(status: np.ndarray, checked: np.ndarray) -> None:
    """Validation codes win over the inverse's own (a rejected sample reaches the inverse as NaN)."""
    np.copyto(status, checked, where=checked != 0)


def _as_block(conductance_s: np.ndarray, n_samples: int, n_sensors: int | None) -> np.ndarray:
    cond = np.asarray(conductance_s, dtype=np.float64)
    if cond.ndim == 1:
        cond = cond[:, None]
    if cond.ndim != 2:
        raise ValueError(f"conductance block must be (N, S), got shape {cond.shape}")
    if cond.shape[0] != n_samples:
        raise ValueError(
            f"conductance block has {cond.shape[0]} samples but there are {n_samples} timestamps"
        )
    if n_sensors is not None and cond.shape[1] != n_sensors:
        raise ValueError(
            f"conductance block has {cond.shape[1]} sensor column(s), the estimator expects {n_sensors}"
        )
    return cond


def _range_bounds(force_range_n, n_sensors: int) -> tuple[np.ndarray, np.ndarray] | None:
    if force_range_n is None:
        return None
    lo, hi = (np.broadcast_to(np.asarray(v, dtype=np.float64), (n_sensors,)) for v in force_range_n)
    if not np.all(lo <= hi):
        raise ValueError(f"force_range_n must be (low, high) with low ≤ high, got {force_range_n!r}")
    return lo, hi


def _flag_extrapolation(force: np.ndarray, status: np.ndarray, bounds) -> None:
    if bounds is None:
        return
    lo, hi = bounds
    outside = ((force < lo) | (force > hi)) & (status == ForceStatus.OK) & (force > 0.0)
    status[outside] = ForceStatus.EXTRAPOLATED


class LinearEstimator:
    """Eq. 1 inverse per sensor: ``F = (C − baseline − d)/m``, clipped at 0 N (flagged BELOW_BASELINE).

    models: one :class:`LinearModel` (all sensors) or one per sensor column. baseline_s: optional per-sensor
    unloaded baseline (S) subtracted first (the drift handling of :mod:`models.linear`). force_range_n: optional
    calibrated (low, high) range in N; forces outside are flagged EXTRAPOLATED.
    """

    def __init__(
        self,
        models: LinearModel | Sequence[LinearModel],
        baseline_s: float | np.ndarray | None = None,
        clip_negative: bool = True,
        force_range_n: tuple[float | np.ndarray, float | np.ndarray] | None = None,
        validation: ValidationRule = ESTIMATOR_RULE,
    ) -> None:
        model_list = [models] if isinstance(models, LinearModel) else list(models)
        if not model_list:
            raise ValueError("LinearEstimator needs at least one LinearModel")
        for index, model in enumerate(model_list):
            if not model.m_S_per_N > 0.0:
                raise ValueError(f"sensor {index}: linear slope m_S_per_N = {model.m_S_per_N!r} must be > 0")
        self._per_sensor = len(model_list) > 1
        self.m_S_per_N = np.array([m.m_S_per_N for m in model_list])
        self.d_S = np.array([m.d_S for m in model_list])
        self.baseline_s = None if baseline_s is None else np.asarray(baseline_s, dtype=np.float64)
        self.clip_negative = clip_negative
        self.force_range_n = force_range_n
        self.last_status = np.zeros((0, len(model_list)), dtype=np.int8)
        self._t_prev_s: float | None = None
        self.validation = validation
        self._validator: SampleValidator | None = None

    @property
    def n_sensors(self) -> int | None:
        return self.m_S_per_N.size if self._per_sensor else None

    def reset(self) -> None:
        """Forget the last timestamp (the linear model itself has no memory) and the flat-line runs."""
        self._t_prev_s = None
        self._validator = None

    def update(
        self, t_s: np.ndarray, conductance_s: np.ndarray, saturated: np.ndarray | None = None
    ) -> np.ndarray:
        """Force (N, S) in N for timestamps (N,) s and conductances (N, S) S. ``saturated`` (N, S) bool marks
        ADC-saturated (censored) samples: their force is a lower bound and is flagged READOUT_SATURATED."""
        t = np.asarray(t_s, dtype=np.float64)
        check_timestamps(t, self._t_prev_s)
        cond = _as_block(conductance_s, t.size, self.n_sensors)
        self._validator, cond, checked = _validated(self._validator, self.validation, t, cond, saturated)
        excess = cond - self.d_S
        if self.baseline_s is not None:
            excess = excess - self.baseline_s
        force = excess / self.m_S_per_N
        status = np.zeros(force.shape, dtype=np.int8)
        status[np.isnan(cond)] = ForceStatus.NAN_INPUT
        status[cond == 0.0] = ForceStatus.OPEN_CIRCUIT
        status[cond < 0.0] = ForceStatus.NEGATIVE_CONDUCTANCE
        if self.clip_negative:
            negative = force < 0.0
            status[negative & (status == ForceStatus.OK)] = ForceStatus.BELOW_BASELINE
            force[negative] = 0.0
        _merge(status, checked)
        _flag_extrapolation(force, status, _range_bounds(self.force_range_n, force.shape[1]))
        self.last_status = status
        if t.size:
            self._t_prev_s = float(t[-1])
        return force

    def explain(self) -> list[str]:
        """Summary of the non-OK statuses of the last block."""
        return explain_force_status(self.last_status)


class SLSEstimator:
    """Creep-corrected live force: the exact O(1)-per-sample SLS + Eq. 3 inverse of :class:`models.sls.SLSInverse`.

    params: :class:`SLSParams` (scalars, or (S,) arrays for per-sensor parameters); area_m2 (m², scalar or (S,));
    phys: Eq. 3 constants; interp "hold" or "linear"; with_contact: use the contact term ``K/√F``; n_sensors: the
    column count (inferred from per-sensor params or from the first block when None); force_range_n: optional
    calibrated range (low, high) in N for the EXTRAPOLATED flag.
    """

    def __init__(
        self,
        params: SLSParams,
        area_m2: float | np.ndarray,
        phys: PhysicsConstants,
        interp: str = "hold",
        with_contact: bool = True,
        n_sensors: int | None = None,
        force_range_n: tuple[float | np.ndarray, float | np.ndarray] | None = None,
        validation: ValidationRule = ESTIMATOR_RULE,
    ) -> None:
        self.params = params
        self.area_m2 = area_m2
        self.phys = phys
        self.interp = interp
        self.with_contact = with_contact
        self.force_range_n = force_range_n
        self.validation = validation
        self._validator: SampleValidator | None = None
        if n_sensors is None:
            n_sensors = params.n_sensors
        if n_sensors is None and np.ndim(area_m2) == 1:
            n_sensors = int(np.size(area_m2))
        self._inverse: SLSInverse | None = None
        if n_sensors is not None:
            self._inverse = SLSInverse(params, area_m2, phys, n_sensors, interp, with_contact)
        self.last_status = np.zeros((0, n_sensors or 0), dtype=np.int8)

    @property
    def n_sensors(self) -> int | None:
        return None if self._inverse is None else self._inverse.n_sensors

    def reset(self) -> None:
        """Back to rest (zero force, no creep history, no previous timestamp, no flat-line runs)."""
        if self._inverse is not None:
            self._inverse.reset()
        self._validator = None

    def update(
        self, t_s: np.ndarray, conductance_s: np.ndarray, saturated: np.ndarray | None = None
    ) -> np.ndarray:
        """Force (N, S) in N for timestamps (N,) s and conductances (N, S) S, continuing from the previous block.

        ``saturated`` (N, S) bool marks ADC-saturated (censored) samples (``SampleBlock.saturated``): the reading is
        a bound, so the force is a lower bound; it is computed and carried in the state like any other sample
        (dropping it would hold an older, smaller force) and flagged READOUT_SATURATED."""
        t = np.asarray(t_s, dtype=np.float64)
        cond = _as_block(conductance_s, t.shape[0] if t.ndim == 1 else -1, self.n_sensors)
        if self._inverse is None:
            self._inverse = SLSInverse(
                self.params, self.area_m2, self.phys, cond.shape[1], self.interp, self.with_contact
            )
        self._validator, cond, checked = _validated(self._validator, self.validation, t, cond, saturated)
        result = self._inverse.update(t, cond)
        _merge(result.status, checked)
        _flag_extrapolation(result.force_n, result.status, _range_bounds(self.force_range_n, cond.shape[1]))
        self.last_status = result.status
        return result.force_n

    def explain(self) -> list[str]:
        """Summary of the non-OK statuses of the last block."""
        return explain_force_status(self.last_status)
