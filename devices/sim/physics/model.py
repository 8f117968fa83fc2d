"""The MJCF scene of SenSnake v2 on the ground, with the paper's half-cylindrical obstacle (Sec. III-C).

Robot (paper, Sec. III): 12 segments, 0.96 m, 2.4 kg, 0.036 m radius. Bodies follow ``models.kinematics``: the
head cap is the floating base, the body trails backward along its −x, joint i sits at the front of segment i and
turns segment i and everything behind it (pitch about local y, yaw about local z; positive pitch lifts what is
behind, positive yaw swings it right). The head cap is a short collision nose without sensors; it is lighter and
thinner than a segment, so on flat ground it does not touch and every newton of weight goes through a sensor.

Servos (XM430-W350 at 12 V, ROBOTIS e-manual): stall torque 4.1 N·m at 2.3 A (1.78 N·m/A), no-load speed 46 rev/min
(4.82 rad/s), gear ratio 353.5. The joint's passive terms (damping 1.08 N·m·s/rad, reflected rotor inertia
0.045 kg·m², friction loss 0.03 N·m) and the position gain (21 N·m/rad) are the published MuJoCo models of this
servo, not measured on our robot: a starting point. The position loop itself runs in :mod:`.world`.

Obstacle: a cylinder of radius ``height`` lying across the path with its axis on the ground, so what shows above
the ground is the paper's half cylinder; PTFE-covered (low friction, configurable). Ground friction is configurable.

Pure string building; any thread.
"""

from __future__ import annotations

from dataclasses import dataclass

from devices.scene import GROUND_ROLL_M, Obstacle, Scene, half_cylinder_scene

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class ServoParams:
    """A position-controlled XM430-W350 at 12 V (see the module docstring for where each number comes from)."""

    stall_torque_nm: float = 4.1
    no_load_speed_rad_s: float = 46.0 * 2.0 * 3.141592653589793 / 60.0
    torque_constant_nm_per_a: float = 4.1 / 2.3
    position_gain_nm_per_rad: float = 21.0
    damping_nm_s_per_rad: float = 1.08
    armature_kg_m2: float = 0.045
    friction_loss_nm: float = 0.03


@dataclass(frozen=True)
class ShellParams:
    """The compliant hollow TPU shell over each segment's three sheets (paper, Sec. III-A, Fig. 5D-E), modelled as a
    light body on two slide joints (sideways y, up-down z in the segment's frame) sprung against the servo's housing,
    free to travel ``travel_m`` before it bottoms out on the housing.
    Every contact force on the segment passes through these springs: that is what spreads a load over the robot's
    length (a rigid body on rigid contacts rests on any 3 of its 24 contact points and rocks between them) and what
    the sheet under the shell feels. Assumed values, not measured (docs/PHYSICS_LAB.md): ~1 mm of shell deflection
    under one segment's share of the weight (2 N), near-critical damping of a segment bouncing on it, and the TPU
    shell with its sheets, rubber covers and holders as 60 g of the segment's 196 g (an XM430 alone is 82 g)."""

    stiffness_n_per_m: float = 2000.0
    damping_n_s_per_m: float = 30.0
    mass_kg: float = 0.06
    travel_m: float = 0.003  # then the shell bottoms out on the housing (a joint limit): a stall force is borne


@dataclass(frozen=True)
class SceneParams:
    """Robot and terrain. ``obstacle_height_m`` 0 means flat ground only. Lengths in m, masses in kg."""

    n_segments: int = 12
    axes: tuple[str, ...] = tuple("pitch" if i % 2 == 0 else "yaw" for i in range(12))
    segment_length_m: float = 0.08
    segment_radius_m: float = 0.036
    robot_mass_kg: float = 2.4
    head_mass_kg: float = 0.01  # the collision nose: the real robot has none, so it weighs as little as MuJoCo allows well
    obstacle_height_m: float = 0.28 * 0.96
    obstacle_width_m: float = 4.0  # "spans the whole width": far wider than any path the robot takes
    obstacle_friction: float = 0.1  # PTFE sheet on the obstacle
    ground_friction: float = 0.3
    timestep_s: float = 0.002
    # Optional walls either side of the robot (y = ±wall_offset_m, a corridor), for pushing a joint against them.
    wall_offset_m: float | None = None
    servo: ServoParams = ServoParams()
    shell: ShellParams = ShellParams()
    # MuJoCo's solref of every terrain contact: a time constant (s) and a damping ratio ([lab.physics]
    # contact_time_constant_s, contact_damping_ratio): near rigid and critically damped, the compliance being the shell's
    contact_solref: tuple[float, float] = (0.01, 1.0)
    # the terrain's roll resistance lever (m) where a scene names none ([lab.physics] roll_resistance_m); the legacy
    # half cylinder takes it
    roll_resistance_m: float = GROUND_ROLL_M
    # A scene file's terrain (devices.sim.physics.scene); None: the one half cylinder of obstacle_height_m at x = 0
    # with obstacle_friction, on ground_friction (the lab config's legacy keys, the paper's obstacle by default).
    terrain_scene: Scene | None = None

    @property
    def terrain(self) -> Scene:
        """The terrain in force: the scene file's, or the legacy half cylinder."""
        if self.terrain_scene is not None:
            return self.terrain_scene
        return half_cylinder_scene(self.obstacle_height_m, self.obstacle_friction, self.ground_friction,
                                   roll_m=self.roll_resistance_m)

    @property
    def body_length_m(self) -> float:
        return self.n_segments * self.segment_length_m

    @property
    def segment_mass_kg(self) -> float:
        return (self.robot_mass_kg - self.head_mass_kg) / self.n_segments


