"""The simulated calibration rig: one rig servo winding a cable through a spring onto a probe that presses a sensor.

The servo is a one-servo :class:`~devices.sim.dxl_chain.VirtualChain` (``.chain``, the wire end of device ``rig``),
so :class:`devices.rig.CalibrationRig` drives it through dynamixel-sdk exactly as on the bench. While the cable is
slack nothing happens; past the (seeded, unknown to the driver) contact angle ``θ_c`` the spring stretches and the
probe presses the sensor with ``F = k·r·(θ − θ_c)`` (SPEC §2). The cable tension loads the servo (torque ``F·r``),
so its present current rises with the force — which is how the driver finds the contact.

The sensor under the probe creeps (standard linear solid, the same physics as the simulated board's sensors);
:meth:`VirtualRig.sensor_conductance_s` gives its conductance. Thread-safe like the chain (one lock).
"""

from __future__ import annotations

import bisect
import threading
from collections import deque

import numpy as np

from devices.config import RigConfig
from devices.sim.board import SensorBank
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import VirtualChain

CONTACT_ANGLE_RAD = 0.6  # from the servo's centre position; the seeded rig varies it by ±0.1 rad
HISTORY = 4096  # (time, force) records kept: the board may sample a past moment after the rig has moved on


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

    def applied_force_n(self) -> float:
        """The probe's true force on the sensor now (N): ``k·r·max(0, θ − θ_c)``."""
        if self._snapped:
            return 0.0
        theta = float(self.chain.present_positions_rad()[0])
        stretch_m = self.config.wheel_radius_m * max(0.0, theta - self.contact_angle_rad)
        return self.config.spring_k_n_per_m * stretch_m

    def holds_torque(self) -> bool:
        """True while the rig servo's torque is on (a calibration session has the rig), as of the rig's last wire
        exchange — read without the chain's lock, so the board's thread never waits on the rig's bus."""
        return self._torque_on

    def update_load(self) -> None:
        """Apply the cable tension to the servo as a load torque (N·m) and remember the force at this moment.
        Called before each wire exchange."""
        with self._lock:
            force = self.applied_force_n()
            self.chain.set_load(self.config.servo_id, force * self.config.wheel_radius_m + self._jam_nm)
            self._torque_on = bool(self.chain.register(self.config.servo_id, "Torque Enable"))
            now = self.clock.now()
            if self._history_t and now <= self._history_t[-1]:
                return
            self._history_t.append(now)
            self._history_f.append(force)

    def force_at_n(self, t_s: float) -> float:
        """The probe's force (N) at simulated time ``t_s``: interpolated between the moments the rig's wire last
        saw (the servo moves only when driven), the last of them after it (the present angle if never driven). The simulated board
        samples frames lazily, possibly after the rig has moved on; this keeps its readings causal."""
        with self._lock:
            times = self._history_t
            if not times:
                return self.applied_force_n()  # never driven over the wire (posed by hand): the present angle
            if t_s >= times[-1]:
                return self._history_f[-1]  # the servo moves only when driven; no wait on the rig's bus
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
