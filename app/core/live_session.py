"""The live board session: board frame → validated sample → model state → {recording, subscribers}. No Qt.

One straight data path, used by ``sensnake record`` and by the GUI's Forces tab alike:

1. :class:`devices.board.BoardReader` (its own thread) parses SPEC §4 frames: resync after garbage, CRC, counts
   within the 12-bit range, channel count as configured, board clock segments. Only verified frames reach step 2.
2. :meth:`LiveSession.process_block` (the controlling thread: the CLI's main thread or the GUI thread) runs the
   force pipeline (:class:`app.core.forces_pipeline.ForcesPipeline`, optional) and the sensor health monitor
   (:class:`models.health.HealthMonitor`), hands the block, its forces and health changes to the running
   :class:`app.core.recorder.Recorder`, then to every subscriber (the tab's plots and body map) as a
   :class:`LiveUpdate`.
3. :meth:`LiveSession.handle_status` and :meth:`LiveSession.handle_stats` turn the reader's link events into gap
   and segment marks and counters in the file, and into user messages; :class:`LinkMonitor` decides when a noisy
   link deserves a loud warning. A noisy link never stops a recording: only the port going away ends one.

:func:`record_timed` is the whole of ``sensnake record`` minus argument parsing and printing: it records for a
given length of board time and says how it ended (:class:`TimedOutcome`), raising a one-line error for the cases
that end it early (board silent, wrong channel count).

Thread use: everything here runs on one controlling thread, except :meth:`LiveSession.post_status` (any thread).
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.core.errors import BoardSilentError
from app.core.forces_pipeline import ForcesBlock, ForcesPipeline
from app.core.recorder import Recorder
from app.core.recording import DEFAULT_MIN_FREE_BYTES
from app.core.run_documents import live_run_start
from devices.board import BoardReader, BoardStats, BoardStatus, SampleBlock
from devices.board_wire import PROTOCOL_VERSION
from devices.config import BoardConfig
from devices.errors import BoardProtocolError
from models.health import HealthMonitor, describe
from models.health import trusted as health_trusted

CRC_WARN_FRACTION = 0.05  # of the frames seen in the window: above this the link is bad, say so loudly
CRC_WARN_MIN = 10  # a handful of CRC errors (e.g. on plugging in) is not a storm
LINK_WINDOW_S = 5.0
WARN_REPEAT_S = 10.0
NO_FRAMES_TIMEOUT_S = 3.0
QUIET_GONE_S = 1.0  # no frame for this long at the end of a timed recording: the board is gone
MISMATCH_GIVE_UP_S = 2.0  # only frames of the wrong channel count for this long: the config does not fit the board
WAIT_S = 0.1
TOLD_STATES = ("disconnected", "reconnected", "error")  # reader states worth a line to the user


# -- link health -------------------------------------------------------------------------------------------------
class LinkMonitor:
    """Judges the board link from the reader's cumulative counters over the last :data:`LINK_WINDOW_S` seconds.

    :meth:`update` returns a warning sentence when CRC errors, garbage or out-of-range frames exceed
    :data:`CRC_WARN_FRACTION` of the frames (at most every :data:`WARN_REPEAT_S`), else None. Never stops anything.
    """

    def __init__(self, port: str) -> None:
        self.port = port
        self._history: list[tuple[float, BoardStats]] = []
        self._last_warning_s = -np.inf
        self.warnings = 0
        self.level = "ok"

    def update(self, stats: BoardStats, now_s: float | None = None) -> str | None:
        now = time.monotonic() if now_s is None else now_s
        self._history.append((now, stats))
        while len(self._history) > 2 and now - self._history[1][0] >= LINK_WINDOW_S:
            self._history.pop(0)
        _, old = self._history[0]
        bad = (stats.crc_errors - old.crc_errors) + (stats.out_of_range_frames - old.out_of_range_frames)
        seen = bad + stats.frames - old.frames
        storm = bad >= CRC_WARN_MIN and bad > CRC_WARN_FRACTION * max(seen, 1)
        self.level = "error" if storm else ("warn" if stats.crc_errors or stats.dropped_frames else "ok")
        if not storm or now - self._last_warning_s < WARN_REPEAT_S:
            return None
        self._last_warning_s = now
        self.warnings += 1
        return (f"WARNING: bad board link on {self.port}: {bad} corrupt frames in the last {seen} "
                f"({bad / max(seen, 1):.0%}) — check the cable, its shielding and the baud rate; recording goes on "
                "and keeps every good frame")


def describe_stats(stats: BoardStats) -> str:
    """The counters in one line for the user."""
    parts = [f"{stats.crc_errors} CRC errors", f"{stats.resyncs} resyncs", f"{stats.dropped_frames} dropped frames"]
    if stats.out_of_range_frames:
        parts.append(f"{stats.out_of_range_frames} out-of-range frames")
    if stats.channel_mismatches:
        parts.append(f"{stats.channel_mismatches} frames with the wrong channel count")
    if stats.reconnects:
        parts.append(f"{stats.reconnects} reconnects ({stats.missing_s:.1f} s missing)")
    return ", ".join(parts)


# -- the session ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LiveUpdate:
    """What one board block became: the block itself, its forces (None without a pipeline), and the channels whose
    health changed (indices; empty when none)."""

    block: SampleBlock
    forces: ForcesBlock | None
    health_changed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    problem: str | None = None  # why this block's forces could not be estimated, if so


class LiveSession:
    """The board's live data path; see the module docstring. ``LiveSession(config.board, pipeline, health)``."""

    def __init__(self, board: BoardConfig, pipeline: ForcesPipeline | None = None,
                 health: HealthMonitor | None = None, t0_monotonic_s: float | None = None,
                 force_page: Any = None) -> None:
        self.board = board
        self.channel_names = tuple(board.channel_names)
        self.pipeline = pipeline
        if pipeline is not None:
            pipeline.set_readout(board.r_c_ohm)  # the one validation rule, with this board's ceiling 1/R_C
        self.health = health
        self.t0_monotonic_s = time.monotonic() if t0_monotonic_s is None else t0_monotonic_s
        self.link = LinkMonitor(board.port)
        self.recorder: Recorder | None = None
        self.stats = BoardStats()
        self._subscribers: list[Callable[[LiveUpdate], None]] = []
        self._statuses: queue.SimpleQueue[BoardStatus] = queue.SimpleQueue()
        self.last_status: BoardStatus | None = None
        self.samples = 0
        # where each block's latest forces go for a feedback controller (app.core.force_control.ForcePage)
        self.force_page = force_page

    # -- subscribers -----------------------------------------------------------------------------------------------
    def subscribe(self, callback: Callable[[LiveUpdate], None]) -> None:
        """Call ``callback(update)`` for every processed block, on the controlling thread."""
        self._subscribers.append(callback)

    def unsubscribe(self, callback: Callable[[LiveUpdate], None]) -> None:
        if callback in self._subscribers:
            self._subscribers.remove(callback)

    # -- the data path ---------------------------------------------------------------------------------------------
    def session_time_s(self, host_time_s: np.ndarray) -> np.ndarray:
        return np.asarray(host_time_s, dtype=float) - self.t0_monotonic_s

    def process_block(self, block: SampleBlock) -> LiveUpdate:
        """A block of verified samples: estimate forces, update health, record, tell subscribers."""
        forces = problem = None
        if self.pipeline is not None:
            forces = self.pipeline.process(block.board_time_s, block.conductance_s, block.saturated)
            problem = self.pipeline.last_block_problem
        changed = np.zeros(0, dtype=np.intp)
        if self.health is not None:
            report = self.health.update(self.session_time_s(block.host_time_s), block.conductance_s,
                                        block.saturated)
            if report is not None and report.changed.size:
                changed = np.asarray(report.changed, dtype=np.intp)
        self.samples += len(block)
        if self.force_page is not None and forces is not None and len(block):
            # the latest frame's forces, stamped with when it reached the host; a channel the health monitor flags
            # (any flag that means the reading cannot be trusted) may not drive a correction
            trusted = np.isfinite(forces.force_n[-1])
            if self.health is not None:
                trusted &= health_trusted(self.health.flags)
            self.force_page.publish(float(block.host_time_s[-1]), forces.force_n[-1], trusted)
        recorder = self.recorder
        if recorder is not None and recorder.is_active:
            if forces is not None and recorder.with_forces:
                recorder.add_block(block, forces.force_n, forces.status)
            else:
                recorder.add_block(block)
            if problem:
                recorder.log_event(problem, kind="forces")
            if changed.size and self.health is not None:
                flags = self.health.flags
                for i in changed:
                    word = describe(int(flags[i])) if flags[i] else "ok"
                    recorder.log_event(f"{self.channel_names[i]}: {word}", kind="health")
        update = LiveUpdate(block=block, forces=forces, health_changed=changed, problem=problem)
        for callback in list(self._subscribers):
            callback(update)
        return update

    def post_status(self, status: BoardStatus) -> None:
        """For a reader's ``on_status`` (reader thread): queue it for :meth:`pending_statuses`. Any thread."""
        self._statuses.put(status)

    def pending_statuses(self) -> list[BoardStatus]:
        """Statuses posted since the last call, each already applied with :meth:`handle_status`."""
        out: list[BoardStatus] = []
        while True:
            try:
                status = self._statuses.get_nowait()
            except queue.Empty:
                return out
            self.handle_status(status)
            out.append(status)

    def handle_status(self, status: BoardStatus) -> None:
        """A reader state change: gaps and reconnects are marked in the recording; health restarts after a gap."""
        self.last_status = status
        recorder = self.recorder
        active = recorder is not None and recorder.is_active
        if status.state in ("disconnected", "mismatch", "error"):
            if active:
                assert recorder is not None
                recorder.mark_gap(status.host_time_s, status.message)
        elif status.state == "stall":
            if active:
                assert recorder is not None
                recorder.log_event(status.message, status.host_time_s, kind="stall")
        elif status.state == "reconnected":
            if self.health is not None:
                self.health.reset()
            if self.pipeline is not None:
                self.pipeline.reset()  # the board restarted: its creep state is stale
            if active:
                assert recorder is not None
                recorder.log_event(status.message, status.host_time_s, kind="reconnect")

    def handle_stats(self, stats: BoardStats) -> str | None:
        """The reader's counters (about once a second or every loop): stored in the recording; returns a loud
        warning sentence when the link has turned bad (see :class:`LinkMonitor`), else None."""
        self.stats = stats
        warning = self.link.update(stats)
        recorder = self.recorder
        if recorder is not None and recorder.is_active:
            recorder.update_stats(stats)
            if warning:
                recorder.log_event(warning, kind="link")
        return warning

    # -- recording ---------------------------------------------------------------------------------------------
    def start_recording(self, path: str | Path, config_text: str, *, with_robot: bool = False,
                        n_joints: int = 12, min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
                        calibration_json: str | None = None, with_forces: bool | None = None,
                        on_failed: Callable[[str], None] | None = None,
                        t0_monotonic_s: float | None = None, note: str = "",
                        run_start: Mapping[str, Any] | None = None) -> Recorder:
        """Start a recorder fed by this session. Forces are stored when a pipeline estimates them (with the
        calibration in force, see :meth:`recording_calibration_json`), unless ``with_forces`` is False.
        ``t0_monotonic_s`` (default: now) is the recording's ``started``; frames that arrived before it are not
        recorded. ``note``: the operator's note, kept in the recording's ``run_start``; ``run_start``: the whole
        RunStart document of a plan that knows its condition (a robot trial's), instead of a ``record`` run's."""
        if self.recorder is not None and self.recorder.running:
            raise RuntimeError(f"already recording to {self.recorder.path}")
        if calibration_json is None and with_forces is not False:
            calibration_json = self.recording_calibration_json()
        recorder = Recorder(path, config_text, self.channel_names, calibration_json=calibration_json,
                            with_robot=with_robot, n_joints=n_joints, min_free_bytes=min_free_bytes,
                            t0_monotonic_s=t0_monotonic_s, on_failed=on_failed,
                            run_start=run_start if run_start is not None else
                            live_run_start(config_text, calibration_json, note=note))
        recorder.start()
        self.attach_recorder(recorder)
        return recorder

    def attach_recorder(self, recorder: Recorder) -> None:
        """Feed a started recorder from now on (the GUI builds it inside its Qt face); logs the session's state at
        the start: calibration, sensor health, a board not connected, the link counters so far."""
        if self.recorder is not None and self.recorder.running and self.recorder is not recorder:
            raise RuntimeError(f"already recording to {self.recorder.path}")
        self.recorder = recorder
        if self.pipeline is not None:
            recorder.log_event(f"calibration: {self.pipeline.summary()[0]}; estimator "
                               f"{self.pipeline.estimator_kind}")
        if self.health is not None:
            flags = self.health.flags
            bad = [f"{n}: {describe(int(f))}" for n, f in zip(self.channel_names, flags) if f]
            if bad:
                recorder.log_event("health at start: " + "; ".join(bad), kind="health")
        status = self.last_status
        if status is not None and not status.connected:
            recorder.mark_gap(time.monotonic(), "board not connected when the recording started")
        recorder.update_stats(self.stats)

    def stop_recording(self, exit_status: str = "success", reason: str = "") -> Recorder | None:
        """Flush and close the running recording (joins its writer thread); returns it. ``exit_status`` and
        ``reason``: how the run ended, for its ``run_stop`` (``abort`` when stopped early)."""
        recorder = self.recorder
        if recorder is not None:
            recorder.update_stats(self.stats)
            recorder.stop(exit_status, reason)
        return recorder

    def add_robot_states(self, states: Sequence[Any]) -> None:
        recorder = self.recorder
        if recorder is not None and recorder.is_active:
            recorder.add_robot_states(states)

    def recording_calibration_json(self) -> str | None:
        """The calibration in force, stored with a recording's forces; None when no sensor gets a force (no file
        loaded: the recording keeps conductance only)."""
        pipeline = self.pipeline
        if pipeline is None or not pipeline.estimated.any():
            return None
        return pipeline.calibration_json


