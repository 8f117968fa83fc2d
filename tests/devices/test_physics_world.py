"""The MuJoCo model of SenSnake v2 (devices/sim/physics): weight on the sensors, lifting, stalling, draping.

Each test steps a world directly (no clock, no wire), a few simulated seconds at 2 ms.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from devices.sim.physics.model import SceneParams  # noqa: E402
from devices.sim.physics.world import PhysicsWorld  # noqa: E402

FLAT = SceneParams(obstacle_height_m=0.0)


def _held_straight(scene: SceneParams = FLAT, seconds: float = 1.5) -> PhysicsWorld:
    world = PhysicsWorld(scene)
    world.command(np.ones(world.n_joints, dtype=bool), np.zeros(world.n_joints))
    world.step(int(seconds / scene.timestep_s))
    return world


def test_at_rest_on_flat_ground_the_bottom_sensors_carry_the_weight():
    world = _held_straight()
    bottom, left, right = world.segment_loads_n()
    assert bottom.sum() == pytest.approx(world.weight_n, rel=0.05)
    assert np.all(bottom > 0.5 * world.weight_n / world.n_joints)  # every segment rests on the ground
    assert left.sum() + right.sum() < 0.01 * world.weight_n
    assert world.steps == 750 and world.stepping_s > 0.0  # the benchmark's headroom counts this time


def test_lifting_the_tail_unloads_its_sensors_and_the_rest_take_the_weight():
    world = _held_straight()
    before = world.segment_loads_n()[0]
    goal = np.zeros(world.n_joints)
    goal[10] = 0.6  # joint 11 (pitch): a positive angle lifts segments 11 and 12
    world.command(np.ones(world.n_joints, dtype=bool), goal)
    world.step(1000)
    after = world.segment_loads_n()[0]
    assert before[11] > 1.0
    assert after[11] < 0.02
    assert world.joint_state().position_rad[10] == pytest.approx(0.6, abs=0.05)
    assert after.sum() == pytest.approx(world.weight_n, rel=0.05)


def test_a_joint_pushed_against_a_wall_draws_torque_up_to_the_stall_limit():
    scene = SceneParams(obstacle_height_m=0.0, wall_offset_m=0.045)
    world = _held_straight(scene, seconds=0.5)
    goal = np.zeros(world.n_joints)
    goal[11] = 1.0  # joint 12 (yaw): swing the tail segment right, into the wall
    world.command(np.ones(world.n_joints, dtype=bool), goal, np.full(world.n_joints, 0.5))
    torques, saturated = [], []
    for _ in range(60):
        world.step(25)
        torques.append(world.joint_state().torque_nm[11])
        saturated.append(world.joint_state().saturated_s[11])
    state = world.joint_state()
    stall = scene.servo.stall_torque_nm
    assert abs(torques[0]) < 0.5 * stall  # free at first …
    assert max(abs(t) for t in torques[-10:]) > 0.9 * stall  # … then stalled against the wall
    assert state.position_rad[11] < 0.9  # the wall stops it short of the goal
    assert max(saturated) > 0.2  # the demand stays above the stall torque (what trips the overload)
    _, _, right = world.segment_loads_n()
    assert right[11] > 1.0  # the right sheet of the tail segment feels the wall


def test_the_limp_robot_drapes_over_the_obstacle_and_conforms_to_it():
    scene = SceneParams()  # the paper's obstacle, 0.28 × body length
    world = PhysicsWorld(scene)
    world.step(int(6.0 / scene.timestep_s))
    state = world.joint_state()
    assert np.all(np.abs(state.velocity_rad_s) < 0.05)  # settled
    pitch = state.position_rad[[2, 4, 6, 8]]
    # Two segments per pitch joint wrapped on a circle of radius obstacle + body radius.
    wrap = -2 * scene.segment_length_m / (scene.obstacle_height_m + scene.segment_radius_m)
    assert pitch == pytest.approx(np.full(4, wrap), abs=0.1)
    bottom = world.segment_loads_n()[0]
    assert bottom[4:7].min() > 1.0  # the middle lies on the top of the obstacle
    points = world.body_state().points_m
    assert points[:, 2].min() < 0.05 and points[:, 2].max() > scene.obstacle_height_m  # from the ground over the top
