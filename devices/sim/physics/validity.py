"""Is the world still physics? The checks a MuJoCo world runs after each batch of steps, and MuJoCo's log.

A simulation that blew up must not be recorded as a run: MuJoCo, left to itself, resets a state whose acceleration
is NaN or huge ("Nan, Inf or huge value in QACC") back to the model's start and carries on, and the body then
"moves" metres in one tick. :class:`ValidityMonitor` (one per :class:`devices.sim.physics.world.PhysicsWorld`,
which sets ``mjDSBL_AUTORESET`` so nothing is reset behind its back) checks, after every batch of steps:

- **MuJoCo's own warnings** (``mjData.warning``): a NaN, Inf or huge value in QPOS, QVEL or QACC, the contact or
  constraint buffer full (contacts silently dropped), a bad inertia or control; and any non-finite state;
- **penetration** deeper than the contact model resolves (:data:`MAX_PENETRATION_M`, see there);
- **speed**: a body point faster than the servos and gravity can move it (:func:`speed_limit_m_s`);
- **energy from nowhere**: the robot's mechanical energy (kinetic, gravity, the shells' springs, and the tail
  load's potential, a constant force being conservative) rising by more than the torque-on servos' peak power can
  have given it since the lowest it was (:data:`ENERGY_MARGIN_J`).

The first check that fails gives an :class:`InvalidState` (what, and when on the world's clock). MuJoCo's log —
the text it writes to standard output and to a ``MUJOCO_LOG.TXT`` in the working folder by default — goes to this
module's logger instead (:func:`route_mujoco_log`; its errors already raise ``mujoco.FatalError`` in Python and write
no file).

Pure computation on the world's model and data: called under the world's lock, from whichever thread steps it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from devices.scene import RESOLVED_DEPTH_M, RESOLVED_ONSETS

log = logging.getLogger(__name__)

# MuJoCo's warnings that mean the state is not physics any more (mjWARN_VGEOMFULL is the renderer's, not the state's).
# In the order MuJoCo checks them within a step (positions and velocities before the step, accelerations after), so
# that of the warnings one bad step raises, the first named is the cause (a NaN velocity makes the acceleration NaN).
_WARNINGS: tuple[tuple[mujoco.mjtWarning, str], ...] = (
    (mujoco.mjtWarning.mjWARN_BADQPOS, "bad QPOS (NaN, Inf or huge position)"),
    (mujoco.mjtWarning.mjWARN_BADQVEL, "bad QVEL (NaN, Inf or huge velocity)"),
    (mujoco.mjtWarning.mjWARN_BADQACC, "bad QACC (NaN, Inf or huge acceleration)"),
    (mujoco.mjtWarning.mjWARN_CONTACTFULL, "contact buffer full (contacts dropped)"),
    (mujoco.mjtWarning.mjWARN_CNSTRFULL, "constraint buffer full (constraints dropped)"),
    (mujoco.mjtWarning.mjWARN_INERTIA, "inertia matrix not positive definite"),
    (mujoco.mjtWarning.mjWARN_BADCTRL, "bad control (NaN, Inf or huge)"),
)
_PER_DOF = {mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQPOS}

# Penetration. MuJoCo's soft contact (solref 10 ms critically damped, solimp 0.9-0.95 over 1 mm: model.build_mjcf)
# lets a loaded shell sink until the impedance-weighted spring balances the load: a segment resting under its own
# weight sinks ~0.1 mm, the whole robot's weight on one shell well under 1 mm (measured: 0.9 mm at most lying and
# moving on flat ground). A landing sinks deeper for a moment — a critically damped contact meeting a shell at v
# sinks about v·τ/e (τ = 10 ms): 4.6 mm at the 1.25 m/s of an 8 cm drop, 8.7 mm measured for a body pulled off
# the paper's obstacle by a tail load — and gives it back within a few τ. So a contact is not resolving the geometry
# when it stays deeper than MAX_PENETRATION_M (several times the resting depth, more than the shell's 3 mm travel
# before it bottoms out on the housing) for MAX_PENETRATION_S (5 τ, when a landing's depth is long gone), or goes
# deeper than half the shell's radius at any moment (the capsule's axis on its way through the surface). A scene's
# contact_onset_m (force growing from zero over that depth) sinks a shell deeper by design: the lasting limit is then
# at least MAX_PENETRATION_ONSETS times it.
MAX_PENETRATION_M = RESOLVED_DEPTH_M  # 5 mm: a scene's features are at least this thick (devices.scene)
MAX_PENETRATION_S = 0.05
MAX_PENETRATION_ONSETS = RESOLVED_ONSETS
PENETRATION_LIMIT_RADII = 0.5

# Energy: the robot's mechanical energy may rise by what the torque-on servos give, at most each XM430's peak power on
# its torque-speed line (stall torque × no-load speed / 4: 4.9 W), and by this much more: what the soft contacts and
# the shells' travel stops hold as compression (not counted in MuJoCo's energy; ~0.05 J for 100 N over 1 mm) and
# the integrator's rounding, with a wide margin. A blow-up gains kilojoules in a step.
ENERGY_MARGIN_J = 1.0

# Speed: the fastest a body point can go is a servo swinging the whole body at its no-load speed plus a fall from the
# top of the scene's tallest obstacle and a body length above it, plus the tail load dragging the whole robot a body
# length with nothing holding it — a sum of worst cases that no gait or fall reaches (the gaits' fastest point moves
# under 0.1 m/s, a fall off the paper's obstacle at 0.3-1.5 m/s: app.core.physics_check.FAST_M_S).


@dataclass(frozen=True)
class InvalidState:
    """Why a world's state stopped being physics: ``what`` happened, at ``time_s`` on the world's clock (s)."""

    what: str
    time_s: float

    def describe(self, clock_zero_s: float = 0.0) -> str:
        """One line: what, and when on a clock that reads 0 at the world's ``clock_zero_s``."""
        return f"{self.what} at t={self.time_s - clock_zero_s:.2f} s"


