"""Calibrate one sensor from its trials: the linear model, the SLS model (joint and force-trend) and a per-trial
table, with uncertainties and warnings a user can act on.

Pipeline (NUMERICS pitfall 4's cure, with the paper's procedure kept alongside as a reference):

1. per trial: find the hold (its force is the mean applied force over it), refuse a flat or disconnected sensor,
   count saturated samples, fit Eq. 9 to the hold and run the paper's Eqs. 7–8 on it (reported, refused when
   rank-deficient or non-physical);
2. derivative-free estimate (integrated Eq. 5) per trial and for all trials → starting values;
3. output-error fit per trial (the table's E0/E1/mu1) and jointly for all trials (``sls``) and with parameters
   linear in force (``sls_trend``), in the conductance domain with Eq. 3 inside the residual;
4. the paper's linear model (Eq. 1) from the mean conductance over the window;
5. warnings: saturated samples, no loading ramp (E0 poorly identified), poor fit (rmse against the noise),
   non-physical paper results, single force level (no trend).

Pure numerics: any thread may call :func:`calibrate_sensor`; it takes arrays and returns a dataclass.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import special
from scipy.optimize import minimize_scalar

from models.creep_arms import SecondArm, check_second_arm
from models.errors import FlatSensorError
from models.fit_dfree import DerivativeFreeEstimate, estimate_sls
from models.fit_output import (
    DRIFT_BOUND_S_PER_S,
    NOISE_SMOOTH_SAMPLES,
    PARAM_NAMES,
    SETTLING_LOG_TAU_BOUNDS,
    FitTrial,
    OutputFit,
    baseline_offset,
    censored_noise,
    estimate_noise,
    fit_output_casadi,
    fit_output_scipy,
    noise_below_ceiling,
    trial_costs,
)
from models.fit_paper import ExponentialFit, PaperLSResult, fit_exponential, fit_paper_ls
from models.fit_profile import profile_tau, refined_tau_interval
from models.linear import DEFAULT_WINDOW_S, LinearFit, fit_linear_trials, trial_mean
from models.physics import PhysicsConstants, strain_from_conductance
from models.sls import TYPICAL_SLS, SLSParams, abc_from_sls, conductance_from_force

# The hold starts where the applied force first reaches this fraction of the trial's top force, and ends where it
# falls below the second fraction.
HOLD_FRACTION = 0.95
HOLD_END_FRACTION = 0.9
HOLD_END_SAMPLES = 3
# Samples below this fraction of the hold force are left out of the SLS fits (see models.fit_output).
MIN_FORCE_FRACTION = 0.05
MIN_TRIAL_SAMPLES = 10  # finite conductance samples a trial needs before it is judged at all
# Strain for the derivative-free estimate is taken where the force is at least this fraction of the hold force:
# below it the contact term dominates the reading and the inverted strain is mostly noise.
DFREE_FORCE_FRACTION = 0.2
# A trial whose smoothed conductance varies by less than this fraction of its level is flat (sensor not responding).
FLAT_RELATIVE_SPAN = 5e-3
FLAT_NOISE_MULTIPLE = 8.0
# A poor fit (docs/NUMERICS.md, "Poor fit"): the per-trial misfit is systematic — rmse above this multiple of the
# estimated conductance noise — AND it matters in force: its force equivalent (rmse / dC/dF of the fitted model at the
# trial's level) exceeds both POOR_FIT_FORCE_FRACTION of the trial's force (the accuracy a calibration is meant to
# deliver) and POOR_FIT_REFERENCE_MULTIPLE × the scatter of the applied-force reference over the hold (a model cannot
# fit the sensor better than the force it is given: a rig's reference moves by whole encoder ticks, 7.5 mN on the
# default rig).
POOR_FIT_NOISE_RATIO = 2.0
POOR_FIT_FORCE_FRACTION = 0.005
POOR_FIT_REFERENCE_MULTIPLE = 2.0
# dC/dF is taken from the fitted model run on the trial's force scaled by 1 ± this.
SENSITIVITY_STEP = 0.01
# E0's 95 % interval wider than this fraction of E0 is reported as poorly identified.
WIDE_INTERVAL = 0.5
# A trial with more than this fraction of its hold at the readout's ceiling is said to be (a warning): its own
# parameters rest on its loading ramp and the creep below the ceiling, the censored samples bounding the rest. Its
# intervals are reported where its own fit resolves τ and the likelihood rises as the intervals assume at both ends
# (interval_end_rises); refused, named, otherwise. Such trials were once refused outright; with the censored
# (Tobit) likelihood their linearised intervals held the truth 94–100 % per parameter on 99 such trials of 40 fresh
# ceiling sensors at 6 Hz and 36 trials at 100 Hz (benchmarks/bench_coverage.py, 2026-12-05), and the likelihood
# rose at least 0.92 t² at every end of their intervals (more on one side where most of the hold is censored: the
# interval is then wider than it need be there, docs/decisions/0015).
MAX_CENSORED_FRACTION = 0.5
# Multi-start over log τ: starting creep times from TAU_GRID_LOW × the sample step to TAU_GRID_HIGH × the record
# length, TAU_GRID_POINTS of them; the joint fit runs from the JOINT_STARTS best distinct ones and keeps the lowest
# cost (a slow-creep sensor otherwise stops on the τ → 0 plateau, whose cost is far above the optimum).
TAU_GRID_LOW, TAU_GRID_HIGH, TAU_GRID_POINTS = 3.0, 30.0, 9
JOINT_STARTS = 2
# Profile over log τ (models.fit_profile): from PROFILE_TAU_LOW × the sample step to TAU_RESOLVABLE_SPANS × the
# record length, PROFILE_TAU_POINTS values; (E0, E1) follow τ, so its minima are starts in the right basin even where
# the τ grid above (E0, E1 held) only sees the τ → 0 plateau; its curve gives τ's profile-likelihood interval.
PROFILE_TAU_LOW, PROFILE_TAU_POINTS = 0.5, 81
PROFILE_STARTS = 2
# The resolvable creep: τ between the sample step and this multiple of the record length.
TAU_RESOLVABLE_SPANS = 100.0


# The joint-fit solver: the fastest within 1 % of the best error (benchmarks/bench_pareto.py, fitting table). The
# CasADi Gauss–Newton fit (exact Jacobian from sensitivities carried through the mapaccum roll-out) and scipy's
# least_squares (batched finite differences) reach the same parameters (≤ 1e-8 relative), but scipy is faster on
# every row measured (4 trials × 370 s at 100 Hz: 0.14 vs 0.23 s CPU at 5 Hz, 0.64 vs 1.32 s at 30 Hz, 1.5 vs 3.1 s
# with every sample) and lighter (12 × 1 kHz trials fitted at 30 Hz: +84 MB vs +231 MB, 2.2 vs 4.6 s CPU): CasADi
# builds its graph per fit. So scipy is the default; CasADi stays selectable (--solver gauss-newton|ipopt|sqpmethod)
# and is the cross-check in tests.
DEFAULT_SOLVER = "scipy"


# Records sampled faster than this are block-averaged to it before fitting (sensnake fit --fit-rate; only where the
# force holds still and the readout is clear of its ceiling: decimate_trial): a 1 kHz trial of
# 370 s is 370 000 samples, which the output-error fit would run through its recursion ~100 times per start (minutes
# and ~0.45 GB per trial). Averaging k samples keeps their information about a slow creep (white noise shrinks by
# √k) at 1/k of the cost. The error it costs (benchmarks/bench_pareto.py, fitting table, worst parameter error
# against the truth at 0.2 % noise, 2026-11-28): every sample 0.011 %, 30 Hz 0.014 %, 10 Hz 0.011 %, 5 Hz 0.011 %;
# 5 Hz is the fastest within 1 % of the best error, the paper's own rate is 6 Hz.
DEFAULT_FIT_RATE_HZ = 5.0


# A block is averaged only where the force holds still: its mean differs from both neighbours' by at most this share of
# the trial's top force (a loading ramp moves ~0.5 N per 0.2 s block at the paper's 2 s ramp; a noisy reference's
# block means ~0.02 N).
STEADY_BLOCK_FRACTION = 0.02
NEAR_CEILING_SIGMAS = 5.0


def decimate_trial(trial: TrialInput, rate_hz: float, saturation_s: float | None = None) -> TrialInput:
    """``trial`` block-averaged to at most ``rate_hz`` (unchanged when it is not faster) where that loses nothing.
    Blocks of k consecutive samples (k from the median step) become one sample at their mean time, force and
    conductance (NaN samples left out; ``counts`` says how many samples each output stands for, and the fit weighs
    it by √count, so the averaged samples keep their information and their noise level is known). A block is kept
    sample by sample where averaging would bias the fit: while the force moves (a loading ramp: the mean of a
    nonlinear response is not the response to the mean force, and the hold between samples no longer matches a
    force that moved within the step). Measured (benchmarks/bench_coverage.py --rate 30): averaging every block put
    the 95 % intervals of 30 Hz trials at 35 % coverage (0.2 % noise); this keeps them at ~95 %.

    Where the readout reaches its ceiling ``saturation_s`` (a sample at it, or the block's mean within
    :data:`NEAR_CEILING_SIGMAS` noise s.d. of it) a steady block becomes two samples: the mean of its samples read
    as numbers (with ``within_ss``, their squared deviations about that mean) and one censored sample standing for
    those at the ceiling. Over a block in which the model hardly moves, that pair carries the block's whole censored
    likelihood (the Gaussian part depends on the read samples only through their count and mean, the censored part
    only through the count), so nothing is selected by the noise — a plain mean of a block that happened to stay
    below the ceiling would be biased low — and a 1 kHz trial at the ceiling is fitted from ~10 samples a second
    instead of 1000 (it took 27–115 s of CPU per sensor). ``noise_s`` then carries the raw samples' noise (the
    censored likelihood's σ), measured before averaging."""
    t = np.asarray(trial.time_s, dtype=np.float64)
    if not rate_hz > 0 or t.size < 4:
        return trial
    step = float(np.median(np.diff(t)))
    k = int(math.floor(1.0 / (rate_hz * step) + 1e-6)) if step > 0 else 1
    if k < 2:
        return trial
    force = np.asarray(trial.force_n, dtype=np.float64)
    c = np.asarray(trial.conductance_s, dtype=np.float64)
    counts_in = np.ones(t.size) if trial.counts is None else np.asarray(trial.counts, dtype=np.float64)
    # Blocks of k samples; the tail (< k samples) is a block of its own.
    block_of = np.arange(t.size) // k
    n_blocks = int(block_of[-1]) + 1

    def means(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
        finite = np.isfinite(values)
        w = np.where(finite, weights, 0.0)
        total = np.bincount(block_of, w, n_blocks)
        sums = np.bincount(block_of, np.where(finite, values, 0.0) * w, n_blocks)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(total > 0, sums / total, math.nan)

    block_force = means(force, counts_in)
    block_c = means(c, counts_in)
    block_t = means(t, np.ones(t.size))
    block_counts = np.bincount(block_of, np.where(np.isfinite(c), counts_in, 0.0), n_blocks)
    top = float(np.nanmax(np.abs(force))) if np.isfinite(force).any() else 0.0
    change = np.abs(np.diff(block_force))
    change = np.where(np.isfinite(change), change, np.inf)
    tolerance = STEADY_BLOCK_FRACTION * top
    steady = np.isfinite(block_force)
    if n_blocks > 1:
        steady[:-1] &= change <= tolerance
        steady[1:] &= change <= tolerance
    split = np.zeros(n_blocks, dtype=bool)
    noise_s = trial.noise_s
    censored = np.zeros(t.size, dtype=bool)
    if saturation_s is not None:
        ceiling = saturation_s * (1 - 1e-12)
        censored = c >= ceiling
        near = np.bincount(block_of, censored.astype(np.float64), n_blocks) > 0
        if near.any():
            noise = (raw_noise_below_ceiling(c, force, saturation_s) if trial.counts is None
                     else noise_below_ceiling(c, trial.counts, saturation_s))
            if math.isfinite(noise):
                near |= block_c >= ceiling - NEAR_CEILING_SIGMAS * noise
                if noise_s is None and trial.counts is None:
                    noise_s = noise
        if trial.counts is None and noise_s is not None:
            split = steady & near  # each becomes (the read samples' mean, the censored samples' count)
        steady &= ~near
    keep_raw = ~(steady | split)[block_of]
    parts_t = [block_t[steady], t[keep_raw]]
    parts_f = [block_force[steady], force[keep_raw]]
    parts_c = [block_c[steady], c[keep_raw]]
    parts_n = [np.maximum(block_counts, 1.0)[steady], counts_in[keep_raw]]
    parts_w = [np.full(int(steady.sum()), math.nan), np.full(int(keep_raw.sum()), math.nan)]
    if split.any():
        in_split = split[block_of] & np.isfinite(c)
        for is_censored, group in ((False, in_split & ~censored), (True, in_split & censored)):
            n = np.bincount(block_of, group.astype(np.float64), n_blocks)
            present = split & (n > 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                mean_t, mean_c = (np.bincount(block_of, np.where(group, v, 0.0), n_blocks) / n for v in (t, c))
            parts_t.append(mean_t[present])
            parts_f.append(block_force[present])  # the force holds still over the block: its mean for both parts
            parts_c.append(mean_c[present])
            parts_n.append(n[present])
            if not is_censored:
                deviation = np.where(group, c - mean_c[block_of], 0.0)
                within = np.bincount(block_of, deviation * deviation, n_blocks)
                parts_w.append(within[present])
            else:
                parts_w.append(np.full(int(present.sum()), math.nan))
    order = np.concatenate(parts_t)
    sort = np.argsort(order, kind="stable")
    times = order[sort]
    # The two parts of a block can share a mean time: kept apart by a millionth of a step (time stays increasing).
    tied = np.flatnonzero(np.diff(times) <= 0)
    times[tied + 1] = times[tied] + 1e-6 * step
    within_ss = np.concatenate(parts_w)[sort]
    return TrialInput(trial.name, times, np.concatenate(parts_f)[sort], np.concatenate(parts_c)[sort],
                      counts=np.concatenate(parts_n)[sort],
                      within_ss=within_ss if np.isfinite(within_ss).any() else trial.within_ss,
                      noise_s=noise_s)


def raw_noise_below_ceiling(conductance_s: np.ndarray, force_n: np.ndarray, ceiling_s: float) -> float:
    """The noise (S) of a raw record (one reading per sample) that reaches the readout's ceiling, for the censored
    likelihood: from second differences of three consecutive loaded samples (force ≥ :data:`MIN_FORCE_FRACTION` of
    the record's top: unloaded readings sit at 0 S, clipped, and scatter too little) whose running mean over
    :data:`models.fit_output.NOISE_SMOOTH_SAMPLES` lies more than 6 s.d. below the ceiling (there the censoring has
    not touched them; picked by their own values, those close under it scatter too little). Measured on trials 80 %
    at the ceiling at 1 % noise: 6.5–7.4 µS for a true 11.3 µS when the unloaded start and the gaps between samples
    far from the ceiling were counted; the censored fit then read a false drift and E1 several standard errors off.
    NaN when fewer than 20 such triples remain."""
    c = np.asarray(conductance_s, dtype=np.float64)
    force = np.asarray(force_n, dtype=np.float64)
    finite = np.isfinite(c) & np.isfinite(force)
    if not finite.any():
        return math.nan
    top = float(np.percentile(force[finite], 99))
    usable = finite & (force >= MIN_FORCE_FRACTION * top) & (c < ceiling_s * (1 - 1e-12))

    def from_triples(keep: np.ndarray) -> float:
        triple = keep[:-2] & keep[1:-1] & keep[2:]
        d2 = (c[:-2] - 2 * c[1:-1] + c[2:])[triple]
        if d2.size < 20:
            return math.nan
        return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))

    sigma = from_triples(usable)  # a first scale: too small where the samples crowd under the ceiling
    if not sigma > 0:
        return sigma
    window = NOISE_SMOOTH_SAMPLES
    kernel = np.ones(window)
    total = np.convolve(np.where(finite, c, 0.0), kernel, mode="same")
    count = np.convolve(finite.astype(np.float64), kernel, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = total / count
    for _ in range(2):  # the margin from the first scale, then from the scale it gives
        far = from_triples(usable & (smooth < ceiling_s - 6.0 * sigma))
        if not far > 0:
            break
        sigma = far
    return sigma


@dataclass(frozen=True)
class TrialInput:
    """One calibration trial: its name (file), time (s), applied force (N), measured conductance (S)."""

    name: str
    time_s: np.ndarray
    force_n: np.ndarray
    conductance_s: np.ndarray
    counts: np.ndarray | None = None  # raw samples each sample stands for (decimate_trial); None: one each
    # Per sample, Σ(reading − mean)² (S²) of the raw samples it averages, where decimate_trial averaged only the read
    # samples of a block at the readout's ceiling (NaN elsewhere): they count as the raw samples they were in the
    # residual variance. None: no such sample.
    within_ss: np.ndarray | None = None
    noise_s: float | None = None  # the raw samples' noise (S), measured before averaging (None: not measured)


@dataclass(frozen=True)
class TrialReport:
    """One row of the per-trial table. ``params`` from this trial's own output-error fit; ``exp_fit`` is Eq. 9 on
    the hold; ``paper`` the Eqs. 7–8 regression (refused with a reason when ill-posed); ``noise_s`` the estimated
    conductance noise (S); ``rmse_s`` of the per-trial fit (S)."""

    name: str
    force_n: float
    hold_start_s: float
    hold_end_s: float
    exp_fit: ExponentialFit
    paper: PaperLSResult
    dfree: DerivativeFreeEstimate | None
    params: SLSParams
    ci95: dict[str, tuple[float, float]]
    rmse_s: float
    noise_s: float
    n_saturated: int
    has_ramp: bool
    warnings: tuple[str, ...]
    refused: str | None = None  # why this trial's own parameters are not reported (None: they are)
    misfit_force_n: float = math.nan  # the hold's misfit as a force (N): its rmse / dC/dF of this trial's fit there

    def to_dict(self) -> dict:
        """The SPEC §3.3 ``trials`` entry (plus extra keys that ``estimate`` ignores). A refused trial writes null
        parameters and its reason under ``refused``."""
        a, b, c = abc_from_sls(float(self.params.E0_Pa), float(self.params.E1_Pa), float(self.params.mu1_Pa_s))
        values: dict[str, float | None] = {
            "E0_Pa": float(self.params.E0_Pa), "E1_Pa": float(self.params.E1_Pa),
            "mu1_Pa_s": float(self.params.mu1_Pa_s), "a_s": a, "b_Pa": b, "c_Pa_s": c}
        if self.refused is not None:
            values = dict.fromkeys(values)
        return {
            "file": self.name, "force_N": self.force_n,
            "c1": self.exp_fit.c1, "c2": self.exp_fit.c2, "c3": self.exp_fit.c3,
            **values, "refused": self.refused,
            "rmse_S": self.rmse_s, "misfit_force_N": _or_none(self.misfit_force_n), "warnings": list(self.warnings),
            "ci95": {k: list(v) for k, v in self.ci95.items()},
            "hold_s": [self.hold_start_s, self.hold_end_s], "noise_S": self.noise_s,
            "saturated_samples": self.n_saturated,
            "exp_fit_t0_s": self.exp_fit.t0_s,
            "paper_ls": {"ok": self.paper.ok, "E0_Pa": _or_none(self.paper.E0_Pa),
                         "E1_Pa": _or_none(self.paper.E1_Pa), "mu1_Pa_s": _or_none(self.paper.mu1_Pa_s),
                         "condition_number": _or_none(self.paper.condition_number),
                         "warnings": list(self.paper.warnings)},
        }


@dataclass(frozen=True)
class SensorCalibration:
    """Everything ``sensnake fit`` writes for one sensor (SPEC §3.3) and what the GUI shows."""

    area_m2: float
    linear: LinearFit | None  # None when the trials cannot support it (one force level)
    sls: SLSParams
    sls_ci95: dict[str, tuple[float, float]]
    sls_trend: dict[str, tuple[float, float]] | None
    trend_ci95: dict[str, tuple[float, float]]
    trials: tuple[TrialReport, ...]
    force_range_n: tuple[float, float]
    rmse_s: float
    solver: str
    warnings: tuple[str, ...] = field(default_factory=tuple)
    # At a search bound, unidentifiable (singular Jacobian), not converged, or τ outside what the records resolve:
    # ``sls`` is then not to be trusted; ``estimate`` refuses it unless --allow-degenerate.
    degenerate_reasons: tuple[str, ...] = field(default_factory=tuple)
    # 95 % profile-likelihood interval of the creep time τ = mu1/E1 (s) from models.fit_profile (no linearisation;
    # an end the records do not bound is 0 or inf).
    tau_ci95: tuple[float, float] = (0.0, math.inf)
    # A baseline drift found and separated from the creep (S/s; :func:`calibrate_with_drift`): 0.0 when looked for
    # and not found, None when not looked for. The parameters are those of the trials with it removed.
    drift_s_per_s: float | None = None
    # The baseline settles instead of drifting (calibrate_with_drift): its time constant (s); the baseline is then
    # drift_s_per_s·τb·(1 − e^(−t/τb)) (models.fit_output.baseline_offset). inf: a linear drift (or none).
    drift_tau_s: float = math.inf
    # Trials whose reading jumps within the hold (reading_step): the SLS model cannot describe them.
    steps: tuple[ReadingStep, ...] = ()
    # The two-arm creep check (models.creep_arms; run by calibrate_with_drift): None when not run, or when it could
    # not be made (then ``second_arm_note`` says why, and the file says so).
    second_arm: SecondArm | None = None
    second_arm_note: str | None = None

    @property
    def degenerate(self) -> bool:
        """True when the joint SLS fit must not be used as if it were good (see ``degenerate_reasons``)."""
        return bool(self.degenerate_reasons)

    def to_dict(self) -> dict:
        """The sensor's SPEC §3.3 entry (``area_m2``, ``linear``, ``sls``, ``sls_trend``, ``trials``) plus extras
        (``degenerate``, ``degenerate_reasons``, ``sls_ci95``, ``warnings``, …)."""
        entry: dict = {"area_m2": self.area_m2}
        if self.linear is not None:
            entry["linear"] = self.linear.model.to_dict()
            entry["linear_r2"] = _or_none(self.linear.r_squared)
            if self.linear.baseline_s is not None:
                entry["linear_baseline_S"] = [_or_none(float(b)) for b in self.linear.baseline_s]
        entry["sls"] = self.sls.to_dict()
        if self.sls_trend is not None:
            entry["sls_trend"] = {k: list(v) for k, v in self.sls_trend.items()}
        entry["trials"] = [t.to_dict() for t in self.trials]
        entry["sls_ci95"] = {k: list(v) for k, v in self.sls_ci95.items()}
        if self.trend_ci95:
            entry["sls_trend_ci95"] = {k: list(v) for k, v in self.trend_ci95.items()}
        entry["force_range_N"] = list(self.force_range_n)
        entry["rmse_S"] = self.rmse_s
        entry["solver"] = self.solver
        entry["warnings"] = list(self.warnings)
        entry["degenerate"] = self.degenerate
        entry["degenerate_reasons"] = list(self.degenerate_reasons)
        entry["tau_s_ci95"] = [_or_none(self.tau_ci95[0]), _or_none(self.tau_ci95[1])]  # null: not bounded
        if self.drift_s_per_s is not None:
            entry["drift_S_per_s"] = self.drift_s_per_s
        if math.isfinite(self.drift_tau_s):
            entry["drift_settling_tau_s"] = self.drift_tau_s
        if self.steps:
            entry["reading_steps"] = [step.to_dict() for step in self.steps]
        if self.second_arm is not None:
            entry["creep_second_arm"] = self.second_arm.to_dict()
        elif self.second_arm_note is not None:
            entry["creep_second_arm"] = {"resolved": None, "checked": False, "reason": self.second_arm_note}
        return entry


# The censored likelihood's σ of a trial at the ceiling is re-estimated from the trial's own fit until it moves by
# less than this share (at most CENSORED_NOISE_ROUNDS fits; each round closes ~2/3 of the gap).
CENSORED_NOISE_TOLERANCE = 2e-3
CENSORED_NOISE_ROUNDS = 6


def _censored_noise_refined(fit_trials: list[FitTrial], per_trial: OutputFit, area_m2: float,
                            phys: PhysicsConstants, saturation_s: float) -> tuple[list[FitTrial], OutputFit]:
    """The trials that reach the readout's ceiling with the σ of their censored likelihood
    (:func:`models.fit_output.censored_noise`) estimated from their own fit, and the per-trial fit redone with it.
    The σ and the fit depend on each other: alternated until σ settles. A σ 3 % off moved E1 by ~1 standard error at
    100 Hz; one from differences of the samples far below the ceiling was 5–20 % off on trials 80 % at it."""
    at_ceiling = [i for i, t in enumerate(fit_trials)
                  if np.any(np.asarray(t.conductance_s) >= saturation_s * (1 - 1e-12))]
    if not at_ceiling:
        return fit_trials, per_trial
    trials = list(fit_trials)
    params = list(_present(per_trial.params))

    def first_sigma(trial: FitTrial) -> float:
        """The σ the trial's fit ran with (the one models.fit_output picks when none is given)."""
        if trial.noise_s is not None:
            return trial.noise_s
        loaded = np.asarray(trial.force_n) >= MIN_FORCE_FRACTION * trial.hold_force_n
        counts = None if trial.counts is None else np.asarray(trial.counts)[loaded]
        return noise_below_ceiling(np.asarray(trial.conductance_s)[loaded], counts, saturation_s)

    sigma = {i: first_sigma(trials[i]) for i in at_ceiling}
    sigma = {i: value for i, value in sigma.items() if math.isfinite(value) and value > 0}
    changed = False
    for _ in range(CENSORED_NOISE_ROUNDS):
        moved = []
        for i in sigma:
            new = censored_noise(trials[i], params[i], area_m2, phys, saturation_s, sigma[i], MIN_FORCE_FRACTION)
            if abs(new / sigma[i] - 1) > CENSORED_NOISE_TOLERANCE:
                moved.append(i)
            sigma[i] = new
            trials[i] = replace(trials[i], noise_s=new)
        if not moved:
            break
        changed = True
        refit = fit_output_scipy([trials[i] for i in moved], area_m2, phys, [params[i] for i in moved], "per_trial",
                                 saturation_s=saturation_s, min_force_fraction=MIN_FORCE_FRACTION)
        for i, fitted in zip(moved, _present(refit.params)):
            params[i] = fitted
    if changed:
        per_trial = fit_output_scipy(trials, area_m2, phys, params, "per_trial", saturation_s=saturation_s,
                                     min_force_fraction=MIN_FORCE_FRACTION)
    return trials, per_trial


def _present(params: Sequence[SLSParams | None]) -> list[SLSParams]:
    """Per-trial fits always carry parameters; this states it for the type checker (and fails loudly if not)."""
    out = [p for p in params if p is not None]
    if len(out) != len(params):
        raise RuntimeError("a per-trial fit returned no parameters")
    return out


def _or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def hold_segment(force_n: np.ndarray) -> tuple[slice, float]:
    """The hold (a slice of samples) and its force (N, the mean applied force over it).

    The hold starts at the first sample at :data:`HOLD_FRACTION` of the top force (its 99th percentile, robust to
    spikes) and ends where the force stays below :data:`HOLD_END_FRACTION` of it for :data:`HOLD_END_SAMPLES`
    samples (unloading at the end of a record, a slipping probe), or at the end of the record. NaN force samples do
    not end it.
    """
    finite = force_n[np.isfinite(force_n)]
    if finite.size == 0:
        raise ValueError("the force column has no finite sample")
    top = float(np.percentile(finite, 99))
    if not top > 0:
        raise ValueError(f"the applied force never rises above zero (top {top:g} N): was the rig loading?")
    reached = np.flatnonzero(np.nan_to_num(force_n, nan=-np.inf) >= HOLD_FRACTION * top)
    start = int(reached[0])
    below = (np.nan_to_num(force_n[start:], nan=np.inf) < HOLD_END_FRACTION * top).astype(int)
    # The force must stay low for HOLD_END_SAMPLES samples: a single glitch in the force reading does not end it.
    run = np.convolve(below, np.ones(HOLD_END_SAMPLES, dtype=int), mode="valid")
    dropped = np.flatnonzero(run == HOLD_END_SAMPLES)
    stop = start + int(dropped[0]) if dropped.size else force_n.size
    hold = force_n[start:stop]
    return slice(start, stop), float(np.nanmean(hold[hold >= HOLD_END_FRACTION * top]))  # glitches left out


def _hold_noise(conductance_s: np.ndarray, saturation_s: float | None, counts: np.ndarray | None = None) -> float:
    """The raw samples' noise (S) from the hold's unsaturated samples (``counts``: raw samples each one averages,
    see :func:`decimate_trial`); NaN when fewer than 20 remain (no poor-fit verdict then)."""
    if saturation_s is not None:
        keep = conductance_s < saturation_s * (1 - 1e-12)
        conductance_s = conductance_s[keep]
        counts = None if counts is None else counts[keep]
    return estimate_noise(conductance_s, counts) if conductance_s.size >= 20 else math.nan


def _check_not_flat(trial: TrialInput) -> None:
    """Refuse a trial whose conductance does not respond: its smoothed span must exceed both
    :data:`FLAT_RELATIVE_SPAN` of its level and :data:`FLAT_NOISE_MULTIPLE` × the noise left after smoothing (a
    flat-lined but noisy channel must not pass for a working one)."""
    c = trial.conductance_s[np.isfinite(trial.conductance_s)]
    if c.size < MIN_TRIAL_SAMPLES:  # too few to smooth: a span of 0 would call a rising reading "flat"
        raise ValueError(f"{trial.name}: {c.size} conductance sample(s): too few to fit (at least "
                         f"{MIN_TRIAL_SAMPLES}: a baseline, the loading and a hold)")
    if not (c.size and float(np.max(np.abs(c))) > 1e-12):
        raise FlatSensorError(f"{trial.name}: conductance is zero throughout: the sensor is disconnected (check its "
                              "wiring and board channel); fit refused")
    window = max(3, c.size // 50)
    smooth = np.convolve(c, np.ones(window) / window, mode="valid")
    level = float(np.max(np.abs(smooth)))
    noise = estimate_noise(c)
    smooth_noise = noise / math.sqrt(window) if math.isfinite(noise) else 0.0
    span = float(np.ptp(smooth))
    if span < max(FLAT_RELATIVE_SPAN * level, FLAT_NOISE_MULTIPLE * smooth_noise):
        force = trial.force_n[np.isfinite(trial.force_n)]
        if force.size and float(np.ptp(force)) < 0.1 * float(np.max(np.abs(force))):
            raise FlatSensorError(
                f"{trial.name}: the force is constant throughout the record ({float(np.median(force)):.3g} N, no "
                f"loading ramp) and the conductance does not change ({span:.3g} S span at {level:.3g} S): no creep "
                "is visible, so τ → 0 or τ → ∞ (purely elastic over this record) cannot be told apart from a stuck "
                "channel; record the loading ramp and a longer hold; fit refused")
        raise FlatSensorError(
            f"{trial.name}: conductance is flat ({span:.3g} S span at {level:.3g} S, noise {noise:.3g} S) while the "
            f"force goes to {np.nanmax(trial.force_n):.3g} N: the sensor is not responding (flat-lined, loose or "
            "not under the probe); fit refused")


def hold_misfit(trial: TrialInput, hold: slice, params: SLSParams, area_m2: float, phys: PhysicsConstants,
                saturation_s: float | None) -> tuple[float, float]:
    """The fitted model's misfit over the hold and its sensitivity there: (rmse (S) of measured − model over the
    hold's unsaturated samples, at the raw samples' level (an average of k weighs k), dC/dF (S/N) at the trial's
    level — the model run on the trial's own force record scaled by 1 ± :data:`SENSITIVITY_STEP`, the hold's median
    conductance change over the force change). NaN where the model cannot be run (a strain ≥ 1 is clamped) or no
    sample is left.

    Over the hold only: during the ramp the conductance changes by tens of µS per sample, so a force reference read a
    fraction of a sample early or late (a busy rig thread) leaves residuals there that say nothing about the creep
    model; the hold, at constant force, is where the model's creep is judged."""
    force = np.nan_to_num(np.asarray(trial.force_n, dtype=np.float64), nan=0.0)
    step = SENSITIVITY_STEP
    try:
        model, up, down = (np.asarray(conductance_from_force(trial.time_s, force * scale, params, area_m2, phys,
                                                             overstrain="clamp"), dtype=np.float64)[hold]
                           for scale in (1.0, 1 + step, 1 - step))
    except ValueError:
        return math.nan, math.nan
    measured = np.asarray(trial.conductance_s, dtype=np.float64)[hold]
    used = np.isfinite(measured) & np.isfinite(model)
    if saturation_s is not None:
        used &= measured < saturation_s * (1 - 1e-12)
    # An average of k raw samples counts as k of them (decimate_trial): the rmse is then the raw samples', as the
    # noise it is judged against.
    counts = np.ones(measured.size) if trial.counts is None else np.asarray(trial.counts, dtype=np.float64)[hold]
    # A sample averaging the read samples of a block at the ceiling adds their spread about its mean (decimate_trial):
    # the rmse is the one those raw samples give.
    spread = (np.zeros(measured.size) if trial.within_ss is None
              else np.nan_to_num(np.asarray(trial.within_ss, dtype=np.float64)[hold], nan=0.0))
    rmse = (float(np.sqrt(np.sum(counts[used] * np.square(measured[used] - model[used]) + spread[used])
                          / np.sum(counts[used]))) if used.any() else math.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = (up - down) / (2 * step * force[hold])
    ratio = ratio[np.isfinite(ratio)]
    return rmse, (float(np.median(ratio)) if ratio.size else math.nan)


# A step in the reading (reading_step): the hold's residual (the trial's own fit) is fitted by a line on each side of
# every instant, over STEP_WINDOW_S each; a jump between the two lines of more than STEP_SIGMAS standard errors (the
# residual's own sample-to-sample scatter: a noisy force reference adds to it) that also matters in force (as a poor
# fit: above 0.5 % of the trial's force and 2 × the reference's scatter) is a step. Measured on rig-like trials the
# thresholds were not tuned on (tests/models/test_baseline_shapes.py): good fits, a sensor that relaxes and a 1 µS/s
# drift reach 2.4–6.5 standard errors, a 4 % step or a 5 % probe slip 15–290.
STEP_WINDOW_S = 10.0
STEP_SIGMAS = 8.0


@dataclass(frozen=True)
class ReadingStep:
    """A jump of a trial's reading within its hold that the SLS model (driven by the measured force) does not make:
    at ``time_s`` (s from the trial's start), ``size_s`` (S), ``force_n`` its force equivalent (N, through the
    trial's dC/dF; NaN without one), ``sigmas`` its size in standard errors."""

    trial: str
    time_s: float
    size_s: float
    force_n: float
    sigmas: float

    def describe(self) -> str:
        force = f" ({self.force_n * 1e3:+.3g} mN)" if math.isfinite(self.force_n) else ""
        return (f"the reading jumps by {self.size_s * 1e6:+.3g} µS{force} at {self.time_s:.0f} s while the force "
                f"holds ({self.sigmas:.0f} standard errors)")

    def to_dict(self) -> dict[str, float | str | None]:
        return {"trial": self.trial, "time_s": self.time_s, "size_S": self.size_s,
                "force_N": _or_none(self.force_n), "standard_errors": self.sigmas}


def reading_step(trial: TrialInput, hold: slice, params: SLSParams, area_m2: float, phys: PhysicsConstants,
                 saturation_s: float | None, noise_s: float, sensitivity_s_per_n: float, force_n: float,
                 reference_n: float) -> ReadingStep | None:
    """The largest step in ``trial``'s reading over its hold that the fitted model ``params`` does not make, or None
    when no jump passes both :data:`STEP_SIGMAS` and the force tolerance (see :data:`STEP_WINDOW_S`). A creep, a
    drift, a settling baseline or a sensor that relaxes bend the residual smoothly: the lines follow them. Samples at
    or near the readout's ceiling are left out (their read values are biased low by the censoring)."""
    t = np.asarray(trial.time_s, dtype=np.float64)[hold]
    measured = np.asarray(trial.conductance_s, dtype=np.float64)[hold]
    force = np.nan_to_num(np.asarray(trial.force_n, dtype=np.float64), nan=0.0)
    try:
        model = np.asarray(conductance_from_force(trial.time_s, force, params, area_m2, phys, overstrain="clamp"),
                           dtype=np.float64)[hold]
    except ValueError:
        return None
    counts = np.ones(t.size) if trial.counts is None else np.asarray(trial.counts, dtype=np.float64)[hold]
    used = np.isfinite(measured) & np.isfinite(model)
    if saturation_s is not None:
        margin = NEAR_CEILING_SIGMAS * noise_s if math.isfinite(noise_s) else 0.0
        used &= (measured < saturation_s * (1 - 1e-12)) & (model < saturation_s - margin)
        if trial.within_ss is not None:
            used &= ~np.isfinite(np.asarray(trial.within_ss, dtype=np.float64)[hold])
    t, r, n = t[used], (measured - model)[used], counts[used]
    if t.size < 20:
        return None
    # The residual's own scatter per raw sample, from its first differences (robust): what a jump is judged against.
    d = np.diff(r) / np.sqrt(1.0 / n[:-1] + 1.0 / n[1:])
    scatter = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    if not scatter > 0:
        return None
    sums = [np.concatenate([[0.0], np.cumsum(v)]) for v in (n, n * t, n * t * t, n * r, n * t * r)]
    split = np.arange(1, t.size)
    at = 0.5 * (t[split - 1] + t[split])
    lo, hi = np.searchsorted(t, at - STEP_WINDOW_S), np.searchsorted(t, at + STEP_WINDOW_S)

    def line(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The weighted line over samples [a, b) at ``at`` and its variance per unit raw-sample variance."""
        s0, s1, s2, sy, sty = (c[b] - c[a] for c in sums)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_t = s1 / s0
            sxx = s2 - s1 * mean_t
            slope = (sty - mean_t * sy) / sxx
            return sy / s0 + slope * (at - mean_t), 1.0 / s0 + (at - mean_t) ** 2 / sxx

    before, var_before = line(lo, split)
    after, var_after = line(split, hi)
    jump = after - before
    with np.errstate(invalid="ignore", divide="ignore"):
        sigmas = np.abs(jump) / (scatter * np.sqrt(var_before + var_after))
    inside = (at - STEP_WINDOW_S >= t[0]) & (at + STEP_WINDOW_S <= t[-1]) & (split - lo >= 5) & (hi - split >= 5)
    sigmas = np.where(inside & np.isfinite(sigmas), sigmas, 0.0)
    k = int(np.argmax(sigmas))
    if not sigmas[k] > STEP_SIGMAS:
        return None
    size = float(jump[k])
    step_n = size / sensitivity_s_per_n if sensitivity_s_per_n > 0 else math.nan
    tolerance = max(POOR_FIT_FORCE_FRACTION * force_n, POOR_FIT_REFERENCE_MULTIPLE * reference_n)
    if math.isfinite(step_n) and abs(step_n) <= tolerance:
        return None
    return ReadingStep(trial.name, float(at[k] - trial.time_s[0]), size, step_n, float(sigmas[k]))


def reference_scatter(force_n: np.ndarray) -> float:
    """Scatter (N, s.d.) of the applied-force reference over a hold, from first differences (a slow trend does not
    count): a rig's reference moving between encoder ticks gives ~0.8 tick; a perfect reference 0."""
    f = np.asarray(force_n, dtype=np.float64)
    d = np.diff(f[np.isfinite(f)])
    return float(math.sqrt(np.mean(np.square(d)) / 2.0)) if d.size else 0.0


def poor_fit_verdict(rmse_s: float, noise_s: float, misfit_n: float, force_n: float, reference_n: float) -> str:
    """Why a trial's fit is poor ("" when it is not): the misfit is systematic (rmse > :data:`POOR_FIT_NOISE_RATIO` ×
    the noise) and its force equivalent ``misfit_n`` exceeds both :data:`POOR_FIT_FORCE_FRACTION` of the trial force
    and :data:`POOR_FIT_REFERENCE_MULTIPLE` × the reference's scatter. Without a usable sensitivity (``misfit_n``
    NaN: the fitted model does not rise with force) the noise ratio alone decides. No verdict without a noise
    estimate (NaN: too few unsaturated samples)."""
    if not (math.isfinite(noise_s) and rmse_s > POOR_FIT_NOISE_RATIO * noise_s and rmse_s > 0):
        return ""
    ratio = f"{rmse_s / noise_s:.1f}× the noise ({noise_s * 1e6:.3g} µS)" if noise_s > 0 else "above a zero noise"
    if not math.isfinite(misfit_n):
        return f"the hold's rmse {rmse_s * 1e6:.3g} µS is {ratio} and the fitted model does not rise with force"
    tolerance = max(POOR_FIT_FORCE_FRACTION * force_n, POOR_FIT_REFERENCE_MULTIPLE * reference_n)
    if misfit_n <= tolerance:
        return ""
    return (f"the hold's rmse {rmse_s * 1e6:.3g} µS ({ratio}) is {misfit_n * 1e3:.3g} mN of force, "
            f"{100 * misfit_n / force_n:.2g} % of the trial's {force_n:.3g} N (tolerated: {tolerance * 1e3:.3g} mN)")


def _strain(trial: TrialInput, phys: PhysicsConstants, rows: np.ndarray) -> np.ndarray:
    result = strain_from_conductance(trial.conductance_s[rows], trial.force_n[rows], phys)
    strain = np.where(result.ok, result.strain, np.nan)
    return strain


def paper_procedure(trial: TrialInput, hold: slice, force_n: float, area_m2: float,
                    phys: PhysicsConstants) -> tuple[ExponentialFit, PaperLSResult]:
    """The paper's Sec. IV-B on the hold (a slice of samples at ``force_n`` N): Eq. 9, strain from Eq. 3 at the
    constant force using the fitted C, then Eqs. 7–8 with ε̇ from the fit and σ̇ from the measured force."""
    t = trial.time_s[hold]
    exp_fit = fit_exponential(t, trial.conductance_s[hold])
    fitted = exp_fit(t)
    result = strain_from_conductance(fitted, np.full(t.shape, force_n), phys)
    strain = np.where(result.ok, result.strain, np.nan)
    # dε/dt = dε/dC · dC/dt along the fitted curve; dε/dC by central differences of the smooth inversion.
    dc = 1e-7 * np.maximum(np.abs(fitted), 1e-12)
    up = strain_from_conductance(fitted + dc, np.full(t.shape, force_n), phys).strain
    down = strain_from_conductance(fitted - dc, np.full(t.shape, force_n), phys).strain
    strain_rate = (up - down) / (2 * dc) * exp_fit.derivative(t)
    stress = trial.force_n[hold] / area_m2
    stress_rate = np.gradient(stress, t) if t.size > 1 else np.zeros_like(t)
    return exp_fit, fit_paper_ls(stress, strain, strain_rate, stress_rate)


def _fit(trials: list[FitTrial], area_m2: float, phys: PhysicsConstants, start, mode: str,
         saturation_s: float | None, solver: str) -> OutputFit:
    if solver == "scipy" or mode == "per_trial":
        return fit_output_scipy(trials, area_m2, phys, start, mode, saturation_s=saturation_s,
                                min_force_fraction=MIN_FORCE_FRACTION)
    return fit_output_casadi(trials, area_m2, phys, start, mode, saturation_s=saturation_s,
                             min_force_fraction=MIN_FORCE_FRACTION, solver=solver)


def _tau_grid(base: SLSParams, step_s: float, span_s: float) -> list[SLSParams]:
    """``base`` with its creep time moved over a log grid (E0, E1 kept; mu1 = E1·τ): starts for the multi-start."""
    taus = np.geomspace(TAU_GRID_LOW * step_s, TAU_GRID_HIGH * span_s, TAU_GRID_POINTS)
    e1 = float(base.E1_Pa)
    return [SLSParams(float(base.E0_Pa), e1, e1 * float(tau)) for tau in taus]


def _distinct_starts(candidates: Sequence[SLSParams], totals: np.ndarray, count: int) -> list[SLSParams]:
    """The ``count`` lowest-cost candidates whose creep times differ by more than a factor 3 (distinct basins)."""
    chosen: list[SLSParams] = []
    for index in np.argsort(totals):
        if not np.isfinite(totals[index]):
            continue
        tau = math.log(float(candidates[index].tau_s))
        if all(abs(tau - math.log(float(c.tau_s))) > math.log(3.0) for c in chosen):
            chosen.append(candidates[index])
        if len(chosen) == count:
            break
    return chosen or [candidates[int(np.argmin(totals))]]


def _elastic_cost(fit_trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, joint: SLSParams,
                  saturation_s: float | None) -> float:
    """The lowest cost (as ``trial_costs``, summed over trials) of a purely elastic sensor (no creep: E1 → ∞),
    searched over its stiffness between the joint fit's long-run and instantaneous stiffnesses (two batched grids)."""
    e0, e1 = float(joint.E0_Pa), float(joint.E1_Pa)
    b = e0 * e1 / (e0 + e1)

    def costs(stiffness: np.ndarray) -> np.ndarray:
        params = [SLSParams(float(e), float(e) * 1e12, float(e) * 1e12) for e in stiffness]
        return trial_costs(fit_trials, area_m2, phys, params, saturation_s=saturation_s,
                           min_force_fraction=MIN_FORCE_FRACTION).sum(axis=1)

    grid = np.geomspace(b / 1.5, e0 * 1.5, 25)
    totals = costs(grid)
    best = int(np.argmin(totals))
    lo, hi = math.log(grid[max(best - 1, 0)]), math.log(grid[min(best + 1, grid.size - 1)])
    refined = minimize_scalar(lambda log_e: float(costs(np.array([math.exp(log_e)]))[0]), bounds=(lo, hi),
                              method="bounded", options={"xatol": 1e-9})
    return float(min(float(refined.fun), float(np.min(totals))))


def _creep_resolved(joint: OutputFit, elastic_cost: float) -> bool:
    """Does the creep term (E1, mu1) lower the cost significantly below the best purely elastic model? F-test,
    2 extra parameters, at the 0.1 % level (the residuals of a real record are not independent: a strict level)."""
    cost = float(sum(joint.cost_per_trial))
    if not cost > 0:
        return elastic_cost > 0
    # The scale is the read samples' residual variance: a censored sample's near-zero residual is not a noise draw.
    scale = joint.residual_variance if joint.residual_variance > 0 else cost / max(int(sum(joint.n_used)) - 3, 1)
    dof = max(int(sum(joint.n_used)) - 3, 1)
    f = ((elastic_cost - cost) / 2) / scale
    return bool(f > special.fdtri(2, dof, 0.999))


def _degenerate_reasons(joint: OutputFit, step_s: float, span_s: float, creep_resolved: bool = True) -> list[str]:
    """Why the joint fit must not be stored as good: at a bound, unidentifiable, not converged, or a creep the
    records cannot resolve (τ → 0 and τ → ∞ both look elastic; the reason names both)."""
    assert joint.ref is not None
    reasons = []
    if not creep_resolved:
        reasons.append("no creep is resolved: the creep term does not fit these records significantly better than "
                       "a purely elastic sensor (F-test, 0.1 %), so τ → 0 and τ → ∞ both look purely elastic here and "
                       "E1, mu1 are not identified; hold longer, or check the sensor")
    if joint.at_bound:
        reasons.append("a parameter sits at its search bound (10^±6 of the starting scale)")
    if any(not (math.isfinite(hi) and lo > 0) for lo, hi in joint.ci95.values()):
        reasons.append("parameters not identifiable from these trials (singular Jacobian: infinite 95 % interval)")
    if not joint.success:
        reasons.append(f"the optimiser did not converge ({joint.message})")
    tau_s = float(joint.ref.tau_s)
    if not step_s <= tau_s <= TAU_RESOLVABLE_SPANS * span_s:
        side = "shorter than one sample step" if tau_s < step_s else "longer than the records"
        reasons.append(f"creep time τ = mu1/E1 = {tau_s:.3g} s is far {side} ({step_s:.3g} s steps, {span_s:.0f} s "
                       "records): no creep is resolved, and τ → 0 and τ → ∞ both look purely elastic here; hold "
                       "longer or sample faster")
    return reasons


def degenerate_tau_named(warnings: Sequence[str]) -> bool:
    """A warning already names τ as unresolved (so the open profile interval need not be said twice)."""
    return any("τ" in w and ("resolv" in w or "far from" in w) for w in warnings)


# A trial's 95 % intervals are the linearised (Wald) ones, ±t standard errors in the log-parameters. They assume the
# trial's cost rises by t² residual variances at each end; where the likelihood is flatter than that (a trial mostly at
# the readout's ceiling: its censored samples bound the creep from one side only) an end lies short of where the data
# stop supporting the parameter, and the interval is too narrow. An end whose rise falls below this share of t²
# is not reported as a 95 % interval (models.calibration.calibrate_sensor).
WALD_END_RISE_SHARE = 0.5


def interval_end_rises(trial: FitTrial, params: SLSParams, cov: np.ndarray, variance: float, t_quantile: float,
                       area_m2: float, phys: PhysicsConstants, saturation_s: float | None) -> np.ndarray:
    """(3, 2): how far ``trial``'s cost rises (in its residual variances) from its own fit ``params`` to the low and
    high end of each parameter's 95 % interval (E0, E1, μ1), each end reached along the line the linearisation
    moves the other log-parameters on (``cov[:, k]/cov[k, k]``, ``cov`` the 3×3 log-parameter covariance): t² each
    where the Wald interval is right, less where the likelihood is flatter than it assumes. One batched model run."""
    centre = np.log([float(getattr(params, n)) for n in PARAM_NAMES])
    candidates = [params]
    for k in range(3):
        direction = t_quantile * cov[:, k] / math.sqrt(cov[k, k])
        for sign in (-1.0, 1.0):
            candidates.append(SLSParams(*(float(v) for v in np.exp(centre + sign * direction))))
    costs = trial_costs([trial], area_m2, phys, candidates, saturation_s=saturation_s,
                        min_force_fraction=MIN_FORCE_FRACTION)[:, 0]
    return ((costs[1:] - costs[0]) / variance).reshape(3, 2)


def _flat_interval_end(trial: FitTrial, per_trial: OutputFit, index: int, area_m2: float, phys: PhysicsConstants,
                       saturation_s: float | None) -> str | None:
    """Which end of trial ``index``'s 95 % intervals the likelihood is too flat at (:func:`interval_end_rises`
    below :data:`WALD_END_RISE_SHARE` of t²), or None when every end holds."""
    if index >= len(per_trial.cov_per_trial):
        return None
    cov, t_quantile = per_trial.cov_per_trial[index], per_trial.t_per_trial[index]
    variance = per_trial.variance_per_trial[index]
    if not (np.all(np.isfinite(cov)) and variance > 0 and np.all(np.diag(cov) > 0)):
        return None  # an infinite interval is named by _trial_unresolved
    rises = interval_end_rises(trial, per_trial.params[index], cov, variance, t_quantile, area_m2, phys,
                               saturation_s) / (t_quantile * t_quantile)
    k, side = np.unravel_index(int(np.argmin(rises)), rises.shape)
    if rises[k, side] >= WALD_END_RISE_SHARE:
        return None
    return (f"the likelihood at the {('low', 'high')[side]} end of {PARAM_NAMES[k]}'s interval rises "
            f"{rises[k, side]:.2f} of what the interval assumes")


def _trial_unresolved(params: SLSParams, ci95: dict[str, tuple[float, float]], step_s: float,
                      span_s: float) -> str | None:
    """Why one trial's own fit is not identified (None when it is): τ outside what a record resolves, or an
    infinite / non-positive 95 % interval (singular Jacobian)."""
    tau_s = float(params.tau_s)
    if not step_s <= tau_s <= TAU_RESOLVABLE_SPANS * span_s:
        return f"creep time τ = {tau_s:.3g} s is outside what a {span_s:.0f} s record at {step_s:.3g} s steps resolves"
    if any(not (math.isfinite(hi) and lo > 0) for lo, hi in ci95.values()):
        return "singular Jacobian (infinite 95 % interval)"
    return None


def calibrate_sensor(trials: Sequence[TrialInput], area_m2: float, phys: PhysicsConstants, *,
                     window_s: tuple[float, float] = DEFAULT_WINDOW_S, saturation_s: float | None = None,
                     solver: str = DEFAULT_SOLVER, fit_trend: bool = True,
                     subtract_baseline: bool = False,
                     fit_rate_hz: float | None = DEFAULT_FIT_RATE_HZ,
                     drift_s_per_s: float = 0.0, drift_tau_s: float = math.inf) -> SensorCalibration:
    """Fit one sensor from its trials (see the module docstring). ``area_m2`` in m²; ``saturation_s`` the readout's
    largest conductance (S) — samples at it are censored; ``solver`` for the joint and trend fits: a CasADi solver
    of :func:`models.fit_output.fit_output_casadi` (``"gauss-newton"``, the default, see :data:`DEFAULT_SOLVER`;
    ``"ipopt"``, ``"sqpmethod"``) or ``"scipy"`` (the cross-check); all agree to ≤ 1e-8 relative (benchmarks/bench_fitters.py).
    ``subtract_baseline``: the linear model's drift handling — each trial's unloaded conductance is subtracted
    from its window mean before the line is fitted (the per-trial baselines are kept in the result).

    ``fit_rate_hz``: trials sampled faster are block-averaged to this rate first (:func:`decimate_trial`; None or 0
    fits every sample).

    ``drift_s_per_s``: a baseline drift (S/s, from each trial's start) already measured (:func:`calibrate_with_drift`):
    the model is fitted to the readings with it added, so a sample at the readout's ceiling stays censored at the
    ceiling the board had; the paper's procedure, the linear model and the misfit see the readings without it.
    ``drift_tau_s``: that baseline settles with this time constant (s; :func:`models.fit_output.baseline_offset`),
    ``drift_s_per_s`` its rate at each trial's start; inf: a linear drift.

    Raises :class:`FlatSensorError` (a ValueError) for a flat or disconnected sensor, ValueError for unusable
    trials (no force, too few samples), each naming the trial.
    """
    if not trials:
        raise ValueError("no trials given")
    if fit_rate_hz:
        trials = [decimate_trial(trial, fit_rate_hz, saturation_s) for trial in trials]
    readings = list(trials)  # as read (a drift in them): what the output-error fits compare with
    if drift_s_per_s:
        trials = [_drift_removed(trial, drift_s_per_s, saturation_s, drift_tau_s) for trial in readings]
    if not (area_m2 > 0 and math.isfinite(area_m2)):
        raise ValueError(f"sensor area must be a positive number of m², got {area_m2!r}")
    fit_trials: list[FitTrial] = []
    prelim: list[dict] = []
    for trial, reading in zip(trials, readings, strict=True):
        try:
            hold, hold_n = hold_segment(trial.force_n)
        except ValueError as exc:
            raise ValueError(f"{trial.name}: {exc}") from exc
        _check_not_flat(trial)
        try:
            trial_mean(trial.time_s, trial.conductance_s, window_s)
        except ValueError as exc:
            raise ValueError(f"{trial.name}: {exc}; choose another --window") from exc
        n_hold = hold.stop - hold.start
        if n_hold < 10:
            raise ValueError(f"{trial.name}: the hold has only {n_hold} samples; need ≥ 10")
        exp_fit, paper = paper_procedure(trial, hold, hold_n, area_m2, phys)
        loaded = trial.force_n >= DFREE_FORCE_FRACTION * hold_n
        rows = np.flatnonzero(loaded)
        strain = _strain(trial, phys, rows)
        if not np.any(np.isfinite(strain)):
            raise ValueError(f"{trial.name}: no sample gives a strain from Eq. 3 (the contact term K/√F exceeds "
                             "every reading): check the physics constants (--physics) and the force column")
        if saturation_s is not None:
            # A reading at the ceiling is not a strain (the readout clipped it): left out of the starting values.
            strain[trial.conductance_s[rows] >= saturation_s * (1 - 1e-12)] = np.nan
        try:
            dfree = estimate_sls([(trial.time_s[rows], trial.force_n[rows] / area_m2, strain)])
        except ValueError:
            dfree = None
        # The record shows its loading when it starts unloaded: a ramp or a step faster than one sample both
        # identify E0 (the instantaneous response); only a record that starts already loaded does not.
        before = trial.force_n[: hold.start + 1]
        has_ramp = bool(np.any(before[np.isfinite(before)] < MIN_FORCE_FRACTION * hold_n))
        # Saturated samples and the hold's saturated share, in raw samples (an averaged sample counts as those it
        # stands for).
        n_sat = _n_censored(trial, saturation_s)
        raw = np.ones(trial.time_s.size) if trial.counts is None else np.asarray(trial.counts, dtype=np.float64)
        hold_raw = raw[hold][np.isfinite(trial.conductance_s[hold])]
        sat_fraction = (float(np.sum(raw[hold][trial.conductance_s[hold] >= saturation_s * (1 - 1e-12)]))
                        / max(float(np.sum(hold_raw)), 1.0) if saturation_s else 0.0)
        fit_trials.append(FitTrial(trial.name, trial.time_s, trial.force_n, reading.conductance_s, hold_n,
                                   counts=trial.counts, offset_s=_drift_offset(trial, drift_s_per_s, drift_tau_s),
                                   within_ss=trial.within_ss, noise_s=trial.noise_s))
        prelim.append({"hold": hold, "hold_n": hold_n, "exp": exp_fit, "paper": paper, "dfree": dfree,
                       "strain": (trial.time_s[rows], trial.force_n[rows] / area_m2, strain), "ramp": has_ramp,
                       "sat": n_sat, "sat_fraction": sat_fraction,
                       # The raw samples' noise where it was measured before averaging (a trial at the ceiling).
                       "noise": trial.noise_s if trial.noise_s is not None else _hold_noise(
                           trial.conductance_s[hold], saturation_s, None if trial.counts is None else trial.counts[hold])})

    step_s = float(np.median(np.concatenate([np.diff(t.time_s) for t in trials])))
    span_s = float(max(t.time_s[-1] - t.time_s[0] for t in trials))
    try:
        estimates = [estimate_sls([p["strain"] for p in prelim])]
    except ValueError:
        estimates = []
    estimates += [p["dfree"] for p in prelim if p["dfree"]]
    # Starting values only: one that is not a physical parameter set (a record almost all at the ceiling can give
    # τ → 0) is dropped, and the typical sensor stands in when none is left.
    candidates = [SLSParams(e.E0_Pa, e.E1_Pa, e.mu1_Pa_s) for e in estimates
                  if all(math.isfinite(v) and v > 0 for v in (e.E0_Pa, e.E1_Pa, e.mu1_Pa_s))] or [TYPICAL_SLS]
    candidates += _tau_grid(candidates[0], step_s, span_s)
    # The profile over log τ: each trial's own minimum and the joint minima join the starts.
    profile = profile_tau(fit_trials, area_m2, phys,
                          np.geomspace(PROFILE_TAU_LOW * step_s, TAU_RESOLVABLE_SPANS * span_s, PROFILE_TAU_POINTS),
                          saturation_s=saturation_s)
    profile_starts = [p for p in profile.best_per_trial() if p is not None]
    profile_joint = profile.joint_minima(PROFILE_STARTS)
    candidates += profile_starts + profile_joint
    # Each trial starts from whichever candidate fits it best (one batched model run): a noisy trial's own
    # estimate can sit on a plateau (E0 → ∞, τ → 0) that another start avoids.
    costs = trial_costs(fit_trials, area_m2, phys, candidates, saturation_s=saturation_s,
                        min_force_fraction=MIN_FORCE_FRACTION)
    per_trial_start = [candidates[int(np.argmin(costs[:, i]))] for i in range(len(fit_trials))]
    per_trial = fit_output_scipy(fit_trials, area_m2, phys, per_trial_start, "per_trial",
                                 saturation_s=saturation_s, min_force_fraction=MIN_FORCE_FRACTION)
    if saturation_s is not None:
        fit_trials, per_trial = _censored_noise_refined(fit_trials, per_trial, area_m2, phys, saturation_s)
        for p, fitted_trial in zip(prelim, fit_trials):
            if fitted_trial.noise_s is not None:
                p["noise"] = fitted_trial.noise_s
    # The joint fit runs from the best few distinct starts (the per-trial results, their median, the τ grid) and
    # keeps the lowest cost; the check below holds it to every candidate's cost.
    median = SLSParams(*(float(np.median([float(getattr(p, n)) for p in per_trial.params])) for n in PARAM_NAMES))
    joint_candidates: list[SLSParams] = [median, *_present(per_trial.params), *_tau_grid(median, step_s, span_s),
                                         *profile_joint, *profile_starts]
    totals = trial_costs(fit_trials, area_m2, phys, joint_candidates, saturation_s=saturation_s,
                         min_force_fraction=MIN_FORCE_FRACTION).sum(axis=1)
    joint = None
    for start in _distinct_starts(joint_candidates, totals, JOINT_STARTS):
        fit = _fit(fit_trials, area_m2, phys, start, "joint", saturation_s, solver)
        if joint is None or sum(fit.cost_per_trial) < sum(joint.cost_per_trial):
            joint = fit
        assert joint.ref is not None  # a joint fit always returns its parameters
        if not _degenerate_reasons(joint, step_s, span_s):
            break  # a regular optimum below every evaluated start: no need for the next basin
    assert joint is not None and joint.ref is not None
    best_candidate = float(np.min(totals))
    if sum(joint.cost_per_trial) > best_candidate * (1 + 1e-6):
        # Never return a worse optimum than a point already evaluated: restart from the best candidate.
        fit = _fit(fit_trials, area_m2, phys, joint_candidates[int(np.argmin(totals))], "joint", saturation_s,
                   solver)
        if sum(fit.cost_per_trial) < sum(joint.cost_per_trial):
            joint = fit
    assert joint.ref is not None
    # A per-trial fit must do at least as well on its trial as the joint parameters: if not, it stopped in a worse
    # local minimum; those trials are refitted from the joint solution.
    own = trial_costs(fit_trials, area_m2, phys, [joint.ref], saturation_s=saturation_s,
                      min_force_fraction=MIN_FORCE_FRACTION)[0]
    stuck = own < np.array(per_trial.cost_per_trial) * (1 - 1e-6)
    if stuck.any():
        restart = [joint.ref if stuck[i] else _present(per_trial.params)[i] for i in range(len(fit_trials))]
        per_trial = fit_output_scipy(fit_trials, area_m2, phys, restart, "per_trial", saturation_s=saturation_s,
                                     min_force_fraction=MIN_FORCE_FRACTION)
    forces = np.array([p["hold_n"] for p in prelim])
    distinct = np.ptp(forces) > 0.05 * float(np.mean(forces))
    trend = None
    if fit_trend and distinct:
        trend = _fit(fit_trials, area_m2, phys, joint.ref, "trend", saturation_s, solver)

    sensor_warnings: list[str] = list(joint.warnings)
    reports = []
    steps: list[ReadingStep] = []
    for i, (trial, p) in enumerate(zip(trials, prelim)):
        warnings: list[str] = []
        if p["sat"]:
            warnings.append(f"{p['sat']} saturated sample(s) (readout at its limit): censored in the fit; lower "
                            "the force or the readout gain")
        refused = None
        trial_params = per_trial.params[i]
        assert trial_params is not None
        unresolved = _trial_unresolved(trial_params, per_trial.ci95_per_trial[i], step_s, span_s)
        mostly_censored = p["sat_fraction"] > MAX_CENSORED_FRACTION
        if unresolved and mostly_censored:
            refused = (f"{100 * p['sat_fraction']:.0f} % of the hold is saturated (readout at 1/R_C) and the rest "
                       f"does not pin the trial down ({unresolved}): it only says 'at least this much', so its own "
                       "SLS parameters are not identifiable; refused for the per-trial table (it still bounds the "
                       "joint fit)")
        elif unresolved:
            refused = (f"{unresolved}: this trial alone does not identify its SLS parameters (they would sit at a "
                       "search bound); refused for the per-trial table (it still enters the joint fit)")
        elif p["sat"]:
            flat = _flat_interval_end(fit_trials[i], per_trial, i, area_m2, phys, saturation_s)
            if flat:
                refused = (f"{flat}, {100 * p['sat_fraction']:.0f} % of the hold at the readout's ceiling: its "
                           "linearised 95 % interval would be too narrow; refused for the per-trial table (it still "
                           "enters the joint fit)")
        if refused is not None:
            warnings.append(f"per-trial fit refused: {refused}")
        elif mostly_censored:
            warnings.append(f"{100 * p['sat_fraction']:.0f} % of the hold is at the readout's ceiling: this trial's "
                            "parameters rest on its loading ramp and the creep below the ceiling (the censored "
                            "samples bound the rest), so its intervals are wider; lower the force or the readout gain")
        if not p["ramp"]:
            warnings.append("no loading ramp in the record: E0 (the instantaneous stiffness) is poorly identified; "
                            "start recording before loading")
        rmse = per_trial.rmse_s[i]
        hold_rmse, sensitivity = hold_misfit(trial, p["hold"], trial_params, area_m2, phys, saturation_s)
        misfit_n = hold_rmse / sensitivity if sensitivity > 0 else math.nan
        verdict = poor_fit_verdict(hold_rmse if math.isfinite(hold_rmse) else rmse, p["noise"], misfit_n,
                                   p["hold_n"], reference_scatter(trial.force_n[p["hold"]]))
        step = reading_step(trial, p["hold"], trial_params, area_m2, phys, saturation_s, p["noise"], sensitivity,
                            p["hold_n"], reference_scatter(trial.force_n[p["hold"]]))
        if verdict:
            cause = ("a step in the reading" if step is not None
                     else "creased sensor, slipping probe, drift?")
            warnings.append(f"poor fit: {verdict}: the SLS model does not describe this trial ({cause})")
        if step is not None:
            steps.append(step)
            warnings.append(f"a step in the reading: {step.describe()}: a contact or connector shift or a slipping "
                            "probe, not creep")
            if refused is None:
                refused = (f"a step in the reading ({step.size_s * 1e6:+.3g} µS at {step.time_s:.0f} s): the SLS "
                           "model cannot describe this trial, and its own fit would read the step as creep")
                warnings.append(f"per-trial fit refused: {refused}")
        # The paper's LS comparison is information (stored under the trial's "paper" with its own notes), not a
        # warning: it is "not identified" on most good trials, and a warning that is always there teaches users to
        # ignore warnings.
        reports.append(TrialReport(trial.name, p["hold_n"], float(trial.time_s[p["hold"].start]),
                                   float(trial.time_s[p["hold"].stop - 1]), p["exp"], p["paper"],
                                   p["dfree"], per_trial.params[i], per_trial.ci95_per_trial[i], rmse, p["noise"],
                                   p["sat"], p["ramp"], tuple(warnings), refused, misfit_n))

    if not distinct:
        sensor_warnings.append("all trials are at one force: no force trend fitted, and forces far from "
                               f"{float(np.mean(forces)):.3g} N will be extrapolated")
    for name in PARAM_NAMES:
        lo, hi = joint.ci95[name]
        value = float(getattr(joint.ref, name))
        if not (hi - lo) / 2 < WIDE_INTERVAL * value:
            hint = {"E0_Pa": "record the loading ramp",
                    "mu1_Pa_s": "the creep time τ is far from the record length: hold longer or check the sensor",
                    "E1_Pa": "hold longer so the creep settles"}[name]
            sensor_warnings.append(f"{name} poorly identified (95 % interval {lo:.3g} … {hi:.3g}): {hint}")
    tau_lo, tau_hi = refined_tau_interval(fit_trials, area_m2, phys, profile, saturation_s=saturation_s)
    fitted_tau = float(joint.ref.tau_s)
    if not tau_lo <= fitted_tau <= tau_hi:
        # The joint fit and the τ profile disagree on where the optimum is (seen with a baseline drift): an
        # interval that does not hold its own estimate is never reported as is. Widened to hold it, and said.
        sensor_warnings.append(
            f"the fitted τ {fitted_tau:.4g} s lies outside its 95 % profile interval [{tau_lo:.4g}, {tau_hi:.4g}] s: "
            "the fit is not at the profile's optimum (a drifting baseline or a second creep time can do this); "
            "the interval is widened to hold the estimate and the parameters should not be trusted")
        tau_lo, tau_hi = min(tau_lo, fitted_tau), max(tau_hi, fitted_tau)
    if not degenerate_tau_named(sensor_warnings) and not math.isfinite(tau_hi):
        sensor_warnings.append(f"creep time τ not bounded above by these records (95 % profile interval τ ≥ "
                               f"{tau_lo:.3g} s, fitted {float(joint.ref.tau_s):.3g} s): E1 and mu1 are correlated; "
                               "forces within the calibrated range are still right, hold longer to pin τ down")
    degenerate = _degenerate_reasons(joint, step_s, span_s, _creep_resolved(
        joint, _elastic_cost(fit_trials, area_m2, phys, joint.ref, saturation_s)))
    if steps:
        names = ", ".join(step.trial for step in steps)
        degenerate.append(f"a step in the reading of {len(steps)} trial(s) ({names}): the model cannot describe a "
                          "jump the force does not make, and the fit reads it as creep (τ, E1 and their intervals "
                          "are wrong); leave those trials out or record them again")
    sensor_warnings.extend(f"degenerate SLS fit: {reason}" for reason in degenerate
                           if not any(reason in w for w in sensor_warnings))
    if not any(p["ramp"] for p in prelim):
        sensor_warnings.append("no trial contains its loading ramp: E0 is poorly identified")
    n_sat = sum(p["sat"] for p in prelim)
    if n_sat:
        sensor_warnings.append(f"{n_sat} saturated sample(s) across the trials were censored")
    poor = [r.name for r in reports if any(w.startswith("poor fit") for w in r.warnings)]
    if poor:
        sensor_warnings.append(f"poor fit in {', '.join(poor)}")
    if trend is not None:
        sensor_warnings.extend(w for w in trend.warnings if w not in sensor_warnings)
        trend_rmse = float(np.sqrt(np.sum(np.square(trend.rmse_s) * np.array(trend.n_used)) / sum(trend.n_used)))
        joint_rmse_s = float(np.sqrt(np.sum(np.square(joint.rmse_s) * np.array(joint.n_used)) / sum(joint.n_used)))
        if joint_rmse_s > POOR_FIT_NOISE_RATIO * trend_rmse:
            sensor_warnings.append(
                f"the parameters depend on force: one parameter set (sls, used by estimate) fits "
                f"{joint_rmse_s / trend_rmse:.1f}× worse than the force trend (sls_trend); expect force errors "
                f"away from {joint.ref_force_n:.3g} N")

    try:
        linear = fit_linear_trials([(t.time_s, t.force_n, t.conductance_s, t.counts) for t in trials], window_s,
                                   subtract_baseline=subtract_baseline)
        sensor_warnings.extend(linear.warnings)
    except ValueError as exc:
        linear = None
        sensor_warnings.append(f"linear model not fitted: {exc}")
    joint_rmse = float(np.sqrt(np.sum(np.square(joint.rmse_s) * np.array(joint.n_used)) / sum(joint.n_used)))
    return SensorCalibration(
        area_m2=float(area_m2), linear=linear, sls=joint.ref, sls_ci95=joint.ci95,
        sls_trend=trend.trend if trend is not None else None, trend_ci95=trend.ci95 if trend is not None else {},
        trials=tuple(reports), force_range_n=(float(forces.min()), float(forces.max())), rmse_s=joint_rmse,
        solver=joint.solver, warnings=tuple(sensor_warnings), degenerate_reasons=tuple(degenerate),
        tau_ci95=(tau_lo, tau_hi), steps=tuple(steps))


# -- a drifting baseline -----------------------------------------------------------------------------------------
DRIFT_STATISTIC = 25.0  # N·ln(SSE0/SSE1), a likelihood ratio (χ², 1 dof): 25 ≈ 5 σ; below it no drift is claimed


def without_drift(trial: TrialInput, rate_s_per_s: float, tau_s: float = math.inf) -> TrialInput:
    """``trial`` with a baseline ramp of ``rate_s_per_s`` (S/s from the trial's start; settling with time constant
    ``tau_s``, :func:`models.fit_output.baseline_offset`) taken out."""
    if rate_s_per_s == 0.0:
        return trial
    corrected = trial.conductance_s - baseline_offset(trial.time_s - trial.time_s[0], rate_s_per_s, tau_s)
    return replace(trial, conductance_s=corrected)


def _drift_offset(trial: TrialInput | FitTrial, rate_s_per_s: float, tau_s: float = math.inf) -> np.ndarray | None:
    """The drift's part of each reading (S), for :class:`models.fit_output.FitTrial` (None without a drift)."""
    if not rate_s_per_s:
        return None
    return baseline_offset(np.asarray(trial.time_s, dtype=np.float64) - float(trial.time_s[0]), rate_s_per_s, tau_s)


def _drift_removed(trial: TrialInput, rate_s_per_s: float, saturation_s: float | None,
                   tau_s: float = math.inf) -> TrialInput:
    """``trial`` without its drift, for what reads the conductance directly (the paper's procedure, the linear model,
    starting values, misfit): a sample at the ceiling stays at it (censored: only a lower bound), the others are kept
    below it (taking the drift out cannot make a reading censored)."""
    corrected = without_drift(trial, rate_s_per_s, tau_s)
    if saturation_s is None:
        return corrected
    censored = trial.conductance_s >= saturation_s * (1 - 1e-12)
    c = np.where(censored, saturation_s, np.minimum(corrected.conductance_s, saturation_s * (1 - 1e-9)))
    return replace(trial, conductance_s=c)


def _check_arm(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, start: SLSParams,
               saturation_s: float | None) -> tuple[SecondArm | None, str | None]:
    """The two-arm check, or why it could not be made (never silent: the reason is stored instead)."""
    try:
        return check_second_arm(trials, area_m2, phys, start, saturation_s=saturation_s), None
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return None, f"the two-arm check could not be made: {exc}"


def calibrate_with_drift(trials: Sequence[TrialInput], area_m2: float, phys: PhysicsConstants, *,
                         saturation_s: float | None = None, fit_rate_hz: float | None = DEFAULT_FIT_RATE_HZ,
                         **options: Any) -> SensorCalibration:
    """:func:`calibrate_sensor`, with a baseline drift looked for and separated from the creep.

    A drift (temperature, a relaxing shell) adds ``d·t`` to every trial; fitted as creep it makes τ too long and E1
    too low with no other sign. The SLS parameters are shared by the trials at every force while the creep they
    describe scales with the force and levels off after a few τ; a drift does neither, so one rate ``d`` common to
    all trials can be told apart: the force-trend model (parameters linear in force) is fitted with and without
    ``d`` as a parameter, the samples at the readout's ceiling censored against the model plus the drift (the
    ceiling does not move with a drift: leaving them out picks the samples the noise kept below it, which reads as a
    false drift). When ``d`` lowers the cost by more than chance (likelihood ratio > :data:`DRIFT_STATISTIC`), the
    calibration is fitted with it (:func:`calibrate_sensor` ``drift_s_per_s``), ``drift_s_per_s`` says the rate and
    a warning what was done; otherwise it is the plain fit with ``drift_s_per_s = 0``. One force level only, or τ
    near the hold's length: the two cannot be separated (docs/NUMERICS.md). A second, slower creep arm
    (:mod:`models.creep_arms`) is checked with and without a drift; its result is always stored.

    A baseline that is not linear in time is named, not fitted as a drift: when a drift is found, the baseline is
    also fitted as one that settles, ``d·τb·(1 − e^(−t/τb))`` (τb → ∞ is the drift); when that beats the drift by
    more than :data:`DRIFT_STATISTIC`, with τb inside what the records resolve, the calibration is fitted with the
    settling baseline and a warning names it (``drift_tau_s``). A step in a trial's reading
    (:func:`reading_step`, found by :func:`calibrate_sensor`) is neither a drift nor a second arm: neither is looked
    for, and the calibration is degenerate with the step named."""
    if fit_rate_hz:
        trials = [decimate_trial(trial, fit_rate_hz, saturation_s) for trial in trials]
    plain = calibrate_sensor(trials, area_m2, phys, saturation_s=saturation_s, fit_rate_hz=None, **options)
    if plain.steps:
        note = (f"steps in the readings of {', '.join(step.trial for step in plain.steps)}: a baseline drift and a "
                "second creep arm were not looked for (a step would read as either)")
        return replace(plain, second_arm_note=note, warnings=(*plain.warnings, note))
    # A trial at the readout's ceiling keeps the σ its censored likelihood settled on in the plain fit.
    trials = [replace(t, noise_s=r.noise_s) if _n_censored(t, saturation_s) and math.isfinite(r.noise_s) else t
              for t, r in zip(trials, plain.trials)]
    fit_trials = [FitTrial(t.name, t.time_s, t.force_n, t.conductance_s, hold_segment(t.force_n)[1], counts=t.counts,
                           within_ss=t.within_ss, noise_s=t.noise_s) for t in trials]
    arm, arm_note = _check_arm(fit_trials, area_m2, phys, plain.sls, saturation_s)
    plain = replace(plain, second_arm=arm, second_arm_note=arm_note)
    if arm_note:
        plain = replace(plain, warnings=(*plain.warnings, arm_note))
    forces = np.array([float(r.force_n) for r in plain.trials])
    if not np.ptp(forces) > 0.05 * float(np.mean(forces)):  # the force trend's own criterion (calibrate_sensor)
        return replace(plain, warnings=(*plain.warnings, "one force level: a baseline drift cannot be told apart "
                                        "from creep (not looked for)"))
    if arm is not None and arm.resolved and not arm.drift_too:
        return replace(plain, drift_s_per_s=0.0, warnings=(
            *plain.warnings, f"{arm.message()} (a slow change that scales with the force: a second creep arm, not a "
            "baseline drift; none removed)"))
    # The drift as a parameter of the force-trend fit (the paper's sensors' parameters grow with force: one shared
    # set would misfit, and a drift would soak the misfit up), from the plain fit's joint parameters. Always scipy:
    # a local fit with one more parameter (the CasADi paths reach the same optimum).
    try:
        base = fit_output_scipy(fit_trials, area_m2, phys, plain.sls, "trend", saturation_s=saturation_s,
                                min_force_fraction=MIN_FORCE_FRACTION)
        drifting = fit_output_scipy(fit_trials, area_m2, phys, plain.sls, "trend", saturation_s=saturation_s,
                                    min_force_fraction=MIN_FORCE_FRACTION, drift=True)
    except (ValueError, ArithmeticError):
        return replace(plain, drift_s_per_s=0.0)  # no comparable fits: nothing claimed
    statistic = likelihood_ratio(base, drifting)
    if statistic < DRIFT_STATISTIC:
        return replace(plain, drift_s_per_s=0.0)
    rate, tau_b = drifting.drift_s_per_s, math.inf
    settling = _settling_fit(fit_trials, area_m2, phys, plain.sls, saturation_s, drifting)
    settles = settling is not None and likelihood_ratio(drifting, settling) > DRIFT_STATISTIC
    if settles:
        assert settling is not None
        rate, tau_b = settling.drift_s_per_s, settling.drift_tau_s
    fitted = replace(calibrate_sensor(trials, area_m2, phys, saturation_s=saturation_s, fit_rate_hz=None,
                                      drift_s_per_s=rate, drift_tau_s=tau_b, **options),
                     second_arm=arm, second_arm_note=arm_note)
    baseline_cov = settling.drift_cov if settles and settling is not None else drifting.drift_cov
    if baseline_cov is not None:
        fitted = _with_baseline_uncertainty(fitted, fit_trials, area_m2, phys, saturation_s, rate, tau_b,
                                            baseline_cov)
    censored = sum(_n_censored(t, saturation_s) for t in trials)
    lo, hi = drifting.drift_ci95
    ceiling_note = f"; {censored} sample(s) at the readout's ceiling censored against it" if censored else ""
    if settles:
        assert settling is not None
        tau_lo, tau_hi = settling.drift_tau_ci95
        note = (f"the baseline settles, it does not drift: {rate * tau_b * 1e6:+.3g} µS in all with a time constant "
                f"of {tau_b:.3g} s (95 % [{tau_lo:.3g}, {tau_hi:.3g}] s; a linear drift fits it worse by a likelihood "
                f"ratio of {likelihood_ratio(drifting, settling):.0f}), found and separated from the creep (the "
                f"parameters are fitted with it: τ {float(fitted.sls.tau_s):.3g} s; the force trend at "
                f"{drifting.ref_force_n:.3g} N reads τ {_trend_tau(settling):.3g} s with it, "
                f"{_trend_tau(drifting):.3g} s taken as a linear drift, {_trend_tau(base):.3g} s with none)"
                f"{ceiling_note}: let the sensor settle (temperature, load history) before calibrating")
    else:
        note = (f"baseline drift of {rate * 1e6:+.3g} µS/s (95 % [{lo * 1e6:+.3g}, {hi * 1e6:+.3g}]) found and "
                f"separated from the creep (the parameters are fitted with it; without that, τ would read "
                f"{float(plain.sls.tau_s):.3g} s instead of {float(fitted.sls.tau_s):.3g} s){ceiling_note}: check the "
                "sensor's temperature and settling")
    warnings = [*fitted.warnings, note]
    if arm_note:
        warnings.append(arm_note)
    if arm is not None and arm.resolved:
        warnings.append(f"{arm.message()} (besides the drift)")
    if drifting.at_bound:
        note = (f"a baseline drift beyond ±{DRIFT_BOUND_S_PER_S * 1e6:g} µS/s (best {rate * 1e6:+.3g} µS/s at the "
                "search's edge): the trials are not usable as they are")
        return replace(fitted, drift_s_per_s=rate, drift_tau_s=tau_b, warnings=(*warnings, note),
                       degenerate_reasons=(*fitted.degenerate_reasons, note))
    return replace(fitted, drift_s_per_s=rate, drift_tau_s=tau_b, warnings=tuple(warnings))


def _with_baseline_uncertainty(cal: SensorCalibration, fit_trials: Sequence[FitTrial], area_m2: float,
                               phys: PhysicsConstants, saturation_s: float | None, rate: float, tau_b: float,
                               cov: np.ndarray) -> SensorCalibration:
    """``cal`` (fitted with the baseline held at ``rate``, ``tau_b``) with its intervals widened by the baseline's
    own uncertainty (``cov``: its covariance in (rate, ln τb)): the fits are repeated with the baseline moved by one
    standard deviation along each principal axis of ``cov``, from ``cal``'s parameters, and each parameter's shift
    is added in quadrature to its standard error (per trial, joint, force trend). Held fixed, a baseline measured
    from the same trials made their intervals too narrow (per trial 91.8 %, joint 83 % on fresh drifting sensors)."""
    values, vectors = np.linalg.eigh(np.atleast_2d(cov))
    moves = [math.sqrt(v) * vectors[:, k] for k, v in enumerate(values) if v > 0 and math.isfinite(v)]
    if not moves:
        return cal
    z = 1.959964  # the intervals' t quantile at these degrees of freedom
    live = [i for i, r in enumerate(cal.trials) if r.refused is None]
    trial_shift = [dict.fromkeys(PARAM_NAMES, 0.0) for _ in cal.trials]
    joint_shift = dict.fromkeys(PARAM_NAMES, 0.0)
    trend_shift = dict.fromkeys(cal.trend_ci95, 0.0)
    for move in moves:
        moved_rate = rate + float(move[0])
        moved_tau = tau_b * math.exp(float(move[1])) if move.size > 1 else tau_b
        moved = [replace(t, offset_s=_drift_offset(t, moved_rate, moved_tau)) for t in fit_trials]
        try:
            per_trial = fit_output_scipy([moved[i] for i in live], area_m2, phys,
                                         [cal.trials[i].params for i in live], "per_trial",
                                         saturation_s=saturation_s, min_force_fraction=MIN_FORCE_FRACTION)
            joint = fit_output_scipy(moved, area_m2, phys, cal.sls, "joint", saturation_s=saturation_s,
                                     min_force_fraction=MIN_FORCE_FRACTION)
            trend = (fit_output_scipy(moved, area_m2, phys, cal.sls, "trend", saturation_s=saturation_s,
                                      min_force_fraction=MIN_FORCE_FRACTION) if cal.sls_trend is not None else None)
        except (ValueError, ArithmeticError):
            return replace(cal, warnings=(*cal.warnings, "the baseline's own uncertainty could not be carried into "
                                          "the intervals (a refit failed): they are too narrow"))
        for j, i in enumerate(live):
            for name in PARAM_NAMES:
                shift = math.log(float(getattr(per_trial.params[j], name)) / float(getattr(cal.trials[i].params, name)))
                trial_shift[i][name] += shift * shift
        assert joint.ref is not None
        for name in PARAM_NAMES:
            shift = math.log(float(getattr(joint.ref, name)) / float(getattr(cal.sls, name)))
            joint_shift[name] += shift * shift
        if trend is not None and trend.trend is not None and cal.sls_trend is not None:
            for name in PARAM_NAMES:
                for k, part in enumerate(("intercept", "slope")):
                    if f"{name}.{part}" in trend_shift:
                        shift = trend.trend[name][k] - cal.sls_trend[name][k]
                        trend_shift[f"{name}.{part}"] += shift * shift

    def widen_log(value: float, interval: tuple[float, float], extra: float) -> tuple[float, float]:
        lo, hi = interval
        if not (lo > 0 and math.isfinite(hi) and value > 0):
            return interval
        half = math.sqrt((math.log(hi / lo) / 2) ** 2 + z * z * extra)
        return (value * math.exp(-half), value * math.exp(half)) if half < 700.0 else (0.0, math.inf)

    trials = []
    for i, report in enumerate(cal.trials):
        if report.refused is not None:
            trials.append(report)
            continue
        ci = {name: widen_log(float(getattr(report.params, name)), report.ci95[name], trial_shift[i][name])
              for name in PARAM_NAMES}
        trials.append(replace(report, ci95={**report.ci95, **ci}))
    joint_ci = {**cal.sls_ci95, **{name: widen_log(float(getattr(cal.sls, name)), cal.sls_ci95[name],
                                                   joint_shift[name]) for name in PARAM_NAMES}}
    trend_ci = dict(cal.trend_ci95)
    for key, extra in trend_shift.items():
        lo, hi = trend_ci[key]
        centre, half = (lo + hi) / 2, (hi - lo) / 2
        half = math.sqrt(half * half + z * z * extra)
        trend_ci[key] = (centre - half, centre + half)
    return replace(cal, trials=tuple(trials), sls_ci95=joint_ci, trend_ci95=trend_ci)


def _trend_tau(fit: OutputFit) -> float:
    """τ (s) of a force-trend fit at its reference force."""
    return float(fit.ref.tau_s) if fit.ref is not None else math.nan


def _settling_fit(fit_trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, start: SLSParams,
                  saturation_s: float | None, drifting: OutputFit) -> OutputFit | None:
    """The force-trend fit with a settling baseline (:func:`models.fit_output.baseline_offset`), or None when the
    baseline does not settle within what the records resolve (its τb at the search range's upper end is the linear
    drift, at its lower a jump at the start) or the fit fails.

    Its start: with the drift fit's SLS parameters held, the best settling baseline for each τb on a grid over the
    search range is one weighted linear least-squares problem in its rate (samples read as numbers; no model run
    per τb). A best τb at the grid's top is a linear drift: no full fit is made (a drifting sensor costs nothing
    more)."""
    span = float(max(t.time_s[-1] - t.time_s[0] for t in fit_trials))
    taus = span * np.exp(np.linspace(*SETTLING_LOG_TAU_BOUNDS, 41))
    gg = np.zeros(taus.size)
    gr = np.zeros(taus.size)
    for trial, params in zip(fit_trials, drifting.params):
        force = np.nan_to_num(np.asarray(trial.force_n, dtype=np.float64), nan=0.0)
        model = np.asarray(conductance_from_force(trial.time_s, force, params, area_m2, phys, overstrain="clamp"),
                           dtype=np.float64)
        y = np.asarray(trial.conductance_s, dtype=np.float64)
        used = np.isfinite(y) & np.isfinite(model) & (force >= MIN_FORCE_FRACTION * trial.hold_force_n)
        if saturation_s is not None:
            used &= y < saturation_s * (1 - 1e-12)
        if not used.any():
            continue
        counts = np.ones(y.size) if trial.counts is None else np.asarray(trial.counts, dtype=np.float64)
        weight2 = counts[used] / float(np.median(y[used])) ** 2
        elapsed = (np.asarray(trial.time_s, dtype=np.float64) - float(trial.time_s[0]))[used]
        shape = taus[None, :] * -np.expm1(-elapsed[:, None] / taus[None, :])  # (N, K): the baseline per unit rate
        gg += np.einsum("n,nk,nk->k", weight2, shape, shape)
        gr += (weight2 * (y - model)[used]) @ shape
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = np.where(gg > 0, gr * gr / gg, 0.0)  # the cost each τb's best rate removes
    best = int(np.argmax(gain))
    if best >= taus.size - 1 or not gain[best] > 0:
        return None
    try:
        fit = fit_output_scipy(fit_trials, area_m2, phys, start, "trend", saturation_s=saturation_s,
                               min_force_fraction=MIN_FORCE_FRACTION, settling=True,
                               baseline_start=(float(gr[best] / gg[best]), float(taus[best])))
    except (ValueError, ArithmeticError):
        return None
    log_tau = math.log(fit.drift_tau_s / span)
    inside = SETTLING_LOG_TAU_BOUNDS[0] + 0.01 < log_tau < SETTLING_LOG_TAU_BOUNDS[1] - 0.01
    return fit if inside and math.isfinite(fit.drift_tau_ci95[1]) else None


def _n_censored(trial: TrialInput, saturation_s: float | None) -> int:
    """Raw samples of ``trial`` at the readout's ceiling (censored; an averaged sample counts as those it stands
    for)."""
    if saturation_s is None:
        return 0
    at = trial.conductance_s >= saturation_s * (1 - 1e-12)
    return int(np.count_nonzero(at)) if trial.counts is None else int(round(float(np.sum(trial.counts[at]))))


def likelihood_ratio(simpler: OutputFit, richer: OutputFit) -> float:
    """The likelihood ratio (χ²) of ``richer`` over ``simpler``, two fits of the same samples: the drop in cost over
    the richer fit's residual variance of the samples read as numbers (:attr:`OutputFit.residual_variance`); 0 when
    it is not lower. The cost's censored part is already a log-likelihood in those units (the Tobit residual), so
    the ratio holds with samples at the readout's ceiling; ``N·ln(cost₀/cost₁)`` counted them as noise draws with
    residuals near 0 and read a drift of −5e-5 µS/s into drift-free 1 kHz records at the ceiling."""
    cost0, cost1 = float(sum(simpler.cost_per_trial)), float(sum(richer.cost_per_trial))
    variance = richer.residual_variance
    if not (math.isfinite(cost0) and math.isfinite(cost1) and variance > 0) or not cost0 > cost1:
        return 0.0
    return (cost0 - cost1) / variance
