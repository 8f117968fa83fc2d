"""The simulated rig with a segment's compliant shell under its probe (VirtualRig.mount_shell) and its dial gauge."""

from __future__ import annotations

import pytest

from devices.config import RigConfig
from devices.sim.clock import SimClock
from devices.sim.gauge import SimDialGauge
from devices.sim.rig import ShellSpecimen, VirtualRig

K, R = 246.0, 0.02


class ManualClock(SimClock):
    """Simulated time that moves only when the test moves it."""

    def __init__(self) -> None:
        super().__init__()
        self.t = 0.0

    def now(self) -> float:
        return self.t


def _rig(shell: ShellSpecimen | None, clock: SimClock | None = None) -> VirtualRig:
    rig = VirtualRig(RigConfig(), clock or SimClock(1000.0), seed=3)
    rig.mount_shell(shell)
    return rig


def _wind(rig: VirtualRig, past_contact_rad: float) -> float:
    """Pose the (limp) rig servo ``past_contact_rad`` past its contact; returns the cable wound past it (m)."""
    ticks = 2048 + (rig.contact_angle_rad + past_contact_rad) * 4096 / (2 * 3.141592653589793)
    rig.chain.set_limp_position(1, ticks)
    theta = float(rig.chain.present_positions_rad()[0])
    return R * max(0.0, theta - rig.contact_angle_rad)


def test_a_rigid_sensor_is_what_the_rig_always_was():
    rig = _rig(None)
    cable = _wind(rig, 0.8)
    assert rig.applied_force_n() == pytest.approx(K * cable)
    assert rig.probe_travel_m() == 0.0


def test_on_a_shell_the_probe_travels_and_the_force_is_what_the_shell_bears():
    rig = _rig(ShellSpecimen(1400.0, 0.0, 0.003))
    cable = _wind(rig, 0.5)
    travel = rig.probe_travel_m()
    assert travel == pytest.approx(K * cable / (K + 1400.0))
    assert rig.applied_force_n() == pytest.approx(1400.0 * travel)  # less than k·r·Δθ by k/(k + k_shell)
    assert rig.applied_force_n() < K * cable
    _wind(rig, 1.5)  # 7.4 N of winding: the shell bottoms out at 3 mm, the rest goes into the spring
    assert rig.probe_travel_m() == pytest.approx(0.003)
    rig.snap_cable()
    assert rig.probe_travel_m() == 0.0 and rig.applied_force_n() == 0.0


def test_the_gauges_measuring_force_loads_the_shell_and_its_rate_stiffens_it():
    rig = _rig(ShellSpecimen(2000.0, 0.0, 0.003, gauge_force_n=1.0, gauge_rate_n_per_m=150.0))
    assert rig.applied_force_n() == pytest.approx(1.0)  # slack cable: the plunger alone presses the sensor
    cable = _wind(rig, 0.5)
    assert rig.probe_travel_m() == pytest.approx(K * cable / (K + 2000.0 + 150.0))


def test_the_shells_damping_lags_the_probe_and_the_gauge_reads_to_its_digit():
    clock = ManualClock()
    rig = _rig(ShellSpecimen(2000.0, 30.0, 0.003), clock)
    cable = _wind(rig, 0.5)
    static = K * cable / (K + 2000.0)
    assert rig.probe_travel_m() == 0.0  # the winding was a jump: no time has passed for the shell to follow
    clock.t = 30.0 / (K + 2000.0)  # one time constant c/(k + k_shell), 13 ms
    assert rig.probe_travel_m() == pytest.approx(static * (1 - 0.36788), rel=1e-3)
    clock.t = 1.0
    assert rig.probe_travel_m() == pytest.approx(static)
    gauge = SimDialGauge(rig, seed=1, zero_m=0.0)
    reading = gauge.read_m("test")
    assert abs(reading / 1e-5 - round(reading / 1e-5)) < 1e-6  # whole digits
    assert reading == pytest.approx(rig.probe_travel_m(), abs=2e-5)


def test_a_typed_gauge_reading_is_asked_again_and_the_end_of_input_is_named():
    from devices.errors import GaugeReadError
    from devices.gauge import TypedGauge

    lines = iter(["", "1,25"])
    assert TypedGauge(ask=lambda prompt: next(lines)).read_m("step 1") == pytest.approx(0.00125)

    def ended(prompt: str) -> str:
        raise EOFError

    with pytest.raises(GaugeReadError, match="input ended"):
        TypedGauge(ask=ended).read_m("step 2")
    with pytest.raises(GaugeReadError, match="not a number"):
        TypedGauge(ask=lambda prompt: "twelve").read_m("step 3")