def route_mujoco_log() -> None:
    """MuJoCo's warnings go to this module's logger (never to standard output or a ``MUJOCO_LOG.TXT`` in the
    working folder). Process-wide; the world installs it on import."""
    mujoco.set_mju_user_warning(_mujoco_warning)


def _mujoco_warning(text: str) -> None:
    log.warning("MuJoCo: %s", text)


def speed_limit_m_s(body_length_m: float, top_m: float, no_load_speed_rad_s: float, mass_kg: float,
                    tail_load_n: float, gravity_m_s2: float) -> float:
    """The fastest (m/s) any point of the robot can physically move (see the comment above :class:`InvalidState`)."""
    swing = no_load_speed_rad_s * body_length_m
    fall = math.sqrt(2.0 * gravity_m_s2 * (top_m + body_length_m))
    drag = math.sqrt(2.0 * abs(tail_load_n) * body_length_m / mass_kg)
    return swing + fall + drag


class ValidityMonitor:
    """The checks of the module docstring on one world's ``model`` and ``data``. ``bodies``: the robot's body ids
    whose origins are its points (head and segments); ``tail_body``: the body the tail load pulls."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, bodies: np.ndarray, tail_body: int, *,
                 speed_limit_m_s: float, servo_peak_w: float, penetration_m: float, shell_radius_m: float) -> None:
        self._model, self._data = model, data
        self._bodies = np.asarray(bodies)
        self._tail = int(tail_body)
        self.speed_limit_m_s = speed_limit_m_s
        self.servo_peak_w = servo_peak_w
        self.energy_margin_j = ENERGY_MARGIN_J
        self.penetration_m = penetration_m  # deeper than this for MAX_PENETRATION_S: not resolved
        self.deepest_m = PENETRATION_LIMIT_RADII * shell_radius_m  # deeper than this at any moment: not resolved
        self._deep_since = math.inf
        self._counts = data.warning.number  # a live view of MuJoCo's warning counts, by mjtWarning
        self._watched = np.array([int(kind) for kind, _ in _WARNINGS])
        self._seen = np.zeros(len(_WARNINGS), dtype=np.int64)
        self._points: np.ndarray | None = None
        self._points_time = 0.0
        self._floor_j = math.inf  # the lowest energy less the servos' allowance so far
        self._allowance_j = 0.0  # what the torque-on servos could have given since the last rebase
        # the largest of each checked quantity so far, for calibrating the limits against runs that are fine
        self.peak_depth_m = 0.0
        self.peak_speed_m_s = 0.0
        self.peak_energy_gain_j = 0.0

    def rebase(self) -> None:
        """Forget the reference points and energy: the state was set from outside (placed, posed by hand, a load
        changed), which is no motion of the physics."""
        self._points = None
        self._deep_since = math.inf
        self._floor_j = math.inf
        self._allowance_j = 0.0
        self._seen = self._counts[self._watched].astype(np.int64)

    def check(self, stepped_s: float, servos_on: int, tail_load_n: float, energy_checked: bool) -> str | None:
        """After a batch of ``stepped_s`` seconds with ``servos_on`` servos powered: what is wrong (one phrase) or
        None. ``energy_checked`` False (a hand or an external torque at work: energy from outside) skips the energy
        check and restarts its bookkeeping."""
        data, model = self._data, self._model
        counts = self._counts[self._watched]
        if np.any(counts > self._seen):
            k = int(np.flatnonzero(counts > self._seen)[0])  # the first in MuJoCo's order within a step
            self._seen = counts.astype(np.int64)
            kind, text = _WARNINGS[k]
            info = int(data.warning[int(kind)].lastinfo)
            if kind in _PER_DOF:
                return f"MuJoCo: {text} at DOF {info}{_dof_name(model, info)}"
            return f"MuJoCo: {text} ({info})"
        if not math.isfinite(float(data.qpos.sum()) + float(data.qvel.sum())):  # a NaN or Inf anywhere sums to one
            where = "qvel" if not np.all(np.isfinite(data.qvel)) else "qpos" if not np.all(np.isfinite(data.qpos)) \
                else "qpos and qvel: their sum overflows"
            return f"a non-finite state (NaN or Inf in {where})"
        now = float(data.time)
        depth = -float(np.min(data.contact.dist[:data.ncon])) if data.ncon else 0.0
        self.peak_depth_m = max(self.peak_depth_m, depth)
        if depth > self.deepest_m:
            return (f"a contact {depth * 1000:.1f} mm deep, deeper than the contact model resolves (half the shell's "
                    f"radius, {self.deepest_m * 1000:.0f} mm)")
        if depth <= self.penetration_m:
            self._deep_since = math.inf
        else:
            self._deep_since = min(self._deep_since, now - stepped_s)
            if now - self._deep_since >= MAX_PENETRATION_S - 1e-9:
                return (f"a contact {depth * 1000:.1f} mm deep, deeper than {self.penetration_m * 1000:.1f} mm for "
                        f"{now - self._deep_since:.2f} s: not resolved by the contact model (a landing's depth "
                        f"lasts a few of its 10 ms)")
        points = data.xpos[self._bodies]
        if self._points is not None and now > self._points_time:
            speed = float(np.max(np.linalg.norm(points - self._points, axis=1))) / (now - self._points_time)
            self.peak_speed_m_s = max(self.peak_speed_m_s, speed)
            if speed > self.speed_limit_m_s:
                return (f"a body point at {speed:.3g} m/s, faster than the physics allows "
                        f"({self.speed_limit_m_s:.1f} m/s: servos, a fall and the tail load together)")
        self._points = points.copy()
        self._points_time = now
        if not energy_checked:
            self._floor_j = math.inf
            self._allowance_j = 0.0
            return None
        mujoco.mj_energyPos(model, data)
        mujoco.mj_energyVel(model, data)
        # the tail load, a constant force -F x at the tail's centre of mass, has the potential F·x
        energy = float(data.energy[0] + data.energy[1]) + tail_load_n * float(data.xipos[self._tail, 0])
        self._allowance_j += servos_on * self.servo_peak_w * stepped_s
        level = energy - self._allowance_j
        if math.isfinite(self._floor_j):
            self.peak_energy_gain_j = max(self.peak_energy_gain_j, level - self._floor_j)
        if level > self._floor_j + self.energy_margin_j:
            return (f"energy from nowhere: +{level - self._floor_j:.3g} J more than the powered servos "
                    f"({servos_on} × {self.servo_peak_w:.1f} W at most) and the tail load can give")
        self._floor_j = min(self._floor_j, level)
        return None


def _dof_name(model: mujoco.MjModel, dof: int) -> str:
    if not 0 <= dof < model.nv:
        return ""
    joint = model.joint(int(model.dof_jntid[dof]))
    return f" (joint {joint.name})" if joint.name else ""
