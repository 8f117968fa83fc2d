"""Profile of the SLS fit over the creep time τ = mu1/E1: for each τ on a log grid, the best (E0, E1) and the cost.

For a fixed τ the strain is *linear* in the two compliances: ``ε(t) = σ(t)/E0 + g_τ(t)/E1``, where ``g_τ`` is the
Kelvin–Voigt creep of the measured stress history with unit stiffness (``τ·ġ + g = σ``, the exact zero-order-hold
recursion of :mod:`models.sls`). With the strain taken from the measured conductance (Eq. 3 inverted at the
measured force) and each sample weighted by ``|dC/dε|/C_typical`` (the output-error fit's conductance-domain weight,
linearised), the best ``(1/E0, 1/E1)`` at each τ is a 2×2 weighted least-squares problem: the whole profile over a
few dozen τ values costs one batched creep recursion per trial and a handful of sums.

Why: the output-error fit (:mod:`models.fit_output`) is local. On a slow-creep sensor (τ ≫ the record, or τ of a few
thousand seconds with 1 % noise) every start that holds E0, E1 fixed while τ moves can sit on the τ → 0 plateau,
where the model is purely elastic and the cost is well above the optimum. The profile does not have that problem:
(E0, E1) follow τ. Its minimum (per trial and jointly for all trials) is a start in the right basin; the output-error
fit then refines all three parameters in the conductance domain.

The profile curve also gives an interval for τ that does not rely on linearisation (profile likelihood: the τ whose
best cost is within ``χ²₁(0.95)·s²`` of the minimum), honest when the record cannot pin τ down.

Pure numerics: any thread may call these; nothing is shared between calls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import special

from models.fit_output import FitTrial
from models.physics import PhysicsConstants, strain_from_conductance
from models.sls import SLSParams, strain_from_force

# Samples used for the strain profile: force at least this fraction of the hold force (below it the contact term
# dominates the reading and the inverted strain is mostly noise).
PROFILE_FORCE_FRACTION = 0.2
# Long records are thinned to about this many samples per trial for the profile (it only picks a start and an
# interval; the output-error fit sees every sample it is given).
PROFILE_MAX_SAMPLES = 4000


@dataclass(frozen=True)
class TauProfile:
    """The profile over ``taus`` (s). ``joint_cost[k]`` the weighted strain-domain cost of the best shared (E0, E1)
    at ``taus[k]``, ``joint_e0``/``joint_e1`` (Pa) those values (NaN where the best compliances are not both
    positive: ``joint_valid`` False); ``trial_*`` the same per trial, shape (T, K). ``n_used`` samples per trial."""

    taus: np.ndarray
    joint_cost: np.ndarray
    joint_e0: np.ndarray
    joint_e1: np.ndarray
    joint_valid: np.ndarray
    trial_cost: np.ndarray
    trial_e0: np.ndarray
    trial_e1: np.ndarray
    trial_valid: np.ndarray
    n_used: tuple[int, ...]

    def best_joint(self) -> SLSParams | None:
        """Parameters at the lowest valid joint cost (None when no τ gives positive E0 and E1)."""
        return _best(self.taus, self.joint_cost, self.joint_e0, self.joint_e1, self.joint_valid)

    def best_per_trial(self) -> list[SLSParams | None]:
        """Each trial's own profile minimum (None for a trial with no valid τ)."""
        return [_best(self.taus, self.trial_cost[i], self.trial_e0[i], self.trial_e1[i], self.trial_valid[i])
                for i in range(self.trial_cost.shape[0])]

    def joint_minima(self, count: int) -> list[SLSParams]:
        """Up to ``count`` valid local minima of the joint profile, lowest cost first (distinct basins)."""
        cost = np.where(self.joint_valid, self.joint_cost, np.inf)
        padded = np.concatenate([[np.inf], cost, [np.inf]])
        minima = [k for k in range(cost.size) if np.isfinite(cost[k])
                  and cost[k] <= padded[k] and cost[k] <= padded[k + 2]]
        minima.sort(key=lambda k: cost[k])
        return [SLSParams(float(self.joint_e0[k]), float(self.joint_e1[k]), float(self.joint_e1[k] * self.taus[k]))
                for k in minima[:count]]

    def tau_interval(self, n_params: int = 3) -> tuple[float, float]:
        """95 % profile-likelihood interval for τ (s) from the joint profile: every grid τ whose cost is within
        ``χ²₁(0.95)·s²`` of the minimum (s² = min cost / (n − n_params)). An end at the grid's edge is open: it is
        reported as 0 or inf (the records do not bound τ on that side)."""
        cost = np.where(np.isfinite(self.joint_cost), self.joint_cost, np.inf)
        best = float(np.min(cost))
        if not math.isfinite(best):
            return (0.0, math.inf)
        dof = max(sum(self.n_used) - n_params, 1)
        inside = np.flatnonzero(cost <= best + float(special.chdtri(1, 0.05)) * best / dof)
        lo, hi = int(inside[0]), int(inside[-1])
        return (0.0 if lo == 0 else float(self.taus[lo - 1]),
                math.inf if hi == self.taus.size - 1 else float(self.taus[hi + 1]))


