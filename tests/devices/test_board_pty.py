"""BoardReader through real pyserial on a pseudo-terminal: the code path of a USB board, minus the copper."""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from devices.board import BoardReader
from devices.config import LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel

pytestmark = pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")), reason="needs os.openpty")

PUMP_PERIOD_S = 0.002


class PtyBoard:
    """A VirtualBoard whose bytes are pumped into a pty master by a thread, as a USB adapter would deliver them."""

    def __init__(self, board: VirtualBoard) -> None:
        import tty

        self.board = board
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave  # kept open so the pty exists before the reader opens it
        self._stop = threading.Event()
        board.host_opened(board.board.baud)
        self._thread = threading.Thread(target=self._pump, name="pty-board-pump", daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        while not self._stop.wait(PUMP_PERIOD_S):  # the board's UART pace, not a test waiting on a result
            data = self.board.host_read(time.monotonic())
            if data:
                os.write(self.master, data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        os.close(self.master)
        os.close(self._slave)


def test_reader_on_a_real_serial_port(tmp_path):
    config = LabConfig()
    board = VirtualBoard(config.board, SimClock(10.0), ContactModel(config, None, seed=2).forces_n, seed=3,
                         noise_counts=0.0)
    pty = PtyBoard(board)
    try:
        board_cfg = replace(config.board, port=pty.path)
        with BoardReader(board_cfg) as reader:
            assert reader.wait_for_frames(30, 10.0), reader.stats
            block = reader.read_block()
            stats = reader.stats
    finally:
        pty.close()
    assert block is not None and block.counts.shape[1] == 36
    assert np.all(np.diff(block.seq.astype(np.int64)) == 1)
    lsb = (3.3 / 4095) / (2.5 * 900.0)
    assert np.max(np.abs(block.conductance_s - board.true_conductance_s(block.seq))) <= 0.5 * lsb + 1e-12
    assert stats.crc_errors == 0 and stats.connected
