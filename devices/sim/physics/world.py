"""One MuJoCo world: SenSnake v2 with position servos, the ground and the obstacle; joint states and sensor forces.

The servo loop (XM430-W350 in position mode, :class:`devices.sim.physics.model.ServoParams`) runs here at every
physics step: the set point slews toward the goal at the commanded speed (the servo's profile velocity), the motor
torque is ``kp·(set point − angle)`` clipped to the stall torque along the motor's torque–speed line, and torque off
leaves only the joint's passive damping and friction (the limp robot). A joint whose demanded torque stays above
the stall torque is *saturated*; :attr:`JointState.saturated_s` says for how long, so the simulated chain trips the
overload error from physics, as the servo firmware does.

Sensor forces: every contact is on a segment's compliant shell (``model.ShellParams``: the shell rides on springs
over the servo's housing, so the load a contact puts on the body builds up and falls off smoothly as the shell
deflects). Its normal force (``mj_contactForce``) goes to the sheets by where it touches the circumference, in the
segment's frame (angle from the bottom, −z, toward the left, +y): a sheet 3.5 cm wide on a 3.6 cm radius covers
``SHEET_HALF_ARC_DEG`` either side of its centre (bottom 0°, left +90°, right −90°) and takes all of a contact there;
a contact between two sheets is shared between them in proportion to how near it is to each (the shell spreads it),
and one on the rigid PLA top (beyond ``TOP_FADE_DEG``) reaches no sheet. The weights are continuous in the angle,
so a segment rolling a little never flips a load from one sheet to another.

The teach "hand": posing a limp joint (:meth:`set_joint_angle`) grips it with a stiff joint constraint and bends it
toward the pose at a hand's speed (``HAND_SPEED_RAD_S``), then *holds* it there, as a person's hand holds the robot
in shape while the pose is captured, until the servo takes over (torque on) or the hand lets go
(:meth:`release_hand`). Without it gravity pulls a posed pitch joint back down: a limp XM430's gearbox does not hold
the segments lifted behind a joint (the static friction identified on comparable Dynamixels, MX-64/MX-106, is about
0.1 N·m plus 0.2 × the load, and lifting joint 5 of the robot lying on the ground takes a few tenths of a N·m; the
published XM430 friction loss used here is 0.03 N·m). The hand moves the joint through the physics, never by setting
the state: a pose put in at once while the body is still falling (a user setting poses a fraction of a second
apart) has to be lifted out of the terrain with the fall's speed kept, and the body then slams into the ground
deeper than the contact model resolves (``benchmarks/bench_hand_posing.py``). Bent at a hand's speed, the body
lifts, swings and lands as a real one does, and whichever end is lighter moves.

Rest (:attr:`rest_enabled`, the app's lab): once every velocity has stayed below ``REST_SPEED`` for ``REST_AFTER_S``
of simulated time with nothing commanded still to do (no servo slewing toward its goal, none straining near its
stall torque, where the overload may yet trip), the world
stops stepping and its clock moves on with the body frozen (counted in ``rested_s``); any change of command, a hand
or an external torque wakes it. Besides saving the machine, this removes the slow creep of MuJoCo's soft contacts
(a limp robot draped on PTFE creeps at ~2e-3 rad/s forever; with no-slip iterations it stops, i.e. it is an artefact,
not a slide).

Validity (:mod:`.validity`): MuJoCo's automatic reset of a blown-up state is off (``mjDSBL_AUTORESET``); after every
batch of steps the world checks MuJoCo's warnings, the state's finiteness, the contacts' depth, the body's speed and
its energy. The first failure stops the world at its last good state (it steps no more; its clock moves on, the body
frozen) and :attr:`invalid` says what and when; :meth:`place` starts it afresh. MuJoCo's log goes to logging.

Threads: every public method takes the world's lock, so the chain (the robot port's thread), the board (its port's
thread) and a stepping thread may all call; :meth:`advance_to` steps until the world's clock reaches a time.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from devices.scene import SIDES, channel_map  # noqa: F401 - channel_map: callers import it from here too
from devices.sim.physics.model import (
    GRAVITY_M_S2,
    SceneParams,
    build_mjcf,
    hand_name,
    joint_name,
    segment_name,
    shell_joint_names,
)
from devices.sim.physics.validity import (
    MAX_PENETRATION_M,
    MAX_PENETRATION_ONSETS,
    InvalidState,
    ValidityMonitor,
    route_mujoco_log,
    speed_limit_m_s,
)

route_mujoco_log()  # MuJoCo's warnings to logging, never to a MUJOCO_LOG.TXT in the working folder

SHEET_HALF_ARC_DEG = 28.0  # a 3.5 cm wide sheet on the 3.6 cm radius shell (paper, Sec. III-A): 55.7° of arc
TOP_FADE_DEG = 152.0  # from the side sheets' edge (118°) the share fades to 0 here: the PLA top carries the rest
MAX_CATCH_UP_S = 0.5  # further behind than this, the world skips ahead (counted in lagged_s) instead of stalling
REST_SPEED = 5e-3  # rad/s or m/s, any degree of freedom: below this the body counts as still
# How fast the teach hand bends a joint toward its pose (rad/s): a person bending the robot, about the servo's own
# no-load speed (4.8 rad/s); a pose 1 rad away is reached in about 0.25 s.
HAND_SPEED_RAD_S = 4.0
STRAIN_FRACTION = 0.8  # a servo demanding more than this × its stall torque strains (may trip): no rest
CONTACT_MEMORY_S = 0.05  # a shell off the ground for less than this still shares its load as its last contacts did
REST_AFTER_S = 1.0  # simulated seconds still (and nothing commanded left to do) before the world rests
# a state to go back to (PhysicsWorld._snapshot): time, qpos, qvel, act, the warm start, the hands' grips
_Snapshot = tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
# a joint limit's constraint rows (as an int: comparing an array with MuJoCo's enum object costs 20 µs a call)
_LIMIT_JOINT = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)


@dataclass(frozen=True)
class JointState:
    """Per joint, head first: angle (rad), velocity (rad/s), motor torque applied (N·m), demanded (N·m, before
    the stall-torque clip) and how long the demand has been above the stall torque without a break (s)."""

    position_rad: np.ndarray
    velocity_rad_s: np.ndarray
    torque_nm: np.ndarray
    demand_nm: np.ndarray
    saturated_s: np.ndarray


@dataclass(frozen=True)
class BodyState:
    """Where the robot is: ``points_m`` (n+1, 3) head tip then the back end of each segment, ``frames`` (n, 3, 3)
    each segment's rotation (columns: forward x, left y, up z), world frame (obstacle axis at x = 0)."""

    time_s: float
    points_m: np.ndarray
    frames: np.ndarray


