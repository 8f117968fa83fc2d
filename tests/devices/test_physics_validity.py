"""The physics lab checks itself (devices/sim/physics/validity.py): a state that is not physics stops the world.

Each test steps a world directly for a fraction of a simulated second and then breaks it on purpose — a NaN
injected, a kick of energy from nowhere, the body teleported into the ground or far away — as a solver blowing up
would; and the refusals of what no physics can honour (a tail load beyond friction, a plate thinner than the contact
model resolves).
"""

from __future__ import annotations

import logging

import mujoco
import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from devices.config import LabConfig  # noqa: E402
from devices.errors import SceneError  # noqa: E402
from devices.scene import load_scene, parse_scene  # noqa: E402
from devices.sim.physics.backend import PhysicsBackend  # noqa: E402
from devices.sim.physics.headless import ManualClock  # noqa: E402
from devices.sim.physics.model import SceneParams  # noqa: E402
from devices.sim.physics.world import PhysicsWorld  # noqa: E402

FLAT = SceneParams(obstacle_height_m=0.0)


def _held(seconds: float = 0.2) -> PhysicsWorld:
    world = PhysicsWorld(FLAT)
    world.command(np.ones(world.n_joints, dtype=bool), np.zeros(world.n_joints))
    world.step(int(seconds / FLAT.timestep_s))
    assert world.invalid is None  # lying held straight on flat ground is physics
    return world


def test_a_nan_stops_the_world_at_its_last_good_state_names_the_dof_and_writes_no_mujoco_log(tmp_path, monkeypatch,
                                                                                            caplog):
    monkeypatch.chdir(tmp_path)
    world = _held()
    assert world.model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_AUTORESET  # no silent reset
    before = world.body_state().points_m
    at_s = world.time_s
    world.data.qvel[29] = np.nan  # what a solver blowing up leaves in a velocity
    with caplog.at_level(logging.WARNING, logger="devices.sim.physics"):
        world.step(10)
    assert world.invalid is not None
    assert world.invalid.what.startswith("MuJoCo: bad QVEL") and "at DOF 29 (joint " in world.invalid.what
    assert world.invalid.time_s == pytest.approx(at_s)  # the first bad step, not the end of the batch
    assert world.invalid.describe(clock_zero_s=at_s - 1.0).endswith("at t=1.00 s")
    assert np.all(np.isfinite(world.body_state().points_m))  # readers see the last good state, not NaN …
    assert np.allclose(world.body_state().points_m, before, atol=1e-3)
    world.advance_to(world.time_s + 1.0)  # … and it steps no more: the clock moves on, the body frozen
    assert np.allclose(world.body_state().points_m, before, atol=1e-3)
    assert any("Nan, Inf or huge value in QVEL at DOF 29" in r.getMessage() for r in caplog.records)
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()  # MuJoCo's log went to logging, not to the working folder
    world.place()  # a new start is physics again
    world.step(10)
    assert world.invalid is None


def test_energy_from_nowhere_ends_the_world(caplog):
    world = _held()
    world.data.qvel[0] += 3.0  # the whole body kicked forward at 3 m/s: +11 J that no servo gave
    world.step(5)
    assert world.invalid is not None and world.invalid.what.startswith("energy from nowhere: +")


def test_a_body_point_faster_than_anything_can_move_it_ends_the_world():
    world = _held()
    world.data.qpos[0] += 2.0  # 2 m in one 2 ms step: 1000 m/s
    world.step(1)
    assert world.invalid is not None and "faster than the physics allows" in world.invalid.what


def test_a_contact_deeper_than_the_contact_model_resolves_ends_the_world():
    world = _held()
    world.data.qpos[2] -= 0.03  # the body's axis 3 cm down: its shells 3 cm into the ground
    world.step(1)
    assert world.invalid is not None and "deeper than the contact model resolves" in world.invalid.what


def test_the_apps_lab_reports_an_invalid_world_and_puts_the_robot_back_at_its_start(caplog):
    clock = ManualClock()
    backend = PhysicsBackend(LabConfig(), clock, scene=FLAT)  # type: ignore[arg-type]
    world = backend.world
    backend._restart_invalid = True  # as start() sets it, without the stepping thread
    clock.set(0.2)
    backend.advance_to(0.2)
    world.data.qvel[29] = np.nan
    clock.set(0.3)
    with caplog.at_level(logging.ERROR, logger="devices.sim.physics.backend"):
        backend.advance_to(0.3)
    assert [s.what for s in backend.invalid_states][0].startswith("MuJoCo: bad QVEL")
    assert any("stopped being physics" in r.getMessage() and "put back at the scene's start" in r.getMessage()
               for r in caplog.records)
    assert world.invalid is None and world.time_s == pytest.approx(0.3, abs=0.01)  # its clock runs on
    clock.set(0.5)
    backend.advance_to(0.5)
    assert world.invalid is None and np.all(np.isfinite(world.body_state().points_m))
    backend.close()


def test_a_tail_load_beyond_friction_is_refused_with_the_formula():
    scene = load_scene("paper_obstacle")
    assert scene.holdable_load_n() == pytest.approx(2.4 * 9.81 * 0.3)  # the ground's μ 0.3 > the PTFE's 0.1
    scene.refuse_unholdable_load(7.0, "--tail-load")  # within it: nothing said
    with pytest.raises(SceneError) as refused:
        scene.refuse_unholdable_load(30.0, "--tail-load")
    assert str(refused.value) == (
        "--tail-load 30 N is more than friction can hold on scene paper_obstacle: 2.4 kg × 9.81 m/s² × μ 0.3 (the "
        "largest friction coefficient of the scene, the ground's) = 7.06 N; beyond it the robot is dragged backward "
        "whatever it does")
    grippy = parse_scene("[ground]\nfriction = 0.2\n[[obstacle]]\nshape = 'box'\nx_m = 1\nlength_m = 0.3\n"
                         "height_m = 0.05\nfriction = 0.5\n", name="grippy")
    with pytest.raises(SceneError, match=r"μ 0.5 \(the largest friction coefficient of the scene, obstacle #1's\)"):
        grippy.refuse_unholdable_load(12.0, "'tail_loads_n'")
