"""NUMERICS.md "Stress cases" for the sensor model and estimators: nothing returns NaN/inf silently, nothing hangs,
every refusal says why."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from models.estimators import LinearEstimator, SLSEstimator
from models.linear import LinearModel
from models.physics import DEFAULT_PHYSICS
from models.sls import (
    TYPICAL_AREA_M2,
    TYPICAL_SLS,
    ForceStatus,
    SLSParams,
    conductance_from_force,
    force_from_conductance,
    one_minus_phi1,
    strain_from_force,
    strain_from_force_superposition,
)

NO_CONTACT = DEFAULT_PHYSICS.without_contact()
OK_OR_OPEN = (ForceStatus.OK, ForceStatus.OPEN_CIRCUIT)


def _assert_no_silent_nan(result, cond):
    """Every NaN/inf force sits on a NaN input, and every NaN input is flagged."""
    bad = ~np.isfinite(result.force_n)
    assert np.array_equal(bad, np.isnan(cond)), "non-finite force on a finite reading"
    assert np.all(result.status[np.isnan(cond)] == ForceStatus.NAN_INPUT)


# ---------------------------------------------------------------- near-zero force, C = 0, ε → 1, saturation


@settings(max_examples=60, deadline=None)
@given(force_n=st.floats(min_value=1e-12, max_value=1e-2), contact=st.booleans())
def test_near_zero_force_round_trips(force_n, contact):
    phys = DEFAULT_PHYSICS if contact else NO_CONTACT
    t = np.arange(5.0)
    force = np.array([0.0, force_n, force_n, 0.0, force_n])
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, phys)
    result = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, phys, with_status=True)
    # Without the contact term a tiny force is a tiny strain on top of R0: relative precision degrades as 1/F.
    tol = 1e-9 * force_n if contact else 1e-12
    assert np.all(np.abs(result.force_n - force) <= tol)
    assert np.all(np.isin(result.status, OK_OR_OPEN))


def test_zero_conductance_is_zero_force_in_every_path():
    t = np.arange(4.0)
    cond = np.zeros((4, 3))
    for phys in (DEFAULT_PHYSICS, NO_CONTACT):
        for interp in ("hold", "linear"):
            res = force_from_conductance(
                t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp, with_status=True
            )
            assert np.array_equal(res.force_n, np.zeros((4, 3)))
            assert np.all(res.status == ForceStatus.OPEN_CIRCUIT)
            one = force_from_conductance(t, cond[:, 0], TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp)
            assert np.array_equal(one, np.zeros(4))


def test_forward_refuses_a_force_that_drives_strain_to_one_unless_asked_to_clamp():
    t, force = np.arange(3.0), np.array([0.0, 1e4, 1e4])
    with pytest.raises(ValueError, match="strain to .* ≥ 1"):
        conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, NO_CONTACT)
    clamped = conductance_from_force(
        t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, overstrain="clamp"
    )
    assert np.allclose(clamped[1:], np.sqrt(1e4) / DEFAULT_PHYSICS.K_contact_ohm_sqrtN)


@pytest.mark.parametrize("phys", [DEFAULT_PHYSICS, NO_CONTACT], ids=["contact", "no-contact"])
def test_readings_beyond_strain_one_saturate_with_a_finite_force(phys):
    t = np.arange(4.0)
    # Huge conductances (a short on the line) and +inf. Without the contact term ε ≥ 0.9 needs R ≲ R0·e^(−228).
    huge = 10.0 if phys.has_contact else 1e120
    cond = np.array([[1e-3, 1e-3], [huge, np.inf], [huge * 100, 1e-3], [1e-3, 1e-3]])
    res = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, phys, with_status=True)
    assert np.all(np.isfinite(res.force_n))
    assert res.status[1, 0] == ForceStatus.SATURATED and res.status[1, 1] == ForceStatus.SATURATED
    assert res.status[2, 0] == ForceStatus.SATURATED
    assert any("ε → 1" in line for line in res.explain())
    # at the limit the strain is ~1: force ≈ E0·A (1 − creep) — far above any real contact
    assert res.force_n[1, 1] > 100.0


def test_adc_saturated_samples_are_flagged_by_the_estimators():
    t = np.arange(0.0, 10.0, 0.5)
    force = np.full(t.size, 3.0)
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    c_max = 0.9 * cond.max()  # readout ceiling below the true reading: censored
    censored = np.minimum(cond, c_max)
    mask = cond > c_max
    est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    out = est.update(t, censored[:, None], saturated=mask)
    assert np.all(est.last_status[mask[:, None]] == ForceStatus.READOUT_SATURATED)
    assert np.all(out[mask] < 3.0)  # a lower bound
    lin = LinearEstimator(LinearModel(2e-4, 0.0))
    lin.update(t, censored[:, None], saturated=mask)
    assert np.all(lin.last_status[mask[:, None]] == ForceStatus.READOUT_SATURATED)
    with pytest.raises(ValueError, match="saturated mask"):
        est.update(t + 100, censored[:, None], saturated=np.zeros((t.size, 2), dtype=bool))


# ---------------------------------------------------------------- steps between / at samples


def test_force_step_exactly_at_a_sample_and_between_samples():
    fine_t = np.arange(0.0, 60.0, 0.001)
    step_at = 20.0004  # between the 6 Hz samples … and one exactly on a sample (30.0)
    fine_f = np.where(fine_t >= step_at, 3.0, 1.0) + np.where(fine_t >= 30.0, 1.0, 0.0)
    fine_c = conductance_from_force(fine_t, fine_f, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    pick = np.arange(0, fine_t.size, 1000 // 6 + 1)
    t, cond, truth = fine_t[pick], fine_c[pick], fine_f[pick]
    res = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, with_status=True)
    assert np.all(res.status == ForceStatus.OK)
    # The step between samples costs at most the creep during the unseen fraction of a step (h/τ ~ 2e-3 of σ).
    assert np.max(np.abs(res.force_n - truth)) < 0.01
    on_sample = np.isclose(t, 30.0, atol=1e-9)
    if on_sample.any():
        assert abs(res.force_n[on_sample][0] - 4.0) < 0.01


# ---------------------------------------------------------------- long records and x = h/τ ≈ 1e-5


def test_370_s_at_6_hz_and_3700_s_records_stay_exact():
    for seconds in (370.0, 3700.0):
        t = np.arange(0.0, seconds, 1 / 6)
        force = np.where(t >= 2.0, 3.0, 0.0)
        expected = np.where(
            t >= 2.0,
            3.0
            / TYPICAL_AREA_M2
            * (1 / TYPICAL_SLS.E0_Pa + (-np.expm1(-(t - 2.0) / TYPICAL_SLS.tau_s)) / 5e5),
            0.0,
        )
        strain = strain_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2)
        assert np.max(np.abs(strain - expected)) <= 1e-13 * expected.max()
        cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        back = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        assert np.max(np.abs(back - force)) < 1e-10


@pytest.mark.slow
def test_370_s_at_1_khz_float64_keeps_full_precision():
    t = np.arange(370_000) * 1e-3  # x = h/τ = 1e-5: float32 would lose the creep increment entirely
    force = np.where(t >= 1.0, 3.0, 0.0)
    p = TYPICAL_SLS
    expected = np.where(
        t >= 1.0, 3.0 / TYPICAL_AREA_M2 * (1 / p.E0_Pa + (-np.expm1(-(t - 1.0) / p.tau_s)) / p.E1_Pa), 0
    )
    for interp in ("hold", "linear"):
        strain = strain_from_force(t, force, p, TYPICAL_AREA_M2, interp)
        if interp == "hold":
            assert np.max(np.abs(strain - expected)) <= 1e-12 * expected.max()
    cond = conductance_from_force(t, force, p, TYPICAL_AREA_M2, NO_CONTACT)
    back = force_from_conductance(t, cond, p, TYPICAL_AREA_M2, NO_CONTACT)
    assert np.max(np.abs(back - force)) < 1e-10


def test_float32_would_fail_where_float64_recursion_does_not():
    x = 1e-5
    alpha32 = np.exp(np.float32(-x))
    assert abs(float(np.float32(1) - alpha32) - x) / x > 1e-3  # float32 loses ~all digits of 1 − α
    assert abs(float(-np.expm1(-x)) - (x - x * x / 2)) / x < 1e-10
    assert float(one_minus_phi1(np.array(x))) == pytest.approx(x / 2 - x * x / 6, rel=1e-12)


# ---------------------------------------------------------------- timestamps


@settings(max_examples=40, deadline=None)
@given(
    steps=st.lists(
        st.one_of(st.just(0.0), st.floats(min_value=1e-4, max_value=500.0)), min_size=2, max_size=60
    ),
    interp=st.sampled_from(["hold", "linear"]),
    seed=st.integers(0, 2**16),
)
def test_nonuniform_and_duplicate_timestamps_match_superposition(steps, interp, seed):
    t = np.concatenate([[0.0], np.cumsum(steps)])
    force = np.random.default_rng(seed).uniform(0.0, 5.0, t.size)
    fast = strain_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, interp)
    naive = strain_from_force_superposition(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, interp)
    assert np.max(np.abs(fast - naive)) <= 1e-12 * max(np.max(np.abs(naive)), 1e-300)


def test_backwards_timestamps_are_refused_with_the_sample_named_everywhere():
    t = np.array([0.0, 1.0, 2.0, 1.5])
    c = np.full(4, 1e-3)
    with pytest.raises(ValueError, match="backwards at sample 3"):
        force_from_conductance(t, c, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    with pytest.raises(ValueError, match="backwards"):
        strain_from_force_superposition(t, c, TYPICAL_SLS, TYPICAL_AREA_M2)
    est = LinearEstimator(LinearModel(1e-4, 0.0))
    est.update(t[:3], c[:3, None])
    with pytest.raises(ValueError, match="previous block"):
        est.update(np.array([1.0]), c[:1, None])


# ---------------------------------------------------------------- NaN / dropped samples


@settings(max_examples=40, deadline=None)
@given(
    nan_mask=st.lists(st.booleans(), min_size=30, max_size=30),
    contact=st.booleans(),
    interp=st.sampled_from(["hold", "linear"]),
    n_sensors=st.sampled_from([1, 3]),
)
def test_nan_samples_never_leak(nan_mask, contact, interp, n_sensors):
    phys = DEFAULT_PHYSICS if contact else NO_CONTACT
    t = np.arange(30.0) * 0.5
    force = np.tile((2.0 + np.sin(t))[:, None], (1, n_sensors))
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp)
    cond[np.array(nan_mask), 0] = np.nan
    res = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp, with_status=True)
    _assert_no_silent_nan(res, cond)
    assert np.all(res.force_n[np.isfinite(res.force_n)] >= 0.0)


# ---------------------------------------------------------------- τ → 0, τ → ∞, random parameters


@pytest.mark.parametrize("tau_s", [1e-9, 1e-3, 1e3, 1e12])
@pytest.mark.parametrize("interp", ["hold", "linear"])
def test_extreme_retardation_times(tau_s, interp):
    p = SLSParams(3e5, 5e5, 5e5 * tau_s)
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.05, 0.5, 400))
    force = np.clip(3 + np.sin(t / 3) + rng.normal(0, 0.3, t.size), 0, None)
    strain = strain_from_force(t, force, p, TYPICAL_AREA_M2, interp)
    naive = strain_from_force_superposition(t, force, p, TYPICAL_AREA_M2, interp)
    assert np.max(np.abs(strain - naive)) <= 1e-12 * np.max(naive)
    cond = conductance_from_force(t, force, p, TYPICAL_AREA_M2, DEFAULT_PHYSICS, interp)
    back = force_from_conductance(t, cond, p, TYPICAL_AREA_M2, DEFAULT_PHYSICS, interp)
    assert np.max(np.abs(back - force)) <= 1e-9 * np.max(force)


@settings(max_examples=60, deadline=None)
@given(
    log_e0=st.floats(4.0, 8.0),
    log_e1=st.floats(4.0, 8.0),
    log_tau=st.floats(-6.0, 8.0),
    interp=st.sampled_from(["hold", "linear"]),
    contact=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_round_trip_over_random_parameters(log_e0, log_e1, log_tau, interp, contact, seed):
    e0, e1 = 10.0**log_e0, 10.0**log_e1
    p = SLSParams(e0, e1, e1 * 10.0**log_tau)
    phys = DEFAULT_PHYSICS if contact else NO_CONTACT
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.01, 2.0, 80))
    force = rng.uniform(0.0, 6.0, t.size)
    assume(6.0 / TYPICAL_AREA_M2 / p.b < 0.5)  # keep ε well below 1, where Eq. 3 means something
    cond = conductance_from_force(t, force, p, TYPICAL_AREA_M2, phys, interp)
    res = force_from_conductance(t, cond, p, TYPICAL_AREA_M2, phys, interp, with_status=True)
    assert np.all(np.isfinite(res.force_n))
    hold_fallback = interp == "hold" and np.any(-np.expm1(-np.diff(t) / p.tau_s) * (1 + e0 / e1) > 1.999)
    if not hold_fallback:
        # Conditioning: at large strains the tunnelling part is a tiny fraction of the reading.
        assert np.max(np.abs(res.force_n - force)) <= 1e-7 * 6.0


# ---------------------------------------------------------------- quantised readout, drift below baseline


def test_12_bit_quantised_conductance_gives_bounded_finite_forces():
    # SPEC §4 readout: V = counts/4095·3.3 V, C = (V_ref − V)/(V_ref·R_C).
    v_ref, r_c = 2.5, 900.0
    t = np.arange(0.0, 120.0, 1 / 30)
    force = np.where(t > 5, 2.0 + 0.5 * np.sin(t), 0.0)
    cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    counts = np.clip(np.round((v_ref - cond * v_ref * r_c) / 3.3 * 4095), 0, 4095)
    quantised = np.maximum((v_ref - counts / 4095 * 3.3) / (v_ref * r_c), 0.0)
    res = force_from_conductance(
        t, quantised, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, with_status=True
    )
    assert np.all(np.isfinite(res.force_n))
    assert np.all(np.isin(res.status, OK_OR_OPEN))
    loaded = t > 6
    assert np.sqrt(np.mean((res.force_n[loaded] - force[loaded]) ** 2)) < 0.05


def test_conductance_below_unloaded_baseline_is_clipped_and_flagged():
    # Without the contact term the unloaded reading is 1/R0; drift below it means "negative force".
    t = np.arange(10.0)
    cond = np.full(t.size, 1.0 / NO_CONTACT.R0_ohm)
    cond[3:6] *= 0.98
    res = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, NO_CONTACT, with_status=True)
    assert np.all(res.force_n >= 0.0)
    assert np.all(res.status[3:6] == ForceStatus.BELOW_BASELINE)
    assert any("baseline" in line for line in res.explain())


@pytest.mark.parametrize("n_sensors", [1, 2])
def test_contact_path_flags_strains_near_one(n_sensors):
    # With the contact term a reading just below √F_max/K solves to ε ≈ 1: a finite force, flagged.
    p = TYPICAL_SLS
    f_max = TYPICAL_AREA_M2 * p.E0_Pa  # ε = 1 on the first sample (no creep yet)
    c_edge = 0.999999 * np.sqrt(f_max) / DEFAULT_PHYSICS.K_contact_ohm_sqrtN
    cond = np.full((1, n_sensors), c_edge)
    res = force_from_conductance(np.zeros(1), cond, p, TYPICAL_AREA_M2, DEFAULT_PHYSICS, with_status=True)
    assert np.all(np.isfinite(res.force_n))
    assert np.all(res.status == ForceStatus.SATURATED)
    assert np.all(res.force_n > 0.9 * f_max)


@settings(max_examples=60, deadline=None)
@given(
    readings=st.lists(
        st.one_of(
            st.floats(min_value=-1e-3, max_value=1e3),
            st.floats(min_value=1e-9, max_value=5e-3),
            st.sampled_from([0.0, np.nan, np.inf, 1e300, 5e-324]),
        ),
        min_size=1,
        max_size=40,
    ),
    contact=st.booleans(),
    interp=st.sampled_from(["hold", "linear"]),
    n_sensors=st.sampled_from([1, 2]),
)
def test_arbitrary_readings_never_leak_nan_and_never_hang(readings, contact, interp, n_sensors):
    phys = DEFAULT_PHYSICS if contact else NO_CONTACT
    cond = np.tile(np.array(readings)[:, None], (1, n_sensors))
    t = np.arange(cond.shape[0]) * 0.1
    res = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp, with_status=True)
    _assert_no_silent_nan(res, cond)
    finite = np.isfinite(res.force_n)
    assert np.all(res.force_n[finite] >= 0.0)
    assert np.all(res.status != ForceStatus.NOT_CONVERGED)
    assert np.all(np.isin(res.status, [int(s) for s in ForceStatus]))
