"""Teach logic against the simulated chain (real ServoChain + RobotController over the wire) and `sensnake teach`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from app.core.teach import TeachSession, sim_hand_for, ticks_from_angle
from devices.config import RobotConfig
from devices.controller import RobotController
from devices.errors import JointLimitError
from devices.servo_chain import ServoChain
from tests.waiting import wait_until

BUS_TIMEOUT_S = 3.0
POSE_TICKS = np.array([2048 + 37 * k * (-1) ** k for k in range(12)], dtype=int)


@pytest.fixture
def controller(sim_lab_fast):
    robot = RobotConfig()
    chain = ServoChain(robot)
    ctl = RobotController(chain, robot)
    ctl.start()
    yield ctl
    ctl.close()


def _wait_states(controller, n):
    """Block until the controller has read ``n`` more states; fails the test if it does not within WAIT_S."""
    start = controller.stats().ticks
    assert wait_until(lambda: controller.stats().ticks >= start + n), f"the controller did not tick {n} times"


def test_teach_captures_a_hand_pose_to_the_tick_and_holds_it(controller, sim_lab_fast):
    robot = controller.robot
    session = TeachSession(controller.submit, robot, controller.set_torque)
    session.torque_off().result(BUS_TIMEOUT_S)
    chain = sim_lab_fast.chain
    assert all(chain.register(sid, "Torque Enable") == 0 for sid in robot.joint_ids)
    hand = sim_hand_for(robot)
    assert hand is not None
    for sid, ticks in zip(robot.joint_ids, POSE_TICKS):
        hand.set_ticks(sid, int(ticks))
    pose = session.capture().result(BUS_TIMEOUT_S)
    np.testing.assert_array_equal(controller.chain.ticks_from_angles(pose.angles_rad), POSE_TICKS)

    goals = session.hold().result(BUS_TIMEOUT_S)
    np.testing.assert_allclose(goals, pose.angles_rad, atol=1e-12)
    assert all(chain.register(sid, "Torque Enable") == 1 for sid in robot.joint_ids)
    np.testing.assert_array_equal(chain.goal_positions_ticks(), POSE_TICKS)  # goal = present before torque on
    _wait_states(controller, 10)
    present = controller.latest_state.position_rad
    # no jump: after torque on the joints stay where the hand left them (±1 tick of encoder noise)
    assert np.max(np.abs(controller.chain.ticks_from_angles(present) - POSE_TICKS)) <= 1


def test_selected_joints_only_and_sim_hand_refuses_a_holding_joint(controller):
    robot = controller.robot
    session = TeachSession(controller.submit, robot, controller.set_torque)
    session.hold().result(BUS_TIMEOUT_S)
    session.torque_off([3, 4]).result(BUS_TIMEOUT_S)
    hand = sim_hand_for(robot)
    hand.set_angle(2, 0.3)  # joint ID 3 is limp
    with pytest.raises(ValueError, match="servo 5 has torque on"):
        hand.set_angle(4, 0.3)
    pose = session.capture().result(BUS_TIMEOUT_S)
    assert pose.angles_rad[2] == pytest.approx(0.3, abs=0.0016)
    with pytest.raises(ValueError, match="servo 99 is not one of the robot's joints"):
        session.torque_off([99])


def test_hold_refuses_a_joint_outside_its_limits(controller, sim_lab_fast):
    robot = controller.robot
    session = TeachSession(controller.submit, robot, controller.set_torque)
    session.torque_off().result(BUS_TIMEOUT_S)
    sim_lab_fast.chain.set_limp_position(6, ticks_from_angle(robot, 5, 1.70))  # beyond joint_max_rad = 1.57
    with pytest.raises(JointLimitError, match=r"joint 6 is at 1\.700 rad, outside its limits"):
        session.hold().result(BUS_TIMEOUT_S)
    assert sim_lab_fast.chain.register(6, "Torque Enable") == 0  # torque stayed off: nothing jumped


def test_cli_teach_after_seconds_writes_the_shape_and_holds(sim_lab_fast, tmp_path, capsys):
    robot = RobotConfig()
    chain = sim_lab_fast.chain
    # The simulated servos power up limp, as real ones do: pose them "by hand" before teach captures.
    for sid, ticks in zip(robot.joint_ids, POSE_TICKS):
        chain.set_limp_position(sid, int(ticks))
    out = tmp_path / "pose.json"
    code = main(["teach", "--robot", "sim", "--after", "0.2", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    data = json.loads(out.read_text())
    assert data["format"] == "sensnake-shape" and data["name"] == "pose"
    ticks = np.rint(np.asarray(data["angles_rad"]) / (2 * np.pi / 4096) + 2048).astype(int)
    np.testing.assert_array_equal(ticks, POSE_TICKS)
    assert all(chain.register(sid, "Torque Enable") == 1 for sid in robot.joint_ids)
    np.testing.assert_array_equal(chain.goal_positions_ticks(), POSE_TICKS)
    assert "wrote" in capsys.readouterr().out


def test_cli_teach_bad_port_is_one_line(tmp_path, capsys):
    code = main(["teach", "--robot", "/dev/does-not-exist", "--after", "0", "--out", str(tmp_path / "x.json")])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err.count("\n") == 0 and "/dev/does-not-exist" in err


def test_cli_teach_waits_for_enter(sim_lab_fast, tmp_path, capsys, monkeypatch):
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO("\n"))
    out = tmp_path / "enter.json"
    assert main(["teach", "--robot", "sim", "--out", str(out)]) == 0
    assert "press Enter" in capsys.readouterr().out and out.exists()
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    assert main(["teach", "--robot", "sim", "--out", str(tmp_path / "eof.json")]) == 1
    assert "standard input closed" in capsys.readouterr().err
    assert not (tmp_path / "eof.json").exists()
