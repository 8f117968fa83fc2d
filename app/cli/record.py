"""``sensnake record --daq PORT [--baud B] --seconds S --out REC.h5 [--config FILE]`` (SPEC §1, §3.5, §4); without
``--daq`` the port is the ``--config`` file's ``[board] port``.

A thin face over the core: :class:`app.core.live_session.LiveSession` (the same data path the GUI's Forces tab
uses: verified frames → health → :class:`app.core.recorder.Recorder`) driven by
:func:`app.core.live_session.record_timed`. This module parses arguments, prints one progress line on stderr
(updated in place) and turns the outcome into an exit code.

What the user gets: ``S`` seconds of board time (gaps included). A noisy link (garbage, CRC errors, dropped frames,
out-of-range frames) is counted, warned about loudly and written into the file; every good frame is kept. A pulled
cable is marked as a gap and the board is picked up again when it comes back (a new clock segment); if the recording
ends with the board gone, the command exits 1 saying how long it was missing. Ctrl-C, SIGTERM and SIGHUP stop
early, keep the file and exit 128 + the signal number. A recording that never receives a frame does not touch an
existing file at ``--out``. Exits 1 with one line when the port cannot be opened, no frame arrives within
:data:`NO_FRAMES_TIMEOUT_S` (board off, wrong ``--baud``) or the board's channel count differs from the config's.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

from app.cli._robot import lab_config, port_from
from app.core import live_session
from app.core.errors import BoardGoneError, BoardSilentError
from app.core.live_session import LiveSession, TimedOutcome, describe_stats, record_timed
from app.core.lsl_link import LiveTake, LslLinks
from devices import factory
from devices.board import BoardReader, BoardStats
from devices.config import MAX_BAUD, LabConfig, load_config, mocap_stream_spec
from devices.errors import BoardProtocolError
from models.health import HealthMonitor

PROGRESS_INTERVAL_S = 0.25
NO_FRAMES_TIMEOUT_S = live_session.NO_FRAMES_TIMEOUT_S
EXIT_INTERRUPTED = 130
STOP_SIGNALS = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s)


class StopSignal(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread so the recording ends like Ctrl-C (file kept)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_stop(signum: int, _frame: object) -> None:
    raise StopSignal(signum)


def run(args: argparse.Namespace) -> int:
    if not args.seconds > 0:
        raise ValueError(f"--seconds must be positive, got {args.seconds}")
    named = lab_config(args)
    port = port_from(args, "daq", "board", named)  # --daq, else the config's [board] port
    config = named if named is not None else load_config()
    board = replace(config.board, port=port)
    if args.baud is not None:
        if args.baud <= 0:
            raise ValueError(f"--baud must be a positive rate in bps, got {args.baud}")
        if args.baud > MAX_BAUD:
            raise ValueError(f"--baud {args.baud} is faster than any serial port here (at most {MAX_BAUD} bps)")
        board = replace(board, baud=int(args.baud))
    if factory.is_sim(board.port):
        factory.sim_lab(replace(config, board=board))  # the simulated board follows the config's channel list
    out = Path(args.out)
    live = LiveSession(board, health=HealthMonitor(board.n_channels, board.rate_hz))
    reader = BoardReader(board, on_status=live.post_status)
    links = LslLinks(live, config.mocap, config.robot.axes)
    spec = mocap_stream_spec(getattr(args, "mocap", None) or config.lab.mocap)
    previous = {s: signal.signal(s, _raise_stop) for s in STOP_SIGNALS}
    progress = _Progress(out, args.seconds)
    try:
        if spec:  # before anything is recorded: a stream that does not answer ends the command
            links.adopt(links.open_inlet(spec))
            inlet = links.inlet
            assert inlet is not None
            print(f"sensnake record: motion capture from LSL stream {inlet.stream_name!r} ({len(inlet.channels)} "
                  f"channels, {inlet.rate_hz:g} Hz)", file=sys.stderr)
        links.publish(getattr(args, "lsl_out", False))
        started = time.monotonic()  # before the port opens: every frame is recorded, at time_s >= 0
        reader.start()  # PortOpenError (an OSError) ends the command with one line
        recorder = live.start_recording(out, config.source_text, t0_monotonic_s=started,
                                        note=getattr(args, "note", "") or "")
        links.start(recorder)
        try:
            outcome = record_timed(live, reader, args.seconds, on_progress=progress.show, on_message=progress.note,
                                   no_frames_timeout_s=NO_FRAMES_TIMEOUT_S)
        except StopSignal as stop:
            take = links.stop(recorder, close_inlet=True)
            code = _interrupted(live, reader, progress, out, 128 + stop.signum, f"terminated by {stop}")
            _write_take(take, out, config, started, recorder.kept)
            return code
        except KeyboardInterrupt:
            take = links.stop(recorder, close_inlet=True)
            code = _interrupted(live, reader, progress, out, EXIT_INTERRUPTED, "interrupted")
            _write_take(take, out, config, started, recorder.kept)
            return code
        except (BoardProtocolError, BoardSilentError):
            progress.finish()
            _close(live, reader)
            raise
        take = links.stop(recorder, close_inlet=True)  # the take ends before the recording closes
        _close(live, reader)
    finally:
        reader.close()
        links.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    progress.finish()
    outcome = replace(outcome, kept=recorder.kept, error=recorder.error)
    code = _report(outcome, out, board.n_channels)
    _write_take(take, out, config, started, recorder.kept)
    return code


def _write_take(take: LiveTake | None, out: Path, config: LabConfig, started: float, kept: bool) -> None:
    """``/mocap`` written into the closed recording from what the inlet received."""
    if take is None or not kept:
        return
    result = take.write(out, started, config.mocap, config.robot.axes)
    print(take.summary(result, out))


def _close(live: LiveSession, reader: BoardReader, exit_status: str = "success", reason: str = "") -> None:
    reader.close()
    live.pending_statuses()
    live.handle_stats(reader.stats)
    live.stop_recording(exit_status, reason)


def _interrupted(live: LiveSession, reader: BoardReader, progress: _Progress, out: Path, code: int,
                 why: str) -> int:
    # A second signal while the file is closed must not cut the close short: ignore them from here on.
    for s in (signal.SIGINT, *STOP_SIGNALS):
        signal.signal(s, signal.SIG_IGN)
    progress.finish()
    _close(live, reader, "abort", why)
    recorder = live.recorder
    frames = recorder.n_daq_samples if recorder is not None else 0
    where = f"kept {frames} frames in {out}" if recorder is not None and recorder.kept else \
        f"no frames recorded; {out} not written"
    print(f"sensnake record: {why}; {where}", file=sys.stderr)
    return code


def _report(outcome: TimedOutcome, out: Path, n_channels: int) -> int:
    if outcome.error:
        raise OSError(outcome.error)
    stats = outcome.stats
    summary = (f"recorded {outcome.frames} frames ({outcome.recorded_s:.1f} s) of {n_channels} channels to {out}: "
               f"{describe_stats(stats)}")
    if outcome.gone_for_s > 0.0:
        since = f" since {outcome.gone_since_s:.1f} s" if outcome.gone_since_s is not None else ""
        raise BoardGoneError(
            f"the board on the --daq port was gone{since} and still missing when the recording ended "
            f"({outcome.gone_for_s:.1f} s missing at the end, {outcome.missing_s:.1f} s in all); {out} keeps the "
            f"{outcome.frames} frames received before ({describe_stats(stats)})")
    print(summary)
    return 0


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
        gone = ""
        if stats.disconnected_since_s is not None:
            gone = f"  BOARD MISSING {now - stats.disconnected_since_s:.1f} s"
        line = (f"recording {self.out.name}: {min(recorded_s, self.seconds):6.1f}/{self.seconds:g} s  "
                f"{frames} frames  {stats.crc_errors} CRC errors  {stats.dropped_frames} dropped{gone}")
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
