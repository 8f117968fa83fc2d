"""Offline Tikhonov smoother (models/smoothing.py) applied to estimated forces."""

from __future__ import annotations

import numpy as np
import pytest

from models.smoothing import smooth_tikhonov, tikhonov_lambda


@pytest.mark.parametrize("order", [1, 2])
def test_banded_solve_equals_the_dense_normal_equations(order):
    rng = np.random.default_rng(0)
    y = rng.normal(size=(50, 3))
    y[[4, 20, 21], 1] = np.nan
    lam = 7.5
    got = smooth_tikhonov(y, lam, order)
    d = np.diff(np.eye(50), n=order, axis=0)
    for j in range(3):
        w = (~np.isnan(y[:, j])).astype(float)
        ref = np.linalg.solve(np.diag(w) + lam * d.T @ d, np.where(w > 0, y[:, j], 0.0))
        ref[w == 0] = np.nan
        assert np.allclose(got[:, j], ref, rtol=1e-10, atol=1e-12, equal_nan=True)


def test_polynomials_in_the_null_space_pass_unchanged():
    t = np.arange(200.0)
    assert np.allclose(smooth_tikhonov(np.full(200, 3.0), 1e4, 1), 3.0)
    line = 0.5 + 0.01 * t
    assert np.allclose(smooth_tikhonov(line, 1e4, 2), line, rtol=1e-9)


@pytest.mark.parametrize("order", [1, 2])
def test_gain_is_one_half_at_the_requested_cutoff(order):
    rate_hz, cutoff_hz = 30.0, 0.5
    t = np.arange(6000) / rate_hz
    signal = np.sin(2 * np.pi * cutoff_hz * t)
    out = smooth_tikhonov(signal, tikhonov_lambda(rate_hz, cutoff_hz, order), order)
    middle = slice(1000, 5000)
    gain = np.sqrt(np.mean(out[middle] ** 2) / np.mean(signal[middle] ** 2))
    assert gain == pytest.approx(0.5, abs=0.02)  # H(ω_c) = 1/(1 + 1)


def test_refusals_and_edge_cases():
    with pytest.raises(ValueError, match="cutoff"):
        tikhonov_lambda(30.0, 20.0)
    with pytest.raises(ValueError, match="lam"):
        smooth_tikhonov(np.ones(3), -1.0)
    assert np.array_equal(smooth_tikhonov(np.array([1.0, 2.0]), 0.0), [1.0, 2.0])
    assert np.all(np.isnan(smooth_tikhonov(np.full(5, np.nan), 3.0)))
    single = smooth_tikhonov(np.array([np.nan, 2.0, np.nan]), 10.0, 2)
    assert single[1] == pytest.approx(2.0, rel=1e-6)