# -- a timed recording (sensnake record) ---------------------------------------------------------------------------
@dataclass(frozen=True)
class TimedOutcome:
    """How a timed recording ended. ``recorded_s`` is board time covered (gaps included), ``missing_s`` the time
    the board's port was gone, ``gone_for_s`` how long it had been gone (or silent) when the recording ended —
    0.0 when it ended with the board streaming."""

    frames: int
    recorded_s: float
    stats: BoardStats
    missing_s: float
    gone_for_s: float
    gone_since_s: float | None  # recording time (s) when the board went away for good, if it did
    kept: bool
    error: str | None  # the recorder's write failure, if any


def _frames(block: SampleBlock, part: slice) -> SampleBlock:
    """The frames ``part`` of ``block``."""
    def cut(values: np.ndarray | None) -> np.ndarray | None:
        return None if values is None else values[part]

    return replace(block, counts=block.counts[part], conductance_s=block.conductance_s[part],
                   board_time_s=block.board_time_s[part], host_time_s=block.host_time_s[part], seq=block.seq[part],
                   saturated=block.saturated[part], gap_before=cut(block.gap_before),
                   clock_segment=cut(block.clock_segment))


def record_timed(live: LiveSession, reader: BoardReader, seconds: float,
                 on_progress: Callable[[float, BoardStats, int], None] | None = None,
                 on_message: Callable[[str], None] | None = None,
                 no_frames_timeout_s: float = NO_FRAMES_TIMEOUT_S) -> TimedOutcome:
    """Record ``seconds`` of board time through ``live`` (whose recorder is running) from a started ``reader``.

    Board time runs on across re-plugs (the gap is measured by the host clock), so a pulled cable cannot make the
    recording run forever, and a board that comes back is recorded on. Noisy links are counted and warned about,
    never a reason to stop. Raises :class:`BoardSilentError` when no frame arrives within ``no_frames_timeout_s``, :class:`BoardProtocolError` when the board sends only frames of the wrong channel
    count (at the start, or for :data:`MISMATCH_GIVE_UP_S`). Ends (returns) when ``seconds`` are covered, or — on
    the host clock — when they have passed with the board gone. KeyboardInterrupt passes through untouched.
    Controlling thread only.
    """
    say = on_message or (lambda _text: None)
    wall_start = time.monotonic()
    bytes_at_start = reader.stats.bytes_discarded
    board_start: float | None = None
    first_host: float | None = None
    recorded_s = 0.0
    last_data_wall = wall_start
    mismatch_since: float | None = None
    recorder = live.recorder
    recording_start = recorder.t0_monotonic_s if recorder is not None else wall_start
    while True:
        for status in live.pending_statuses():
            if status.state in TOLD_STATES or (status.state == "mismatch" and board_start is not None):
                say(status.message)  # a mismatch before any good frame ends the recording: said once, below
            if status.state == "mismatch":
                mismatch_since = mismatch_since or status.host_time_s
            elif status.state in ("connected", "reconnected"):
                mismatch_since = None
        reader.wait_for_frames(1, WAIT_S)
        block = reader.read_block()
        now = time.monotonic()
        if block is not None and board_start is None:
            # Frames sampled before the recording started (a board that held them until the port was read) are
            # not part of it: the S seconds start at the first frame the recording keeps.
            first = int(np.searchsorted(block.host_time_s, recording_start, side="left"))
            if first >= len(block):
                last_data_wall = now
                block = None
            elif first:
                block = _frames(block, slice(first, None))
        if block is not None:
            last_data_wall = now
            mismatch_since = None
            if board_start is None:
                board_start = float(block.board_time_s[0])
                first_host = float(block.host_time_s[0])
            # Board time decides the length: frames drained past it (a late read at a high rate) are not written.
            keep = int(np.searchsorted(block.board_time_s - board_start, seconds + 1e-6, side="right"))
            if keep:
                live.process_block(block if keep == len(block) else _frames(block, slice(keep)))
            recorded_s = min(float(block.board_time_s[keep - 1 if keep else 0]) - board_start, seconds)
            if keep < len(block):
                recorded_s = seconds
        stats = reader.stats
        warning = live.handle_stats(stats)
        if warning:
            say(warning)
        if recorder is not None and recorder.error:
            break
        if board_start is None:
            if mismatch_since is not None and (stats.channel_mismatches or stats.version_mismatches):
                raise BoardProtocolError(f"{live.last_status.message if live.last_status else 'channel mismatch'}")
            if stats.connected and now - wall_start > no_frames_timeout_s:
                if stats.version_mismatches:  # whole frames of another protocol: not a baud rate problem
                    raise BoardProtocolError(
                        f"board on {reader.board.port} speaks protocol version {stats.other_version}; this app "
                        f"reads version {PROTOCOL_VERSION} (SPEC §4): update the board's firmware or SenSnake "
                        "Studio so they match")
                noise = stats.bytes_discarded - bytes_at_start
                heard = f"only {noise} bytes of noise" if noise else "nothing"
                raise BoardSilentError(
                    f"no frames from the board on {reader.board.port} in {no_frames_timeout_s:g} s ({heard}): "
                    "check that the board is powered and streaming and that --baud matches it (tried "
                    f"{reader.board.baud})")
        elif mismatch_since is not None and now - mismatch_since > MISMATCH_GIVE_UP_S:
            message = live.last_status.message if live.last_status else "channel count mismatch"
            raise BoardProtocolError(f"{message} (for {now - mismatch_since:.1f} s)")
        if on_progress is not None:
            on_progress(recorded_s, stats, live.samples)
        if recorded_s >= seconds:
            break
        # The board is gone or silent: the host clock decides when the time is up.
        if first_host is not None and now - first_host >= seconds and now - last_data_wall > QUIET_GONE_S:
            break
    for status in live.pending_statuses():
        if status.state in TOLD_STATES:
            say(status.message)
    stats = reader.stats
    live.handle_stats(stats)
    now = time.monotonic()
    gone_for = 0.0
    gone_since = None
    if board_start is not None and (stats.disconnected_since_s is not None or now - last_data_wall > QUIET_GONE_S):
        since = stats.disconnected_since_s if stats.disconnected_since_s is not None else last_data_wall
        gone_for = now - since
        gone_since = since - live.t0_monotonic_s
    return TimedOutcome(frames=live.samples, recorded_s=recorded_s, stats=stats, missing_s=stats.missing_s,
                        gone_for_s=gone_for, gone_since_s=gone_since, kept=False,
                        error=recorder.error if recorder is not None else None)
