"""The calibration rig: a position-controlled servo winds a cable through a spring onto a probe (SPEC §2).

Past the angle ``θ_contact`` where the cable goes taut the probe presses the sensor with ``F = k·r·(θ − θ_contact)``,
so a force is commanded by a position: ``θ = θ_contact + F/(k·r)``. :meth:`CalibrationRig.find_contact` finds
``θ_contact`` from the servo's present current, which rises with the cable tension: it winds in small steps from a
slack position, averages the current once the wheel reports rest after each step, and fits a hinge (flat, then a
line) to all the steps; the knee is the contact. The knee's standard error comes with it, and a contact the current
cannot place to ``CONTACT_MAX_UNCERTAINTY_N`` of probe force is refused, not guessed.

Threads: like :class:`devices.servo_chain.ServoChain`, a rig is NOT thread-safe; one thread owns it. Every call
blocks until the servo has settled (a few tens of ms per step on the bench), except :meth:`CalibrationRig.start_force`
and :meth:`CalibrationRig.start_ramp`, which only send the goal (so the loading ramp can be sampled). ``interrupt``
(a callable any thread may make true) ends a wait early with :class:`RigInterrupted`; :meth:`CalibrationRig.release` ignores it, so a stopped run can
still take the load off.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from devices import control_table as ct
from devices.config import RigConfig, RobotConfig
from devices.errors import DeviceError, RigForceError, RigInterrupted
from devices.servo_chain import ServoChain

DEFAULT_MAX_FORCE_N = RigConfig().max_force_n  # 8 N: above the paper's 5.25 N, well below the spring's range
TORQUE_CONSTANT_NM_PER_A = 1.78  # XM430-W350 at 12 V (4.1 N·m stall at 2.3 A): only used to scale thresholds
ANGLE_LIMIT_RAD = math.pi - 0.01
SETTLE_TOLERANCE_RAD = 3 * 2 * math.pi / 4096  # three ticks
SETTLE_TIMEOUT_S = 5.0
CURRENT_SAMPLES = 16  # reads averaged per step; the current's last bits are noisy (±2 LSB ≈ ±0.5 N here)
# A read while the wheel still moves carries the acceleration's torque (tens of mA: several newtons); the current is
# only read once the servo reports zero velocity this many reads in a row, and moving reads are dropped.
REST_READS = 2
REST_READ_LIMIT = 200  # reads waited for rest at most (~0.2 s at 1 Mbps) before the step is taken as it is
# The contact is refused (not guessed) when the current's noise leaves it this uncertain (one standard error, in
# newtons of probe force: k·r × the angle's error).
CONTACT_MAX_UNCERTAINTY_N = 0.15
CONTACT_MIN_LOADED_STEPS = 5
# The loaded steps' current, in newtons of cable tension (nominal torque constant), against the spring's k·r: gear
# friction can hold part of the load (a lower rate); nothing makes the rate several times what the spring pulls.
CONTACT_SLOPE_RANGE = (0.2, 3.0)
# The rig check: at rest the servo's current is the cable's tension × r / the torque constant (≈ 11 mA per newton on
# the default rig). Above this multiple of the current the rig's maximum force would draw, something other than the
# spring holds the wheel (a jammed probe, a caught cable).
CHECK_CURRENT_MARGIN = 2.0
PROFILE_VELOCITY_MAX = 32767  # the register's range; the servo caps it at its Velocity Limit


@dataclass(frozen=True)
class RigCheckLine:
    """One line of the rig check: what was checked, passed or not, and what was seen (or why it failed)."""

    name: str
    ok: bool
    detail: str


class CalibrationRig:
    """Drives the calibration rig of ``rig``; see the module docstring."""

    def __init__(self, rig: RigConfig, max_force_n: float | None = None, *,
                 search_step_rad: float = 0.02, unwind_rad: float = 0.4, contact_threshold_n: float = 0.5,
                 fit_until_n: float = 3.0, interrupt: Callable[[], bool] | None = None) -> None:
        self.config = rig
        self.interrupt = interrupt
        self.max_force_n = float(rig.max_force_n if max_force_n is None else max_force_n)
        self.search_step_rad = search_step_rad
        self.unwind_rad = unwind_rad
        self.contact_threshold_n = contact_threshold_n
        self.fit_until_n = fit_until_n
        self.contact_rad: float | None = None
        self._slack_rad: float | None = None  # where the contact search started (cable slack)
        self._profile_lsb = 0  # the Profile Velocity this driver last wrote (0: never, or back to full speed)
        self._chain = ServoChain(RobotConfig(
            port=rig.port, baud=rig.baud, joint_ids=(rig.servo_id,), axes=("pitch",), signs=(1,),
            zero_offsets_rad=(0.0,), joint_min_rad=(-ANGLE_LIMIT_RAD,), joint_max_rad=(ANGLE_LIMIT_RAD,),
            max_joint_speed_rad_s=2.0), device="rig")

    @property
    def newtons_per_rad(self) -> float:
        """``k·r``: force per radian of winding past the contact."""
        return self.config.spring_k_n_per_m * self.config.wheel_radius_m

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def open(self) -> None:
        """Open the rig's port, check the servo answers and is an XM430-W350, and turn its torque on."""
        self._chain.open()
        try:
            self._chain.check_models()
            self._chain.set_torque(True)
        except BaseException:
            self._chain.close()
            raise

    def close(self) -> None:
        """Close the port (the servo keeps holding its position)."""
        self._chain.close()

    def check(self) -> list[RigCheckLine]:
        """The rig check before a run, one line per step, each with what was seen or why it failed: the port opens,
        the rig servo answers and is an XM430-W350, its torque can be enabled, its position is inside its range with
        no hardware error and its current at rest is no more than :data:`CHECK_CURRENT_MARGIN` × what the spring
        draws at the rig's maximum force. A step that fails
        stops the check; the steps after it read "not tried". Leaves the port closed (torque on: the servo holds).
        Never raises for the rig's own faults."""
        sid = self.config.servo_id
        names = ("port opens", f"rig servo {sid} answers (XM430-W350)", "torque can be enabled",
                 "position and current sane")
        lines: list[RigCheckLine] = []

        def fail(exc: BaseException) -> list[RigCheckLine]:
            lines.append(RigCheckLine(names[len(lines)], False, str(exc) or type(exc).__name__))
            lines.extend(RigCheckLine(n, False, "not tried: an earlier step failed") for n in names[len(lines):])
            return lines

        try:
            self._chain.open()
        except (DeviceError, OSError, ValueError) as exc:
            return fail(exc)
        try:
            lines.append(RigCheckLine(names[0], True, f"{self.config.port} at {self.config.baud} baud"))
            try:
                info = self._chain.ping(sid)
                self._chain.check_models()
            except (DeviceError, OSError, ValueError) as exc:
                return fail(exc)
            lines.append(RigCheckLine(names[1], True, f"{info.model_name}, firmware {info.firmware}"))
            try:
                self._chain.set_torque(True)
            except (DeviceError, OSError, ValueError) as exc:
                return fail(exc)
            lines.append(RigCheckLine(names[2], True, "torque on: the servo holds its position"))
            try:
                currents = [float(self._chain.read_state().current_ma[0]) for _ in range(CURRENT_SAMPLES)]
                position = self.position_rad()
            except (DeviceError, OSError, ValueError) as exc:
                return fail(exc)
            current = float(np.median(currents))
            limit_ma = (CHECK_CURRENT_MARGIN * self.max_force_n * self.config.wheel_radius_m
                        / TORQUE_CONSTANT_NM_PER_A * 1000.0)
            seen = f"at {position:+.3f} rad, {current:.0f} mA at rest"
            if not abs(position) <= ANGLE_LIMIT_RAD:
                lines.append(RigCheckLine(names[3], False, f"{seen}: outside the servo's range (±{ANGLE_LIMIT_RAD:.2f} "
                                                           "rad): re-spool the cable or check the servo's zero"))
            elif abs(current) > limit_ma:
                lines.append(RigCheckLine(names[3], False, f"{seen}: above {limit_ma:.0f} mA (twice what the spring "
                                                           f"pulls at {self.max_force_n:g} N), something holds the "
                                                           "wheel (a jammed probe, a caught cable): free it"))
            else:
                lines.append(RigCheckLine(names[3], True, seen))
            return lines
        finally:
            self._chain.close()

    def __enter__(self) -> CalibrationRig:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- motion ------------------------------------------------------------------------------------------------
    def position_rad(self) -> float:
        return float(self._chain.read_state().position_rad[0])

    def move_to(self, angle_rad: float, timeout_s: float = SETTLE_TIMEOUT_S, *, interruptible: bool = True) -> float:
        """Command ``angle_rad`` and wait until the servo is there (rad); returns the settled position.

        Raises :class:`RigInterrupted` when ``interrupt()`` turns true during the wait (unless ``interruptible`` is
        False); the servo then holds wherever it is going.
        """
        self._full_speed()
        sent = float(self._chain.write_goals(np.array([angle_rad]))[0])
        deadline = time.monotonic() + timeout_s
        while True:
            if interruptible and self.interrupt is not None and self.interrupt():
                raise RigInterrupted(f"rig servo {self.config.servo_id}: move to {sent:.3f} rad interrupted")
            state = self._chain.read_state()
            position = float(state.position_rad[0])
            if abs(position - sent) <= SETTLE_TOLERANCE_RAD and abs(float(state.velocity_rad_s[0])) < 0.05:
                return position
            if time.monotonic() > deadline:
                raise DeviceError(f"rig servo {self.config.servo_id} did not reach {sent:.3f} rad within "
                                  f"{timeout_s:g} s (at {position:.3f} rad): check the cable is not jammed")

    def position_at_rest_rad(self) -> float:
        """The position (rad) once the servo reports zero velocity ``REST_READS`` reads in a row (``move_to`` returns
        within three ticks of the goal, while the wheel may still creep the last ticks): what an instrument read
        next (a dial gauge on the probe) sees. Raises :class:`DeviceError` if it never comes to rest."""
        still = 0
        for _ in range(REST_READ_LIMIT):
            state = self._chain.read_state()
            still = still + 1 if state.velocity_rad_s[0] == 0.0 else 0
            if still >= REST_READS:
                return float(state.position_rad[0])
        raise DeviceError(f"rig servo {self.config.servo_id} does not come to rest (its velocity keeps reading "
                          "non-zero): check that the wheel turns freely and the cable is not caught")

    def _current_at_rest_ma(self) -> float:
        """Present current at rest (mA): read once the servo reports zero velocity ``REST_READS`` times in a row,
        reads that still move dropped, then a trimmed mean. It depends on how many reads are made, not on when they
        are made: a starved thread or a slow bus reads the same quantity."""
        still = 0
        for _ in range(REST_READ_LIMIT):
            still = still + 1 if self._chain.read_state().velocity_rad_s[0] == 0.0 else 0
            if still >= REST_READS:
                break
        samples: list[float] = []
        for _ in range(2 * CURRENT_SAMPLES):
            state = self._chain.read_state()
            if state.velocity_rad_s[0] == 0.0:
                samples.append(float(state.current_ma[0]))
                if len(samples) == CURRENT_SAMPLES:
                    break
        if len(samples) < CURRENT_SAMPLES // 2:
            raise DeviceError(f"rig servo {self.config.servo_id} does not come to rest at its goal (its velocity "
                              "keeps reading non-zero): check that the wheel turns freely and the cable is not caught")
        ordered = np.sort(samples)
        trim = len(ordered) // 4
        return float(ordered[trim:len(ordered) - trim].mean())

    def find_contact(self) -> float:
        """Find ``θ_contact`` (rad), store it, leave the probe just touching (zero force) and return it."""
        ma_per_n = self.config.wheel_radius_m / TORQUE_CONSTANT_NM_PER_A * 1000.0
        start = max(-ANGLE_LIMIT_RAD, self.position_rad() - self.unwind_rad)
        self._slack_rad = start
        self.move_to(start)
        baseline_ma = self._current_at_rest_ma()
        angles: list[float] = []
        excess_n: list[float] = []
        angle = start
        while True:
            angle += self.search_step_rad
            if angle > ANGLE_LIMIT_RAD:
                self.move_to(start)
                raise DeviceError(f"rig servo {self.config.servo_id}: no contact found up to {ANGLE_LIMIT_RAD:.2f} rad; "
                                  "check that the cable is attached and the probe sits on the sensor")
            position = self.move_to(angle)
            force_n = (self._current_at_rest_ma() - baseline_ma) / ma_per_n
            angles.append(position)
            excess_n.append(force_n)
            # Two steps in a row: one noisy reading must not end the search.
            if len(excess_n) >= 2 and min(excess_n[-2:]) >= self.fit_until_n:
                break
        fit = _hinge_fit_contact(np.array(angles), np.array(excess_n))
        if fit is None:
            self.move_to(start)
            raise DeviceError(f"rig servo {self.config.servo_id}: the current did not rise with winding; check "
                              "the spring and the cable")
        reason = self._contact_doubt(fit)
        if reason:
            self.move_to(start)
            raise DeviceError(
                f"rig servo {self.config.servo_id}: the contact is too uncertain to calibrate on ({reason}): the "
                "servo's current is too noisy or does not rise in a line. Check that the cable runs freely over the "
                "spring and nothing rubs on the wheel, then search again")
        contact = fit.contact_rad
        self.contact_rad = contact
        self.move_to(self.contact_rad)
        return self.contact_rad

    def _contact_doubt(self, fit: _HingeFit) -> str:
        """Why the fitted contact cannot be trusted ("" if it can): its error, too few loaded steps, or a current
        rising at a rate the spring cannot explain (noise that ended the search, not the cable)."""
        newtons_per_rad = self.newtons_per_rad
        if fit.error_rad * newtons_per_rad > CONTACT_MAX_UNCERTAINTY_N:
            return (f"±{fit.error_rad:.3f} rad = ±{fit.error_rad * newtons_per_rad:.2f} N of probe force; at most "
                    f"±{CONTACT_MAX_UNCERTAINTY_N:g} N")
        if fit.n_loaded < CONTACT_MIN_LOADED_STEPS:
            return f"{fit.n_loaded} loaded steps; at least {CONTACT_MIN_LOADED_STEPS}"
        ratio = fit.slope_n_per_rad / newtons_per_rad
        if not CONTACT_SLOPE_RANGE[0] <= ratio <= CONTACT_SLOPE_RANGE[1]:
            return (f"the current rose {ratio:.1f}× as fast per radian as the spring's {newtons_per_rad:.2f} N/rad "
                    f"explains; {CONTACT_SLOPE_RANGE[0]:g}-{CONTACT_SLOPE_RANGE[1]:g}× is plausible")
        return ""

    def command_force(self, force_n: float) -> float:
        """Apply ``force_n`` (N): move to ``θ_contact + F/(k·r)`` and wait there. Returns the angle (rad).

        Refuses (:class:`RigForceError`) a negative force, one above ``max_force_n``, or one past the servo's range.
        """
        return self.move_to(self._target_for(force_n))

    def start_force(self, force_n: float) -> float:
        """Send the goal for ``force_n`` (N) and return at once with the goal angle (rad); the servo ramps there
        while the caller samples :meth:`applied_force_n`. Same refusals as :meth:`command_force`."""
        target = self._target_for(force_n)
        self._full_speed()
        return float(self._chain.write_goals(np.array([target]))[0])

    def start_ramp(self, force_n: float, duration_s: float) -> float:
        """Load to ``force_n`` (N) at a steady rate that takes ``duration_s`` from the contact, paced by the servo
        itself, and return at once with the goal angle (rad); the caller samples :meth:`applied_force_n`.

        The servo's Profile Velocity is set to the winding past the contact over ``duration_s`` (at least one unit,
        0.229 rpm) and the goal sent once: the servo keeps the ramp however late the computer's next command would
        be (a ramp paced by one goal per sample stalls wherever a busy computer's thread does, while the record
        draws a straight line over the stall). From below the contact the slack is wound at the same speed first.
        The next goal of any other command goes at full speed again. Same refusals as :meth:`command_force`; a
        ``duration_s`` of 0 or less is :meth:`start_force`."""
        target = self._target_for(force_n)
        assert self.contact_rad is not None  # _target_for refused otherwise
        if not duration_s > 0:
            return self.start_force(force_n)
        speed_rad_s = (target - self.contact_rad) / duration_s
        lsb = int(min(PROFILE_VELOCITY_MAX, max(1, round(speed_rad_s / ct.RAD_S_PER_VELOCITY_LSB))))
        self._set_profile_velocity(lsb)
        return float(self._chain.write_goals(np.array([target]))[0])

    def _set_profile_velocity(self, lsb: int) -> None:
        if lsb != self._profile_lsb:
            self._chain.write_item(self.config.servo_id, "Profile Velocity", lsb)
            self._profile_lsb = lsb

    def _full_speed(self) -> None:
        """Undo a :meth:`start_ramp`'s Profile Velocity before the next goal (0: the servo's own velocity limit)."""
        if self._profile_lsb:
            self._set_profile_velocity(0)

    def _target_for(self, force_n: float) -> float:
        if self.contact_rad is None:
            raise RuntimeError("the rig does not know where the probe touches the sensor: run find_contact() first")
        if not math.isfinite(force_n) or force_n < 0:
            raise RigForceError(f"cannot apply {force_n} N: the rig only pushes (0 N or more)")
        if force_n > self.max_force_n:
            raise RigForceError(f"refusing {force_n:g} N: beyond the rig's safe maximum of {self.max_force_n:g} N "
                                "(protects the sensor and the spring); raise max_force_n only if the hardware allows")
        target = self.contact_rad + force_n / self.newtons_per_rad
        if target > ANGLE_LIMIT_RAD:
            reachable = (ANGLE_LIMIT_RAD - self.contact_rad) * self.newtons_per_rad
            raise RigForceError(f"cannot apply {force_n:g} N: the servo would pass its range (at most "
                                f"{reachable:.2f} N from this contact angle); re-spool the cable")
        return target

    def reachable_force_n(self) -> float:
        """The largest force the servo's range allows from the contact found (N), or from the most wound contact the
        spring's travel allows before a contact is known."""
        contact = self.contact_rad if self.contact_rad is not None else ANGLE_LIMIT_RAD / 2
        return max(0.0, (ANGLE_LIMIT_RAD - contact) * self.newtons_per_rad)

    def applied_force_n(self) -> float:
        """The force now (N) from the present position: ``k·r·(θ − θ_contact)``, 0 while the cable is slack."""
        if self.contact_rad is None:
            raise RuntimeError("the rig does not know where the probe touches the sensor: run find_contact() first")
        return max(0.0, self.newtons_per_rad * (self.position_rad() - self.contact_rad))

    def release(self) -> None:
        """Take the load off: unwind to just before the contact, or, if a contact search was cut short, back to
        where it started. Not interruptible (it is what a stop does)."""
        if self.contact_rad is not None:
            self.move_to(max(-ANGLE_LIMIT_RAD, self.contact_rad - 0.1), interruptible=False)
        elif self._slack_rad is not None:
            self.move_to(self._slack_rad, interruptible=False)


