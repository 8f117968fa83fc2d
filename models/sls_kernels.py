"""Compiled time loops of the SLS recursion (numba), vectorised across sensors: the forward creep strain and the
conductance → force inverse. The pure-numpy paths in :mod:`models.sls` stay the exact reference; tests hold these to
them (``tests/models/test_sls_kernels.py``).

numba is imported lazily, on the first call of :func:`kernels` (never at module import), so ``sensnake --help`` and
the app's start do not pay for it; compiled code is cached on disk (``cache=True``), so only the very first run on a
machine compiles (~seconds), later processes load it (~0.1 s). When numba is missing, or ``SENSNAKE_NO_JIT=1``,
:func:`kernels` returns None and :mod:`models.sls` runs its numpy paths.

The kernels are written in the scalar subset numba compiles; run uncompiled they are plain (slow) Python with the
same results. Status codes are the integers of :class:`models.sls.ForceStatus` / :class:`models.physics.StrainStatus`
(repeated here as constants because compiled code cannot look enums up). Any thread may call them (no shared state).
"""

from __future__ import annotations

import math
import os
from types import SimpleNamespace

import numpy as np

# ForceStatus codes (models.sls) and StrainStatus codes (models.physics) used inside the kernels.
_OK, _NAN_INPUT, _OPEN_CIRCUIT, _NEGATIVE, _BELOW_BASELINE, _SATURATED, _NOT_CONVERGED = 0, 1, 2, 3, 4, 5, 6
_STRAIN_NEAR_ONE_CODE, _STRAIN_NOT_CONVERGED_CODE = 5, 7
_STRAIN_NEAR_ONE = 0.9
_NEWTON_MAX_ITER = 100
_ACCEPT_STEP_HALLEY = 1e-6  # relative: the cubic error left after a Halley step this small is ~1e-18
_BELOW_BASELINE_FLAG_N = 1e-9


def creep_strain(oma: np.ndarray, drive: np.ndarray, ramp: np.ndarray, use_ramp: bool, q0: np.ndarray,
                 out: np.ndarray) -> None:
    """Kelvin–Voigt strain q (N, S) into ``out``: ``q += oma·(drive[i−1] − q) + ramp·(drive[i] − drive[i−1])``
    (drive[−1] = 0). ``oma``/``ramp`` are (N, S) or (N, 1) (shared τ)."""
    n, s = drive.shape
    shared = oma.shape[1] == 1
    q = q0.copy()
    for i in range(n):  # time outer, sensors inner: rows of the (N, S) arrays are contiguous
        for j in range(s):
            jj = 0 if shared else j
            prev = drive[i - 1, j] if i > 0 else 0.0
            q[j] += oma[i, jj] * (prev - q[j])
            if use_ramp:
                q[j] += ramp[i, jj] * (drive[i, j] - prev)
            out[i, j] = q[j]


def solve_contact(cond: float, p: float, w: float, f_guess: float, k: float, r0: float, kc: float) -> tuple[float, int]:
    """One step's force F (N) with the contact term: the root of ``g(F) = C·(K/√F + R0·(1−ε)·e^(−kε)) − 1``,
    ε = p + w·F. g is convex and strictly decreasing (both resistance terms are), positive at ``(K·C)²`` (the contact
    term alone is 1/C there) and negative at ``F_max = (1 − p)/w`` (ε = 1) when ``K·C < √F_max``; otherwise the
    reading is beyond the ε → 1 limit (SATURATED, F = F_max), as in :func:`models.sls_contact._solve_contact_step`.

    Halley's method in F itself (one sqrt and one exp per iteration serve g, g' and g''; no logarithms: the reference
    solves by Newton in ln F and pays two more transcendental calls), warm-started at ``f_guess`` and kept inside the
    shrinking bracket, with a geometric bisection whenever a step would leave it. A relative step below
    ``_ACCEPT_STEP_HALLEY`` ends it (error ~step³). Measured (1 core, process time, shared machine): Halley + fastmath
    without nnan/ninf (NaN checks stay exact) 13-15 M sensor-samples/s at 36 sensors against 11-13 with Newton."""
    f_max = (1.0 - p) / w
    if not f_max > 0.0:
        return 0.0, _SATURATED
    f_lo = kc * cond * kc * cond
    if f_lo >= f_max:
        return f_max, _SATURATED
    if r0 * cond < 1e-17:
        # The tunnelling part (≤ R0) is below rounding next to 1/C: the root is the contact-only bound (K·C)²
        # (this also covers readings so small that F underflows, where Newton in F could not move).
        return f_lo, _OK
    f_hi = f_max
    f = f_guess if f_lo < f_guess < f_hi else math.sqrt(f_lo * f_hi) if f_lo > 0.0 else 0.5 * f_hi
    for _ in range(_NEWTON_MAX_ITER):
        inv_f = 1.0 / f
        contact = kc * math.sqrt(inv_f)
        eps = p + w * f
        one_minus = 1.0 - eps
        if one_minus > 0.0:
            decay = r0 * math.exp(-k * eps)
            g = cond * (contact + one_minus * decay) - 1.0
            slope = cond * (-0.5 * contact * inv_f - decay * (1.0 + k * one_minus) * w)
            curve = cond * (0.75 * contact * inv_f * inv_f + w * w * decay * k * (2.0 + k * one_minus))
        else:
            g = cond * contact - 1.0
            slope = cond * (-0.5 * contact * inv_f)
            curve = cond * (0.75 * contact * inv_f * inv_f)
        if g == 0.0:
            return f, _OK
        if g > 0.0:
            f_lo = f
        else:
            f_hi = f
        # Halley's step (cubic convergence; g' and g'' reuse the sqrt and exp): the error left after a step of
        # relative size s is ~s³, so a step below _ACCEPT_STEP_HALLEY ends it at rounding level.
        step = g / slope
        step = step / (1.0 - 0.5 * step * curve / slope)
        f_new = f - step
        inside = f_lo <= f_new <= f_hi
        if inside and abs(step) <= _ACCEPT_STEP_HALLEY * f:
            return f_new, _OK
        if not inside:
            f_new = math.sqrt(f_lo * f_hi) if f_lo > 0.0 else 0.5 * f_hi
        f = f_new
        if f_hi - f_lo <= 4e-16 * f:
            return f, _OK
    return f, _NOT_CONVERGED


