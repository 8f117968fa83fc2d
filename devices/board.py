"""The multiplexing force-sensor board: wire protocol (SPEC §4), readout circuit, and a threaded reader.

:class:`FrameParser` turns a byte stream into verified frames: it resynchronises on the sync bytes after garbage,
checks version, channel count and CRC-16/CCITT-FALSE, and never hands out a frame whose CRC is wrong or whose counts
exceed the 12-bit ADC's range (a CRC-valid frame with a count above 4095 is corrupt all the same). It counts every CRC
error, out-of-range frame, resync, ``seq`` gap and discarded byte.

:class:`BoardReader` owns one reader thread per board: it opens the port through :func:`devices.factory.open_serial`
(so ``sim`` and real ports share this code), parses frames into a preallocated ring, and survives a pulled cable by
reopening the port every :data:`RECONNECT_INTERVAL_S` and marking the gap. A board that comes back (re-plugged or
power-cycled) restarts its clock at 0: that starts a new clock segment, never a 2³² µs wrap. Frames whose channel
count differs from the configured board are counted and never stored. Consumers drain the ring with
:meth:`BoardReader.read_block`, which returns a :class:`SampleBlock` with counts, conductance and time stamps.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import serial

from devices import factory

# The wire format and readout circuit live in devices.board_wire (below the port factory and the simulated lab);
# their names stay importable from here, the board's public module.
from devices.board_wire import (  # noqa: F401 - re-exported
    BITS_PER_BYTE,
    CRC_SIZE,
    FLAG_SATURATED,
    HEADER_SIZE,
    MAX_CHANNELS,
    PROTOCOL_VERSION,
    SEQ_MODULUS,
    SYNC,
    T_US_MODULUS,
    conductance_from_counts,
    counts_from_conductance,
    crc16_ccitt_false,
    crc16_ccitt_false_table,
    encode_frame,
    saturated_from_counts,
)
from devices.board_wire import CRC_STRUCT as _CRC
from devices.board_wire import HEADER_STRUCT as _HEADER
from devices.config import BoardConfig
from devices.errors import BoardProtocolError, PortOpenError

ADC_MAX_COUNTS = 4095  # SPEC §4: 12-bit readings; a CRC-valid frame above this is corrupt

RECONNECT_INTERVAL_S = 0.5
READ_TIMEOUT_S = 0.02
IDLE_POLL_S = 0.004
STALL_S = 1.0  # a frame read this long after its board time: the host stalled (a stall event)
MAX_CLOCK_DRIFT = 5e-4  # s/s: the board's and the host's clocks differ by less (crystals: ~50 ppm)
FRESH_BACKLOG_S = 0.05  # reads this soon after a board clock's first frames hold the rest of its backlog
PACE_SPAN_S = 1.0  # host seconds of frames over which the board clock's pace is measured
FAST_BOARD_PACE = 1.5  # board seconds per host second above which the board's clock runs fast on purpose (a simulated
#                        lab at N× real time); below it the pace is taken as the host's own
MAX_READ_BYTES = 1 << 16
FULL_BUFFER_BYTES = 4000  # a read this long may have emptied the driver's buffer with more behind it
DEFAULT_RING_SECONDS = 20.0
MIN_RING_FRAMES = 256


# -- parser ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """One verified board frame. ``counts`` are 12-bit ADC readings, uint16, shape (n,)."""

    seq: int
    t_us: int
    flags: int
    counts: np.ndarray


class FrameParser:
    """Incremental SPEC §4 frame parser. Not thread-safe: feed it from one thread.

    Counters (all cumulative): ``frames`` delivered, ``crc_errors`` (a header that looked valid but whose CRC did not
    match), ``bad_headers`` (sync found but version or ``n`` impossible), ``resyncs`` (times the parser had to search
    for the next sync instead of finding it where the previous frame ended), ``seq_gaps`` (a delivered frame whose
    ``seq`` is not the previous + 1, modulo 2³²), ``dropped_frames`` (frames missing inside those gaps),
    ``duplicate_frames`` (a CRC-valid frame repeating the previous one's ``seq``: dropped, not a gap),
    ``bytes_discarded`` (bytes skipped while searching), ``out_of_range_frames`` (a CRC-valid frame with a count
    above ``max_count``: impossible for the ADC, so corrupt; dropped whole), ``version_mismatches`` (a CRC-valid
    frame in another protocol version, ``other_version``: the board speaks it; dropped). Invariant:
    ``bytes_received == bytes_in_frames + bytes_discarded + bytes_pending``.
    """

    def __init__(self, max_channels: int = MAX_CHANNELS, max_count: int = ADC_MAX_COUNTS) -> None:
        self.max_channels = max_channels
        self.max_count = max_count
        self._buf = bytearray()
        self._last_seq: int | None = None
        self._in_sync = True  # a fresh stream is expected to start on a frame
        self.frames = 0
        self.crc_errors = 0
        self.bad_headers = 0
        self.resyncs = 0
        self.seq_gaps = 0
        self.dropped_frames = 0
        self.duplicate_frames = 0
        self.bytes_discarded = 0
        self.out_of_range_frames = 0
        self.version_mismatches = 0  # CRC-valid frames in another protocol version (dropped)
        self.other_version: int | None = None  # the last such version
        self.bytes_received = 0
        self.bytes_in_frames = 0

    @property
    def bytes_pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def reset_stream(self) -> None:
        """Forget buffered bytes and the last ``seq`` (after a reconnect); counters are kept."""
        self.bytes_discarded += len(self._buf)
        self._buf.clear()
        self._last_seq = None
        self._in_sync = True

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Append ``data`` and return every complete, verified frame it completes, in stream order."""
        self.bytes_received += len(data)
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        pos = 0
        end = len(buf)
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # Keep a trailing 0xA5: it may be the first half of the next sync.
                keep_from = end - 1 if end > pos and buf[end - 1] == SYNC[0] else end
                self._discard(keep_from - pos)
                pos = keep_from
                break
            if start > pos:
                self._discard(start - pos)
            pos = start
            if end - pos < HEADER_SIZE:
                break
            version, flags, seq, t_us, n = _HEADER.unpack_from(buf, pos + 2)
            if version != PROTOCOL_VERSION and 1 <= n <= self.max_channels:
                # A whole frame with a valid CRC in another protocol version is a board that speaks it, not noise.
                other_end = pos + HEADER_SIZE + 2 * n + CRC_SIZE
                if other_end > end:
                    break  # wait for the rest: it may prove the version
                (crc_other,) = _CRC.unpack_from(buf, other_end - CRC_SIZE)
                if crc16_ccitt_false(memoryview(buf)[pos + 2:other_end - CRC_SIZE]) == crc_other:
                    self.version_mismatches += 1
                    self.other_version = version
                    self._discard(other_end - pos)
                    pos = other_end
                    continue
            if version != PROTOCOL_VERSION or not 1 <= n <= self.max_channels:
                self.bad_headers += 1
                self._discard(1)
                pos += 1
                continue
            frame_end = pos + HEADER_SIZE + 2 * n + CRC_SIZE
            if frame_end > end:
                # Garbage that looks like a header with a large n would make us wait for up to 2 KB (most of a
                # second on a 36-channel board). A complete, CRC-valid frame further on proves it false.
                later = self._next_valid_frame(buf, pos + 1, end)
                if later < 0:
                    break
                self.bad_headers += 1
                self._discard(later - pos)
                pos = later
                continue
            (crc_wire,) = _CRC.unpack_from(buf, frame_end - CRC_SIZE)
            if crc16_ccitt_false(memoryview(buf)[pos + 2:frame_end - CRC_SIZE]) != crc_wire:
                self.crc_errors += 1
                self._discard(1)
                pos += 1
                continue
            counts = np.frombuffer(buf, dtype="<u2", count=n, offset=pos + HEADER_SIZE).astype(np.uint16)
            if int(counts.max()) > self.max_count:
                # A 12-bit ADC cannot read this: the frame is corrupt despite its CRC. Skip it whole (its bytes
                # were a frame, so the stream is still in step); its seq shows up as a gap.
                self.out_of_range_frames += 1
                self.bytes_in_frames += frame_end - pos
                pos = frame_end
                continue
            if self._last_seq is not None and seq == self._last_seq:
                # The same frame again (a board or adapter repeating itself): one sample, once. Counted, dropped,
                # and not a gap: the next frame follows it by one.
                self.duplicate_frames += 1
                self.bytes_in_frames += frame_end - pos
                pos = frame_end
                continue
            frames.append(Frame(seq=seq, t_us=t_us, flags=flags, counts=counts))
            self._count_seq(seq)
            self.frames += 1
            self.bytes_in_frames += frame_end - pos
            self._in_sync = True
            pos = frame_end
        del buf[:pos]
        return frames

    def _next_valid_frame(self, buf: bytearray, start: int, end: int) -> int:
        """Offset of the first complete frame with a valid CRC at or after ``start``, or -1."""
        at = buf.find(SYNC, start)
        while at >= 0 and at + HEADER_SIZE <= end:
            version, _, _, _, n = _HEADER.unpack_from(buf, at + 2)
            frame_end = at + HEADER_SIZE + 2 * n + CRC_SIZE
            if version == PROTOCOL_VERSION and 1 <= n <= self.max_channels and frame_end <= end:
                (crc_wire,) = _CRC.unpack_from(buf, frame_end - CRC_SIZE)
                if crc16_ccitt_false(memoryview(buf)[at + 2:frame_end - CRC_SIZE]) == crc_wire:
                    return at
            at = buf.find(SYNC, at + 1)
        return -1

    def _discard(self, n_bytes: int) -> None:
        if n_bytes <= 0:
            return
        if self._in_sync:
            self.resyncs += 1
            self._in_sync = False
        self.bytes_discarded += n_bytes

    def _count_seq(self, seq: int) -> None:
        last = self._last_seq
        self._last_seq = seq
        if last is None:
            return
        step = (seq - last) % SEQ_MODULUS
        if step == 1:
            return
        self.seq_gaps += 1
        # A huge or zero step is a board restart (or a repeat), not millions of lost frames.
        if 1 < step < SEQ_MODULUS // 2:
            self.dropped_frames += step - 1


# -- reader ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SampleBlock:
    """Samples drained from a :class:`BoardReader`; N frames × C channels.

    ``board_time_s`` is the board clock (``t_us`` unwrapped across its 2³² µs wrap; when the board restarts — a new
    clock segment — it continues from the previous segment's end plus the host clock's gap, so it never runs
    backwards), ``clock_segment[i]`` counts the board's restarts since the reader started (0 first), ``host_time_s`` the host's
    ``time.monotonic()`` when the frame's last byte arrived (the read time, less the wire time of the bytes read
    after it; never before the previous frame's). ``gap_before[i]`` is True when frames are missing just before
    sample ``i`` (dropped frames, or a reconnect after a pulled cable).
    """

    counts: np.ndarray  # (N, C) uint16
    conductance_s: np.ndarray  # (N, C) float64
    board_time_s: np.ndarray  # (N,) float64
    host_time_s: np.ndarray  # (N,) float64
    seq: np.ndarray  # (N,) uint32
    saturated: np.ndarray  # (N, C) bool
    gap_before: np.ndarray | None = None  # (N,) bool; None means no gap anywhere
    clock_segment: np.ndarray | None = None  # (N,) int32; None means segment 0 throughout

    def __len__(self) -> int:
        return int(self.seq.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.counts.shape[1])


BoardState = Literal["connected", "disconnected", "reconnected", "mismatch", "error", "closed", "stall"]


@dataclass(frozen=True)
class BoardStatus:
    """A change in the reader's state. ``state`` is one of ``connected``, ``disconnected``, ``reconnected``,
    ``mismatch`` (channel count differs from the config), ``error`` (unexpected failure; the reader stopped),
    ``closed``. ``message`` is a sentence for the user."""

    state: BoardState
    message: str
    connected: bool
    host_time_s: float = field(default_factory=time.monotonic)


@dataclass(frozen=True)
class BoardStats:
    """Cumulative counters since :meth:`BoardReader.start`."""

    frames: int = 0
    crc_errors: int = 0
    resyncs: int = 0
    seq_gaps: int = 0
    dropped_frames: int = 0
    duplicate_frames: int = 0  # frames repeating the previous seq (dropped: each sample is stored once)
    bytes_discarded: int = 0
    bad_headers: int = 0
    reconnects: int = 0
    channel_mismatches: int = 0
    overflow_frames: int = 0  # frames lost because nobody drained the ring in time
    out_of_range_frames: int = 0  # CRC-valid frames with a count above the ADC's maximum (rejected)
    clock_segments: int = 1  # the board's clock restarted clock_segments − 1 times (re-plug, power cycle)
    clock_backsteps: int = 0  # the board's clock stepped back while seq went on (a clock glitch: no gap marked)
    host_stalls: int = 0  # times the host did not read for STALL_S or more (frames then timed by the board clock)
    version_mismatches: int = 0  # CRC-valid frames in another protocol version (the board speaks other_version)
    other_version: int | None = None
    missing_s: float = 0.0  # total time the port was gone (including now, if it is gone)
    disconnected_since_s: float | None = None  # host monotonic time the port went away, None while connected
    connected: bool = False


def _board_step_s(earlier: Frame, later: Frame) -> float | None:
    """Board seconds from ``earlier`` to ``later`` when they are consecutive in one clock segment and plausibly
    timed (clock forward by less than a minute, seq forward by as many frames as that time holds, give or take);
    ``None`` otherwise (a restart, a clock glitch, frames lost in between: no claim is made across them)."""
    if earlier.counts.size != later.counts.size:
        return None
    t_step = (later.t_us - earlier.t_us) % T_US_MODULUS
    seq_step = (later.seq - earlier.seq) % SEQ_MODULUS
    if seq_step != 1 or not 0 < t_step < 60_000_000:
        return None
    return t_step * 1e-6


class BoardReader:
    """Reads one force-sensor board on its own thread; see the module docstring.

    ``on_status`` is called from the reader thread (keep it short; Qt users re-emit it as a queued signal), except
    the first ``connected`` and the final ``closed``, which come from the threads calling :meth:`start` and
    :meth:`close`. :meth:`start`, :meth:`close`, :meth:`read_block`, :attr:`status` and :attr:`stats` may be called
    from any thread. The ring holds ``ring_seconds`` of frames; a consumer that drains less often loses the oldest
    (counted in ``stats.overflow_frames``).
    """

    def __init__(self, board: BoardConfig, on_status: Callable[[BoardStatus], None] | None = None,
                 ring_seconds: float = DEFAULT_RING_SECONDS) -> None:
        self.board = board
        self._on_status = on_status
        n = board.n_channels
        self._capacity = max(MIN_RING_FRAMES, int(np.ceil(board.rate_hz * ring_seconds)))
        self._counts = np.zeros((self._capacity, n), dtype=np.uint16)
        self._board_time = np.zeros(self._capacity)
        self._host_time = np.zeros(self._capacity)
        self._seq = np.zeros(self._capacity, dtype=np.uint32)
        self._gap = np.zeros(self._capacity, dtype=bool)
        self._write_total = 0  # frames ever written
        self._read_total = 0  # frames ever handed out
        self._lock = threading.Lock()
        self._data_ready = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._port: serial.SerialBase | None = None
        self._parser = FrameParser(max_count=board.adc_max_counts)
        self._status = BoardStatus("closed", f"board on {board.port} not started", False)
        self._reconnects = 0
        self._channel_mismatches = 0
        self._overflow = 0
        self._overflow_since_read = 0
        self._gap_pending = False
        self._last_t_us: int | None = None
        self._last_seq_stored: int | None = None
        self._last_host_time_s = -np.inf
        self._host_offset_s: float | None = None  # host time − board time of a promptly read frame (s)
        self._last_offset_board_s: float | None = None
        self._stalled = False
        self._stalls = 0
        self._late_delivery_said = False
        self._fresh_until_s = math.inf  # a board clock's first frames (a backlog) are dated back until then
        self._pace_anchor: tuple[float, float, float] | None = None  # (first arrival, arrival, board time)
        self._board_pace: float | None = None  # board seconds per host second, once measured over PACE_SPAN_S
        self._last_poll_s = time.monotonic()  # when the reader thread last looked at the port
        # The reader thread's last pause of STALL_S / 2 or more between two looks at the port (start, end): it did not
        # run (the process stopped, the machine suspended or overloaded)
        self._host_gap = (-math.inf, -math.inf)
        self._clock_backsteps = 0
        self._board_time_base_s = 0.0
        self._segment = 0
        self._segment_pending = False
        self._last_store_host_s: float | None = None
        self._lost_at_s: float | None = None
        self._missing_s = 0.0
        self._segment_col = np.zeros(self._capacity, dtype=np.int32)

    # -- public API -------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Open the port and start the reader thread. Raises :class:`PortOpenError` if the port cannot be opened."""
        if self._thread is not None or self._stop.is_set():
            raise RuntimeError("a BoardReader starts once; create a new one to read again")
        self._port = self._open()
        self._set_status("connected", f"board connected on {self.board.port}", True)
        self._thread = threading.Thread(target=self._run, name=f"board-reader:{self.board.port}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread (joins it) and close the port. Idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self._close_port()
        if self._status.state != "closed":
            self._set_status("closed", f"board on {self.board.port} closed", False)

    def __enter__(self) -> BoardReader:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def status(self) -> BoardStatus:
        return self._status

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def stats(self) -> BoardStats:
        p = self._parser
        lost_at = self._lost_at_s
        missing = self._missing_s + (time.monotonic() - lost_at if lost_at is not None else 0.0)
        return BoardStats(frames=p.frames, crc_errors=p.crc_errors, resyncs=p.resyncs, seq_gaps=p.seq_gaps,
                          dropped_frames=p.dropped_frames, duplicate_frames=p.duplicate_frames,
                          bytes_discarded=p.bytes_discarded,
                          bad_headers=p.bad_headers, reconnects=self._reconnects,
                          channel_mismatches=self._channel_mismatches, overflow_frames=self._overflow,
                          out_of_range_frames=p.out_of_range_frames, clock_segments=self._segment + 1,
                          clock_backsteps=self._clock_backsteps, host_stalls=self._stalls,
                          version_mismatches=p.version_mismatches, other_version=p.other_version,
                          missing_s=missing, disconnected_since_s=lost_at, connected=self._status.connected)

    @property
    def frames_available(self) -> int:
        with self._lock:
            return self._write_total - self._read_total

    def newest_frame_host_s(self) -> float:
        """``time.monotonic()`` when the newest frame arrived, read or not (−inf before the first). Any thread."""
        with self._lock:
            if self._write_total == 0:
                return -float("inf")
            return float(self._host_time[(self._write_total - 1) % self._capacity])

    def wait_for_frames(self, n_frames: int = 1, timeout_s: float | None = None) -> bool:
        """Block until at least ``n_frames`` frames arrived since the last :meth:`read_block` (True), counting any
        the ring had to drop, or until ``timeout_s`` passes (False).

        For consumers without an event loop (the CLI, tests). Any thread but the reader's.
        """
        with self._data_ready:
            return self._data_ready.wait_for(
                lambda: self._write_total - self._read_total + self._overflow_since_read >= n_frames, timeout_s)

    def read_block(self) -> SampleBlock | None:
        """Everything received since the previous call (oldest first), or ``None`` if nothing arrived."""
        with self._lock:
            count = self._write_total - self._read_total
            if count <= 0:
                return None
            idx = (self._read_total + np.arange(count)) % self._capacity
            counts = self._counts[idx]
            board_time = self._board_time[idx]
            host_time = self._host_time[idx]
            seq = self._seq[idx]
            gap = self._gap[idx]
            segment = self._segment_col[idx]
            self._read_total = self._write_total
            self._overflow_since_read = 0
        return SampleBlock(counts=counts, conductance_s=conductance_from_counts(counts, self.board),
                           board_time_s=board_time, host_time_s=host_time, seq=seq,
                           saturated=saturated_from_counts(counts), gap_before=gap if gap.any() else None,
                           clock_segment=segment if segment.any() else None)

    # -- reader thread ----------------------------------------------------------------------------------------
    def _open(self) -> serial.SerialBase:
        try:
            return factory.open_serial(self.board.port, self.board.baud, "board", timeout_s=READ_TIMEOUT_S)
        except serial.SerialException as exc:
            raise PortOpenError(f"cannot open board port {self.board.port}: {exc}") from exc

    def _close_port(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            # The adapter may be gone already; then there is nothing left to release.
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._port is None:
                    self._try_reconnect()
                    continue
                try:
                    data = self._read_waiting(self._port)
                except (serial.SerialException, OSError) as exc:
                    self._on_link_lost(exc)
                    continue
                now = time.monotonic()
                self._note_pause(now)
                if data:
                    self._ingest(data, now)
                self._last_poll_s = now
                if not data:
                    # Idle: poll a few hundred times a second rather than block in read(), which on the simulated
                    # port would spin; the added latency (< IDLE_POLL_S) is far below a GUI frame.
                    self._stop.wait(IDLE_POLL_S)
        except BaseException as exc:
            # Thread boundary: tell the user the board stopped, then let threading.excepthook print the traceback.
            self._set_status("error", f"board reader on {self.board.port} stopped: {type(exc).__name__}: {exc}",
                             False)
            raise
        finally:
            self._close_port()

    def _note_pause(self, now: float) -> None:
        """The reader thread looks at the port at ``now`` (before :attr:`_last_poll_s` moves on): a pause of STALL_S / 2
        or more since its previous look is remembered — it did not run meanwhile."""
        if now - self._last_poll_s >= STALL_S / 2:
            self._host_gap = (self._last_poll_s, now)

    @staticmethod
    def _read_waiting(port: serial.SerialBase) -> bytes:
        """Everything the port holds now (up to ``MAX_READ_BYTES``), read until it holds no more: a backlog the
        driver hands over a buffer at a time is taken in one piece, so its frames are dated together."""
        data = b""
        topped_up = 0
        while len(data) < MAX_READ_BYTES:
            waiting = port.in_waiting
            if not waiting:
                # A read that emptied a full driver buffer (a pty's holds 4 kB) may have more behind it a moment
                # later: looked at again twice, 1 ms apart, before the backlog is taken as whole.
                if len(data) < FULL_BUFFER_BYTES or topped_up >= 2:
                    break
                topped_up += 1
                time.sleep(0.001)
                continue
            data += port.read(min(waiting, MAX_READ_BYTES - len(data)))
        return data

    def _on_link_lost(self, exc: BaseException) -> None:
        self._close_port()
        if self._lost_at_s is None:
            self._lost_at_s = time.monotonic()
        self._set_status("disconnected", f"board on {self.board.port} disconnected ({exc}); retrying every "
                         f"{RECONNECT_INTERVAL_S:g} s — check the cable", False)

    def _try_reconnect(self) -> None:
        if self._stop.wait(RECONNECT_INTERVAL_S):
            return
        try:
            self._port = self._open()
        except PortOpenError:
            return
        self._parser.reset_stream()
        self._last_poll_s = time.monotonic()
        self._fresh_until_s = math.inf
        self._reconnects += 1
        self._gap_pending = True
        # A board that was unplugged restarts its clock (and seq) at 0: the next frame opens a new clock segment.
        self._segment_pending = True
        missing = ""
        if self._lost_at_s is not None:
            gone_s = time.monotonic() - self._lost_at_s
            self._missing_s += gone_s
            self._lost_at_s = None
            missing = f" after {gone_s:.1f} s missing"
        self._set_status("reconnected", f"board reconnected on {self.board.port}{missing}; the gap is marked and "
                         "the board's clock starts a new segment", True)

    def _ingest(self, data: bytes, host_time_s: float) -> None:
        expected = self.board.n_channels
        other_versions = self._parser.version_mismatches
        frames = self._parser.feed(data)
        if self._parser.version_mismatches > other_versions and self._status.state != "mismatch":
            self._set_status("mismatch", f"board on {self.board.port} speaks protocol version "
                             f"{self._parser.other_version}; this app reads version {PROTOCOL_VERSION} (SPEC §4): "
                             "update the board's firmware or SenSnake Studio so they match", True)
        # Frames read together arrived one after another: date each by when its last byte came off the wire
        # (bytes behind it × byte time before the read), so their host times keep the board's spacing.
        byte_time_s = BITS_PER_BYTE / self.board.baud
        behind = self._parser.bytes_pending
        arrival = np.empty(len(frames))
        for k in range(len(frames) - 1, -1, -1):
            arrival[k] = host_time_s - behind * byte_time_s
            behind += HEADER_SIZE + 2 * frames[k].counts.size + CRC_SIZE
        # A frame was sampled no later than the next one's arrival less the board's time between them (in host
        # seconds: a simulated lab's board clock may run N× real time): frames that waited (in a board that blocks
        # until the host opens, or an adapter that holds them) and then came together keep the board's spacing back
        # from the last one instead of all landing within the read. Done for a board clock's first frames (those read
        # within FRESH_BACKLOG_S of the first), and once the clock's pace is measured.
        sampled_by = arrival.copy()
        pace = self._board_pace
        if host_time_s <= self._fresh_until_s or pace is not None:
            per_host_s = pace if pace is not None and pace > FAST_BOARD_PACE else 1.0
            for k in range(len(frames) - 2, -1, -1):
                step_s = _board_step_s(frames[k], frames[k + 1])
                if step_s is not None:
                    sampled_by[k] = min(sampled_by[k],
                                        sampled_by[k + 1] - step_s / per_host_s * (1.0 - MAX_CLOCK_DRIFT))
        if frames and self._fresh_until_s == math.inf:
            self._fresh_until_s = host_time_s + FRESH_BACKLOG_S  # the rest of a backlog the driver hands over late
        polled_s = self._last_poll_s
        for frame, frame_host_time_s, frame_sampled_by_s in zip(frames, arrival, sampled_by):
            if frame.counts.size != expected:
                self._channel_mismatches += 1
                if self._status.state != "mismatch":
                    error = BoardProtocolError(
                        f"board on {self.board.port} sends {frame.counts.size} channels but the config lists "
                        f"{expected} (board.channel_names): fix the config's channel list or the board firmware")
                    self._set_status("mismatch", str(error), True)
                continue
            if self._status.state == "mismatch":
                self._set_status("connected", f"board on {self.board.port} sends {expected} channels again", True)
            self._store(frame, float(frame_host_time_s), float(frame_sampled_by_s), polled_s)

    def _store(self, frame: Frame, host_time_s: float, sampled_by_s: float | None = None,
               polled_s: float | None = None) -> None:
        last_t_us, last_seq = self._last_t_us, self._last_seq_stored
        if last_t_us is None or last_seq is None:
            self._board_time_base_s = frame.t_us * 1e-6
        else:
            t_step = (frame.t_us - last_t_us) % T_US_MODULUS
            seq_step = (frame.seq - last_seq) % SEQ_MODULUS
            # Backwards by less than half the modulus is a restart (power cycle without a reconnect), not a wrap:
            # a real 2³² µs wrap moves forward by one frame period and seq by one. A clock that steps back while
            # seq goes on by one is the board's clock glitching, not a restart: no gap, no new segment; that frame
            # is taken to be one nominal period after the last (the board time never runs backwards).
            clock_back = t_step >= T_US_MODULUS // 2
            restarted = seq_step >= SEQ_MODULUS // 2 or (clock_back and seq_step != 1)
            if self._segment_pending or restarted:
                self._segment += 1
                self._gap_pending = True
                self._host_offset_s = None  # a new board clock: its offset to the host's is learnt again
                self._pace_anchor = None
                last_host = self._last_store_host_s if self._last_store_host_s is not None else host_time_s
                self._board_time_base_s += max(host_time_s - last_host, 0.0)
            elif clock_back:
                self._clock_backsteps += 1
                self._board_time_base_s += 1.0 / self.board.rate_hz
            else:
                self._board_time_base_s += t_step * 1e-6
        self._measure_pace(host_time_s, self._board_time_base_s)
        host_time_s = self._host_time_for(self._board_time_base_s, host_time_s,
                                          host_time_s if sampled_by_s is None else sampled_by_s,
                                          host_time_s if polled_s is None else polled_s)
        self._segment_pending = False
        self._last_t_us = frame.t_us
        self._last_store_host_s = host_time_s
        gap = self._gap_pending or (self._last_seq_stored is not None
                                    and (frame.seq - self._last_seq_stored) % SEQ_MODULUS != 1)
        self._gap_pending = False
        self._last_seq_stored = frame.seq
        with self._lock:
            slot = self._write_total % self._capacity
            self._counts[slot] = frame.counts
            self._board_time[slot] = self._board_time_base_s
            self._host_time[slot] = host_time_s
            self._seq[slot] = frame.seq
            self._gap[slot] = gap
            self._segment_col[slot] = self._segment
            self._write_total += 1
            if self._write_total - self._read_total > self._capacity:
                lost = self._write_total - self._read_total - self._capacity
                self._overflow += lost
                self._overflow_since_read += lost
                self._read_total = self._write_total - self._capacity
            self._data_ready.notify_all()

    def _measure_pace(self, wire_time_s: float, board_time_s: float) -> None:
        """Board seconds per host second: from the newest frame that arrived within 50 ms of the clock's first (a
        backlog read at once ends there) to each frame at least ``PACE_SPAN_S`` later."""
        anchor = self._pace_anchor
        if anchor is None:
            self._pace_anchor = anchor = (wire_time_s, wire_time_s, board_time_s)
        began_s, anchor_wire_s, anchor_board_s = anchor
        if wire_time_s - began_s < 0.05:
            self._pace_anchor = (began_s, wire_time_s, board_time_s)
        elif wire_time_s - anchor_wire_s >= PACE_SPAN_S:
            self._board_pace = (board_time_s - anchor_board_s) / (wire_time_s - anchor_wire_s)

    def _host_time_for(self, board_time_s: float, wire_time_s: float, sampled_by_s: float,
                       polled_s: float) -> float:
        """The host time of a frame: when its last byte came off the wire (``wire_time_s``, an upper bound: the
        read time less the wire time of the bytes behind it; ``sampled_by_s`` tightens it by the frames read with
        it) or, when that is later, when the board's clock says it came — the frames that waited in the port's
        buffer while this process did not read (stopped with SIGSTOP, the machine suspended, a long pause) keep the
        board's spacing instead of all landing at the read. The board clock's offset to the host's is the lower
        envelope of (sampled-by time − board time), allowed to rise by the clocks' worst drift. A frame read more
        than ``STALL_S`` after its board time is an event (``state`` ``stall``: a recording logs it), named by its
        cause: this process did not read for that long (``polled_s``, its previous look at the port, that long
        ago: a host stall, counted) — or it did, and the frames came late (a board or adapter that holds them:
        said once). Never before the previous frame's."""
        offset = self._host_offset_s
        candidate = sampled_by_s - board_time_s
        pace = self._board_pace
        real_time_clock = pace <= FAST_BOARD_PACE if pace is not None else wire_time_s <= self._fresh_until_s
        if offset is not None and candidate < offset and real_time_clock:
            self._restamp_unread(candidate)
        if offset is None or candidate < offset:
            offset = candidate
        elif self._last_offset_board_s is not None:
            offset = min(candidate, offset + MAX_CLOCK_DRIFT * max(board_time_s - self._last_offset_board_s, 0.0))
        self._host_offset_s, self._last_offset_board_s = offset, board_time_s
        predicted = board_time_s + offset
        late_s = wire_time_s - predicted
        if late_s > STALL_S and not self._stalled:
            self._stalled = True
            # This process's pause overlapped the frames' wait: its previous look at the port was that long ago, or
            # its last pause ended while they waited (the first look after a SIGCONT can find the port still empty
            # while the kernel's tty worker, behind other programs, has not handed the waiting bytes over yet)
            gap_start, gap_end = self._host_gap
            paused_s = max(wire_time_s - polled_s, gap_end - max(gap_start, predicted))
            if paused_s >= STALL_S / 2:
                self._stalls += 1
                self._notify("stall", f"the board was not read for {late_s:.1f} s (this process was stopped, or "
                             "the computer suspended or overloaded); the frames that waited are timed by the board's "
                             "clock, not stamped all at once", predicted)
            elif not self._late_delivery_said:
                self._late_delivery_said = True
                self._notify("stall", f"frames from the board on {self.board.port} came up to {late_s:.1f} s late "
                             "although this app was reading (the board or its USB adapter held them back); they are "
                             "timed by the board's clock", predicted)
        elif late_s < STALL_S / 2:
            self._stalled = False
        host_time_s = max(min(sampled_by_s, predicted), self._last_host_time_s)
        self._last_host_time_s = host_time_s
        return host_time_s

    def _restamp_unread(self, offset_s: float) -> None:
        """A lower offset envelope says the frames stored before it were stamped late (an adapter's burst handed
        over in pieces: the first piece's frames were dated from its own read). Only for a clock known to run at the
        host's pace (a fast simulated board's offset falls at every frame). Those of this clock segment that no
        consumer has read yet are dated again from the new offset, never before the frame stored before them; frames
        already handed out keep their stamps."""
        with self._lock:
            first = max(self._read_total, self._write_total - self._capacity)
            count = self._write_total - first
            if count <= 0:
                return
            idx = (first + np.arange(count)) % self._capacity
            idx = idx[self._segment_col[idx] == self._segment]
            if idx.size == 0:
                return
            # Never before the frame stored just before them (handed out already, or of an earlier clock segment):
            # host times never run backwards, across a reconnect too.
            floor_s = -np.inf
            before = (self._write_total - idx.size) - 1
            if before >= max(self._write_total - self._capacity, 0):
                floor_s = float(self._host_time[before % self._capacity])
            restamped = np.minimum(self._host_time[idx], self._board_time[idx] + offset_s)
            self._host_time[idx] = np.maximum.accumulate(np.maximum(restamped, floor_s))
            self._last_host_time_s = float(self._host_time[idx[-1]])
            self._last_store_host_s = self._last_host_time_s

    def _notify(self, state: BoardState, message: str, host_time_s: float) -> None:
        """Tell ``on_status`` of an event that does not change the reader's state (a stall)."""
        if self._on_status is not None:
            self._on_status(BoardStatus(state, message, True, host_time_s))

    def _set_status(self, state: BoardState, message: str, connected: bool) -> None:
        status = BoardStatus(state, message, connected)
        self._status = status
        if self._on_status is not None:
            self._on_status(status)