class PhysicsWorld:
    """SenSnake v2 in MuJoCo. ``place`` puts the straight robot somewhere; then command and advance it."""

    def __init__(self, scene: SceneParams | None = None) -> None:
        self.scene = scene or SceneParams()
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(self.scene))
        # a blown-up state stays as it is, for the validity checks to see, instead of MuJoCo silently resetting it
        self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        self.data = mujoco.MjData(self.model)
        self._warned = self.data.warning.number  # a live view of MuJoCo's warning counts (0 until one is raised)
        self._lock = threading.RLock()
        n = self.scene.n_segments
        self.n_joints = n
        joints = [self.model.joint(joint_name(i)) for i in range(n)]
        self._qadr = np.array([int(j.qposadr[0]) for j in joints])
        self._dadr = np.array([int(j.dofadr[0]) for j in joints])
        self._seg_body = np.array([self.model.body(segment_name(i)).id for i in range(n)])
        self._seg_geom = np.array([self.model.geom(segment_name(i)).id for i in range(n)])
        self._segment_of_geom = np.full(self.model.ngeom, -1)
        self._segment_of_geom[self._seg_geom] = np.arange(n)
        self._head_geom = self.model.geom("head").id
        shell = [self.model.joint(name) for i in range(n) for name in shell_joint_names(i)]
        self._shell_qadr = np.array([int(j.qposadr[0]) for j in shell]).reshape(n, 2)
        self._shell_dadr = np.array([int(j.dofadr[0]) for j in shell]).reshape(n, 2)
        self._shell_joint_ids = np.array([j.id for j in shell])
        self._is_shell_joint = np.zeros(self.model.njnt, dtype=bool)
        self._is_shell_joint[self._shell_joint_ids] = True
        self._sheet_share = np.zeros((n, 3))  # last contacts' sheet loads per newton of their resultant
        self._share_time = np.full(n, -math.inf)
        self._last_push = np.zeros((n, 2))
        servo = self.scene.servo
        self._kp = servo.position_gain_nm_per_rad
        self._stall = servo.stall_torque_nm
        self._w0 = servo.no_load_speed_rad_s
        self._dt = float(self.model.opt.timestep)
        self._torque_on = np.zeros(n, dtype=bool)
        self._goal = np.zeros(n)
        self._speed = np.full(n, self._w0)
        self._setpoint = np.zeros(n)
        self._external = np.zeros(n)
        self._applied = np.zeros(n)
        self._demand = np.zeros(n)
        self._saturated_s = np.zeros(n)
        self._offset_s = 0.0
        self.lagged_s = 0.0  # simulated time skipped because stepping fell behind the clock
        self.steps = 0
        self.stepping_s = 0.0  # wall time spent inside step() (any thread): the world's share of the machine
        self._force_buf = np.zeros(6)
        # what changed the world's state last (a step, a placing, a pose by hand): the contacts read for one state
        # serve every reading of that state
        self._state_version = 0
        self._contacts_of: tuple[tuple[int, float, bytes, bytes, int], _Contacts] | None = None
        self._loads_of: tuple[tuple[int, float, bytes, bytes, int], np.ndarray] | None = None  # (state, loads)
        self._hand_eq = np.array([self.model.equality(hand_name(i)).id for i in range(n)])
        self._held = np.zeros(n, dtype=bool)
        self._hand_at = np.zeros(n)  # where each hand's grip holds its joint now (rad): its constraint's angle
        self._hand_pose = np.zeros(n)  # where the hand is taking it (rad)
        self._hand_slew = HAND_SPEED_RAD_S * self._dt  # rad per step
        self._hands_moving = False  # some held joint's grip is still on its way to the pose
        self.rest_enabled = False  # the app's lab turns it on (PhysicsBackend.start); batch runs step every step
        self._resting = False
        self._still_s = 0.0
        self.rested_s = 0.0  # simulated time the world spent resting (not stepped, body frozen)
        self._loads_at_rest: np.ndarray | None = None
        self._state_at_rest: JointState | None = None
        self._tail_load_n = 0.0
        self.invalid: InvalidState | None = None  # why the world stopped (see the module docstring), None: it is fine
        terrain = self.scene.terrain
        onset = terrain.contact_onset_m or 0.0
        robot_bodies = np.concatenate([[self.model.body("head").id], self._seg_body])
        self.validity = ValidityMonitor(
            self.model, self.data, robot_bodies, int(self._seg_body[-1]), speed_limit_m_s=self._speed_limit(0.0),
            servo_peak_w=servo.stall_torque_nm * servo.no_load_speed_rad_s / 4.0,
            penetration_m=max(MAX_PENETRATION_M, MAX_PENETRATION_ONSETS * onset),
            shell_radius_m=self.scene.segment_radius_m)
        self.place()

    def _speed_limit(self, tail_load_n: float) -> float:
        scene = self.scene
        top = max((o.top_m for o in scene.terrain.obstacles), default=0.0)
        return speed_limit_m_s(scene.body_length_m, top, scene.servo.no_load_speed_rad_s, scene.robot_mass_kg,
                               tail_load_n, GRAVITY_M_S2)

    # -- set-up ------------------------------------------------------------------------------------------------------
    def place(self, head_x_m: float | None = None, height_m: float | None = None,
              angles_rad: Sequence[float] | None = None) -> None:
        """Put the robot at rest with its head tip at ``head_x_m`` (default: the scene's ``head_x_m``, else segment 6
        over the x = 0 (the paper's start over its obstacle), else the body centred on x = 0 on flat ground) and its
        axis ``height_m`` above the ground (default: just above the highest terrain under the body), joints at
        ``angles_rad`` (default straight)."""
        with self._lock:
            scene = self.scene
            terrain = scene.terrain
            clock_s = self.time_s  # the world's clock runs on through a new start
            mujoco.mj_resetData(self.model, self.data)
            self._offset_s = clock_s
            self.data.xfrc_applied[self._seg_body[-1], 0] = -self._tail_load_n  # the load stays on
            if head_x_m is None:
                head_x_m = terrain.head_x_m
            if head_x_m is None:
                head_x_m = 5.5 * scene.segment_length_m if terrain.obstacles else 0.5 * scene.body_length_m
            if height_m is None:
                under = terrain.max_height_between(head_x_m - scene.body_length_m, head_x_m)
                height_m = under + scene.segment_radius_m + 0.002
            self.data.qpos[0:3] = (head_x_m, 0.0, height_m)
            self.data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
            angles = np.zeros(self.n_joints) if angles_rad is None else np.asarray(angles_rad, dtype=float)
            self.data.qpos[self._qadr] = angles
            self._setpoint[:] = angles
            self._goal[:] = angles
            self._saturated_s[:] = 0.0
            self._held[:] = False
            self._hands_moving = False
            self.data.eq_active[self._hand_eq] = False
            self._share_time[:] = -math.inf
            self.invalid = None
            self._wake()
            mujoco.mj_forward(self.model, self.data)
            self._state_version += 1
            self.validity.rebase()

    # -- commands (any thread) ---------------------------------------------------------------------------------------
    def command(self, torque_on: np.ndarray, goal_rad: np.ndarray, speed_rad_s: np.ndarray | None = None) -> None:
        """Torque enable, goal angle (rad) and profile speed (rad/s, default the no-load speed) per joint. A joint
        turned on holds where it is and then moves toward its goal (the firmware's goal = present on torque-on)."""
        with self._lock:
            on = np.asarray(torque_on, dtype=bool)
            goal = np.asarray(goal_rad, dtype=float)
            speed = None if speed_rad_s is None else np.clip(speed_rad_s, 0.0, self._w0)
            if self._resting and (np.any(on != self._torque_on) or np.any(goal != self._goal)
                                  or (speed is not None and np.any(speed != self._speed))):
                self._wake()
            if np.any(on & self._held):  # the servo takes over from the hand
                self._release(on & self._held)
            newly_on = on & ~self._torque_on
            if newly_on.any():
                self._setpoint[newly_on] = self.data.qpos[self._qadr][newly_on]
            self._torque_on[:] = on
            self._goal[:] = goal
            if speed is not None:
                self._speed[:] = speed
            self._saturated_s[~on] = 0.0

    def set_joint_angle(self, joint: int, angle_rad: float) -> None:
        """Pose a limp joint by hand (the teach "hand"): grip it where it is and bend it toward ``angle_rad`` at
        ``HAND_SPEED_RAD_S`` as the world steps, then hold it there until the servo takes over (torque on) or
        :meth:`release_hand`. Posed again on the way, the hand turns toward the new angle from where it is.
        ValueError if the joint's torque is on (its servo holds it, as the simulated chain says too)."""
        with self._lock:
            if self._torque_on[joint]:
                raise ValueError(f"joint {joint + 1} has torque on and its servo holds it; turn torque off to pose it")
            if not self._held[joint]:  # the hand grips the joint where it is
                self._hand_at[joint] = float(self.data.qpos[self._qadr[joint]])
                self.model.eq_data[self._hand_eq[joint], 0] = self._hand_at[joint]
                self.data.eq_active[self._hand_eq[joint]] = True
                self._held[joint] = True
            self._hand_pose[joint] = angle_rad
            self._hands_moving = bool(np.any(self._held & (self._hand_at != self._hand_pose)))
            self._wake()

    def _move_hands(self) -> None:
        """One step of the hands on their way (before a physics step): each grip moves ``HAND_SPEED_RAD_S`` × the
        time step toward its pose, landing on it exactly."""
        moving = self._held & (self._hand_at != self._hand_pose)
        gap = self._hand_pose[moving] - self._hand_at[moving]
        slew = self._hand_slew
        self._hand_at[moving] = np.where(np.abs(gap) <= slew, self._hand_pose[moving],
                                         self._hand_at[moving] + np.sign(gap) * slew)
        self.model.eq_data[self._hand_eq[moving], 0] = self._hand_at[moving]
        self._hands_moving = bool(np.any(self._hand_at[moving] != self._hand_pose[moving]))

    def release_hand(self, joints: Sequence[int] | None = None) -> None:
        """The hand lets go of ``joints`` (default: all): gravity and contacts alone move them from now on."""
        with self._lock:
            mask = np.zeros(self.n_joints, dtype=bool)
            mask[list(range(self.n_joints)) if joints is None else list(joints)] = True
            self._release(mask & self._held)

    @property
    def held(self) -> np.ndarray:
        """Which joints the hand holds (bool per joint)."""
        with self._lock:
            return self._held.copy()

    def _release(self, mask: np.ndarray) -> None:
        if mask.any():
            self._held[mask] = False
            self.data.eq_active[self._hand_eq[mask]] = False
            self._hands_moving = bool(np.any(self._held & (self._hand_at != self._hand_pose)))
            self._wake()

    def set_external_torque(self, joint: int, torque_nm: float) -> None:
        """An extra torque on a joint (N·m), e.g. a hand pushing on the body."""
        with self._lock:
            if self._external[joint] != torque_nm:
                self._wake()
            self._external[joint] = torque_nm

    def set_tail_load(self, force_n: float) -> None:
        """A constant backward force (N, along −x in the world) on the tail segment: the load a robot drags, the
        published perturbation of a body pushing against terrain (Fu & Li 2023). 0 removes it."""
        with self._lock:
            body = self._seg_body[-1]
            if self.data.xfrc_applied[body, 0] != -force_n:
                self._wake()
            self.data.xfrc_applied[body, :] = 0.0
            self.data.xfrc_applied[body, 0] = -float(force_n)
            if float(force_n) != self._tail_load_n:
                self._tail_load_n = float(force_n)
                self.validity.speed_limit_m_s = self._speed_limit(self._tail_load_n)
                self.validity.rebase()  # the load's potential is measured from here

    # -- rest ------------------------------------------------------------------------------------------------------------
    @property
    def resting(self) -> bool:
        """True while the world rests (see the module docstring): not stepped, its body frozen."""
        with self._lock:
            return self._resting

    def _wake(self) -> None:
        self._resting = False
        self._still_s = 0.0
        self._loads_at_rest = None
        self._state_at_rest = None

    def _note_stillness(self, stepped_s: float) -> None:
        still = (float(np.max(np.abs(self.data.qvel))) < REST_SPEED and not self._hands_moving
                 and not np.any(self._torque_on & (self._setpoint != self._goal))
                 and not np.any(np.abs(self._demand) > STRAIN_FRACTION * self._stall))
        self._still_s = self._still_s + stepped_s if still else 0.0
        if self._still_s >= REST_AFTER_S:
            self._resting = True

    # -- time ------------------------------------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """The world's clock (s): simulated time stepped, plus any time skipped (``lagged_s``)."""
        with self._lock:
            return float(self.data.time) + self._offset_s

    def pose_snapshot(self) -> tuple[float, np.ndarray]:
        """(the world's clock as :attr:`time_s`, a copy of ``qpos``) read together: what a copy of the world needs to
        be drawn in the same pose (the app's 3-D view of the lab's own process)."""
        with self._lock:
            return float(self.data.time) + self._offset_s, self.data.qpos.copy()

    def step(self, n: int = 1) -> None:
        """``n`` physics steps of ``scene.timestep_s``, each with one servo-loop update."""
        with self._lock:
            if self.invalid is not None:  # stopped at its last good state (see the module docstring)
                return
            started = time.perf_counter()
            data, model = self.data, self.model
            good = self._snapshot()
            warned = self._warned
            stepped = 0
            data.qfrc_applied[self._dadr] = self._external
            if not self._torque_on.any():  # all limp (Teach, the app at power-up): no servo loop to run
                self._applied[:] = 0.0
                self._demand[:] = 0.0
                self._saturated_s[:] = 0.0
                data.ctrl[:] = 0.0
                while stepped < n and self._hands_moving:  # a hand on its way moves between steps
                    self._move_hands()
                    mujoco.mj_step(model, data)
                    stepped += 1
                    if warned.any():
                        break
                if stepped < n and not warned.any():
                    # Nothing to compute between steps: MuJoCo takes them all in one call. A warning raised on the
                    # way (the world then is invalid) sends it back to where the call started to take them one by
                    # one again and stop at the step MuJoCo found bad, so what and when stay exact (the same steps:
                    # the state, the warm start and the inputs are restored).
                    start = good if stepped == 0 else self._snapshot()
                    counts, infos = data.warning.number.copy(), data.warning.lastinfo.copy()
                    mujoco.mj_step(model, data, nstep=n - stepped)
                    if not warned.any():
                        stepped = n
                    else:
                        # the warnings too: those of the steps after the bad one would hide which came first
                        self._restore(start)
                        data.warning.number[:], data.warning.lastinfo[:] = counts, infos
                        while stepped < n:
                            mujoco.mj_step(model, data)
                            stepped += 1
                            if warned.any():
                                break
            else:
                stepped = self._servo_steps(n)
            self.steps += stepped
            self._state_version += 1
            self._check_validity(stepped, good)
            if self.rest_enabled and self.invalid is None:
                self._note_stillness(stepped * self._dt)
            self.stepping_s += time.perf_counter() - started

    def _servo_steps(self, n: int) -> int:
        """Up to ``n`` steps, each with one servo-loop update (see the module docstring), stopping after a step that
        raised a MuJoCo warning; how many were taken. The arithmetic is the loop's, in the same order (the results
        to the bit): only what does not change within the batch is computed once (the slew per step, the external
        torques) and what only the last step leaves (demand, applied) is kept from it."""
        data, model = self.data, self.model
        warned = self._warned
        qadr, dadr = self._qadr, self._dadr
        torque_on, goal, setpoint = self._torque_on, self._goal, self._setpoint
        every_on = bool(torque_on.all())
        kp, stall, w0, dt = self._kp, self._stall, self._w0, self._dt
        slew = self._speed * dt
        at_goal = bool(np.array_equal(setpoint, goal))  # the set point moves no more: adding 0 changes nothing
        saturated = self._saturated_s
        demand = applied = np.zeros(self.n_joints)
        stepped = 0
        for _ in range(n):
            q = data.qpos[qadr]
            qd = data.qvel[dadr]
            if not at_goal:
                setpoint += np.clip(goal - setpoint, -slew, slew)
                at_goal = bool(np.array_equal(setpoint, goal))
            demand = kp * (setpoint - q)
            # A DC motor's torque–speed line: turning at ω in the torque's direction leaves τ_stall·(1 − ω/ω0).
            along = np.where(demand * qd > 0.0, np.abs(qd), 0.0)
            limit = stall * np.minimum(np.maximum(1.0 - along / w0, 0.0), 1.0)
            applied = np.minimum(np.maximum(demand, -limit), limit)
            if not every_on:
                applied = np.where(torque_on, applied, 0.0)
            over = np.abs(demand) > stall
            if not every_on:
                over &= torque_on
            saturated = np.where(over, saturated + dt, 0.0)
            data.ctrl[:] = applied
            if self._hands_moving:  # limp joints a hand is still bending
                self._move_hands()
            mujoco.mj_step(model, data)
            stepped += 1
            if warned.any():
                break
        self._saturated_s = saturated
        self._demand = np.where(torque_on, demand, 0.0) if stepped else self._demand
        self._applied = applied if stepped else self._applied
        return stepped

    def _snapshot(self) -> _Snapshot:
        """What :meth:`_restore` needs to go back to this state: time, qpos, qvel, act, the solver's warm start and
        where the hands' grips are."""
        data = self.data
        return (float(data.time), data.qpos.copy(), data.qvel.copy(), data.act.copy(), data.qacc_warmstart.copy(),
                self._hand_at.copy())

    def _restore(self, good: _Snapshot) -> None:
        """Back to the state ``good`` taken by :meth:`_snapshot`."""
        data = self.data
        data.time, data.qpos[:], data.qvel[:], data.act[:], data.qacc_warmstart[:], self._hand_at[:] = good
        self.model.eq_data[self._hand_eq, 0] = self._hand_at
        self._hands_moving = bool(np.any(self._held & (self._hand_at != self._hand_pose)))

    def _check_validity(self, n: int, good: _Snapshot) -> None:
        """After ``n`` steps from the state ``good``: the validity checks (:mod:`.validity`); on the first failure
        the world goes back to ``good`` and stops there (:attr:`invalid`)."""
        what = self.validity.check(n * self._dt, int(self._torque_on.sum()), self._tail_load_n,
                                   energy_checked=not (self._held.any() or np.any(self._external)))
        if what is None:
            return
        data = self.data
        # a warning stopped the steps at the bad one, which MuJoCo dates at its start (its log's "Time = ")
        when = float(data.time) - (self._dt if self._warned.any() else 0.0)
        self.invalid = InvalidState(what, when + self._offset_s)
        self._restore(good)
        mujoco.mj_forward(self.model, data)
        self._state_version += 1

    def advance_to(self, t_s: float) -> None:
        """Step until the world's clock reaches ``t_s`` (s); if that is more than ``MAX_CATCH_UP_S`` ahead, skip the
        excess (the robot freezes for it, counted in ``lagged_s``) so a slow machine never blocks a caller long."""
        with self._lock:
            self.limit_lag(t_s)
            behind = t_s - self.time_s
            if self._resting or self.invalid is not None:  # nothing moves: the clock moves on without stepping
                if behind > 0.0:
                    self._offset_s += behind
                    self.rested_s += behind if self.invalid is None else 0.0
                return
            n = int(math.floor(behind / self._dt))
            if n > 0:
                self.step(n)

    def limit_lag(self, t_s: float) -> None:
        """Skip ahead (counted in ``lagged_s``, the robot frozen for it) so that ``t_s`` is at most
        ``MAX_CATCH_UP_S`` ahead of the world's clock; a resting world skips nothing (it rests through any gap)."""
        with self._lock:
            behind = t_s - self.time_s
            if not self._resting and self.invalid is None and behind > MAX_CATCH_UP_S:
                skip = behind - MAX_CATCH_UP_S
                self._offset_s += skip
                self.lagged_s += skip

    # -- readings (any thread) -------------------------------------------------------------------------------------------
    def joint_state(self) -> JointState:
        """The joints now. While the world rests this is the same object on every call (its arrays are shared: do
        not modify them), so a reader can tell that nothing changed."""
        with self._lock:
            if self._resting:
                if self._state_at_rest is None:
                    self._state_at_rest = self._joint_state()
                return self._state_at_rest
            return self._joint_state()

    def _joint_state(self) -> JointState:
        with self._lock:
            return JointState(
                position_rad=self.data.qpos[self._qadr].copy(),
                velocity_rad_s=self.data.qvel[self._dadr].copy(),
                torque_nm=self._applied.copy(),
                demand_nm=self._demand.copy(),
                saturated_s=self._saturated_s.copy(),
            )

    def segment_loads_n(self) -> np.ndarray:
        """(3, n) normal force (N) on the bottom, left and right sheet of every segment (rows in ``SIDES`` order).

        What a sheet feels is the load through the compliant shell, not the contact's instantaneous impulse: per
        segment, the force the shell's springs, dampers and travel stops pass to the housing, plus the shell's own
        weight (the sheets sit outside the shell, under the rubber cover), i.e. the contact force without the light
        shell's rattle. It is shared among the sheets as the present contacts are (:func:`sheet_weights` of each
        contact's angle, weighted by its normal force), or as the last contacts were when the shell has just hopped
        off for a step (``CONTACT_MEMORY_S``)."""
        with self._lock:
            if self._resting and self._loads_at_rest is not None:
                return self._loads_at_rest.copy()
            key = self._state_key()
            if self._loads_of is not None and self._loads_of[0] == key:  # read again at the same instant (a board
                return self._loads_of[1].copy()  # instant that is also a control tick): the same loads
            sheets, push = self._contact_sheets()
            transmitted = self._shell_force()  # (n, 2): y (left), z (up) in each segment's frame, N
            now = float(self.data.time)
            loads = np.zeros((3, self.n_joints))
            resultant = np.array([math.hypot(y, z) for y, z in push.tolist()])
            pushed = resultant > 1e-6  # segments with contacts now: shared as they are
            direction = np.zeros((self.n_joints, 2))
            if pushed.any():
                self._sheet_share[pushed] = sheets[:, pushed].T / resultant[pushed, None]
                self._share_time[pushed] = now
                direction[pushed] = push[pushed] / resultant[pushed, None]
            # a shell off the ground for a moment: shared as its last contacts were
            remembered = ~pushed & (now - self._share_time <= CONTACT_MEMORY_S)
            direction[remembered] = self._last_push[remembered]
            loaded = pushed | remembered
            self._last_push[loaded] = direction[loaded]
            # the shell's load along the direction the contacts push it (never negative: a sheet only presses)
            along = np.array([ty * dy + tz * dz for (ty, tz), (dy, dz) in zip(transmitted.tolist(),
                                                                             direction.tolist())])
            pressed = loaded & (along > 0.0)
            loads[:, pressed] = (self._sheet_share[pressed] * along[pressed, None]).T
            self._loads_of = (key, loads.copy())
            if self._resting:
                self._loads_at_rest = loads.copy()
            return loads

    def _contacts(self) -> _Contacts:
        """This step's contacts, as arrays (see :class:`_Contacts`), read once per state of the world (the sheets'
        loads and the weight check at one instant share them). One read of MuJoCo's arrays for them all, not a
        Python loop over ``mj_contactForce``: with the elliptic cone MuJoCo keeps a contact's force in its frame as
        ``efc_force[efc_address : efc_address + dim]`` (normal, then the tangents), which is what
        ``mj_contactForce`` copies; a contact without rows (excluded) has none."""
        key = self._state_key()
        if self._contacts_of is not None and self._contacts_of[0] == key:
            return self._contacts_of[1]
        found = self._read_contacts()
        self._contacts_of = (key, found)
        return found

    def _state_key(self) -> tuple[int, float, bytes, bytes, int]:
        """What tells one state of the world from another: a step, a placing, a pose by hand bump the version; the
        time and the state's bytes catch a caller stepping MuJoCo itself (mj_step2) or setting a state (tests)."""
        data = self.data
        return self._state_version, float(data.time), data.qpos.tobytes(), data.qvel.tobytes(), data.ncon

    def _read_contacts(self) -> _Contacts:
        data = self.data
        ncon = data.ncon
        if ncon == 0:
            return _NO_CONTACTS
        contact = data.contact
        geom1, geom2 = contact.geom1.copy(), contact.geom2.copy()
        first, second = self._segment_of_geom[geom1], self._segment_of_geom[geom2]
        address, dim = contact.efc_address, contact.dim
        local = np.zeros((ncon, 3))  # in the contact's frame: normal, first and second tangent
        rows = address >= 0
        local[rows, 0] = data.efc_force[address[rows]]
        tangents = rows & (dim >= 3)
        local[tangents, 1] = data.efc_force[address[tangents] + 1]
        local[tangents, 2] = data.efc_force[address[tangents] + 2]
        frames = contact.frame.reshape(ncon, 3, 3)  # rows: the frame's axes
        force = np.einsum("kji,kj->ki", frames, local)  # on geom2 from geom1, world frame
        segment = np.where(first >= 0, first, second)
        on_robot = segment >= 0
        radial = np.zeros((ncon, 2))
        share = np.zeros((ncon, 3))
        placed = np.zeros(ncon, dtype=bool)
        if on_robot.any():
            seg = segment[on_robot]
            # the whole force on the segment: on geom2 as MuJoCo gives it, the opposite where the segment is geom1
            on_segment = np.where((second[on_robot] == seg)[:, None], force[on_robot], -force[on_robot])
            rotations = data.xmat[self._seg_body[seg]].reshape(-1, 3, 3)
            radial[on_robot] = np.einsum("kji,kj->ki", rotations, on_segment)[:, 1:3]  # axial: to the housing
            where = np.einsum("kji,kj->ki", rotations, contact.pos[on_robot] - data.geom_xpos[self._seg_geom[seg]])
            pairs = where[:, 1:3].tolist()
            placed[on_robot] = [math.hypot(y, z) >= 1e-9 for y, z in pairs]  # False: on the axis, no angle
            share[on_robot] = sheet_weights_many(np.array([math.degrees(math.atan2(y, -z)) for y, z in pairs]))
        return _Contacts(geom1, geom2, first, second, local[:, 0], force, segment, radial, share, placed)

    def _contact_sheets(self) -> tuple[np.ndarray, np.ndarray]:
        """Per segment, the part of its contact forces normal to its sheets — the radial part (y, z in the segment's
        frame) of each contact's whole force, normal and friction, as a sheet only feels pressure — shared among its
        sheets (3, n) by where each contact is, and their resultant (n, 2), from MuJoCo's contacts this step."""
        n = self.n_joints
        sheets = np.zeros((n, 3))
        push = np.zeros((n, 2))
        found = self._contacts()
        used = (found.segment >= 0) & (found.normal_n > 0.0) & found.placed
        if used.any():
            segment, radial = found.segment[used], found.radial_n[used]
            magnitude = np.array([math.hypot(y, z) for y, z in radial.tolist()])
            np.add.at(sheets, segment, magnitude[:, None] * found.share[used])
            np.add.at(push, segment, radial)
        return sheets.T.copy(), push

    def _shell_force(self) -> np.ndarray:
        """(n, 2) the force (N) each shell passes to its segment's housing (y, z in the segment's frame) through its
        springs, dampers and travel stops, plus the shell's weight: the load on the sheets, quasi-statically."""
        data, model = self.data, self.model
        shell = self.scene.shell
        qadr, dadr = self._shell_qadr, self._shell_dadr
        elastic = shell.stiffness_n_per_m * data.qpos[qadr] + shell.damping_n_s_per_m * data.qvel[dadr]
        limits = np.flatnonzero(data.efc_type == _LIMIT_JOINT)
        limits = limits[self._is_shell_joint[data.efc_id[limits]]]
        if limits.size:
            forces = np.zeros(data.nefc)
            forces[limits] = data.efc_force[limits]
            generalized = np.zeros(model.nv)
            mujoco.mj_mulJacTVec(model, data, generalized, forces)
            elastic = elastic - generalized[dadr]  # a stop pushing the shell back pushes the housing forward
        gravity = model.opt.gravity
        rotations = data.xmat[self._seg_body].reshape(-1, 3, 3)
        weight_local = shell.mass_kg * np.einsum("nij,i->nj", rotations, gravity)[:, 1:3]  # (n, 2) y, z
        return elastic - weight_local

    def total_contact_normal_n(self) -> float:
        """Sum of the normal forces of every robot contact, sensed or not (N): the weight check's reference."""
        with self._lock:
            found = self._contacts()
            robot = (found.first >= 0) | (found.second >= 0) | (found.geom1 == self._head_geom) \
                | (found.geom2 == self._head_geom)
            return float(sum(found.normal_n[robot].tolist(), 0.0))

    def vertical_contact_force_n(self) -> float:
        """The upward part (N) of every contact force on the robot (normal and friction): the weight when nothing
        accelerates, whatever the terrain's shape (:meth:`contact_support_n`'s total)."""
        return self.contact_support_n()[1]

    def contact_support_n(self) -> tuple[np.ndarray, float]:
        """The weight check on any terrain, this step: ``(sheets, total)`` — ``sheets`` (3, n) the upward part (N) of
        the whole contact force (normal *and* friction) on each segment's bottom, left and right sheet, shared among
        them by where each contact is as the sheets' readings are (:func:`sheet_weights`), and ``total`` the upward
        part of every contact force on the robot, sensed or not (its segments' ends, the PLA top, the nose).
        ``total`` is the weight when nothing accelerates (Newton), whatever the terrain's shape; ``sheets`` summed
        is that less what lands on no sheet. A sheet's *reading* is only the pressure part of its force
        (:meth:`segment_loads_n`); on a slope friction holds up some weight no sheet reads."""
        with self._lock:
            sheets = np.zeros((self.n_joints, 3))
            found = self._contacts()
            robot_first = (found.first >= 0) | (found.geom1 == self._head_geom)
            robot_second = (found.second >= 0) | (found.geom2 == self._head_geom)
            robot = robot_first != robot_second  # not the robot's, or the robot on itself (no net force): left out
            if not robot.any():
                return sheets.T.copy(), 0.0
            # the force in the contact frame acts on geom2 from geom1
            up = found.force_n[:, 2] * np.where(robot_second, 1.0, -1.0)
            total = float(sum(up[robot].tolist(), 0.0))  # in the contacts' order, as a sum over them one by one
            # on a segment (the nose carries no sheet), at an angle around it: shared by its sheets
            shared = robot & (found.segment >= 0) & found.placed
            if shared.any():
                np.add.at(sheets, found.segment[shared], up[shared, None] * found.share[shared])
            return sheets.T.copy(), total

    def body_state(self) -> BodyState:
        with self._lock:
            frames = self.data.xmat[self._seg_body].reshape(-1, 3, 3).copy()
            starts = self.data.xpos[self._seg_body].copy()
            back = frames[-1] @ np.array([-self.scene.segment_length_m, 0.0, 0.0])
            points = np.vstack([starts, starts[-1] + back])
            return BodyState(self.time_s, points, frames)

    def update_scene(self, renderer: mujoco.Renderer, camera: mujoco.MjvCamera) -> None:
        """Copy the world into ``renderer``'s scene (under the lock), the camera looking at the body's centroid."""
        with self._lock:
            camera.lookat[:] = self.data.xpos[self._seg_body].mean(axis=0)
            renderer.update_scene(self.data, camera)

    @property
    def weight_n(self) -> float:
        return self.scene.robot_mass_kg * abs(float(self.model.opt.gravity[2]))


