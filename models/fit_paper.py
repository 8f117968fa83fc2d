"""The paper's parameter estimation (Sec. IV-B), kept as the reference estimator — with its failure modes reported.

* :func:`fit_exponential` — Eq. 9, ``C = c1 + c2·exp(−c3·t)``. Separable (NUMERICS pitfall 6): for a fixed ``c3``
  the model is linear in ``c1, c2``, so we search ``log c3`` in one dimension and solve ``c1, c2`` by least squares.
* :func:`fit_paper_ls` — Eqs. 7–8, ``σ = [ε, ε̇, −σ̇]·[b, c, a]``, then Eq. 6 inverted to ``E0, E1, mu1``.
  On a constant-force hold ``σ̇ ≡ 0``, so ``a`` (hence ``E0``) is not identifiable (NUMERICS pitfall 4). This
  function checks the column-scaled condition number, the relative standard error of each coefficient and the
  physical signs, and *refuses* (``ok=False`` with the reason) instead of returning numbers that look like an answer.

Pure numerics: any thread may call these; nothing is shared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from models.sls import sls_from_abc

# Column-scaled condition numbers above this mean a coefficient is a near-linear combination of the others.
RANK_CONDITION_LIMIT = 1e8
# A coefficient whose standard error exceeds this fraction of its value is reported as not identified.
IDENTIFIABILITY_REL_SE = 0.5


@dataclass(frozen=True)
class ExponentialFit:
    """Eq. 9 on one trial: ``C(t) = c1 + c2·exp(−c3·t)``; ``c1``, ``c2`` in S, ``c3`` in 1/s; ``rmse_s`` in S."""

    c1: float
    c2: float
    c3: float
    rmse_s: float
    t0_s: float = 0.0  # the time origin used: C(t) = c1 + c2·exp(−c3·(t − t0_s)); 0 = the trial's own clock

    def __call__(self, t_s: np.ndarray) -> np.ndarray:
        return self.c1 + self.c2 * np.exp(-self.c3 * (np.asarray(t_s, dtype=np.float64) - self.t0_s))

    def derivative(self, t_s: np.ndarray) -> np.ndarray:
        """dC/dt in S/s."""
        return -self.c3 * self.c2 * np.exp(-self.c3 * (np.asarray(t_s, dtype=np.float64) - self.t0_s))


def _separable_solve(t: np.ndarray, y: np.ndarray, c3: float) -> tuple[float, float, float]:
    """Best ``c1, c2`` for a fixed ``c3`` and the residual sum of squares, in closed form on centred data
    (a 1-D regression of y on exp(−c3·t); centring keeps it accurate when the basis is nearly constant)."""
    basis = np.exp(-c3 * t)
    b_mean = float(basis.mean())
    y_mean = float(y.mean())
    b_c = basis - b_mean
    y_c = y - y_mean
    # Element-wise sums rather than BLAS dot products: on a busy machine a threaded BLAS call on a vector costs
    # milliseconds of thread hand-off, and this runs ~100 times per trial.
    sbb = float(np.sum(b_c * b_c))
    if not sbb > 0:
        return y_mean, 0.0, float(np.sum(y_c * y_c))
    c2 = float(np.sum(b_c * y_c)) / sbb
    residual = y_c - c2 * b_c
    return y_mean - c2 * b_mean, c2, float(np.sum(residual * residual))


def fit_exponential(t_s: np.ndarray, conductance_s: np.ndarray, c3_range_per_s: tuple[float, float] | None = None,
                    grid_points: int = 64) -> ExponentialFit:
    """Fit Eq. 9 to a hold by a 1-D search over ``log c3`` (grid, then bounded Brent refinement).

    ``t_s`` (s) and ``conductance_s`` (S) are the hold's samples; NaN samples are skipped. Time is measured from the
    first sample (``t0_s``) so ``c2`` is the deviation at the start of the hold, not extrapolated to t = 0 s of the
    trial file. ``c3_range_per_s`` defaults to 1/(100·span) … 100/median step: rates slower than the record or
    faster than the sampling cannot be told from a constant or a step.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    y = np.asarray(conductance_s, dtype=np.float64)
    keep = np.isfinite(t_s) & np.isfinite(y)
    t_s, y = t_s[keep], y[keep]
    if t_s.size < 4:
        raise ValueError(f"Eq. 9 needs at least 4 finite samples, got {t_s.size}")
    t0 = float(t_s[0])
    t = t_s - t0
    span = float(t[-1])
    if span <= 0:
        raise ValueError("Eq. 9 needs samples at more than one time")
    if c3_range_per_s is None:
        step = float(np.median(np.diff(t)))
        c3_range_per_s = (1.0 / (100.0 * span), 100.0 / step)
    lo, hi = math.log(c3_range_per_s[0]), math.log(c3_range_per_s[1])
    grid = np.linspace(lo, hi, grid_points)
    sse = np.array([_separable_solve(t, y, math.exp(g))[2] for g in grid])
    best = int(np.argmin(sse))
    left, right = grid[max(best - 1, 0)], grid[min(best + 1, grid_points - 1)]
    if right > left:
        result = minimize_scalar(lambda g: _separable_solve(t, y, math.exp(g))[2], bounds=(left, right),
                                 method="bounded", options={"xatol": 1e-10})
        log_c3 = float(result.x) if result.fun <= sse[best] else float(grid[best])
    else:
        log_c3 = float(grid[best])
    c3 = math.exp(log_c3)
    c1, c2, rss = _separable_solve(t, y, c3)
    return ExponentialFit(c1=c1, c2=c2, c3=c3, rmse_s=math.sqrt(rss / t.size), t0_s=t0)


