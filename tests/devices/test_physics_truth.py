"""The physics lab's contact forces against cases with a known answer.

A straight body on flat ground carries its weight segment by segment; the contact forces' vertical part equals the
weight when nothing accelerates, on any terrain; a shape played follow-the-leader moves load smoothly from sheet to
sheet (a real shell deflects: no sheet jumps by newtons between two 30 Hz frames). Each test steps a world directly.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")

from devices.scene import load_scene  # noqa: E402
from devices.sim.physics.model import GRAVITY_M_S2, SceneParams  # noqa: E402
from devices.sim.physics.world import PhysicsWorld, sheet_weights  # noqa: E402
from models.trajectory import plan_follow_the_leader  # noqa: E402

FLAT = SceneParams(obstacle_height_m=0.0)
FRAME_S = 1.0 / 30.0  # the board's frame period


def test_a_straight_robot_on_flat_ground_carries_each_segments_weight_on_its_bottom_sheet():
    world = PhysicsWorld(FLAT)
    world.command(np.ones(12, dtype=bool), np.zeros(12))
    world.step(1500)
    bottom, left, right = world.segment_loads_n()
    share = np.full(12, FLAT.segment_mass_kg * GRAVITY_M_S2)
    share[0] += FLAT.head_mass_kg * GRAVITY_M_S2  # segment 1 also carries the nose in front of it
    assert bottom == pytest.approx(share, rel=0.05)
    assert left.sum() + right.sum() < 0.01
    assert world.vertical_contact_force_n() == pytest.approx(world.weight_n, rel=1e-3)


def _play(scene: SceneParams, shape: np.ndarray, speed_rad_s: float, seconds: float) -> tuple[np.ndarray, float]:
    """Sheet loads (frames × 3 × 12) every board frame while ``shape`` plays follow-the-leader from straight."""
    world = PhysicsWorld(scene)
    world.command(np.ones(12, dtype=bool), np.zeros(12))
    world.step(500)
    plan = plan_follow_the_leader(world.joint_state().position_rad, shape, scene.axes, speed_rad_s)
    frames, t, next_frame = [], 0.0, 0.0
    while t < min(seconds, plan.total_s):
        world.command(np.ones(12, dtype=bool), plan.goal_at(t), np.full(12, 1.0))
        world.step(10)
        t += 0.02
        if t >= next_frame:
            next_frame += FRAME_S
            frames.append(world.segment_loads_n())
    return np.array(frames), world.weight_n


@pytest.mark.parametrize("speed_rad_s", [0.034, 0.3])
def test_a_bent_shape_played_on_flat_ground_moves_its_load_smoothly_and_the_sheets_carry_the_weight(speed_rad_s):
    shape = np.zeros(12)
    shape[[1, 2, 3, 4, 5]] = [0.45, 0.2, -0.55, -0.2, 0.45]  # yaw and pitch bends (not a shape anything was tuned on)
    loads, weight = _play(FLAT, shape, speed_rad_s, seconds=8.0)
    bottom_sum = loads[:, 0].sum(axis=1)
    assert np.mean(np.abs(bottom_sum - weight) < 0.1 * weight) >= 0.95
    jumps = np.abs(np.diff(loads, axis=0)).reshape(len(loads) - 1, -1).max(axis=1)
    assert np.mean(jumps > 1.0) < 0.01


def _one_step_losses(world: PhysicsWorld, shape: np.ndarray, speed_rad_s: float, seconds: float) -> int:
    """Play ``shape`` follow-the-leader from straight and count the times a segment's terrain contact carrying
    > 0.5 N vanishes for a single 2 ms step and comes back."""
    import mujoco
    buf = np.zeros(6)

    def normals() -> np.ndarray:
        n = np.zeros(world.n_joints)
        segment_of = world._segment_of_geom
        for i in range(world.data.ncon):
            contact = world.data.contact[i]
            first, second = segment_of[contact.geom1], segment_of[contact.geom2]
            if max(first, second) >= 0 > min(first, second):
                mujoco.mj_contactForce(world.model, world.data, i, buf)
                n[max(first, second)] += buf[0]
        return n

    world.command(np.ones(12, dtype=bool), np.zeros(12))
    world.step(500)
    plan = plan_follow_the_leader(world.joint_state().position_rad, shape, world.scene.axes, speed_rad_s)
    history, t = [], 0.0
    while t < seconds:
        world.command(np.ones(12, dtype=bool), plan.goal_at(t), np.full(12, 1.0))
        for _ in range(10):
            world.step(1)
            history.append(normals())
        t += 0.02
    h = np.array(history)
    return int(((h[:-2] > 0.5) & (h[1:-1] == 0.0) & (h[2:] > 0.5)).sum())


def test_a_contact_whose_force_grows_from_zero_lets_go_gradually_where_mujocos_default_hops():
    """A yaw-and-pitch shape played on flat ground drags and lifts loaded shells. MuJoCo's default contact impedance
    (0.9 at zero penetration) holds such a contact near full strength until the geometry separates and then drops it
    for one step, over and over (the shell rebounds: the chatter of a dragged end, docs/PHYSICS_LAB.md). An impedance
    growing from zero (a scene's ``[ground] contact_onset_m``, as a compliant cover's force grows with its
    deflection) lets go gradually: not one loss. The lab's default is still MuJoCo's."""
    from devices.scene import Scene
    shape = np.zeros(12)
    shape[[1, 3, 5]] = [0.35, -0.35, 0.35]
    shape[[2, 4]] = -0.3
    assert _one_step_losses(PhysicsWorld(FLAT), shape, 0.3, seconds=4.0) > 20
    soft = SceneParams(terrain_scene=Scene(contact_onset_m=0.0003))
    assert _one_step_losses(PhysicsWorld(soft), shape, 0.3, seconds=4.0) == 0


def test_the_sheet_share_of_a_contact_is_continuous_around_the_segment():
    angles = np.linspace(-180.0, 180.0, 7201)
    weights = np.array([sheet_weights(a) for a in angles])
    assert np.abs(np.diff(weights, axis=0)).max() < 0.01  # 0.05° apart: no step anywhere
    assert weights.sum(axis=1).max() == pytest.approx(1.0)
    assert np.all(weights.sum(axis=1) <= 1.0 + 1e-12)
    assert tuple(sheet_weights(0.0)) == (1.0, 0.0, 0.0)
    assert tuple(sheet_weights(90.0)) == (0.0, 1.0, 0.0) and tuple(sheet_weights(-90.0)) == (0.0, 0.0, 1.0)
    assert sheet_weights(180.0).sum() == 0.0  # the rigid top has no sheet


@pytest.mark.parametrize("name", ["paper_obstacle", "step", "wedge", "two_obstacles"])
def test_on_every_built_in_scene_the_settled_robot_is_held_up_by_its_weight(name):
    world = PhysicsWorld(SceneParams(terrain_scene=load_scene(name)))
    world.step(2500)  # 5 s limp
    assert world.vertical_contact_force_n() == pytest.approx(world.weight_n, rel=0.02)
    bottom = world.segment_loads_n()[0]
    # the sheets feel most of it (a rounded end resting on an edge passes an axial part that no sheet feels; normals
    # on a slope or a curve add up to more than the weight)
    assert 0.9 * world.weight_n <= bottom.sum() <= 1.3 * world.weight_n
    points = world.body_state().points_m
    assert points[:, 2].min() > -0.005  # nothing sank into the ground


def test_on_the_paper_obstacle_the_normal_forces_exceed_the_weight_by_the_curve_alone():
    world = PhysicsWorld(SceneParams())
    world.step(3000)
    bottom = world.segment_loads_n()[0]
    frames = world.body_state().frames
    vertical = float(np.sum(bottom * frames[:, 2, 2]))  # each bottom sheet pushes along its segment's up axis
    # the sheets feel pressure, not shear: the PTFE's friction (μ 0.1) holds up the few per cent they miss
    assert 0.9 * world.weight_n < vertical < world.weight_n
    assert world.vertical_contact_force_n() == pytest.approx(world.weight_n, rel=1e-3)
    assert bottom.sum() > 1.1 * world.weight_n


def test_a_limp_chain_wrapping_a_frictionless_half_cylinder_presses_it_with_four_over_pi_of_its_weight():
    """A known answer for why the sheets' readings add up to more than the weight on a curve. A flexible chain of
    weight w per length wrapped over a frictionless half cylinder (centre-line radius R) has tension T = wR·cos θ
    (tangential balance, T = 0 at the feet) and so presses N = w·cos θ + T/R = 2w·cos θ per length: in all 4wR, 4/π
    of its weight πRw. The paper's obstacle is that case: 0.96 m of body is half the circumference at its centre line
    (R = 0.2688 + 0.036 m). The limp robot, 12 rigid links, settles to within 5 % of it; with no friction the
    sheets' readings' vertical part is the weight (less what its rounded ends pass axially)."""
    from devices.scene import Obstacle, Scene
    cylinder = Obstacle("half_cylinder", 0.0, 0.0, radius_m=0.2688)
    world = PhysicsWorld(SceneParams(terrain_scene=Scene(ground_friction=0.0, obstacles=(cylinder,), head_x_m=0.48)))
    world.step(3000)  # 6 s limp
    readings = world.segment_loads_n()
    assert readings[1:].sum() < 0.01 * world.weight_n  # it lies on its bottom sheets
    assert readings.sum() == pytest.approx(4.0 / np.pi * world.weight_n, rel=0.05)
    vertical = float(np.sum(readings[0] * world.body_state().frames[:, 2, 2]))
    assert vertical == pytest.approx(world.weight_n, rel=0.03)
    assert world.contact_support_n()[1] == pytest.approx(world.weight_n, rel=1e-3)


def _momentum_z(world: PhysicsWorld) -> float:
    """The robot's vertical momentum (kg·m/s) in the state the next step starts from (its kinematics computed)."""
    import mujoco
    mujoco.mj_step1(world.model, world.data)
    mujoco.mj_subtreeVel(world.model, world.data)
    return float(world.data.subtree_linvel[0, 2] * world.model.body_subtreemass[0])


