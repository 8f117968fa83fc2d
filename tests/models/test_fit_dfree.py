"""Derivative-free initial estimate (integrated Eq. 5, column-scaled lstsq, physical projection)."""

from __future__ import annotations

import numpy as np
import pytest

from models.fit_dfree import estimate_sls
from models.physics import PhysicsConstants, strain_from_conductance
from models.synthetic import TYPICAL_TRUTH, make_trial

PHYS = PhysicsConstants()


def _rows(trial, fraction=0.2):
    loaded = trial.force_n >= fraction * trial.nominal_force_n
    result = strain_from_conductance(trial.conductance_s[loaded], trial.force_n[loaded], PHYS)
    return trial.time_s[loaded], trial.force_n[loaded] / TYPICAL_TRUTH.area_m2, result.strain


def test_noise_free_estimate_is_close_to_truth():
    trials = [make_trial(TYPICAL_TRUTH, PHYS, f) for f in (1.75, 5.25)]
    estimate = estimate_sls([_rows(t) for t in trials])
    assert not estimate.projected
    # Trapezoid integration of a 6 Hz record limits the accuracy; the output-error fit removes the rest.
    assert estimate.E0_Pa == pytest.approx(6e5, rel=0.02)
    assert estimate.E1_Pa == pytest.approx(9e5, rel=0.02)
    assert estimate.mu1_Pa_s == pytest.approx(9e7, rel=0.02)


def test_noisy_estimate_stays_physical():
    for seed in range(5):
        trial = make_trial(TYPICAL_TRUTH, PHYS, 3.0, seed=seed, noise_rel=0.01)
        estimate = estimate_sls([_rows(trial)])
        values = (estimate.E0_Pa, estimate.E1_Pa, estimate.mu1_Pa_s)
        assert all(np.isfinite(v) and v > 0 for v in values)
        assert estimate.E0_Pa > estimate.b_Pa


def test_pure_hold_has_no_ramp_and_is_projected_with_a_note():
    trial = make_trial(TYPICAL_TRUTH, PHYS, 3.0, preload_s=0.0, ramp_s=0.0)
    estimate = estimate_sls([_rows(trial)])
    assert estimate.projected
    assert "no loading ramp" in estimate.note
    # b (long-run stiffness) and τ = c/b are still identified by the hold.
    assert estimate.b_Pa == pytest.approx(float(TYPICAL_TRUTH.params_at(3.0).b), rel=0.02)
    assert estimate.c_Pa_s / estimate.b_Pa == pytest.approx(100.0, rel=0.02)


def test_flat_strain_is_refused():
    t = np.arange(0, 100, 1 / 6)
    with pytest.raises(ValueError, match="flat or disconnected"):
        estimate_sls([(t, np.full(t.size, 2000.0), np.full(t.size, 1e-3))])


def test_implausible_instantaneous_stiffness_falls_back_to_the_prior():
    # A trial whose noise pushes a to ~0 (E0 → ∞) must not hand an optimiser a plateau as its start.
    trial = make_trial(TYPICAL_TRUTH, PHYS, 1.75, seed=3, noise_rel=0.03)
    estimate = estimate_sls([_rows(trial)])
    assert estimate.b_Pa < estimate.E0_Pa < 100 * estimate.b_Pa
    assert np.isfinite(estimate.mu1_Pa_s) and estimate.mu1_Pa_s > 0
