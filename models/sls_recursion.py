"""The forward SLS recursion (part of :mod:`models.sls`, which re-exports it): force → strain → conductance.

The exact O(1)-per-sample step updates, the O(N²) superposition reference, the force-dependent variant, and the
input checks and step coefficients the inverse shares. The conventions are in :mod:`models.sls`. Pure numerics, any
thread; :func:`engine` sets a module-wide choice (tests and benchmarks only).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from models import sls_ckernel, sls_kernels
from models.physics import PhysicsConstants, conductance_from_strain
from models.sls_model import SLSParams, SLSTrend

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


def _compiled_inverse():
    """The conductance → force kernel: the C library (:mod:`models.sls_ckernel`, ~1 ms to load) when it builds,
    else numba's, else None (the numpy reference)."""
    if _engine != "auto" or sls_kernels.disabled():
        return None
    c_kernel = sls_ckernel.inverse_kernel()
    if c_kernel is not None:
        return c_kernel
    numba_kernels = sls_kernels.kernels()
    return None if numba_kernels is None else numba_kernels.inverse

# Below this x = h/τ, 1 − φ1 comes from its Taylor series (direct evaluation cancels: relative error ~ε_mach/x).
_SERIES_X = 0.1


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