@pytest.mark.parametrize("name", ["flat", "two_obstacles"])
def test_the_contact_forces_obey_newton_step_by_step_while_the_body_falls_and_lands(name):
    """Where the contact forces' upward part is not the weight, the body is accelerating: Σ F_z − W = dp_z/dt at
    every 2 ms step, through a drop onto flat ground and a limp settle over the low cylinder and the step (its
    landings push 4–10× the weight). The residual is the step's first-order discretisation of a rotating body's
    momentum (it halves with the step: 0.21 → 0.10 → 0.05 N at 2, 1, 0.5 ms on two obstacles; 4·10⁻⁵ N for the
    straight drop)."""
    import mujoco
    world = PhysicsWorld(SceneParams(terrain_scene=load_scene(name)))
    if name == "flat":
        world.place(height_m=0.08)  # dropped from 4.4 cm
    dt = world.scene.timestep_s
    worst_residual = worst_off = 0.0
    momentum = _momentum_z(world)
    for _ in range(1000):
        mujoco.mj_step2(world.model, world.data)
        support = world.contact_support_n()[1]  # the forces of the step just taken
        following = _momentum_z(world)
        worst_residual = max(worst_residual, abs(support - world.weight_n - (following - momentum) / dt))
        worst_off = max(worst_off, abs(support - world.weight_n))
        momentum = following
    assert worst_off > 2.0 * world.weight_n  # landings: the check is not the resting case
    assert worst_residual < 0.015 * world.weight_n


