"""A segment's shell from the calibration rig's force against deflection: stiffness and travel, with 95 % intervals.

The rig winds its cable ``u = r·(θ − θ_ref)`` (m) through its spring (``k``) onto a probe; a dial gauge reads the
probe's position ``g`` (m). Past the contact ``u_c`` the probe follows the shell in, ``d = g − g₀``, and the probe is in
equilibrium between the spring, the gauge's plunger (``F_g0 − k_g·d``) and the shell (``F_g0 + k_shell·d``, the
preload balancing at ``d = 0``)::

    k·(u − u_c − d) − k_g·d = k_shell·d   ⇒   d = s·(u − u_c),   s = k / (k + k_shell + k_g)

until the shell bottoms out after ``D`` of travel (``d`` then stays at ``D`` however far the cable winds). So the
readings against the winding are a flat line (slack), a rising line of slope ``s``, and (if the ramp reaches it) a
flat line again: ``g = g₀ + min(s·max(0, u − u_c), D)``, fitted by least squares (a grid over the knees, then
``scipy.optimize.least_squares``). Only ``u`` (the servo's encoder, 4096 ticks a turn: 0.03 mm of cable on a 20 mm
wheel) and ``g`` are measured; the force at each step follows as ``k·(u − u_c − d) + F_g0 − k_g·d``. The stiffness is
``k/s − k − k_g``, its interval that of ``s`` mapped through it; the travel is ``D`` plus the preload's
``F_g0/k_shell``. Intervals are t-intervals from the Jacobian with the residual's scatter, not less than the gauge's
digit allows (``resolution/√12``); they hold the gauge's noise only: the spring's own ``k`` scales the stiffness
directly (a spring known to ±5 % gives it to ±5 %) and is not in them.

A value is refused (named "not fixed", with the reason) when the data cannot fix it: fewer than
:data:`MIN_LOADED_STEPS` steps between contact and bottoming, an interval wider than ±:data:`FIXED_WITHIN`, or a
residual several times what the gauge explains (the shell is not a linear spring over the range); the travel when
the shell never bottomed out. The damping never: readings at rest see only the static deflection. Pure numerics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from models.errors import ShellFitError

MIN_STEPS = 6  # readings in all
MIN_LOADED_STEPS = 4  # between contact and bottoming out, for the slope
MIN_BOTTOMED_STEPS = 3  # past the bottoming knee, for the travel
NO_CONTACT_DIGITS = 5  # the probe moving less than this many gauge digits over the whole ramp: no contact
FALL_DIGITS = 3  # a reading this many digits below an earlier one while the cable winds on: the cable let go
FIXED_WITHIN = 0.10  # a 95 % interval within ±10 % of the value fixes it
NONLINEAR_FACTOR = 3.0  # a residual RMS above this × what the gauge explains: not a linear spring
BOTTOM_F_TEST = 0.01  # the bottoming knee must beat the single-knee fit at this level (extra-sum-of-squares F test)


@dataclass(frozen=True)
class ShellFit:
    """The fit's values (SI units), each with its 95 % interval; ``not_fixed`` names each value the data cannot
    fix and why (``shell_stiffness_n_per_m``, ``shell_travel_m``, ``shell_damping_n_s_per_m``)."""

    stiffness_n_per_m: float
    stiffness_interval: tuple[float, float]
    travel_m: float  # nan when the shell never bottomed out
    travel_interval: tuple[float, float]
    slope: float  # probe travel per metre of cable, s
    contact_cable_m: float  # u_c
    residual_rms_m: float
    noise_floor_m: float  # what the gauge's digit alone explains (resolution/√12)
    n_slack: int
    n_loaded: int
    n_bottomed: int
    largest_travel_m: float
    largest_force_n: float
    force_n: np.ndarray  # the force at each step (N)
    travel_from_rest_m: np.ndarray  # d at each step (m)
    not_fixed: dict[str, str] = field(default_factory=dict)


def _model(u: np.ndarray, g0: float, s: float, uc: float, d_max: float) -> np.ndarray:
    return g0 + np.minimum(s * np.maximum(0.0, u - uc), d_max)


def _grid(u: np.ndarray, g: np.ndarray, bottomed: bool) -> tuple[float, float, float, float, float]:
    """The best (sse, g0, s, uc, d_max) over knees at the readings' midpoints (and before the first), each with its
    linear least squares."""
    cands = np.concatenate([[u[0] - (u[1] - u[0])], 0.5 * (u[1:] + u[:-1])])
    best = (math.inf, 0.0, 0.0, 0.0, math.inf)
    ends = cands if bottomed else [math.inf]
    for uc in cands:
        for ub in ends:
            if ub <= uc:
                continue
            x = np.clip(u, uc, ub) - uc
            if np.count_nonzero(x > 0) < 2:
                continue
            design = np.column_stack([np.ones_like(u), x])
            coef, *_ = np.linalg.lstsq(design, g, rcond=None)
            if coef[1] <= 0:
                continue
            sse = float(np.sum((design @ coef - g) ** 2))
            if sse < best[0]:
                best = (sse, float(coef[0]), float(coef[1]), float(uc),
                        float(coef[1] * (ub - uc)) if bottomed else math.inf)
    return best


def _refine(u: np.ndarray, g: np.ndarray, start: tuple[float, float, float, float, float], bottomed: bool
            ) -> tuple[np.ndarray, float, np.ndarray]:
    """Least squares from the grid's best: (params, sse, Jacobian at the fit); params g0, s, uc[, d_max]."""
    from scipy.optimize import least_squares

    _, g0, s, uc, d_max = start
    x0 = np.array([g0, s, uc, d_max] if bottomed else [g0, s, uc])

    def residual(p: np.ndarray) -> np.ndarray:
        return _model(u, p[0], p[1], p[2], p[3] if bottomed else math.inf) - g

    scale = np.array([1e-4, 0.1, 1e-3, 1e-4] if bottomed else [1e-4, 0.1, 1e-3])
    result = least_squares(residual, x0, x_scale=scale, method="lm" if len(u) > len(x0) else "trf")
    p = result.x
    sse = float(np.sum(result.fun ** 2))
    if sse > start[0]:  # the polish went astray on a kink: keep the grid's
        p, sse = x0, start[0]
    s, uc = p[1], p[2]
    d_max = p[3] if bottomed else math.inf
    rising = s * np.maximum(0.0, u - uc)
    loaded = (u > uc) & (rising < d_max)
    cols = [np.ones_like(u), np.where(loaded, np.maximum(0.0, u - uc), 0.0), np.where(loaded, -s, 0.0)]
    if bottomed:
        cols.append((rising >= d_max).astype(float))
    return p, sse, np.column_stack(cols)


