"""app/gui/board_bridge.py against the simulated board at the wire (real BoardReader, fast SimClock)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from app.gui.board_bridge import BoardBridge
from devices.config import LabConfig

pytestmark = pytest.mark.usefixtures("sim_lab_fast")


@pytest.fixture
def bridge(qtbot):
    bridge = BoardBridge(LabConfig().board)
    yield bridge
    bridge.stop()


def test_blocks_reach_the_history_and_signal(qtbot, bridge):
    blocks = []
    bridge.block.connect(blocks.append)
    with qtbot.waitSignal(bridge.connected, timeout=15_000) as connected:
        bridge.start()
    assert connected.args == [True]
    qtbot.waitUntil(lambda: len(bridge.history) >= 60, timeout=10_000)
    assert blocks and blocks[0].conductance_s.shape[1] == 36
    t_last, values_us = bridge.history.latest()
    assert values_us.shape == (36,)
    assert np.all(values_us >= 0) and values_us.max() > 50  # µS: loaded bottom sensors read hundreds
    assert t_last == pytest.approx(float(bridge.to_session_time(blocks[-1].host_time_s[-1:])[0]), abs=1e-3)
    assert bridge.bridge_stats.samples == sum(len(b) for b in blocks)
    assert bridge.bridge_stats.max_delivery_lag_s < 5.0


def test_cable_pull_is_reported_and_reconnects(qtbot, bridge, sim_lab_fast):
    states = []
    bridge.board_status.connect(lambda status: states.append(status.state))
    with qtbot.waitSignal(bridge.connected, timeout=15_000):
        bridge.start()
    qtbot.waitUntil(lambda: len(bridge.history) > 10, timeout=10_000)
    with qtbot.waitSignal(bridge.connected, timeout=15_000) as lost:
        sim_lab_fast.board.unplug()
    assert lost.args == [False]
    assert "disconnected" in states
    with qtbot.waitSignal(bridge.connected, timeout=15_000) as back:
        sim_lab_fast.board.replug()
    assert back.args == [True]
    assert "reconnected" in states
    before = bridge.bridge_stats.samples
    qtbot.waitUntil(lambda: bridge.bridge_stats.samples > before + 5, timeout=10_000)
    assert bridge.stats.reconnects == 1


def test_channel_count_mismatch_names_both_counts(qtbot, bridge, sim_lab_fast):
    sim_lab_fast.board.set_channel_count(30)
    messages = []
    bridge.status.connect(messages.append)
    bridge.start()
    qtbot.waitUntil(lambda: any("30" in m and "36" in m for m in messages), timeout=10_000)
    assert not bridge.is_connected
    assert len(bridge.history) == 0


def test_stop_joins_and_restart_works(qtbot, bridge):
    bridge.start()
    qtbot.waitUntil(lambda: len(bridge.history) > 5, timeout=10_000)
    bridge.stop()
    assert not bridge.is_running and not bridge.is_connected
    count = bridge.bridge_stats.samples
    with qtbot.waitSignal(bridge.connected, timeout=15_000):
        bridge.start()
    qtbot.waitUntil(lambda: bridge.bridge_stats.samples > count, timeout=10_000)


def test_a_stop_before_the_opened_reader_is_adopted_still_ends_its_thread(qtbot, bridge):
    before = set(threading.enumerate())
    bridge.start()
    opener = bridge._opener
    assert opener is not None
    opener.join(timeout=10)  # the port is open and the reader's thread runs; its adoption is queued, not yet run
    readers = [t for t in threading.enumerate() if t not in before and t.name.startswith("board-reader")]
    assert len(readers) == 1
    bridge.stop()
    assert not readers[0].is_alive()
    qtbot.wait(50)  # the queued adoption arrives after the stop: it must not revive the closed reader
    assert bridge._reader is None and not bridge.is_connected


def test_a_simulated_lab_at_20x_keeps_its_frames_on_the_host_clock_at_a_twentieth_of_the_board_spacing(
        qtbot, bridge, sim_lab_fast):
    """The board clock runs 20× the host's: once its pace is measured, frames read together are dated back by the
    board's time between them in host seconds, not by the board's 33 ms (which put them up to seconds in the past)."""
    bridge.start()
    qtbot.waitUntil(lambda: bridge._reader is not None, timeout=15_000)
    reader = bridge._reader
    # Measured from the frames' arrival over a span that grows from 1 s: a frame held up by a loaded machine at the
    # span's end makes the first figure low (14.5 seen at load 12), later ones converge.
    qtbot.waitUntil(lambda: reader._board_pace is not None and 15 < reader._board_pace < 25, timeout=20_000)
    blocks: list = []
    bridge.block.connect(blocks.append)
    qtbot.waitUntil(lambda: sum(len(b) for b in blocks) > 200, timeout=20_000)
    host = np.concatenate([b.host_time_s for b in blocks])
    board = np.concatenate([b.board_time_s for b in blocks])
    speed = sim_lab_fast.clock.speed
    assert np.median(np.diff(host)) == pytest.approx(np.median(np.diff(board)) / speed, rel=0.25)
    assert host[-1] > time.monotonic() - 1.0  # stamped about when it came, not seconds before
