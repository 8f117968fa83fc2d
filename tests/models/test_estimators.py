"""Streaming estimators: state across blocks, NaN pass-through, reset, creep correction against the linear model."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.estimators import LinearEstimator, SLSEstimator
from models.linear import LinearModel, fit_linear_trials
from models.physics import DEFAULT_PHYSICS
from models.sls import (
    TYPICAL_AREA_M2,
    TYPICAL_FORCES_N,
    TYPICAL_SLS,
    ForceStatus,
    SLSParams,
    conductance_from_force,
    force_from_conductance,
)

RATE_HZ = 6.0


def _hold(force_n, seconds=370.0, ramp_start_s=5.0):
    t = np.arange(0.0, seconds, 1 / RATE_HZ)
    force = np.where(t >= ramp_start_s, force_n, 0.0)
    return t, force


def _blocks(n, rng):
    cuts = np.unique(np.concatenate([[0, n], rng.integers(0, n, 12)]))
    return list(zip(cuts[:-1], cuts[1:], strict=True))


def test_sls_estimator_in_blocks_equals_the_batch_inverse():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.1, 0.3, 900))
    force = np.clip(3 + np.sin(t[:, None] / 5 + np.arange(4)) + rng.normal(0, 0.2, (900, 4)), 0, None)
    params = SLSParams(np.full(4, 3e5), np.array([5e5, 4e5, 6e5, 5e5]), np.full(4, 5e7))
    cond = conductance_from_force(t, force, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, "linear")
    batch = force_from_conductance(t, cond, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, "linear")
    est = SLSEstimator(params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, interp="linear")
    assert est.n_sensors == 4
    streamed = np.concatenate([est.update(t[a:b], cond[a:b]) for a, b in _blocks(t.size, rng)])
    assert np.allclose(streamed, batch, rtol=1e-13, atol=1e-14)
    assert np.allclose(streamed, force, rtol=1e-10, atol=1e-10)


def test_sls_estimator_infers_sensor_count_and_resets_to_rest():
    t, force = _hold(3.0, seconds=60.0)
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    assert est.n_sensors is None
    first = est.update(t, cond[:, None])
    assert est.n_sensors == 1
    with pytest.raises(ValueError, match="backwards"):
        est.update(t[:5], cond[:5, None])
    est.reset()
    again = est.update(t, cond[:, None])
    assert np.array_equal(first, again)
    with pytest.raises(ValueError, match="expects 1"):
        est.update(t[-1:] + 1, np.ones((1, 2)))


def test_nan_samples_pass_through_without_corrupting_state():
    t, force = _hold(3.0, seconds=120.0)
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    block = np.column_stack([cond, cond])
    block[200:230, 1] = np.nan  # a dropout on sensor 1 during a constant force: holding over it is exact
    est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    out = np.concatenate([est.update(t[:210], block[:210]), est.update(t[210:], block[210:])])
    assert np.all(np.isnan(out[200:230, 1]))
    ok = ~np.isnan(out[:, 1])
    assert np.allclose(out[ok, 1], out[ok, 0], rtol=1e-12)
    assert np.allclose(out[:, 0], force, rtol=1e-10, atol=1e-12)


def test_constant_force_hold_reads_constant_while_the_linear_model_drifts():
    # Calibrate the linear model the paper's way (mean over 225–300 s of each hold) on the same synthetic sensor.
    trials = []
    for f in TYPICAL_FORCES_N:
        t, force = _hold(f)
        trials.append(
            (t, force, conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS))
        )
    linear = fit_linear_trials(trials).model

    t, force = _hold(3.0)
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    loaded = t >= 5.0
    sls_force = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS).update(t, cond[:, None])[:, 0]
    lin_force = LinearEstimator(linear).update(t, cond[:, None])[:, 0]
    assert np.max(np.abs(sls_force[loaded] - 3.0)) < 0.01 * 3.0
    drift = lin_force[loaded].max() - lin_force[loaded].min()
    assert drift > 0.2 * 3.0  # creep makes the linear reading climb by tens of percent over the hold
    assert lin_force[loaded][0] < 3.0 < lin_force[loaded][-1]


def test_linear_estimator_baseline_clipping_and_statuses():
    model = LinearModel(2e-4, 1e-4)
    est = LinearEstimator([model, model], baseline_s=np.array([0.0, 5e-5]), force_range_n=(0.5, 5.5))
    cond = np.array(
        [[1e-4 + 2e-4 * 3.0, 1e-4 + 5e-5 + 2e-4 * 3.0], [5e-5, 1e-4], [0.0, np.nan], [2e-3, -1.0]]
    )
    force = est.update(np.arange(4.0), cond)
    assert force[0] == pytest.approx([3.0, 3.0])
    assert force[1, 0] == 0.0 and est.last_status[1, 0] == ForceStatus.BELOW_BASELINE
    assert force[1, 1] == 0.0 and est.last_status[1, 1] == ForceStatus.BELOW_BASELINE
    assert est.last_status[2, 0] == ForceStatus.OPEN_CIRCUIT
    assert np.isnan(force[2, 1]) and est.last_status[2, 1] == ForceStatus.NAN_INPUT
    assert force[3, 0] == pytest.approx(9.5) and est.last_status[3, 0] == ForceStatus.EXTRAPOLATED
    assert est.last_status[3, 1] == ForceStatus.NEGATIVE_CONDUCTANCE
    assert len(est.explain()) == 5
    with pytest.raises(ValueError, match="must be > 0"):
        LinearEstimator(LinearModel(-1.0, 0.0))


def test_sls_estimator_flags_extrapolation_outside_the_calibrated_range():
    t, force = _hold(8.0, seconds=30.0)
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, force_range_n=(1.75, 5.25))
    out = est.update(t, cond[:, None])
    loaded = t >= 5.0
    assert np.allclose(out[loaded, 0], 8.0, rtol=1e-10)
    assert np.all(est.last_status[loaded, 0] == ForceStatus.EXTRAPOLATED)
    assert any("calibrated range" in line for line in est.explain())


def _split_record():
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.02, 0.5, 120))
    force = np.clip(2.5 + np.sin(t[:, None] / 4 + np.arange(3)) + rng.normal(0, 0.3, (120, 3)), 0, None)
    return t, conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)


SPLIT_T, SPLIT_COND = _split_record()


@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(0, 120), max_size=8), nan_rows=st.lists(st.integers(0, 119), max_size=10))
def test_any_block_split_gives_the_same_forces(cuts, nan_rows):
    t, cond = SPLIT_T, SPLIT_COND.copy()
    cond[nan_rows, 1] = np.nan
    whole = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS).update(t, cond)
    est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    bounds = [0, *sorted(cuts), 120]
    parts = [est.update(t[a:b], cond[a:b]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    assert np.allclose(np.concatenate(parts), whole, rtol=1e-12, atol=1e-13, equal_nan=True)
