"""BoardReader against the VirtualBoard at the wire (SimSerial through devices.factory, port ``sim``)."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from devices.board import BoardReader, BoardStatus
from devices.config import BoardConfig, LabConfig
from devices.errors import PortOpenError
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel

WAIT_S = 10.0
LSB_S = (3.3 / 4095) / (2.5 * 900.0)  # conductance of one ADC count


class StatusLog:
    """Collects BoardStatus callbacks (reader thread) and lets the test wait for a state."""

    def __init__(self) -> None:
        self.states: list[str] = []
        self.messages: list[str] = []
        self._cond = threading.Condition()

    def __call__(self, status: BoardStatus) -> None:
        with self._cond:
            self.states.append(status.state)
            self.messages.append(status.message)
            self._cond.notify_all()

    def wait_for(self, state: str, count: int = 1, timeout_s: float = WAIT_S) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.states.count(state) >= count, timeout_s)


def make_board(board_cfg: BoardConfig | None = None, *, noise_counts: float = 0.0, speed: float = 20.0,
               **kwargs) -> VirtualBoard:
    config = LabConfig() if board_cfg is None else replace(LabConfig(), board=board_cfg)
    clock = SimClock(speed)
    contact = ContactModel(config, None, seed=3)
    return VirtualBoard(config.board, clock, contact.forces_n, seed=4, noise_counts=noise_counts, **kwargs)


@pytest.fixture
def virtual_board(install_sim_device):
    return install_sim_device("board", make_board())


def drain(reader: BoardReader, n_frames: int):
    assert reader.wait_for_frames(n_frames, WAIT_S), f"fewer than {n_frames} frames arrived: {reader.stats}"
    block = reader.read_block()
    assert block is not None
    return block


def test_conductance_matches_ground_truth_within_quantisation(virtual_board):
    with BoardReader(BoardConfig()) as reader:
        block = drain(reader, 40)
    truth = virtual_board.true_conductance_s(block.seq)
    assert block.counts.shape == (len(block), 36) and block.counts.dtype == np.uint16
    assert np.all(np.diff(block.seq.astype(np.int64)) == 1)
    # Noise is off: the only error is rounding to the nearest count (± half an LSB).
    assert np.max(np.abs(block.conductance_s - truth)) <= 0.5 * LSB_S + 1e-12
    # Loaded bottom sensors read a real signal, well above quantisation.
    bottom = [k for k in range(36) if k % 3 == 2]
    assert np.all(block.conductance_s[:, bottom].mean(axis=0) > 100 * LSB_S)
    assert np.allclose(np.diff(block.board_time_s), 1 / 30.0, atol=2e-6)
    assert np.all(np.diff(block.host_time_s) >= 0)
    assert not block.saturated.any()
    assert block.gap_before is None


def test_noisy_board_stays_within_a_few_counts(virtual_board):
    virtual_board.noise_counts = 0.5
    with BoardReader(BoardConfig()) as reader:
        block = drain(reader, 30)
    error_counts = (block.conductance_s - virtual_board.true_conductance_s(block.seq)) / LSB_S
    assert np.max(np.abs(error_counts)) < 0.5 + 6 * 0.5
    assert 0.2 < np.std(error_counts) < 0.9


def test_cable_pull_reconnects_and_marks_the_gap(virtual_board):
    log = StatusLog()
    with BoardReader(BoardConfig(), on_status=log) as reader:
        drain(reader, 10)
        virtual_board.unplug()
        assert log.wait_for("disconnected")
        assert not reader.stats.connected
        virtual_board.replug()
        assert log.wait_for("reconnected")
        block = drain(reader, 10)
        stats = reader.stats
    assert log.states[:3] == ["connected", "disconnected", "reconnected"]
    assert "check the cable" in log.messages[1]
    assert stats.reconnects == 1 and stats.connected
    assert block.gap_before is not None
    first_after = int(np.argmax(block.gap_before))
    assert block.gap_before.sum() == 1
    # The frames sampled while the cable was out are missing, not invented.
    seq = block.seq.astype(np.int64)
    assert first_after == 0 or seq[first_after] - seq[first_after - 1] > 1
    assert log.states[-1] == "closed"


def test_unplugged_board_cannot_be_opened(install_sim_device):
    board = make_board()
    board.unplug()
    install_sim_device("board", board)
    reader = BoardReader(BoardConfig())
    with pytest.raises(PortOpenError, match="board port sim"):
        reader.start()
    reader.close()


def test_channel_count_mismatch_names_both_counts(virtual_board):
    log = StatusLog()
    virtual_board.set_channel_count(40)
    with BoardReader(BoardConfig(), on_status=log) as reader:
        assert log.wait_for("mismatch")
        assert reader.read_block() is None  # nothing of the wrong shape reaches consumers
        virtual_board.set_channel_count(None)
        assert log.wait_for("connected", count=2)
        block = drain(reader, 5)
        mismatches = reader.stats.channel_mismatches
    message = log.messages[log.states.index("mismatch")]
    assert "40 channels" in message and "36" in message
    assert mismatches >= 1
    assert block.counts.shape[1] == 36


def test_crc_errors_and_garbage_are_counted_and_never_delivered(virtual_board):
    with BoardReader(BoardConfig()) as reader:
        drain(reader, 5)
        virtual_board.corrupt_frames(4)
        virtual_board.inject_garbage(500)
        virtual_board.drop_frames(3)
        block = drain(reader, 40)
        stats = reader.stats
    # A flip in the length field can make a frame look longer; the next CRC then fails on the longer span.
    assert 1 <= stats.crc_errors <= 4 + 500
    assert stats.resyncs >= 1  # the corrupted frames follow each other: one loss of sync
    assert stats.bytes_discarded >= 500
    assert stats.seq_gaps >= 1 and stats.dropped_frames >= 7 - 1
    truth = virtual_board.true_conductance_s(block.seq)
    assert np.max(np.abs(block.conductance_s - truth)) <= 0.5 * LSB_S + 1e-12
    assert block.gap_before is not None and block.gap_before.sum() >= 1


def test_board_clock_wrap_is_unwrapped(install_sim_device):
    install_sim_device("board", make_board(board_clock_offset_us=2**32 - 300_000))  # wraps 0.3 s (sim) after start
    with BoardReader(BoardConfig()) as reader:
        block = drain(reader, 25)
    assert block.board_time_s[0] < 2**32 * 1e-6 < block.board_time_s[-1]  # the block spans the wrap
    assert np.allclose(np.diff(block.board_time_s), 1 / 30.0, atol=2e-6)


def test_faulty_sensors_show_in_the_samples(virtual_board):
    virtual_board.noise_counts = 0.5
    virtual_board.set_saturated(5)
    virtual_board.set_flatline(8, counts=2000)
    virtual_board.set_loose(11, noise_counts=200.0, dropout_prob=0.2)
    with BoardReader(BoardConfig()) as reader:
        block = drain(reader, 60)
    assert block.saturated[:, 5].all() and not block.saturated[:, 4].any()
    assert np.all(block.counts[:, 8] == 2000)
    assert np.std(block.counts[:, 11].astype(float)) > 50
    assert np.std(block.counts[:, 14].astype(float)) < 5


def test_full_sim_lab_board_feels_the_robot_pose(sim_lab_fast):
    """The whole simulated lab: posing the (limp) robot by hand moves the load between the bottom sensors."""
    tail_bottom = [3 * (segment - 1) + 2 for segment in range(9, 13)]
    with BoardReader(sim_lab_fast.config.board) as reader:
        before = drain(reader, 15)
        # Joint 5 (pitch) bent: the tail end of the body lifts off the ground.
        sim_lab_fast.chain.set_limp_position(5, 2048 + 0.5 / (2 * np.pi / 4096))
        reader.read_block()  # drop the frames sampled around the move
        after = drain(reader, 15)
    lifted = after.conductance_s[:, tail_bottom].mean()
    assert lifted < 0.5 * before.conductance_s[:, tail_bottom].mean()


@pytest.mark.hardware
def test_real_board_streams_verified_frames():
    """On the bench: SENSNAKE_HARDWARE=1 SENSNAKE_BOARD_PORT=/dev/ttyUSB1 pytest -k real_board."""
    import os

    from devices.config import load_config

    config = load_config(os.environ["SENSNAKE_CONFIG"]) if "SENSNAKE_CONFIG" in os.environ else LabConfig()
    board_cfg = replace(config.board, port=os.environ.get("SENSNAKE_BOARD_PORT", config.board.port))
    with BoardReader(board_cfg) as reader:
        block = drain(reader, int(board_cfg.rate_hz * 2))
        stats = reader.stats
    assert block.counts.shape[1] == board_cfg.n_channels
    assert stats.crc_errors <= 0.01 * stats.frames
    assert np.median(np.diff(block.board_time_s)) == pytest.approx(1 / board_cfg.rate_hz, rel=0.2)


def test_ring_overflow_keeps_the_newest_frames_and_counts_the_rest(virtual_board):
    with BoardReader(BoardConfig(), ring_seconds=0.0) as reader:  # the minimum ring: 256 frames
        # Nobody drains while 300 frames arrive: the oldest 44 or more must make way.
        assert reader.wait_for_frames(300, WAIT_S), reader.stats
        block = reader.read_block()
        stats = reader.stats
    assert len(block) == 256
    assert np.all(np.diff(block.seq.astype(np.int64)) == 1)  # the newest 256, in order
    assert stats.overflow_frames >= 300 - 256
    assert block.seq[-1] - block.seq[0] == 255
