"""Output-error fits: recovery of known truth, CasADi = scipy = the project's forward model, honest intervals."""

from __future__ import annotations

import numpy as np
import pytest

from models.fit_output import PARAM_NAMES, FitTrial, casadi_conductance, fit_output_casadi, fit_output_scipy
from models.physics import PhysicsConstants
from models.sls import SLSParams, conductance_from_force
from models.synthetic import TREND_TRUTH, TYPICAL_TRUTH, Readout, SensorTruth, paper_protocol

PHYS = PhysicsConstants()
AREA_M2 = TYPICAL_TRUTH.area_m2
START = SLSParams(4.5e5, 6.5e5, 5e7)  # ~30 % off the truth, like a derivative-free estimate on noisy data


def _fit_trials(trials):
    return [FitTrial(t.name, t.time_s, t.force_n, t.conductance_s, t.nominal_force_n) for t in trials]


def _rel_errors(params, truth):
    return np.array([abs(float(getattr(params, n)) / float(getattr(truth, n)) - 1) for n in PARAM_NAMES])


def test_casadi_graph_equals_the_sls_forward_model():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.05, 0.5, 400))  # non-uniform steps
    force = 0.2 + 4 * np.abs(np.sin(t / 9))
    trials = [FitTrial("a", t, force, np.ones(t.size), 3.0),
              FitTrial("b", t[:250], 1.3 * force[:250], np.ones(250), 3.0)]
    params = SLSParams(5e5, 7e5, 3e7)
    for trial, model in zip(trials, casadi_conductance(trials, AREA_M2, PHYS, params)):
        reference = conductance_from_force(trial.time_s, trial.force_n, params, AREA_M2, PHYS)
        np.testing.assert_allclose(model, reference, rtol=1e-12)


@pytest.mark.parametrize("solver", ["scipy", "gauss-newton", "ipopt"])
def test_noise_free_joint_fit_recovers_truth(solver):
    trials = _fit_trials(paper_protocol(TYPICAL_TRUTH, PHYS, repeats=1))
    if solver == "scipy":
        fit = fit_output_scipy(trials, AREA_M2, PHYS, START)
    else:
        fit = fit_output_casadi(trials, AREA_M2, PHYS, START, solver=solver)
    assert fit.success, fit.message
    assert np.max(_rel_errors(fit.ref, TYPICAL_TRUTH.params_at(0))) <= 1e-6
    assert max(fit.rmse_s) < 1e-12


def test_noise_free_trend_fit_recovers_intercepts_and_slopes():
    trials = _fit_trials(paper_protocol(TREND_TRUTH, PHYS, repeats=1))
    fit = fit_output_scipy(trials, AREA_M2, PHYS, START, "trend")
    for name in PARAM_NAMES:
        intercept, slope = fit.trend[name]
        true_intercept, true_slope = getattr(TREND_TRUTH, name)
        assert intercept == pytest.approx(true_intercept, rel=1e-6)
        assert slope == pytest.approx(true_slope, rel=1e-6)
        for part, value in (("slope", slope), ("intercept", intercept)):
            lo, hi = fit.ci95[f"{name}.{part}"]
            assert lo <= value <= hi


def test_noise_free_per_trial_fits_and_nan_samples_are_skipped():
    protocol = paper_protocol(TREND_TRUTH, PHYS, repeats=1)
    trials = _fit_trials(protocol)
    for trial in trials:
        trial.conductance_s[100::37] = np.nan  # dropped samples
        trial.force_n[500::53] = np.nan  # dropped force readings: held, not read as unloading
    fit = fit_output_scipy(trials, AREA_M2, PHYS, START, "per_trial")
    for params, synthetic in zip(fit.params, protocol):
        assert np.max(_rel_errors(params, synthetic.params)) <= 1e-6
    assert all(n < t.time_s.size - 50 for n, t in zip(fit.n_used, trials))


@pytest.mark.parametrize(("noise_rel", "median_limit"), [(0.001, 0.01), (0.01, 0.05)])
def test_noisy_fits_meet_the_accuracy_targets(noise_rel, median_limit):
    protocol = paper_protocol(TYPICAL_TRUTH, PHYS, seed=11, noise_rel=noise_rel)
    trials = _fit_trials(protocol)
    per_trial = fit_output_scipy(trials, AREA_M2, PHYS, START, "per_trial")
    errors = np.array([_rel_errors(p, TYPICAL_TRUTH.params_at(0)) for p in per_trial.params])
    assert np.all(np.median(errors, axis=0) <= median_limit), np.median(errors, axis=0)
    for p in per_trial.params:  # never non-physical
        assert all(np.isfinite(float(getattr(p, n))) and float(getattr(p, n)) > 0 for n in PARAM_NAMES)
    joint = fit_output_casadi(trials, AREA_M2, PHYS, START)
    assert np.all(_rel_errors(joint.ref, TYPICAL_TRUTH.params_at(0)) <= median_limit)


def test_saturated_samples_are_censored_not_fitted():
    # A softer sensor: at 5.25 N the readout saturates (C > 1/900 S).
    soft = SensorTruth.constant(4.0e5, 6.0e5, 6.0e7)
    readout = Readout()
    protocol = paper_protocol(soft, PHYS, seed=3, repeats=1, noise_rel=0.001, readout=readout)
    assert any(t.saturated.any() for t in protocol)
    trials = _fit_trials(protocol)
    censored = fit_output_scipy(trials, AREA_M2, PHYS, START, saturation_s=readout.saturation_s)
    naive = fit_output_scipy(trials, AREA_M2, PHYS, START)
    assert censored.n_censored > 0
    truth = soft.params_at(0)
    assert np.max(_rel_errors(censored.ref, truth)) < 0.01
    assert np.max(_rel_errors(naive.ref, truth)) > np.max(_rel_errors(censored.ref, truth))