def _best(taus, cost, e0, e1, valid) -> SLSParams | None:
    masked = np.where(valid, cost, np.inf)
    if not np.any(np.isfinite(masked)):
        return None
    k = int(np.argmin(masked))
    return SLSParams(float(e0[k]), float(e1[k]), float(e1[k] * taus[k]))


def _hold_last_valid(values: np.ndarray) -> np.ndarray:
    finite = np.isfinite(values)
    if finite.all():
        return np.asarray(values, dtype=np.float64)
    index = np.where(finite, np.arange(values.size), -1)
    np.maximum.accumulate(index, out=index)
    return np.where(index >= 0, values[np.maximum(index, 0)], 0.0)


def _gram(trial: FitTrial, area_m2: float, phys: PhysicsConstants, taus: np.ndarray,
          saturation_s: float | None) -> tuple[np.ndarray, int]:
    """Weighted sums for one trial, one row per τ: [Sσσ, Sσg, Sgg, Sσε, Sgε, Sεε] (K, 6), and the samples used."""
    t = np.asarray(trial.time_s, dtype=np.float64)
    force = _hold_last_valid(np.asarray(trial.force_n, dtype=np.float64))
    read = np.asarray(trial.conductance_s, dtype=np.float64)
    # The strain is that of the reading less its known offset (a drift); censoring is the reading's own.
    c = read if trial.offset_s is None else read - np.asarray(trial.offset_s, dtype=np.float64)
    stride = max(1, int(math.ceil(t.size / PROFILE_MAX_SAMPLES)))
    if stride > 1:
        # Thinned: the force is held over the coarser step (exact for the hold recursion on the thinned record).
        t, force, c, read = t[::stride], force[::stride], c[::stride], read[::stride]
    raw_force = np.asarray(trial.force_n, dtype=np.float64)[::stride]
    usable = (np.isfinite(c) & (c > 0) & np.isfinite(raw_force)
              & (raw_force >= PROFILE_FORCE_FRACTION * trial.hold_force_n))
    if saturation_s is not None:
        usable &= read < saturation_s * (1 - 1e-12)
    rows = np.flatnonzero(usable)
    empty = np.zeros((taus.size, 6))
    if rows.size < 5:
        return empty, 0
    result = strain_from_conductance(c[rows], force[rows], phys)
    ok = np.asarray(result.ok) & np.isfinite(result.strain)
    rows, strain = rows[ok], np.asarray(result.strain)[ok]
    if rows.size < 5:
        return empty, 0
    k = phys.tunnelling_k
    # |dC/dε| / C_typical: the conductance-domain weight of a strain residual (the output-error fit's weighting).
    dc_de = c[rows] ** 2 * phys.R0_ohm * np.exp(-k * strain) * (1 + k * (1 - strain))
    w2 = (dc_de / float(np.median(c[rows]))) ** 2
    extra_ss, extra_n = 0.0, 0
    if trial.counts is not None:  # an average of k raw samples counts as k of them (decimate_trial)
        counts = np.asarray(trial.counts, dtype=np.float64)[::stride][rows]
        w2 = w2 * counts
        if trial.within_ss is not None:
            # The read samples of a block at the ceiling averaged into one (decimate_trial): their spread about the
            # mean, a strain-domain cost of spread/C_typical² whatever τ, and their count, as the raw samples give.
            spread = np.asarray(trial.within_ss, dtype=np.float64)[::stride][rows]
            tracked = np.isfinite(spread)
            extra_ss = float(np.sum(spread[tracked])) / float(np.median(c[rows])) ** 2
            extra_n = int(round(float(np.sum(counts[tracked] - 1.0))))
    sigma_all = force / area_m2
    # g_τ for every τ at once: unit stiffnesses, so the recursion's strain is σ + g_τ.
    unit = SLSParams(np.ones(taus.size), np.ones(taus.size), taus.astype(np.float64))
    strain_unit = strain_from_force(t, np.repeat(force[:, None], taus.size, axis=1), unit, area_m2)
    g = strain_unit[rows] - sigma_all[rows, None]
    s = sigma_all[rows]
    ws = w2 * s
    return np.column_stack([
        np.full(taus.size, float(ws @ s)), ws @ g, np.einsum("n,nk,nk->k", w2, g, g),
        np.full(taus.size, float(ws @ strain)), (w2 * strain) @ g,
        np.full(taus.size, float((w2 * strain) @ strain) + extra_ss),
    ]), int(rows.size) + extra_n