@dataclass(frozen=True)
class PaperLSResult:
    """Eqs. 7–8 regression. ``a_s`` (s), ``b_Pa``, ``c_Pa_s`` and E0/E1/mu1 (Pa, Pa, Pa·s) are NaN when refused.

    ``ok`` is False when the regression is rank-deficient, a coefficient is not identified or the result is
    non-physical; ``warnings`` then says which, in words a user can act on.
    """

    ok: bool
    a_s: float
    b_Pa: float
    c_Pa_s: float
    E0_Pa: float
    E1_Pa: float
    mu1_Pa_s: float
    condition_number: float
    rel_std_error: tuple[float, float, float]  # of (b, c, a)
    warnings: tuple[str, ...] = field(default_factory=tuple)


def fit_paper_ls(stress_pa: np.ndarray, strain: np.ndarray, strain_rate_per_s: np.ndarray,
                 stress_rate_pa_s: np.ndarray) -> PaperLSResult:
    """Eq. 8: least squares of ``σ`` on ``Φ = [ε, ε̇, −σ̇]`` → ``[b, c, a]`` → Eq. 6 inverted.

    Solved by column-scaled ``lstsq`` (never the normal equations, which square the condition number). Refuses with
    a reason when: a column is all zero or the scaled condition number exceeds :data:`RANK_CONDITION_LIMIT` (rank
    deficiency — on a pure hold ``σ̇ ≡ 0``); a coefficient's standard error exceeds
    :data:`IDENTIFIABILITY_REL_SE` of its value (e.g. ``σ̇`` is only noise); or Eq. 6 gives non-physical
    parameters (``a, b, c ≤ 0`` or ``E0 ≤ b``, i.e. ``E1 < 0``). NaN rows are skipped.
    """
    columns = [np.asarray(x, dtype=np.float64) for x in (strain, strain_rate_per_s, stress_rate_pa_s)]
    phi = np.column_stack([columns[0], columns[1], -columns[2]])
    target = np.asarray(stress_pa, dtype=np.float64)
    keep = np.all(np.isfinite(phi), axis=1) & np.isfinite(target)
    phi, target = phi[keep], target[keep]
    names = ("ε", "ε̇", "σ̇")
    nan3 = (math.nan, math.nan, math.nan)

    def refuse(reason: str, cond: float, rel: tuple[float, float, float] = nan3,
               abc: tuple[float, float, float] = nan3) -> PaperLSResult:
        return PaperLSResult(False, abc[0], abc[1], abc[2], math.nan, math.nan, math.nan, cond, rel, (reason,))

    if phi.shape[0] <= 3:
        return refuse(f"paper LS: only {phi.shape[0]} usable samples for 3 coefficients", math.inf)
    norms = np.linalg.norm(phi, axis=0)
    zero = [names[i] for i in range(3) if not norms[i] > 0]
    if zero:
        return refuse(
            f"paper LS rank-deficient: column {', '.join(zero)} is identically zero (a constant-force hold has "
            "σ̇ = 0, so a and E0 are not identifiable); use the output-error fit", math.inf)
    scaled = phi / norms
    singular = np.linalg.svd(scaled, compute_uv=False)
    cond = float(singular[0] / singular[-1]) if singular[-1] > 0 else math.inf
    if not cond < RANK_CONDITION_LIMIT:
        return refuse(f"paper LS rank-deficient: condition number {cond:.3g} of [ε, ε̇, −σ̇]; use the output-error "
                      "fit", cond)
    coef_scaled, *_ = np.linalg.lstsq(scaled, target, rcond=None)
    coef = coef_scaled / norms
    residual = target - scaled @ coef_scaled
    dof = phi.shape[0] - 3
    sigma2 = float(residual @ residual) / dof
    # Covariance of the scaled coefficients from the SVD (no normal equations formed).
    _, s, vt = np.linalg.svd(scaled, full_matrices=False)
    cov_scaled = (vt.T / s**2) @ vt * sigma2
    se = np.sqrt(np.diag(cov_scaled)) / norms
    with np.errstate(divide="ignore", invalid="ignore"):
        rel_b, rel_c, rel_a = (float(x) for x in np.abs(se / coef))
    rel = (rel_b, rel_c, rel_a)
    b, c, a = (float(x) for x in coef)
    poorly = [f"{label} (±{100 * r:.0f}%)" for label, r in zip(("b", "c", "a"), rel) if not r < IDENTIFIABILITY_REL_SE]
    if poorly:
        return refuse(f"paper LS: coefficient {', '.join(poorly)} not identified by the data (rank-deficient in "
                      "practice: σ̇ carries no signal on a hold); use the output-error fit", cond, rel, (a, b, c))
    e0, e1, mu1 = sls_from_abc(a, b, c)
    if not math.isfinite(e0):
        return refuse(f"paper LS non-physical: a = {a:.3g} s, b = {b:.3g} Pa, c = {c:.3g} Pa·s gives E1 < 0 or a "
                      "negative coefficient; use the output-error fit", cond, rel, (a, b, c))
    return PaperLSResult(True, a, b, c, e0, e1, mu1, cond, rel, ())
