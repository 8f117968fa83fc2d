"""The simulated calibration rig: one rig servo winding a cable through a spring onto a probe that presses a sensor.

The servo is a one-servo :class:`~devices.sim.dxl_chain.VirtualChain` (``.chain``, the wire end of device ``rig``),
so :class:`devices.rig.CalibrationRig` drives it through dynamixel-sdk exactly as on the bench. While the cable is
slack nothing happens; past the (seeded, unknown to the driver) contact angle ``θ_c`` the spring stretches and the
probe presses the sensor with ``F = k·r·(θ − θ_c)`` (SPEC §2). The cable tension loads the servo (torque ``F·r``),
so its present current rises with the force — which is how the driver finds the contact.

The sensor under the probe creeps (standard linear solid, the same physics as the simulated board's sensors);
:meth:`VirtualRig.sensor_conductance_s` gives its conductance. Thread-safe like the chain (one lock).

By default the sensor lies on something rigid: the probe does not move once the cable is taut. With a segment's
compliant shell under it (:meth:`VirtualRig.mount_shell`, a :class:`ShellSpecimen`) the probe travels with the
shell's deflection ``d`` (m, from its rest with the cable slack): the spring stretches by ``r·(θ − θ_c) − d`` only,
the shell pushes back with ``k_shell·d + c·ḋ`` until it bottoms out after its travel, and a dial gauge on the probe
(its plunger's measuring force ``F_g0 − k_g·d`` pushing the probe toward the shell) reads ``d``
(:meth:`VirtualRig.probe_travel_m`; :class:`devices.sim.gauge.SimDialGauge` gives the gauge's readings). The probe
and the shell's own mass are left out (60 g on ~2000 N/m rings at ~30 Hz, overdamped by the shell's damping: gone
long before a reading).
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from devices.config import RigConfig
from devices.sim.board import SensorBank
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import VirtualChain

CONTACT_ANGLE_RAD = 0.6  # from the servo's centre position; the seeded rig varies it by ±0.1 rad
HISTORY = 4096  # (time, force) records kept: the board may sample a past moment after the rig has moved on


@dataclass(frozen=True)
class ShellSpecimen:
    """A segment's compliant shell under the rig's probe, and the dial gauge on the probe (SI units).

    ``gauge_force_n`` is the gauge plunger's measuring force at the reading taken with the cable slack (it pushes the
    probe toward the shell, so the shell already carries it), ``gauge_rate_n_per_m`` how much that force falls per
    metre the probe travels into the shell (the plunger's spring extending)."""

    stiffness_n_per_m: float
    damping_n_s_per_m: float
    travel_m: float
    gauge_force_n: float = 0.0
    gauge_rate_n_per_m: float = 0.0

    def __post_init__(self) -> None:
        if not (self.stiffness_n_per_m > 0 and self.damping_n_s_per_m >= 0 and self.travel_m > 0
                and self.gauge_force_n >= 0 and self.gauge_rate_n_per_m >= 0):
            raise ValueError(f"a shell specimen needs a positive stiffness and travel and no negative damping or "
                             f"gauge force: {self}")

    @property
    def preload_travel_m(self) -> float:
        """How far the gauge's measuring force alone has pushed the shell in (m), at most its travel."""
        return min(self.travel_m, self.gauge_force_n / self.stiffness_n_per_m)


class _RigChain(VirtualChain):
    """The rig's servo: before every exchange on the wire, the spring's pull is applied as the servo's load."""

    def __init__(self, rig: VirtualRig, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._rig = rig

    def host_write(self, data: bytes, now_s: float) -> None:
        self._rig.update_load()
        super().host_write(data, now_s)

    def host_read(self, now_s: float) -> bytes:
        self._rig.update_load()
        return super().host_read(now_s)


class VirtualRig:
    """A simulated calibration rig; see the module docstring."""

    def __init__(self, rig: RigConfig, clock: SimClock, seed: int = 0) -> None:
        self.config = rig
        self.clock = clock
        rng = np.random.default_rng(seed)
        self.contact_angle_rad = CONTACT_ANGLE_RAD + float(rng.uniform(-0.1, 0.1))
        self._lock = threading.RLock()
        self.chain: VirtualChain = _RigChain(self, ids=(rig.servo_id,), baud=rig.baud, clock=clock,
                                             seed=int(rng.integers(2**31)))
        self.sensor = SensorBank.create(1, rng)
        self._snapped = False
        self._torque_on = False
        self._jam_nm = 0.0  # extra load torque of a jam fault (N·m)
        self._shell: ShellSpecimen | None = None  # None: the sensor lies on something rigid (the default rig)
        self._travel_m = 0.0  # the probe's travel into the shell from its slack rest (m)
        self._travel_time_s = clock.now()
        self._history_t: deque[float] = deque(maxlen=HISTORY)
        self._history_f: deque[float] = deque(maxlen=HISTORY)

    def jam(self, torque_nm: float = 0.5) -> None:
        """Fault: something holds the wheel (a jammed probe, a cable caught): an extra load torque (N·m) on the
        servo until ``jam(0)``."""
        with self._lock:
            self._jam_nm = float(torque_nm)

    def snap_cable(self, snapped: bool = True) -> None:
        """Fault: the cable snaps (or the probe slips off the sensor): no force reaches the sensor or the servo
        from now on, whatever the servo's angle, until ``snap_cable(False)``."""
        with self._lock:
            self._snapped = snapped

    def mount_shell(self, shell: ShellSpecimen | None) -> None:
        """Put a segment's compliant shell (and a dial gauge on the probe) under the probe; ``None`` puts the sensor
        back on something rigid. Call it with the cable slack: the shell starts at rest."""
        with self._lock:
            self._shell = shell
            self._travel_m = 0.0
            self._travel_time_s = self.clock.now()

    def _cable_m(self, at_s: float | None = None) -> float:
        """How far the cable's end has been wound past the contact angle (m), 0 while slack or snapped: now, or at
        simulated time ``at_s`` (the servo advanced to it)."""
        if self._snapped:
            return 0.0
        theta = float(self.chain.present_positions_at_rad(math.inf if at_s is None else at_s)[0])
        return self.config.wheel_radius_m * max(0.0, theta - self.contact_angle_rad)

    def _advance_shell(self, cable_m: float) -> float:
        """The probe's travel into the shell now (m), the shell's state advanced from its last update with the
        cable held at ``cable_m`` meanwhile: a first-order lag ``c·ḋ = k·max(0, u − d) − (k_shell + k_g)·d`` (the
        gauge's preload balances the shell's at ``d = 0``), clipped where the shell bottoms out."""
        shell = self._shell
        assert shell is not None
        now = self.clock.now()
        dt, self._travel_time_s = max(0.0, now - self._travel_time_s), now
        k, ks = self.config.spring_k_n_per_m, shell.stiffness_n_per_m + shell.gauge_rate_n_per_m
        limit = shell.travel_m - shell.preload_travel_m
        d = self._travel_m
        static = min(limit, k * cable_m / (k + ks))
        tau_taut = shell.damping_n_s_per_m / (k + ks)
        if tau_taut <= 0.0 or dt > 20.0 * tau_taut:
            d = static
        else:
            n = max(1, math.ceil(dt / (0.25 * tau_taut)))
            h = dt / n
            for _ in range(n):  # exact exponential steps, the regime (cable taut or slack) re-chosen each step
                if cable_m > d:
                    d = static + (d - static) * math.exp(-h / tau_taut)
                else:
                    d = d * math.exp(-h * ks / shell.damping_n_s_per_m)
                d = min(d, limit)
        self._travel_m = d
        return d

    def probe_travel_m(self) -> float:
        """The probe's true travel into the shell now (m, 0 with the cable slack); 0 without a shell."""
        with self._lock:
            if self._shell is None:
                return 0.0
            return self._advance_shell(self._cable_m())

    def applied_force_n(self) -> float:
        """The probe's true force on the sensor now (N): ``k·r·max(0, θ − θ_c)`` on a rigid sensor; on a shell,
        the spring's ``k·max(0, r·(θ − θ_c) − d)`` plus the gauge's measuring force."""
        with self._lock:
            cable_m = self._cable_m()
            if self._shell is None:
                return self.config.spring_k_n_per_m * cable_m
            travel = self._advance_shell(cable_m)
            gauge_n = self._shell.gauge_force_n - self._shell.gauge_rate_n_per_m * travel
            return self.config.spring_k_n_per_m * max(0.0, cable_m - travel) + max(0.0, gauge_n)

    def holds_torque(self) -> bool:
        """True while the rig servo's torque is on (a calibration session has the rig), as of the rig's last wire
        exchange — read without the chain's lock, so the board's thread never waits on the rig's bus."""
        return self._torque_on

    def update_load(self) -> None:
        """Apply the cable tension to the servo as a load torque (N·m) and remember the force at this moment.
        Called before each wire exchange."""
        with self._lock:
            force = self.applied_force_n()
            self._load_and_remember(self.clock.now(), force)
            self._torque_on = bool(self.chain.register(self.config.servo_id, "Torque Enable"))

    def _load_and_remember(self, t_s: float, force: float) -> None:
        """The cable's tension at ``t_s`` on the servo as its load torque, and the force in the history (once per
        moment, in time order). Under the rig's lock."""
        self.chain.set_load(self.config.servo_id, force * self.config.wheel_radius_m + self._jam_nm)
        if not self._history_t or t_s > self._history_t[-1]:
            self._history_t.append(t_s)
            self._history_f.append(force)

    def force_at_n(self, t_s: float) -> float:
        """The probe's force (N) at simulated time ``t_s``: interpolated between the moments the rig's force was
        last taken (its wire exchanges, this call's own), after the last of them the servo advanced to ``t_s`` (it
        moves on its own between commands: a ramp at its Profile Velocity; the present angle if never driven). The
        simulated board samples frames lazily, possibly after the rig has moved on; this keeps its readings causal.
        On a compliant shell the force after the last exchange is that exchange's (the shell's state is advanced
        only there). Waits at most for the rig chain's lock (one packet's handling), never for the rig's bus."""
        with self._lock:
            times = self._history_t
            if not times:
                return self.applied_force_n()  # never driven over the wire (posed by hand): the present angle
            if t_s > times[-1] and self._shell is None:
                force = self.config.spring_k_n_per_m * self._cable_m(at_s=t_s)
                self._load_and_remember(t_s, force)
                return force
            if t_s >= times[-1]:
                return self._history_f[-1]
            k = bisect.bisect_right(times, t_s)
            if k == 0:
                return self._history_f[0]
            t0, t1 = times[k - 1], times[k]
            f0, f1 = self._history_f[k - 1], self._history_f[k]
            return f0 + (f1 - f0) * (t_s - t0) / (t1 - t0)

    def sensor_conductance_s(self, t_s: float | None = None) -> float:
        """The sensor's conductance (S) at simulated time ``t_s`` (default: now).

        The creep state advances from the previous call with the force held, so call it regularly (every sample
        of a trial) and with non-decreasing times.
        """
        with self._lock:
            now = self.clock.now() if t_s is None else t_s
            return float(self.sensor.step(now, np.array([self.applied_force_n()]))[0])


class RigBench:
    """The simulated calibration rig alone on its own clock (no robot, no board): what a bench test of a specimen on
    the rig needs behind the ``sim`` rig port (:func:`devices.factory.start_sim_rig_bench`)."""

    def __init__(self, rig: RigConfig, clock: SimClock, seed: int = 0) -> None:
        self.clock = clock
        self.rig = VirtualRig(rig, clock, seed=seed)

    def endpoint(self, device: str) -> VirtualChain:
        if device != "rig":
            raise ValueError(f"the simulated rig bench has only the rig's servo bus, not {device!r}")
        return self.rig.chain

    def close(self) -> None:
        """Nothing runs in the background; here for the same shape as the simulated lab."""
