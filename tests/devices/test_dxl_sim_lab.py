"""ServoChain on the whole simulated lab (``sim`` port through devices.factory): robot bus and rig bus."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from devices import control_table as ct
from devices.config import RobotConfig
from devices.servo_chain import ServoChain

pytest.importorskip("devices.sim.rig", reason="the simulated lab needs devices/sim/rig.py (board engineer's)")


def test_robot_bus_on_the_sim_lab(sim_lab_fast, read_until_at):
    with ServoChain(RobotConfig()) as chain:
        assert [i.servo_id for i in chain.scan(ids=range(1, 13))] == list(range(1, 13))
        chain.set_torque(True)
        goal = np.linspace(-0.3, 0.3, 12)
        chain.write_goals(goal)
        state = read_until_at(chain, goal)
        assert np.allclose(state.position_rad, goal, atol=3 * ct.RAD_PER_TICK)
        assert np.allclose(sim_lab_fast.chain.present_positions_rad(), goal, atol=3 * ct.RAD_PER_TICK)


def test_rig_bus_is_a_separate_one_servo_chain(sim_lab_fast):
    rig = sim_lab_fast.config.rig
    robot = dataclasses.replace(RobotConfig(), joint_ids=(rig.servo_id,), axes=("pitch",), signs=(1,),
                                zero_offsets_rad=(0.0,), joint_min_rad=(-3.0,), joint_max_rad=(3.0,), baud=rig.baud)
    with ServoChain(robot, device="rig") as chain:
        info = chain.ping(rig.servo_id)
        assert info.model_number == ct.MODEL_NUMBER_XM430_W350
        assert chain.read_state().position_rad.shape == (1,)
