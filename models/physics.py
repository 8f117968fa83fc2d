"""Resistance–strain physics of the piezo-resistive sensor (the paper's Eq. 3–4), pure numerics.

``R_s = K/√F + R0·(1−ε)·exp(−k·ε)`` with the contact term lumped as ``K = (ρ1+ρ2)/2·√(πH)`` (SPEC §3.3) and the
tunnelling exponent ``k = γ·D·((π/(6φ))^(1/3) − 1)``, ``γ = (4π/h)·√(2·m_e·φ_b)``.

The inverse (strain from resistance) solves ``ln(1−ε) − k·ε = ln(R_t/R0)`` (``R_t = R_s − K/√F``) by Newton in this
log form (NUMERICS pitfall 3). The closed form with Lambert W needs ``e^k`` and overflows float64 for k > 709, so it
is deliberately not used.

Every function here is pure and thread-safe: any thread may call it.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

# CODATA 2022 (h and e are exact in the SI since 2019; m_e is CODATA 2022, what scipy.constants 1.15+ carries).
# Literals, not ``scipy.constants``: importing that pulls in scipy's array-API layer and numpy.f2py (~0.2-0.4 s),
# the largest single cost of opening the app (the simulated lab's sensor models import this module).
PLANCK_J_S = 6.62607015e-34
ELECTRON_MASS_KG = 9.1093837139e-31
ELECTRON_VOLT_J = 1.602176634e-19

PHYSICS_KEYS = ("R0_ohm", "D_m", "phi", "barrier_eV", "K_contact_ohm_sqrtN")

# Above this strain the model is far outside its physical range (useful strains are 1e-4 … 2e-2); the solver still
# returns the root but flags it.
STRAIN_NEAR_ONE = 0.9

_NEWTON_MAX_ITER = 60  # hard cap; the normal range converges in ≤ 8 (tested)


@dataclass(frozen=True)
class PhysicsConstants:
    """Constants of Eq. 3–4. Defaults are the paper's values; ``K_contact_ohm_sqrtN`` is the SPEC's placeholder.

    R0_ohm: initial resistance of the piezo-resistive layer (Ω). D_m: filler particle diameter (m).
    phi: filler volume fraction (dimensionless, 0 < phi < π/6 so that the tunnelling exponent is positive).
    barrier_eV: potential barrier between adjacent particles (eV). K_contact_ohm_sqrtN: lumped contact term so that
    the contact resistance is ``K/√F`` (Ω·√N); 0 disables the contact term.
    """

    R0_ohm: float = 2580.0
    D_m: float = 5e-7
    phi: float = 0.2873
    barrier_eV: float = 0.05
    K_contact_ohm_sqrtN: float = 1772.45

    def __post_init__(self) -> None:
        for key in PHYSICS_KEYS:
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ValueError(f"physics constant {key} must be a number, got {value!r}")
            if not math.isfinite(float(value)):
                raise ValueError(f"physics constant {key} must be finite, got {value!r}")
            object.__setattr__(self, key, float(value))
        for key in ("R0_ohm", "D_m", "barrier_eV"):
            if getattr(self, key) <= 0.0:
                raise ValueError(f"physics constant {key} must be > 0, got {getattr(self, key)!r}")
        if not 0.0 < self.phi < math.pi / 6.0:
            raise ValueError(
                f"physics constant phi must be in (0, π/6 ≈ 0.5236) so the tunnelling exponent is positive, "
                f"got {self.phi!r}"
            )
        if self.K_contact_ohm_sqrtN < 0.0:
            raise ValueError(
                f"physics constant K_contact_ohm_sqrtN must be ≥ 0, got {self.K_contact_ohm_sqrtN!r}"
            )

    @property
    def gamma_per_m(self) -> float:
        """γ = (4π/h)·√(2·m_e·φ_b) in 1/m (≈ 2.291e9 for φ_b = 0.05 eV)."""
        barrier_j = self.barrier_eV * ELECTRON_VOLT_J
        return 4.0 * math.pi / PLANCK_J_S * math.sqrt(2.0 * ELECTRON_MASS_KG * barrier_j)

    @property
    def tunnelling_k(self) -> float:
        """Dimensionless k = γ·D·((π/(6φ))^(1/3) − 1) (≈ 253.7 with the paper's values)."""
        return self.gamma_per_m * self.D_m * ((math.pi / (6.0 * self.phi)) ** (1.0 / 3.0) - 1.0)

    @property
    def has_contact(self) -> bool:
        return self.K_contact_ohm_sqrtN > 0.0

    def without_contact(self) -> PhysicsConstants:
        """The same constants with the contact term switched off (K = 0)."""
        return PhysicsConstants(self.R0_ohm, self.D_m, self.phi, self.barrier_eV, 0.0)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> PhysicsConstants:
        """Build from SPEC §3.3 keys, at the top level of ``data`` or under ``data["physics"]``.

        Every key is required (the default K_contact is a placeholder, never a hidden constant). Raises ValueError
        naming a missing, non-numeric or non-finite key.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"physics must be a JSON object, got {type(data).__name__}")
        source: Mapping[str, object] = data
        if "physics" in data and not any(key in data for key in PHYSICS_KEYS):
            nested = data["physics"]
            if not isinstance(nested, Mapping):
                raise ValueError(f"'physics' must be a JSON object, got {type(nested).__name__}")
            source = nested
        missing = [key for key in PHYSICS_KEYS if key not in source]
        if missing:
            raise ValueError(
                f"physics is missing key(s) {', '.join(missing)} (need {', '.join(PHYSICS_KEYS)})"
            )
        values = {}
        for key in PHYSICS_KEYS:
            value = source[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"physics key {key} must be a number, got {value!r}")
            if not math.isfinite(float(value)):
                raise ValueError(f"physics key {key} must be finite, got {value!r}")
            values[key] = float(value)
        return cls(**values)

    def to_dict(self) -> dict[str, float]:
        """SPEC §3.3 ``physics`` object."""
        return {key: float(getattr(self, key)) for key in PHYSICS_KEYS}


DEFAULT_PHYSICS = PhysicsConstants()


class StrainStatus(enum.IntEnum):
    """Per-sample outcome of :func:`strain_from_resistance`. Only OK and NEGATIVE_STRAIN carry a usable strain."""

    OK = 0
    NEGATIVE_STRAIN = 1  # R_t > R0: reading above the unloaded resistance (drift); strain returned is < 0
    CONTACT_EXCEEDS_READING = 2  # R_t ≤ 0: the contact term K/√F alone exceeds the reading; strain NaN
    NO_FORCE = 3  # F ≤ 0 with a contact term: contact resistance infinite, no strain information; strain NaN
    OPEN_CIRCUIT = 4  # R = ∞ (C = 0): no current, no strain information; strain NaN
    STRAIN_NEAR_ONE = 5  # ε ≥ 0.9: root returned, but far outside the model's physical range
    NAN_INPUT = 6  # resistance or force is NaN; strain NaN
    NOT_CONVERGED = 7  # Newton did not converge (should not happen); last iterate returned
    NEGATIVE_RESISTANCE = 8  # R < 0: not a reading; strain NaN
    SHORT_CIRCUIT = 9  # R = 0 (C = ∞): beyond the ε → 1 limit; strain NaN


STRAIN_STATUS_TEXT = {
    StrainStatus.OK: "ok",
    StrainStatus.NEGATIVE_STRAIN: "reading above the unloaded resistance R0 (drift below baseline): negative strain",
    StrainStatus.CONTACT_EXCEEDS_READING: "contact term K/√F alone exceeds the measured resistance: force too low "
    "for this reading or K_contact too large",
    StrainStatus.NO_FORCE: "force ≤ 0 with a contact term: contact resistance is infinite",
    StrainStatus.OPEN_CIRCUIT: "open circuit (R = ∞, C = 0): no strain information",
    StrainStatus.STRAIN_NEAR_ONE: f"strain ≥ {STRAIN_NEAR_ONE}: far outside the model's range (useful 1e-4 … 2e-2)",
    StrainStatus.NAN_INPUT: "resistance or force is NaN",
    StrainStatus.NOT_CONVERGED: "Newton iteration did not converge",
    StrainStatus.NEGATIVE_RESISTANCE: "negative resistance is not a reading",
    StrainStatus.SHORT_CIRCUIT: "zero resistance (short circuit): beyond the model's ε → 1 limit",
}


def explain_status(status: np.ndarray, texts: Mapping[Any, str] | None = None) -> list[str]:
    """One line per non-OK status present in ``status``: '<count> sample(s) NAME: <explanation>'. ``texts`` maps
    each IntEnum member to its explanation (default: :class:`StrainStatus`)."""
    if texts is None:
        texts = STRAIN_STATUS_TEXT
    codes = np.asarray(status)
    lines = []
    for code, text in texts.items():
        if int(code) == 0:
            continue
        count = int(np.count_nonzero(codes == int(code)))
        if count:
            lines.append(f"{count} sample(s) {code.name}: {text}")
    return lines


@dataclass(frozen=True)
class StrainResult:
    """Strain (dimensionless) and a :class:`StrainStatus` code per sample, same shape; ``iterations`` is the
    largest number of Newton iterations any sample needed."""

    strain: np.ndarray
    status: np.ndarray
    iterations: int

    @property
    def ok(self) -> np.ndarray:
        """True where the strain is usable (OK or NEGATIVE_STRAIN)."""
        return (self.status == StrainStatus.OK) | (self.status == StrainStatus.NEGATIVE_STRAIN)

    def explain(self) -> list[str]:
        """Human-readable summary of every non-OK status present."""
        return explain_status(self.status, STRAIN_STATUS_TEXT)


def contact_resistance(force_n: npt.ArrayLike, phys: PhysicsConstants) -> np.ndarray:
    """K/√F in Ω; ∞ for F ≤ 0 when K > 0, 0 everywhere when K = 0. NaN force gives NaN."""
    force = np.asarray(force_n, dtype=np.float64)
    if not phys.has_contact:
        return np.where(np.isnan(force), np.nan, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = phys.K_contact_ohm_sqrtN / np.sqrt(np.where(force > 0.0, force, 0.0))
    return np.where(np.isnan(force), np.nan, r)


def tunnelling_resistance(strain: npt.ArrayLike, phys: PhysicsConstants) -> np.ndarray:
    """R0·(1−ε)·exp(−k·ε) in Ω (the strain-dependent part of Eq. 3)."""
    eps = np.asarray(strain, dtype=np.float64)
    return phys.R0_ohm * (1.0 - eps) * np.exp(-phys.tunnelling_k * eps)


def resistance_from_strain(
    strain: npt.ArrayLike, force_n: npt.ArrayLike, phys: PhysicsConstants
) -> np.ndarray:
    """Eq. 3: total resistance in Ω from strain (dimensionless) and force (N), broadcast together.

    With a contact term, F → 0 gives R → ∞ (conductance 0); negative forces are treated as no contact (R = ∞).
    Strains ≥ 1 give a tunnelling part ≤ 0, which is not physical: callers should keep ε < 1.
    """
    return contact_resistance(force_n, phys) + tunnelling_resistance(strain, phys)


def conductance_from_strain(
    strain: npt.ArrayLike, force_n: npt.ArrayLike, phys: PhysicsConstants
) -> np.ndarray:
    """1/R of Eq. 3 in siemens; exactly 0 where R = ∞ (no contact)."""
    r = resistance_from_strain(strain, force_n, phys)
    with np.errstate(divide="ignore"):
        return 1.0 / r


def strain_from_conductance(
    conductance_s: np.ndarray, force_n: np.ndarray, phys: PhysicsConstants
) -> StrainResult:
    """Strain from conductance in siemens (C = 0 is an open circuit); see :func:`strain_from_resistance`."""
    c = np.asarray(conductance_s, dtype=np.float64)
    with np.errstate(divide="ignore", over="ignore"):  # C subnormal: 1/C = ∞, an open circuit
        r = np.where(c == 0.0, np.inf, 1.0 / np.where(c == 0.0, 1.0, c))
    return strain_from_resistance(r, force_n, phys)


_CHUNK = 8192  # elements per Newton chunk: keeps the temporaries in cache


def _newton_strain_low(log_ratio: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The ε-form Newton of :func:`_newton_strain` for L > −(1+k), chunked and in place (it is the hot loop of the
    no-contact inverse).

    Start: for L ≤ 0 the root of the second-order model ``−(1+k)ε − ε²/2 = L``, which is right of the root because
    ln(1−ε) ≤ −ε − ε²/2, and below 1 for every L > −(1+k); for L > 0 the tangent ``−L/(1+k)``. From there the
    relative error is ≲ ε²/(3(1+k)) (≤ 1e-6 at ε = 0.02), so one Newton step reaches ~1e-13 and the second, which
    is also the convergence check, reaches rounding level.
    """
    flat = log_ratio.reshape(-1)
    out = np.empty_like(flat)
    converged = np.ones(flat.shape, dtype=bool)
    kp1 = 1.0 + k
    tol = 16.0 * np.finfo(float).eps
    max_iter_used = 0
    for lo in range(0, flat.size, _CHUNK):
        big_l = flat[lo : lo + _CHUNK]
        nonpos = np.minimum(big_l, 0.0)
        e = np.multiply(nonpos, -2.0)
        e /= np.sqrt(kp1 * kp1 - 2.0 * nonpos) + kp1
        if float(big_l.max()) > 0.0:
            positive = big_l > 0.0
            e[positive] = -big_l[positive] / kp1
        om = np.empty_like(e)
        g = np.empty_like(e)
        for iteration in range(1, _NEWTON_MAX_ITER + 1):
            np.subtract(1.0, e, out=om)
            np.negative(e, out=g)
            np.log1p(g, out=g)
            g -= k * e
            g -= big_l
            # Newton step e ← e + g·(1−ε)/(1 + k·(1−ε)); g < 0 right of the root, so the step is ≤ 0.
            g *= om
            om *= k
            om += 1.0
            g /= om
            e += g
            max_iter_used = max(max_iter_used, iteration)
            if iteration >= 2:
                np.abs(g, out=g)
                np.abs(e, out=om)
                om *= tol
                small = g <= om
                if small.all():
                    break
        else:
            converged[lo : lo + _CHUNK] = small
        out[lo : lo + _CHUNK] = e
    return out.reshape(log_ratio.shape), converged.reshape(log_ratio.shape), max_iter_used


def _newton_strain(log_ratio: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Root ε of ``g(ε) = ln(1−ε) − k·ε − L = 0`` for each L = ln(R_t/R0) (finite). Returns (ε, converged, iters).

    g is strictly decreasing and concave on ε < 1, so Newton started to the right of the root decreases monotonically
    onto it and never leaves the domain (starts: :func:`_newton_strain_low`). For L ≤ −(1+k), i.e. ε > 0.996, Newton
    runs on v = ln(1−ε) instead, where ``v + k·e^v = k + L`` is convex increasing, from v = k + L (right of its
    root), so that even strains within 1e-300 of 1 are resolved without leaving the domain.
    """
    log_r = np.asarray(log_ratio, dtype=np.float64)
    eps = np.empty_like(log_r)
    converged = np.zeros(log_r.shape, dtype=bool)
    max_iter_used = 0

    low = log_r > -(1.0 + k)
    if np.any(low):
        all_low = low.all()
        l_low = log_r if all_low else log_r[low]
        e, done, iters = _newton_strain_low(l_low, k)
        max_iter_used = iters
        if all_low:
            return e, done, max_iter_used
        eps[low] = e
        converged[low] = done

    high = ~low
    if np.any(high):
        l_high = log_r[high]
        target = k + l_high
        v = target.copy()
        done = np.zeros(l_high.shape, dtype=bool)
        for iteration in range(1, _NEWTON_MAX_ITER + 1):
            ev = np.exp(v)
            f = v + k * ev - target
            step = f / (1.0 + k * ev)
            v_new = v - step
            newly = (np.abs(step) <= 4.0 * np.finfo(float).eps * np.maximum(np.abs(v), 1.0)) | (v_new >= v)
            v = np.where(done | (v_new >= v), v, v_new)
            done |= newly
            max_iter_used = max(max_iter_used, iteration)
            if done.all():
                break
        eps[high] = -np.expm1(v)
        converged[high] = done
    return eps, converged, max_iter_used


def strain_from_resistance(
    r_ohm: npt.ArrayLike, force_n: npt.ArrayLike, phys: PhysicsConstants
) -> StrainResult:
    """Invert Eq. 3 for the strain, vectorised: ``ln(1−ε) − k·ε = ln(R_t/R0)`` with ``R_t = R_s − K/√F``.

    r_ohm: measured resistance in Ω (∞ allowed: open circuit); force_n: the force in N the contact term is evaluated
    at (ignored when K = 0), broadcast against r_ohm. Converges to ~1e-16 relative in ≤ 8 iterations for
    ε ∈ [1e-4, 0.5]. Guards (see :class:`StrainStatus`): R_t ≤ 0, R_t > R0 (negative strain, returned and flagged),
    F ≤ 0 with a contact term, ε → 1 (flagged), NaN, R < 0, R = ∞. A NaN in the result always has a non-OK status.
    """
    r = np.asarray(r_ohm, dtype=np.float64)
    if not phys.has_contact and r.size:
        # Hot path of the no-contact inverse: one min/max pass proves every reading usable (NaN fails both).
        r_min, r_max = float(r.min()), float(r.max())
        # The ratio, not R, must be > 0: a subnormal R (5e-324 Ω) is > 0 but R/R0 underflows to 0 (log → -inf).
        if r_min / phys.R0_ohm > 0.0 and r_max < np.inf:
            eps, converged, iterations = _newton_strain(np.log(r / phys.R0_ohm), phys.tunnelling_k)
            status = np.zeros(r.shape, dtype=np.int8)
            if float(eps.min()) < 0.0:
                status[eps < 0.0] = StrainStatus.NEGATIVE_STRAIN
            if float(eps.max()) >= STRAIN_NEAR_ONE:
                status[eps >= STRAIN_NEAR_ONE] = StrainStatus.STRAIN_NEAR_ONE
            if not converged.all():
                status[~converged] = StrainStatus.NOT_CONVERGED
            return StrainResult(strain=eps, status=status, iterations=iterations)
    r, force = np.broadcast_arrays(r, np.asarray(force_n, dtype=np.float64))
    status = np.full(r.shape, StrainStatus.OK, dtype=np.int8)
    strain = np.full(r.shape, np.nan)

    nan_in = np.isnan(r) | (np.isnan(force) if phys.has_contact else False)
    status[nan_in] = StrainStatus.NAN_INPUT
    negative_r = ~nan_in & (r < 0.0)
    status[negative_r] = StrainStatus.NEGATIVE_RESISTANCE
    open_circuit = ~nan_in & np.isposinf(r)
    status[open_circuit] = StrainStatus.OPEN_CIRCUIT
    # R = 0, or so small that R/R0 underflows to 0: indistinguishable from a short (log would be -inf).
    short = ~nan_in & (r / phys.R0_ohm == 0.0)
    status[short] = StrainStatus.SHORT_CIRCUIT
    usable = ~(nan_in | negative_r | open_circuit | short)
    if phys.has_contact:
        no_force = usable & (force <= 0.0)
        status[no_force] = StrainStatus.NO_FORCE
        usable &= ~no_force
    with np.errstate(divide="ignore", invalid="ignore"):
        r_t = r - contact_resistance(np.where(usable, force, 1.0), phys)
    exceeds = usable & (r_t <= 0.0)
    status[exceeds] = StrainStatus.CONTACT_EXCEEDS_READING
    usable &= ~exceeds
    tunnel_short = usable & (r_t / phys.R0_ohm == 0.0)  # R_t > 0 but R_t/R0 underflows: a short at the tunnel
    status[tunnel_short] = StrainStatus.SHORT_CIRCUIT
    usable &= ~tunnel_short

    iterations = 0
    if np.any(usable):
        log_ratio = np.log(r_t[usable] / phys.R0_ohm)
        eps, converged, iterations = _newton_strain(log_ratio, phys.tunnelling_k)
        strain[usable] = eps
        sub = np.full(eps.shape, StrainStatus.OK, dtype=np.int8)
        sub[eps < 0.0] = StrainStatus.NEGATIVE_STRAIN
        sub[eps >= STRAIN_NEAR_ONE] = StrainStatus.STRAIN_NEAR_ONE
        sub[~converged] = StrainStatus.NOT_CONVERGED
        status[usable] = sub
    return StrainResult(strain=strain, status=status, iterations=iterations)
