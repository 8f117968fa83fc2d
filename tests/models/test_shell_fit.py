"""models.shell_fit: a shell's stiffness and travel from the rig's windings and a dial gauge's readings."""

from __future__ import annotations

import numpy as np
import pytest

from models.errors import ShellFitError
from models.shell_fit import fit_shell

K = 246.0
RES = 1e-5


def _steps(stiffness, travel=0.003, *, gauge_rate=0.0, gauge_force=0.0, noise=3e-6, seed=0, top_n=8.0, n=16,
           curve=0.0):
    rng = np.random.default_rng(seed)
    cable = np.concatenate([[-0.003, -0.002, -0.001], np.linspace(top_n / n / K, top_n / K, n)])
    contact = 0.0004
    rest = gauge_force / stiffness
    d = np.minimum(K * np.maximum(0.0, cable - contact) / (K + stiffness + gauge_rate), travel - rest)
    d = d * (1.0 - curve * d / 0.003)
    gauge = np.round((d + 0.0012 + rng.normal(0.0, noise, len(d))) / RES) * RES
    return cable, gauge


@pytest.mark.parametrize("stiffness", [1400.0, 3000.0])
def test_recovers_the_stiffness_with_an_interval_holding_it(stiffness):
    fit = fit_shell(*_steps(stiffness), spring_k_n_per_m=K, resolution_m=RES)
    assert fit.stiffness_n_per_m == pytest.approx(stiffness, rel=0.02)
    assert fit.stiffness_interval[0] < stiffness < fit.stiffness_interval[1]
    assert "shell_stiffness_n_per_m" not in fit.not_fixed
    assert "shell_damping_n_s_per_m" in fit.not_fixed  # readings at rest never fix it


def test_travel_fixed_only_when_the_shell_bottoms_out():
    soft = fit_shell(*_steps(1400.0), spring_k_n_per_m=K, resolution_m=RES)  # bottoms out at 4.2 N
    assert soft.n_bottomed >= 3 and soft.travel_interval[0] < 0.003 < soft.travel_interval[1]
    assert "shell_travel_m" not in soft.not_fixed
    stiff = fit_shell(*_steps(3000.0), spring_k_n_per_m=K, resolution_m=RES)  # would need 9 N
    assert np.isnan(stiff.travel_m) and "never bottomed out" in stiff.not_fixed["shell_travel_m"]


def test_the_gauges_own_spring_is_taken_out():
    steps = _steps(2000.0, gauge_rate=150.0, gauge_force=1.0)
    naive = fit_shell(*steps, spring_k_n_per_m=K, resolution_m=RES)
    fit = fit_shell(*steps, spring_k_n_per_m=K, resolution_m=RES, gauge_rate_n_per_m=150.0, gauge_force_n=1.0)
    assert naive.stiffness_n_per_m == pytest.approx(2150.0, rel=0.02)  # the plunger's rate looks like shell
    assert fit.stiffness_n_per_m == pytest.approx(2000.0, rel=0.02)
    assert fit.travel_m == pytest.approx(0.003, rel=0.02)  # the preload's 0.5 mm given back


def test_no_contact_and_a_snapped_cable_are_refused_with_the_reason():
    cable, gauge = _steps(2000.0)
    with pytest.raises(ShellFitError, match="no contact reached"):
        fit_shell(cable, np.full_like(gauge, gauge[0]), spring_k_n_per_m=K, resolution_m=RES)
    snapped = gauge.copy()
    snapped[10:] = gauge[0]  # the probe back at rest from step 11 while the cable winds on
    with pytest.raises(ShellFitError, match="snapped"):
        fit_shell(cable, snapped, spring_k_n_per_m=K, resolution_m=RES)
    with pytest.raises(ShellFitError, match="at least"):
        fit_shell(cable[:4], gauge[:4], spring_k_n_per_m=K, resolution_m=RES)


def test_a_shell_that_is_no_linear_spring_or_barely_moves_is_not_fixed():
    curved = fit_shell(*_steps(3000.0, curve=0.3), spring_k_n_per_m=K, resolution_m=RES)
    assert "not a straight line" in curved.not_fixed["shell_stiffness_n_per_m"]
    rigid = fit_shell(*_steps(120000.0), spring_k_n_per_m=K, resolution_m=RES)
    assert "95 % interval" in rigid.not_fixed["shell_stiffness_n_per_m"]
