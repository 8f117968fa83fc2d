"""The paper's estimators: Eq. 9 separable fit, Eqs. 7–8 regression with its refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.fit_paper import fit_exponential, fit_paper_ls
from models.sls import SLSParams, abc_from_sls, sls_from_abc, strain_from_force

AREA_M2 = 1.4e-3
TRUTH = SLSParams(6.0e5, 9.0e5, 9.0e7)


@pytest.mark.parametrize(("c1", "c2", "c3"), [(8e-4, -2e-4, 0.01), (5e-4, 1e-4, 0.2), (1e-3, -3e-4, 0.002)])
def test_exponential_fit_recovers_noise_free_curve(c1, c2, c3):
    t = np.arange(0, 370, 1 / 6) + 7.0
    y = c1 + c2 * np.exp(-c3 * (t - t[0]))
    fit = fit_exponential(t, y)
    assert fit.c1 == pytest.approx(c1, rel=1e-7)
    assert fit.c2 == pytest.approx(c2, rel=1e-6)
    assert fit.c3 == pytest.approx(c3, rel=1e-6)
    np.testing.assert_allclose(fit(t), y, rtol=1e-8)


def test_exponential_fit_skips_nan_and_tolerates_noise():
    rng = np.random.default_rng(4)
    t = np.arange(0, 370, 1 / 6)
    y = 8e-4 - 2e-4 * np.exp(-0.01 * t) + rng.normal(0, 1e-6, t.size)
    y[::50] = np.nan
    fit = fit_exponential(t, y)
    assert fit.c3 == pytest.approx(0.01, rel=0.02)
    assert fit.rmse_s == pytest.approx(1e-6, rel=0.1)


def test_abc_round_trip():
    a, b, c = abc_from_sls(6e5, 9e5, 9e7)
    assert sls_from_abc(a, b, c) == pytest.approx((6e5, 9e5, 9e7), rel=1e-12)
    assert all(math.isnan(v) for v in sls_from_abc(a, b, 0.5 * a * b))  # c/a < b: E1 would be negative


def _excited_record():
    """A sinusoidal stress with exact model strain, sampled finely enough for accurate derivatives."""
    t = np.linspace(0, 600, 60001)
    force = 3.0 + 1.5 * np.sin(2 * np.pi * t / 200.0)
    strain = strain_from_force(t, force, TRUTH, AREA_M2, interp="linear")
    stress = force / AREA_M2
    return t, stress, strain, np.gradient(strain, t), np.gradient(stress, t)


def test_paper_ls_recovers_parameters_when_stress_varies():
    t, stress, strain, strain_rate, stress_rate = _excited_record()
    keep = t > 5  # skip the start-up from rest
    result = fit_paper_ls(stress[keep], strain[keep], strain_rate[keep], stress_rate[keep])
    assert result.ok, result.warnings
    assert result.E0_Pa == pytest.approx(6e5, rel=1e-3)
    assert result.E1_Pa == pytest.approx(9e5, rel=1e-3)
    assert result.mu1_Pa_s == pytest.approx(9e7, rel=1e-3)


def test_paper_ls_reports_rank_deficiency_on_a_pure_hold():
    t = np.arange(0, 370, 1 / 6)
    force = np.full(t.size, 3.0)
    strain = strain_from_force(t, force, TRUTH, AREA_M2)
    result = fit_paper_ls(force / AREA_M2, strain, np.gradient(strain, t), np.zeros(t.size))
    assert not result.ok
    assert math.isnan(result.E0_Pa) and math.isnan(result.mu1_Pa_s)
    assert "rank-deficient" in result.warnings[0] and "σ̇" in result.warnings[0]


def test_paper_ls_reports_unidentified_coefficient_when_stress_rate_is_noise():
    rng = np.random.default_rng(1)
    t = np.arange(0, 370, 1 / 6)
    force = 3.0 + rng.normal(0, 1e-3, t.size)
    strain = strain_from_force(t, np.full(t.size, 3.0), TRUTH, AREA_M2)
    result = fit_paper_ls(force / AREA_M2, strain, np.gradient(strain, t), np.gradient(force / AREA_M2, t))
    assert not result.ok
    assert "not identified" in result.warnings[0]


def test_paper_ls_reports_non_physical_result():
    t, stress, strain, strain_rate, stress_rate = _excited_record()
    keep = t > 5
    # Flipping the sign of σ̇ makes a < 0: Eq. 6 has no physical inverse.
    result = fit_paper_ls(stress[keep], strain[keep], strain_rate[keep], -stress_rate[keep])
    assert not result.ok
    assert "non-physical" in result.warnings[0]
    assert result.a_s < 0
