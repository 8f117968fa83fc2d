"""The rig driver against the independent XM430 emulator (tests/emulators/xm430_emulator.py, written from the
e-manual, its own process on a pty): the loading ramp the driver asks of the servo's Profile Velocity is the ramp the
servo makes."""

from __future__ import annotations

import time

import numpy as np
import pytest

from devices.config import RigConfig
from devices.rig import CalibrationRig
from tests.devices.sampling import sampled_rate
from tests.emulators.xm430_emulator import EmulatorProcess


@pytest.fixture
def rig_emulator():
    process = EmulatorProcess("--ids", "1")
    try:
        yield process
    finally:
        assert process.close() == 0


def test_start_ramp_winds_at_the_rate_asked_and_a_release_goes_at_full_speed(rig_emulator):
    with CalibrationRig(RigConfig(port=rig_emulator.path)) as rig:
        rig.contact_rad = rig.position_rad()  # no spring on the emulator: say the probe touches here
        goals_before = rig_emulator.state(1)["goal_writes"]
        target = rig.start_ramp(3.0, 1.0)  # 3 N over 1 s: 0.61 rad/s, 25 units of 0.229 rpm
        assert target == pytest.approx(rig.contact_rad + 3.0 / rig.newtons_per_rad, abs=0.002)
        _, angle, rate = sampled_rate(rig.position_rad, 1.3)
        expected = round((target - rig.contact_rad) / 1.0 / (0.229 * 2 * np.pi / 60)) * 0.229 * 2 * np.pi / 60
        assert rate == pytest.approx(expected, rel=0.05)  # the servo holds the ramp between the host's reads
        assert angle[-1] == pytest.approx(target, abs=0.01)
        assert rig_emulator.state(1)["goal_writes"] == goals_before + 1  # one goal for the whole ramp
        t_release = time.monotonic()
        rig.release()
        # 0.71 rad back at the no-load speed (~4.8 rad/s), not at the ramp's 0.6 rad/s (1.2 s)
        assert time.monotonic() - t_release < 0.6
