"""A baseline that is not a linear drift is named as what it is, on fresh sensors (new seeds): one that settles
exponentially is fitted as settling (not as a linear drift, which read τ 12–21 % short with intervals that missed), a
step inside each trial is said to be a step (not a second creep arm or a drift) and the fit is refused as
degenerate; a step is told from a smooth misfit on rig-like trials the thresholds were not tuned on."""

from __future__ import annotations

import json

import numpy as np
import pytest

from models.calibration import STEP_SIGMAS, TrialInput, calibrate_sensor, calibrate_with_drift
from models.physics import PhysicsConstants
from models.synthetic import Readout, paper_protocol, random_sensor
from tests.models.test_poor_fit import FORCES_N, SENSORS, rig_trial

PHYS = PhysicsConstants()
READOUT = Readout()


def _fresh(seed: int, baseline, repeats: int = 1):
    """A fresh sensor's paper trials (0.2 % noise, 12-bit readout) with ``baseline(t, rng)`` (S) added to each."""
    rng = np.random.default_rng(seed)
    truth = random_sensor(rng)
    trials = paper_protocol(truth, PHYS, seed=seed, noise_rel=0.002, repeats=repeats)
    inputs = [TrialInput(t.name, t.time_s, t.force_n,
                         READOUT.quantise(t.conductance_s + baseline(t.time_s, rng))[0]) for t in trials]
    return truth, inputs


@pytest.mark.parametrize(("seed", "amplitude_s", "tau_b_s"), [(7311, 25e-6, 240.0), (7312, 12e-6, 90.0)])
def test_a_settling_baseline_is_named_and_fitted_as_settling_not_as_a_linear_drift(seed, amplitude_s, tau_b_s):
    truth, trials = _fresh(seed, lambda t, _rng: amplitude_s * -np.expm1(-t / tau_b_s))
    cal = calibrate_with_drift(trials, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s)
    assert cal.drift_s_per_s is not None and cal.drift_tau_s == pytest.approx(tau_b_s, rel=0.1)
    assert cal.drift_s_per_s * cal.drift_tau_s == pytest.approx(amplitude_s, rel=0.1)
    assert float(cal.sls.tau_s) == pytest.approx(float(truth.params_at(3.0).tau_s), rel=0.03)
    assert any(w.startswith("the baseline settles, it does not drift") for w in cal.warnings)
    assert not any(w.startswith("baseline drift of") for w in cal.warnings)
    entry = json.loads(json.dumps(cal.to_dict()))
    assert entry["drift_settling_tau_s"] == pytest.approx(cal.drift_tau_s)


def test_a_linear_drift_is_not_taken_for_a_settling_baseline():
    truth, trials = _fresh(7313, lambda t, _rng: 0.1e-6 * t)
    cal = calibrate_with_drift(trials, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s)
    assert cal.drift_s_per_s == pytest.approx(0.1e-6, rel=0.05)
    assert cal.drift_tau_s == float("inf") and "drift_settling_tau_s" not in cal.to_dict()
    assert any(w.startswith("baseline drift of") for w in cal.warnings)


@pytest.mark.parametrize("seed", [7321, 7322])
def test_a_step_inside_each_trial_is_named_and_refused_not_read_as_drift_or_arm(seed):
    """A reading that jumps by 1–2 % at a random time of each hold, the force unchanged (a connector shift): it was
    fitted as a linear drift or a second creep arm."""

    def step(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(8e-6, 15e-6) * (t >= rng.uniform(120.0, 300.0))

    truth, trials = _fresh(seed, step)
    cal = calibrate_with_drift(trials, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s)
    assert len(cal.steps) >= 3, cal.steps
    assert cal.degenerate and any("a step in the reading" in r for r in cal.degenerate_reasons)
    for report in cal.trials:
        if report.name in {s.trial for s in cal.steps}:
            assert report.refused is not None and "a step in the reading" in report.refused
    assert cal.drift_s_per_s is None  # not looked for: a step would read as one
    assert not any("baseline drift of" in w or "second, slower creep is resolved" in w for w in cal.warnings)
    entry = json.loads(json.dumps(cal.to_dict()))
    assert entry["creep_second_arm"]["checked"] is False and entry["reading_steps"]


@pytest.mark.parametrize("defect", ["", "relaxes", "drift", "step", "slip"])
def test_a_step_is_told_from_a_smooth_misfit_on_rig_trials(defect):
    """Rig-like trials (the reference in encoder ticks, the 12-bit readout) of three sensors: a step in the reading
    and a probe slip the reference misses are steps; a good fit, a sensor that relaxes instead of creeping and a
    1 µS/s drift are not (they bend the residual smoothly)."""
    for sensor, noise in (("soft_slow", 0.3), ("stiff_fast", 1.5), ("trend", 0.8)):
        truth = SENSORS[sensor]
        trials = [rig_trial(truth.params_at(f), f, seed + 40, noise_counts=noise, defect=defect)
                  for seed, f in enumerate(FORCES_N)]
        cal = calibrate_sensor(trials, 1.4e-3, PHYS, saturation_s=READOUT.saturation_s)
        found = {step.trial for step in cal.steps}
        if defect in ("step", "slip"):
            assert found == {t.name for t in trials}, (sensor, cal.steps)
            assert all(step.sigmas > STEP_SIGMAS and 140.0 < step.time_s < 160.0 for step in cal.steps)
        else:
            assert not found, (sensor, cal.steps)
