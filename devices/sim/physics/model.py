"""The MJCF scene of SenSnake v2 on the ground, with the paper's half-cylindrical obstacle (Sec. III-C).

Robot (paper, Sec. III): 12 segments, 0.96 m, 2.4 kg, 0.036 m radius. Bodies follow ``models.kinematics``: the
head cap is the floating base, the body trails backward along its −x, joint i sits at the front of segment i and
turns segment i and everything behind it (pitch about local y, yaw about local z; positive pitch lifts what is
behind, positive yaw swings it right). The head cap is a short collision nose without sensors; it is lighter and
thinner than a segment, so on flat ground it does not touch and every newton of weight goes through a sensor.

Servos (XM430-W350 at 12 V, ROBOTIS e-manual): stall torque 4.1 N·m at 2.3 A (1.78 N·m/A), no-load speed 46 rev/min
(4.82 rad/s), gear ratio 353.5. The joint's passive terms (damping 1.08 N·m·s/rad, reflected rotor inertia
0.045 kg·m², friction loss 0.03 N·m) and the position gain (21 N·m/rad) are the published MuJoCo models of this
servo, not measured on our robot: a starting point (issue 13). The position loop itself runs in :mod:`.world`.

Obstacle: a cylinder of radius ``height`` lying across the path with its axis on the ground, so what shows above
the ground is the paper's half cylinder; PTFE-covered (low friction, configurable). Ground friction is configurable.

Pure string building; any thread.
"""

from __future__ import annotations

from dataclasses import dataclass

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
class SceneParams:
    """Robot and terrain. ``obstacle_height_m`` 0 means flat ground only. Lengths in m, masses in kg."""

    n_segments: int = 12
    axes: tuple[str, ...] = tuple("pitch" if i % 2 == 0 else "yaw" for i in range(12))
    segment_length_m: float = 0.08
    segment_radius_m: float = 0.036
    robot_mass_kg: float = 2.4
    head_mass_kg: float = 0.05
    obstacle_height_m: float = 0.28 * 0.96
    obstacle_width_m: float = 0.8
    obstacle_friction: float = 0.1  # PTFE sheet on the obstacle
    ground_friction: float = 0.3
    timestep_s: float = 0.002
    # Optional walls either side of the robot (y = ±wall_offset_m, a corridor), for pushing a joint against them.
    wall_offset_m: float | None = None
    servo: ServoParams = ServoParams()

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


def build_mjcf(scene: SceneParams) -> str:
    """The scene as an MJCF XML string."""
    length, radius = scene.segment_length_m, scene.segment_radius_m
    servo = scene.servo
    # Capsules: MuJoCo collides capsules with planes and capsules analytically (a cylinder against the big obstacle
    # cylinder goes through the general convex solver, which lets a small body sink deep and then push thousands of
    # newtons). The rounded ends stand for the robot's rounded shells between the joints.
    half = max(length / 2.0 - radius - SEGMENT_GAP_M / 2.0, 0.001)
    # Segments collide with the terrain only (contype 1 / conaffinity 0 vs the terrain's 0 / 1): neighbours share a
    # joint and never touch in the real robot's joint range.
    robot_geom = 'contype="1" conaffinity="0" condim="3"'
    body = ""
    for i in reversed(range(scene.n_segments)):
        axis = "0 1 0" if scene.axes[i] == "pitch" else "0 0 1"
        pos = "0 0 0" if i == 0 else f"{-length:.6f} 0 0"
        rgba = "0.95 0.75 0.2 1" if i % 2 == 0 else "0.85 0.6 0.15 1"
        body = (
            f'<body name="{segment_name(i)}" pos="{pos}">'
            f'<joint name="{joint_name(i)}" type="hinge" axis="{axis}" range="-3.0 3.0" limited="false"/>'
            f'<geom name="{segment_name(i)}" type="capsule" size="{radius} {half:.6f}" '
            f'pos="{-length / 2:.6f} 0 0" euler="0 90 0" mass="{scene.segment_mass_kg:.6f}" rgba="{rgba}" '
            f'{robot_geom}/>'
            f'<site name="{segment_name(i)}_mid" pos="{-length / 2:.6f} 0 0"/>'
            f"{body}</body>"
        )
    obstacle = ""
    if scene.obstacle_height_m > 0:
        obstacle = (
            f'<geom name="obstacle" type="capsule" size="{scene.obstacle_height_m:.6f} {scene.obstacle_width_m / 2:.6f}" '
            f'pos="0 0 0" euler="90 0 0" friction="{scene.obstacle_friction} 0.005 0.0001" '
            f'contype="0" conaffinity="1" rgba="0.85 0.88 0.95 0.45"/>'
        )
    walls = ""
    if scene.wall_offset_m is not None:
        for side, name in ((-1, "wall_right"), (1, "wall_left")):
            walls += (
                f'<geom name="{name}" type="box" size="{scene.body_length_m:.4f} 0.1 0.1" '
                f'pos="0 {side * (scene.wall_offset_m + 0.1):.6f} 0.1" '
                f'contype="0" conaffinity="1" rgba="0.6 0.6 0.7 0.5"/>'
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
    return f"""<mujoco model="sensnake_v2">
  <compiler angle="degree" autolimits="true"/>
  <option timestep="{scene.timestep_s}" integrator="implicitfast" cone="pyramidal" gravity="0 0 {-GRAVITY_M_S2}"/>
  <default>
    <joint damping="{servo.damping_nm_s_per_rad}" armature="{servo.armature_kg_m2}"
           frictionloss="{servo.friction_loss_nm}"/>
    <!-- Soft contacts (40 ms time constant) stand for the compliant TPU shell: two neighbouring segments on the
         obstacle's top share the load instead of rocking between rigid contacts (which chatters the sensors). -->
    <geom friction="{scene.ground_friction} 0.005 0.0001" solref="0.04 1"/>
  </default>
  <visual><global offwidth="640" offheight="480"/><quality shadowsize="0"/></visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.35 0.4 0.45" rgb2="0.3 0.35 0.4" width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="8 8"/>
  </asset>
  <worldbody>
    <light pos="0 -1 2" dir="0 0.5 -1" castshadow="false"/>
    <geom name="ground" type="plane" size="5 5 0.1" material="grid" contype="0" conaffinity="1"/>
    {obstacle}{walls}
    <body name="head" pos="0 0 {head_z}">
      <freejoint name="base"/>
      <geom name="head" type="cylinder" size="{HEAD_RADIUS_M} {HEAD_LENGTH_M / 2}" pos="{HEAD_LENGTH_M / 2} 0 0"
            euler="0 90 0" mass="{scene.head_mass_kg}" rgba="0.3 0.3 0.3 1" contype="0" conaffinity="0"/>
      {body}
    </body>
  </worldbody>
  <equality>{hands}</equality>
  <actuator>{actuators}</actuator>
</mujoco>
"""
