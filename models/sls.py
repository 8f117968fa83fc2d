"""Standard linear solid (the paper's Eq. 2, 6, 10–12): force ↔ strain ↔ conductance, exact and O(1) per sample.

Model: a spring ``E0`` in series with (``E1`` ∥ dashpot ``mu1``). Writing ``ε = σ/E0 + q``, the Kelvin–Voigt strain
obeys ``τ·q̇ + q = σ/E1`` with ``τ = mu1/E1``. Over a step ``h`` with ``x = h/τ`` and ``α = e^(−x)`` it has the exact
updates (NUMERICS pitfall 1)::

    hold   (force held between samples, what Eq. 12 does):   q⁺ = q + (1−α)·(σ/E1 − q)
    linear (force linear between samples):                   q⁺ = q + (1−α)·(σ/E1 − q) + (1−φ1)·(σ⁺ − σ)/E1

with ``φ1 = (1 − e^(−x))/x``; ``1−φ1`` uses a series for x < 0.1 so that x ≈ 1e-5 (370 s at 1 kHz) keeps full
precision. The updates are written as increments of q (rather than ``α·q + …``) for the same reason.

Conventions shared by every function here:

- ``t_s`` is (N,) seconds; forces/conductances are (N,) or (N, S) for S sensors; parameters and area are scalars or
  (S,) arrays (one per sensor). All arithmetic is float64.
- The record starts from rest: before the first sample the force is 0 and the creep strain is 0, and the first
  sample is a step from 0 (Eq. 10's ``σ0·J(t)``).
- Duplicate timestamps are zero-length steps (an instantaneous change); timestamps going backwards or non-finite
  timestamps are refused with a ValueError naming the sample.
- A NaN sample is a dropped sample: its output is NaN, and the model carries on as if the last valid force had been
  held over the gap (zero-order hold of the missing value), so the state is never corrupted.
- The paper's parameters "increase linearly with force" (Sec. IV-A). Strictly that breaks superposition; here the
  model uses fixed parameters, i.e. the parameters at one reference force: the calibration's ``sls`` entry, or
  ``SLSTrend.at(reference_force_n)`` (the middle of the calibrated range is the natural choice).
  ``strain_from_force_trend`` / ``force_from_conductance_trend`` run the force-dependent variant (parameters at the
  current force inside each step; one sensor, hold) so the benchmark can measure the error of the fixed choice
  (bench_estimators: up to ~18 % at the ends of 1.75–5.25 N when the parameters change by ±25 % over that range).
- The inverse under "hold" propagates an error by ``1 − (1−α)(1 + E0/E1)`` per step, which exceeds 1 in magnitude
  only when E0 > E1 and a step is longer than about τ (a long gap, or τ → 0); such steps are inverted under the
  linear assumption, which is always stable (see :meth:`SLSInverse.update`).

Every function and class here is pure numerics and may be called from any thread; an :class:`SLSInverse` instance
holds state and must be used from one thread at a time.
"""

from __future__ import annotations

import contextlib
import enum
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from models import sls_kernels
from models.physics import (
    STRAIN_NEAR_ONE,
    PhysicsConstants,
    StrainStatus,
    conductance_from_strain,
    explain_status,
    strain_from_resistance,
)

INTERPOLATIONS = ("hold", "linear")
ENGINES = ("auto", "numpy")
_engine = "auto"  # "auto": the compiled kernels (models.sls_kernels) when numba is there; "numpy": the reference


@contextlib.contextmanager
def engine(name: str) -> Iterator[None]:
    """Run the recursions with ``name``: ``"auto"`` (compiled when numba is available) or ``"numpy"`` (the exact
    pure-numpy reference paths). For tests and benchmarks; not thread-safe (it sets a module-wide choice)."""
    global _engine
    if name not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {name!r}")
    previous, _engine = _engine, name
    try:
        yield
    finally:
        _engine = previous


def _compiled():
    return sls_kernels.kernels() if _engine == "auto" else None

SLS_KEYS = ("E0_Pa", "E1_Pa", "mu1_Pa_s")

