"""Qt bridge around the force-sensor board's reader (:class:`devices.board.BoardReader`).

The reader owns the port on its own thread and buffers frames in its ring. This bridge, on the GUI thread:

- opens the reader on a short-lived worker thread (the GUI thread never touches a port) and retries every
  ``RETRY_OPEN_S`` while the port cannot be opened (a board plugged in later is picked up);
- drains ``read_block()`` from one QTimer at ≤ 60 Hz into a preallocated, bounded history of conductance in µS
  (:class:`widgets.ring_plot.TraceHistory`, times in seconds since :attr:`BoardBridge.t0_monotonic_s`) and emits
  every drained block — acquisition never waits for the GUI: if the GUI stalls, the reader's ring keeps filling;
- keeps the blocks of the last ``RECENT_S`` seconds (references, no copy) so a view opened later (the Forces tab is
  built when first shown) starts with the recent past, estimated as it would have been live (:meth:`recent_blocks`);
- turns the reader's status callbacks (called on the reader thread) into signals on the GUI thread.

Signals: ``status(str)`` a sentence for the user, ``connected(bool)``, ``block(object)`` each drained
:class:`SampleBlock`, ``board_status(object)`` the raw :class:`BoardStatus` (``state`` tells disconnected /
reconnected / mismatch apart), ``stats_changed(object)`` the :class:`BoardStats` about once a second,
``open_failed(str)`` each time the port cannot be opened (a board missing; retried).

All public methods are for the GUI thread.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from PySide6.QtCore import QObject, QTimer, Signal

from app.gui.thread_bridge import ThreadBridge
from devices.board import BoardReader, BoardStats, BoardStatus, SampleBlock
from devices.config import BoardConfig
from widgets.ring_plot import TraceHistory, append_with_gaps

MAX_DRAIN_HZ = 60.0
DEFAULT_DRAIN_HZ = 30.0
RETRY_OPEN_S = 2.0
STATS_INTERVAL_S = 1.0
HISTORY_BUDGET_BYTES = 96_000_000
RECENT_S = 60.0  # what a view opened later starts with (twice the Forces tab's default 30 s window)


@dataclass
class BridgeStats:
    """What the bridge itself measured (GUI thread): blocks and samples delivered, the latest and worst lag (s)
    from a frame's arrival at the host to its delivery on the GUI thread."""

    blocks: int = 0
    samples: int = 0
    last_delivery_lag_s: float = 0.0
    max_delivery_lag_s: float = 0.0