@pytest.mark.slow
def test_confidence_intervals_cover_the_truth_about_95_percent():
    n_seeds = 40
    truth = TYPICAL_TRUTH.params_at(0)
    covered = np.zeros((n_seeds, 3), dtype=bool)
    for seed in range(n_seeds):
        trials = _fit_trials(paper_protocol(TYPICAL_TRUTH, PHYS, seed=100 + seed, repeats=1, noise_rel=0.005))
        fit = fit_output_scipy(trials, AREA_M2, PHYS, START)
        for k, name in enumerate(PARAM_NAMES):
            lo, hi = fit.ci95[name]
            covered[seed, k] = lo <= float(getattr(truth, name)) <= hi
    # Binomial: 40 draws at p = 0.95 → ≥ 34 covered with probability > 0.99 (per parameter).
    assert np.all(covered.sum(axis=0) >= 34), covered.sum(axis=0)
    # And the intervals are not vacuous: they must miss sometimes in 120 draws at 95 % (P(no miss) ≈ 0.2 %).
    assert covered.sum() < covered.size


@pytest.mark.parametrize("solver", ["scipy", "gauss-newton"])
def test_non_uniform_timestamps_and_unequal_lengths(solver):
    rng = np.random.default_rng(8)
    trials = []
    for i, force in enumerate((1.75, 3.0, 5.25)):
        t = np.cumsum(rng.uniform(0.1, 0.25, 1500 + 200 * i))  # jittered sampling, different lengths
        t -= t[0]
        applied = force * np.clip((t - 5.0) / 2.0, 0.0, 1.0)
        c = conductance_from_force(t, applied, TYPICAL_TRUTH.params_at(force), AREA_M2, PHYS)
        trials.append(FitTrial(f"t{i}", t, applied, c, force))
    if solver == "scipy":
        fit = fit_output_scipy(trials, AREA_M2, PHYS, START)
    else:
        fit = fit_output_casadi(trials, AREA_M2, PHYS, START, solver=solver)
    assert np.max(_rel_errors(fit.ref, TYPICAL_TRUTH.params_at(0))) <= 1e-6


def test_unidentifiable_creep_gives_a_wide_interval():
    # τ = 1e5 s in a 370 s record: the creep is a straight line, mu1 and E1 trade off.
    slow = SensorTruth.constant(6.0e5, 9.0e5, 9.0e10)
    trials = _fit_trials(paper_protocol(slow, PHYS, seed=2, repeats=1, noise_rel=0.01))
    fit = fit_output_scipy(trials, AREA_M2, PHYS, SLSParams(6e5, 9e5, 9e9))
    lo, hi = fit.ci95["E1_Pa"]
    assert (hi - lo) / float(fit.ref.E1_Pa) > 1.0


@pytest.mark.parametrize("mode", ["joint", "trend"])
def test_casadi_jacobian_matches_finite_differences(mode):
    import casadi as ca

    from models.fit_output import _casadi_graph, _Problem

    trials = _fit_trials(paper_protocol(TREND_TRUTH, PHYS, repeats=1, duration_s=120.0))
    problem = _Problem(trials, AREA_M2, PHYS, START, mode, None, 0.05, "hold")
    theta, model, derivatives = _casadi_graph(ca, problem)
    evaluate = ca.Function("f", [theta], [model, *derivatives])
    point = np.linspace(0.1, -0.2, problem.n_params)
    outputs = [np.asarray(x) for x in evaluate(point)]
    for k in range(problem.n_params):
        h = 1e-6
        up, down = point.copy(), point.copy()
        up[k] += h
        down[k] -= h
        central = (np.asarray(evaluate(up)[0]) - np.asarray(evaluate(down)[0])) / (2 * h)
        np.testing.assert_allclose(outputs[k + 1], central, rtol=1e-5, atol=1e-8 * np.max(np.abs(central)))


@pytest.mark.parametrize("solver", ["gauss-newton", "ipopt", "sqpmethod"])
def test_casadi_and_scipy_agree_on_a_sensor_at_the_readouts_ceiling(solver):
    """The censored (Tobit) likelihood is the same in both paths: 61 % of the 5.25 N holds at the ceiling."""
    readout = Readout()
    synthetic = paper_protocol(SensorTruth.constant(4.5e5, 8e5, 8e7), PHYS, seed=4, noise_rel=0.002, readout=readout)
    assert float(np.mean(synthetic[-1].saturated)) > 0.5
    trials = [FitTrial(t.name, t.time_s, t.force_n, t.conductance_s, t.nominal_force_n) for t in synthetic]
    start = SLSParams(4e5, 7e5, 6e7)
    for mode in ("joint", "trend"):
        reference = fit_output_scipy(trials, AREA_M2, PHYS, start, mode, saturation_s=readout.saturation_s)
        fit = fit_output_casadi(trials, AREA_M2, PHYS, start, mode, saturation_s=readout.saturation_s, solver=solver)
        assert fit.success
        for name in PARAM_NAMES:
            assert float(getattr(fit.ref, name)) == pytest.approx(float(getattr(reference.ref, name)), rel=1e-6)
        assert sum(fit.cost_per_trial) == pytest.approx(sum(reference.cost_per_trial), rel=1e-9)
