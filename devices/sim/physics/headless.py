"""The physics lab stepped by its caller, as fast as the machine goes: for batch experiments (``sensnake experiment``).

The same parts as the app's physics lab — the MuJoCo world, the virtual XM430 chain and the virtual board — on a
:class:`ManualClock` that only the caller advances. The caller talks to both devices through their wire: goals and
torque enable go in as Dynamixel Protocol 2.0 sync writes (:mod:`devices.dxl_wire`), the present state comes back as
sync-read status packets, and the board's SPEC §4 bytes go to the caller, who parses them with the host's own
:class:`devices.board.FrameParser`.
(The threaded drivers pace themselves by the wall clock, so they cannot run faster than real time; this is their
wire protocol without the wall clock.)

One thread: the caller's.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, replace

import numpy as np

from devices import control_table as ct
from devices import dxl_wire as wire
from devices.config import LabConfig
from devices.scene import Scene
from devices.sim.board import VirtualBoard
from devices.sim.dxl_chain import VirtualChain
from devices.sim.physics.backend import PhysicsBackend, scene_from_config
from devices.sim.physics.world import BodyState

_PRESENT = struct.Struct("<hii")  # Present Current (126), Present Velocity (128), Present Position (132)
_PRESENT_LENGTH = 10
ADDR_TORQUE_ENABLE = 64
ADDR_GOAL_POSITION = 116
REPLY_WAIT_S = 0.012


class ManualClock:
    """Simulated seconds that advance only when told (:meth:`set`); wall time is simulated time (speed 1)."""

    speed = 1.0

    def __init__(self) -> None:
        self._t_s = 0.0

    def now(self) -> float:
        return self._t_s

    def set(self, t_s: float) -> None:
        self._t_s = max(self._t_s, float(t_s))

    def sim_from_wall(self, wall_s: float) -> float:
        return float(wall_s)

    def wall_from_sim(self, sim_s: float) -> float:
        return float(sim_s)


@dataclass(frozen=True)
class RobotReading:
    """The chain's present state as the host reads it (SPEC §2 angles with the config's signs and offsets)."""

    time_s: float
    position_rad: np.ndarray
    current_ma: np.ndarray
    alert_ids: tuple[int, ...]  # servos whose status carried the alert bit (a hardware error, e.g. overload)


class HeadlessPhysicsLab:
    """World + virtual chain + virtual board on a manual clock. See the module docstring."""

    def __init__(self, config: LabConfig, seed: int = 0, terrain: Scene | None = None) -> None:
        """``terrain``: the scene to build the world on, in place of the config's ``[lab] scene`` (default: the
        config's)."""
        self.config = config
        self.seed = seed
        self.clock = ManualClock()
        rng = np.random.default_rng(seed)
        robot = config.robot
        clock = self.clock  # duck-typed SimClock: now / sim_from_wall / wall_from_sim / speed
        scene = None if terrain is None else replace(scene_from_config(config), terrain_scene=terrain)
        self.physics = PhysicsBackend(config, clock, scene)  # type: ignore[arg-type]
        self.chain = VirtualChain(robot.joint_ids, robot.baud, clock, seed=int(rng.integers(2**31)),  # type: ignore[arg-type]
                                  physics=self.physics)
        sim = config.lab  # the simulated sensors and the readout's noise as the app's lab has them (devices.sim.lab)
        nominal = {"e0_pa": sim.sensor_E0_Pa, "e1_pa": sim.sensor_E1_Pa, "tau_s": sim.sensor_tau_s,
                   "area_m2": sim.sensor_area_m2, "spread": sim.sensor_spread}
        self.board = VirtualBoard(config.board, clock, force_source=self.physics.forces_n,  # type: ignore[arg-type]
                                  seed=int(rng.integers(2**31)), noise_counts=sim.noise_counts,
                                  sensor_nominal=nominal)
        self.chain.host_opened(robot.baud)
        self.board.host_opened(config.board.baud)
        self._servo_parser = wire.PacketParser()
        self._signs = np.asarray(robot.signs, dtype=float)
        self._offsets = np.asarray(robot.zero_offsets_rad, dtype=float)

    # -- time -------------------------------------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return self.clock.now()

    def advance_to(self, t_s: float) -> None:
        """Run the world to simulated time ``t_s`` (s)."""
        self.clock.set(t_s)
        self.physics.advance_to(t_s)

    # -- robot bus ----------------------------------------------------------------------------------------------------------
    def _sync_write(self, address: int, size: int, values: list[int]) -> None:
        params = bytearray(struct.pack("<HH", address, size))
        for servo_id, value in zip(self.config.robot.joint_ids, values):
            params.append(servo_id)
            params += int(value).to_bytes(size, "little", signed=True)
        self.chain.host_write(wire.build_packet(wire.BROADCAST_ID, wire.SYNC_WRITE, bytes(params)),
                              self.clock.now())

    def set_torque(self, on: bool) -> None:
        self._sync_write(ADDR_TORQUE_ENABLE, 1, [int(on)] * self.config.robot.n_joints)

    def write_goals(self, angles_rad: np.ndarray) -> None:
        """Goal angles (rad, SPEC §2 with signs and offsets) as one sync write of Goal Position."""
        ticks = (np.asarray(angles_rad, dtype=float) - self._offsets) * self._signs / ct.RAD_PER_TICK + ct.CENTER_TICKS
        self._sync_write(ADDR_GOAL_POSITION, 4, [int(round(t)) for t in np.clip(ticks, 0, 4095)])

    def read_robot(self) -> RobotReading:
        """One sync read of Present Current/Velocity/Position; the replies are collected ``REPLY_WAIT_S`` of simulated
        time later (12 replies after the default 500 µs Return Delay Time each take ~8.5 ms at 1 Mbaud). A servo
        that did not answer reads NaN."""
        ids = self.config.robot.joint_ids
        params = struct.pack("<HH", ct.ADDR_PRESENT_CURRENT, _PRESENT_LENGTH) + bytes(ids)
        asked_s = self.clock.now()
        self.chain.host_write(wire.build_packet(wire.BROADCAST_ID, wire.SYNC_READ, params), asked_s)
        self.advance_to(asked_s + REPLY_WAIT_S)
        ticks = np.full(len(ids), np.nan)
        current = np.full(len(ids), np.nan)
        alerts: list[int] = []
        index = {sid: j for j, sid in enumerate(ids)}
        for packet in self._servo_parser.feed(self.chain.host_read(self.clock.now())):
            if not isinstance(packet, wire.Packet) or packet.instruction != wire.STATUS:
                continue
            j = index.get(packet.servo_id)
            if j is None or len(packet.params) < 1 + _PRESENT_LENGTH:
                continue
            error = packet.params[0]
            if error & ct.ERROR_ALERT_BIT:
                alerts.append(packet.servo_id)
            c, _, p = _PRESENT.unpack_from(packet.params, 1)
            ticks[j], current[j] = p, c * ct.CURRENT_MA_PER_LSB
        position = (ticks - ct.CENTER_TICKS) * ct.RAD_PER_TICK * self._signs + self._offsets
        return RobotReading(asked_s, position, current * self._signs, tuple(alerts))

    # -- board --------------------------------------------------------------------------------------------------------------
    def read_board_bytes(self) -> bytes:
        """Every byte of the board's SPEC §4 stream that has arrived by now (the host parses them)."""
        return self.board.host_read(self.clock.now())

    def ground_truth_calibration(self) -> dict:
        """The simulated sensors' true parameters (SPEC §3.3): what a perfect calibration of this board would say."""
        return self.board.ground_truth_calibration()

    # -- the simulated body (not visible to a driver) -----------------------------------------------------------------
    def body_state(self) -> BodyState:
        return self.physics.body_state()

    def set_tail_load(self, force_n: float) -> None:
        """A constant backward force (N) on the tail segment (see ``PhysicsWorld.set_tail_load``)."""
        self.physics.world.set_tail_load(force_n)

    def segment_loads_n(self) -> np.ndarray:
        """(3, n) true normal force per sheet (bottom, left, right rows), N."""
        return self.physics.world.segment_loads_n()

    def contact_support_n(self) -> tuple[np.ndarray, float]:
        """The upward part (N) of the whole contact forces per sheet (3, n) and on the whole robot (see
        ``PhysicsWorld.contact_support_n``)."""
        return self.physics.world.contact_support_n()
