"""RobotBridge with the robot on a real port (the independent XM430 emulator on a pty, its own process): the control
loop runs in its own process; a play goes through it; a killed loop process is said so, keeps what was received and
leaves the app up; a child that cannot start falls back to the app's process with the reason; port sim stays
in-process."""

from __future__ import annotations

import dataclasses
import os
import signal
import sys

import pytest

from app.gui.robot_bridge import MOTION_FAULT, MOTION_FINISHED, RobotBridge
from devices.config import LabConfig
from devices.loop_process import ControllerProcess
from models.trajectory import FollowTheLeader

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the emulator needs a pty (Linux)")

TIMEOUT_MS = 30_000  # subprocesses on a loaded 2-core machine


@pytest.fixture
def bridge(qtbot, emulator):
    robot = RobotBridge(dataclasses.replace(LabConfig().robot, port=emulator.path))
    yield robot
    robot.close()


def connect(qtbot, bridge: RobotBridge) -> None:
    with qtbot.waitSignal(bridge.connected, timeout=TIMEOUT_MS) as blocker:
        bridge.connect()
    assert blocker.args == [True]


def wave(bridge: RobotBridge, speed: float) -> FollowTheLeader:
    robot = bridge.config
    return FollowTheLeader([0.3 * (-1) ** i for i in range(12)], robot.axes, speed, 1, rate_hz=robot.control_rate_hz)


def test_on_a_real_port_the_loop_runs_in_its_own_process_and_plays(qtbot, bridge, emulator):
    events: list[str] = []
    bridge.event.connect(events.append)
    connect(qtbot, bridge)
    assert isinstance(bridge.controller, ControllerProcess) and bridge.controller.pid != os.getpid()
    assert bridge.loop_where == f"its own process (pid {bridge.controller.pid})"
    assert any("control loop in its own process" in e for e in events)
    blocks: list[list] = []
    bridge.state_block.connect(blocks.append)
    source = wave(bridge, 1.0)
    bridge.play(source, "wave")
    qtbot.waitUntil(lambda: bridge.motion_state == MOTION_FINISHED, timeout=TIMEOUT_MS)
    assert source.progress.done
    assert emulator.counts()["sync_write"] > 10
    qtbot.waitUntil(lambda: sum(len(b) for b in blocks) > 10, timeout=TIMEOUT_MS)
    stats = bridge.loop_stats()
    assert stats.ticks > 10


def test_a_killed_loop_process_is_said_so_keeps_what_was_received_and_the_app_reconnects(qtbot, bridge, emulator):
    errors: list[str] = []
    bridge.error.connect(errors.append)
    received: list = []
    bridge.state_block.connect(received.extend)
    connect(qtbot, bridge)
    bridge.play(wave(bridge, 0.05), "slow")
    qtbot.waitUntil(lambda: len(received) > 5 and bridge.controller.motion_name == "slow", timeout=TIMEOUT_MS)
    pid = bridge.controller.pid
    with qtbot.waitSignal(bridge.connected, timeout=TIMEOUT_MS) as blocker:
        os.kill(pid, signal.SIGKILL)
    assert blocker.args == [False] and not bridge.is_connected
    died = [e for e in errors if "control loop process" in e]
    assert len(died) == 1, errors  # once, though the motion's Future and on_error both carry it
    assert f"pid {pid}" in died[0] and "killed by SIGKILL" in died[0] and "Reconnect the robot" in died[0]
    assert bridge.motion_state == MOTION_FAULT
    assert "reconnect" in bridge.connection_text
    n_received = len(received)
    assert n_received > 5  # nothing taken back
    connect(qtbot, bridge)  # the app stays up: Connect starts a new loop process
    assert bridge.controller.pid != pid
    qtbot.waitUntil(lambda: len(received) > n_received + 5, timeout=TIMEOUT_MS)


def test_a_loop_process_that_cannot_start_falls_back_to_the_apps_process_saying_why(qtbot, bridge, monkeypatch):
    monkeypatch.setattr(sys, "executable", "/nonexistent/python3")
    events: list[str] = []
    bridge.event.connect(events.append)
    connect(qtbot, bridge)
    assert not isinstance(bridge.controller, ControllerProcess)
    assert bridge.loop_where.startswith("the app's process (cannot start /nonexistent/python3")
    assert any("control loop in the app's process (cannot start" in e for e in events)


def test_port_sim_keeps_the_loop_in_the_apps_process(qtbot, sim_lab_fast):
    bridge = RobotBridge(LabConfig().robot)
    try:
        connect(qtbot, bridge)
        assert not isinstance(bridge.controller, ControllerProcess)
        assert bridge.loop_where == "the app's process (port sim: the simulated lab lives in the app's process)"
    finally:
        bridge.close()
