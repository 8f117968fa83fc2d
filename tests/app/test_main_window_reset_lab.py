"""Lab ▸ Reset lab puts the simulated robot back at its scene's start; File ▸ Open config with another simulated lab
(another [lab] scene) restarts the simulated lab on it and says so."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest
from PySide6.QtCore import QSettings

from app.gui.lab import LabContext
from app.gui.main_window import MainWindow
from app.gui.robot_bridge import MOTION_STOPPED
from devices import factory
from devices.config import LabConfig, SimLabConfig
from tests.app.windows import open_connected_window
from tests.motion_sources import JointRamp

WAIT_MS = 30_000


def test_reset_lab_stops_the_motion_and_lays_the_robot_back_at_its_scenes_start(qtbot, install_fast_sim_lab,
                                                                                   tmp_path):
    PhysicsWorld = pytest.importorskip("devices.sim.physics.world").PhysicsWorld
    config = dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))
    sim = install_fast_sim_lab(config, speed=2.0)
    world = sim.physics.world
    start_head = world.body_state().points_m[0].copy()  # where the lab puts the robot at start
    win = open_connected_window(qtbot, config, tmp_path, WAIT_MS)
    try:
        robot = win.lab.robot
        robot.set_torque(True).result(timeout=30)
        world.place(head_x_m=float(start_head[0]) + 0.25, angles_rad=np.full(world.n_joints, 0.3))  # elsewhere, bent
        robot.run_motion(JointRamp(index=2), "ramp")
        win.reset_lab_action.trigger()
        qtbot.waitUntil(lambda: "lab reset" in win.status.message, timeout=WAIT_MS)
        assert robot.motion_state == MOTION_STOPPED  # stopped before anything was moved
        with world._lock:  # (re-entrant) the pose and the simulated time since the reset, read together
            since_reset_s = float(world.data.time)
            head = world.body_state().points_m[0]
            angles = world.joint_state().position_rad
        assert abs(head[0] - (start_head[0] + 0.25)) > 0.15, (head, start_head)  # not where it was put
        yaw = [j for j, axis in enumerate(config.robot.axes) if axis == "yaw"]
        assert np.max(np.abs(angles[yaw])) < 0.01  # laid straight (the 0.3 rad bend is gone) …
        # … and limp: the pitch joints sag over the obstacle exactly as a body freshly laid at the scene's start does
        # after the same simulated time (a wall-clock-paced lab may have run on for a while on a loaded machine; at
        # rest the sag reaches ~0.5 rad, so no fixed bound on it can tell "limp" from "still bent")
        reference = PhysicsWorld(world.scene)
        reference.place()
        reference.step(round(since_reset_s / world.scene.timestep_s))
        expected = reference.joint_state().position_rad
        assert np.max(np.abs(angles - expected)) < 0.05, (since_reset_s, angles, expected)
        # where a body freshly laid at the start is after that time (it slides off the obstacle's top when the
        # lab has run on for seconds: 8 cm seen at load 12)
        expected_head = reference.body_state().points_m[0]
        assert np.linalg.norm(head - expected_head) < 0.03, (since_reset_s, head, expected_head, start_head)
        assert all(sim.chain.register(sid, "Torque Enable") == 0 for sid in config.robot.joint_ids)  # limp
    finally:
        win.close()


def test_reset_lab_on_the_scripted_lab_says_why_it_cannot(qtbot, sim_lab_fast, tmp_path):
    win = open_connected_window(qtbot, dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="scripted")),
                                tmp_path, WAIT_MS)
    try:
        win.reset_lab_action.trigger()
        qtbot.waitUntil(lambda: "lab not reset" in win.status.message, timeout=WAIT_MS)
        assert "scripted" in win.status.message
    finally:
        win.close()


@pytest.fixture
def no_lab_yet():
    """No simulated lab made yet, as when the app starts; the one the test makes is closed after it."""
    previous = factory.install_sim_lab(None)
    yield
    made = factory.install_sim_lab(previous)
    if made is not None and hasattr(made, "close"):
        made.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ptys (Linux)")
def test_open_config_with_another_scene_restarts_the_simulated_lab_on_it(qtbot, tmp_path, no_lab_yet):
    first = tmp_path / "flat_lab.toml"
    first.write_text('[lab]\nphysics = "scripted"\nscene = "flat"\n', encoding="utf-8")
    second = tmp_path / "step_lab.toml"
    second.write_text('[lab]\nphysics = "scripted"\nscene = "step"\n', encoding="utf-8")
    from devices.config import load_config

    lab = LabContext(load_config(first), lab_process=True)
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.show()
    try:
        old = factory.installed_sim_lab()
        assert old.config.lab.scene == "flat"
        assert win.open_config(second) is True
        new = factory.installed_sim_lab()
        assert new is not old and not old.alive and new.alive  # the old lab ended, a new one runs
        assert new.config.lab.scene == "step" and new.call("config.lab.scene") == "step"
        assert "simulated lab restarted" in win.status.message and "step" in win.status.message
        assert "step" in win.show_tab("scene").scene_label.text()
        qtbot.waitUntil(lambda: win.lab.robot.is_connected, timeout=WAIT_MS)  # the robot, on the new lab
        assert win.open_config(second) is True  # the same lab again: kept, not restarted
        assert factory.installed_sim_lab() is new
    finally:
        win.close()
