"""The MuJoCo model of SenSnake v2 (devices/sim/physics): weight on the sensors, lifting, stalling, draping.

Each test steps a world directly (no clock, no wire), a few simulated seconds at 2 ms.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from devices.sim.physics.model import SceneParams  # noqa: E402
from devices.sim.physics.world import HAND_SPEED_RAD_S, PhysicsWorld  # noqa: E402

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


def test_a_joint_held_against_a_load_it_cannot_move_draws_torque_up_to_the_stall_limit():
    world = _held_straight(seconds=0.5)
    world.command(np.ones(world.n_joints, dtype=bool), np.zeros(world.n_joints), np.full(world.n_joints, 0.5))
    world.set_external_torque(11, -6.0)  # a push on the tail's yaw joint stronger than the servo's 4.1 N·m stall
    torques, saturated = [], []
    for _ in range(60):
        world.step(25)
        torques.append(world.joint_state().torque_nm[11])
        saturated.append(world.joint_state().saturated_s[11])
    stall = world.scene.servo.stall_torque_nm
    assert max(abs(t) for t in torques[-10:]) > 0.9 * stall  # the servo gives all it has …
    assert world.joint_state().position_rad[11] < -0.2  # … and is pushed back all the same
    assert max(saturated) > 0.2  # the demand stays above the stall torque (what trips the overload)


def test_a_segment_pushed_against_a_wall_loads_the_sheet_on_that_side():
    scene = SceneParams(obstacle_height_m=0.0, wall_offset_m=0.040)
    world = _held_straight(scene, seconds=0.5)
    goal = np.zeros(world.n_joints)
    goal[11] = 1.0  # joint 12 (yaw): swing the tail segment right, into the wall
    world.command(np.ones(world.n_joints, dtype=bool), goal, np.full(world.n_joints, 0.5))
    world.step(1500)
    _, left, right = world.segment_loads_n()
    assert right[11] > 1.0  # the right sheet of the tail segment feels the wall …
    assert left[11] < 0.1  # … its left sheet does not
    assert world.joint_state().position_rad[11] < 0.99  # the wall (and the body wedged against it) stops it short


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


def _limp_on_flat_ground() -> PhysicsWorld:
    world = PhysicsWorld(FLAT)
    world.command(np.zeros(world.n_joints, dtype=bool), np.zeros(world.n_joints))
    world.step(250)
    return world


def test_a_joint_posed_by_hand_stays_while_held_and_falls_back_when_let_go():
    world = _limp_on_flat_ground()
    world.set_joint_angle(2, 0.5)  # joint 3 (pitch) bent up: lifts the segments behind it off the ground
    world.step(1000)  # 2 s
    assert world.joint_state().position_rad[2] == pytest.approx(0.5, abs=0.005)
    assert world.held[2] and world.held.sum() == 1
    world.release_hand()
    world.step(500)  # 1 s: the passive joint (damping, friction loss) does not hold it up
    assert world.joint_state().position_rad[2] < 0.3
    assert not world.held.any()


def test_a_hand_bending_a_front_joint_lifts_the_head_end_and_never_pushes_the_body_through_the_floor():
    """Bending a joint near the head of a robot lying on the ground moves its lighter end: the long part behind the
    joint stays where it lies. A pose that would swing a segment into the floor lifts the body instead, so the world
    stays physical (it was ended invalid: a contact 0.2 m deep)."""
    world = _limp_on_flat_ground()
    before = world.body_state().points_m.copy()
    world.set_joint_angle(2, 0.6)  # joint 3 bent up: the head end rises, the tail stays
    world.step(250)
    after = world.body_state().points_m
    assert np.linalg.norm(after[-1] - before[-1]) < 0.005
    assert after[0, 2] > before[0, 2] + 0.05
    world.set_joint_angle(0, -0.5)  # joint 1 bent down: the head would dig into the floor
    world.step(500)
    assert world.invalid is None, world.invalid
    assert world.body_state().points_m[:, 2].min() > -0.002
    assert world.joint_state().position_rad[[0, 2]] == pytest.approx([-0.5, 0.6], abs=0.005)


def _demo_poses(n: int) -> list[np.ndarray]:
    """An S-curve, the head lifted, a C-curve of the yaw joints (tools/screenshot.py's poses of the Teach tab)."""
    j = np.arange(n)
    return [0.35 * np.sin(2 * np.pi * j / n),
            np.where(np.isin(j, (0, 2)), -0.45, np.where(j == 4, 0.2, 0.0)) + np.where(j % 2 == 1, 0.25, 0.0),
            np.where(j % 2 == 1, 0.28, 0.0)]


def test_poses_set_by_hand_while_the_body_still_falls_are_reached_and_the_world_stays_valid():
    """A user posing the limp robot quickly in the Teach tab: the three poses 0.6 s apart while the body still
    drapes over the obstacle. The hand bends the joints at a hand's speed; it used to put each pose in at once and
    lift the body out of the terrain with its fall kept, and the body slammed into the ground (a contact 23 mm deep:
    invalid, the app's lab reset the robot to the scene's start)."""
    world = PhysicsWorld(SceneParams())
    dt = world.scene.timestep_s
    world.step(int(2.0 / dt))  # limp: the drape under way
    for pose in _demo_poses(world.n_joints):
        for joint, angle in enumerate(pose):
            world.set_joint_angle(joint, float(angle))
        reached_s = None
        for k in range(30):  # 0.6 s in the app's 20 ms ticks
            world.step(10)
            assert world.invalid is None, world.invalid
            if reached_s is None and np.abs(world.joint_state().position_rad - pose).max() < 0.01:
                reached_s = (k + 1) * 10 * dt
        assert reached_s is not None and reached_s < 0.4  # within a fraction of a second
    world.step(int(1.0 / dt))
    assert world.invalid is None, world.invalid
    assert world.joint_state().position_rad == pytest.approx(_demo_poses(world.n_joints)[-1], abs=0.005)
    assert world.validity.peak_depth_m < world.validity.deepest_m  # (the checks' limits as they are)


def test_a_hand_on_its_way_moves_the_same_however_the_steps_are_batched():
    """The hand moves between physics steps, so the world's state after 0.3 s is the same stepped one by one or in
    one call (its validity checks still run after each call)."""
    worlds = [PhysicsWorld(SceneParams()) for _ in range(2)]
    for world in worlds:
        world.step(500)
        for joint, angle in enumerate(_demo_poses(world.n_joints)[0]):
            world.set_joint_angle(joint, float(angle))
    for _ in range(150):
        worlds[0].step(1)
    worlds[1].step(150)
    assert np.array_equal(worlds[0].data.qpos, worlds[1].data.qpos)
    assert np.array_equal(worlds[0].data.qvel, worlds[1].data.qvel)


def test_a_pitch_joint_bent_by_hand_moves_no_faster_than_a_hand():
    world = _limp_on_flat_ground()
    start = world.joint_state().position_rad[2]
    world.set_joint_angle(2, start + 1.0)
    world.step(50)  # 0.1 s
    moved = world.joint_state().position_rad[2] - start
    assert 0.25 < moved < HAND_SPEED_RAD_S * 0.1 + 0.01
    world.step(200)
    assert world.joint_state().position_rad[2] == pytest.approx(start + 1.0, abs=0.005)


def test_a_joint_with_torque_on_cannot_be_posed_by_hand():
    world = _held_straight(seconds=0.2)
    with pytest.raises(ValueError, match="torque on"):
        world.set_joint_angle(3, 0.4)
    assert not world.held.any()


def test_torque_on_takes_the_posed_joint_over_from_the_hand():
    world = _limp_on_flat_ground()
    world.set_joint_angle(4, 0.5)
    world.step(250)
    on = np.zeros(world.n_joints, dtype=bool)
    on[4] = True
    world.command(on, world.joint_state().position_rad)  # the firmware: goal = present on torque-on
    assert not world.held[4]
    world.step(1000)
    assert world.joint_state().position_rad[4] == pytest.approx(0.5, abs=0.03)  # the servo holds it now


def test_the_limp_robot_still_drapes_over_the_obstacle_after_the_hand_let_go():
    scene = SceneParams()
    world = PhysicsWorld(scene)
    world.set_joint_angle(2, 0.0)
    world.step(500)
    assert world.joint_state().position_rad[2] == pytest.approx(0.0, abs=0.005)  # held straight over the edge
    world.release_hand()
    world.step(int(6.0 / scene.timestep_s))
    wrap = -2 * scene.segment_length_m / (scene.obstacle_height_m + scene.segment_radius_m)
    assert world.joint_state().position_rad[2] == pytest.approx(wrap, abs=0.1)


def _run_to(world: PhysicsWorld, t_s: float) -> None:
    """Advance the world's clock to ``t_s`` in 0.1 s calls (one call further than MAX_CATCH_UP_S ahead skips)."""
    while world.time_s < t_s - 1e-9:
        world.advance_to(min(t_s, world.time_s + 0.1))


def test_a_still_world_rests_and_wakes_on_a_command():
    world = PhysicsWorld(SceneParams())
    world.rest_enabled = True
    n = world.n_joints
    world.command(np.zeros(n, dtype=bool), np.zeros(n))
    _run_to(world, 15.0)  # drapes over the obstacle, then lies still
    assert world.resting
    state, loads, steps = world.joint_state(), world.segment_loads_n(), world.steps
    _run_to(world, 25.0)
    assert world.steps == steps and world.rested_s > 9.9  # 10 s more on the clock, none of it stepped
    assert world.time_s == pytest.approx(25.0, abs=0.01)
    assert np.array_equal(world.joint_state().position_rad, state.position_rad)
    assert world.joint_state() is world.joint_state()  # one state while resting: readers can skip copying it
    assert np.array_equal(world.segment_loads_n(), loads)
    assert loads[0].sum() > 0.5 * world.weight_n
    goal = world.joint_state().position_rad.copy()
    goal[10] += 0.3
    resting_state = world.joint_state()
    world.command(np.ones(n, dtype=bool), goal, np.full(n, 1.0))
    assert not world.resting
    assert world.joint_state() is not resting_state
    _run_to(world, 27.0)
    assert world.steps > steps
    assert world.joint_state().position_rad[10] == pytest.approx(goal[10], abs=0.05)


def test_a_world_does_not_rest_while_a_servo_still_has_work_or_strains():
    world = PhysicsWorld(FLAT)
    world.rest_enabled = True
    n = world.n_joints
    world.command(np.ones(n, dtype=bool), np.zeros(n), np.full(n, 0.5))
    world.set_external_torque(11, -6.0)  # stalls, strains, and must go on straining until the overload trips
    rested, saturated = [], []
    while world.time_s < 6.0:
        world.advance_to(world.time_s + 0.05)
        rested.append(world.resting)
        saturated.append(world.joint_state().saturated_s[11])
    assert not any(rested)
    assert max(saturated) > 0.2  # what trips the overload goes on accumulating
