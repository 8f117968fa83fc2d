"""The Forces tab's force history estimated again off the GUI thread, when a calibration is loaded or the estimator
changes: the whole history stays, in the new units.

A new calibration changes what every past sample means (a sensor's µS become newtons), and the creep-aware estimator
needs the sensor's past to estimate its present (τ ~ 10² s): so the history is estimated again, from the board's own
conductance history (:attr:`app.gui.board_bridge.BoardBridge.history`, every sample still held at full rate — at 30 Hz
about two hours), with a fresh copy of the pipeline. That takes seconds for a long session: it runs on a worker
thread (:class:`Reestimation`) while the live view and the controller go on with the calibration in force. Then, on
the GUI thread, the blocks that arrived meanwhile are run through the same copy, and the tab switches to it and to
the new history at once (the live pipeline object adopts the copy's state, so the live session and the controller's
force page go on from the re-estimated past, not from a sensor at rest).

The worker yields to the GUI thread after every chunk: it asks the GUI thread's event loop for a turn (``post``) and
waits until that turn has come. A chunk's Python and numpy work holds the interpreter lock, and the GUI thread takes
the lock at every call between Qt and Python (each paint of a plot item, each slot): running freely, the worker took
it back between those calls, and the window had no 5 ms tick for as long as the worker ran (100-800 ms for 70 s of
history, bench_gui_blocking). One chunk per turn of the event loop costs the worker a little time and bounds what a
turn waits to about one chunk.

- :func:`snapshot` and :meth:`Reestimation.finish`: GUI thread.
- :meth:`Reestimation.run`: the worker thread (it touches only its own pipeline copy, arrays and history).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.core.forces_pipeline import US_PER_S, ForcesPipeline
from devices.board import SampleBlock
from widgets.ring_plot import TraceHistory, append_with_gaps

# Samples per estimator call on the worker thread: ~30 µs a sample (one sample a call costs ~0.9 ms), and each call
# holds the interpreter lock for its numpy work: 300 (~10 ms) leaves the GUI thread its turn often enough.
CHUNK_SAMPLES = 300
# Longest wait for the GUI thread's turn after a chunk: a window closed, or an event loop held up this long, does not
# keep the worker waiting for ever.
TURN_WAIT_S = 1.0
RESET = None  # in Reestimation.pending: the board reconnected here (the live pipeline restarted its state)


@dataclass(frozen=True)
class Snapshot:
    """The board's conductance history as it was when the load began: ``session_t_s`` (N,) seconds on the plots'
    clock, ``conductance_us`` (N×C) the history's own float32 µS with NaN rows at gaps (converted a chunk at a time
    by :meth:`conductance_s`, on the worker), ``board_minus_session_s`` what puts a sample on the board's clock (the
    estimator's), ``older_s`` how much older history exists only as min/max buckets (not estimated), ``ceiling_s``
    the readout's ceiling (None: none)."""

    session_t_s: np.ndarray
    conductance_us: np.ndarray
    board_minus_session_s: float
    older_s: float
    ceiling_s: float | None = None

    @property
    def span_s(self) -> float:
        return float(self.session_t_s[-1] - self.session_t_s[0]) if self.session_t_s.size else 0.0

    def conductance_s(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start:stop`` in S (float64). Readings within float32 rounding of the readout's ceiling are put at
        the ceiling (the history stores µS as float32; the estimator's rule tells saturated from above-ceiling to
        1e-9)."""
        conductance_s = self.conductance_us[start:stop].astype(np.float64) / US_PER_S
        ceiling_s = self.ceiling_s
        if ceiling_s is not None:
            with np.errstate(invalid="ignore"):
                conductance_s[np.abs(conductance_s - ceiling_s) <= 1e-6 * ceiling_s] = ceiling_s
        return conductance_s


def snapshot(board: Any, ceiling_s: float | None) -> Snapshot | None:
    """GUI thread: copy what ``board`` (a BoardBridge) holds at full rate, as it is stored (a copy of 2 h × 36
    channels takes a few ms; its conversion to S, ~0.1-0.5 s for that much, is left to the worker). None when it
    holds nothing (no board, or nothing received yet)."""
    history = getattr(board, "history", None)
    recent = board.recent_blocks() if board is not None and hasattr(board, "recent_blocks") else []
    if history is None or len(history) == 0 or not recent:
        return None
    t_s, values_us = history.full_rate()
    last: SampleBlock = recent[-1]
    board_minus_session = float(last.board_time_s[-1]) - float(board.to_session_time(last.host_time_s[-1:])[0])
    oldest, _newest = history.span()
    return Snapshot(t_s, values_us, board_minus_session, max(0.0, float(t_s[0] - oldest)) if t_s.size else 0.0,
                    ceiling_s)


def joined(blocks: Sequence[SampleBlock]) -> SampleBlock | None:
    """One block of ``blocks`` in order (a board's time never runs backwards across blocks, so the estimators take
    them as one: one call instead of one per block)."""
    if not blocks:
        return None
    if len(blocks) == 1:
        return blocks[0]
    gaps = None
    if any(b.gap_before is not None for b in blocks):
        gaps = np.concatenate([b.gap_before if b.gap_before is not None else np.zeros(len(b), dtype=bool)
                               for b in blocks])
    segments = None
    if any(b.clock_segment is not None for b in blocks):
        segments = np.concatenate([b.clock_segment if b.clock_segment is not None
                                   else np.zeros(len(b), dtype=np.int32) for b in blocks])
    return SampleBlock(counts=np.concatenate([b.counts for b in blocks]),
                       conductance_s=np.concatenate([b.conductance_s for b in blocks]),
                       board_time_s=np.concatenate([b.board_time_s for b in blocks]),
                       host_time_s=np.concatenate([b.host_time_s for b in blocks]),
                       seq=np.concatenate([b.seq for b in blocks]),
                       saturated=np.concatenate([b.saturated for b in blocks]),
                       gap_before=gaps, clock_segment=segments)


@dataclass
class Reestimation:
    """One re-estimation: ``pipeline`` (a fresh copy with the calibration and estimator wanted) run over
    ``source`` into a new history of ``history_budget_bytes``; ``pending`` the blocks (or :data:`RESET`) that
    arrived on the GUI thread after the snapshot; ``note`` what the tab says when it is done; ``post(fn)`` calls
    ``fn()`` on the GUI thread at its event loop's next turn (the worker waits for it after each chunk; None: no
    waiting)."""

    pipeline: ForcesPipeline
    source: Snapshot | None
    history_budget_bytes: int
    note: str = ""
    post: Callable[[Callable[[], None]], None] | None = None
    pending: list[SampleBlock | None] = field(default_factory=list)
    history: TraceHistory | None = None
    error: str = ""
    thread: threading.Thread | None = None
    cancelled: threading.Event = field(default_factory=threading.Event)

    def start(self, deliver: Callable[[Reestimation], None]) -> None:
        """GUI thread: run :meth:`run` on a worker thread, then ``deliver(self)`` (from the worker: post it)."""

        def work() -> None:
            self.run()
            if not self.cancelled.is_set():
                deliver(self)

        self.thread = threading.Thread(target=work, name="forces-reestimate", daemon=True)
        self.thread.start()

    def run(self) -> None:
        """Worker thread: the new history, estimated from the snapshot a chunk at a time (cancellable between)."""
        n_channels = len(self.pipeline.channel_names)
        try:
            history = TraceHistory.for_budget(n_channels, self.history_budget_bytes)
            source = self.source
            if source is not None:
                for start in range(0, source.session_t_s.size, CHUNK_SAMPLES):
                    if self.cancelled.is_set():
                        return
                    t_s = source.session_t_s[start:start + CHUNK_SAMPLES]
                    forces = self.pipeline.process(t_s + source.board_minus_session_s,
                                                   source.conductance_s(start, start + CHUNK_SAMPLES))
                    history.append(t_s, forces.display)
                    self._wait_for_gui_turn()
        except (ValueError, ArithmeticError, MemoryError) as exc:
            self.error = f"the history could not be estimated again: {exc}"
            return
        self.history = history

    def _wait_for_gui_turn(self) -> None:
        """Worker: let the GUI thread's event loop come round once (see the module docstring)."""
        if self.post is None:
            return
        turned = threading.Event()
        self.post(turned.set)
        deadline = time.monotonic() + TURN_WAIT_S
        while not turned.wait(0.05) and not self.cancelled.is_set() and time.monotonic() < deadline:
            pass

    def cancel(self) -> None:
        """Any thread: stop at the next chunk; nothing is delivered."""
        self.cancelled.set()

    def join(self) -> None:
        thread = self.thread
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def finish(self, session_time_s: Callable[[np.ndarray], np.ndarray]) -> TraceHistory:
        """GUI thread, once :meth:`run` is done: run the blocks that arrived meanwhile through the pipeline copy and
        into the new history (so it reaches the newest sample); returns that history."""
        self.join()
        history = self.history if self.history is not None else TraceHistory.for_budget(
            len(self.pipeline.channel_names), self.history_budget_bytes)
        segments: list[list[SampleBlock]] = [[]]
        for item in self.pending:
            if item is RESET:
                segments.append([])
            else:
                segments[-1].append(item)
        for k, blocks in enumerate(segments):
            if k:
                self.pipeline.reset()  # as the live pipeline did when the board reconnected
            block = joined(blocks)
            if block is not None:
                forces = self.pipeline.process(block.board_time_s, block.conductance_s, block.saturated)
                append_with_gaps(history, session_time_s(block.host_time_s), forces.display, block.gap_before)
        self.pending.clear()
        self.history = history
        return history
