"""SLS model: parameters, exact recursion against the paper's O(N²) superposition, and the O(1) inverse."""

from __future__ import annotations

import numpy as np
import pytest

from models.physics import DEFAULT_PHYSICS, conductance_from_strain, tunnelling_resistance
from models.sls import (
    TYPICAL_AREA_M2,
    TYPICAL_SLS,
    ForceStatus,
    SLSInverse,
    SLSParams,
    SLSTrend,
    conductance_from_force,
    force_from_conductance,
    force_from_conductance_trend,
    one_minus_phi1,
    strain_from_force,
    strain_from_force_superposition,
    strain_from_force_trend,
)

NO_CONTACT = DEFAULT_PHYSICS.without_contact()
PER_SENSOR = SLSParams(
    E0_Pa=np.array([3.0e5, 2.0e5, 6.0e5]),
    E1_Pa=np.array([5.0e5, 1.5e5, 4.0e5]),
    mu1_Pa_s=np.array([5.0e7, 3.0e6, 1.2e8]),
)
AREAS = np.array([1.4e-3, 1.2e-3, 1.6e-3])


def _nonuniform_record(rng, n, mean_step_s=0.2):
    t = np.concatenate([[0.0], np.cumsum(rng.exponential(mean_step_s, n - 1))])
    force = np.clip(3.0 + 1.5 * np.sin(t / 9.0)[:, None] + rng.normal(0, 0.6, (n, 3)), 0.0, None)
    force[: n // 10] = 0.0
    return t, force


# ---------------------------------------------------------------- parameters


def test_derived_parameters_follow_eq6_and_from_abc_inverts_them():
    p = TYPICAL_SLS
    assert p.tau_s == pytest.approx(100.0)
    assert p.a == pytest.approx(5e7 / 8e5)
    assert p.b == pytest.approx(3e5 * 5e5 / 8e5)
    assert p.c == pytest.approx(5e7 * 3e5 / 8e5)
    back = SLSParams.from_abc(p.a, p.b, p.c)
    for key in ("E0_Pa", "E1_Pa", "mu1_Pa_s"):
        assert getattr(back, key) == pytest.approx(getattr(p, key), rel=1e-13)


def test_from_abc_refuses_non_physical_combinations():
    with pytest.raises(ValueError, match="E1 would be < 0"):
        SLSParams.from_abc(1.0, 5e5, 3e5)  # E0 = c/a = 3e5 < b
    with pytest.raises(ValueError, match="positive"):
        SLSParams.from_abc(-1.0, 1.0, 1.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
def test_params_must_be_positive_and_finite(bad):
    with pytest.raises(ValueError, match="E1_Pa"):
        SLSParams(3e5, bad, 5e7)


def test_per_sensor_params_must_agree_in_length_and_match_the_data():
    with pytest.raises(ValueError, match="one length"):
        SLSParams(np.ones(2), np.ones(3), 1.0)
    with pytest.raises(ValueError, match="3 sensors"):
        strain_from_force(np.arange(4.0), np.ones((4, 2)), PER_SENSOR, 1e-3)


def test_stack_sensor_and_dict_round_trip():
    stacked = SLSParams.stack([PER_SENSOR.sensor(i) for i in range(3)])
    assert np.array_equal(stacked.E1_Pa, PER_SENSOR.E1_Pa)
    assert SLSParams.from_dict(TYPICAL_SLS.to_dict()) == TYPICAL_SLS
    with pytest.raises(ValueError, match="mu1_Pa_s"):
        SLSParams.from_dict({"E0_Pa": 1.0, "E1_Pa": 1.0})


def test_trend_evaluates_linearly_and_refuses_non_positive_values():
    trend = SLSTrend(E0_Pa=(1e5, 5e4), E1_Pa=(2e5, 1e5), mu1_Pa_s=(1e7, 1e7))
    p = trend.at(2.0)
    assert (p.E0_Pa, p.E1_Pa, p.mu1_Pa_s) == (2e5, 4e5, 3e7)
    with pytest.raises(ValueError, match="E0_Pa"):
        SLSTrend(E0_Pa=(1e5, -1e5), E1_Pa=(1.0, 0.0), mu1_Pa_s=(1.0, 0.0)).at(2.0)


def test_one_minus_phi1_is_accurate_across_the_series_switch():
    x = np.array([0.0, 1e-12, 1e-5, 0.0999999, 0.1, 0.5, 30.0, np.inf])
    # reference by high-precision series / direct formula in extended arithmetic where safe
    from fractions import Fraction

    def exact(value):
        if value == 0.0:
            return 0.0
        if np.isinf(value):
            return 1.0
        xf = Fraction(value)
        total, term = Fraction(0), Fraction(1)
        for n in range(1, 60):
            term = term * xf / (n + 1) if n > 1 else xf / 2
            total += term if n % 2 else -term
        return float(total)

    got = one_minus_phi1(x)
    for value, g in zip(x[:-2], got[:-2], strict=True):
        assert g == pytest.approx(exact(value), rel=4e-16, abs=0.0)
    assert got[-2] == pytest.approx(1 - (1 - np.exp(-30.0)) / 30.0, rel=1e-15)
    assert got[-1] == 1.0


# ---------------------------------------------------------------- forward


@pytest.mark.parametrize("interp", ["hold", "linear"])
def test_recursion_equals_naive_superposition_on_nonuniform_steps(interp):
    rng = np.random.default_rng(7)
    t, force = _nonuniform_record(rng, 600)
    fast = strain_from_force(t, force, PER_SENSOR, AREAS, interp)
    naive = strain_from_force_superposition(t, force, PER_SENSOR, AREAS, interp)
    assert np.max(np.abs(fast - naive)) <= 1e-12 * np.max(np.abs(naive))


@pytest.mark.parametrize("interp", ["hold", "linear"])
def test_one_sensor_fast_path_equals_the_vectorised_path(interp):
    rng = np.random.default_rng(3)
    t, force = _nonuniform_record(rng, 300)
    both = strain_from_force(
        t, np.column_stack([force[:, 0], force[:, 0]]), TYPICAL_SLS, TYPICAL_AREA_M2, interp
    )
    single = strain_from_force(t, force[:, 0], TYPICAL_SLS, TYPICAL_AREA_M2, interp)
    assert single.shape == (300,)
    assert np.max(np.abs(both[:, 0] - single)) <= 1e-15 * np.max(single)


def test_constant_force_gives_the_creep_compliance_of_eq11():
    t = np.linspace(0.0, 370.0, 2221)
    force = np.full(t.size, 3.0)
    sigma = 3.0 / TYPICAL_AREA_M2
    p = TYPICAL_SLS
    expected = sigma * (1 / p.E0_Pa + (1 - np.exp(-t / p.tau_s)) / p.E1_Pa)
    for interp in ("hold", "linear"):
        got = strain_from_force(t, force, p, TYPICAL_AREA_M2, interp)
        assert np.max(np.abs(got - expected)) <= 1e-13 * expected.max()
    # instantaneous σ/E0, long-run σ/b
    long = strain_from_force(np.array([0.0, 1e6]), np.array([3.0, 3.0]), p, TYPICAL_AREA_M2)
    assert long[0] == pytest.approx(sigma / p.E0_Pa, rel=1e-15)
    assert long[1] == pytest.approx(sigma / p.b, rel=1e-14)


def test_nan_force_sample_is_a_dropped_sample():
    rng = np.random.default_rng(11)
    t, force = _nonuniform_record(rng, 200)
    gappy = force.copy()
    gappy[50:53, 1] = np.nan
    got = strain_from_force(t, gappy, PER_SENSOR, AREAS, "hold")
    assert np.all(np.isnan(got[50:53, 1]))
    keep = np.ones(200, dtype=bool)
    keep[50:53] = False
    dropped = strain_from_force(t[keep], force[keep][:, 1:2], PER_SENSOR.sensor(1), AREAS[1], "hold")
    assert np.allclose(got[keep, 1], dropped[:, 0], rtol=1e-13, atol=0.0)
    # other columns untouched
    assert np.array_equal(got[:, 0], strain_from_force(t, force, PER_SENSOR, AREAS, "hold")[:, 0])


def test_duplicate_timestamps_are_zero_steps_and_backwards_is_refused():
    t = np.array([0.0, 1.0, 1.0, 2.0])
    force = np.array([1.0, 1.0, 2.0, 2.0])
    strain = strain_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2)
    # the step at t = 1 s is instantaneous: the duplicate adds exactly ΔF/(A·E0)
    assert strain[2] - strain[1] == pytest.approx(1.0 / TYPICAL_AREA_M2 / TYPICAL_SLS.E0_Pa, rel=1e-12)
    with pytest.raises(ValueError, match="backwards at sample 2"):
        strain_from_force(np.array([0.0, 1.0, 0.5]), np.ones(3), TYPICAL_SLS, TYPICAL_AREA_M2)
    with pytest.raises(ValueError, match="not finite"):
        strain_from_force(np.array([0.0, np.nan]), np.ones(2), TYPICAL_SLS, TYPICAL_AREA_M2)


def test_force_dependent_trend_with_zero_slopes_is_the_linear_model():
    rng = np.random.default_rng(5)
    t, force = _nonuniform_record(rng, 300)
    p = TYPICAL_SLS
    flat = SLSTrend((p.E0_Pa, 0.0), (p.E1_Pa, 0.0), (p.mu1_Pa_s, 0.0))
    got = strain_from_force_trend(t, force[:, 0], flat, TYPICAL_AREA_M2)
    assert np.allclose(got, strain_from_force(t, force[:, 0], p, TYPICAL_AREA_M2), rtol=1e-13, atol=0)


# ---------------------------------------------------------------- inverse


@pytest.mark.parametrize("interp", ["hold", "linear"])
@pytest.mark.parametrize("phys", [DEFAULT_PHYSICS, NO_CONTACT], ids=["contact", "no-contact"])
def test_forward_then_inverse_round_trip(interp, phys):
    rng = np.random.default_rng(21)
    t, force = _nonuniform_record(rng, 800)
    cond = conductance_from_force(t, force, PER_SENSOR, AREAS, phys, interp)
    result = force_from_conductance(t, cond, PER_SENSOR, AREAS, phys, interp, with_status=True)
    assert np.max(np.abs(result.force_n - force)) <= 1e-10 * np.max(force)
    zero = force == 0.0
    expected = ForceStatus.OPEN_CIRCUIT if phys.has_contact else ForceStatus.OK
    assert np.all(result.status[zero] == expected)
    assert np.all(result.status[~zero] == ForceStatus.OK)


def test_blocks_give_the_same_forces_as_one_call():
    rng = np.random.default_rng(2)
    t, force = _nonuniform_record(rng, 500)
    cond = conductance_from_force(t, force, PER_SENSOR, AREAS, DEFAULT_PHYSICS, "linear")
    whole = force_from_conductance(t, cond, PER_SENSOR, AREAS, DEFAULT_PHYSICS, "linear")
    inverse = SLSInverse(PER_SENSOR, AREAS, DEFAULT_PHYSICS, 3, "linear")
    cuts = [0, 1, 7, 130, 131, 400, 500]
    parts = [inverse.update(t[a:b], cond[a:b]).force_n for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    assert np.allclose(np.concatenate(parts), whole, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("interp", ["hold", "linear"])
def test_noisy_conductance_force_error_matches_the_noise_bound(interp):
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 370.0, 1 / 6)
    force = np.where(t > 10.0, 3.0 + np.sin(2 * np.pi * 0.02 * t), 0.5)
    strain = strain_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, interp)
    strain_noise = 2e-5
    noisy_strain = strain[:, None] + rng.normal(0, strain_noise, (t.size, 8))
    noisy = 1.0 / tunnelling_resistance(noisy_strain, NO_CONTACT)
    clean = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, NO_CONTACT, interp)
    assert np.allclose(clean, 1.0 / tunnelling_resistance(strain, NO_CONTACT), rtol=1e-14)
    estimate = force_from_conductance(t, noisy, TYPICAL_SLS, TYPICAL_AREA_M2, NO_CONTACT, interp)
    p = TYPICAL_SLS
    x = (1 / 6) / p.tau_s
    e_eff = p.E0_Pa if interp == "hold" else 1 / (1 / p.E0_Pa + one_minus_phi1(x) / p.E1_Pa)
    bound = e_eff * TYPICAL_AREA_M2 * strain_noise
    rms = np.sqrt(np.mean((estimate - force[:, None]) ** 2))
    assert rms == pytest.approx(bound, rel=0.10)


