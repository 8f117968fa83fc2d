"""The simulated lab wires its devices together: the rig's probe is felt by the board channel of rig.sensor (the
scripted lab, at 50× real time)."""

from __future__ import annotations

import numpy as np

from devices.sim.lab import SimLab
from tests.conftest import scripted_config


def test_rig_probe_force_replaces_the_contact_force_on_its_board_channel():
    lab = SimLab(scripted_config(), seed=3, speed=50.0)
    channel = lab.config.board.channel_names.index(lab.config.rig.sensor)
    t = lab.clock.now()
    before = lab.forces_n(t)
    servo_id = lab.config.rig.servo_id
    # Turn the rig wheel 0.5 rad past the contact angle by hand (torque off → limp) and read the force again.
    theta = lab.rig.contact_angle_rad + 0.5
    lab.rig.chain.set_limp_position(servo_id, int(round(2048 + theta * 4096 / (2 * np.pi))))
    after = lab.forces_n(t)
    expected = lab.rig.applied_force_n()
    assert expected > 1.0
    assert np.isclose(after[channel], expected)
    others = np.delete(np.arange(after.size), channel)
    np.testing.assert_array_equal(after[others], before[others])


def test_resting_robot_stays_below_the_readout_saturation_and_walls_level_off():
    lab = SimLab(scripted_config(), seed=2, speed=50.0)
    peak = max(float(lab.contact.forces_n(t).max()) for t in np.arange(0.0, 120.0, 0.5))
    assert 1.0 < peak < 4.5  # weight share + travelling bump, below ~5 N where the typical sensor saturates
    # A hard yaw bend by hand pushes the body far past the virtual walls: the press levels off, it does not explode.
    for joint_id, axis in zip(lab.config.robot.joint_ids, lab.config.robot.axes):
        if axis == "yaw":
            lab.chain.set_limp_position(joint_id, 2048 + 1000)
    _, left, right = lab.contact.segment_loads_n(0.0)
    assert max(left.max(), right.max()) <= 3.0 + 1.0 + 1e-9  # wall cap + side bump
