"""``sensnake record --daq PORT [--baud B] --seconds S --out REC.h5 [--config FILE]`` (SPEC §1, §3.5, §4).

Records the force-sensor board to a recording file, with one progress line on stderr updated in place. The length
``S`` is measured on the board's clock (the data's own time), or on the host clock if the board stops sending, so
a pulled cable cannot make it run forever. Exits non-zero with one line when the port cannot be opened, the board
sends a channel count other than the config's, no frame arrives within :data:`NO_FRAMES_TIMEOUT_S` (board off,
wrong ``--baud``), or CRC errors exceed :data:`CRC_ERROR_FRACTION` of the frames;
the file keeps what was recorded. Ctrl-C stops early and keeps the file. The main thread owns the writer; the
board reader has its own thread.
"""

from __future__ import annotations

import argparse
import queue
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.core.recording import RecordingWriter
from devices import factory
from devices.board import BoardReader, BoardStats, BoardStatus, SampleBlock
from devices.config import load_config
from devices.errors import BoardProtocolError

CRC_ERROR_FRACTION = 0.05
CRC_ERROR_MIN = 10  # a handful of CRC errors (e.g. on plugging in) is not a storm
PROGRESS_INTERVAL_S = 0.25
WAIT_S = 0.1
NO_FRAMES_TIMEOUT_S = 3.0
EXIT_INTERRUPTED = 130


class BoardSilentError(TimeoutError):
    """The port opened but no valid frame arrived."""


class CrcStormError(RuntimeError):
    """Too many frames from the board fail their CRC: the link is bad."""