HEAD_RADIUS_M = 0.028  # thinner than a segment: the nose does not touch flat ground when the body is straight
HEAD_LENGTH_M = 0.03
SEGMENT_GAP_M = 0.002  # between neighbouring cylinders, so their end faces never overlap when straight
HAND_SOLREF_S = 0.01  # the hand's grip: a stiff constraint (10 ms time constant), stiffer than the soft contacts


def segment_name(index: int) -> str:
    """Body and geom name of segment ``index`` (0 = head segment)."""
    return f"seg{index + 1:02d}"


def joint_name(index: int) -> str:
    return f"j{index + 1:02d}"


def hand_name(index: int) -> str:
    """The equality constraint with which the teach hand holds joint ``index`` at an angle."""
    return f"hand{index + 1:02d}"


def shell_joint_names(index: int) -> tuple[str, str]:
    """The two slide joints (sideways y, up-down z) of segment ``index``'s compliant shell."""
    return f"{segment_name(index)}_sy", f"{segment_name(index)}_sz"


def _obstacle_geom(index: int, obstacle: Obstacle, width_m: float) -> tuple[str, str]:
    """(geom XML, asset XML) of one obstacle. Friction: the obstacle's own (the robot's geoms carry 0, and MuJoCo
    takes the larger of a pair's two coefficients, so the pair's coefficient is the terrain's)."""
    name = f"obstacle{index + 1}"
    # An obstacle resisting the roll collides through explicit pairs only (build_mjcf), as the ground does.
    affinity = "0" if obstacle.roll_resistance_m > 0 else "1"
    common = (f'friction="{obstacle.friction} 0.005 0.0001" contype="0" conaffinity="{affinity}" '
              f'rgba="0.8 0.84 0.92 0.8"')
    if obstacle.shape == "half_cylinder":
        # A capsule of the radius lying across the path with its axis on the ground: what shows above the ground
        # is the half cylinder (capsule-capsule collisions are analytic in MuJoCo).
        return (f'<geom name="{name}" type="capsule" size="{obstacle.radius_m:.6f} {width_m / 2:.6f}" '
                f'pos="{obstacle.x_m:.6f} 0 0" euler="90 0 0" {common}/>'), ""
    if obstacle.shape == "box":
        return (f'<geom name="{name}" type="box" size="{obstacle.length_m / 2:.6f} {width_m / 2:.6f} '
                f'{obstacle.height_m / 2:.6f}" pos="{obstacle.x_m:.6f} 0 {obstacle.height_m / 2:.6f}" {common}/>'), ""
    # wedge: a triangular prism (a convex mesh), 0 high at its back edge, height_m at its front edge, then a
    # vertical face down to the ground.
    lo, hi = obstacle.x_range_m
    h, w = obstacle.height_m, width_m / 2
    vertices = [(lo, -w, 0.0), (hi, -w, 0.0), (hi, -w, h), (lo, w, 0.0), (hi, w, 0.0), (hi, w, h)]
    text = " ".join(f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices)
    return f'<geom name="{name}" type="mesh" mesh="{name}_mesh" {common}/>', f'<mesh name="{name}_mesh" vertex="{text}"/>'


def soft_onset_solimp(onset_m: float) -> str:
    """A contact impedance that grows from zero (MuJoCo solimp d0 dmax width): 0 where a shell just touches, 0.95 at
    ``onset_m`` of penetration, so a contact's force grows from zero as a shell's cover presses in and falls to zero
    as it lifts off, as a compliant cover's does (a scene's ``[ground] contact_onset_m``). MuJoCo's default (0.9 at
    zero penetration) holds a contact near full strength until the geometry separates, then drops it in one step: a
    loaded shell lifting slowly (an end dragged or pushed along the floor) loses its contact for one 2 ms step every
    20-35 ms (220 times in 30 s of the two obstacles' drape at 0.3 rad/s; 0 with 0.3 mm). Not the default: it moves
    the force-feedback traversal yardstick (docs/PHYSICS_LAB.md, "A dragged end stick-slips")."""
    return f"0 0.95 {onset_m!r}"