@dataclass(frozen=True)
class _HingeFit:
    contact_rad: float  # the knee
    error_rad: float  # its standard error
    slope_n_per_rad: float  # the loaded line's rate
    n_loaded: int  # steps past the knee


def _hinge_fit_contact(angles_rad: np.ndarray, excess_n: np.ndarray) -> _HingeFit | None:
    """The knee of ``F = b + s·max(0, θ − θ_c)`` fitted by least squares (grid over θ_c, linear in b and s), with
    its standard error, the rate ``s`` and how many steps lie past the knee.

    Fitting the flat part and the loaded part together uses every step, so one noisy step cannot drag the contact
    the way a line through "loaded" steps picked by a threshold would. The error is the x-intercept's of the loaded
    line against the flat level: ``σ/s · √(1/n_flat + 1/n_loaded + (θ̄_loaded − θ_c)²/Sxx_loaded)``. ``None`` if the
    load does not rise (no rising knee with two steps past it and one before).
    """
    best_sse, best = math.inf, None
    for knee in np.linspace(angles_rad[0], angles_rad[-1], 4 * len(angles_rad)):
        design = np.column_stack([np.ones_like(angles_rad), np.maximum(0.0, angles_rad - knee)])
        coef, *_ = np.linalg.lstsq(design, excess_n, rcond=None)
        if coef[1] <= 0:
            continue
        sse = float(np.sum((design @ coef - excess_n) ** 2))
        if sse < best_sse:
            best_sse, best = sse, (float(knee), float(coef[1]))
    if best is None:
        return None
    knee, slope = best
    loaded = angles_rad[angles_rad > knee]
    n_loaded, n_flat = len(loaded), len(angles_rad) - len(loaded)
    if n_loaded < 2 or n_flat < 1 or len(angles_rad) < 4:
        return None
    sigma = math.sqrt(best_sse / (len(angles_rad) - 3))
    sxx = float(np.sum((loaded - loaded.mean()) ** 2))
    se = sigma / slope * math.sqrt(1.0 / n_flat + 1.0 / n_loaded + (float(loaded.mean()) - knee) ** 2 / sxx)
    return _HingeFit(knee, se, slope, n_loaded)
