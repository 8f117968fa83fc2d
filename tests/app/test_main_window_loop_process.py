"""The whole window with the robot on a real port (the independent XM430 emulator on a pty, its own process) and
the control loop in its own process: the loop process killed during a motion while the Forces tab records. The
window says what happened and what to do, shows the robot disconnected, keeps what was recorded and delivered, and
Connect on the Hardware tab starts a new loop process that ticks."""

from __future__ import annotations

import os
import signal
import sys

import pytest

from app.core.recording import open_recording
from app.gui.robot_bridge import MOTION_FAULT
from devices.config import SIM_PORT, load_config
from devices.loop_process import ControllerProcess
from models.trajectory import FollowTheLeader
from tests.app.windows import open_connected_window

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the emulator needs a pty (Linux)"),
              pytest.mark.usefixtures("sim_lab_fast")]

TIMEOUT_MS = 30_000  # subprocesses on a loaded 2-core machine


@pytest.fixture
def window(qtbot, emulator, tmp_path, monkeypatch):
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    config = load_config().with_ports(robot=emulator.path, board=SIM_PORT, rig=SIM_PORT)
    win = open_connected_window(qtbot, config, tmp_path, TIMEOUT_MS)
    with qtbot.waitSignal(win.lab.board.connected, timeout=TIMEOUT_MS):
        win.lab.board.start()
    yield win
    win.close()


def test_a_killed_loop_process_is_said_in_the_window_keeps_the_recording_and_connect_starts_a_new_one(
        qtbot, window, tmp_path):
    lab, robot = window.lab, window.lab.robot
    controller = robot.controller
    assert isinstance(controller, ControllerProcess)
    pid = controller.pid
    assert pid != os.getpid()
    delivered: list = []
    robot.state_block.connect(delivered.extend)
    forces = window.show_tab("forces")
    session = forces.start_recording(tmp_path / "during.h5", duration_s=None)
    assert session is not None and session.recorder.with_robot
    robot.set_torque(True).result(timeout=30)
    cfg = lab.config.robot
    robot.play(FollowTheLeader([0.4 * (-1) ** i for i in range(12)], cfg.axes, 0.05, 1, rate_hz=cfg.control_rate_hz),
               "slow wave")
    qtbot.waitUntil(lambda: controller.motion_name == "slow wave" and session.recorder.n_robot_samples > 10,
                    timeout=TIMEOUT_MS)
    assert "slow wave" in window.status.robot_label.text()

    with qtbot.waitSignal(robot.connected, timeout=TIMEOUT_MS) as blocker:
        os.kill(pid, signal.SIGKILL)
    assert blocker.args == [False]
    # The window says what happened and what to do, in its message area, and shows the robot disconnected.
    qtbot.waitUntil(lambda: "control loop process" in window.status.message, timeout=TIMEOUT_MS)
    message = window.status.message
    assert f"pid {pid}" in message and "killed by SIGKILL" in message and "motion 'slow wave' stopped" in message
    assert "servos hold their last goal" in message and "Reconnect the robot (Hardware tab → Connect)" in message
    assert not robot.is_connected and robot.motion_state == MOTION_FAULT
    robot_text = window.status.robot_label.text()
    assert "control loop stopped" in robot_text and "reconnect" in robot_text and "slow wave" not in robot_text
    # What was delivered and recorded before the death is kept; the recording goes on (the board is not the robot).
    n_delivered, n_recorded = len(delivered), session.recorder.n_robot_samples
    assert n_delivered > 10 and n_recorded > 10
    assert session.is_active
    forces.stop_recording()
    qtbot.waitUntil(lambda: not session.is_active, timeout=TIMEOUT_MS)
    recording = open_recording(tmp_path / "during.h5")
    assert recording.robot is not None and recording.robot.time_s.size == n_recorded
    assert len(delivered) == n_delivered  # nothing arrives from a dead loop, nothing was taken back

    # Connect on the Hardware tab starts a new loop process, which ticks.
    hardware = window.show_tab("hardware")
    button = hardware.panel.connect_button
    qtbot.waitUntil(button.isEnabled, timeout=TIMEOUT_MS)
    with qtbot.waitSignal(robot.connected, timeout=TIMEOUT_MS) as blocker:
        button.click()
    assert blocker.args == [True]
    new = robot.controller
    assert isinstance(new, ControllerProcess) and new.pid not in (None, pid)
    qtbot.waitUntil(lambda: len(delivered) > n_delivered + 10, timeout=TIMEOUT_MS)
    assert f"its own process (pid {new.pid})" in robot.loop_where
    assert "control loop stopped" not in window.status.robot_label.text()
