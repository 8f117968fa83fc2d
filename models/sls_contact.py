"""The per-step contact solve of the SLS inverse (part of :mod:`models.sls`, which re-exports it).

``C·(K/√F + R0·(1−ε)·e^(−kε)) = 1`` for the new force F, scalar and vectorised over sensors, for fixed parameters
and for E0 linear in force: safeguarded Newton in log F inside a bracket that always holds the root. Pure numerics,
any thread.
"""

from __future__ import annotations

import math

import numpy as np

from models.sls_model import ForceStatus

_NEWTON_MAX_ITER = 100  # per-step force solve: warm-started Newton needs ~3, the bisection fallback ≤ 60
_LOG_F_TOL = 1e-13
_FAST_NEWTON_ITER = 5  # warm-started Newton: typically 3 steps
_FAST_STEP_TOL = 1e-8  # a last step this small in log F leaves a quadratic error ~1e-16


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