def test_inverse_zero_and_nan_conductance():
    t = np.arange(6.0)
    cond = np.array([[0.0], [np.nan], [1e-3], [np.nan], [0.0], [-1e-4]])
    result = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, with_status=True)
    f, s = result.force_n[:, 0], result.status[:, 0]
    assert f[0] == 0.0 and s[0] == ForceStatus.OPEN_CIRCUIT
    assert np.isnan(f[1]) and s[1] == ForceStatus.NAN_INPUT
    assert f[2] > 0.0 and s[2] == ForceStatus.OK
    assert np.isnan(f[3]) and s[3] == ForceStatus.NAN_INPUT
    assert f[4] == 0.0 and f[5] == 0.0 and s[5] == ForceStatus.NEGATIVE_CONDUCTANCE
    assert any("NAN_INPUT" in line for line in result.explain())


def test_nan_conductance_does_not_corrupt_the_state():
    rng = np.random.default_rng(8)
    t, force = _nonuniform_record(rng, 300)
    keep = np.ones(300, dtype=bool)
    keep[100:104] = False
    # The sensor really saw the record without samples 100–103 (force held over the gap); those readings are lost.
    for interp in ("hold", "linear"):
        gappy = np.full((300, 3), np.nan)
        for j in range(3):
            rows = keep if j == 2 else slice(None)
            gappy[rows, j] = conductance_from_force(
                t[rows], force[rows, j], PER_SENSOR.sensor(j), AREAS[j], DEFAULT_PHYSICS, interp
            )
        got = force_from_conductance(t, gappy, PER_SENSOR, AREAS, DEFAULT_PHYSICS, interp)
        assert np.all(np.isnan(got[100:104, 2]))
        if interp == "hold":
            assert np.allclose(got[keep, 2], force[keep, 2], rtol=1e-10, atol=1e-10)
        else:
            # "linear" holds the last force over the gap too, then ramps over the last step: a small, finite bias.
            assert np.all(np.isfinite(got[keep, 2]))
            assert np.max(np.abs(got[keep, 2] - force[keep, 2])) < 0.05 * np.max(force)
        assert np.allclose(got[:, :2], force[:, :2], rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("phys", [DEFAULT_PHYSICS, NO_CONTACT], ids=["contact", "no-contact"])
@pytest.mark.parametrize("n_sensors", [1, 2])
def test_hold_inverse_stays_bounded_when_e0_exceeds_e1_and_steps_exceed_tau(phys, n_sensors):
    # Per step the hold inverse multiplies an error by −E0/E1 when h ≫ τ; such steps are inverted as "linear".
    p = SLSParams(6e5, 1.5e5, 1.5e5 * 0.01)  # τ = 10 ms, E0/E1 = 4
    t = np.arange(0.0, 300.0, 1.0)
    rng = np.random.default_rng(1)
    force = 3.0 + rng.normal(0, 0.3, t.size)
    cond = conductance_from_force(t, force, p, TYPICAL_AREA_M2, phys, "hold")
    noisy = cond * (1 + rng.normal(0, 1e-4, t.size))
    block = np.tile(noisy[:, None], (1, n_sensors))
    est = force_from_conductance(t, block, p, TYPICAL_AREA_M2, phys, "hold")[:, 0]
    assert np.all(np.isfinite(est))
    error = np.abs(est - force)
    # Without the fallback the error would grow like 4^n; with it, it stays at the scale of the sample-to-sample
    # force change (the disagreement between the hold and linear assumptions) and does not grow.
    assert np.max(error) < 2 * np.max(np.abs(np.diff(force)))
    assert np.max(error[-100:]) < 2 * np.max(error[:100])


@pytest.mark.parametrize("interp", ["hold", "linear"])
@pytest.mark.parametrize("phys", [DEFAULT_PHYSICS, NO_CONTACT], ids=["contact", "no-contact"])
def test_one_sensor_inverse_path_equals_the_vectorised_path(interp, phys):
    rng = np.random.default_rng(17)
    t, force = _nonuniform_record(rng, 400)
    cond = conductance_from_force(t, force[:, 0], TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp)
    cond[[50, 51, 200]] = [np.nan, 0.0, np.nan]
    single = force_from_conductance(t, cond, TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp, with_status=True)
    pair = force_from_conductance(
        t, np.column_stack([cond, cond]), TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp, with_status=True
    )
    assert np.allclose(single.force_n, pair.force_n[:, 0], rtol=1e-13, atol=1e-14, equal_nan=True)
    assert np.array_equal(single.status, pair.status[:, 0])


RISING = SLSTrend(
    E0_Pa=(1.5e5, 3e5 / 7), E1_Pa=(2.5e5, 5e5 / 7), mu1_Pa_s=(2.5e7, 5e7 / 7)
)  # each parameter ∝ (0.5 + F/7 N): ±25 % over 1.75–5.25 N around the typical sensor


@pytest.mark.parametrize("phys", [DEFAULT_PHYSICS, NO_CONTACT], ids=["contact", "no-contact"])
def test_force_dependent_inverse_round_trips_the_force_dependent_forward(phys):
    rng = np.random.default_rng(12)
    t, force = _nonuniform_record(rng, 500)
    strain = strain_from_force_trend(t, force[:, 0], RISING, TYPICAL_AREA_M2)
    cond = conductance_from_strain(strain, force[:, 0], phys)
    result = force_from_conductance_trend(t, cond, RISING, TYPICAL_AREA_M2, phys)
    assert np.max(np.abs(result.force_n - force[:, 0])) <= 1e-10 * np.max(force)
    # the fixed-parameter inverse at the middle of the range is visibly wrong on the same data
    fixed = force_from_conductance(t, cond, RISING.at(3.5), TYPICAL_AREA_M2, phys)
    assert np.max(np.abs(fixed - force[:, 0])) > 0.05


def test_force_dependent_inverse_with_flat_trend_equals_the_fixed_inverse():
    rng = np.random.default_rng(13)
    t, force = _nonuniform_record(rng, 300)
    p = TYPICAL_SLS
    flat = SLSTrend((p.E0_Pa, 0.0), (p.E1_Pa, 0.0), (p.mu1_Pa_s, 0.0))
    cond = conductance_from_force(t, force[:, 0], p, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    cond[[40, 41]] = np.nan
    trend_res = force_from_conductance_trend(t, cond, flat, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    fixed_res = force_from_conductance(t, cond, p, TYPICAL_AREA_M2, DEFAULT_PHYSICS, with_status=True)
    assert np.allclose(trend_res.force_n, fixed_res.force_n, rtol=1e-12, atol=1e-13, equal_nan=True)
    assert np.array_equal(trend_res.status, fixed_res.status)


def test_force_dependent_inverse_refuses_invalid_trends():
    t = np.arange(3.0)
    cond = np.full(3, 1e-3)
    with pytest.raises(ValueError, match="intercept"):
        force_from_conductance_trend(
            t, cond, SLSTrend((0.0, 1e5), (1e5, 0), (1e7, 0)), TYPICAL_AREA_M2, NO_CONTACT
        )
    falling = SLSTrend((3e5, 0.0), (5e5, -2e5), (5e7, 0.0))  # E1 ≤ 0 beyond 2.5 N
    with pytest.raises(ValueError, match="sample 0"):
        force_from_conductance_trend(t, np.full(3, 2e-3), falling, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
