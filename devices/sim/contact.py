"""A cheap contact model for the simulated robot: what each force sensor feels.

The robot lies on flat ground. Its weight (``ROBOT_MASS_KG``·g) is shared by the bottom sensors; the pitch joints
bend the body in the vertical plane, and segments lifted above the lowest point carry less of it (a soft
exponential share, so bending one way lifts some segments and loads the others). The yaw joints bend it in the
horizontal plane; side sensors that the bent body pushes past a pair of virtual walls at ±``WALL_OFFSET_M`` are
pressed by a stiff spring. A slowly travelling bump (an obstacle sliding along the body) adds a moving load on the
bottom and alternately on one side, so live traces look alive even when the robot holds still.

Channel names follow SPEC §2 (``S06B``: segment 6, bottom); channels with other names feel nothing. All of it is a
few 12-element vector operations per call (any thread).
"""

from __future__ import annotations

import re
from typing import Protocol

import numpy as np

from devices.config import LabConfig

GRAVITY_M_S2 = 9.81
ROBOT_MASS_KG = 2.4  # SenSnake v2
LIFT_SCALE_M = 0.01  # a segment 1 cm above the lowest one carries e⁻¹ of a grounded segment's share
WALL_OFFSET_M = 0.12
WALL_STIFFNESS_N_PER_M = 400.0
# A wall press levels off at this force (the shell gives way): a hard yaw bend must not read as ~100 N.
WALL_MAX_FORCE_N = 3.0
BUMP_SPEED_M_S = 0.03
BUMP_WIDTH_M = 0.06
# Weight share (~2 N) + bump stays below ~5 N, where the typical sensor saturates the default readout (1/R_C),
# so a resting robot does not show saturated sensors; posing it over an obstacle can still saturate, as in the lab.
BUMP_FORCE_N = 1.5
SIDE_BUMP_FORCE_N = 1.0
_NAME = re.compile(r"^S(\d+)([LRB])$")


def _wall_force_n(penetration_m: np.ndarray) -> np.ndarray:
    """Spring force of a wall pressed ``penetration_m`` deep (≤ 0: no contact), levelling off at WALL_MAX_FORCE_N."""
    linear = WALL_STIFFNESS_N_PER_M * np.maximum(0.0, penetration_m)
    return WALL_MAX_FORCE_N * np.tanh(linear / WALL_MAX_FORCE_N)


class HasJointAngles(Protocol):
    def present_positions_rad(self) -> np.ndarray: ...


class ContactModel:
    """Forces on every configured channel from the chain's joint angles and time.

    ``chain`` is anything with ``present_positions_rad() -> (n_joints,)`` in joint order (the simulated servo chain);
    ``None`` means a straight body.
    """

    def __init__(self, config: LabConfig, chain: HasJointAngles | None, seed: int = 0) -> None:
        self.config = config
        self.chain = chain
        robot = config.robot
        self.n_segments = robot.n_joints
        self.segment_length_m = robot.segment_length_m
        self._pitch = np.array([axis == "pitch" for axis in robot.axes])
        names = config.board.channel_names
        self._segment = np.full(len(names), -1)
        self._side = np.full(len(names), "", dtype="<U1")
        for channel, name in enumerate(names):
            match = _NAME.match(name)
            if match and 1 <= int(match.group(1)) <= self.n_segments:
                self._segment[channel] = int(match.group(1)) - 1
                self._side[channel] = match.group(2)
        self._known = self._segment >= 0
        self._known_segment = self._segment[self._known]
        self._known_side = np.array(["BLR".index(side) for side in self._side[self._known]], dtype=np.intp)
        rng = np.random.default_rng(seed)
        # Shells are not identical: each sensor picks up a slightly different share of the same load.
        self._coupling = np.clip(rng.normal(1.0, 0.08, len(names)), 0.7, 1.3)
        self._bump_phase_m = float(rng.uniform(0.0, self.n_segments * self.segment_length_m))
        self.weight_n = ROBOT_MASS_KG * GRAVITY_M_S2

    def _angles(self) -> np.ndarray:
        if self.chain is None:
            return np.zeros(self.n_segments)
        angles = np.asarray(self.chain.present_positions_rad(), dtype=np.float64)
        if angles.shape != (self.n_segments,):
            return np.zeros(self.n_segments)
        return angles

    def segment_loads_n(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bottom, left, right) force per segment in newtons at simulated time ``t_s``."""
        angles = self._angles()
        length = self.segment_length_m
        pitch = np.where(self._pitch, angles, 0.0)
        yaw = np.where(self._pitch, 0.0, angles)
        # Segment centres in each plane, head at the origin, body along +x.
        heights = np.cumsum(length * np.sin(np.cumsum(pitch)))
        lateral = np.cumsum(length * np.sin(np.cumsum(yaw)))
        lateral -= lateral.mean()
        share = np.exp(-(heights - heights.min()) / LIFT_SCALE_M)
        bottom = self.weight_n * share / share.sum()
        left = _wall_force_n(lateral - WALL_OFFSET_M)
        right = _wall_force_n(-lateral - WALL_OFFSET_M)
        # The travelling bump.
        body_length = self.n_segments * length
        along = (np.arange(self.n_segments) + 0.5) * length
        bump_at = (self._bump_phase_m + BUMP_SPEED_M_S * t_s) % body_length
        bump = np.exp(-0.5 * ((along - bump_at) / BUMP_WIDTH_M) ** 2)
        bottom = bottom + BUMP_FORCE_N * bump
        lap = int((self._bump_phase_m + BUMP_SPEED_M_S * t_s) // body_length)
        if lap % 2 == 0:
            left = left + SIDE_BUMP_FORCE_N * bump
        else:
            right = right + SIDE_BUMP_FORCE_N * bump
        return bottom, left, right

    def forces_n(self, t_s: float) -> np.ndarray:
        """Force in newtons on each channel of ``config.board`` at simulated time ``t_s``, shape (C,), ≥ 0."""
        bottom, left, right = self.segment_loads_n(t_s)
        loads = np.stack([bottom, left, right])  # rows in the order of "BLR"
        forces = np.zeros(self._segment.size)
        forces[self._known] = loads[self._known_side, self._known_segment]
        return forces * self._coupling