def _solve(gram: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best non-negative (1/E0, 1/E1) per row of weighted sums (K, 6) → cost, E0, E1, valid (both positive)."""
    sss, ssg, sgg, sse, sge, see = gram.T
    with np.errstate(divide="ignore", invalid="ignore"):
        det = sss * sgg - ssg * ssg
        x0 = (sgg * sse - ssg * sge) / det
        x1 = (sss * sge - ssg * sse) / det
        # Nearly collinear columns (τ → 0: g → σ) lose the 2×2 solve to rounding: treat as not valid.
        well_posed = det > 1e-10 * sss * sgg
        valid = well_posed & (x0 > 0) & (x1 > 0)
        cost_full = see - 2 * (x0 * sse + x1 * sge) + x0 * x0 * sss + 2 * x0 * x1 * ssg + x1 * x1 * sgg
        # Boundaries of the positive quadrant: only σ/E0 (no creep) or only g/E1.
        cost_e0 = see - np.where(sss > 0, np.maximum(sse, 0) ** 2 / sss, 0.0)
        cost_e1 = see - np.where(sgg > 0, np.maximum(sge, 0) ** 2 / sgg, 0.0)
        cost = np.where(valid, cost_full, np.minimum(cost_e0, cost_e1))
        e0 = np.where(valid, 1.0 / x0, np.nan)
        e1 = np.where(valid, 1.0 / x1, np.nan)
    return np.maximum(cost, 0.0), e0, e1, valid


def profile_tau(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, taus: np.ndarray, *,
                saturation_s: float | None = None) -> TauProfile:
    """The profile over ``taus`` (s, increasing) for each trial and for all trials jointly (shared E0, E1): see the
    module docstring. Saturated samples (≥ ``saturation_s``) and samples below 20 % of the hold force are left out."""
    taus = np.asarray(taus, dtype=np.float64)
    grams, used = [], []
    for trial in trials:
        gram, n = _gram(trial, area_m2, phys, taus, saturation_s)
        grams.append(gram)
        used.append(n)
    per = [_solve(g) for g in grams]
    joint = _solve(np.sum(grams, axis=0))
    return TauProfile(taus, joint[0], joint[1], joint[2], joint[3],
                      np.array([p[0] for p in per]), np.array([p[1] for p in per]), np.array([p[2] for p in per]),
                      np.array([p[3] for p in per]), tuple(used))


def refined_tau_interval(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, profile: TauProfile,
                         *, saturation_s: float | None = None, points: int = 41) -> tuple[float, float]:
    """:meth:`TauProfile.tau_interval` on a finer grid: the coarse interval's span (each closed end) is profiled
    again at ``points`` values, so a well-pinned τ gets an interval a few percent wide instead of the coarse grid's
    ±1 step. An end the coarse profile left open stays open; a fine end at the fine grid's edge keeps the coarse end
    (conservative)."""
    lo, hi = profile.tau_interval()
    start = lo if lo > 0 else float(profile.taus[0])
    stop = hi if math.isfinite(hi) else float(profile.taus[-1])
    if not (0 < start < stop):
        return lo, hi
    fine = profile_tau(trials, area_m2, phys, np.geomspace(start, stop, points), saturation_s=saturation_s)
    fine_lo, fine_hi = fine.tau_interval()
    return (fine_lo if lo > 0 and fine_lo > 0 else lo,
            fine_hi if math.isfinite(hi) and math.isfinite(fine_hi) else hi)

