"""Slow-creep sensors (τ = mu1/E1 of 800, 1600, 3000 s under 370 s holds) at 0, 0.2 and 1 %
conductance noise. Each fit must reach the optimum (a cost no worse than the truth's), hold the truth inside its
95 % intervals, and estimate a held-out record to a few mN; never collapse to τ → 0 as it once did (τ ≈ 1e-17 s,
0.11 N RMS, exit 0). Trials that alone cannot resolve τ are refused for the per-trial table with the reason."""

from __future__ import annotations

import numpy as np
import pytest

from models.calibration import TrialInput, calibrate_sensor
from models.fit_output import FitTrial, trial_costs
from models.fit_profile import profile_tau
from models.physics import PhysicsConstants
from models.sls import conductance_from_force, force_from_conductance
from models.synthetic import SensorTruth, paper_protocol

PHYS = PhysicsConstants()
CEILING_S = 1.0 / 900.0


def _truth(tau_s: float) -> SensorTruth:
    return SensorTruth.constant(6.0e5, 9.0e5, 9.0e5 * tau_s)


@pytest.mark.parametrize("noise", [0.0, 0.002, 0.01])
@pytest.mark.parametrize("tau_s", [800.0, 1600.0, 3000.0])
def test_slow_creep_is_recovered_with_honest_intervals(tau_s, noise):
    truth = _truth(tau_s)
    trials = paper_protocol(truth, PHYS, seed=0, noise_rel=noise)
    cal = calibrate_sensor([TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials],
                           truth.area_m2, PHYS, saturation_s=CEILING_S)
    assert not cal.degenerate, cal.degenerate_reasons
    # The optimum: never a cost above the truth's (the collapse had ~2× the truth's cost).
    fit_trials = [FitTrial(t.name, t.time_s, t.force_n, t.conductance_s, t.nominal_force_n) for t in trials]
    costs = trial_costs(fit_trials, truth.area_m2, PHYS, [cal.sls, truth.params_at(3.0)], saturation_s=CEILING_S,
                        min_force_fraction=0.05).sum(axis=1)
    assert costs[0] <= costs[1] * (1 + 1e-9) + 1e-20
    # Honest intervals: the truth inside each 95 % interval; τ within a factor 2.5.
    for name in ("E0_Pa", "E1_Pa", "mu1_Pa_s"):
        lo, hi = cal.sls_ci95[name]
        # (noise-free fits end at rounding level: the interval is then ~1e-15 wide, hence the 1e-9 slack)
        assert lo * (1 - 1e-9) <= float(getattr(truth.params_at(3.0), name)) <= hi * (1 + 1e-9), (name, lo, hi)
    assert tau_s / 2.5 < float(cal.sls.tau_s) < tau_s * 2.5
    # τ's profile-likelihood interval (no linearisation) holds the truth too, and is written to the file.
    lo, hi = cal.tau_ci95
    assert lo <= tau_s <= hi
    assert cal.to_dict()["tau_s_ci95"] == [lo, hi if np.isfinite(hi) else None]
    if noise == 0.0:
        assert float(cal.sls.tau_s) == pytest.approx(tau_s, rel=1e-6)
    # A held-out two-step record estimated with the fitted parameters: a few mN at most (was 0.11 N RMS).
    t = np.arange(0.0, 600.0, 1 / 6)
    force = np.where(t >= 300.0, 4.5, np.where(t >= 10.0, 2.0, 0.0))
    c = conductance_from_force(t, force, truth.params_at(3.0), truth.area_m2, PHYS)
    estimate = force_from_conductance(t, c, cal.sls, truth.area_m2, PHYS)
    loaded = force > 0
    assert float(np.sqrt(np.mean((estimate[loaded] - force[loaded]) ** 2))) < 0.005
    # A per-trial result is either reported with a τ the record resolves, or refused saying why.
    for report in cal.trials:
        if report.refused is None:
            assert 1 / 6 <= float(report.params.tau_s) <= 100 * 370
        else:
            assert "τ" in report.refused or "singular" in report.refused


def test_noisy_slow_creep_names_what_a_single_trial_cannot_resolve():
    """At 1 % noise and τ = 3000 s some 370 s trials alone push τ to the search bound: refused, not tabled."""
    truth = _truth(3000.0)
    trials = paper_protocol(truth, PHYS, seed=0, noise_rel=0.01)
    cal = calibrate_sensor([TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials],
                           truth.area_m2, PHYS, saturation_s=CEILING_S)
    refused = [r for r in cal.trials if r.refused is not None]
    assert refused
    for report in refused:
        entry = report.to_dict()
        assert entry["E1_Pa"] is None and "does not identify" in entry["refused"]
    assert any("E1_Pa poorly identified" in w for w in cal.warnings)
    assert not np.isfinite(cal.tau_ci95[1])  # 370 s holds do not bound a 3000 s creep from above at 1 % noise
    assert any(w.startswith("creep time τ not bounded above") for w in cal.warnings)


def test_profile_interval_for_tau_is_bounded_when_the_records_bound_it_and_open_when_not():
    taus = np.geomspace(1 / 12, 37000.0, 41)
    tight = paper_protocol(_truth(800.0), PHYS, seed=0, noise_rel=0.002)
    loose = paper_protocol(_truth(3000.0), PHYS, seed=0, noise_rel=0.01)
    for trials, truth_tau, closed in ((tight, 800.0, True), (loose, 3000.0, False)):
        fit_trials = [FitTrial(t.name, t.time_s, t.force_n, t.conductance_s, t.nominal_force_n) for t in trials]
        lo, hi = profile_tau(fit_trials, 1.4e-3, PHYS, taus).tau_interval()
        assert lo <= truth_tau <= hi
        assert np.isfinite(hi) == closed


@pytest.mark.parametrize("seed", [3, 7, 11])
def test_a_tau_interval_always_holds_its_own_estimate_and_a_disagreement_is_said(seed):
    """With a baseline drift of +0.2 µS/s the fit once printed τ 321.89 s with a 95 % interval [305.92, 316.03]
    — the estimate outside its own interval, silently. Now the interval always holds the estimate, and when the
    profile put it elsewhere the fit says so."""
    truth = _truth(100.0)
    for drift, expect_said in ((0.2e-6, True), (0.0, False)):
        trials = paper_protocol(truth, PHYS, seed=seed, noise_rel=0.002, drift_s_per_s=drift)
        cal = calibrate_sensor([TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials],
                               truth.area_m2, PHYS, saturation_s=CEILING_S)
        lo, hi = cal.tau_ci95
        tau = float(cal.sls.tau_s)
        assert lo <= tau <= hi, (drift, lo, tau, hi)
        said = [w for w in cal.warnings if "outside its 95 % profile interval" in w]
        # With the drift (τ fitted ~2× the truth) the disagreement is said; without it, no false alarm.
        assert bool(said) == expect_said, (drift, tau, cal.tau_ci95, cal.warnings)
        if said:
            assert f"{tau:.4g}" in said[0] and "should not be trusted" in said[0]
