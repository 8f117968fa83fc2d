"""Fitting honestly: the fitter finds the optimum or says why not — degenerate fits are marked, a trial at the readout's
ceiling whose own fit cannot place τ refused with the reason, τ → 0 / τ → ∞ named as such, no false 'no loading
ramp' warnings."""

from __future__ import annotations

import numpy as np
import pytest

from models.calibration import TrialInput, calibrate_sensor
from models.errors import FlatSensorError
from models.physics import PhysicsConstants
from models.synthetic import TYPICAL_TRUTH, SensorTruth, make_trial, paper_protocol

PHYS = PhysicsConstants()
CEILING_S = 1.0 / 900.0


def _inputs(trials):
    return [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]


def test_well_formed_trials_get_no_false_ramp_warnings():
    """A loading step faster than one sample is still a recorded loading: E0 is identified."""
    trials = paper_protocol(TYPICAL_TRUTH, PHYS, seed=1, repeats=1, noise_rel=0.001, ramp_s=0.1)
    cal = calibrate_sensor(_inputs(trials), TYPICAL_TRUTH.area_m2, PHYS, saturation_s=CEILING_S)
    assert not any("loading ramp" in w for t in cal.trials for w in t.warnings)
    assert not any("loading ramp" in w for w in cal.warnings)
    assert not cal.degenerate and cal.to_dict()["degenerate"] is False
    assert float(cal.sls.E0_Pa) == pytest.approx(6e5, rel=0.01)


def test_record_that_starts_loaded_is_warned():
    trials = [make_trial(TYPICAL_TRUTH, PHYS, f, seed=i, preload_s=0.0, ramp_s=0.0, noise_rel=0.001,
                         name=f"F{f}") for i, f in enumerate((1.75, 4.0))]
    # the record starts at its hold force: conductance creeps, force constant from the first sample
    cal = calibrate_sensor(_inputs(trials), TYPICAL_TRUTH.area_m2, PHYS)
    assert all(any(w.startswith("no loading ramp") for w in t.warnings) for t in cal.trials)


def test_unresolvable_creep_is_degenerate_with_the_right_reason():
    """τ = 1e7 s over 370 s records: no creep is visible; τ → 0 and τ → ∞ look alike; marked degenerate, named."""
    slow = SensorTruth.constant(6.0e5, 9.0e5, 9.0e12)
    trials = paper_protocol(slow, PHYS, seed=4, repeats=1, noise_rel=0.002)
    cal = calibrate_sensor(_inputs(trials), slow.area_m2, PHYS)
    assert cal.degenerate
    assert any("no creep is resolved" in r and "τ → ∞" in r for r in cal.degenerate_reasons)
    entry = cal.to_dict()
    assert entry["degenerate"] is True and entry["degenerate_reasons"] == list(cal.degenerate_reasons)
    assert not any("flat" in w for w in cal.warnings)


def test_constant_force_and_conductance_names_the_elastic_case_not_a_broken_sensor():
    t = np.arange(0.0, 370.0, 1 / 6)
    rng = np.random.default_rng(0)
    trial = TrialInput("held.csv", t, np.full(t.size, 3.0), 6e-4 * (1 + rng.normal(0, 1e-4, t.size)))
    with pytest.raises(FlatSensorError, match=r"force is constant throughout.*τ → 0 or τ → ∞"):
        calibrate_sensor([trial], TYPICAL_TRUTH.area_m2, PHYS)


def test_mostly_censored_trial_is_refused_for_the_table_and_says_why():
    """A trial whose whole hold sits at the readout ceiling reports no per-trial E1 (was 0.44 Pa): its own fit cannot
    place τ, and the reason names the ceiling (a trial only partly there keeps its interval:
    tests/models/test_fit_ceiling_rates.py)."""
    strong = SensorTruth.constant(3.0e5, 5.0e5, 5.0e7)  # saturates the default readout at 5.25 N
    trials = [make_trial(strong, PHYS, f, seed=i, noise_rel=0.001, name=f"F{f}") for i, f in enumerate((1.75, 5.25))]
    clipped = [TrialInput(t.name, t.time_s, t.force_n, np.minimum(t.conductance_s, CEILING_S)) for t in trials]
    cal = calibrate_sensor(clipped, strong.area_m2, PHYS, saturation_s=CEILING_S)
    refused = {t.name: t.refused for t in cal.trials}
    assert refused["F1.75"] is None
    assert refused["F5.25"] is not None and "saturated" in refused["F5.25"]
    entry = cal.to_dict()["trials"][1]
    assert entry["E1_Pa"] is None and entry["refused"] == refused["F5.25"]


@pytest.mark.parametrize("tau_s, side", [(0.01, "shorter than one sample step"), (1e5, "longer than the records")])
def test_creep_faster_than_a_sample_or_slower_than_the_records_is_degenerate_naming_the_side(tau_s, side):
    """τ → 0 (0.01 s at 6 Hz) and τ → ∞ (1e5 s under 370 s holds): refused as degenerate with the right reason,
    never as a flat sensor, and estimate would refuse the file (its 'degenerate' is true)."""
    truth = SensorTruth.constant(6.0e5, 9.0e5, 9.0e5 * tau_s)
    trials = paper_protocol(truth, PHYS, seed=1, repeats=1, noise_rel=0.002)
    cal = calibrate_sensor(_inputs(trials), truth.area_m2, PHYS, saturation_s=CEILING_S)
    assert cal.degenerate and cal.to_dict()["degenerate"] is True
    assert any(side in r and "τ → 0 and τ → ∞" in r for r in cal.degenerate_reasons)
    assert not any("flat" in w for w in cal.warnings)


def test_disconnected_sensor_is_refused_by_name():
    t = np.arange(0.0, 370.0, 1 / 6)
    dead = TrialInput("dead.csv", t, np.where(t > 5, 3.0, 0.0), np.zeros(t.size))
    with pytest.raises(FlatSensorError, match=r"dead.csv: conductance is zero throughout: the sensor is disconnected"):
        calibrate_sensor([dead], TYPICAL_TRUTH.area_m2, PHYS)
