"""The SLS inverse, conductance → force (part of :mod:`models.sls`, which re-exports it).

:class:`SLSInverse` streams blocks with its state carried between them (O(1) per sample, NUMERICS pitfall 2);
:func:`force_from_conductance` is the one-shot form and :func:`force_from_conductance_trend` the force-dependent
variant. The conventions are in :mod:`models.sls`. Pure numerics; an :class:`SLSInverse` is used from one thread at
a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.physics import STRAIN_NEAR_ONE, PhysicsConstants, StrainStatus, strain_from_resistance
from models.sls_contact import _solve_contact_scalar, _solve_contact_step, _solve_contact_trend_scalar
from models.sls_model import ForceResult, ForceStatus, SLSParams, SLSTrend
from models.sls_recursion import (
    _as_2d,
    _check_area,
    _check_interp,
    _coeffs,
    _compiled_inverse,
    check_timestamps,
    one_minus_phi1,
)

_OPEN_BELOW_S = float(np.finfo(np.float64).tiny)  # conductances below this read as open circuits
_BELOW_BASELINE_FLAG_N = 1e-9  # negative forces are always clipped to 0 N; flagged only beyond this


@dataclass
class _InverseState:
    q: np.ndarray  # Kelvin–Voigt strain after the last sample (S,)
    sigma_prev: np.ndarray  # stress held/used at the last sample (S,), Pa
    force_prev: np.ndarray  # last force (S,), N: warm start of the per-step solve
    t_prev_s: float | None = None


class SLSInverse:
    """Streaming conductance → force inverse of the SLS + Eq. 3 model, O(1) per sample (NUMERICS pitfall 2).

    Per step the new stress enters the strain linearly through the instantaneous compliance
    ``1/E_eff = 1/E0 + (1−φ1)/E1`` (linear) or ``1/E0`` (hold): ``ε_n = σ_n/E_eff + p_n`` with ``p_n`` known from
    the past. Without the contact term ε_n comes straight from Eq. 3 and ``σ_n = E_eff·(ε_n − p_n)``. With it the
    equation ``C·R(F) = 1`` is scalar and strictly monotone in F: it is solved by Newton in log F, warm-started at the
    previous force and safeguarded by a bracket ``[(K·C)², F(ε=1)]`` with bisection, vectorised over sensors.

    Use from one thread at a time. ``update`` carries the state between blocks; ``reset`` returns to rest.
    """

    def __init__(
        self,
        params: SLSParams,
        area_m2: float | np.ndarray,
        phys: PhysicsConstants,
        n_sensors: int,
        interp: str = "hold",
        with_contact: bool = True,
    ) -> None:
        _check_interp(interp)
        if n_sensors < 1:
            raise ValueError(f"n_sensors must be ≥ 1, got {n_sensors}")
        self.params = params
        self.interp = interp
        self.n_sensors = int(n_sensors)
        self.phys = phys if with_contact else phys.without_contact()
        self._co = _coeffs(params, area_m2, self.n_sensors)
        self.reset()

    def reset(self) -> None:
        """Back to rest: zero force, zero creep, no previous timestamp."""
        s = self.n_sensors
        self._state = _InverseState(q=np.zeros(s), sigma_prev=np.zeros(s), force_prev=np.zeros(s))

    @property
    def last_time_s(self) -> float | None:
        return self._state.t_prev_s

    def update(self, t_s: np.ndarray, conductance_s: np.ndarray) -> ForceResult:
        """Forces (N, S) in N for a block of timestamps (N,) s and conductances (N, S) S, continuing the state."""
        t = np.asarray(t_s, dtype=np.float64)
        cond = np.asarray(conductance_s, dtype=np.float64)
        if cond.ndim == 1 and self.n_sensors == 1:
            cond = cond[:, None]
        if cond.ndim != 2 or cond.shape[1] != self.n_sensors:
            raise ValueError(f"conductance must be (N, {self.n_sensors}), got shape {cond.shape}")
        steps = check_timestamps(t, self._state.t_prev_s)
        if cond.shape[0] != steps.size:
            raise ValueError(f"conductance has {cond.shape[0]} samples but there are {steps.size} timestamps")
        n, s = cond.shape
        force = np.empty((n, s))
        status = np.zeros((n, s), dtype=np.int8)
        if n == 0:
            return ForceResult(force, status)
        co = self._co
        # Sensors sharing one τ share the step coefficients: (N, 1) broadcasts and saves two N×S passes of expm1.
        tau = co.tau[:1] if np.all(co.tau == co.tau[0]) else co.tau
        x = steps[:, None] / tau[None, :]
        oma = -np.expm1(-x)
        if self.interp == "linear":
            ramp = one_minus_phi1(x)
        else:
            ramp = None
            # The hold inverse propagates an error in q by 1 − (1−α)(1 + E0/E1) per step: when E0 > E1 and a step
            # is much longer than τ this exceeds 1 in magnitude and noise would grow without bound. Such steps
            # (only possible after a long gap or with τ → 0) are inverted under the linear assumption instead,
            # which is always stable; every other step stays exactly "hold".
            if np.any(co.e0 > co.e1):
                unstable = oma * (1.0 + co.e0 / co.e1) > 1.999
                if unstable.any():
                    ramp = np.where(unstable, one_minus_phi1(x), 0.0)

        # One min/max pass decides whether the block needs per-sample masks at all (NaN propagates into both).
        c_min, c_max = float(cond.min()), float(cond.max())
        clean = c_min >= _OPEN_BELOW_S and c_max < np.inf
        if not clean:
            # Below ~2e-308 S the resistance overflows float64: such a reading is an open circuit.
            cond = np.where((cond > 0.0) & (cond < _OPEN_BELOW_S), 0.0, cond)
            status[np.isnan(cond)] = ForceStatus.NAN_INPUT
            status[cond < 0.0] = ForceStatus.NEGATIVE_CONDUCTANCE
            status[cond == 0.0] = ForceStatus.OPEN_CIRCUIT
        compiled = _compiled_inverse()
        if compiled is not None:
            self._run_compiled(compiled, cond, oma, ramp, force, status)
        elif s == 1:
            self._run_one_sensor(cond[:, 0], oma[:, 0], None if ramp is None else ramp[:, 0], force, status)
        elif self.phys.has_contact:
            self._run_contact(cond, oma, ramp, force, status)
        else:
            self._run_no_contact(cond, oma, ramp, force, status, clean)
        self._state.t_prev_s = float(t[-1])
        return ForceResult(force, status)

    # -- the compiled path (models.sls_kernels): the one-sensor algebra below, compiled, for every sensor.
    def _run_compiled(self, kern, cond, oma, ramp, force, status) -> None:
        co, st, phys = self._co, self._state, self.phys
        contact = phys.has_contact
        if contact:
            strain = strain_status = np.zeros((1, 1))
        else:
            valid = (cond > 0.0) & np.isfinite(cond)
            res = strain_from_resistance(1.0 / np.where(valid, cond, 1.0), 1.0, phys)
            strain, strain_status = res.strain, res.status.astype(np.int64)
        # Sensor-major copies (S, N): each sensor's row is contiguous for the compiled loop.
        n, s = cond.shape
        oma_t = np.ascontiguousarray(np.broadcast_to(oma, (n, oma.shape[1])).T)
        ramp_t = oma_t if ramp is None else np.ascontiguousarray(ramp.T)
        force_t = np.empty((s, n))
        status_t = np.ascontiguousarray(status.T)
        kern(np.ascontiguousarray(cond.T), oma_t, ramp_t, ramp is not None, co.e0, co.e1, co.area, contact,
                     phys.tunnelling_k, phys.R0_ohm, phys.K_contact_ohm_sqrtN, np.ascontiguousarray(strain.T),
                     np.ascontiguousarray(strain_status.T), st.q, st.sigma_prev, st.force_prev, force_t, status_t)
        force[...] = force_t.T
        status[...] = status_t.T

    # -- the no-contact path: strain is a function of the reading alone, so Eq. 3 is inverted for the whole block
    # at once and only the linear recursion runs per step.
    def _run_no_contact(self, cond, oma, ramp, force, status, clean: bool) -> None:
        co, st = self._co, self._state
        n, s = cond.shape
        if clean:
            strain_res = strain_from_resistance(1.0 / cond, 1.0, self.phys)
            strain = strain_res.strain
            use = zero = np.empty((0, 0), dtype=bool)  # never indexed: every row is plain
            plain_rows = np.ones(n, dtype=bool)
            # ε ≥ 0.9: the ε → 1 limit (flagged, force kept).
            if strain_res.status.any():
                status[strain_res.status == StrainStatus.STRAIN_NEAR_ONE] = ForceStatus.SATURATED
                status[strain_res.status == StrainStatus.NOT_CONVERGED] = ForceStatus.NOT_CONVERGED
        else:
            valid = (cond > 0.0) & np.isfinite(cond)
            strain_res = strain_from_resistance(1.0 / np.where(valid, cond, 1.0), 1.0, self.phys)
            infinite = np.isposinf(cond)
            saturated = infinite | (valid & (strain_res.status == StrainStatus.STRAIN_NEAR_ONE))
            strain = np.where(infinite, 1.0, strain_res.strain)
            status[saturated] = ForceStatus.SATURATED
            status[valid & (strain_res.status == StrainStatus.NOT_CONVERGED)] = ForceStatus.NOT_CONVERGED
            use = valid | saturated  # samples whose force comes from the model
            zero = (cond <= 0.0) & ~np.isnan(cond)
            plain_rows = use.all(axis=1)
        inv_e0 = 1.0 / co.e0
        inv_e1 = 1.0 / co.e1
        q = st.q.copy()
        sig_prev = st.sigma_prev.copy()
        p = np.empty(s)
        sig = np.empty(s)
        for i in range(n):
            # p: the strain the past alone explains at sample i; the new stress adds σ/E_eff on top of it.
            np.multiply(sig_prev, inv_e1, out=p)
            p -= q
            p *= oma[i]
            p += q
            if ramp is None:
                np.subtract(strain[i], p, out=sig)
                sig *= co.e0
            else:
                p -= ramp[i] * sig_prev * inv_e1
                np.subtract(strain[i], p, out=sig)
                sig /= inv_e0 + ramp[i] * inv_e1
            if not plain_rows[i]:
                # NaN: hold the last stress over the gap; C ≤ 0: no contact, zero stress.
                sig = np.where(use[i], sig, np.where(zero[i], 0.0, sig_prev))
            force[i] = sig
            np.maximum(sig, 0.0, out=sig_prev)
            if ramp is None:
                q, p = p, q
            else:
                np.multiply(sig_prev, ramp[i] * inv_e1, out=q)
                q += p
        force *= co.area[None, :]
        negative = force < 0.0
        if negative.any():
            # Rounding leaves ~1e-17 N either side of an exact zero: only a real deficit is worth a flag.
            flagged = negative & (force < -_BELOW_BASELINE_FLAG_N) & (status == ForceStatus.OK)
            status[flagged] = ForceStatus.BELOW_BASELINE
            force[negative] = 0.0
        if not clean:
            force[np.isnan(cond)] = np.nan
        st.q = q
        st.sigma_prev = sig_prev
        last_valid = ~np.isnan(force[-1])
        st.force_prev = np.where(last_valid, force[-1], st.force_prev)

    # -- one sensor: the same algebra as the vectorised paths on Python floats, ~10× faster per step than numpy
    # calls on length-1 arrays (long single-sensor records: 370 s at 1 kHz is 370 000 steps).
    def _run_one_sensor(self, cond, oma, ramp, force, status) -> None:
        co, st, phys = self._co, self._state, self.phys
        e0, e1, area = float(co.e0[0]), float(co.e1[0]), float(co.area[0])
        inv_e0, inv_e1 = 1.0 / e0, 1.0 / e1
        contact = phys.has_contact
        if not contact:
            valid = (cond > 0.0) & np.isfinite(cond)
            strain_res = strain_from_resistance(1.0 / np.where(valid, cond, 1.0), 1.0, phys)
            strain_list = strain_res.strain.tolist()
            strain_status = strain_res.status.tolist()
        k, r0, kc = phys.tunnelling_k, phys.R0_ohm, phys.K_contact_ohm_sqrtN
        c_list = cond.tolist()
        a_list = oma.tolist()
        r_list = ramp.tolist() if ramp is not None else None
        out = [0.0] * len(c_list)
        codes = [0] * len(c_list)
        q = float(st.q[0])
        sig_prev = float(st.sigma_prev[0])
        f_prev = float(st.force_prev[0])
        for i, c in enumerate(c_list):
            p = q + a_list[i] * (sig_prev * inv_e1 - q)
            r_i = r_list[i] if r_list is not None else 0.0
            p -= r_i * sig_prev * inv_e1
            inv_eff = inv_e0 + r_i * inv_e1
            code = 0
            if c != c:  # NaN: hold the last stress over the gap
                code = ForceStatus.NAN_INPUT
                sig = sig_prev
                f_out = math.nan
            elif c <= 0.0:
                code = ForceStatus.OPEN_CIRCUIT if c == 0.0 else ForceStatus.NEGATIVE_CONDUCTANCE
                sig = 0.0
                f_out = 0.0
            elif c == math.inf:
                code = ForceStatus.SATURATED
                sig = max((1.0 - p) / inv_eff, 0.0)
                f_out = sig * area
            elif contact:
                f_out, code = _solve_contact_scalar(c, p, inv_eff / area, f_prev, k, r0, kc)
                if code == 0 and p + inv_eff / area * f_out >= STRAIN_NEAR_ONE:
                    code = ForceStatus.SATURATED
                sig = f_out / area
            else:
                sig = (strain_list[i] - p) / inv_eff
                if strain_status[i] == StrainStatus.STRAIN_NEAR_ONE:
                    code = ForceStatus.SATURATED
                elif strain_status[i] == StrainStatus.NOT_CONVERGED:
                    code = ForceStatus.NOT_CONVERGED
                if sig < 0.0:
                    if code == 0 and sig * area < -_BELOW_BASELINE_FLAG_N:
                        code = ForceStatus.BELOW_BASELINE
                    sig = 0.0
                f_out = sig * area
            out[i] = f_out
            codes[i] = code
            q = p + r_i * sig * inv_e1
            sig_prev = sig
            if f_out > 0.0:
                f_prev = f_out
        force[:, 0] = out
        status[:, 0] = codes
        st.q = np.array([q])
        st.sigma_prev = np.array([sig_prev])
        st.force_prev = np.array([f_prev])

    # -- the contact path: one scalar monotone equation per sensor and step.
    def _run_contact(self, cond, oma, ramp, force, status) -> None:
        co, st = self._co, self._state
        phys = self.phys
        k = phys.tunnelling_k
        r0 = phys.R0_ohm
        kc = phys.K_contact_ohm_sqrtN
        inv_e0 = 1.0 / co.e0
        inv_e1 = 1.0 / co.e1
        q = st.q.copy()
        sig_prev = st.sigma_prev.copy()
        f_prev = st.force_prev.copy()
        n, s = cond.shape
        for i in range(n):
            p = q + oma[i] * (sig_prev * inv_e1 - q)
            if ramp is None:
                inv_eff = inv_e0
            else:
                p = p - ramp[i] * sig_prev * inv_e1
                inv_eff = inv_e0 + ramp[i] * inv_e1
            w = inv_eff / co.area  # strain per newton of new force
            c_i = cond[i]
            f_new, st_new = _solve_contact_step(c_i, p, w, f_prev, k, r0, kc)
            # A root at ε ≥ 0.9 is far outside the model's range: flagged like the no-contact path does.
            st_new[(st_new == 0) & (p + w * f_new >= STRAIN_NEAR_ONE)] = ForceStatus.SATURATED
            nan_i = np.isnan(c_i)
            status[i] = np.where(status[i] == 0, st_new, status[i])
            sig = np.where(nan_i, sig_prev, f_new / co.area)
            force[i] = np.where(nan_i, np.nan, f_new)
            if ramp is None:
                q = p
            else:
                q = p + ramp[i] * sig * inv_e1
            sig_prev = sig
            f_prev = np.where(nan_i | (f_new <= 0.0), f_prev, f_new)
        st.q = q
        st.sigma_prev = sig_prev
        st.force_prev = f_prev


def force_from_conductance(
    t_s: np.ndarray,
    conductance_s: np.ndarray,
    params: SLSParams,
    area_m2: float | np.ndarray,
    phys: PhysicsConstants,
    interp: str = "hold",
    *,
    with_contact: bool = True,
    with_status: bool = False,
) -> np.ndarray | ForceResult:
    """Force (N) from conductance (S), the exact inverse of :func:`conductance_from_force`, O(1) per sample.

    Same shape as ``conductance_s``. ``with_contact=False`` ignores the contact term of ``phys``. C = 0 gives 0 N;
    NaN gives NaN (state held); non-physical readings are clipped/limited and flagged — pass ``with_status=True``
    to get a :class:`ForceResult` with the per-sample :class:`ForceStatus` codes instead of the bare array.
    """
    steps = check_timestamps(t_s)
    cond, was_1d = _as_2d(conductance_s, steps.size, "conductance_s")
    inverse = SLSInverse(params, area_m2, phys, cond.shape[1], interp, with_contact)
    result = inverse.update(t_s, cond)
    if was_1d:
        result = ForceResult(result.force_n[:, 0], result.status[:, 0])
    return result if with_status else result.force_n


def _trend_value(pair: tuple[float, float], force_n: float, key: str, index: int) -> float:
    value = pair[0] + pair[1] * force_n
    if not value > 0.0:
        raise ValueError(
            f"sls_trend gives {key} = {value:.4g} ≤ 0 at the estimated force {force_n:.4g} N (sample {index}): "
            f"the trend is not valid there; use fixed parameters (the calibration's 'sls' entry)"
        )
    return value


def force_from_conductance_trend(
    t_s: np.ndarray,
    conductance_s: np.ndarray,
    trend: SLSTrend,
    area_m2: float,
    phys: PhysicsConstants,
    *,
    with_contact: bool = True,
) -> ForceResult:
    """Force (N) from conductance (S) with the paper's force-dependent parameters: the exact inverse of
    :func:`strain_from_force_trend` + Eq. 3 (one sensor (N,), hold interpolation, any thread).

    Per step the creep uses E1, τ at the force held over the step and the instantaneous part uses E0 at the new force,
    so the per-step equation stays scalar and monotone (needs E0's intercept > 0). Statuses as
    :func:`force_from_conductance`; ValueError (naming the sample) if the trend turns non-positive at an estimated
    force. O(1) per sample, but a Python loop: for offline use and benchmarks, not the 1 kHz many-sensor stream.
    """
    steps = check_timestamps(t_s)
    cond = np.asarray(conductance_s, dtype=np.float64)
    if cond.shape != steps.shape:
        raise ValueError(f"conductance_s must be (N,) with N = {steps.size}, got shape {cond.shape}")
    area = float(_check_area(area_m2, 1)[0])
    if not trend.E0_Pa[0] > 0.0:
        raise ValueError(
            f"sls_trend E0_Pa intercept must be > 0 for a monotone inverse, got {trend.E0_Pa[0]!r}"
        )
    phys_used = phys if with_contact else phys.without_contact()
    contact = phys_used.has_contact
    k, r0, kc = phys_used.tunnelling_k, phys_used.R0_ohm, phys_used.K_contact_ohm_sqrtN
    valid = (cond >= _OPEN_BELOW_S) & np.isfinite(cond)
    if not contact:
        strain_res = strain_from_resistance(1.0 / np.where(valid, cond, 1.0), 1.0, phys_used)
    force = np.zeros(cond.size)
    status = np.zeros(cond.size, dtype=np.int8)
    q = 0.0
    f_prev = 0.0  # force held over the coming step (N)
    sig_over_e1 = 0.0
    for i, c in enumerate(cond.tolist()):
        tau = _trend_value(trend.mu1_Pa_s, f_prev, "mu1_Pa_s", i) / _trend_value(
            trend.E1_Pa, f_prev, "E1_Pa", i
        )
        q += -math.expm1(-steps[i] / tau) * (sig_over_e1 - q)
        if c != c:
            force[i] = math.nan
            status[i] = ForceStatus.NAN_INPUT
            continue  # the previous force stays held over the gap
        code: int = ForceStatus.OK
        if not valid[i] and c != math.inf:
            f_new = 0.0
            code = ForceStatus.NEGATIVE_CONDUCTANCE if c < 0.0 else ForceStatus.OPEN_CIRCUIT
        elif contact:
            # C = ∞ is beyond every finite reading: the solver returns the ε → 1 cap, flagged SATURATED.
            f_new, code = _solve_contact_trend_scalar(min(c, 1e300), q, area, trend.E0_Pa, k, r0, kc)
        else:
            strain = 1.0 if c == math.inf else float(strain_res.strain[i])
            d = strain - q  # = F/(A·E0(F))
            a, b = trend.E0_Pa
            code = 0
            if c == math.inf or strain_res.status[i] == StrainStatus.STRAIN_NEAR_ONE:
                code = ForceStatus.SATURATED
            if d * area * b >= 1.0:
                f_new, code = 1e12, ForceStatus.SATURATED
            else:
                f_new = d * area * a / (1.0 - d * area * b)
            if f_new < 0.0:
                if f_new < -_BELOW_BASELINE_FLAG_N and code == 0:
                    code = ForceStatus.BELOW_BASELINE
                f_new = 0.0
        force[i] = f_new
        status[i] = code
        f_prev = f_new
        sig_over_e1 = f_new / area / _trend_value(trend.E1_Pa, f_new, "E1_Pa", i)
    return ForceResult(force, status)
