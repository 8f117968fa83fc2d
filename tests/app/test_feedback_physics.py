"""Force feedback in the physics lab: where a taught shape does not fit the terrain, feedback keeps the body in
contact with the obstacle's far face (the face that propels it) and advances farther than feedforward."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

pytest.importorskip("mujoco")

from app.core.experiment import run_experiment  # noqa: E402
from app.core.shapes import Shape  # noqa: E402

LOW_CYLINDER = str(Path(__file__).resolve().parents[2] / "benchmarks" / "scenes" / "low_cylinder.toml")  # r 0.20 m


def _far_face_contact(path) -> tuple[float, float]:
    """(fraction of ticks with ≥ 2 segments pressing on the obstacle's far face, the centroid's advance in m)."""
    with h5py.File(path) as f:
        bottom = f["sim/sheet_true_N"][:, 2::3]
        points = f["sim/points_m"][:]
    mid_x = 0.5 * (points[:, 1:, 0] + points[:, :-1, 0])
    mid_z = 0.5 * (points[:, 1:, 2] + points[:, :-1, 2])
    on_far_face = (mid_x > 0.02) & (mid_z > 0.05)
    pressing = (on_far_face & (bottom > 0.3)).sum(axis=1)
    return float(np.mean(pressing >= 2)), float(points[-1, :, 0].mean() - points[0, :, 0].mean())


def test_feedback_regains_the_far_face_contact_a_mismatched_shape_loses(tmp_path):
    # The drape of a 0.31 m cylinder (wrap angle −2L/(R + r) per pitch joint) played over a 0.20 m one: its bends are
    # too open, so the front of the body lifts off the far face as it propagates.
    angles = [0.0] * 12
    for joint in (2, 4, 6, 8):
        angles[joint] = -2 * 0.08 / (0.31 + 0.036)
    shape = Shape("tall-wrap", tuple("pitch" if i % 2 == 0 else "yaw" for i in range(12)), tuple(angles))
    results = {}
    for controller in ("feedforward", "feedback"):
        out = tmp_path / f"{controller}.h5"
        run_experiment(out, scene=LOW_CYLINDER, shape=shape, speed_rad_s=0.1, seconds=30.0, controller=controller,
                       rest_cap_s=0.0)  # the play only: its recording is what the fractions are of
        results[controller] = _far_face_contact(out)
    (ff_contact, ff_advance), (fb_contact, fb_advance) = results["feedforward"], results["feedback"]
    assert fb_contact >= ff_contact + 0.05
    assert fb_advance > ff_advance
    with h5py.File(tmp_path / "feedback.h5") as f:
        correction = f["control/correction_rad"][:]
        assert f["control"].attrs["controller"] == "feedback"
    assert np.abs(correction).max() > 0.02  # it did correct
    with h5py.File(tmp_path / "feedforward.h5") as f:
        assert "control" not in f


def test_the_default_lead_turns_the_draped_front_up_and_forward_in_the_physics():
    """On the robot (here the physics lab), a positive lead pitch at joint 3 on the paper obstacle's drape turns the
    two light front segments up and forward (head higher and farther out over the far face), a negative one down:
    what docs/FORCE_FEEDBACK.md says the lead does, measured on the body rather than read off the sign convention."""
    from devices.scene import load_scene
    from devices.sim.physics.model import SceneParams
    from devices.sim.physics.world import PhysicsWorld

    moved = {}
    for bend in (0.3, -0.3):
        world = PhysicsWorld(SceneParams(terrain_scene=load_scene("paper_obstacle")))
        world.command(np.zeros(12, bool), np.zeros(12))
        world.step(int(4.0 / 0.002))  # limp: it drapes
        drape = world.joint_state().position_rad.copy()
        world.command(np.ones(12, bool), drape)
        world.step(250)
        before = world.body_state().points_m[0].copy()
        goal = drape.copy()
        goal[2] += bend
        world.command(np.ones(12, bool), goal)
        world.step(int(3.0 / 0.002))
        moved[bend] = world.body_state().points_m[0] - before
    assert moved[0.3][2] > 0.01 and moved[0.3][0] > 0.01  # up (cm) and forward
    assert moved[-0.3][0] < 0.0  # the other way it bends back down toward the obstacle
