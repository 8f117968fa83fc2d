"""app/gui/recording_session.py: the GUI's writer-thread recording, on real SampleBlocks and ChainStates."""

from __future__ import annotations

import time

import numpy as np

from app.core.recording import open_recording
from app.gui.recording_session import RecordingSession
from devices.board import SampleBlock
from devices.servo_chain import ChainState

CHANNELS = ("S01L", "S01R", "S01B")


def make_block(t0: float, n: int, seq0: int) -> SampleBlock:
    counts = np.full((n, 3), 3000, dtype=np.uint16)
    host = t0 + np.arange(n) / 30.0
    return SampleBlock(counts=counts, conductance_s=np.full((n, 3), 1e-4), board_time_s=host.copy(),
                       host_time_s=host, seq=np.arange(seq0, seq0 + n, dtype=np.uint32),
                       saturated=np.zeros((n, 3), dtype=bool))


def test_blocks_robot_states_forces_and_events_round_trip(qtbot, tmp_path):
    session = RecordingSession(tmp_path / "r.h5", "[board]\n", CHANNELS, calibration_json='{"format": "x"}',
                               with_robot=True, n_joints=2)
    session.start()
    now = time.monotonic()
    for k in range(5):
        session.add_block(make_block(now + k / 3, 10, 10 * k), force_n=np.full((10, 3), float(k)))
    states = [ChainState(host_time_s=now + i / 50, position_rad=np.array([0.1, -0.1]),
                         velocity_rad_s=np.zeros(2), current_ma=np.array([5.0, 6.0]),
                         goal_rad=None if i % 2 else np.array([0.2, -0.2])) for i in range(20)]
    session.add_robot_states(states)
    session.mark_gap(now + 1.0, "board unplugged")
    session.log_event("S10R: noisy (loose?)", kind="health")
    with qtbot.waitSignal(session.stopped, timeout=15_000) as stopped:
        session.stop()
    session.stop()  # twice is fine
    assert "saved" in stopped.args[0] and not session.is_active
    rec = open_recording(tmp_path / "r.h5")
    assert rec.n_samples == 50 and rec.forces_n[-1, 0] == 4.0
    assert rec.robot.time_s.size == 20
    np.testing.assert_allclose(rec.robot.goal_rad[0], [0.2, -0.2])
    np.testing.assert_allclose(rec.robot.goal_rad[1], [0.1, -0.1])  # no goal sent yet: present stands in
    assert rec.time_s[0] == rec.robot.time_s[0]  # one clock for board and robot
    assert [e.kind for e in rec.events].count("health") == 1 and rec.gaps


def test_a_file_that_cannot_be_created_fails_cleanly(qtbot, tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    session = RecordingSession(blocker / "r.h5", "", CHANNELS)
    with qtbot.waitSignal(session.failed, timeout=15_000) as failed:
        session.start()
    assert "cannot" in failed.args[0]
    assert not session.is_active
    session.add_block(make_block(time.monotonic(), 3, 0))  # ignored, no error
    session.stop()