def run(args: argparse.Namespace) -> int:
    if not args.seconds > 0:
        raise ValueError(f"--seconds must be positive, got {args.seconds}")
    config = load_config(args.config) if args.config else load_config()
    board = replace(config.board, port=args.daq.strip())
    if args.baud is not None:
        if args.baud <= 0:
            raise ValueError(f"--baud must be a positive rate in bps, got {args.baud}")
        board = replace(board, baud=int(args.baud))
    if factory.is_sim(board.port):
        factory.sim_lab(replace(config, board=board))  # the simulated board follows the config's channel list
    out = Path(args.out)
    statuses: queue.SimpleQueue[BoardStatus] = queue.SimpleQueue()
    reader = BoardReader(board, on_status=statuses.put)
    reader.start()  # PortOpenError (an OSError) ends the command with one line
    try:
        writer = RecordingWriter(out, config.source_text, board.channel_names)
    except BaseException:
        reader.close()
        raise
    progress = _Progress(out, args.seconds)
    try:
        _record(reader, writer, statuses, progress, args.seconds)
    except KeyboardInterrupt:
        progress.finish()
        print(f"sensnake record: interrupted; kept {writer.n_daq_samples} frames in {out}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (CrcStormError, BoardProtocolError, BoardSilentError):
        progress.finish()
        raise
    finally:
        reader.close()
        _store_stats(writer, reader.stats)
        writer.close()
    progress.finish()
    stats = reader.stats
    print(f"recorded {writer.n_daq_samples} frames ({writer.duration_s:.1f} s) of {board.n_channels} channels to "
          f"{out}: {stats.crc_errors} CRC errors, {stats.dropped_frames} dropped frames, "
          f"{stats.reconnects} reconnects")
    return 0


def _record(reader: BoardReader, writer: RecordingWriter, statuses: queue.SimpleQueue[BoardStatus],
            progress: _Progress, seconds: float) -> None:
    wall_start = time.monotonic()
    bytes_at_start = reader.stats.bytes_discarded
    board_start: float | None = None
    board_span = 0.0
    last_data_wall = wall_start
    while True:
        _handle_statuses(statuses, writer, progress)
        reader.wait_for_frames(1, WAIT_S)
        block = reader.read_block()
        now = time.monotonic()
        if block is not None:
            last_data_wall = now
            if board_start is None:
                board_start = float(block.board_time_s[0])
            # --seconds is board time: frames drained past it (a late read at a high rate) are not written.
            keep = int(np.searchsorted(block.board_time_s - board_start, seconds + 1e-6, side="right"))
            if keep < len(block):
                if keep:
                    writer.append_daq(_first_frames(block, keep))
                progress.show(seconds, reader.stats, writer.n_daq_samples)
                _handle_statuses(statuses, writer, progress)
                return
            board_span = float(block.board_time_s[-1]) - board_start
            writer.append_daq(block)
        stats = reader.stats
        _store_stats(writer, stats)
        _check_crc(stats, writer)
        if board_start is None and stats.connected and now - wall_start > NO_FRAMES_TIMEOUT_S:
            noise = stats.bytes_discarded - bytes_at_start
            heard = f"only {noise} bytes of noise" if noise else "nothing"
            raise BoardSilentError(
                f"no frames from the board on {reader.board.port} in {NO_FRAMES_TIMEOUT_S:g} s ({heard}): check "
                f"that the board is powered and streaming and that --baud matches it (tried {reader.board.baud})")
        progress.show(board_span, stats, writer.n_daq_samples)
        # The board went quiet (cable pulled): fall back to the host clock for the remaining time.
        if board_span >= seconds or (now - wall_start >= seconds and now - last_data_wall > 1.0):
            _handle_statuses(statuses, writer, progress)
            return


def _first_frames(block: SampleBlock, n: int) -> SampleBlock:
    """The first ``n`` frames of ``block`` (n ≥ 1)."""
    gap = None if block.gap_before is None else block.gap_before[:n]
    return replace(block, counts=block.counts[:n], conductance_s=block.conductance_s[:n],
                               board_time_s=block.board_time_s[:n], host_time_s=block.host_time_s[:n],
                               seq=block.seq[:n], saturated=block.saturated[:n], gap_before=gap)


def _handle_statuses(statuses: queue.SimpleQueue[BoardStatus], writer: RecordingWriter,
                     progress: _Progress) -> None:
    while True:
        try:
            status = statuses.get_nowait()
        except queue.Empty:
            return
        if status.state == "mismatch":
            raise BoardProtocolError(f"{status.message}; the recording {writer.path} keeps what came before")
        if status.state == "disconnected":
            writer.mark_gap(status.host_time_s, status.message)
            progress.note(status.message)
        elif status.state in ("reconnected", "error"):
            writer.log_event(status.message, status.host_time_s, kind=status.state)
            progress.note(status.message)


def _check_crc(stats: BoardStats, writer: RecordingWriter) -> None:
    seen = stats.frames + stats.crc_errors
    if stats.crc_errors >= CRC_ERROR_MIN and stats.crc_errors > CRC_ERROR_FRACTION * seen:
        raise CrcStormError(
            f"{stats.crc_errors} CRC errors in {seen} frames (more than {CRC_ERROR_FRACTION:.0%}): the board link "
            f"is bad — check the cable, its shielding and the baud rate; {writer.path} keeps what was recorded")


def _store_stats(writer: RecordingWriter, stats: BoardStats) -> None:
    if not writer.closed:
        writer.update_stats(stats.crc_errors, stats.dropped_frames, stats.resyncs)


class _Progress:
    """One status line on stderr, rewritten in place at most every PROGRESS_INTERVAL_S."""

    def __init__(self, out: Path, seconds: float) -> None:
        self.out = out
        self.seconds = seconds
        self._last = 0.0
        self._shown = False
        self._interactive = sys.stderr.isatty()  # only a terminal understands the clear-line escape

    def show(self, recorded_s: float, stats: BoardStats, frames: int) -> None:
        now = time.monotonic()
        if now - self._last < PROGRESS_INTERVAL_S:
            return
        self._last = now
        line = (f"recording {self.out.name}: {min(recorded_s, self.seconds):6.1f}/{self.seconds:g} s  "
                f"{frames} frames  {stats.crc_errors} CRC errors  {stats.dropped_frames} dropped")
        clear_to_end = "\x1b[K" if self._interactive else ""
        print(f"\r{line}{clear_to_end}", end="", file=sys.stderr, flush=True)
        self._shown = True

    def note(self, message: str) -> None:
        self.finish()
        print(f"sensnake record: {message}", file=sys.stderr, flush=True)

    def finish(self) -> None:
        if self._shown:
            print(file=sys.stderr, flush=True)
        self._shown = False
