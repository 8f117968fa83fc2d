"""The compiled recursions (models.sls_kernels, numba) against the exact pure-numpy reference paths of models.sls."""

from __future__ import annotations

import numpy as np
import pytest

from models import sls, sls_kernels
from models.physics import DEFAULT_PHYSICS
from models.sls import (
    TYPICAL_AREA_M2,
    SLSParams,
    conductance_from_force,
    force_from_conductance,
    strain_from_force,
)

pytestmark = pytest.mark.skipif(sls_kernels.kernels() is None, reason="numba not installed (compiled path off)")


def _forces(n_sensors: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, SLSParams]:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 0.3, 600))
    t = np.concatenate([[0.0], t, t[-1:] + 0.0])  # a duplicate timestamp: a zero-length step
    base = rng.uniform(0.5, 5.0, n_sensors)
    force = base * (1 + 0.3 * np.sin(t[:, None] / rng.uniform(3, 30, n_sensors))) * (t[:, None] > 2)
    params = SLSParams(rng.uniform(2e5, 8e5, n_sensors), rng.uniform(2e5, 9e5, n_sensors),
                       rng.uniform(1e7, 1e9, n_sensors))
    return t, force, params


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
def test_inverse_compiled_equals_reference_including_bad_samples(n_sensors, interp, with_contact):
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


def test_streaming_blocks_equal_one_call():
    t, force, params = _forces(36, seed=3)
    cond = np.asarray(conductance_from_force(t, force, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS))
    whole = force_from_conductance(t, cond, params, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    inverse = sls.SLSInverse(params, TYPICAL_AREA_M2, DEFAULT_PHYSICS, 36)
    parts = [inverse.update(t[i:i + 97], cond[i:i + 97]).force_n for i in range(0, t.size, 97)]
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=1e-12)
