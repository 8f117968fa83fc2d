"""The compiled recursions (models.sls_kernels, numba; models.sls_ckernel, C) against the exact pure-numpy reference
paths of models.sls."""

from __future__ import annotations

import numpy as np
import pytest

from models import sls, sls_ckernel, sls_inverse, sls_kernels
from models.physics import DEFAULT_PHYSICS
from models.sls import (
    TYPICAL_AREA_M2,
    SLSParams,
    conductance_from_force,
    force_from_conductance,
    strain_from_force,
)

needs_numba = pytest.mark.skipif(sls_kernels.kernels() is None, reason="numba not installed (compiled path off)")


def _inverse_backend(name: str):
    if name == "c":
        kernel = sls_ckernel.inverse_kernel()
        if kernel is None:
            pytest.skip(f"C kernel not built: {sls_ckernel.why_not}")
        return kernel
    kernels = sls_kernels.kernels()
    if kernels is None:
        pytest.skip("numba not installed (compiled path off)")
    return kernels.inverse


@pytest.fixture(params=["c", "numba"])
def inverse_backend(request, monkeypatch):
    """Runs the test with the inverse on one compiled backend (the app picks C, then numba)."""
    kernel = _inverse_backend(request.param)
    monkeypatch.setattr(sls_inverse, "_compiled_inverse", lambda: kernel)
    return request.param


def _forces(n_sensors: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, SLSParams]:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 0.3, 600))
    t = np.concatenate([[0.0], t, t[-1:] + 0.0])  # a duplicate timestamp: a zero-length step
    base = rng.uniform(0.5, 5.0, n_sensors)
    force = base * (1 + 0.3 * np.sin(t[:, None] / rng.uniform(3, 30, n_sensors))) * (t[:, None] > 2)
    params = SLSParams(rng.uniform(2e5, 8e5, n_sensors), rng.uniform(2e5, 9e5, n_sensors),
                       rng.uniform(1e7, 1e9, n_sensors))
    return t, force, params


@needs_numba
@pytest.mark.parametrize("n_sensors", [1, 36])
@pytest.mark.parametrize("interp", ["hold", "linear"])
def test_forward_strain_compiled_equals_reference(n_sensors, interp):
    t, force, params = _forces(n_sensors)
    compiled = strain_from_force(t, force, params, TYPICAL_AREA_M2, interp)
    with sls.engine("numpy"):
        reference = strain_from_force(t, force, params, TYPICAL_AREA_M2, interp)
    np.testing.assert_allclose(compiled, reference, rtol=1e-13, atol=1e-18)


@pytest.mark.parametrize("n_sensors", [1, 36])
@pytest.mark.parametrize("interp", ["hold", "linear"])
@pytest.mark.parametrize("with_contact", [True, False])
def test_inverse_compiled_equals_reference_including_bad_samples(n_sensors, interp, with_contact, inverse_backend):
    t, force, params = _forces(n_sensors, seed=n_sensors)
    phys = DEFAULT_PHYSICS if with_contact else DEFAULT_PHYSICS.without_contact()
    cond = np.asarray(conductance_from_force(t, force, params, TYPICAL_AREA_M2, phys, interp)).reshape(t.size, -1)
    cond = cond.copy()
    cond[50, 0], cond[60, -1], cond[70, 0], cond[80, -1] = np.nan, -1e-4, 0.0, np.inf
    args = (t, cond, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, interp)
    compiled = force_from_conductance(*args, with_contact=with_contact, with_status=True)
    with sls.engine("numpy"):
        reference = force_from_conductance(*args, with_contact=with_contact, with_status=True)
    np.testing.assert_array_equal(compiled.status, reference.status)
    finite = np.isfinite(reference.force_n) & (reference.status != sls.ForceStatus.SATURATED)
    np.testing.assert_array_equal(np.isnan(compiled.force_n), np.isnan(reference.force_n))
    np.testing.assert_allclose(compiled.force_n[finite], reference.force_n[finite], rtol=1e-9, atol=1e-12)
    truth = force.reshape(t.size, -1)
    good = (reference.status == 0) & (truth > 0.1)
    good[50:] = False  # after the bad samples the state legitimately differs from the truth
    np.testing.assert_allclose(compiled.force_n[good], truth[good], rtol=1e-7)


