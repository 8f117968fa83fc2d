"""The Teach tab on the physics lab: with torque off the limp robot settles over the obstacle under gravity, and the
tab captures that pose as it would on the real robot (the paper's "push the robot down to conform", Sec. III-C)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PySide6.QtCore import Qt

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from app.core.shapes import ShapeLibrary  # noqa: E402
from app.gui.lab import LabContext  # noqa: E402
from app.gui.tabs.teach import TeachTab  # noqa: E402
from devices.config import LabConfig, SimLabConfig  # noqa: E402

PHYSICS = dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))
WAIT_MS = 20000


def test_the_teach_tab_captures_the_limp_robot_settled_over_the_obstacle(qtbot, tmp_path, install_fast_sim_lab):
    sim = install_fast_sim_lab(PHYSICS, speed=3.0)
    sim.start_background()  # the app's lab: the world steps with the clock between driver reads
    scene = sim.physics.world.scene
    wrap = -2 * scene.segment_length_m / (scene.obstacle_height_m + scene.segment_radius_m)
    lab = LabContext(PHYSICS)
    try:
        with qtbot.waitSignal(lab.robot.connected, timeout=WAIT_MS) as blocker:
            lab.robot.connect_robot()
        assert blocker.args == [True]
        tab = TeachTab(lab, ShapeLibrary(tmp_path / "shapes"))
        qtbot.addWidget(tab)
        tab.resize(1280, 760)
        tab.show()
        qtbot.mouseClick(tab.panel.torque_off_all_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: all(tab.limp), timeout=WAIT_MS)

        def settled() -> bool:
            state = lab.robot.latest_state
            if state is None:
                return False
            pitch = np.asarray(state.position_rad)[[2, 4, 6, 8]]
            return bool(np.all(np.abs(pitch - wrap) < 0.1)) and bool(np.all(np.abs(state.velocity_rad_s) < 0.05))

        qtbot.waitUntil(settled, timeout=WAIT_MS)  # gravity drapes it; nobody posed a joint
        # … and comes to rest (the world stops stepping): a body still creeping at the 0.05 rad/s allowed above moves
        # more than the encoder's resolution between the capture and the comparison below on a loaded machine
        qtbot.waitUntil(lambda: sim.physics.world.resting, timeout=WAIT_MS)
        qtbot.mouseClick(tab.panel.capture_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: len(tab.keyframes) == 1, timeout=WAIT_MS)
        captured = np.asarray(tab.keyframes[0].angles_rad)
        assert captured[[2, 4, 6, 8]] == pytest.approx(np.full(4, wrap), abs=0.1)  # conformed to the obstacle
        assert np.abs(captured[1::2]).max() < 0.05  # yaw joints stay straight
        # What the tab captured is what the simulated body is doing (through the wire, to the encoder's resolution).
        assert captured == pytest.approx(sim.physics.joint_state().position_rad, abs=0.01)
    finally:
        lab.close()
        sim.close()


def test_the_gait_tab_plays_the_captured_shape_and_the_simulated_robot_advances(qtbot, tmp_path,
                                                                                install_fast_sim_lab):
    """Sec. III-C in the app: the settled shape, played follow-the-leader from the Gait tab, moves the body forward
    over the obstacle; the tab does not know it talks to a simulation."""
    from app.core.shapes import Shape
    from app.gui.robot_bridge import MOTION_FINISHED, MOTION_RUNNING
    from app.gui.tabs.gait import GaitTab

    sim = install_fast_sim_lab(PHYSICS, speed=3.0)
    sim.start_background()
    library = ShapeLibrary(tmp_path / "shapes")
    lab = LabContext(PHYSICS)
    try:
        with qtbot.waitSignal(lab.robot.connected, timeout=WAIT_MS):
            lab.robot.connect_robot()
        world = sim.physics.world
        qtbot.waitUntil(lambda: world.time_s > 6.0, timeout=WAIT_MS)  # limp at power-up: it drapes over the top
        shape = lab.robot.latest_state.position_rad
        library.save(Shape("conform", PHYSICS.robot.axes, tuple(float(a) for a in shape)))
        start_x = float(world.body_state().points_m[:, 0].mean())
        tab = GaitTab(lab, library)
        qtbot.addWidget(tab)
        tab.show()
        panel = tab.panel
        panel.set_mode("follow")
        panel.speed_spin.setValue(0.3)
        panel.shifts_spin.setValue(3)
        qtbot.waitUntil(panel.play_button.isEnabled, timeout=WAIT_MS)
        with qtbot.waitSignal(lab.robot.motion_changed, timeout=WAIT_MS, check_params_cb=lambda s: s == MOTION_RUNNING):
            qtbot.mouseClick(panel.play_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_FINISHED, timeout=60000)
        # The last goals are sent; let the body get there (a loaded machine can leave the world behind the clock).
        done_s = world.time_s
        qtbot.waitUntil(lambda: world.time_s > done_s + 1.0
                        and float(np.abs(world.joint_state().velocity_rad_s).max()) < 0.05, timeout=WAIT_MS)
        advance = float(world.body_state().points_m[:, 0].mean()) - start_x
        assert advance > 0.02  # forward (+x), over the obstacle (about 5 cm here)
        assert "finished" in panel.status_label.text()  # no overload on the way
    finally:
        lab.close()
        sim.close()


def test_a_joint_bent_in_the_teach_tab_stays_bent_until_torque_off_lets_it_go(qtbot, tmp_path, install_fast_sim_lab):
    """The simulated hand holds what it bent against gravity (as a person holds the robot in shape), so the tab
    captures the pose it was given; "Torque off" again lets go and gravity brings the joint down."""
    flat = dataclasses.replace(PHYSICS, lab=SimLabConfig(physics="mujoco", obstacle_height_ratio=0.0))
    sim = install_fast_sim_lab(flat, speed=3.0)
    sim.start_background()
    world = sim.physics.world
    lab = LabContext(flat)
    try:
        with qtbot.waitSignal(lab.robot.connected, timeout=WAIT_MS):
            lab.robot.connect_robot()
        tab = TeachTab(lab, ShapeLibrary(tmp_path / "shapes"))
        qtbot.addWidget(tab)
        tab.resize(1280, 760)
        tab.show()
        qtbot.mouseClick(tab.panel.torque_off_all_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: all(tab.limp), timeout=WAIT_MS)
        tab.pose_joint(2, 0.5)  # joint 3 (pitch) bent up: lifts the body behind it off the ground
        posed_s = world.time_s
        qtbot.waitUntil(lambda: world.time_s > posed_s + 2.0, timeout=WAIT_MS)
        assert world.joint_state().position_rad[2] == pytest.approx(0.5, abs=0.005)  # still where the hand put it
        qtbot.mouseClick(tab.panel.capture_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: len(tab.keyframes) == 1, timeout=WAIT_MS)
        assert tab.keyframes[0].angles_rad[2] == pytest.approx(0.5, abs=0.01)  # through the wire
        qtbot.mouseClick(tab.panel.torque_off_all_button, Qt.MouseButton.LeftButton)  # let go
        qtbot.waitUntil(lambda: not world.held.any(), timeout=WAIT_MS)
        qtbot.waitUntil(lambda: lab.robot.latest_state is not None
                        and lab.robot.latest_state.position_rad[2] < 0.3, timeout=WAIT_MS)  # gravity takes over
    finally:
        lab.close()
        sim.close()