# Below this x = h/τ, 1 − φ1 comes from its Taylor series (direct evaluation cancels: relative error ~ε_mach/x).
_SERIES_X = 0.1
_NEWTON_MAX_ITER = 100  # per-step force solve: warm-started Newton needs ~3, the bisection fallback ≤ 60
_LOG_F_TOL = 1e-13
_FAST_NEWTON_ITER = 5  # warm-started Newton: typically 3 steps
_FAST_STEP_TOL = 1e-8  # a last step this small in log F leaves a quadratic error ~1e-16
_OPEN_BELOW_S = float(np.finfo(np.float64).tiny)  # conductances below this read as open circuits
_BELOW_BASELINE_FLAG_N = 1e-9  # negative forces are always clipped to 0 N; flagged only beyond this


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


# --------------------------------------------------------------------------------------------------------------------
# step coefficients and input checks


def one_minus_phi1(x: np.ndarray) -> np.ndarray:
    """``1 − φ1(x)`` with ``φ1 = (1 − e^(−x))/x``, accurate to ~1e-16 relative for all x ≥ 0 (x = ∞ gives 1)."""
    x = np.asarray(x, dtype=np.float64)
    small = x < _SERIES_X
    xs = np.where(small, x, 0.0)
    series = xs * (
        1 / 2
        - xs
        * (
            1 / 6
            - xs
            * (
                1 / 24
                - xs
                * (
                    1 / 120
                    - xs * (1 / 720 - xs * (1 / 5040 - xs * (1 / 40320 - xs * (1 / 362880 - xs / 3628800))))
                )
            )
        )
    )
    xl = np.where(small, 1.0, x)
    direct = 1.0 + np.expm1(-xl) / xl
    return np.where(small, series, direct)


def check_timestamps(t_s: np.ndarray, t_prev_s: float | None = None) -> np.ndarray:
    """Validate timestamps (s): 1-D, finite, never decreasing (duplicates are zero-length steps). Returns the steps
    h (N,) in s, where h[0] is the step from ``t_prev_s`` (0 when None: the record starts at t[0]). ValueError names
    the first bad sample."""
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1:
        raise ValueError(f"timestamps must be a 1-D array, got shape {t.shape}")
    bad = ~np.isfinite(t)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ValueError(
            f"timestamp at sample {i} is not finite ({t[i]!r}): drop or repair it before estimating"
        )
    steps = np.empty_like(t)
    if t.size:
        steps[1:] = np.diff(t)
        steps[0] = 0.0 if t_prev_s is None else t[0] - t_prev_s
    back = steps < 0.0
    if np.any(back):
        i = int(np.argmax(back))
        before = t_prev_s if i == 0 else t[i - 1]
        where = "the previous block's last sample" if i == 0 else f"sample {i - 1}"
        raise ValueError(
            f"timestamps go backwards at sample {i}: t = {t[i]!r} s < {before!r} s at {where}; "
            f"sort the record or split it where the clock was reset"
        )
    return steps


def _as_2d(values: np.ndarray, n_samples: int, what: str) -> tuple[np.ndarray, bool]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1:
        arr2 = arr[:, None]
    elif arr.ndim == 2:
        arr2 = arr
    else:
        raise ValueError(f"{what} must be (N,) or (N, S), got shape {arr.shape}")
    if arr2.shape[0] != n_samples:
        raise ValueError(f"{what} has {arr2.shape[0]} samples but there are {n_samples} timestamps")
    return arr2, arr.ndim == 1


