"""The simulated lab wires its devices together: the rig's probe is felt by the board channel of rig.sensor."""

from __future__ import annotations

import numpy as np

from devices.sim.lab import SimLab


def test_rig_probe_force_reaches_its_board_channel():
    lab = SimLab(seed=3, speed=50.0)
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
    assert np.isclose(after[channel] - before[channel], expected)
    others = np.delete(np.arange(after.size), channel)
    np.testing.assert_array_equal(after[others], before[others])
