"""The paper's linear calibration (Eq. 1): fit, inverse, baseline drift handling."""

from __future__ import annotations

import numpy as np
import pytest

from models.linear import (
    LinearModel,
    fit_linear,
    fit_linear_trials,
    paper_negative_offset,
    trial_baseline,
    trial_mean,
)


def _trial(force_n, baseline_s, m=2e-4, d=1e-4, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 370.0, 1 / 6)
    force = np.where(t >= 20.0, force_n, 0.0)
    cond = baseline_s + np.where(t >= 20.0, m * force + d, 0.0) + rng.normal(0, 1e-7, t.size)
    return t, force, cond


def test_model_forward_and_inverse_are_consistent():
    model = LinearModel(2e-4, 1e-4)
    force = np.array([0.0, 1.75, 5.25])
    assert np.allclose(model.force_from_conductance(model.conductance_from_force(force)), force, rtol=1e-14)
    assert LinearModel.from_dict(model.to_dict()) == model


def test_inverse_refuses_a_non_positive_slope_and_constructor_non_finite():
    with pytest.raises(ValueError, match="m_S_per_N"):
        LinearModel(0.0, 1e-4).force_from_conductance(1e-3)
    with pytest.raises(ValueError, match="d_S"):
        LinearModel(1.0, float("nan"))


def test_fit_recovers_an_exact_line_with_r2_one():
    force = np.array([1.75, 3.0, 4.0, 5.25] * 3)
    fit = fit_linear(force, 2e-4 * force + 1e-4)
    assert LinearModel.fit(force, 2e-4 * force + 1e-4).model == fit.model
    assert fit.model.m_S_per_N == pytest.approx(2e-4, rel=1e-12)
    assert fit.model.d_S == pytest.approx(1e-4, rel=1e-10)
    assert fit.r_squared == pytest.approx(1.0, abs=1e-12)
    assert fit.rmse_S < 1e-15
    assert fit.warnings == ()


def test_fit_with_noise_reports_residuals_and_r2():
    rng = np.random.default_rng(1)
    force = np.repeat([1.75, 3.0, 4.0, 5.25], 3)
    cond = 2e-4 * force + 1e-4 + rng.normal(0, 2e-5, force.size)
    fit = fit_linear(force, cond)
    assert 0.9 < fit.r_squared < 1.0
    assert np.allclose(fit.residuals_S, cond - fit.model.conductance_from_force(force))
    assert fit.rmse_S == pytest.approx(np.sqrt(np.mean(fit.residuals_S**2)))


def test_fit_refuses_one_force_and_warns_on_flat_or_negative_sensor():
    with pytest.raises(ValueError, match="two or more distinct forces"):
        fit_linear([3.0, 3.0], [1e-3, 1.1e-3])
    flat = fit_linear([1.0, 2.0, 3.0], [1e-3, 1e-3, 1e-3])
    assert np.isnan(flat.r_squared)
    assert any("flat-lined" in w for w in flat.warnings)
    assert any("not positive" in w for w in flat.warnings)
    skipped = fit_linear([1.0, 2.0, np.nan], [1.0, 2.0, 3.0])
    assert any("left out" in w for w in skipped.warnings)


def test_trial_mean_and_baseline():
    t, force, cond = _trial(3.0, 5e-5)
    assert trial_mean(t, cond) == pytest.approx(5e-5 + 2e-4 * 3.0 + 1e-4, rel=1e-5)
    assert trial_baseline(t, force, cond) == pytest.approx(5e-5, rel=1e-3)
    assert trial_baseline(t, np.full(t.size, 3.0), cond) is None
    with pytest.raises(ValueError, match="no valid samples in the window"):
        trial_mean(t, cond, (400.0, 500.0))


def test_fit_from_trials_with_per_trial_baseline_removes_drift():
    # Each trial starts from a different unloaded baseline (drift); subtracting it recovers the true line.
    trials = [
        _trial(f, b, seed=i) for i, (f, b) in enumerate(zip([1.75, 3.0, 4.0, 5.25], [0.0, 4e-5, -3e-5, 6e-5]))
    ]
    drifting = fit_linear_trials(trials)
    corrected = LinearModel.fit_trials(trials, subtract_baseline=True)
    assert corrected.model.m_S_per_N == pytest.approx(2e-4, rel=1e-3)
    assert corrected.model.d_S == pytest.approx(1e-4, rel=1e-2)
    assert corrected.r_squared > drifting.r_squared
    assert corrected.baseline_s.shape == (4,)


def test_paper_negative_offset_shifts_each_column_by_its_most_negative_value():
    force = np.array([[-0.2, 1.0], [0.5, 2.0], [np.nan, 3.0]])
    shifted, offset = paper_negative_offset(force)
    assert np.allclose(offset, [0.2, 0.0])
    assert np.nanmin(shifted[:, 0]) == pytest.approx(0.0)
    assert np.array_equal(shifted[:, 1], force[:, 1])