@pytest.mark.parametrize("terrain", [
    # terrains no built-in scene has: a lower, rougher half cylinder, and a steep wedge whose slope friction must hold
    '[ground]\nfriction = 0.35\n[[obstacle]]\nshape = "half_cylinder"\nx_m = 0.0\nradius_m = 0.22\nfriction = 0.15\n'
    '[robot]\nhead_x_m = 0.38\nstart = "settle"\n',
    '[ground]\nfriction = 0.4\n[[obstacle]]\nshape = "wedge"\nx_m = 0.0\nlength_m = 0.5\nheight_m = 0.16\n'
    'friction = 0.35\n[robot]\nhead_x_m = 0.3\nstart = "settle"\n',
])
def test_the_whole_contact_forces_carry_the_weight_where_the_sheets_readings_cannot(tmp_path, terrain):
    path = tmp_path / "terrain.toml"
    path.write_text(terrain, encoding="utf-8")
    world = PhysicsWorld(SceneParams(terrain_scene=load_scene(str(path))))
    world.step(3000)  # 6 s limp: settled
    sheets, total = world.contact_support_n()
    assert total == pytest.approx(world.weight_n, rel=0.01)  # Newton, nothing accelerating
    assert total == pytest.approx(world.vertical_contact_force_n(), abs=1e-9)
    assert sheets.sum() <= total + 1e-9 and sheets.sum() > 0.8 * total  # what lands on no sheet: ends, top
    readings = world.segment_loads_n()
    frames = world.body_state().frames
    # a sheet reads pressure only: its readings' vertical part misses what friction holds up on the slopes
    assert float(np.sum(readings[0] * frames[:, 2, 2])) < sheets[0].sum()


