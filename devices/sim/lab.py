"""The built-in simulated lab: a 12-servo Dynamixel chain, the force-sensor board and the calibration rig.

Each device is emulated at the wire (``devices.sim.transport.SimEndpoint``), so the real drivers run against it.
Only ``devices.factory`` creates a :class:`SimLab`; tests build their own (seeded, ``speed`` > 1) and install it there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from devices.config import SIM_MOCAP, LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel
from devices.sim.dxl_chain import VirtualChain
from devices.sim.rig import VirtualRig
from devices.sim.transport import SimEndpoint

if TYPE_CHECKING:  # pragma: no cover
    from devices.sim.mocap_stream import SimulatedMocapStream
    from devices.sim.physics.backend import PhysicsBackend


class SimLab:
    """The simulated robot, board and rig sharing one clock and one random seed."""

    def __init__(self, config: LabConfig | None = None, *, seed: int = 0, speed: float = 1.0) -> None:
        self.config = config or LabConfig()
        self.clock = SimClock(speed)
        rng = np.random.default_rng(seed)
        robot = self.config.robot
        # [lab] physics = "mujoco": the robot is a body in a physics world that the chain drives and the board feels.
        # Without the mujoco package it is the scripted lab, and ``physics_note`` says why (the 3-D tab shows it).
        self.physics: PhysicsBackend | None = None
        self.physics_note = ""
        if self.config.lab.physics == "mujoco":
            try:
                from devices.sim.physics.backend import PhysicsBackend
            except (ImportError, OSError) as exc:
                self.physics_note = (f"the scripted lab stands in for the physics lab ([lab] physics = \"mujoco\"): "
                                     f"mujoco cannot be loaded ({exc}); install it with: pip install mujoco")
            else:
                self.physics = PhysicsBackend(self.config, self.clock)
        self.chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=self.clock,
                                  seed=int(rng.integers(2**31)), physics=self.physics)
        self.contact = ContactModel(self.config, self.chain, seed=int(rng.integers(2**31)))
        board_seed, rig_seed = int(rng.integers(2**31)), int(rng.integers(2**31))
        self.rig = VirtualRig(self.config.rig, self.clock, seed=rig_seed)
        names = self.config.board.channel_names
        self._rig_channel = names.index(self.config.rig.sensor) if self.config.rig.sensor in names else None
        sim = self.config.lab
        nominal = {"e0_pa": sim.sensor_E0_Pa, "e1_pa": sim.sensor_E1_Pa, "tau_s": sim.sensor_tau_s,
                   "area_m2": sim.sensor_area_m2, "spread": sim.sensor_spread}
        self.board = VirtualBoard(self.config.board, self.clock, force_source=self.forces_n, seed=board_seed,
                                  noise_counts=sim.noise_counts, sensor_nominal=nominal)
        if self._rig_channel is not None:
            # The probe covers the whole sensor: the rig's sensor is pressed over the documented area exactly.
            self.board.sensors.area_m2[self._rig_channel] = sim.sensor_area_m2
        self._on_beam = False
        self.mocap_stream: SimulatedMocapStream | None = None
        self.realtime_threads = False  # the lab's own process: its threads ask for the servos' real-time priority

    def forces_n(self, t_s: float) -> np.ndarray:
        """Force on every board channel from the robot's contacts — except the channel of ``rig.sensor`` while the
        rig's servo holds torque: that segment then lies on the rig's beam (the paper's calibration setup, Sec.
        IV-C), so the probe alone loads it — 0 N with the probe lifted, ``k·r·(θ − θ_c)`` once it presses — and
        the robot's weight never does. Moving it onto the beam forgets its creep (it rested before being mounted).
        With the rig's torque off, a probe turned onto the sensor by hand still sets the force it feels."""
        forces = self.physics.forces_n(t_s) if self.physics is not None else self.contact.forces_n(t_s)
        if self._rig_channel is not None:
            probe_n = self.rig.force_at_n(t_s)
            on_beam = self.rig.holds_torque()
            if on_beam and not self._on_beam:
                self.board.sensors.forget_creep(self._rig_channel)
            self._on_beam = on_beam
            if on_beam or probe_n > 0.0:
                forces[self._rig_channel] = probe_n
        return forces

    @property
    def rig_sensor(self) -> str | None:
        """The sensor under the rig's probe (``rig.sensor`` at first; :meth:`move_rig_to` moves it)."""
        return None if self._rig_channel is None else self.config.board.channel_names[self._rig_channel]

    def move_rig_to(self, sensor: str) -> None:
        """Put ``sensor``'s segment on the rig's beam under the probe, as a person does between two sensors'
        calibrations: from now on the probe alone loads it while the rig holds torque (its creep forgotten when it
        goes on the beam), and the sensor it leaves bears the robot's weight again. Its area stays its own: the
        probe covers the whole sensor, so a calibration's moduli carry it, as they do when the robot loads it.
        ValueError when ``sensor`` is not a channel of the board. Call it while the rig is idle."""
        names = self.config.board.channel_names
        if sensor not in names:
            raise ValueError(f"sensor {sensor} is not a channel of the simulated board ({names[0]} … {names[-1]})")
        channel = names.index(sensor)
        if channel != self._rig_channel:
            self._rig_channel = channel
            self._on_beam = False  # mounted anew: its creep is forgotten when the rig next holds it

    def rig_sensor_truth(self) -> dict[str, float]:
        """The simulated parameters of the sensor on the rig (``rig.sensor``): ``E0_Pa``, ``E1_Pa``, ``mu1_Pa_s``,
        ``tau_s``, ``area_m2`` — what a calibration on the rig should recover."""
        if self._rig_channel is None:
            raise ValueError(f"rig.sensor {self.config.rig.sensor} is not a channel of the simulated board")
        one = self.board.sensors.params.sensor(self._rig_channel)
        return {"E0_Pa": float(one.E0_Pa), "E1_Pa": float(one.E1_Pa), "mu1_Pa_s": float(one.mu1_Pa_s),
                "tau_s": float(one.tau_s), "area_m2": float(self.board.sensors.area_m2[self._rig_channel])}

    def start_background(self) -> None:
        """Keep the physics world stepping with the clock between driver events (the app's lab); no-op when the
        lab is scripted. Daemon thread; :meth:`close` stops it. With ``[lab] mocap = true`` the simulated motion
        capture starts too."""
        if self.physics is not None:
            self.physics.start()
            if self.config.lab.mocap == SIM_MOCAP:
                self.start_mocap_stream()

    def start_mocap_stream(self) -> str:
        """Publish the simulated body's motion capture (:mod:`devices.sim.mocap_stream`) if not yet; returns the
        stream's name. ValueError on the scripted lab (no body in a world to film)."""
        if self.physics is None:
            raise ValueError("the scripted simulated lab has no body to film: motion capture needs the physics lab "
                             "([lab] physics = \"mujoco\")" + (f"; {self.physics_note}" if self.physics_note else ""))
        if self.mocap_stream is None:
            from devices.sim.mocap_stream import SimulatedMocapStream

            physics, clock = self.physics, self.clock
            self.mocap_stream = SimulatedMocapStream(
                physics.body_state, lambda world_s: clock.wall_from_sim(world_s + physics.time0_s), self.config.mocap,
                self.config.robot.n_joints, physics.world.scene.terrain.height_at, realtime=self.realtime_threads)
        self.mocap_stream.start()
        return self.mocap_stream.name

    def close(self) -> None:
        if self.mocap_stream is not None:
            self.mocap_stream.close()
        if self.physics is not None:
            self.physics.close()

    def endpoint(self, device: str) -> SimEndpoint:
        """The wire end of ``device``: ``robot`` (servo bus), ``board`` (force sensors) or ``rig`` (rig servo bus)."""
        if device == "robot":
            return self.chain
        if device == "board":
            return self.board
        if device == "rig":
            return self.rig.chain
        raise ValueError(f"the simulated lab has no device {device!r}")
