"""Output-error fit of the SLS parameters in the measured conductance domain (NUMERICS pitfalls 4–5).

The residual is ``model conductance − measured conductance``, where the model is the project's forward model
(:func:`models.sls.conductance_from_force`: the SLS creep recursion driven by the *measured* force, then Eq. 3 with
the contact term). Parameters are searched in log space, scaled to O(1) by the starting values.

Three shapes of problem, all through one residual machinery:

* ``joint`` — one parameter set for all trials of a sensor (what ``estimate`` uses, ``sls``);
* ``trend`` — each parameter linear in the trial's hold force, ``P(F) = P_ref·(1 + u·(F − F_ref)/F_ref)``
  (the paper's observation; reported as ``[intercept, slope_per_N]``, ``sls_trend``);
* ``per_trial`` — independent parameters for every trial (the per-trial table), solved as one block-diagonal
  problem so each Jacobian costs 4 batched model runs however many trials there are.

Two solvers: :func:`fit_output_scipy` (``scipy.optimize.least_squares`` with a batched finite-difference Jacobian:
all Jacobian columns come from one model run over extra columns) and :func:`fit_output_casadi` (a CasADi step
``Function`` rolled out with ``mapaccum``, exact AD Jacobian, Gauss–Newton Hessian for ipopt or
``sqpmethod``+``qrqp``, or a damped Gauss–Newton loop on the CasADi residual/Jacobian). They agree to ≤ 1e-8; the
scipy path measured 2–3× faster for these 3–6 parameter joint fits (CasADi pays ~0.15 s to build its graph), so
it is the default in :mod:`models.calibration` and CasADi is the cross-check (benchmarks/bench_fitters.py). casadi is imported
inside the function, never at module import.

Samples are weighted in units of the trial's typical conductance, times √(raw samples each one averages) for a
block-averaged record (``FitTrial.counts``); samples below ``min_force_fraction`` of the hold force are left out
(the contact term makes the model singular at F → 0 and the readout there is noise); NaN samples are skipped;
samples at or above ``saturation_s`` are censored (they only say "at least this much"). A censored sample enters
with its censored-normal (Tobit) likelihood, ``−log Φ((model − ceiling)/σ)`` written as a residual
``σ·√(−2 log Φ)``, σ the trial's noise: near the ceiling the noise decides which samples come out as numbers, so
those that do are biased low, and only the likelihood of both kinds together is unbiased (a one-sided penalty
``min(model − ceiling, 0)`` made E1 2–4 standard errors high on trials a quarter saturated; the residual tends to
it as σ → 0). The residual variance and the rms misfit come from the uncensored samples. Uncertainties come from
the Jacobian at the solution (Gauss–Newton covariance scaled by the residual variance) as 95 % intervals.

Pure numerics: any thread may call these; nothing is shared between calls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special
from scipy.optimize import least_squares, minimize_scalar

from models.physics import PhysicsConstants
from models.sls import SLSParams, conductance_from_force

PARAM_NAMES = ("E0_Pa", "E1_Pa", "mu1_Pa_s")
MODES = ("joint", "trend", "per_trial")
LOG_PARAM_BOUND = math.log(1e6)  # log-parameters stay within 10^±6 of the starting scale
_FD_STEP = 1e-7  # relative step in the log-parameters: ~√eps, the model is smooth
_COST_CHUNK_SAMPLES = 1_000_000  # model samples (columns × time steps) per batched candidate run in trial_costs


@dataclass(frozen=True)
class FitTrial:
    """One trial as the fitters see it: time (s), measured force (N), measured conductance (S), hold force (N)."""

    name: str
    time_s: np.ndarray
    force_n: np.ndarray
    conductance_s: np.ndarray
    hold_force_n: float
    counts: np.ndarray | None = None  # raw samples each sample averages (weighted by √count); None: one each
    # A known additive part of the reading (S, per sample), e.g. a baseline drift d·t already measured: the model's
    # conductance plus it is what is compared with the reading and with the readout's ceiling (so a censored sample
    # stays censored at the ceiling the board had, whatever the drift). None: nothing added.
    offset_s: np.ndarray | None = None
    # Per sample, Σ(reading − mean)² (S²) of the raw read samples it averages where the block reached the readout's
    # ceiling (models.calibration.decimate_trial; NaN elsewhere): in the residual variance those samples count as the
    # raw samples they were (their mean alone is biased low by the censoring). None: no such sample.
    within_ss: np.ndarray | None = None
    noise_s: float | None = None  # the raw samples' noise (S), measured before averaging; None: from the samples


# A baseline drift fitted with the force trend (fit_output_scipy(drift=True)): θ's last entry in units of this rate
# (S/s), bounded to ±DRIFT_BOUND_S_PER_S.
DRIFT_SCALE_S_PER_S = 1e-7
DRIFT_BOUND_S_PER_S = 2e-6
# A settling baseline (fit_output_scipy(settling=True)): ``d·τb·(1 − e^(−t/τb))``, d its rate at the trial's start
# (as the drift's), τb its time constant as θ's last entry, ln(τb / the longest record) within these bounds; τb → ∞
# is the linear drift d·t, so the two nest (one parameter more).
SETTLING_LOG_TAU_BOUNDS = (math.log(0.01), math.log(1000.0))


def baseline_offset(elapsed_s: np.ndarray, rate_s_per_s: float, tau_s: float = math.inf) -> np.ndarray:
    """A baseline's part of each reading (S) at ``elapsed_s`` (s from the trial's start): ``rate·t`` (a linear drift,
    ``tau_s`` infinite) or ``rate·τ·(1 − e^(−t/τ))`` (a baseline settling with time constant τ; its rate at the start
    is ``rate``, its total change ``rate·τ``)."""
    elapsed = np.asarray(elapsed_s, dtype=np.float64)
    if not math.isfinite(tau_s):
        return rate_s_per_s * elapsed
    return rate_s_per_s * tau_s * -np.expm1(-elapsed / tau_s)


@dataclass(frozen=True)
class OutputFit:
    """Result of an output-error fit.

    ``params`` holds one :class:`SLSParams` per trial (all equal for ``joint``); ``ref`` is the ``joint``/``trend``
    parameter set at ``ref_force_n``. ``trend`` maps each name of :data:`PARAM_NAMES` to ``(intercept, slope_per_N)``
    (``trend`` mode only). ``ci95`` maps each reported quantity to its (low, high) 95 % interval: for ``joint`` the
    names of :data:`PARAM_NAMES`; for ``trend`` ``"<name>.intercept"``, ``"<name>.slope"`` and
    ``"<name>.at_ref_force"``; for ``per_trial`` ``ci95_per_trial`` holds one
    such dict per trial. ``rmse_s`` per trial (S, over the samples used). ``n_censored`` saturated samples were
    treated as one-sided. ``warnings`` are for the user.
    """

    mode: str
    params: tuple[SLSParams, ...]
    ref: SLSParams | None
    ref_force_n: float
    trend: dict[str, tuple[float, float]] | None
    ci95: dict[str, tuple[float, float]]
    ci95_per_trial: tuple[dict[str, tuple[float, float]], ...]
    rmse_s: tuple[float, ...]
    n_used: tuple[int, ...]
    n_censored: int
    iterations: int
    success: bool
    message: str
    solver: str
    at_bound: bool = False
    warnings: tuple[str, ...] = field(default_factory=tuple)
    cost_per_trial: tuple[float, ...] = ()  # weighted residual sum of squares per trial (see trial_costs)
    drift_s_per_s: float = 0.0  # the baseline drift fitted with the parameters (S/s; drift=True), else 0
    drift_ci95: tuple[float, float] = (0.0, 0.0)  # its 95 % interval (S/s)
    # The residual variance (weighted units, as cost_per_trial) of the samples read as numbers, per degree of freedom:
    # the scale of a likelihood ratio, (cost₀ − cost₁)/residual_variance (a censored sample's residual is not a noise
    # draw: dividing by the count of all samples made such ratios several times too large near the ceiling).
    residual_variance: float = math.nan
    # A settling baseline (settling=True): its time constant (s; inf: the linear drift) and 95 % interval; the
    # rate above is then its rate at the trial's start (models.fit_output.baseline_offset).
    drift_tau_s: float = math.inf
    drift_tau_ci95: tuple[float, float] = (math.inf, math.inf)
    # The baseline's covariance: 1×1 (its rate, (S/s)²) or 2×2 with ln τb (settling); None without a baseline.
    drift_cov: np.ndarray | None = None
    # ``per_trial`` only: each trial's 3×3 covariance of its log-parameters (ln E0, ln E1, ln μ1; scaled by its
    # residual variance), that residual variance (weighted units, as cost_per_trial) and the t quantile of its
    # 95 % intervals: what models.calibration checks its intervals' ends against.
    cov_per_trial: tuple[np.ndarray, ...] = ()
    variance_per_trial: tuple[float, ...] = ()
    t_per_trial: tuple[float, ...] = ()


def _start_scale(start: SLSParams | Sequence[SLSParams], n_trials: int, mode: str) -> np.ndarray:
    """θ's scale: the starting parameters (Pa, Pa, Pa·s), (T, 3) per trial or (3,) shared. ValueError if unusable."""
    starts = [start] * n_trials if isinstance(start, SLSParams) else list(start)
    if len(starts) != n_trials:
        raise ValueError("per-trial starting values: one per trial")
    if mode == "per_trial":
        scale = np.array([[float(getattr(s, n)) for n in PARAM_NAMES] for s in starts])  # (T, 3)
    else:
        scale = np.array([float(getattr(starts[0], n)) for n in PARAM_NAMES])  # (3,)
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"starting parameters must be positive and finite, got {scale}")
    return scale


