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

Where the code lives (one concern per module; this module re-exports them all, so ``from models.sls import …`` is
the one import the rest of the code needs):

- :mod:`models.sls_model`: the parameters (``SLSParams``, ``SLSTrend``, Eq. 6 conversions, the typical sensor) and
  the inverse's result vocabulary (``ForceStatus``, ``ForceResult``).
- :mod:`models.sls_recursion`: input checks, step coefficients and the forward recursion (force → strain →
  conductance), plus the :func:`engine` switch between the compiled kernels and the numpy reference.
- :mod:`models.sls_contact`: the per-step contact solve (safeguarded Newton in log F).
- :mod:`models.sls_inverse`: the streaming inverse ``SLSInverse`` and ``force_from_conductance(_trend)``.
- :mod:`models.sls_kernels`: the compiled (numba) twins of the recursions.

Every function and class here is pure numerics and may be called from any thread; an :class:`SLSInverse` instance
holds state and must be used from one thread at a time.
"""

from __future__ import annotations

from models.sls_contact import _solve_contact_scalar as _solve_contact_scalar
from models.sls_contact import _solve_contact_step as _solve_contact_step
from models.sls_inverse import SLSInverse, force_from_conductance, force_from_conductance_trend
from models.sls_model import (
    FORCE_STATUS_TEXT,
    SLS_KEYS,
    TYPICAL_AREA_M2,
    TYPICAL_FORCES_N,
    TYPICAL_SLS,
    ForceResult,
    ForceStatus,
    SLSParams,
    SLSTrend,
    abc_from_sls,
    explain_force_status,
    sls_from_abc,
)
from models.sls_recursion import (
    ENGINES,
    INTERPOLATIONS,
    check_timestamps,
    conductance_from_force,
    engine,
    one_minus_phi1,
    strain_from_force,
    strain_from_force_superposition,
    strain_from_force_trend,
)

__all__ = [
    "ENGINES",
    "FORCE_STATUS_TEXT",
    "INTERPOLATIONS",
    "SLS_KEYS",
    "TYPICAL_AREA_M2",
    "TYPICAL_FORCES_N",
    "TYPICAL_SLS",
    "ForceResult",
    "ForceStatus",
    "SLSInverse",
    "SLSParams",
    "SLSTrend",
    "abc_from_sls",
    "check_timestamps",
    "conductance_from_force",
    "engine",
    "explain_force_status",
    "force_from_conductance",
    "force_from_conductance_trend",
    "one_minus_phi1",
    "sls_from_abc",
    "strain_from_force",
    "strain_from_force_superposition",
    "strain_from_force_trend",
]
