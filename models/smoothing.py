"""Offline Tikhonov smoothing of an estimated force record (NUMERICS pitfall 2: a smoother only smooths).

Minimises ``Σ w_i·(F_i − F̂_i)² + λ·Σ (Δ^d F)_i²`` over the whole record, with ``d`` = 1 (penalise slope: the
random-walk prior, equivalent to a Rauch–Tung–Striebel smoother with process/measurement variance ratio 1/λ) or 2
(penalise curvature). The normal matrix ``W + λ·DᵀD`` is symmetric positive definite and banded, so the solve is
O(N) (``scipy.linalg.solveh_banded``), shared by all sensor columns. NaN samples get zero weight (the smoother
interpolates across them) and stay NaN in the output.

The penalty acts per sample, so it assumes roughly uniform sampling; :func:`tikhonov_lambda` turns a cut-off
frequency into λ for a given sample rate.

Pure numerics: any thread may call these.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solveh_banded


def tikhonov_lambda(rate_hz: float, cutoff_hz: float, order: int = 1) -> float:
    """λ that puts the smoother's gain at ½ (−6 dB) at ``cutoff_hz`` for samples at ``rate_hz``.

    Away from the record ends the smoother is the zero-phase filter ``H(ω) = 1/(1 + λ·(2 − 2cos ω)^d)``.
    """
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    if not (rate_hz > 0 and 0 < cutoff_hz < rate_hz / 2):
        raise ValueError(f"need 0 < cutoff_hz < rate_hz/2, got cutoff {cutoff_hz} Hz at {rate_hz} Hz")
    omega = 2.0 * math.pi * cutoff_hz / rate_hz
    return 1.0 / (2.0 - 2.0 * math.cos(omega)) ** order


def _penalty_bands(n: int, order: int) -> np.ndarray:
    """Upper-banded form (order+1, n) of DᵀD for the order-d difference operator D."""
    stencil = np.array([-1.0, 1.0]) if order == 1 else np.array([1.0, -2.0, 1.0])
    bands = np.zeros((order + 1, n))
    rows = n - order
    if rows <= 0:
        return bands
    # DᵀD = Σ_r d_rᵀ d_r with d_r the stencil placed at row r; accumulate each band.
    for offset in range(order + 1):
        for a in range(order + 1 - offset):
            coef = stencil[a] * stencil[a + offset]
            # entries (r + a, r + a + offset) for r = 0 … rows−1 live in column r + a + offset of band `offset`
            first_col = a + offset
            bands[order - offset, first_col : first_col + rows] += coef
    return bands


def smooth_tikhonov(force_n: np.ndarray, lam: float, order: int = 1) -> np.ndarray:
    """Tikhonov-smoothed copy of ``force_n`` ((N,) or (N, S), N), λ ≥ 0 in samples^(2·order). NaN stays NaN."""
    if not (math.isfinite(lam) and lam >= 0.0):
        raise ValueError(f"lam must be finite and ≥ 0, got {lam!r}")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    force = np.asarray(force_n, dtype=np.float64)
    was_1d = force.ndim == 1
    f2 = force[:, None] if was_1d else force
    if f2.ndim != 2:
        raise ValueError(f"force must be (N,) or (N, S), got shape {force.shape}")
    n = f2.shape[0]
    if n == 0 or lam == 0.0:
        return force.copy()
    nan = np.isnan(f2)
    out = np.empty_like(f2)
    penalty = lam * _penalty_bands(n, order)
    # Columns sharing a NaN pattern share a matrix: the common case (no NaN) is one banded solve for all.
    patterns: dict[bytes, list[int]] = {}
    for j in range(f2.shape[1]):
        patterns.setdefault(nan[:, j].tobytes(), []).append(j)
    for cols in patterns.values():
        weight = (~nan[:, cols[0]]).astype(np.float64)
        if not weight.any():
            out[:, cols] = np.nan
            continue
        ab = penalty.copy()
        ab[-1] += weight
        if weight.sum() <= order:
            # Too few points to pin a polynomial of the penalty's null space: add a tiny ridge.
            ab[-1] += 1e-12 * max(1.0, lam)
        rhs = np.where(nan[:, cols], 0.0, f2[:, cols])
        out[:, cols] = solveh_banded(ab, rhs, lower=False)
    out[nan] = np.nan
    return out[:, 0] if was_1d else out