def _t95(dof: int) -> float:
    from scipy.stats import t

    return float(t.ppf(0.975, max(dof, 1)))


def fit_shell(cable_m: np.ndarray, gauge_m: np.ndarray, *, spring_k_n_per_m: float, resolution_m: float,
              gauge_force_n: float = 0.0, gauge_rate_n_per_m: float = 0.0, damping_reason: str = "") -> ShellFit:
    """Fit a shell to the rig's steps: ``cable_m`` the cable wound at each step (m, increasing), ``gauge_m`` the
    gauge's reading there (m, positive into the shell). Raises :class:`ShellFitError` when the data gives no
    stiffness at all (too few steps, no contact, the probe falling back while the cable winds on)."""
    u = np.asarray(cable_m, dtype=float)
    g = np.asarray(gauge_m, dtype=float)
    if u.shape != g.shape or u.ndim != 1 or len(u) < MIN_STEPS:
        raise ShellFitError(f"{len(u)} steps: a shell's fit needs at least {MIN_STEPS} readings")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(g))):
        raise ShellFitError("a step's winding or gauge reading is not a number")
    if np.any(np.diff(u) <= 0):
        raise ShellFitError("the cable was not wound further at every step (the rig's angles do not increase)")
    span = float(g.max() - g.min())
    if span < NO_CONTACT_DIGITS * resolution_m:
        raise ShellFitError(
            f"no contact reached: the probe moved {span * 1e3:.3f} mm over the whole ramp (less than "
            f"{NO_CONTACT_DIGITS} gauge digits): the cable never pressed the probe into the shell (a slack or snapped "
            "cable, the probe off the segment, the gauge not on the probe), or the specimen is too stiff for this "
            "gauge to see it give")
    running = np.maximum.accumulate(g)
    fall = running - g
    worst = int(np.argmax(fall))
    if fall[worst] > FALL_DIGITS * resolution_m:
        raise ShellFitError(
            f"the probe fell back from {running[worst] * 1e3:.3f} to {g[worst] * 1e3:.3f} mm (gauge) at step "
            f"{worst + 1} while the cable was wound further: the cable snapped or slipped, or the probe slid off "
            "the shell; check the rig and run again")
    k, kg = spring_k_n_per_m, gauge_rate_n_per_m
    noise_floor = resolution_m / math.sqrt(12.0)

    one = _grid(u, g, bottomed=False)
    p1, sse1, jac1 = _refine(u, g, one, bottomed=False)
    params, sse, jac, bottomed = p1, sse1, jac1, False
    two = _grid(u, g, bottomed=True)
    if math.isfinite(two[0]) and len(u) > 5:
        p2, sse2, jac2 = _refine(u, g, two, bottomed=True)
        n_past = int(np.count_nonzero(p2[1] * np.maximum(0.0, u - p2[2]) >= p2[3]))
        dof2 = len(u) - 4
        floor_sse = dof2 * noise_floor ** 2
        f_stat = (sse1 - sse2) / max(sse2, floor_sse) * dof2
        from scipy.stats import f as f_dist

        if n_past >= MIN_BOTTOMED_STEPS and f_dist.sf(f_stat, 1, dof2) < BOTTOM_F_TEST:
            params, sse, jac, bottomed = p2, sse2, jac2, True

    g0, s, uc = float(params[0]), float(params[1]), float(params[2])
    d_max = float(params[3]) if bottomed else math.inf
    n_params = len(params)
    dof = len(u) - n_params
    residual_rms = math.sqrt(sse / len(u))
    sigma = max(math.sqrt(sse / max(dof, 1)), noise_floor)
    cov = sigma ** 2 * np.linalg.pinv(jac.T @ jac)
    t95 = _t95(dof)
    travel = np.maximum(0.0, g - g0)
    rising = s * np.maximum(0.0, u - uc)
    n_slack = int(np.count_nonzero(u <= uc))
    n_bottomed = int(np.count_nonzero(rising >= d_max)) if bottomed else 0
    n_loaded = len(u) - n_slack - n_bottomed
    force = k * np.maximum(0.0, u - uc - travel) + gauge_force_n - kg * travel
    not_fixed: dict[str, str] = {}

    if not 0.0 < s < 1.0:
        raise ShellFitError(f"the probe moved {s:.3f} mm per mm of cable wound: no spring between them does that "
                            "(the gauge is not on the probe, or the cable slips on the wheel)")
    stiffness = k / s - k - kg
    se_s = math.sqrt(max(float(cov[1, 1]), 0.0))
    s_low, s_high = s - t95 * se_s, s + t95 * se_s
    stiffness_interval = (k / s_high - k - kg if s_high < 1.0 else -math.inf,
                          k / s_low - k - kg if s_low > 0.0 else math.inf)
    if stiffness <= 0:
        raise ShellFitError(f"the probe moved {s:.3f} mm per mm of cable, more than the spring alone allows "
                            f"({k / (k + kg):.3f}): a negative shell stiffness; check the rig's spring_k_n_per_m and "
                            "the gauge's rate")
    half = 0.5 * (stiffness_interval[1] - stiffness_interval[0]) / stiffness
    if n_loaded < MIN_LOADED_STEPS:
        not_fixed["shell_stiffness_n_per_m"] = (f"only {n_loaded} steps between contact and bottoming out; at least "
                                                f"{MIN_LOADED_STEPS} (more --steps, or a lower --max-force)")
    elif not half <= FIXED_WITHIN:
        not_fixed["shell_stiffness_n_per_m"] = (f"its 95 % interval is ±{100 * half:.0f} %, wider than "
                                                f"±{100 * FIXED_WITHIN:.0f} %: the shell deflected "
                                                f"{float(travel.max()) * 1e3:.3f} mm, too little against the gauge's "
                                                f"{resolution_m * 1e3:g} mm digit")
    elif residual_rms > NONLINEAR_FACTOR * noise_floor:
        not_fixed["shell_stiffness_n_per_m"] = (
            f"the deflection is not a straight line in the winding: residual {residual_rms * 1e3:.4f} mm RMS, "
            f"{residual_rms / noise_floor:.0f}× what the gauge's digit explains; the shell stiffens or softens "
            "over the range (a lower --max-force keeps to its first part, or a linear shell does not describe it)")

    preload = gauge_force_n / stiffness
    if bottomed:
        se_d = math.sqrt(max(float(cov[3, 3]), 0.0))
        travel_m = d_max + preload
        travel_interval = (travel_m - t95 * se_d, travel_m + t95 * se_d)
        if not t95 * se_d <= FIXED_WITHIN * travel_m:
            not_fixed["shell_travel_m"] = (f"its 95 % interval is ±{100 * t95 * se_d / travel_m:.0f} %, wider "
                                           f"than ±{100 * FIXED_WITHIN:.0f} %")
    else:
        travel_m, travel_interval = math.nan, (math.nan, math.nan)
        not_fixed["shell_travel_m"] = (
            f"the shell never bottomed out: the probe went {float(travel.max()) * 1e3:.2f} mm in at "
            f"{float(force.max()):.2f} N, so its travel is more than {(float(travel.max()) + preload) * 1e3:.2f} mm "
            "(a higher --max-force reaches it, if the rig allows)")
    not_fixed["shell_damping_n_s_per_m"] = damping_reason or (
        "readings at rest see only the static deflection; the damping acts only while the probe moves")
    return ShellFit(stiffness_n_per_m=stiffness, stiffness_interval=stiffness_interval, travel_m=travel_m,
                    travel_interval=travel_interval, slope=s, contact_cable_m=uc, residual_rms_m=residual_rms,
                    noise_floor_m=noise_floor, n_slack=n_slack, n_loaded=n_loaded, n_bottomed=n_bottomed,
                    largest_travel_m=float(travel.max()), largest_force_n=float(force.max()), force_n=force,
                    travel_from_rest_m=travel, not_fixed=not_fixed)
