"""A drifting baseline is found and separated from the creep, on draws the code was not tuned on: the paper
protocol (4 forces × 3 trials, 0.2 % noise, the 12-bit readout) with an additive drift of 0.2 and 0.02 µS/s, none,
and a sensor whose parameters grow with force (where a shared-parameter fit misfits and must not be read as drift)."""

from __future__ import annotations

import pytest

from models.calibration import TrialInput, calibrate_with_drift
from models.physics import PhysicsConstants
from models.synthetic import TREND_TRUTH, TYPICAL_TRUTH, Readout, paper_protocol

PHYS = PhysicsConstants()


def _fit(truth, seed: int, drift_s_per_s: float, **options):
    trials = paper_protocol(truth, PHYS, seed=seed, noise_rel=0.002, readout=Readout(), drift_s_per_s=drift_s_per_s,
                            **options)
    inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
    return calibrate_with_drift(inputs, truth.area_m2, PHYS, saturation_s=Readout().saturation_s)


@pytest.mark.parametrize(("seed", "drift"), [(501, 0.2e-6), (502, 0.02e-6)])
def test_a_drift_is_measured_and_the_creep_comes_out_right(seed, drift):
    cal = _fit(TYPICAL_TRUTH, seed, drift)
    assert cal.drift_s_per_s == pytest.approx(drift, rel=0.05)
    truth = TYPICAL_TRUTH.params_at(3.0)
    for name in ("E0_Pa", "E1_Pa", "mu1_Pa_s"):
        assert float(getattr(cal.sls, name)) == pytest.approx(float(getattr(truth, name)), rel=0.03), name
    assert float(cal.sls.tau_s) == pytest.approx(100.0, rel=0.03)
    assert any("baseline drift of" in w and "separated from the creep" in w for w in cal.warnings)
    assert cal.to_dict()["drift_S_per_s"] == cal.drift_s_per_s


@pytest.mark.parametrize(("truth", "seed"), [(TYPICAL_TRUTH, 503), (TREND_TRUTH, 504)])
def test_no_drift_is_claimed_where_there_is_none(truth, seed):
    """The force-trend sensor is the case a shared-parameter search would get wrong (it read 0.43 µS/s of drift
    and τ = 22 s before the search compared force-trend fits)."""
    cal = _fit(truth, seed, 0.0)
    assert cal.drift_s_per_s == 0.0
    assert not any("baseline drift" in w for w in cal.warnings)
    assert cal.to_dict()["drift_S_per_s"] == 0.0


@pytest.mark.parametrize("forces", [(3.0,), (3.0, 3.1)])
def test_one_force_level_cannot_separate_drift_and_says_so(forces):
    """One force, or forces within 5 % of each other (the force trend's own criterion): not looked for."""
    cal = _fit(TYPICAL_TRUTH, 505, 0.2e-6, forces_n=forces)
    assert cal.drift_s_per_s is None and "drift_S_per_s" not in cal.to_dict()
    assert any("cannot be told apart from creep" in w for w in cal.warnings)