def _held_then_nudged(world: PhysicsWorld, shape: np.ndarray, seconds: float) -> tuple[float, float]:
    """Hold ``shape`` with the servos, then turn yaw joint 2 by 0.05 rad (a nudge sideways) and hold that for
    ``seconds``; (bottom sheets' load, side sheets' load) at the end, N."""
    on = np.ones(world.n_joints, dtype=bool)
    world.command(on, shape)
    world.step(500)
    bottom, left, right = world.segment_loads_n()
    assert bottom.sum() > 0.9 * world.weight_n and left.sum() + right.sum() < 0.05 * world.weight_n  # upright
    nudged = shape.copy()
    nudged[1] += 0.05
    world.command(on, nudged)
    world.step(int(seconds / world.scene.timestep_s))
    bottom, left, right = world.segment_loads_n()
    return float(bottom.sum()), float(left.sum() + right.sum())


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["arch", "sag"])
def test_a_body_bent_in_pitch_on_a_floor_rolls_onto_its_side_at_a_nudge_as_statics_says(sign):
    """Round segments on a floor that does not resist their roll (``roll_resistance_m = 0``): a
    body bent in pitch, held rigid, has its centre of mass above the line it rolls about (an arch's
    middle, a sag's ends), so it is in an unstable equilibrium — the smallest sideways nudge lays it on its side;
    held straight it is neutral and stays."""
    from devices.scene import Scene
    free = SceneParams(obstacle_height_m=0.0, terrain_scene=Scene(ground_roll_m=0.0))
    angles = sign * np.array([0, 0, 0.4, 0, -0.4, 0, 0, 0, -0.4, 0, 0.4, 0])
    world = PhysicsWorld(free)
    world.place(angles_rad=angles)
    bottom, side = _held_then_nudged(world, angles, seconds=2.0)
    assert side > 0.9 * world.weight_n and bottom < 0.05 * world.weight_n  # lying on its side sheets
    straight = PhysicsWorld(free)
    bottom, side = _held_then_nudged(straight, np.zeros(straight.n_joints), seconds=2.0)
    assert bottom > 0.95 * straight.weight_n and side < 0.01 * straight.weight_n


