"""Derivative-free initial estimate of the SLS parameters (NUMERICS pitfall 4).

Integrating Eq. 5 (``σ + a·σ̇ = b·ε + c·ε̇``) from a time ``t0`` removes every derivative:

    ∫σ dt = b·∫ε dt + c·(ε − ε0) − a·(σ − σ0)

so ``[b, c, a]`` come from a linear least-squares problem on integrals (which average noise) instead of finite
differences (which amplify it). The columns differ by orders of magnitude (∫ε ~ 1 s, ε ~ 1e-2, σ ~ 1e3 Pa), so each
is scaled to unit norm before ``lstsq``. The result starts the output-error fit; it is not the final answer, and a
physical projection keeps it usable when noise pushes it out of the physical region.

Pure numerics: any thread may call these.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.optimize import lsq_linear

from models.sls import abc_from_sls, sls_from_abc


@dataclass(frozen=True)
class DerivativeFreeEstimate:
    """``a_s`` (s), ``b_Pa``, ``c_Pa_s`` (Eq. 6) and E0/E1/mu1 (Pa, Pa, Pa·s), always positive and finite.

    ``projected`` is True when the unconstrained solution was not physical and was moved into the physical region
    (the numbers are then only a starting point); ``note`` says how.
    """

    a_s: float
    b_Pa: float
    c_Pa_s: float
    E0_Pa: float
    E1_Pa: float
    mu1_Pa_s: float
    projected: bool
    note: str = ""


# E0/b = 1 + E0/E1: a starting value outside (1, MAX_E0_OVER_B) means a ≈ 0 or a < 0 came out of the noise, and an
# optimiser started there sits on a plateau (E0 → ∞ makes the instantaneous strain vanish and its gradient with it).
MAX_E0_OVER_B = 100.0


def _plausible(e0_pa: float, b_pa: float) -> bool:
    return math.isfinite(e0_pa) and b_pa < e0_pa < MAX_E0_OVER_B * b_pa


def _rows(t_s: np.ndarray, stress_pa: np.ndarray, strain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    keep = np.isfinite(t_s) & np.isfinite(stress_pa) & np.isfinite(strain)
    t, s, e = t_s[keep], stress_pa[keep], strain[keep]
    if t.size < 3:
        return np.empty((0, 3)), np.empty(0)
    int_s = cumulative_trapezoid(s, t, initial=0.0)
    int_e = cumulative_trapezoid(e, t, initial=0.0)
    design = np.column_stack([int_e, e - e[0], -(s - s[0])])
    return design[1:], int_s[1:]


def estimate_sls(trials: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> DerivativeFreeEstimate:
    """Estimate one parameter set from one or more trials ``(t_s, stress_pa, strain)``, each integrated from its own
    first sample. Use samples where the strain is defined (force clearly above zero); NaN samples are skipped.

    Raises ValueError when there are too few usable samples or no strain signal at all.
    """
    blocks = [_rows(np.asarray(t, float), np.asarray(s, float), np.asarray(e, float)) for t, s, e in trials]
    design = np.vstack([b[0] for b in blocks])
    target = np.concatenate([b[1] for b in blocks])
    if design.shape[0] < 4:
        raise ValueError(f"derivative-free estimate needs at least 4 loaded samples, got {design.shape[0]}")
    norms = np.linalg.norm(design, axis=0)
    if not norms[0] > 0 or not norms[1] > 0:
        raise ValueError("derivative-free estimate: the strain never changes (flat or disconnected sensor)")
    has_ramp = norms[2] > 0
    if not has_ramp:
        # No stress change inside the records: a (and E0) is unidentifiable; fit b, c and leave a to the prior below.
        design, norms = design[:, :2], norms[:2]
    scaled = design / norms
    coef = np.linalg.lstsq(scaled, target, rcond=None)[0] / norms
    b, c = float(coef[0]), float(coef[1])
    a = float(coef[2]) if has_ramp else math.nan
    e0, e1, mu1 = sls_from_abc(a, b, c)
    if _plausible(e0, b):
        return DerivativeFreeEstimate(a, b, c, e0, e1, mu1, projected=False)

    # Physical projection: non-negative coefficients by bounded least squares; then, if still E0 ≤ b, keep b (the
    # long-run stiffness) and τ = c/b (the creep time), which the hold identifies, and put E0 = E1 = 2b.
    bounded = lsq_linear(scaled, target, bounds=(0.0, np.inf)).x / norms
    b = float(bounded[0]) if bounded[0] > 0 else abs(b) or 1.0
    c = float(bounded[1]) if bounded[1] > 0 else abs(c) or b
    a = float(bounded[2]) if has_ramp and bounded[2] > 0 else math.nan
    e0, e1, mu1 = sls_from_abc(a, b, c)
    if _plausible(e0, b):
        return DerivativeFreeEstimate(a, b, c, e0, e1, mu1, projected=True,
                                      note="negative coefficient clipped to zero by bounded least squares")
    tau_s = c / b
    e0 = e1 = 2.0 * b
    mu1 = e1 * tau_s
    a, b2, c2 = abc_from_sls(e0, e1, mu1)
    note = ("no loading ramp in the records: E0 not identified, guessed as 2·b" if not has_ramp
            else "E0 not physical or not plausible (a ≈ 0 or E0 ≤ b); E0 guessed as 2·b from the long-run "
            "stiffness")
    return DerivativeFreeEstimate(a, b2, c2, e0, e1, mu1, projected=True, note=note)
