"""Fixtures shared by the device tests."""

from __future__ import annotations

import numpy as np
import pytest

from devices import control_table as ct

MAX_READS = 300  # each read is one bus round trip: enough for the moves these tests make on sped-up simulators


@pytest.fixture
def read_until_at():
    """``read_until_at(chain, goal_rad, atol_rad=3 ticks)``: read the ServoChain's state until every joint is within
    ``atol_rad`` of ``goal_rad`` (at most MAX_READS reads, each one bus round trip) and return the last state.
    The caller asserts on it, so a chain that never gets there fails with the positions it did reach."""

    def read(chain, goal_rad: np.ndarray, atol_rad: float = 3 * ct.RAD_PER_TICK):
        for _ in range(MAX_READS):
            state = chain.read_state()
            if np.allclose(state.position_rad, goal_rad, atol=atol_rad):
                break
        return state

    return read
