"""The VirtualBoard's sensor physics against models.sls (two implementations of the paper's model) and its wire."""

from __future__ import annotations

import numpy as np

from devices.board import FrameParser, conductance_from_counts
from devices.config import LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel
from models.physics import PhysicsConstants
from models.sls import SLSParams, conductance_from_force, force_from_conductance


def make_board(**kwargs) -> VirtualBoard:
    config = LabConfig()
    return VirtualBoard(config.board, SimClock(1.0), ContactModel(config, None, seed=9).forces_n, seed=10, **kwargs)


def read_until(board: VirtualBoard, sim_s: float) -> bytes:
    """Everything on the wire up to simulated time ``sim_s`` (no waiting: the time is passed in)."""
    return board.host_read(board.clock.wall_from_sim(sim_s))


def test_sensor_physics_matches_models_sls_hold():
    board = make_board(noise_counts=0.0)
    board.host_opened(board.board.baud)
    frames = FrameParser().feed(read_until(board, 10.0))
    received = np.array([f.seq for f in frames])
    assert np.all(np.diff(received) == 1) and len(received) >= 290
    # Frame 0 went by while the port was being opened; its ground truth is kept, and the models start from rest.
    seq = np.arange(received[-1] + 1)
    force = board.true_force_n(seq)
    truth = board.true_conductance_s(seq)
    sensors = board.sensors
    expected = conductance_from_force(seq / board.board.rate_hz, force, sensors.params, sensors.area_m2,
                                      sensors.physics, interp="hold")
    assert np.allclose(truth, expected, rtol=1e-9, atol=1e-15)
    # And the counts on the wire are that conductance through the readout circuit, to half a count.
    counts = np.array([f.counts for f in frames])
    lsb = (3.3 / 4095) / (2.5 * 900.0)
    assert np.max(np.abs(conductance_from_counts(counts, board.board) - truth[received])) <= 0.5 * lsb + 1e-12


def test_ground_truth_calibration_lets_the_models_recover_the_force():
    board = make_board(noise_counts=0.0)
    board.host_opened(board.board.baud)
    frames = FrameParser().feed(read_until(board, 8.0))
    seq = np.arange(frames[-1].seq + 1)
    calibration = board.ground_truth_calibration()
    assert calibration["format"] == "sensnake-calibration" and len(calibration["sensors"]) == 36
    bottom = 2 + 3 * 5  # S06B (channel 17) carries weight all the time
    entry = calibration["sensors"]["S06B"]
    assert entry["linear"]["m_S_per_N"] > 0
    force = force_from_conductance(seq / 30.0, board.true_conductance_s(seq)[:, bottom],
                                   SLSParams.from_dict(entry["sls"]), entry["area_m2"],
                                   PhysicsConstants.from_dict(calibration["physics"]), interp="hold")
    assert np.allclose(force, board.true_force_n(seq)[:, bottom], rtol=1e-6)


def test_opening_mid_stream_starts_with_a_partial_frame_and_resyncs():
    board = make_board()
    # 36 channels at 30 Hz take 88 bytes = 0.44 ms at 2 Mbaud: open the port in the middle of frame 10.
    board.host_read(board.clock.wall_from_sim(10 / 30.0))  # the board streams before anyone listens
    board._deliver_after_s = 10 / 30.0 + 0.0002  # the host opened 0.2 ms into frame 10's transmission
    board._host_open = True
    data = read_until(board, 12.5 / 30.0)
    parser = FrameParser()
    frames = parser.feed(data)
    assert [f.seq for f in frames] == [11, 12]
    assert parser.resyncs == 1 and 0 < parser.bytes_discarded < 88


def test_unplugged_board_raises_like_a_vanished_adapter():
    import serial

    board = make_board()
    board.host_opened(board.board.baud)
    board.unplug()
    try:
        read_until(board, 1.0)
    except serial.SerialException as exc:
        assert "unplugged" in str(exc)
    else:
        raise AssertionError("reading an unplugged board must raise")
    board.replug()
    assert read_until(board, 2.0)  # frames flow again