def inverse(cond: np.ndarray, oma: np.ndarray, ramp: np.ndarray, use_ramp: bool, e0: np.ndarray, e1: np.ndarray,
            area: np.ndarray, contact: bool, k: float, r0: float, kc: float, strain: np.ndarray,
            strain_status: np.ndarray, q_state: np.ndarray, sig_state: np.ndarray, f_state: np.ndarray,
            force: np.ndarray, status: np.ndarray) -> None:
    """The conductance → force recursion of :meth:`models.sls.SLSInverse.update` (the algebra of its one-sensor
    path) for S sensors, **sensor-major**: every array is (S, N) — one contiguous row per sensor, so the state stays
    in registers along a row (the caller transposes). ``oma`` and ``ramp`` may each be (1, N) (shared τ). Without the contact
    term ``strain`` holds Eq. 3's strain of every reading and ``strain_status`` its codes (unused with contact). The
    state arrays (S,) are updated in place; ``status`` keeps codes that are already non-zero."""
    s, n = cond.shape
    shared = oma.shape[0] == 1
    ramp_shared = ramp.shape[0] == 1  # a shared τ's ramp is per sensor when only some steps need the linear fallback
    for j in range(s):
        jj = 0 if shared else j
        jr = 0 if ramp_shared else j
        inv_e0 = 1.0 / e0[j]
        inv_e1 = 1.0 / e1[j]
        a = area[j]
        q = q_state[j]
        sig_prev = sig_state[j]
        f_prev = f_state[j]
        for i in range(n):
            c = cond[j, i]
            p = q + oma[jj, i] * (sig_prev * inv_e1 - q)
            r_i = ramp[jr, i] if use_ramp else 0.0
            p -= r_i * sig_prev * inv_e1
            inv_eff = inv_e0 + r_i * inv_e1
            code = _OK
            if c != c:
                code = _NAN_INPUT
                sig = sig_prev
                f_out = math.nan
            elif c <= 0.0:
                code = _OPEN_CIRCUIT if c == 0.0 else _NEGATIVE
                sig = 0.0
                f_out = 0.0
            elif c == math.inf:
                code = _SATURATED
                sig = max((1.0 - p) / inv_eff, 0.0)
                f_out = sig * a
            elif contact:
                f_out, code = solve_contact(c, p, inv_eff / a, f_prev, k, r0, kc)
                if code == _OK and p + inv_eff / a * f_out >= _STRAIN_NEAR_ONE:
                    code = _SATURATED
                sig = f_out / a
            else:
                sig = (strain[j, i] - p) / inv_eff
                if strain_status[j, i] == _STRAIN_NEAR_ONE_CODE:
                    code = _SATURATED
                elif strain_status[j, i] == _STRAIN_NOT_CONVERGED_CODE:
                    code = _NOT_CONVERGED
                if sig < 0.0:
                    if code == _OK and sig * a < -_BELOW_BASELINE_FLAG_N:
                        code = _BELOW_BASELINE
                    sig = 0.0
                f_out = sig * a
            force[j, i] = f_out
            if status[j, i] == 0:
                status[j, i] = code
            q = p + r_i * sig * inv_e1
            sig_prev = sig
            if f_out > 0.0:
                f_prev = f_out
        q_state[j] = q
        sig_state[j] = sig_prev
        f_state[j] = f_prev


def disabled() -> bool:
    """``SENSNAKE_NO_JIT=1``: no compiled code at all (neither numba nor the C kernel of :mod:`models.sls_ckernel`)."""
    return os.environ.get("SENSNAKE_NO_JIT", "") == "1"


_KERNELS: SimpleNamespace | None = None
_TRIED = False


def kernels() -> SimpleNamespace | None:
    """The compiled kernels (``creep_strain``, ``inverse``), compiling or loading them on first use; None when numba
    is unavailable or ``SENSNAKE_NO_JIT=1`` (the caller then runs its numpy path). Any thread; the first call may take
    seconds on a machine that never compiled them."""
    global _KERNELS, _TRIED
    if _TRIED:
        return _KERNELS
    _TRIED = True
    if disabled():
        return None
    try:
        import numba
    except ImportError:
        return None
    # fastmath without "nnan"/"ninf": NaN and inf samples are tested inside the loops, so those checks stay exact;
    # fused multiply-add, reciprocal and approximate-function flags cost ≤ 1e-15 relative (tests hold it to 1e-9).
    jit = numba.njit(cache=True, nogil=True, fastmath={"contract", "arcp", "nsz", "afn"})
    global solve_contact
    solve_contact = jit(solve_contact)
    _KERNELS = SimpleNamespace(creep_strain=jit(creep_strain), inverse=jit(inverse))
    return _KERNELS
