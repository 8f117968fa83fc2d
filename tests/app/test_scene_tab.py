"""The "3-D lab" tab: offscreen MuJoCo pictures of the physics lab, the 2-D drawing for the scripted lab."""

from __future__ import annotations

import dataclasses
import gc
import sys
from typing import Any

import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from app.gui.lab import LabContext  # noqa: E402
from app.gui.tabs.scene import SceneTab  # noqa: E402
from devices.config import LabConfig, SimLabConfig  # noqa: E402

PHYSICS = dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))


@pytest.fixture
def tab_on(qtbot, install_fast_sim_lab):
    made = []

    def make(config):
        lab_sim = install_fast_sim_lab(config, speed=1.0)
        lab = LabContext(config)
        tab = SceneTab(lab)
        qtbot.addWidget(tab)
        tab.resize(640, 480)
        made.append((tab, lab, lab_sim))
        return tab, lab_sim

    yield make
    for tab, lab, lab_sim in made:
        tab.shutdown()
        lab.close()
        lab_sim.close()


def test_the_physics_lab_is_drawn_in_3d_and_the_picture_follows_the_world(qtbot, tab_on, monkeypatch):
    unraisable = []  # Renderer.__del__ closing an OpenGL context from a thread it is not current in: EGL_BAD_ACCESS
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    tab, lab_sim = tab_on(PHYSICS)
    tab.show()
    qtbot.waitUntil(lambda: tab.view.frames_shown >= 2 or bool(tab.render_error), timeout=20000)
    if tab.render_error:
        pytest.skip(f"no offscreen OpenGL on this machine: {tab.render_error}")
    assert tab.view.showing_picture
    image = tab.view.picture.pixmap().toImage()
    assert image.width() > 100 and image.height() > 100
    # Not a blank frame: the rendered scene has structure (ground, obstacle, robot).
    frame = lab_sim.physics.render_rgb(160, 120)
    assert frame.shape == (120, 160, 3) and frame.std() > 10
    before = frame.copy()
    lab_sim.physics.world.place(head_x_m=-1.0)  # move the robot away from the obstacle: the picture changes
    after = lab_sim.physics.render_rgb(160, 120)
    assert np.abs(after.astype(int) - before.astype(int)).mean() > 1.0
    tab.hide()
    assert not tab.rendering  # hidden: the render thread waits instead of drawing
    # Each thread's renderer is closed by that thread: the tab's by its render thread, the test's at lab close.
    tab.shutdown()
    lab_sim.close()
    gc.collect()
    assert [str(u.exc_value) for u in unraisable] == []


def test_the_scripted_lab_falls_back_to_the_2d_body_drawing(qtbot, tab_on):
    tab, _ = tab_on(dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="scripted")))
    tab.show()
    assert not tab.view.showing_picture
    assert "scripted" in tab.view.reason.text()


def test_without_mujoco_the_default_lab_is_scripted_and_the_tab_says_why(qtbot, tab_on, monkeypatch):
    for name in [m for m in sys.modules if m == "mujoco" or m.startswith(("mujoco.", "devices.sim.physics."))]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "mujoco", None)  # "import mujoco" raises ImportError: a machine without it
    tab, lab_sim = tab_on(LabConfig())  # the default: [lab] physics = "mujoco"
    assert lab_sim.physics is None
    assert "mujoco cannot be loaded" in lab_sim.physics_note and "pip install mujoco" in lab_sim.physics_note
    tab.show()
    assert not tab.view.showing_picture
    assert "pip install mujoco" in tab.view.reason.text()


def test_without_opengl_the_physics_lab_is_drawn_in_2d_with_the_reason(qtbot, tab_on, monkeypatch):
    from devices.sim.physics import render

    def no_gl(*_args, **_kwargs):
        raise render.RenderUnavailable("no OpenGL rendering for the 3-D view (EGLError: no display)")

    monkeypatch.setattr(render, "SceneRenderer", no_gl)  # a machine without EGL/OSMesa
    tab, lab_sim = tab_on(PHYSICS)
    lab_sim.start_background()
    tab.lab.robot.connect_robot()
    tab.show()
    qtbot.waitUntil(lambda: bool(tab.render_error), timeout=20000)
    assert not tab.view.showing_picture
    assert "no OpenGL" in tab.view.reason.text() and "2-D" in tab.view.reason.text()
    # The 2-D drawing follows the simulated robot's joints (the limp robot drapes over the obstacle).
    qtbot.waitUntil(lambda: tab.lab.robot.latest_state is not None, timeout=20000)
    qtbot.waitUntil(lambda: abs(tab.view.body.present_rad[2]) > 0.2, timeout=20000)


