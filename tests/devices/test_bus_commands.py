"""Named bus commands (devices.bus_commands): everything the app submits to the bus thread, and every motion source
it plays, is data that survives pickling — so the same command can run in the control loop's own process."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from app.core.play import build_source
from app.core.shapes import shape_from_dict
from app.core.teach import TeachSession
from devices import bus_commands
from devices.bus_commands import BusCommand, bus_command
from devices.config import RobotConfig
from models.trajectory import ParametricGait, SerpenoidParams


class RecordingChain:
    """Stands in for a ServoChain: records the calls a command makes."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def set_torque(self, enabled, ids):
        self.calls.append(("set_torque", enabled, ids))

    def set_return_delay(self, value, ids):
        self.calls.append(("set_return_delay", value, ids))

    def timing_warnings(self):
        return iter(["latency timer 16 ms"])

    def ping(self, servo_id):
        self.calls.append(("ping", servo_id))


def test_a_lambda_is_refused_as_a_bus_command_with_the_reason():
    with pytest.raises(TypeError, match="module-level function"):
        bus_command(lambda chain: None)


def test_the_hardware_tab_commands_pickle_and_run_the_same_after():
    chain = RecordingChain()
    commands = [bus_command(bus_commands.fix_return_delay, [1, 2]), bus_command(bus_commands.timing_warnings),
                bus_command(bus_commands.link_check, [3], rounds=2), bus_command(bus_commands.set_torque, True, (4,))]
    copies = [pickle.loads(pickle.dumps(c)) for c in commands]
    assert [c.name for c in copies] == ["fix_return_delay", "timing_warnings", "link_check", "set_torque"]
    assert copies[0](chain) == ["latency timer 16 ms"]
    rows = copies[2](chain)
    assert [r.servo_id for r in rows] == [3] and rows[0].ok and rows[0].rtt_mean_ms is not None
    copies[3](chain)
    assert chain.calls == [("set_return_delay", 0, [1, 2]), ("ping", 3), ("ping", 3), ("set_torque", True, [4])]


def test_teach_submits_only_named_commands():
    submitted: list = []

    def run_on_bus(command):
        assert isinstance(command, BusCommand)
        submitted.append(pickle.loads(pickle.dumps(command)))
        from concurrent.futures import Future
        return Future()

    session = TeachSession(run_on_bus, RobotConfig())
    session.capture()
    session.hold()
    session.torque_off([2])
    assert [c.name for c in submitted] == ["_read_pose", "_goals_to_present", "set_torque"]


@pytest.mark.parametrize("mode", ["follow", "keyframes"])
def test_a_play_source_pickles_and_plans_the_same_goals(mode):
    robot = RobotConfig()
    angles = [0.2 * (-1) ** i for i in range(robot.n_joints)]
    keyframes = [{"t_s": 0.0, "angles_rad": angles}, {"t_s": 2.0, "angles_rad": [0.0] * robot.n_joints}]
    shape = shape_from_dict({"format": "sensnake-shape", "version": 1, "name": "wave", "axes": list(robot.axes),
                             "angles_rad": angles, "keyframes": keyframes})
    source = build_source(shape, robot, "follow" if mode == "follow" else "keyframe", 0.5, 1.0, 1)
    copy = pickle.loads(pickle.dumps(source))
    present = np.linspace(-0.1, 0.1, robot.n_joints)
    for t_s in (0.0, 0.02, 0.5, 1.3):
        np.testing.assert_array_equal(copy.goal_at(t_s, present), source.goal_at(t_s, present))


def test_a_gait_source_pickles():
    robot = RobotConfig()
    gait = ParametricGait(robot.axes, SerpenoidParams(0.3, 0.6, 0.5, 0.0, 2, 1.0))
    copy = pickle.loads(pickle.dumps(gait))
    present = np.zeros(robot.n_joints)
    np.testing.assert_array_equal(copy.goal_at(0.7, present), gait.goal_at(0.7, present))
    assert dataclasses.is_dataclass(copy.progress)