def test_streaming_blocks_equal_one_call(inverse_backend):
    t, force, params = _forces(36, seed=3)
    cond = np.asarray(conductance_from_force(t, force, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS))
    whole = force_from_conductance(t, cond, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    inverse = sls.SLSInverse(params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, 36)
    parts = [inverse.update(t[i:i + 97], cond[i:i + 97]).force_n for i in range(0, t.size, 97)]
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=1e-12)


@pytest.mark.parametrize("with_contact", [True, False])
def test_c_and_numba_kernels_agree_on_a_long_record(with_contact):
    t, force, params = _forces(36, seed=7)
    phys = DEFAULT_PHYSICS if with_contact else DEFAULT_PHYSICS.without_contact()
    cond = np.asarray(conductance_from_force(t, force, params, TYPICAL_AREA_M2, phys)).reshape(t.size, -1)
    results = {}
    for name in ("c", "numba"):
        kernel = _inverse_backend(name)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(sls_inverse, "_compiled_inverse", lambda kernel=kernel: kernel)
            results[name] = force_from_conductance(t, cond, params, TYPICAL_AREA_M2, phys, with_contact=with_contact,
                                                   with_status=True)
    np.testing.assert_array_equal(results["c"].status, results["numba"].status)
    np.testing.assert_allclose(results["c"].force_n, results["numba"].force_n, rtol=1e-12, atol=1e-15)


def test_c_kernel_builds_into_a_fresh_cache_and_is_reused(tmp_path, monkeypatch):
    if sls_ckernel._compiler() is None:
        pytest.skip("no C compiler on this machine")
    monkeypatch.setenv("SENSNAKE_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(sls_ckernel, "_tried", False)
    monkeypatch.setattr(sls_ckernel, "_kernel", None)
    assert sls_ckernel.inverse_kernel() is not None, sls_ckernel.why_not
    built = list(tmp_path.glob("sls_inverse_*.so"))
    assert len(built) == 1 and not list(tmp_path.glob("*.tmp"))
    stamp = built[0].stat().st_mtime_ns
    monkeypatch.setattr(sls_ckernel, "_tried", False)
    assert sls_ckernel.inverse_kernel() is not None
    assert built[0].stat().st_mtime_ns == stamp  # loaded, not rebuilt


def test_without_a_compiler_the_c_kernel_says_why_and_the_estimate_still_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("SENSNAKE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, gcc or clang to be found
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(sls_ckernel, "_tried", False)
    monkeypatch.setattr(sls_ckernel, "_kernel", None)
    assert sls_ckernel.inverse_kernel() is None
    assert "no C compiler" in sls_ckernel.why_not
    t, force, params = _forces(3, seed=5)
    cond = np.asarray(conductance_from_force(t, force, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS))
    got = force_from_conductance(t, cond, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    with sls.engine("numpy"):
        reference = force_from_conductance(t, cond, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    np.testing.assert_allclose(got, reference, rtol=1e-9, atol=1e-12)


def test_a_shared_tau_with_only_one_sensor_needing_the_linear_fallback(inverse_backend):
    # Same τ (10 ms), 1 s steps: sensor 1 (E0 = 4·E1) needs the linear fallback on every step, sensor 0 (E0 < E1)
    # none, so the ramp is per sensor while the step factor is shared: the kernels read the two arrays' rows apart.
    params = SLSParams(np.array([1e5, 6e5]), np.array([6e5, 1.5e5]), np.array([6e3, 1.5e3]))
    t = np.arange(0.0, 60.0, 1.0)
    rng = np.random.default_rng(4)
    force = 3.0 + rng.normal(0, 0.3, (t.size, 2))
    cond = np.asarray(conductance_from_force(t, force, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, "hold"))
    noisy = cond * (1 + rng.normal(0, 1e-4, cond.shape))
    compiled = force_from_conductance(t, noisy, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, "hold")
    with sls.engine("numpy"):
        reference = force_from_conductance(t, noisy, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, "hold")
    np.testing.assert_allclose(compiled, reference, rtol=1e-9)
    assert np.max(np.abs(compiled - force)) < 2 * np.max(np.abs(np.diff(force, axis=0)))