def test_the_app_with_no_config_runs_on_the_physics_lab(qtbot):
    """``sensnake gui`` / scripts/run.sh with no config: the packaged config's simulated lab is the physics lab,
    stepping in its own thread and allowed to rest (the scripted fallback without mujoco is tested above)."""
    from devices import factory
    from devices.config import load_config

    previous = factory.install_sim_lab(None)  # as in a fresh process: no simulated lab yet
    try:
        lab = LabContext(load_config())
        sim = factory.sim_lab()
        try:
            assert sim.physics is not None and sim.physics_note == ""
            assert sim.physics.world.rest_enabled
        finally:
            lab.close()
            sim.close()
    finally:
        factory.install_sim_lab(previous)


def test_the_scene_line_names_the_scene_file_and_its_obstacles_or_why_it_cannot_be_read(tmp_path):
    from dataclasses import replace

    from app.gui.tabs.scene import scene_description
    from devices.config import LabConfig

    config = LabConfig()
    assert "paper's obstacle" in scene_description(config) and "half cylinder" in scene_description(config)
    stepped = replace(config, lab=replace(config.lab, scene="step"))
    assert scene_description(stepped).startswith("Scene: step") and "box at x +0.15 m" in scene_description(stepped)
    bad = tmp_path / "bad.toml"
    bad.write_text("[ground]\nfrction = 0.3\n", encoding="utf-8")
    broken = replace(config, lab=replace(config.lab, scene=str(bad)))
    assert "unknown key 'frction'" in scene_description(broken)
    own = tmp_path / "own.toml"  # an obstacle whose roll resistance is not the ground's says so; the default does not
    own.write_text("[[obstacle]]\nshape = 'box'\nx_m = 0\nlength_m = 0.3\nheight_m = 0.1\nroll_resistance_m = 0\n"
                   "[[obstacle]]\nshape = 'box'\nx_m = 1\nlength_m = 0.3\nheight_m = 0.1\n", encoding="utf-8")
    line = scene_description(replace(config, lab=replace(config.lab, scene=str(own))))
    assert line.count("rolls freely") == 1 and line.split(";")[0].endswith("roll resistance 8.5 mm")
    assert "contact onset" not in line  # MuJoCo's impedance: not said
    soft = tmp_path / "soft.toml"
    soft.write_text("[ground]\ncontact_onset_m = 0.0003\n", encoding="utf-8")
    line = scene_description(replace(config, lab=replace(config.lab, scene=str(soft))))
    assert "contact onset 0.3 mm" in line


def test_the_tab_builds_its_hidden_views_only_when_first_needed(qtbot: Any) -> None:
    """A first opening gets the live picture and nothing hidden: no kinematics panel until a motion-capture source is
    picked, no replay timeline until a recording is opened (reading either builds it then), no 2-D drawing while the
    3-D picture is coming."""
    from app.gui.tabs import scene
    from widgets.body_view import BodyView
    from widgets.kinematics_view import KinematicsView
    from widgets.replay_view import ReplayView

    lab = LabContext(LabConfig())
    try:
        tab = scene.SceneTab(lab)
        qtbot.addWidget(tab)
        assert tab.pages.count() == 1 and tab.live_page.count() == 1  # the picture only
        assert tab.findChildren(KinematicsView) == [] and tab.findChildren(ReplayView) == []
        if tab.view.reason.text().startswith("Starting the 3-D picture"):  # the physics lab: its picture is coming
            assert tab.findChildren(BodyView) == [] and not tab.view.showing_picture
        else:  # no physics lab: the 2-D drawing is the page
            assert tab.view.has_body
        tab.resize(1000, 600)
        tab.show()
        qtbot.waitExposed(tab)
        tab._on_mocap_source("sim")  # a source picked: the panel is built and shown, the picture keeps 3/5 of the width
        assert tab.live_page.count() == 2 and tab.kinematics.isVisibleTo(tab)
        picture_px, panel_px = tab.live_page.sizes()
        assert picture_px > panel_px > 0
        tab._on_mocap_source("")
        assert not tab.kinematics.isVisibleTo(tab)
        assert tab.replay_view is tab.replay_view and tab.pages.count() == 2  # asked for: built at once, once
        assert len(tab.findChildren(ReplayView)) == 1
        tab.shutdown()
    finally:
        lab.close()