def build_mjcf(scene: SceneParams) -> str:
    """The scene as an MJCF XML string."""
    length, radius = scene.segment_length_m, scene.segment_radius_m
    servo, shell = scene.servo, scene.shell
    terrain = scene.terrain
    solref = f"{scene.contact_solref[0]!r} {scene.contact_solref[1]!r}"
    # Capsules: MuJoCo collides capsules with planes and capsules analytically (a cylinder against the big obstacle
    # cylinder goes through the general convex solver, which lets a small body sink deep and then push thousands of
    # newtons). The rounded ends stand for the robot's rounded shells between the joints.
    half = max(length / 2.0 - radius - SEGMENT_GAP_M / 2.0, 0.001)
    # Shells collide with the terrain only (contype 1 / conaffinity 0 vs the terrain's 0 / 1): neighbours share a
    # joint and never touch in the real robot's joint range. Friction 0 here: the pair takes the terrain's.
    robot_geom = 'contype="1" conaffinity="0" condim="3" friction="0 0.005 0.0001"'
    shell_joint = (f'type="slide" stiffness="{shell.stiffness_n_per_m}" damping="{shell.damping_n_s_per_m}" '
                   f'armature="0" frictionloss="0" limited="true" range="{-shell.travel_m} {shell.travel_m}" solreflimit="0.01 1"')
    core_mass = scene.segment_mass_kg - shell.mass_kg
    body = ""
    for i in reversed(range(scene.n_segments)):
        axis = "0 1 0" if scene.axes[i] == "pitch" else "0 0 1"
        pos = "0 0 0" if i == 0 else f"{-length:.6f} 0 0"
        rgba = "0.95 0.75 0.2 1" if i % 2 == 0 else "0.85 0.6 0.15 1"
        sy, sz = shell_joint_names(i)
        body = (
            f'<body name="{segment_name(i)}" pos="{pos}">'
            f'<joint name="{joint_name(i)}" type="hinge" axis="{axis}" range="-3.0 3.0" limited="false"/>'
            # the servo and its housing: the segment's mass, inside the shell (never touches anything)
            f'<geom name="{segment_name(i)}_core" type="capsule" size="{radius * 0.8:.6f} {half:.6f}" '
            f'pos="{-length / 2:.6f} 0 0" euler="0 90 0" mass="{core_mass:.6f}" rgba="0.2 0.2 0.2 1" '
            f'contype="0" conaffinity="0"/>'
            f'<site name="{segment_name(i)}_mid" pos="{-length / 2:.6f} 0 0"/>'
            f'<body name="{segment_name(i)}_shell">'
            f'<joint name="{sy}" axis="0 1 0" {shell_joint}/><joint name="{sz}" axis="0 0 1" {shell_joint}/>'
            f'<geom name="{segment_name(i)}" type="capsule" size="{radius} {half:.6f}" '
            f'pos="{-length / 2:.6f} 0 0" euler="0 90 0" mass="{shell.mass_kg:.6f}" rgba="{rgba}" '
            f'{robot_geom}/>'
            f"</body>"
            f"{body}</body>"
        )
    obstacles, assets = "", ""
    for k, obstacle in enumerate(terrain.obstacles):
        geom, asset = _obstacle_geom(k, obstacle, scene.obstacle_width_m)
        obstacles += geom
        assets += asset
    walls = ""
    if scene.wall_offset_m is not None:
        for side, name in ((-1, "wall_right"), (1, "wall_left")):
            walls += (
                f'<geom name="{name}" type="box" size="{scene.body_length_m:.4f} 0.1 0.1" '
                f'pos="0 {side * (scene.wall_offset_m + 0.1):.6f} 0.1" friction="{terrain.ground_friction} 0.005 '
                f'0.0001" contype="0" conaffinity="1" rgba="0.6 0.6 0.7 0.5"/>'
            )
    actuators = "".join(
        f'<motor name="m{i + 1:02d}" joint="{joint_name(i)}" ctrlrange="{-servo.stall_torque_nm} '
        f'{servo.stall_torque_nm}" ctrllimited="true"/>'
        for i in range(scene.n_segments)
    )
    # The teach "hand" (world.PhysicsWorld.hold): one joint equality per joint, off until a person holds that joint.
    hands = "".join(
        f'<joint name="{hand_name(i)}" joint1="{joint_name(i)}" polycoef="0 0 0 0 0" active="false" '
        f'solref="{HAND_SOLREF_S} 1"/>'
        for i in range(scene.n_segments)
    )
    head_z = radius
    # The ground's roll resistance (Scene.ground_roll_m): explicit shell-ground pairs with rolling friction, the
    # ground then colliding through them only. condim 6 gives a contact two rolling coefficients; MuJoCo's
    # capsule-plane contact frame has its first tangent along the capsule's axis, so "0 a 0" in the roll slots resists
    # only the roll about the segment's own axis (tested: tests/devices/test_physics_truth.py), never rolling along
    # the path, and the obstacles' contacts are as without it.
    roll = terrain.ground_roll_m
    # terrain.contact_onset_m: the ground's, half cylinders' and boxes' contacts grow from zero (soft_onset_solimp);
    # it acts through the explicit pairs, so only where the roll is resisted (the default)
    onset = terrain.contact_onset_m
    solimp = f' solimp="{soft_onset_solimp(onset)}"' if onset is not None else ""
    ground_affinity = "0" if roll > 0 else "1"
    pairs = "".join(
        f'<pair geom1="ground" geom2="{segment_name(i)}" condim="6" solref="{solref}"{solimp} '
        f'friction="{terrain.ground_friction} {terrain.ground_friction} 0 {roll} 0"/>'
        for i in range(scene.n_segments)) if roll > 0 else ""
    # The obstacles' roll resistance (Obstacle.roll_resistance_m): every obstacle spans the width (y) and its surface
    # normal lies in the x-z plane, where MuJoCo's contact frame for a capsule on a capsule, a box or a convex mesh
    # takes its first tangent along y (tested: tests/devices/test_physics_truth.py), so "0 a" resists the roll
    # about the second, the heading across the obstacle — a segment lying along the path rolling about its own axis
    # — and never the roll about y, a segment rolling along the path over the obstacle (resisting every axis made
    # the drape stick-slip, docs/PHYSICS_LAB.md).
    # A half cylinder (a capsule) and a box collide with a shell analytically, their contacts' depths continuous:
    # they take the scene's contact onset as the ground does. A wedge is a convex mesh, whose general collider gives
    # a capsule lying on a face one contact point that jumps from end to end, its depth with it: a force growing from
    # zero would jump with it (S01B ±3 N on the wedge's drape at 0.034 rad/s), so a wedge keeps MuJoCo's impedance.
    pairs += "".join(
        f'<pair geom1="obstacle{k + 1}" geom2="{segment_name(i)}" condim="6" solref="{solref}" '
        + ('' if obstacle.shape == "wedge" else solimp)
        + f' friction="{obstacle.friction} {obstacle.friction} 0 0 {obstacle.roll_resistance_m}"/>'
        for k, obstacle in enumerate(terrain.obstacles) if obstacle.roll_resistance_m > 0
        for i in range(scene.n_segments))
    return f"""<mujoco model="sensnake_v2">
  <compiler angle="degree" autolimits="true"/>
  <option timestep="{scene.timestep_s}" integrator="implicitfast" cone="elliptic" gravity="0 0 {-GRAVITY_M_S2}"
          jacobian="sparse"/>
  <!-- jacobian sparse: the chain's 42 degrees of freedom make a very sparse mass matrix and constraint Jacobian;
       MuJoCo's automatic choice (dense below 60) steps it 1.6-2.8x slower. The same equations, summed in another
       order: the results agree to numerical noise, not to the bit (docs/PHYSICS_LAB.md, "How fast"). -->
  <default>
    <joint damping="{servo.damping_nm_s_per_rad}" armature="{servo.armature_kg_m2}"
           frictionloss="{servo.friction_loss_nm}"/>
    <!-- Contacts are near rigid (MuJoCo's default 20 ms, critically damped): the compliance that spreads a load
         is the shell's springs (ShellParams), a physical N/m, not a mass-scaled contact softness. -->
    <geom solref="{solref}"/>
  </default>
  <visual><global offwidth="640" offheight="480"/><quality shadowsize="0"/></visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.35 0.4 0.45" rgb2="0.3 0.35 0.4" width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="8 8"/>
    {assets}
  </asset>
  <worldbody>
    <light pos="0 -1 2" dir="0 0.5 -1" castshadow="false"/>
    <geom name="ground" type="plane" size="5 5 0.1" material="grid" contype="0" conaffinity="{ground_affinity}"
          friction="{terrain.ground_friction} 0.005 0.0001"/>
    {obstacles}{walls}
    <body name="head" pos="0 0 {head_z}">
      <freejoint name="base"/>
      <geom name="head" type="cylinder" size="{HEAD_RADIUS_M} {HEAD_LENGTH_M / 2}" pos="{HEAD_LENGTH_M / 2} 0 0"
            euler="0 90 0" mass="{scene.head_mass_kg}" rgba="0.3 0.3 0.3 1" contype="0" conaffinity="0"/>
      {body}
    </body>
  </worldbody>
  <contact>{pairs}</contact>
  <equality>{hands}</equality>
  <actuator>{actuators}</actuator>
</mujoco>
"""