def test_a_drape_over_the_obstacle_is_held_upright_by_the_obstacle_against_the_same_nudge():
    """Draped over the half cylinder, the part of the body above the line through its two floor contacts would have
    to move down into the obstacle to roll: the obstacle holds it upright (what the drape does in the experiments)."""
    world = PhysicsWorld(SceneParams())
    world.step(2000)  # 4 s limp: settled over the paper's obstacle
    bottom, side = _held_then_nudged(world, world.joint_state().position_rad.copy(), seconds=2.0)
    assert bottom > 0.9 * world.weight_n and side < 0.05 * world.weight_n


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["arch", "sag"])
def test_the_default_ground_resists_the_roll_holds_the_bent_body_upright_and_only_about_the_segments_axis(sign):
    """The default ``roll_resistance_m`` (the shell's flattened contact patch, as a lever arm): the bent bodies of
    the test above stay on their bottom sheets at the same nudge. MuJoCo resists the roll about a capsule-plane
    contact's first tangent, and that tangent runs along the capsule (its direction on the ground): the segment's
    own axis, not the axis it would roll along the path about (a body pushed along the floor meets no added
    resistance)."""
    angles = sign * np.array([0, 0, 0.4, 0, -0.4, 0, 0, 0, -0.4, 0, 0.4, 0])
    world = PhysicsWorld(FLAT)
    world.place(angles_rad=angles)
    bottom, side = _held_then_nudged(world, angles, seconds=2.0)
    assert bottom > 0.95 * world.weight_n and side < 0.01 * world.weight_n
    data, model = world.data, world.model
    assert data.ncon >= 2  # the arch stands on a few shells
    for contact in data.contact[:data.ncon]:
        shell = contact.geom2 if model.geom_bodyid[contact.geom2] else contact.geom1
        axis = data.geom_xmat[shell].reshape(3, 3)[:, 2]  # a capsule's axis is its local z
        normal, tangent1, tangent2 = contact.frame.reshape(3, 3)
        along = axis - (axis @ normal) * normal  # the axis's direction on the ground
        along /= np.linalg.norm(along)
        assert contact.dim == 6 and abs(tangent1 @ along) > 0.999 and abs(tangent2 @ along) < 1e-3
        assert contact.friction[3] == pytest.approx(0.0085) and contact.friction[4] <= 1e-5  # that roll only
    assert world.vertical_contact_force_n() == pytest.approx(world.weight_n, rel=1e-3)


def _obstacle(shape: str, roll_m: float):
    """A wide, gentle obstacle of each shape with room on top for the whole body (0.96 m)."""
    from devices.scene import Obstacle
    if shape == "half_cylinder":
        return Obstacle(shape, 0.0, 0.3, radius_m=3.0, roll_resistance_m=roll_m)
    return Obstacle(shape, 0.0, 0.3, length_m=2.0, height_m=0.05 if shape == "box" else 0.1, roll_resistance_m=roll_m)


@pytest.mark.parametrize("shape", ["half_cylinder", "box", "wedge"])
def test_an_obstacle_resists_the_roll_as_the_ground_does_and_only_about_the_heading(shape):
    """On top of an obstacle the arch of the tests above rolls onto its side at the nudge when the obstacle lets it
    roll freely (``roll_resistance_m = 0`` on the obstacle), and stays on its bottom sheets with the default (the
    shell's patch, as on the ground). MuJoCo's frame for a contact on an obstacle across the path has its first
    tangent along y (the obstacle's width), so the resisted roll is about the second, the heading across it (a
    segment lying along the path rolling about its own axis), never about y (a segment rolling along the path)."""
    from devices.scene import GROUND_ROLL_M, Scene
    angles = np.array([0, 0, 0.4, 0, -0.4, 0, 0, 0, -0.4, 0, 0.4, 0])
    results = {}
    for roll_m in (0.0, GROUND_ROLL_M):
        world = PhysicsWorld(SceneParams(terrain_scene=Scene(obstacles=(_obstacle(shape, roll_m),), head_x_m=0.48)))
        world.place(angles_rad=angles)
        results[roll_m] = _held_then_nudged(world, angles, seconds=2.0)
    bottom, side = results[0.0]
    assert side > 0.9 * world.weight_n and bottom < 0.05 * world.weight_n  # free: lying on its side sheets
    bottom, side = results[GROUND_ROLL_M]
    assert bottom > 0.95 * world.weight_n and side < 0.01 * world.weight_n  # resisted: upright
    data, model = world.data, world.model
    on_obstacle = [c for c in data.contact[:data.ncon] if "obstacle" in (model.geom(c.geom1).name + model.geom(c.geom2).name)]
    assert len(on_obstacle) >= 2  # the arch stands on the obstacle, not on the floor
    for contact in on_obstacle:
        normal, tangent1, tangent2 = contact.frame.reshape(3, 3)
        assert contact.dim == 6 and abs(tangent1[1]) > 0.999 and abs(tangent2[1]) < 1e-3
        assert contact.friction[3] <= 1e-5 and contact.friction[4] == pytest.approx(GROUND_ROLL_M)
    assert world.vertical_contact_force_n() == pytest.approx(world.weight_n, rel=1e-3)