def _per_sensor(value: object, n_sensors: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0 or arr.size == 1:
        return np.full(n_sensors, float(arr.reshape(-1)[0]))
    if arr.shape != (n_sensors,):
        raise ValueError(
            f"{name} has {arr.size} per-sensor values but the data has {n_sensors} sensor column(s)"
        )
    return arr.astype(np.float64, copy=True)


def _check_area(area_m2: object, n_sensors: int) -> np.ndarray:
    area = _per_sensor(area_m2, n_sensors, "area_m2")
    if not np.all(np.isfinite(area) & (area > 0.0)):
        raise ValueError(f"sensor area must be positive and finite (m²), got {area_m2!r}")
    return area


def _check_interp(interp: str) -> None:
    if interp not in INTERPOLATIONS:
        raise ValueError(f"interp must be one of {INTERPOLATIONS}, got {interp!r}")


@dataclass
class _Coeffs:
    e0: np.ndarray
    e1: np.ndarray
    tau: np.ndarray
    area: np.ndarray


def _coeffs(params: SLSParams, area_m2: object, n_sensors: int) -> _Coeffs:
    if params.n_sensors is not None and params.n_sensors not in (1, n_sensors):
        raise ValueError(
            f"SLS parameters are for {params.n_sensors} sensors but the data has {n_sensors} column(s)"
        )
    e0 = _per_sensor(params.E0_Pa, n_sensors, "E0_Pa")
    e1 = _per_sensor(params.E1_Pa, n_sensors, "E1_Pa")
    mu1 = _per_sensor(params.mu1_Pa_s, n_sensors, "mu1_Pa_s")
    return _Coeffs(e0=e0, e1=e1, tau=mu1 / e1, area=_check_area(area_m2, n_sensors))


def _fill_forward(values: np.ndarray, initial: np.ndarray) -> np.ndarray:
    """NaN samples replaced by the last valid value of their column (``initial`` before the first)."""
    out = values.copy()
    nan = np.isnan(out)
    if not nan.any():
        return out
    n, s = out.shape
    idx = np.where(~nan, np.arange(n)[:, None], -1)
    np.maximum.accumulate(idx, axis=0, out=idx)
    cols = np.broadcast_to(np.arange(s), (n, s))
    filled = np.where(idx >= 0, out[np.maximum(idx, 0), cols], initial[None, :])
    return filled


# --------------------------------------------------------------------------------------------------------------------
# forward: force → strain → conductance


def _creep_strain(
    one_minus_alpha: np.ndarray, drive: np.ndarray, ramp: np.ndarray | None, q0: np.ndarray
) -> np.ndarray:
    """Kelvin–Voigt strain q at every sample. drive[n] = σ[n]/E1; ramp[n] = (1−φ1) for the step ending at n (linear
    interpolation) or None (hold). one_minus_alpha[n] is for the step ending at sample n. Returns (N, S)."""
    n, s = drive.shape
    q_all = np.empty((n, s))
    compiled = _compiled()
    if compiled is not None and n:
        oma_c = np.ascontiguousarray(np.broadcast_to(one_minus_alpha, (n, one_minus_alpha.shape[1])))
        ramp_c = oma_c if ramp is None else np.ascontiguousarray(ramp)
        compiled.creep_strain(oma_c, np.ascontiguousarray(drive), ramp_c, ramp is not None,
                              np.ascontiguousarray(q0, dtype=np.float64), q_all)
        return q_all
    prev_drive = np.zeros(s) if n == 0 else drive[0] * 0.0
    if s == 1:
        # One sensor: plain Python floats are ~10× faster per step than numpy scalars.
        oma = one_minus_alpha[:, 0].tolist()
        dr = drive[:, 0].tolist()
        rp = ramp[:, 0].tolist() if ramp is not None else None
        q = float(q0[0])
        prev = 0.0
        out = [0.0] * n
        for i in range(n):
            if i:
                prev = dr[i - 1]
            q += oma[i] * (prev - q)
            if rp is not None:
                q += rp[i] * (dr[i] - prev)
            out[i] = q
        q_all[:, 0] = out
        return q_all
    q_vec = q0.astype(np.float64, copy=True)
    tmp = np.empty(s)
    for i in range(n):
        if i:
            prev_drive = drive[i - 1]
        np.subtract(prev_drive, q_vec, out=tmp)
        tmp *= one_minus_alpha[i]
        q_vec += tmp
        if ramp is not None:
            np.subtract(drive[i], prev_drive, out=tmp)
            tmp *= ramp[i]
            q_vec += tmp
        q_all[i] = q_vec
    return q_all


def strain_from_force(
    t_s: np.ndarray,
    force_n: np.ndarray,
    params: SLSParams,
    area_m2: float | np.ndarray,
    interp: str = "hold",
) -> np.ndarray:
    """Strain (dimensionless) from force (N) by the exact O(1)-per-sample recursion; same shape as ``force_n``.

    See the module docstring for shapes, the rest initial state, timestamps and NaN handling. ``interp``: "hold"
    (force constant between samples, the paper's Eq. 12) or "linear" (force linear between samples).
    """
    _check_interp(interp)
    steps = check_timestamps(t_s)
    force, was_1d = _as_2d(force_n, steps.size, "force_n")
    co = _coeffs(params, area_m2, force.shape[1])
    sigma_raw = force / co.area
    sigma = _fill_forward(sigma_raw, np.zeros(force.shape[1]))
    tau = co.tau[:1] if np.all(co.tau == co.tau[0]) else co.tau  # shared τ: (N, 1) coefficients broadcast
    x = steps[:, None] / tau[None, :]
    oma = -np.expm1(-x)
    ramp = one_minus_phi1(x) if interp == "linear" else None
    drive = sigma / co.e1
    q = _creep_strain(oma, drive, ramp, np.zeros(force.shape[1]))
    strain = sigma / co.e0 + q
    strain[np.isnan(sigma_raw)] = np.nan
    return strain[:, 0] if was_1d else strain


def strain_from_force_superposition(
    t_s: np.ndarray,
    force_n: np.ndarray,
    params: SLSParams,
    area_m2: float | np.ndarray,
    interp: str = "hold",
) -> np.ndarray:
    """The paper's Boltzmann superposition (Eq. 10/12) summed naively over all past increments: O(N²) time.

    The reference for :func:`strain_from_force` (same conventions). "hold" sums step responses ``Δσ_i·J(t − t_i)``;
    "linear" sums ramp responses, the exact integral of J over each linear segment. Use on short records only.
    """
    _check_interp(interp)
    t = np.asarray(t_s, dtype=np.float64)
    steps = check_timestamps(t)
    force, was_1d = _as_2d(force_n, steps.size, "force_n")
    n, s = force.shape
    co = _coeffs(params, area_m2, s)
    sigma_raw = force / co.area
    sigma = _fill_forward(sigma_raw, np.zeros(s))
    strain = np.empty((n, s))
    if interp == "hold":
        increments = np.diff(sigma, axis=0, prepend=0.0)
        for i in range(n):
            u = (t[i] - t[: i + 1])[:, None] / co.tau[None, :]
            compliance = 1.0 / co.e0 + (-np.expm1(-u)) / co.e1
            strain[i] = np.sum(increments[: i + 1] * compliance, axis=0)
    else:
        ramp_x = steps[1:, None] / co.tau[None, :]  # segment i spans samples i → i+1
        phi1 = 1.0 - one_minus_phi1(ramp_x)
        ramp_gap = one_minus_phi1(ramp_x)
        increments = np.diff(sigma, axis=0)
        for i in range(n):
            initial = sigma[0] * (1.0 / co.e0 + (-np.expm1(-(t[i] - t[0]) / co.tau)) / co.e1)
            if i:
                a = (t[i] - t[1 : i + 1])[:, None] / co.tau[None, :]
                # 1 − e^(−a)·φ1 written without cancellation for small a and x.
                mean_compliance = 1.0 / co.e0 + (ramp_gap[:i] + phi1[:i] * (-np.expm1(-a))) / co.e1
                strain[i] = initial + np.sum(increments[:i] * mean_compliance, axis=0)
            else:
                strain[i] = initial
    strain[np.isnan(sigma_raw)] = np.nan
    return strain[:, 0] if was_1d else strain


def strain_from_force_trend(
    t_s: np.ndarray,
    force_n: np.ndarray,
    trend: SLSTrend,
    area_m2: float,
) -> np.ndarray:
    """Strain for the paper's force-dependent parameters (E0, E1, mu1 linear in force), hold interpolation, one
    sensor (N,): each step uses the parameters at the force held over it, and the instantaneous part
    ``σ/E0(F)``. This is quasi-linear viscoelasticity (superposition no longer holds); it exists to measure the error
    of evaluating the parameters at one reference force. ValueError if the trend is non-positive somewhere."""
    steps = check_timestamps(t_s)
    force = np.asarray(force_n, dtype=np.float64)
    if force.shape != steps.shape:
        raise ValueError(f"force_n must be (N,) with N = {steps.size}, got shape {force.shape}")
    filled = _fill_forward(force[:, None], np.zeros(1))[:, 0]
    p = trend.at(np.maximum(filled, 0.0))
    sigma = filled / float(area_m2)
    e1 = np.asarray(p.E1_Pa) * np.ones_like(sigma)
    tau = np.asarray(p.tau_s) * np.ones_like(sigma)
    # step i (ending at sample i) is governed by the force held over it, sample i−1
    tau_step = np.concatenate([[tau[0]], tau[:-1]])
    oma = -np.expm1(-steps / tau_step)
    drive = sigma / e1
    q = _creep_strain(oma[:, None], drive[:, None], None, np.zeros(1))[:, 0]
    strain = sigma / np.asarray(p.E0_Pa) + q
    strain[np.isnan(force)] = np.nan
    return strain


def conductance_from_force(
    t_s: np.ndarray,
    force_n: np.ndarray,
    params: SLSParams,
    area_m2: float | np.ndarray,
    phys: PhysicsConstants,
    interp: str = "hold",
    *,
    overstrain: str = "raise",
) -> np.ndarray:
    """Conductance (S) from force (N): SLS strain, then Eq. 3 with the contact term ``K/√F`` of ``phys`` (K = 0 in
    ``phys`` switches it off). With the contact term, F ≤ 0 reads as an open circuit (C = 0). ValueError if a force
    drives the strain to ≥ 1 (the model has no meaning there: R would be ≤ 0); with ``overstrain="clamp"`` (for
    optimisers exploring parameter space) the strain is clamped at 1 instead, i.e. the tunnelling part is 0 and
    ``C = √F/K`` (∞ without a contact term)."""
    if overstrain not in ("raise", "clamp"):
        raise ValueError(f"overstrain must be 'raise' or 'clamp', got {overstrain!r}")
    strain = strain_from_force(t_s, force_n, params, area_m2, interp)
    too_big = strain >= 1.0
    if overstrain == "clamp":
        strain = np.minimum(strain, 1.0)
    elif np.any(too_big):
        index = np.unravel_index(int(np.argmax(too_big)), strain.shape)
        raise ValueError(
            f"force {np.asarray(force_n)[index]!r} N at sample {index[0]} drives the strain to "
            f"{strain[index]:.3g} ≥ 1: far outside the sensor model (check the force units and the SLS parameters)"
        )
    return conductance_from_strain(strain, np.asarray(force_n, dtype=np.float64), phys)


# --------------------------------------------------------------------------------------------------------------------
# inverse: conductance → force


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
        compiled = _compiled()
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
        kern.inverse(np.ascontiguousarray(cond.T), oma_t, ramp_t, ramp is not None, co.e0, co.e1, co.area, contact,
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


def _newton_in_log_force(
    y: float, y_lo: float, y_hi: float, log_c: float, q: float, area: float, a: float, b: float,
    k: float, r0: float, kc: float,
) -> tuple[float, int]:
    """Solve ``φ(y) = ln(K·e^(−y/2) + R0·(1−ε)·e^(−kε)) + ln C = 0`` for ``y = ln F`` (F in N), with
    ``ε = q + F/(A·(a + b·F))``: safeguarded Newton from ``y``, the root bracketed by ``[y_lo, y_hi]``.

    φ is strictly decreasing (``F/(a + bF)`` increases with F for a > 0). The bracket shrinks with every evaluation
    and a step that would leave it bisects instead. Returns (F, 0), or (last F, NOT_CONVERGED) at the iteration cap.
    One loop for both scalar inverses: the fixed parameters pass ``A = 1, a = 1/w, b = 0`` (ε = q + w·F), the
    force-dependent ones E0's trend. φ is written out here rather than passed as a callable: this is the inner loop
    of the one-sensor stream, and a closure call per iteration cost ~25 % of its time (measured)."""
    for _ in range(_NEWTON_MAX_ITER):
        f = math.exp(y)
        e0_f = a + b * f
        eps = q + f / (area * e0_f)
        one_minus = 1.0 - eps
        contact = kc * math.exp(-0.5 * y)  # K/√F without underflowing F
        if one_minus > 0.0:
            tunnel = r0 * one_minus * math.exp(-k * eps)
            r = contact + tunnel
            dphi = (-0.5 * contact - tunnel * (1.0 / one_minus + k) * (a / (area * e0_f * e0_f)) * f) / r
        else:  # beyond ε = 1 only the contact term is left (the bracket brings y back)
            r = contact
            dphi = -0.5
        phi = math.log(r) + log_c
        if phi == 0.0:
            return f, 0
        if phi > 0.0:
            y_lo = y
        else:
            y_hi = y
        step = phi / dphi
        y_new = y - step
        if abs(step) <= _LOG_F_TOL * max(1.0, abs(y)):
            return math.exp(y_new), 0
        if not y_lo <= y_new <= y_hi:
            y_new = 0.5 * (y_lo + y_hi)
        y = y_new
        if y_hi - y_lo <= 4e-16 * max(1.0, abs(y)):
            return math.exp(y), 0
    return math.exp(y), ForceStatus.NOT_CONVERGED


def _solve_contact_scalar(
    cond: float, p: float, w: float, f_guess: float, k: float, r0: float, kc: float
) -> tuple[float, int]:
    """Scalar twin of :func:`_solve_contact_step` (same bracket, same safeguarded Newton in log F)."""
    f_max = (1.0 - p) / w
    if not f_max > 0.0:
        return 0.0, ForceStatus.SATURATED
    if kc * cond * kc * cond >= f_max:
        return f_max, ForceStatus.SATURATED
    y_lo = 2.0 * math.log(kc * cond)
    y_hi = math.log(f_max)
    y = math.log(f_guess) if f_guess > 0.0 else 0.5 * (y_lo + y_hi)
    if not y_lo < y < y_hi:
        y = 0.5 * (y_lo + y_hi)
    return _newton_in_log_force(y, y_lo, y_hi, math.log(cond), p, 1.0, 1.0 / w, 0.0, k, r0, kc)


def _solve_contact_step(
    cond: np.ndarray, p: np.ndarray, w: np.ndarray, f_guess: np.ndarray, k: float, r0: float, kc: float
) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``C·(K/√F + R0·(1−ε)·e^(−kε)) = 1`` with ``ε = p + w·F`` for F > 0, per sensor. Returns (F, status).

    φ(y) = ln R(e^y) + ln C is strictly decreasing in y = ln F; it is positive at F = (K·C)² (the contact term alone
    already equals 1/C there) and equals ln(K·C/√F_max) at ``F_max = (1 − p)/w`` (ε = 1), so the root is bracketed
    whenever ``K·C < √F_max``; otherwise the reading is beyond the ε → 1 limit (SATURATED, F = F_max).
    """
    s = cond.shape[0]
    force = np.zeros(s)
    status = np.zeros(s, dtype=np.int8)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        f_max = (1.0 - p) / w
        readable = np.isfinite(cond) & (cond > 0.0)
        active = readable & (f_max > 0.0)
        sat = (np.isposinf(cond) | (active & (kc * cond * kc * cond >= f_max))) & (f_max > 0.0)
        force[sat] = f_max[sat]
        status[sat] = ForceStatus.SATURATED
        # Creep strain alone already at ε ≥ 1 (absurd loading history): nothing left to explain the reading.
        status[readable & ~(f_max > 0.0)] = ForceStatus.SATURATED
        active &= ~sat
        if not np.any(active):
            force[np.isnan(cond)] = np.nan
            return force, status
        idx = np.nonzero(active)[0]
        c = cond[idx]
        pa, wa = p[idx], w[idx]
        log_c = np.log(c)
        g = f_guess[idx]
        if np.all(g > 0.0):
            # Fast path: plain Newton from the previous force (one step earlier the force was nearly the same, so
            # 2–3 quadratic steps suffice). Anything that does not settle inside the domain goes to the bracket.
            y = np.log(g)
            for _ in range(_FAST_NEWTON_ITER):
                f = np.exp(y)
                eps = pa + wa * f
                one_minus = 1.0 - eps
                tunnel = r0 * one_minus * np.exp(-k * eps)
                contact = kc * np.exp(-0.5 * y)  # K/√F without underflowing F
                r = contact + tunnel
                step = (np.log(r) + log_c) * r / (-0.5 * contact - tunnel * (1.0 / one_minus + k) * wa * f)
                y = y - step
                if float(np.max(np.abs(step))) <= _FAST_STEP_TOL:
                    break
            # After a step ≤ 1e-8 in log F the quadratic error left is ~1e-16: converged.
            settled = (np.abs(step) <= _FAST_STEP_TOL) & (one_minus > 0.0) & np.isfinite(y)
            force[idx[settled]] = np.exp(y[settled])
            if settled.all():
                force[np.isnan(cond)] = np.nan
                return force, status
            rest = ~settled
            idx, c, pa, wa, log_c, g = idx[rest], c[rest], pa[rest], wa[rest], log_c[rest], g[rest]
        f_sub, done = _solve_contact_bracketed(c, log_c, pa, wa, g, f_max[idx], k, r0, kc)
        force[idx] = f_sub
        status[idx[~done]] = ForceStatus.NOT_CONVERGED
        force[np.isnan(cond)] = np.nan
    return force, status


def _solve_contact_bracketed(c, log_c, pa, wa, g, f_max, k, r0, kc) -> tuple[np.ndarray, np.ndarray]:
    """The guaranteed solve of :func:`_solve_contact_step`: Newton in log F kept inside the shrinking bracket
    ``[(K·C)², F_max]``, bisecting whenever a step would leave it. Returns (F, converged)."""
    y_lo = 2.0 * np.log(kc * c)
    y_hi = np.log(f_max)
    y = np.where((g > 0.0), np.log(np.where(g > 0.0, g, 1.0)), 0.5 * (y_lo + y_hi))
    y = np.where((y > y_lo) & (y < y_hi), y, 0.5 * (y_lo + y_hi))
    done = np.zeros(c.size, dtype=bool)
    for _ in range(_NEWTON_MAX_ITER):
        f = np.exp(y)
        eps = pa + wa * f
        one_minus = 1.0 - eps
        tunnel = r0 * one_minus * np.exp(-k * eps)
        contact = kc * np.exp(-0.5 * y)  # K/√F without underflowing F
        r = contact + tunnel
        phi = np.log(r) + log_c
        dphi = (-0.5 * contact - tunnel * (1.0 / one_minus + k) * wa * f) / r
        # Keep the bracket: φ > 0 means the root is at larger F.
        pos = phi > 0.0
        y_lo = np.where(pos & ~done, y, y_lo)
        y_hi = np.where(~pos & ~done, y, y_hi)
        newton_step = phi / dphi
        converged = (np.abs(newton_step) <= _LOG_F_TOL * np.maximum(1.0, np.abs(y))) | (phi == 0.0)
        y_new = y - newton_step
        outside = ~((y_new >= y_lo) & (y_new <= y_hi)) | ~np.isfinite(y_new)
        y_new = np.where(outside & ~converged, 0.5 * (y_lo + y_hi), y_new)
        y = np.where(done, y, y_new)
        done |= converged | (y_hi - y_lo <= 4e-16 * np.maximum(1.0, np.abs(y)))
        if done.all():
            break
    return np.exp(y), done


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


# --------------------------------------------------------------------------------------------------------------------
# the force-dependent variant (the paper's parameters linear in force), one sensor, hold interpolation


def _trend_value(pair: tuple[float, float], force_n: float, key: str, index: int) -> float:
    value = pair[0] + pair[1] * force_n
    if not value > 0.0:
        raise ValueError(
            f"sls_trend gives {key} = {value:.4g} ≤ 0 at the estimated force {force_n:.4g} N (sample {index}): "
            f"the trend is not valid there; use fixed parameters (the calibration's 'sls' entry)"
        )
    return value


def _solve_contact_trend_scalar(
    cond: float, q: float, area: float, e0: tuple[float, float], k: float, r0: float, kc: float
) -> tuple[float, int]:
    """Solve ``C·(K/√F + R0·(1−ε)·e^(−kε)) = 1`` with ``ε = q + F/(A·(a + b·F))`` (E0 linear in F) for F > 0.

    ``F/(a + bF)`` increases with F whenever a > 0, so φ(ln F) is still strictly decreasing: bracket
    ``[(K·C)², F_cap]`` (F_cap: ε = 1, E0 → 0, or 1e12 N) and safeguarded Newton in log F, as in the fixed case."""
    a, b = e0
    caps = [1e12]
    if b < 0.0:
        caps.append(-a / b * (1.0 - 1e-12))
    room = 1.0 - q  # strain left before ε = 1
    if room <= 0.0:
        return 0.0, ForceStatus.SATURATED
    if room * area * b < 1.0:
        caps.append(room * area * a / (1.0 - room * area * b))
    f_cap = min(caps)
    y_lo = 2.0 * math.log(kc * cond)
    y_hi = math.log(f_cap)
    log_c = math.log(cond)

    if y_lo >= y_hi:
        return f_cap, ForceStatus.SATURATED
    # φ(y_hi) ≥ 0: even the largest admissible force leaves R too high, the reading is beyond the ε → 1 limit.
    f_hi = math.exp(y_hi)
    eps_hi = q + f_hi / (area * (a + b * f_hi))
    tunnel_hi = r0 * (1.0 - eps_hi) * math.exp(-k * eps_hi) if eps_hi < 1.0 else 0.0
    if math.log(kc * math.exp(-0.5 * y_hi) + tunnel_hi) + log_c >= 0.0:
        return f_cap, ForceStatus.SATURATED
    return _newton_in_log_force(0.5 * (y_lo + y_hi), y_lo, y_hi, log_c, q, area, a, b, k, r0, kc)


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