def _theta_layout(mode: str, n_trials: int, hold_n: np.ndarray, ref_force_n: float) -> tuple[int, list[list[int]]]:
    """The length of θ and its groups of components no two of which touch the same residual (one batched model run
    per group)."""
    if mode == "joint":
        return 3, [[0], [1], [2]]
    if mode == "trend":
        if np.ptp(hold_n) <= 1e-6 * ref_force_n:
            raise ValueError("a force trend needs trials at two or more different forces")
        return 6, [[i] for i in range(6)]
    return 3 * n_trials, [[3 * t + j for t in range(n_trials)] for j in range(3)]


def _theta_bounds(mode: str, n_params: int, hold_n: np.ndarray, ref_force_n: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) bounds on θ."""
    lower = np.full(n_params, -np.inf)
    upper = np.full(n_params, np.inf)
    # Log-parameters stay within 10^±6 of the starting scale: a creep too fast or too slow for the record drives
    # them towards ±∞ (exp overflow → inf parameters); at the bound the fit is reported as degenerate instead.
    log_entries = slice(0, 3) if mode == "trend" else slice(None)
    lower[log_entries], upper[log_entries] = -LOG_PARAM_BOUND, LOG_PARAM_BOUND
    if mode == "trend":
        # u is scaled by F_ref; keep every parameter ≥ 5 % of its reference value over the calibrated forces.
        span_up = (hold_n.max() - ref_force_n) / ref_force_n
        span_down = (ref_force_n - hold_n.min()) / ref_force_n
        lower[3:] = -0.95 / span_up if span_up > 0 else -np.inf
        upper[3:] = 0.95 / span_down if span_down > 0 else np.inf
    return lower, upper


def estimate_noise(conductance_s: np.ndarray, counts: np.ndarray | None = None) -> float:
    """Conductance noise std (S) from second differences (robust MAD), insensitive to the slow creep. With
    ``counts`` (samples that average that many raw ones): the raw samples' noise, from runs of equal counts, each
    second difference scaled by √count."""
    finite = np.isfinite(conductance_s)
    c = conductance_s[finite]
    if c.size < 5:
        return math.nan
    d2 = np.diff(c, 2)
    if counts is not None:
        n = np.asarray(counts, dtype=np.float64)[finite]
        same = (n[:-2] == n[1:-1]) & (n[1:-1] == n[2:])
        d2 = d2[same] * np.sqrt(n[1:-1][same])
        if d2.size < 3:
            return math.nan
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def noise_below_ceiling(conductance_s: np.ndarray, counts: np.ndarray | None, ceiling_s: float) -> float:
    """The raw samples' noise (S) of a record that reaches the readout's ceiling. Samples close under the ceiling
    are those the noise kept below it: picked by their own values their scatter is too small (measured: 0.85–0.89 of
    the truth, which biased the censored fit by several standard errors at 100 Hz). So the samples are picked by a
    running mean over :data:`NOISE_SMOOTH_SAMPLES` (hardly moved by any one sample's noise) lying more than 6 s.d.
    below the ceiling, where the censoring has not touched them."""
    c = np.asarray(conductance_s, dtype=np.float64)
    n = np.ones(c.size) if counts is None else np.asarray(counts, dtype=np.float64)
    finite = np.isfinite(c)
    below = finite & (c < ceiling_s * (1 - 1e-12))
    sigma = estimate_noise(c[below], n[below])  # a first scale: too small near the ceiling
    if not sigma > 0 or c.size < NOISE_SMOOTH_SAMPLES:
        return sigma
    kernel = np.ones(NOISE_SMOOTH_SAMPLES)
    total = np.convolve(np.where(finite, c, 0.0), kernel, mode="same")
    count = np.convolve(finite.astype(np.float64), kernel, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = total / count
    far = below & (smooth < ceiling_s - 6.0 * sigma)
    return estimate_noise(c[far], n[far]) if far.sum() >= 20 else sigma


NOISE_SMOOTH_SAMPLES = 25


def censored_noise(trial: FitTrial, params: SLSParams, area_m2: float, phys: PhysicsConstants, saturation_s: float,
                   start_s: float, min_force_fraction: float = 0.05) -> float:
    """The noise σ (S) that makes ``trial``'s readings most likely given the model at ``params`` (the trial's own
    fit), the samples at the ceiling ``saturation_s`` censored (Tobit): ``Σ_read (y − m)²/2σ² + n_read·ln σ −
    Σ_censored ln Φ((m − ceiling)/σ)``, an average of k raw samples counting as k (its spread about its mean
    included where it is known, ``FitTrial.within_ss``; one sample's worth otherwise). Every sample enters, so on a
    trial mostly at the ceiling σ comes from its whole hold, not from the few samples far below the ceiling that a
    difference estimate must pick (those gave 10–14 µS for a true 11.3 µS at 1 % noise, 100 Hz, and a false drift
    in the fit that used them). Searched within a factor e of ``start_s``; ``start_s`` when fewer than 50 raw
    samples are read as numbers or the model cannot be run."""
    force = _hold_last_valid(np.asarray(trial.force_n, dtype=np.float64))
    try:
        model = np.asarray(conductance_from_force(trial.time_s, force, params, area_m2, phys, overstrain="clamp"),
                           dtype=np.float64)
    except ValueError:
        return start_s
    if trial.offset_s is not None:
        model = model + np.asarray(trial.offset_s, dtype=np.float64)
    y = np.asarray(trial.conductance_s, dtype=np.float64)
    used = (np.isfinite(y) & np.isfinite(model) & np.isfinite(trial.force_n)
            & (trial.force_n >= min_force_fraction * trial.hold_force_n))
    counts = np.ones(y.size) if trial.counts is None else np.asarray(trial.counts, dtype=np.float64)
    spread = np.full(y.size, math.nan) if trial.within_ss is None else np.asarray(trial.within_ss, dtype=np.float64)
    at = used & (y >= saturation_s * (1 - 1e-12))
    read = used & ~at
    tracked = read & np.isfinite(spread)
    squares = float(np.sum(counts[read] * (y[read] - model[read]) ** 2) + np.sum(spread[tracked]))
    dof = float(np.sum(np.where(tracked, counts, 1.0)[read]))
    if dof < 50 or not start_s > 0:
        return start_s
    margin, weight = model[at] - censoring_threshold(saturation_s), counts[at]

    def negative_log_likelihood(log_sigma: float) -> float:
        sigma = math.exp(log_sigma)
        return squares / (2 * sigma * sigma) + dof * log_sigma - float(
            np.sum(weight * special.log_ndtr(margin / sigma)))

    best = minimize_scalar(negative_log_likelihood, bounds=(math.log(start_s) - 1, math.log(start_s) + 1),
                           method="bounded", options={"xatol": 1e-5})
    return float(math.exp(best.x)) if best.success else start_s


# A reading at the readout's ceiling (counts = 0) is any true value above the ADC's first transition, half a step
# below 1/R_C: the board rounds to the nearest count (SPEC §4: V = counts/4095 · 3.3 V, C = (V_ref − V)/(V_ref·R_C),
# V_ref 2.5 V), so its step at the ceiling is 3.3/(4095·2.5) of 1/R_C and the censoring threshold lies this share
# below the ceiling. Measured (benchmarks/bench_coverage.py, 100 Hz and 1 kHz at 0.2 % noise, where half a step is
# 0.1 σ and a trial holds 10⁴–10⁵ samples near the ceiling): censored at 1/R_C itself, the trials partly at the
# ceiling read E1 1.5 standard errors low and their intervals held it 75 % of the time.
CEILING_HALF_STEP_SHARE = 0.5 * 3.3 / (4095 * 2.5)


def censoring_threshold(saturation_s: float) -> float:
    """The true conductance (S) above which the readout shows its ceiling ``saturation_s`` (half an ADC step below
    it, :data:`CEILING_HALF_STEP_SHARE`): what a censored sample's likelihood is judged against."""
    return saturation_s * (1.0 - CEILING_HALF_STEP_SHARE)


def _censored_residual(model_s: np.ndarray, ceiling_s: float, noise_s: float) -> np.ndarray:
    """Residual (S) of samples read at the ceiling: ``σ·√(−2 log Φ((model − ceiling)/σ))``, whose square is twice
    the censored sample's negative log-likelihood in the units of the others (Tobit). σ = 0 (noise-free data): the
    one-sided limit ``min(model − ceiling, 0)``."""
    if not noise_s > 0:
        return np.minimum(model_s - ceiling_s, 0.0)
    return noise_s * np.sqrt(-2.0 * special.log_ndtr((model_s - ceiling_s) / noise_s))


def _residual_masks(trials: Sequence[FitTrial], saturation_s: float | None, min_force_fraction: float
                    ) -> tuple[list[np.ndarray], list[np.ndarray], list[float]]:
    """Per trial: the samples in the residual (finite, under load), those censored at the readout's saturation, and
    the weight 1/typical conductance. ValueError naming a trial with no usable sample."""
    masks: list[np.ndarray] = []
    censored: list[np.ndarray] = []
    weights: list[float] = []
    for trial in trials:
        y = trial.conductance_s
        usable = np.isfinite(y) & np.isfinite(trial.force_n) & (
            trial.force_n >= min_force_fraction * trial.hold_force_n)
        sat = usable & (y >= saturation_s * (1 - 1e-12)) if saturation_s is not None else np.zeros_like(usable)
        masks.append(usable)
        censored.append(sat)
        typical = float(np.median(y[usable])) if usable.any() else 0.0
        if not typical > 0:
            raise ValueError(f"{trial.name}: no usable conductance samples under load (flat or disconnected)")
        weights.append(1.0 / typical)
    return masks, censored, weights


def _shared_time_grids(trials: Sequence[FitTrial]) -> list[list[int]]:
    """Indices of trials grouped by identical time grids: each group runs through the forward model as columns of
    one call."""
    groups: list[list[int]] = []
    for i, trial in enumerate(trials):
        for group in groups:
            first = trials[group[0]].time_s
            if first.shape == trial.time_s.shape and np.array_equal(first, trial.time_s):
                group.append(i)
                break
        else:
            groups.append([i])
    return groups


class _Problem:
    """The parameterisation θ ↔ per-trial SLS parameters and the weighted, masked residual."""

    def __init__(self, trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, start: SLSParams
                 | Sequence[SLSParams], mode: str, saturation_s: float | None, min_force_fraction: float,
                 interp: str, fit_drift: bool = False, settling: bool = False) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        fit_drift = fit_drift or settling
        if fit_drift and mode == "per_trial":
            raise ValueError("a common baseline drift is fitted with the joint or trend parameters, not per trial")
        if not trials:
            raise ValueError("no trials to fit")
        self.trials = list(trials)
        self.area_m2 = float(area_m2)
        self.phys = phys
        self.mode = mode
        self.interp = interp
        self.scale = _start_scale(start, len(self.trials), mode)
        self.hold_n = np.array([t.hold_force_n for t in self.trials])
        self.ref_force_n = float(np.mean(self.hold_n))
        self.n_params, self.groups = _theta_layout(mode, len(self.trials), self.hold_n, self.ref_force_n)
        self.bounds = _theta_bounds(mode, self.n_params, self.hold_n, self.ref_force_n)
        # A common baseline drift d·t (t from each trial's start) as θ's last entry: it moves no model state, so its
        # Jacobian column comes from the residuals alone (no model run).
        self.fit_drift = fit_drift
        self.settling = settling
        self.n_baseline = 0
        if fit_drift:
            self.n_params += 1
            limit = DRIFT_BOUND_S_PER_S / DRIFT_SCALE_S_PER_S
            self.bounds = (np.append(self.bounds[0], -limit), np.append(self.bounds[1], limit))
            self.n_baseline = 1
        if settling:  # and its time constant, as ln(τb / the longest record)
            self.n_params += 1
            self.bounds = (np.append(self.bounds[0], SETTLING_LOG_TAU_BOUNDS[0]),
                           np.append(self.bounds[1], SETTLING_LOG_TAU_BOUNDS[1]))
            self.n_baseline = 2
        self.elapsed_s = [np.asarray(t.time_s, dtype=np.float64) - float(t.time_s[0]) for t in self.trials]
        self.span_s = float(max(e[-1] for e in self.elapsed_s)) or 1.0
        self.masks, self.censored, self.weights = _residual_masks(self.trials, saturation_s, min_force_fraction)
        self.saturation_s = saturation_s
        # A dropped force sample is held at the last valid value (what models.sls does with NaN), so the creep state
        # is not disturbed by a fake unloading; the sample itself is masked out of the residual above.
        self.forces = [_hold_last_valid(t.force_n) for t in self.trials]
        self.grid_groups = _shared_time_grids(self.trials)
        self.n_used = tuple(int(m.sum()) for m in self.masks)
        self.n_residuals = int(sum(self.n_used))
        # Per trial: the samples read as numbers (among the used ones) and the noise of those, for the censored
        # likelihood and for the residual variance.
        self.uncensored = [~c[m] for c, m in zip(self.censored, self.masks)]
        self.noise_s = [(t.noise_s if t.noise_s is not None else
                         noise_below_ceiling(t.conductance_s[m], None if t.counts is None else t.counts[m],
                                             float(saturation_s))) if c.any() and saturation_s is not None else math.nan
                        for t, m, c in zip(self.trials, self.masks, self.censored)]
        # Samples that average the read samples of a block at the ceiling: their spread about the mean (weighted
        # units) and the degrees of freedom it adds, per trial (see FitTrial.within_ss).
        self.within_ss, self.within_dof = [], []
        for t, m, u, w in zip(self.trials, self.masks, self.uncensored, self.weights):
            spread = (np.full(int(m.sum()), math.nan) if t.within_ss is None
                      else np.asarray(t.within_ss, dtype=np.float64)[m])
            tracked = np.isfinite(spread) & u
            counts = np.ones(spread.size) if t.counts is None else np.asarray(t.counts, dtype=np.float64)[m]
            self.within_ss.append(float(np.sum(spread[tracked])) * w * w)
            self.within_dof.append(int(round(float(np.sum(counts[tracked] - 1.0)))))
        # Per used sample: the trial's weight × √(raw samples it averages) — every residual then has the raw
        # samples' noise, and an average of k counts as the k samples it stands for.
        self.sample_weights = [w * (np.ones(int(m.sum())) if t.counts is None
                                    else np.sqrt(np.asarray(t.counts, dtype=np.float64)[m]))
                               for t, m, w in zip(self.trials, self.masks, self.weights)]

    # -- θ → parameters ----------------------------------------------------------------------------------------
    def params_array(self, theta: np.ndarray) -> np.ndarray:
        """(T, 3) physical parameters (Pa, Pa, Pa·s) for θ."""
        n_trials = len(self.trials)
        if self.mode == "joint":
            return np.tile(self.scale * np.exp(theta[:3]), (n_trials, 1))
        if self.mode == "trend":
            ref = self.scale * np.exp(theta[:3])
            factor = 1.0 + np.outer((self.hold_n - self.ref_force_n) / self.ref_force_n, theta[3:6])
            return ref * factor
        return self.scale * np.exp(theta.reshape(n_trials, 3))

    def touches(self, index: int) -> list[int]:
        """Trials whose residuals depend on θ[index]."""
        if self.mode == "per_trial":
            return [index // 3]
        return list(range(len(self.trials)))

    # -- model runs ----------------------------------------------------------------------------------------------
    def conductance(self, params: np.ndarray) -> list[np.ndarray]:
        """Model conductance per trial for parameter arrays ``params`` (T, K, 3): K columns per trial → (N_t, K)."""
        out: list[np.ndarray] = [np.empty(0)] * len(self.trials)
        n_cols = params.shape[1]
        for group in self.grid_groups:
            t_s = self.trials[group[0]].time_s
            force = np.repeat(np.column_stack([self.forces[i] for i in group]), n_cols, axis=1)
            p = params[group].reshape(-1, 3)
            sls = SLSParams(p[:, 0].copy(), p[:, 1].copy(), p[:, 2].copy())
            # An optimiser's trial step may overstrain the model (ε ≥ 1): clamp, so the step is simply rejected by its
            # large residual instead of aborting the fit.
            c = np.asarray(conductance_from_force(t_s, force, sls, self.area_m2, self.phys, interp=self.interp,
                                                  overstrain="clamp"))
            c = c.reshape(t_s.shape[0], len(group), n_cols)
            for j, i in enumerate(group):
                out[i] = c[:, j, :]
        return out

    def drift_of(self, theta: np.ndarray) -> tuple[float, float]:
        """The baseline θ holds: (its rate at the trial's start, S/s; its settling time constant, s — inf for a linear
        drift); (0, inf) unless ``fit_drift``."""
        if not self.fit_drift:
            return 0.0, math.inf
        if self.settling:
            return float(theta[-2]) * DRIFT_SCALE_S_PER_S, self.span_s * math.exp(float(theta[-1]))
        return float(theta[-1]) * DRIFT_SCALE_S_PER_S, math.inf

    def residual_blocks(self, model: list[np.ndarray], drift: tuple[float, float] = (0.0, math.inf)
                        ) -> list[np.ndarray]:
        """Weighted residual per trial for the model columns (N_used, K), the trial's known offset and a baseline
        ``drift`` = (rate, S/s; settling time constant, s: :func:`baseline_offset`) added to the model (it is the
        reading, ceiling included, that they are part of)."""
        blocks = []
        for i, trial in enumerate(self.trials):
            mask = self.masks[i]
            m = model[i][mask]
            if trial.offset_s is not None:
                m = m + np.asarray(trial.offset_s, dtype=np.float64)[mask][:, None]
            if drift[0]:
                m = m + baseline_offset(self.elapsed_s[i][mask], *drift)[:, None]
            y = trial.conductance_s[mask][:, None]
            r = m - y
            sat = self.censored[i][mask]
            if sat.any() and self.saturation_s is not None:
                # Censored: the true value is ≥ the ceiling (the module docstring).
                r[sat] = _censored_residual(m[sat], censoring_threshold(self.saturation_s), self.noise_s[i])
            blocks.append(r * self.sample_weights[i][:, None])
        return blocks

    def residual(self, theta: np.ndarray) -> np.ndarray:
        model = self.conductance(self.params_array(theta)[:, None, :])
        return np.concatenate([b[:, 0] for b in self.residual_blocks(model, self.drift_of(theta))])

    def residual_and_jacobian(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual and its forward-difference Jacobian from 1 + len(groups) batched model columns."""
        columns = [self.params_array(theta)]
        for group in self.groups:
            shifted = theta.copy()
            shifted[group] += _FD_STEP
            columns.append(self.params_array(shifted))
        drift = self.drift_of(theta)
        model = self.conductance(np.stack(columns, axis=1))
        blocks = self.residual_blocks(model, drift)
        offsets = np.concatenate([[0], np.cumsum([b.shape[0] for b in blocks])])
        residual = np.concatenate([b[:, 0] for b in blocks])
        jac = np.zeros((residual.size, self.n_params))
        for k in range(self.n_params - self.n_baseline, self.n_params):
            # The baseline moves no model state: its columns come from the residuals alone (no model run).
            step = _FD_STEP * max(1.0, abs(float(theta[k])))
            shifted = theta.copy()
            shifted[k] += step
            shifted_blocks = self.residual_blocks([m[:, :1] for m in model], self.drift_of(shifted))
            jac[:, k] = (np.concatenate([b[:, 0] for b in shifted_blocks]) - residual) / step
        for g, group in enumerate(self.groups):
            for index in group:
                for i in self.touches(index):
                    rows = slice(offsets[i], offsets[i + 1])
                    jac[rows, index] = (blocks[i][:, g + 1] - blocks[i][:, 0]) / _FD_STEP
        return residual, jac

    # -- results -------------------------------------------------------------------------------------------------
    def summarise(self, theta: np.ndarray, residual: np.ndarray, jac: np.ndarray, iterations: int, success: bool,
                  message: str, solver: str) -> OutputFit:
        params = self.params_array(theta)
        per_trial = tuple(SLSParams(*(float(v) for v in row)) for row in params)
        blocks = np.split(residual, np.cumsum(self.n_used)[:-1])
        read = [b[u] for b, u in zip(blocks, self.uncensored)]  # the samples read as numbers
        # Their squares, with the spread within the averaged blocks at the ceiling (as if read sample by sample).
        read_ss = [_sumsq(b) + extra for b, extra in zip(read, self.within_ss)]
        read_n = [b.size + extra for b, extra in zip(read, self.within_dof)]
        rmse = tuple(float(np.sqrt(ss / n) / w) if n else math.nan
                     for ss, n, w in zip(read_ss, read_n, self.weights))
        n_read = int(sum(read_n))
        dof = max(n_read - self.n_params, 1)
        residual_variance = float(sum(read_ss)) / dof
        t_crit = float(special.stdtrit(dof, 0.975))
        edge = np.isclose(theta, self.bounds[0]) | np.isclose(theta, self.bounds[1])
        # A settling time constant at its bound is a baseline that does not settle within the records (or at once):
        # said by the caller, not a parameter at a bound.
        at_bound = bool(np.any(edge[:-1] if self.settling else edge))
        ci: dict[str, tuple[float, float]] = {}
        ci_trials: list[dict[str, tuple[float, float]]] = []
        cov_trials: list[np.ndarray] = []
        variance_trials: list[float] = []
        t_trials: list[float] = []
        warnings: list[str] = []
        ref = None
        trend = None
        if self.mode == "per_trial":
            for i in range(len(self.trials)):
                cols = slice(3 * i, 3 * i + 3)
                rows = slice(int(np.sum(self.n_used[:i])), int(np.sum(self.n_used[: i + 1])))
                j_i, dof_i = jac[rows, cols], max(read_n[i] - 3, 1)
                cov = _covariance(j_i, read_ss[i] / dof_i)
                se = np.sqrt(np.diag(cov))
                t_i = float(special.stdtrit(dof_i, 0.975))
                ci_trials.append({n: _log_interval(float(params[i, k]), t_i * se[k])
                                  for k, n in enumerate(PARAM_NAMES)})
                cov_trials.append(cov)
                variance_trials.append(read_ss[i] / dof_i)
                t_trials.append(t_i)
        else:
            cov = _covariance(jac, residual_variance)
            se = np.sqrt(np.diag(cov))
            ref_values = self.scale * np.exp(theta[:3])
            ref = SLSParams(*(float(v) for v in ref_values))
            for k, n in enumerate(PARAM_NAMES):
                # In trend mode these are the parameters at the reference force (the mean hold force).
                key = n if self.mode == "joint" else f"{n}.at_ref_force"
                ci[key] = _log_interval(float(ref_values[k]), t_crit * se[k])
            if self.mode == "trend":
                trend = {}
                for k, n in enumerate(PARAM_NAMES):
                    u = theta[3 + k]
                    slope = ref_values[k] * u / self.ref_force_n
                    intercept = ref_values[k] * (1 - u)
                    trend[n] = (float(intercept), float(slope))
                    # Delta method with P_ref = s·e^θ: slope = P_ref·u/F_ref, intercept = P_ref·(1 − u).
                    for part, value, d_theta, d_u in (("slope", slope, slope, ref_values[k] / self.ref_force_n),
                                                      ("intercept", intercept, intercept, -ref_values[k])):
                        grad = np.zeros(self.n_params)
                        grad[k], grad[3 + k] = d_theta, d_u
                        with np.errstate(invalid="ignore"):
                            variance = float(grad @ cov @ grad)
                        half = t_crit * math.sqrt(variance) if variance >= 0 else math.inf
                        ci[f"{n}.{part}"] = (float(value - half), float(value + half))
            if not np.all(np.isfinite(se)):
                warnings.append("parameter uncertainty undefined: the Jacobian is singular (parameters not "
                                "identifiable from these trials)")
        if not success:
            warnings.append(f"the optimiser stopped before converging ({message}): the parameters may be off; "
                            "check the trials")
        if at_bound:
            warnings.append("a force-trend slope hit its bound (a parameter would turn non-positive inside the "
                            "calibrated force range): the linear trend does not describe this sensor")
        drift, drift_ci, drift_tau, drift_tau_ci = 0.0, (0.0, 0.0), math.inf, (math.inf, math.inf)
        drift_cov = None
        if self.fit_drift:
            drift, drift_tau = self.drift_of(theta)
            rate_index = self.n_params - self.n_baseline
            half = t_crit * float(np.sqrt(cov[rate_index, rate_index])) * DRIFT_SCALE_S_PER_S
            drift_ci = (drift - half, drift + half) if math.isfinite(half) else (-math.inf, math.inf)
            if self.settling:
                drift_tau_ci = _log_interval(drift_tau, t_crit * float(np.sqrt(cov[-1, -1])))
            units = np.array([DRIFT_SCALE_S_PER_S, 1.0][: self.n_baseline])
            drift_cov = cov[rate_index:, rate_index:] * np.outer(units, units)
        return OutputFit(self.mode, per_trial, ref, self.ref_force_n, trend, ci, tuple(ci_trials), rmse,
                         self.n_used, int(sum(int(c.sum()) for c in self.censored)), iterations, success, message,
                         solver, at_bound, tuple(warnings), tuple(_sumsq(b) for b in blocks), drift, drift_ci,
                         residual_variance, drift_tau, drift_tau_ci, drift_cov, tuple(cov_trials),
                         tuple(variance_trials), tuple(t_trials))


def _hold_last_valid(values: np.ndarray) -> np.ndarray:
    """NaN/inf samples replaced by the last finite value before them (0 before the first)."""
    finite = np.isfinite(values)
    if finite.all():
        return np.asarray(values, dtype=np.float64)
    index = np.where(finite, np.arange(values.size), -1)
    np.maximum.accumulate(index, out=index)
    return np.where(index >= 0, values[np.maximum(index, 0)], 0.0)


def _sumsq(x: np.ndarray) -> float:
    """Σx² without a BLAS call (a threaded BLAS dot on a vector is slow on a busy machine)."""
    return float(np.sum(x * x))


def _log_interval(value: float, half_width_log: float) -> tuple[float, float]:
    """``value·e^(∓w)``: a 95 % interval from a half-width ``w`` in log-parameter space. An unidentified parameter
    (w huge or inf) gets (0, inf) rather than an overflow."""
    if not half_width_log < 700.0:
        return (0.0, math.inf)
    return (value * math.exp(-half_width_log), value * math.exp(half_width_log))


def _covariance(jac: np.ndarray, sigma2: float) -> np.ndarray:
    """σ²·(JᵀJ)⁻¹ via the SVD of J (never forming JᵀJ); inf on the diagonal where J is rank-deficient."""
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    if s.size == 0 or not s[-1] > s[0] * 1e-12:
        return np.full((jac.shape[1], jac.shape[1]), np.inf)
    return (vt.T / s**2) @ vt * sigma2


def _damped_step(r: np.ndarray, j: np.ndarray, damping: float) -> np.ndarray:
    """Levenberg–Marquardt step with Marquardt's diagonal scaling, as an augmented least-squares problem (JᵀJ is
    never formed)."""
    diag = np.sqrt(np.einsum("ij,ij->j", j, j)) + 1e-300
    augmented = np.vstack([j, math.sqrt(damping) * np.diag(diag)])
    return -np.linalg.lstsq(augmented, np.concatenate([r, np.zeros(j.shape[1])]), rcond=None)[0]


def _block_levenberg_marquardt(problem: _Problem, max_iter: int) -> tuple[np.ndarray, int, bool, str]:
    """Per-trial fits as independent 3-parameter LM problems advanced together: one batched model run evaluates
    every trial's candidate, each trial keeps its own damping and stops on its own. Exact 3×3 steps, no dense SVD
    of the whole block-diagonal Jacobian."""
    n_trials = len(problem.trials)
    bounds = np.concatenate([[0], np.cumsum(problem.n_used)])
    rows = [slice(bounds[i], bounds[i + 1]) for i in range(n_trials)]

    def split(theta_flat: np.ndarray):
        r, j = problem.residual_and_jacobian(theta_flat)
        return [r[rows[i]] for i in range(n_trials)], [j[rows[i], 3 * i:3 * i + 3] for i in range(n_trials)]

    theta = np.zeros((n_trials, 3))
    r_blocks, j_blocks = split(theta.ravel())
    cost = np.array([_sumsq(r) for r in r_blocks])
    damping = np.full(n_trials, 1e-3)
    active = np.ones(n_trials, dtype=bool)
    failed = np.zeros(n_trials, dtype=bool)
    iteration = 0
    while iteration < max_iter:
        iteration += 1
        candidate = theta.copy()
        predicted = np.zeros(n_trials)
        for i in np.flatnonzero(active):
            delta = _damped_step(r_blocks[i], j_blocks[i], damping[i])
            linear = r_blocks[i] + j_blocks[i] @ delta
            predicted[i] = cost[i] - _sumsq(linear)
            if predicted[i] <= 1e-14 * cost[i] or np.max(np.abs(delta)) < 1e-10:
                active[i] = False
            else:
                candidate[i] = np.clip(theta[i] + delta, problem.bounds[0][3 * i:3 * i + 3],
                                       problem.bounds[1][3 * i:3 * i + 3])
        if not active.any():
            break
        r_new = problem.residual(candidate.ravel())
        accepted = False
        for i in np.flatnonzero(active):
            block = r_new[rows[i]]
            cost_new = _sumsq(block)
            if np.isfinite(cost_new) and cost_new < cost[i]:
                gain = (cost[i] - cost_new) / predicted[i]
                theta[i] = candidate[i]
                damping[i] = max(damping[i] * (0.1 if gain > 0.75 else 1.0 if gain > 0.25 else 4.0), 1e-9)
                accepted = True
            else:
                damping[i] *= 10.0
                if damping[i] > 1e10:
                    active[i] = False
                    failed[i] = True
        if accepted:
            r_blocks, j_blocks = split(theta.ravel())
            cost = np.array([_sumsq(r) for r in r_blocks])
    if failed.any():
        return theta.ravel(), iteration, False, f"no decrease for trial(s) {np.flatnonzero(failed).tolist()}"
    if active.any():
        return theta.ravel(), iteration, False, f"stopped after {max_iter} iterations"
    return theta.ravel(), iteration, True, "converged"


def trial_costs(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants,
                candidates: Sequence[SLSParams], *, saturation_s: float | None = None,
                min_force_fraction: float = 0.05, interp: str = "hold") -> np.ndarray:
    """(K, T) weighted residual sum of squares of each candidate parameter set on each trial, from one batched model
    run (the candidates are extra columns). Used to pick starting values that are not on a plateau."""
    problem = _Problem(trials, area_m2, phys, candidates[0], "joint", saturation_s, min_force_fraction, interp)
    params = np.array([[float(getattr(c, n)) for n in PARAM_NAMES] for c in candidates])
    # Candidates in chunks of ≤ _COST_CHUNK_SAMPLES model samples per call: the batched run's temporaries scale with
    # columns × samples (40 candidates × 12 trials × 11 000 samples was ~0.3 GB at once).
    n_samples = sum(t.time_s.size for t in problem.trials)
    chunk = max(1, _COST_CHUNK_SAMPLES // max(n_samples, 1))
    costs = np.empty((len(candidates), len(problem.trials)))
    for lo in range(0, len(candidates), chunk):
        part = params[lo:lo + chunk]
        stacked = np.broadcast_to(part[None, :, :], (len(problem.trials), part.shape[0], 3))
        blocks = problem.residual_blocks(problem.conductance(np.ascontiguousarray(stacked)))
        costs[lo:lo + part.shape[0]] = [[_sumsq(block[:, k]) for block in blocks] for k in range(part.shape[0])]
    return costs


def fit_output_scipy(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants,
                     start: SLSParams | Sequence[SLSParams], mode: str = "joint", *,
                     saturation_s: float | None = None, min_force_fraction: float = 0.05, interp: str = "hold",
                     max_nfev: int = 100, drift: bool = False, settling: bool = False,
                     baseline_start: tuple[float, float] | None = None) -> OutputFit:
    """Output-error fit with ``scipy.optimize.least_squares`` (trust-region reflective, bounded for ``trend``);
    ``per_trial`` runs a block Levenberg–Marquardt instead (independent 3×3 steps per trial, one batched model run
    per iteration), which is ~10× faster than a dense trust-region solve of the block-diagonal problem.

    ``start``: one starting :class:`SLSParams` (or one per trial for ``per_trial``), e.g. from the derivative-free
    estimate; it also sets the O(1) scaling. ``area_m2`` in m². ``drift``: a baseline drift ``d·t`` common to all
    trials is fitted with the parameters (joint or trend; ``drift_s_per_s`` and its interval in the result; a
    censored sample is judged against the ceiling with the drift added to the model). ``settling``: that baseline
    settles, ``d·τb·(1 − e^(−t/τb))`` (:func:`baseline_offset`; τb → ∞ is the drift), ``d`` and ``τb`` fitted
    (``drift_s_per_s``, ``drift_tau_s`` and their intervals), from ``baseline_start`` = (d, τb) when given. Returns
    an :class:`OutputFit`.
    """
    problem = _Problem(trials, area_m2, phys, start, mode, saturation_s, min_force_fraction, interp, drift, settling)
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def evaluate(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = theta.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = problem.residual_and_jacobian(theta)
        return cache[key]

    if mode == "per_trial":
        theta, iterations, success, message = _block_levenberg_marquardt(problem, max_nfev)
        residual, jac = problem.residual_and_jacobian(theta)
        return problem.summarise(theta, residual, jac, iterations, success, message,
                                 "block Levenberg–Marquardt (3 parameters per trial)")
    theta0 = np.zeros(problem.n_params)
    if settling and baseline_start is not None:  # (rate S/s, τb s) to start the baseline from
        rate0, tau0 = baseline_start
        theta0[-2] = rate0 / DRIFT_SCALE_S_PER_S
        theta0[-1] = float(np.clip(math.log(tau0 / problem.span_s), *SETTLING_LOG_TAU_BOUNDS))
    result = least_squares(lambda th: evaluate(th)[0], theta0, jac=lambda th: evaluate(th)[1],
                           bounds=problem.bounds, method="trf", x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                           max_nfev=max_nfev)
    residual, jac = evaluate(result.x)
    return problem.summarise(result.x, residual, jac, int(result.nfev), bool(result.success), str(result.message),
                             "scipy least_squares (trf)")


def fit_output_casadi(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants, start: SLSParams,
                      mode: str = "joint", *, saturation_s: float | None = None, min_force_fraction: float = 0.05,
                      solver: str = "gauss-newton", max_iter: int = 50) -> OutputFit:
    """Joint fit with CasADi (``joint`` or ``trend`` mode; the force is held between samples).

    The SLS creep state ``q`` (strain beyond the instantaneous ``σ/E0``) advances by the exact zero-order-hold step
    ``q⁺ = α·q + (1−α)·σ/E1``, ``α = exp(−h·E1/mu1)`` — the same recursion :mod:`models.sls` runs with
    ``interp="hold"`` (tested equal to 1e-12), written here symbolically because CasADi needs the expression graph.
    The step (all trials at once, padded with zero-length steps) carries its forward sensitivities and is rolled out
    with ``mapaccum``; the Jacobian is exact (CasADi ``jtimes`` inside the step). ``solver``:

    * ``"gauss-newton"`` — Levenberg–Marquardt-damped Gauss–Newton on the CasADi residual/Jacobian (default,
      fastest for 3–6 parameters; bounds of ``trend`` enforced by step clipping);
    * ``"ipopt"`` — ipopt with the Gauss–Newton Hessian ``JᵀJ`` supplied as ``hess_lag`` (CasADi's sysid pattern);
    * ``"sqpmethod"`` — CasADi's SQP with the ``qrqp`` QP solver and the Gauss–Newton Hessian via ``hess_lag``.
    """
    import casadi as ca  # heavy import, only when the production fit actually runs

    if mode not in ("joint", "trend"):
        raise ValueError(f"the CasADi fit is for joint fits ('joint' or 'trend'), got {mode!r}")
    problem = _Problem(trials, area_m2, phys, start, mode, saturation_s, min_force_fraction, "hold")
    theta, conductance, derivatives = _casadi_graph(ca, problem)
    n_trials = len(problem.trials)

    rows, weights, targets, censored = [], [], [], []
    for i, trial in enumerate(problem.trials):
        used = np.flatnonzero(problem.masks[i])
        rows.append(used * n_trials + i)  # column-major flattening of the T×N matrix
        weights.append(problem.sample_weights[i])
        targets.append(trial.conductance_s[used])
        censored.append(problem.censored[i][used])
    index = np.concatenate(rows)
    weight = np.concatenate(weights)
    target = np.concatenate(targets)
    cens = np.concatenate(censored)
    selected = index.tolist()
    model = ca.vec(conductance)[selected]
    if any(t.offset_s is not None for t in problem.trials):  # a known offset is part of the reading (FitTrial)
        model = model + ca.DM(np.concatenate([
            np.zeros(int(problem.masks[i].sum())) if t.offset_s is None
            else np.asarray(t.offset_s, dtype=np.float64)[problem.masks[i]] for i, t in enumerate(problem.trials)]))
    residual = weight * (model - target)
    jac = ca.horzcat(*[weight * ca.vec(d)[selected] for d in derivatives])
    if cens.any():
        # Censored samples: their censored-normal (Tobit) likelihood as a residual, as the scipy path (the module
        # docstring); its slope with respect to the model times the model's own sensitivities.
        assert problem.saturation_s is not None  # censored samples exist only when a saturation level was given
        noise = np.concatenate([np.full(int(problem.masks[i].sum()), problem.noise_s[i])
                                for i in range(n_trials)])[cens]
        tobit, slope = _casadi_censored(ca, model[np.flatnonzero(cens).tolist()],
                                        censoring_threshold(float(problem.saturation_s)),
                                        ca.DM(np.nan_to_num(noise, nan=0.0)))
        rows_c = np.flatnonzero(cens).tolist()
        residual[rows_c] = ca.DM(weight[cens]) * tobit
        jac[rows_c, :] = jac[rows_c, :] * ca.repmat(slope, 1, problem.n_params)
    res_jac = ca.Function("residual_jacobian", [theta], [residual, jac])
    res_only = ca.Function("residual", [theta], [residual])

    lower, upper = problem.bounds
    theta0 = np.zeros(problem.n_params)
    if solver == "gauss-newton":
        theta_opt, iterations, success, message = _levenberg_marquardt(res_only, res_jac, theta0, lower, upper, max_iter)
    elif solver in ("ipopt", "sqpmethod"):
        sigma = ca.MX.sym("sigma")
        lam_g = ca.MX.sym("lam_g", 0)
        p_sym = ca.MX.sym("p", 0)
        gauss_newton = ca.mtimes(jac.T, jac)
        # ipopt takes the upper triangle; sqpmethod insists on the full symmetric matrix.
        hess = ca.Function("nlp_hess_l", [theta, p_sym, sigma, lam_g],
                           [sigma * (ca.triu(gauss_newton) if solver == "ipopt" else gauss_newton)],
                           ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x" if solver == "ipopt"
                                                          else "hess_gamma_x_x"])
        objective = 0.5 * ca.sumsqr(residual)
        # The gradient Jᵀr from the carried sensitivities; left to AD it would run backwards through mapaccum.
        grad = ca.Function("nlp_grad_f", [theta, p_sym], [objective, ca.mtimes(jac.T, residual)], ["x", "p"],
                           ["f", "grad_f_x"])
        nlp = {"x": theta, "f": objective}
        opts: dict[str, Any]
        if solver == "ipopt":
            opts = {"hess_lag": hess, "grad_f": grad, "print_time": False,
                    "ipopt": {"print_level": 0, "max_iter": max_iter, "tol": 1e-10, "sb": "yes"}}
        else:
            # sqpmethod has no grad_f option: it differentiates the objective itself.
            opts = {"hess_lag": hess, "qpsol": "qrqp", "print_time": False, "print_header": False,
                    "print_status": False,
                    "print_iteration": False, "max_iter": max_iter, "tol_pr": 1e-12, "tol_du": 1e-12,
                    "qpsol_options": {"print_iter": False, "print_header": False, "error_on_fail": False}}
        nlp_solver = ca.nlpsol("output_error", solver, nlp, opts)
        finite_lower = np.where(np.isfinite(lower), lower, -1e20)
        finite_upper = np.where(np.isfinite(upper), upper, 1e20)
        solution = nlp_solver(x0=theta0, lbx=finite_lower, ubx=finite_upper)
        stats_ = nlp_solver.stats()
        theta_opt = np.asarray(solution["x"]).ravel()
        iterations = int(stats_.get("iter_count", -1))
        message = str(stats_.get("return_status", ""))
        # sqpmethod ends a converged Gauss–Newton run with this status: the step is below its resolution.
        success = bool(stats_.get("success", False)) or message == "Search_Direction_Becomes_Too_Small"
    else:
        raise ValueError(f"solver must be 'gauss-newton', 'ipopt' or 'sqpmethod', got {solver!r}")
    r_opt, j_opt = (np.asarray(x) for x in res_jac(theta_opt))
    return problem.summarise(theta_opt, r_opt.ravel(), j_opt, iterations, success, message, f"casadi {solver}")


def _casadi_censored(ca, model, ceiling_s: float, noise_s):
    """CasADi form of :func:`_censored_residual` (S) and its slope with respect to the model, elementwise:
    ``σ·√(−2 log Φ(x))``, x = (model − ceiling)/σ, with log Φ from erf in |x| ≤ 5 and its asymptotic series
    outside (erf loses it there); σ = 0: the one-sided limit ``min(model − ceiling, 0)``."""
    x = ca.SX.sym("x")
    # Each branch on its own clamped argument, so every branch (and its derivative, which sqpmethod's AD takes
    # through both sides of an if_else) stays finite everywhere.
    low, mid, high = ca.fmin(x, -5), ca.fmin(ca.fmax(x, -5), 5), ca.fmax(x, 5)
    log_cdf = ca.if_else(x < -5, -0.5 * low**2 - ca.log(-low) - 0.5 * math.log(2 * math.pi)
                         + ca.log(1 - 1 / low**2 + 3 / low**4),
                         ca.if_else(x > 5, -ca.exp(-0.5 * high**2) / (high * math.sqrt(2 * math.pi)) * (1 - 1 / high**2),
                                    ca.log(0.5 * (1 + ca.erf(mid / math.sqrt(2))))))
    root = ca.sqrt(-2 * log_cdf + 1e-300)
    # d√(−2 log Φ)/dx = −(φ/Φ)/√(−2 log Φ); 0 where the root underflows (the model far above the ceiling).
    d_root = ca.if_else(root > 1e-150, -ca.exp(-0.5 * x**2 - log_cdf) / (math.sqrt(2 * math.pi) * root), 0)
    unit = ca.Function("tobit_unit", [x], [root, d_root]).map(model.shape[0])
    sigma = ca.fmax(noise_s, 1e-300)
    root_v, d_root_v = unit(((model - ceiling_s) / sigma).T)
    hinge = ca.fmin(model - ceiling_s, 0)
    with_noise = noise_s > 0
    residual = ca.if_else(with_noise, sigma * root_v.T, hinge)
    slope = ca.if_else(with_noise, d_root_v.T, model < ceiling_s)
    return residual, slope


def _casadi_graph(ca, problem: _Problem):
    """The model conductance of every trial and its exact derivatives with respect to θ, as CasADi MX (T×N each;
    trials padded to the longest with zero-length steps; force held between samples). Returns (θ, C, [∂C/∂θ_k]).

    The SLS state is carried with its forward sensitivities: one SX step advances the creep strain q of all trials
    and dq/d(log E1), dq/d(log mu1) (differentiated by CasADi's ``jtimes``), and emits the conductance with its
    derivatives with respect to the log-parameters; ``mapaccum`` rolls it over time. This is ~5× cheaper than
    reverse-engineering the same Jacobian by AD through the rolled-out graph.
    """
    n_trials = len(problem.trials)
    n_max = max(t.time_s.size for t in problem.trials)
    steps = np.zeros((n_trials, n_max))
    stress = np.zeros((n_trials, n_max))
    force_c = np.ones((n_trials, n_max))
    for i, trial in enumerate(problem.trials):
        n = trial.time_s.size
        steps[i, : n - 1] = np.diff(trial.time_s)
        stress[i, :n] = problem.forces[i] / problem.area_m2
        stress[i, n:] = stress[i, n - 1]
        force_c[i, :n] = np.maximum(problem.forces[i], 1e-12)
        force_c[i, n:] = force_c[i, n - 1]
    phys = problem.phys
    contact = phys.K_contact_ohm_sqrtN / np.sqrt(force_c)

    sx = ca.SX
    q, s_e1, s_mu1 = sx.sym("q", n_trials), sx.sym("s_e1", n_trials), sx.sym("s_mu1", n_trials)
    h, sigma, r_contact = sx.sym("h", n_trials), sx.sym("sigma", n_trials), sx.sym("contact", n_trials)
    log_e0, log_e1, log_mu1 = sx.sym("log_e0", n_trials), sx.sym("log_e1", n_trials), sx.sym("log_mu1", n_trials)
    e0, e1, mu1 = ca.exp(log_e0), ca.exp(log_e1), ca.exp(log_mu1)
    k = phys.tunnelling_k
    strain = sigma / e0 + q
    tunnel = phys.R0_ohm * (1 - strain) * ca.exp(-k * strain)
    conductance = 1 / (r_contact + tunnel)
    # dC/dε = C²·R0·e^(−kε)·(1 + k(1−ε)); ε depends on log E0 through σ/E0 and on log E1, log mu1 through q.
    dc_dstrain = conductance**2 * phys.R0_ohm * ca.exp(-k * strain) * (1 + k * (1 - strain))
    outputs = ca.vertcat(conductance, dc_dstrain * (-sigma / e0), dc_dstrain * s_e1, dc_dstrain * s_mu1)
    alpha = ca.exp(-h * e1 / mu1)
    q_next = alpha * q + (1 - alpha) * sigma / e1
    ones = sx.ones(n_trials)
    s_e1_next = ca.jtimes(q_next, ca.vertcat(q, log_e1), ca.vertcat(s_e1, ones))
    s_mu1_next = ca.jtimes(q_next, ca.vertcat(q, log_mu1), ca.vertcat(s_mu1, ones))
    step = ca.Function("sls_hold_step", [ca.vertcat(q, s_e1, s_mu1), ca.vertcat(h, sigma, r_contact),
                                         ca.vertcat(log_e0, log_e1, log_mu1)],
                       [ca.vertcat(q_next, s_e1_next, s_mu1_next), outputs])
    roll = step.mapaccum("sls_roll", n_max)  # (x0, U, P) → states x_1 … x_N, outputs y_0 … y_{N−1}

    theta = ca.MX.sym("theta", problem.n_params)
    log_scale = np.log(problem.scale)
    log_ref = [log_scale[j] + theta[j] for j in range(3)]
    if problem.mode == "trend":
        rel_force = ca.DM((problem.hold_n - problem.ref_force_n) / problem.ref_force_n)
        log_params = [log_ref[j] + ca.log(1 + theta[3 + j] * rel_force) for j in range(3)]  # each T×1
        # d log P_j / d u_j per trial
        d_log_du = [rel_force / (1 + theta[3 + j] * rel_force) for j in range(3)]
    else:
        log_params = [ca.repmat(log_ref[j], n_trials, 1) for j in range(3)]
        d_log_du = []
    data = ca.DM(np.vstack([steps, stress, contact]))
    _, out = roll(ca.DM.zeros(3 * n_trials), data, ca.repmat(ca.vertcat(*log_params), 1, n_max))
    model = out[:n_trials, :]
    d_log = [out[(j + 1) * n_trials:(j + 2) * n_trials, :] for j in range(3)]  # ∂C/∂log P_j, T×N
    derivatives = list(d_log)
    for j, factor in enumerate(d_log_du):
        derivatives.append(d_log[j] * ca.repmat(factor, 1, n_max))
    return theta, model, derivatives


def casadi_conductance(trials: Sequence[FitTrial], area_m2: float, phys: PhysicsConstants,
                       params: SLSParams) -> list[np.ndarray]:
    """The CasADi graph's model conductance (S) per trial at ``params``: lets tests hold the symbolic recursion to
    :func:`models.sls.conductance_from_force`. Samples at F ≤ 0 are not comparable (the graph clips F at 1e-12 N)."""
    import casadi as ca

    problem = _Problem(trials, area_m2, phys, params, "joint", None, 0.0, "hold")
    theta, conductance, _ = _casadi_graph(ca, problem)
    values = np.asarray(ca.Function("conductance", [theta], [conductance])(np.zeros(3)))
    return [values[i, : t.time_s.size] for i, t in enumerate(problem.trials)]


def _levenberg_marquardt(residual_fn, res_jac, theta0: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                         max_iter: int) -> tuple[np.ndarray, int, bool, str]:
    """Damped Gauss–Newton (Levenberg–Marquardt with Marquardt's diagonal scaling) on the CasADi residual and
    Jacobian, box bounds by clipping. Trial points cost a residual only; the Jacobian is evaluated on acceptance.
    Stops when the model predicts a relative decrease below 1e-14 (rounding level) or the step is below 1e-10."""
    theta = theta0.copy()
    r, j = (np.asarray(x) for x in res_jac(theta))
    r = r.ravel()
    cost = _sumsq(r)
    damping = 1e-3
    for iteration in range(1, max_iter + 1):
        diag = np.sqrt(np.einsum("ij,ij->j", j, j)) + 1e-300
        while True:
            # Damped normal equations solved as an augmented least-squares problem (no JᵀJ formed).
            augmented = np.vstack([j, math.sqrt(damping) * np.diag(diag)])
            delta = -np.linalg.lstsq(augmented, np.concatenate([r, np.zeros(theta.size)]), rcond=None)[0]
            candidate = np.clip(theta + delta, lower, upper)
            linear = r + j @ (candidate - theta)
            predicted = cost - _sumsq(linear)
            if predicted <= 1e-14 * cost or np.max(np.abs(candidate - theta)) < 1e-10:
                return theta, iteration, True, "converged"
            r_new = np.asarray(residual_fn(candidate)).ravel()
            cost_new = _sumsq(r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                break
            damping *= 10.0
            if damping > 1e10:
                return theta, iteration, False, "no decrease along the Gauss–Newton direction"
        gain = (cost - cost_new) / predicted
        theta, cost = candidate, cost_new
        r, j = (np.asarray(x) for x in res_jac(theta))
        r = r.ravel()
        damping = max(damping * (0.1 if gain > 0.75 else 1.0 if gain > 0.25 else 4.0), 1e-9)
    return theta, max_iter, False, f"stopped after {max_iter} iterations"
