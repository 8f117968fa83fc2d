"""The app as ``sensnake gui`` opens it on the simulated lab: the lab in its own process, the control loop in
another, the GUI in neither. Every tab that touches the simulated lab still works through the ptys: the robot
connects (simulated, its loop in its own process), the board streams, the Teach tab's hand bends a limp joint and
the capture reads it back through the wire, the 3-D tab draws the lab's world; the lab's process ends with it."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest
from PySide6.QtCore import QSettings, Qt

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from app.gui.lab import LabContext  # noqa: E402
from app.gui.main_window import MainWindow  # noqa: E402
from devices import factory  # noqa: E402
from devices.config import LabConfig, SimLabConfig  # noqa: E402
from devices.loop_process import ControllerProcess  # noqa: E402
from devices.sim.lab_process import LabProcess  # noqa: E402

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ptys (Linux)")

WAIT_MS = 30_000  # three processes on a loaded 2-core machine
FLAT = dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="mujoco", obstacle_height_ratio=0.0))


@pytest.fixture
def no_lab_yet():
    """No simulated lab made yet, as when the app starts; the one the test makes is closed after it."""
    previous = factory.install_sim_lab(None)
    yield
    made = factory.install_sim_lab(previous)
    if made is not None and hasattr(made, "close"):
        made.close()


def test_the_app_runs_on_a_simulated_lab_in_its_own_process_and_every_device_works(qtbot, tmp_path, no_lab_yet):
    lab = LabContext(FLAT, lab_process=True)
    sim = factory.installed_sim_lab()
    assert isinstance(sim, LabProcess) and sim.alive
    assert lab.lab_where == f"its own process (pid {sim.pid})"
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.show()
    try:
        with qtbot.waitSignal(lab.robot.connected, timeout=WAIT_MS) as blocker:
            lab.robot.connect_robot()
        assert blocker.args == [True]
        assert isinstance(lab.robot.controller, ControllerProcess)  # the loop: a process of its own too
        assert lab.robot.loop_where.startswith("its own process")
        assert lab.robot.is_sim and "simulated" in win.status.robot_label.text()
        qtbot.waitUntil(lambda: lab.robot.latest_state is not None, timeout=WAIT_MS)

        # The board streams from the lab's process.
        blocks: list = []
        board = lab.board
        board.block.connect(blocks.append)
        if not board.is_running:
            with qtbot.waitSignal(board.connected, timeout=WAIT_MS):
                board.start()
        qtbot.waitUntil(lambda: sum(len(b.seq) for b in blocks) >= 10, timeout=WAIT_MS)
        assert blocks[0].counts.shape[1] == FLAT.board.n_channels

        # Teach: the simulated hand bends a limp joint in the lab's process; the capture reads it through the wire.
        teach = win.show_tab("teach")
        qtbot.mouseClick(teach.panel.torque_off_all_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: all(teach.limp), timeout=WAIT_MS)
        teach.pose_joint(2, 0.5)
        qtbot.waitUntil(lambda: lab.robot.latest_state is not None
                        and abs(lab.robot.latest_state.position_rad[2] - 0.5) < 0.01, timeout=WAIT_MS)
        qtbot.mouseClick(teach.panel.capture_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: len(teach.keyframes) == 1, timeout=WAIT_MS)
        assert teach.keyframes[0].angles_rad[2] == pytest.approx(0.5, abs=0.01)

        # The 3-D tab draws the lab's world (a copy posed from the lab's joint positions).
        scene = win.show_tab("scene")
        qtbot.waitUntil(lambda: scene.view.frames_shown >= 2 or bool(scene.render_error), timeout=WAIT_MS)
        if not scene.render_error:
            assert scene.view.showing_picture
            qtbot.waitUntil(lambda: sim.physics is not None and sim.physics.shown_time_s is not None, timeout=WAIT_MS)
    finally:
        win.close()
    assert sim.alive  # the lab is the process's (as the in-process one): closed at exit, not with a window
    sim.close()
    assert not sim.alive


def test_a_simulated_lab_process_that_dies_is_said_first_in_every_later_device_error(qtbot, tmp_path, no_lab_yet):
    import os
    import signal

    lab = LabContext(FLAT, lab_process=True)
    sim = factory.installed_sim_lab()
    assert isinstance(sim, LabProcess)
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.show()
    try:
        with qtbot.waitSignal(lab.robot.connected, timeout=WAIT_MS):
            lab.robot.connect_robot()
        with qtbot.waitSignal(lab.sim_lab_died, timeout=WAIT_MS):
            os.kill(sim.pid, signal.SIGKILL)
        gone = lab.sim_lab_gone
        assert gone.startswith("simulated lab stopped: restart the app")  # what to do, before the bar elides it
        assert "simulated lab's process" in gone and "killed by SIGKILL" in gone
        assert win.status.message.startswith(gone)
        # The robot's loop loses its pty too. Whichever reaches the window first, the cause stays in front.
        qtbot.waitUntil(lambda: lab.robot.is_link_lost or not lab.robot.is_connected, timeout=WAIT_MS)
        assert win.status.message.startswith(gone)  # the robot's error is shown by the handler that set that state
        if sim.physics is not None:  # the 3-D view's copy no longer draws the last pose as if it were live
            with pytest.raises(RuntimeError, match="restart the app"):
                sim.physics.render_rgb(64, 48)
        win.show_error("robot: link lost")  # any later device error
        assert win.status.message == f"{gone}. Then: robot: link lost"
    finally:
        win.close()


def test_a_calibration_run_on_the_rig_of_a_lab_in_its_own_process_follows_the_command(qtbot, tmp_path, no_lab_yet):
    """The rig's servo and the board on their ptys, the protocol on the lab's clock read across processes (the same
    start, 10× real time here): the held force is the commanded one."""
    from app.core import calfiles
    from app.core.rig_protocol import COMPLETED, ProtocolSettings
    from app.gui.rig_session import RigSession
    from tests.app.test_rig_session import BENCH_CONFIG, FORCE_TOLERANCE_N, _hold_rows

    sim = LabProcess(BENCH_CONFIG, seed=7, speed=10.0).start()
    factory.install_sim_lab(sim)  # no_lab_yet closes it after the test
    lab = LabContext(BENCH_CONFIG)
    session = RigSession(lab, board_stale_s=10.0)
    try:
        settings = ProtocolSettings(forces_n=(3.0,), sensor="BENCH", trials_per_force=1, hold_s=40.0, baseline_s=15.0,
                                    ramp_s=10.0, rest_s=5.0, sample_rate_hz=6.0)
        with qtbot.waitSignal(session.finished, timeout=120_000) as blocker:
            session.start(settings, tmp_path)
        outcome = blocker.args[0]
        assert outcome.status == COMPLETED, outcome.message
        (record,) = outcome.trials
        trial = calfiles.read_trial_csv(record.path)
        hold = _hold_rows(trial.force_n)
        assert hold.sum() >= 10
        assert float(np.median(trial.force_n[hold])) == pytest.approx(3.0, abs=FORCE_TOLERANCE_N)
    finally:
        session.shutdown()
        lab.close()
