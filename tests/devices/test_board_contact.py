"""The simulated contact model that feeds the virtual board: weight share, bending, side walls, moving bump."""

from __future__ import annotations

import numpy as np

from devices.config import LabConfig
from devices.sim.contact import BUMP_FORCE_N, SIDE_BUMP_FORCE_N, ContactModel


class PosedChain:
    """A chain held in a fixed pose (what the contact model reads from the simulated servos)."""

    def __init__(self, angles_rad) -> None:
        self.angles_rad = np.asarray(angles_rad, dtype=float)

    def present_positions_rad(self) -> np.ndarray:
        return self.angles_rad


def loads(angles, t_s=0.0):
    model = ContactModel(LabConfig(), PosedChain(angles), seed=7)
    return model, model.segment_loads_n(t_s)


def test_straight_robot_shares_its_weight_on_the_bottom_sensors():
    model, (bottom, left, right) = loads(np.zeros(12))
    bump_at_most = BUMP_FORCE_N * (np.sqrt(2 * np.pi) * 0.06 / 0.08 + 1)  # the bump summed over segments
    assert model.weight_n < bottom.sum() < model.weight_n + bump_at_most
    assert np.all(bottom >= model.weight_n / 12 * 0.99)
    assert left.sum() + right.sum() <= SIDE_BUMP_FORCE_N * 3  # only the bump touches a side
    forces = model.forces_n(0.0)
    assert forces.shape == (36,) and np.all(forces >= 0)
    assert np.all(forces[2::3] > 1.0)  # every bottom channel (…B) carries weight


def test_pitch_bending_lifts_some_segments_and_loads_others():
    arch = np.zeros(12)
    arch[4] = 0.4  # joint 5 (pitch) lifts the tail end
    _, (bottom, _, _) = loads(arch, t_s=0.0)
    _, (flat, _, _) = loads(np.zeros(12), t_s=0.0)
    assert bottom[:5].sum() > flat[:5].sum() + 5.0
    assert bottom[8:].sum() < 0.5 * flat[8:].sum()


def test_yaw_bending_presses_side_sensors_against_the_walls():
    curl = np.zeros(12)
    curl[1::2] = 0.5  # every yaw joint bends the same way: the body curls toward one side
    _, (_, left, right) = loads(curl)
    _, (_, left0, right0) = loads(np.zeros(12))
    assert left.sum() + right.sum() > left0.sum() + right0.sum() + 5.0


def test_bump_travels_along_the_body():
    model = ContactModel(LabConfig(), None, seed=7)
    first = np.argmax(model.segment_loads_n(0.0)[0])
    later = np.argmax(model.segment_loads_n(0.08 / 0.03 * 2)[0])  # two segment lengths later
    assert (later - first) % 12 == 2
