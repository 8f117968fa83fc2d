"""The physics world under the simulated lab: joints for the servo chain, contact forces for the board.

:class:`PhysicsBackend` is what ``devices.sim.lab.SimLab`` builds when ``[lab] physics = "mujoco"``: the virtual
chain hands it torque enable, goals and profile speeds and reads angles, velocities and motor torques back
(:meth:`command` / :meth:`advance_to` / :meth:`joint_state`); the virtual board asks it for each channel's normal
force (:meth:`forces_n`), which the board's sensor models turn into conductance and counts. Both advance the world
lazily to the simulated time of their event; :meth:`start` adds a thread that keeps it at the clock between events
(the GUI's lab), so a plot or a 3-D view sees the robot move even when no driver asks.

A world whose state stopped being physics (``PhysicsWorld.invalid``: MuJoCo's warnings, a contact not resolved, a
speed or an energy no physics gives) stops at its last good state. A batch run reads that and ends the run as
invalid; the app's lab (:meth:`start`) says so in its log — what and when — and puts the robot back at the scene's
start (:attr:`invalid_states` keeps what happened), instead of MuJoCo silently resetting it.

Threads: all methods may be called from any thread (the world locks).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from devices.config import LabConfig, LabPhysicsConfig
from devices.scene import load_scene
from devices.sim.clock import SimClock
from devices.sim.physics.model import SceneParams, ServoParams, ShellParams
from devices.sim.physics.validity import InvalidState
from devices.sim.physics.world import BodyState, JointState, PhysicsWorld, channel_map

if TYPE_CHECKING:  # pragma: no cover
    from devices.sim.physics.render import Mark, ThreadRenderers

log = logging.getLogger(__name__)

SAMPLE_HISTORY = 64  # board instants whose sheet loads are kept (~2 s at 30 Hz): a board catches up a few frames
STEP_INTERVAL_S = 0.02  # the background thread catches up every 20 ms of wall time (the 3-D view draws <= 10/s;
# the chain and the board step the world to their own events anyway)


def scene_from_config(config: LabConfig) -> SceneParams:
    """The robot from ``[robot]`` on the terrain of ``[lab] scene`` (a scene file; raises ``SceneError`` naming the
    file, the key and the problem) or, without one, the half cylinder of the ``[lab]`` legacy keys."""
    robot, lab = config.robot, config.lab
    body_length_m = robot.n_joints * robot.segment_length_m
    physical = lab.physical
    return SceneParams(
        n_segments=robot.n_joints, axes=tuple(robot.axes), segment_length_m=robot.segment_length_m,
        obstacle_height_m=lab.obstacle_height_ratio * body_length_m, obstacle_friction=lab.obstacle_friction,
        ground_friction=lab.ground_friction,
        terrain_scene=load_scene(lab.scene, default_roll_m=physical.roll_resistance_m) if lab.scene else None,
        timestep_s=physical.timestep_s, servo=servo_params(physical), shell=shell_params(physical),
        contact_solref=(physical.contact_time_constant_s, physical.contact_damping_ratio),
        roll_resistance_m=physical.roll_resistance_m,
    )


def servo_params(physical: LabPhysicsConfig) -> ServoParams:
    """The servo model of ``[lab.physics]``."""
    return ServoParams(stall_torque_nm=physical.servo_stall_torque_nm,
                       no_load_speed_rad_s=physical.servo_no_load_speed_rad_s,
                       position_gain_nm_per_rad=physical.servo_position_gain_nm_per_rad,
                       damping_nm_s_per_rad=physical.servo_damping_nm_s_per_rad,
                       armature_kg_m2=physical.servo_armature_kg_m2,
                       friction_loss_nm=physical.servo_friction_loss_nm)


def shell_params(physical: LabPhysicsConfig) -> ShellParams:
    """The compliant shell of ``[lab.physics]``."""
    return ShellParams(stiffness_n_per_m=physical.shell_stiffness_n_per_m,
                       damping_n_s_per_m=physical.shell_damping_n_s_per_m, mass_kg=physical.shell_mass_kg,
                       travel_m=physical.shell_travel_m)


class PhysicsBackend:
    """A :class:`PhysicsWorld` on a :class:`SimClock`, with the board's channel map."""

    def __init__(self, config: LabConfig, clock: SimClock, scene: SceneParams | None = None) -> None:
        self.config = config
        self.clock = clock
        self.world = PhysicsWorld(scene or scene_from_config(config))
        self._rows, self._segments = channel_map(config.board.channel_names, self.world.n_joints)
        self._known = self._rows >= 0
        self._time0_s = clock.now()  # the world starts at 0 s when the clock reads this
        # The board samples at k·period of the clock (VirtualBoard); the world is stopped at each such instant on its
        # way and the sheet loads kept, so a frame due in the past reads the forces of its own instant, not of
        # whenever the host came to read (a 50 Hz control tick reading a 30 Hz board made frames 0-20 ms late).
        self._sample_period_s = 1.0 / config.board.rate_hz
        self._next_sample = math.ceil(self._time0_s / self._sample_period_s)
        self._samples: deque[tuple[int, np.ndarray]] = deque(maxlen=SAMPLE_HISTORY)
        self._advance_lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._renderers: ThreadRenderers | None = None  # one per rendering thread, made on first use
        self._restart_invalid = False  # the app's lab (start): an invalid world is reported and restarted
        self.invalid_states: list[InvalidState] = []  # each time the app's lab restarted an invalid world

    @property
    def time0_s(self) -> float:
        """The clock's simulated time at which the world's clock read 0 (world time = clock time − this)."""
        return self._time0_s

    # -- joints (the chain) ----------------------------------------------------------------------------------------------
    def command(self, torque_on: np.ndarray, goal_rad: np.ndarray, speed_rad_s: np.ndarray) -> None:
        self.world.command(torque_on, goal_rad, speed_rad_s)

    def advance_to(self, sim_s: float) -> None:
        """Step the world to the clock's simulated time ``sim_s`` (s), stopping at each board instant on the way to
        keep its sheet loads (:meth:`forces_n`)."""
        with self._advance_lock:
            period = self._sample_period_s
            # a slow machine: the world skips what it cannot catch up on, and the instants skipped read the present
            self.world.limit_lag(sim_s - self._time0_s)
            self._next_sample = max(self._next_sample,
                                    math.ceil((self.world.time_s + self._time0_s) / period - 1e-9))
            while self._next_sample * period <= sim_s:
                self.world.advance_to(self._next_sample * period - self._time0_s)
                self._samples.append((self._next_sample, self.world.segment_loads_n()))
                self._next_sample += 1
            self.world.advance_to(sim_s - self._time0_s)
            if self._restart_invalid and self.world.invalid is not None:
                self._restart()

    def _restart(self) -> None:
        """The app's lab: say that the world stopped being physics (what, when) and put the robot back at the
        scene's start."""
        invalid = self.world.invalid
        assert invalid is not None
        self.invalid_states.append(invalid)
        log.error("physics lab: the simulation stopped being physics (%s); the robot is put back at the scene's "
                  "start", invalid.describe())
        self.world.place()

    def _loads_at(self, t_s: float) -> np.ndarray:
        """The sheet loads (3, n) at ``t_s``: those kept for that board instant, else the present ones."""
        with self._advance_lock:
            self.advance_to(t_s)
            index = round(t_s / self._sample_period_s)
            if abs(index * self._sample_period_s - t_s) <= 1e-9 * max(1.0, abs(t_s)):
                for kept, loads in reversed(self._samples):
                    if kept == index:
                        return loads
                    if kept < index:
                        break
            return self.world.segment_loads_n()

    def joint_state(self) -> JointState:
        return self.world.joint_state()

    def set_joint_angle(self, joint: int, angle_rad: float) -> None:
        self.world.set_joint_angle(joint, angle_rad)

    def set_external_torque(self, joint: int, torque_nm: float) -> None:
        self.world.set_external_torque(joint, torque_nm)

    def release_hand(self, joint: int | None = None) -> None:
        """The teach hand lets go of ``joint`` (default: every joint it holds)."""
        self.world.release_hand(None if joint is None else [joint])

    # -- forces (the board) --------------------------------------------------------------------------------------------
    def forces_n(self, t_s: float) -> np.ndarray:
        """Normal force (N) on each channel of ``config.board`` at the clock's time ``t_s``: the contact force on
        the sheet the channel names (``S06B``), 0 for a channel the robot does not carry. A time already stepped
        past reads the forces kept for it if it is a board instant (the board catches up a few frames at most), else
        the present ones."""
        loads = self._loads_at(t_s)
        forces = np.zeros(self._rows.size)
        forces[self._known] = loads[self._rows[self._known], self._segments[self._known]]
        return forces

    def body_state(self) -> BodyState:
        return self.world.body_state()

    # -- pictures (each rendering thread has its own OpenGL context) ------------------------------------------------
    def render_rgb(self, width: int = 640, height: int = 480, marks: Sequence[Mark] = ()) -> np.ndarray:
        """A (height, width, 3) uint8 picture of the scene; raises ``RenderUnavailable`` (a RuntimeError) when this
        machine cannot render offscreen. The calling thread's renderer (an OpenGL context current in that thread)
        is made on its first call, and again when the size changes; the thread must :meth:`release_renderer` before
        it ends (a context current in another thread cannot be closed: EGL_BAD_ACCESS)."""
        from devices.sim.physics.render import ThreadRenderers

        if self._renderers is None:
            self._renderers = ThreadRenderers(self.world)
        return self._renderers.render(width, height, marks)

    def release_renderer(self) -> None:
        """Close the calling thread's renderer, if it has one (call it from that thread; :meth:`close` does for
        the closing thread)."""
        if self._renderers is not None:
            self._renderers.release()

    # -- background stepping -------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Keep the world at the clock in a daemon thread until :meth:`close`. The world may then rest when nothing
        moves (``PhysicsWorld.rest_enabled``): the app's lab is mostly a robot lying still."""
        if self._thread is not None:
            return
        self.world.rest_enabled = True
        self._restart_invalid = True
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="physics-lab", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self.release_renderer()
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def _run(self) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            self.advance_to(self.clock.now())
            self._stop.wait(max(0.0, STEP_INTERVAL_S - (time.monotonic() - started)))

    def real_time_factor(self) -> float:
        """Simulated seconds stepped per simulated second of clock so far (1.0 = kept up; < 1: ``lagged_s``
        skipped)."""
        elapsed = self.clock.now() - self._time0_s
        return 1.0 if elapsed <= 0 else max(0.0, 1.0 - self.world.lagged_s / elapsed)
