"""The built-in simulated lab: a 12-servo Dynamixel chain, the force-sensor board and the calibration rig.

Each device is emulated at the wire (``devices.sim.transport.SimEndpoint``), so the real drivers run against it.
Only ``devices.factory`` creates a :class:`SimLab`; tests build their own (seeded, ``speed`` > 1) and install it there.
"""

from __future__ import annotations

import numpy as np

from devices.config import LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel
from devices.sim.dxl_chain import VirtualChain
from devices.sim.rig import VirtualRig
from devices.sim.transport import SimEndpoint


class SimLab:
    """The simulated robot, board and rig sharing one clock and one random seed."""

    def __init__(self, config: LabConfig | None = None, *, seed: int = 0, speed: float = 1.0) -> None:
        self.config = config or LabConfig()
        self.clock = SimClock(speed)
        rng = np.random.default_rng(seed)
        robot = self.config.robot
        self.chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=self.clock,
                                  seed=int(rng.integers(2**31)))
        self.contact = ContactModel(self.config, self.chain, seed=int(rng.integers(2**31)))
        self.board = VirtualBoard(self.config.board, self.clock, force_source=self.contact.forces_n,
                                  seed=int(rng.integers(2**31)))
        self.rig = VirtualRig(self.config.rig, self.clock, seed=int(rng.integers(2**31)))

    def endpoint(self, device: str) -> SimEndpoint:
        """The wire end of ``device``: ``robot`` (servo bus), ``board`` (force sensors) or ``rig`` (rig servo bus)."""
        if device == "robot":
            return self.chain
        if device == "board":
            return self.board
        if device == "rig":
            return self.rig.chain
        raise ValueError(f"the simulated lab has no device {device!r}")