class BoardBridge(QObject):
    """The board as the GUI sees it. ``BoardBridge(config.board, parent)`` — see the module docstring."""

    status = Signal(str)
    connected = Signal(bool)
    block = Signal(object)
    board_status = Signal(object)
    stats_changed = Signal(object)
    open_failed = Signal(str)  # the port could not be opened (a board missing): why, and that it is retried

    def __init__(self, config: BoardConfig, parent: QObject | None = None, drain_rate_hz: float | None = None,
                 history_budget_bytes: int = HISTORY_BUDGET_BYTES) -> None:
        super().__init__(parent)
        self.config = config
        self.t0_monotonic_s = time.monotonic()
        self.history = TraceHistory.for_budget(config.n_channels, history_budget_bytes)
        self._recent: deque[SampleBlock] = deque()
        self._recent_samples = 0
        self.recent_max_samples = max(1, int(RECENT_S * config.rate_hz))
        self.bridge_stats = BridgeStats()
        self._reader: BoardReader | None = None
        self._opener: threading.Thread | None = None
        self._opening: BoardReader | None = None  # the reader the opener thread starts, until adopted
        self._wanted = False
        self._is_connected = False
        self._last_status = BoardStatus("closed", f"board on {config.port} not started", False)
        self.open_error = ""  # why the port could not be opened at the last try ("" once it is open)
        self._last_stats_s = 0.0
        self._bridge = ThreadBridge(self)  # reader/worker thread → GUI thread (queued, in order)
        if drain_rate_hz is None:
            # Twice the board's rate (capped): each frame is delivered within half a frame period. Draining at the
            # board's own rate beats against it (two frames in one drain, none in the next) and the plots, which
            # draw what each drain brings, lost paints: 29.5/s of 30 on a quiet machine, far fewer on a busy one.
            drain_rate_hz = max(DEFAULT_DRAIN_HZ, 2.0 * config.rate_hz)
        self.drain_rate_hz = min(max(drain_rate_hz, 1.0), MAX_DRAIN_HZ)
        self._drain_timer = QTimer(self)
        self._drain_timer.setInterval(int(round(1000 / self.drain_rate_hz)))
        self._drain_timer.timeout.connect(self.drain)
        self._retry_timer = QTimer(self)
        self._retry_timer.setSingleShot(True)
        self._retry_timer.setInterval(int(RETRY_OPEN_S * 1000))
        self._retry_timer.timeout.connect(self._open_async)

    # -- state -----------------------------------------------------------------------------------------------------
    @property
    def channel_names(self) -> tuple[str, ...]:
        return self.config.channel_names

    @property
    def is_connected(self) -> bool:
        return self._is_connected

    @property
    def is_running(self) -> bool:
        """True between :meth:`start` and :meth:`stop` (even while the cable is out)."""
        return self._wanted

    @property
    def last_status(self) -> BoardStatus:
        return self._last_status

    @property
    def stats(self) -> BoardStats:
        """The reader's cumulative counters (CRC errors, resyncs, gaps, reconnects, …)."""
        return self._reader.stats if self._reader is not None else BoardStats()

    def newest_frame_host_s(self) -> float:
        """``time.monotonic()`` of the newest frame the reader thread received, drained or not (−inf: none, or no
        reader). Any thread: it tells a consumer whose blocks come late through a busy GUI thread that the board
        still streams."""
        reader = self._reader
        return reader.newest_frame_host_s() if reader is not None else -math.inf

    def to_session_time(self, host_time_s: np.ndarray) -> np.ndarray:
        """``time.monotonic()`` readings → seconds since :attr:`t0_monotonic_s` (the plots' clock)."""
        return np.asarray(host_time_s, dtype=float) - self.t0_monotonic_s

    # -- life cycle ------------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Open the board (on a worker thread) and start delivering blocks; returns at once."""
        if self._wanted:
            return
        self._wanted = True
        self._drain_timer.start()
        self._open_async()

    def stop(self) -> None:
        """Stop delivering, close the reader and join its threads. Blocks briefly; safe to call twice."""
        self._wanted = False
        self._retry_timer.stop()
        self._drain_timer.stop()
        opener, self._opener = self._opener, None
        if opener is not None:
            opener.join()
        opening, self._opening = self._opening, None
        if opening is not None and opening is not self._reader:
            # Opened, its thread running, but not adopted yet (the adoption is still queued for the GUI thread).
            opening.close()
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.close()
            self.drain_reader(reader)
        self._set_connected(False)

    def close(self) -> None:
        self.stop()

    # -- draining (GUI thread, from the timer) ---------------------------------------------------------------------
    def drain(self) -> SampleBlock | None:
        """Move everything the reader holds into the history and emit it; returns the block (or None)."""
        reader = self._reader
        block = self.drain_reader(reader) if reader is not None else None
        now = time.monotonic()
        if reader is not None and now - self._last_stats_s >= STATS_INTERVAL_S:
            self._last_stats_s = now
            self.stats_changed.emit(reader.stats)
        return block

    def drain_reader(self, reader: BoardReader) -> SampleBlock | None:
        block = reader.read_block()
        if block is None or len(block) == 0:
            return None
        t_s = self.to_session_time(block.host_time_s)
        append_with_gaps(self.history, t_s, block.conductance_s * 1e6, block.gap_before)
        self._keep_recent(block)
        lag_s = time.monotonic() - float(block.host_time_s[-1])
        stats = self.bridge_stats
        stats.blocks += 1
        stats.samples += len(block)
        stats.last_delivery_lag_s = lag_s
        stats.max_delivery_lag_s = max(stats.max_delivery_lag_s, lag_s)
        self.block.emit(block)
        return block

    def _keep_recent(self, block: SampleBlock) -> None:
        self._recent.append(block)
        self._recent_samples += len(block)
        while len(self._recent) > 1 and self._recent_samples - len(self._recent[0]) >= self.recent_max_samples:
            self._recent_samples -= len(self._recent.popleft())

    def recent_blocks(self) -> list[SampleBlock]:
        """The blocks drained in the last ``RECENT_S`` seconds (at the board's rate), oldest first."""
        return list(self._recent)

    # -- opening (worker thread) -----------------------------------------------------------------------------------
    def _open_async(self) -> None:
        if not self._wanted or self._reader is not None or (self._opener and self._opener.is_alive()):
            return
        reader = BoardReader(self.config, on_status=self._on_reader_status)
        self._opening = reader
        self.status.emit(f"opening board on {self.config.port}…")
        self._opener = threading.Thread(target=self._open_reader, args=(reader,), name="board-open", daemon=True)
        self._opener.start()

    def _open_reader(self, reader: BoardReader) -> None:
        """Worker thread: open the port. Errors the user can fix are reported; the GUI retries."""
        try:
            reader.start()
        except (OSError, ValueError, RuntimeError) as exc:
            self._bridge.post(self._open_failed, reader, exc)
            return
        self._bridge.post(self._adopt, reader)

    def _adopt(self, reader: BoardReader) -> None:
        if reader is not self._opening:  # stopped (and perhaps started again) since this reader was opened
            reader.close()
            return
        self._opening = None
        if self._opener is not None:
            self._opener.join()
            self._opener = None
        if not self._wanted:
            reader.close()
            return
        self._reader = reader
        self.open_error = ""
        self._set_connected(_delivers_data(reader.status))

    def _open_failed(self, reader: BoardReader, exc: BaseException) -> None:
        if reader is not self._opening:
            reader.close()
            return
        self._opening = None
        if self._opener is not None:
            self._opener.join()
            self._opener = None
        reader.close()
        if not self._wanted:
            return
        self._set_connected(False)
        text = f"board: {exc} — retrying every {RETRY_OPEN_S:g} s"
        self.open_error = text
        self.open_failed.emit(text)
        self.status.emit(text)
        self._retry_timer.start()

    # -- reader callbacks (reader thread) --------------------------------------------------------------------------
    def _on_reader_status(self, status: BoardStatus) -> None:
        self._bridge.post(self._deliver_status, status)

    def _deliver_status(self, status: BoardStatus) -> None:
        if status.state == "stall":  # an event (the host did not read for a while), not a change of state
            self.board_status.emit(status)
            self.status.emit(status.message)
            return
        self._last_status = status
        # Connected state first: whoever shows the message colours it by ``is_connected`` ("board disconnected …"
        # was drawn green, the bridge still counting the board as connected when the message arrived).
        if status.state != "closed" or not self._wanted:
            self._set_connected(_delivers_data(status))
        self.board_status.emit(status)
        self.status.emit(status.message)

    def _set_connected(self, connected: bool) -> None:
        if connected != self._is_connected:
            self._is_connected = connected
            self.connected.emit(connected)


def _delivers_data(status: BoardStatus) -> bool:
    """Connected in the sense the GUI cares about: a board whose frames are accepted (not a channel mismatch)."""
    return status.connected and status.state != "mismatch"
