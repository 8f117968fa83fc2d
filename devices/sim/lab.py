"""The built-in simulated lab: a 12-servo Dynamixel chain, the force-sensor board and the calibration rig.

Each device is emulated at the wire (``devices.sim.transport.SimEndpoint``), so the real drivers run against it.
Only ``devices.factory`` creates a :class:`SimLab`; tests build their own (seeded, ``speed`` > 1) and install it there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from devices.config import LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel
from devices.sim.dxl_chain import VirtualChain
from devices.sim.rig import VirtualRig
from devices.sim.transport import SimEndpoint

if TYPE_CHECKING:  # pragma: no cover
    from devices.sim.physics.backend import PhysicsBackend


class SimLab:
    """The simulated robot, board and rig sharing one clock and one random seed."""

    def __init__(self, config: LabConfig | None = None, *, seed: int = 0, speed: float = 1.0) -> None:
        self.config = config or LabConfig()
        self.clock = SimClock(speed)
        rng = np.random.default_rng(seed)
        robot = self.config.robot
        # [lab] physics = "mujoco": the robot is a body in a physics world that the chain drives and the board feels.
        self.physics: PhysicsBackend | None = None
        if self.config.lab.physics == "mujoco":
            from devices.sim.physics.backend import PhysicsBackend

            self.physics = PhysicsBackend(self.config, self.clock)
        self.chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=self.clock,
                                  seed=int(rng.integers(2**31)), physics=self.physics)
        self.contact = ContactModel(self.config, self.chain, seed=int(rng.integers(2**31)))
        board_seed, rig_seed = int(rng.integers(2**31)), int(rng.integers(2**31))
        self.rig = VirtualRig(self.config.rig, self.clock, seed=rig_seed)
        names = self.config.board.channel_names
        self._rig_channel = names.index(self.config.rig.sensor) if self.config.rig.sensor in names else None
        self.board = VirtualBoard(self.config.board, self.clock, force_source=self.forces_n, seed=board_seed)

    def forces_n(self, t_s: float) -> np.ndarray:
        """Force on every board channel from the robot's contacts — except that while the rig's probe presses, the
        channel of ``rig.sensor`` feels the probe alone: in the lab that segment sits on the calibration beam, not
        under the robot's weight, so a calibration run reads the rig force through the board as it would there."""
        forces = self.physics.forces_n(t_s) if self.physics is not None else self.contact.forces_n(t_s)
        if self._rig_channel is not None:
            probe_n = self.rig.applied_force_n()
            if probe_n > 0.0:
                forces[self._rig_channel] = probe_n
        return forces

    def start_background(self) -> None:
        """Keep the physics world stepping with the clock between driver events (the app's lab); no-op when the
        lab is scripted. Daemon thread; :meth:`close` stops it."""
        if self.physics is not None:
            self.physics.start()

    def close(self) -> None:
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