@dataclass(frozen=True)
class _Contacts:
    """A step's contacts as arrays (k contacts): their geoms, the robot segment of each geom (−1: none), the normal
    force (N) and the whole force (k, 3; on geom2 from geom1, world frame, N); and for a contact on a segment
    (``segment`` ≥ 0: geom1's segment, else geom2's) the radial part of the force on it (k, 2; y, z in its frame),
    how its sheets share it (k, 3) and whether it has an angle around the segment at all (``placed``)."""

    geom1: np.ndarray
    geom2: np.ndarray
    first: np.ndarray
    second: np.ndarray
    normal_n: np.ndarray
    force_n: np.ndarray
    segment: np.ndarray
    radial_n: np.ndarray
    share: np.ndarray
    placed: np.ndarray


_NO_CONTACTS = _Contacts(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros(0),
                         np.zeros((0, 3)), np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 3)),
                         np.zeros(0, dtype=bool))


def sheet_weights_many(angles_deg: np.ndarray) -> np.ndarray:
    """:func:`sheet_weights` of every angle in ``angles_deg`` (k,), as rows (k, 3); the same numbers."""
    angles = np.asarray(angles_deg, dtype=float)
    a = np.abs(angles)
    side = np.where(angles > 0, 1, 2)
    rows = np.arange(a.size)
    weights = np.zeros((a.size, 3))
    edge_b, edge_s0, edge_s1 = SHEET_HALF_ARC_DEG, 90.0 - SHEET_HALF_ARC_DEG, 90.0 + SHEET_HALF_ARC_DEG
    weights[a <= edge_b, 0] = 1.0
    gap = (a > edge_b) & (a < edge_s0)
    f = (a[gap] - edge_b) / (edge_s0 - edge_b)
    weights[gap, 0] = 1.0 - f
    weights[rows[gap], side[gap]] = f
    on_side = (a >= edge_s0) & (a <= edge_s1)
    weights[rows[on_side], side[on_side]] = 1.0
    fade = (a > edge_s1) & (a < TOP_FADE_DEG)
    weights[rows[fade], side[fade]] = 1.0 - (a[fade] - edge_s1) / (TOP_FADE_DEG - edge_s1)
    return weights


def sheet_weights(angle_deg: float) -> np.ndarray:
    """How a contact at ``angle_deg`` around a segment (0 = the bottom sheet's centre, +90 the left's, −90 the
    right's) is shared by the (bottom, left, right) sheets: 1 on a sheet, linear across the gaps between sheets,
    fading to 0 toward the top. Continuous in the angle; the weights sum to 1 except toward the top."""
    a = abs(angle_deg)
    side = 1 if angle_deg > 0 else 2
    weights = np.zeros(3)
    edge_b, edge_s0, edge_s1 = SHEET_HALF_ARC_DEG, 90.0 - SHEET_HALF_ARC_DEG, 90.0 + SHEET_HALF_ARC_DEG
    if a <= edge_b:
        weights[0] = 1.0
    elif a < edge_s0:
        f = (a - edge_b) / (edge_s0 - edge_b)
        weights[0], weights[side] = 1.0 - f, f
    elif a <= edge_s1:
        weights[side] = 1.0
    elif a < TOP_FADE_DEG:
        weights[side] = 1.0 - (a - edge_s1) / (TOP_FADE_DEG - edge_s1)
    return weights
