"""Recording files (SPEC §3.5): the force-sensor board, the robot and live forces on one clock, in HDF5.

Layout (SPEC §3.5, plus extras that readers may ignore): root attributes ``format``, ``version``, ``started``
(ISO 8601, UTC), ``config`` (TOML text); ``/daq`` with ``time_s``, ``seq``, ``counts``, ``conductance_S`` and
attributes ``channels``, ``crc_errors``, ``dropped_frames``, ``resyncs``; ``/robot`` (``time_s``, ``goal_rad``,
``present_rad``, ``current_mA``) when a robot is connected; ``/forces/force_N`` with the calibration JSON as the
attribute ``calibration`` when forces are estimated live. Extras: ``/forces/status`` (int8 per force, the
estimator's :class:`models.sls.ForceStatus` code: 0 ok; e.g. a reading at the readout's ceiling is flagged, never a
silent number), ``/daq/board_time_s`` (the board's own clock,
unwrapped, for exact sample spacing), ``/daq/clock_segment`` (0, then +1 each time the board restarted its clock —
a re-plug or power cycle; ``seq`` and the board clock restart with it), more link counters as ``/daq`` attributes
(``out_of_range_frames``, ``channel_mismatches``, ``reconnects``), and ``/events`` (``time_s``, ``kind``, ``text``:
the gap, segment and health log).

One clock: every ``time_s`` is seconds since ``started``. The writer takes a host ``time.monotonic()`` reading when
it starts and converts every host time stamp it is given (``SampleBlock.host_time_s``, ``ChainState.host_time_s``).

Crash safety: the writer keeps no HDF5 handle open between flushes. Each :meth:`RecordingWriter.flush` (at least
every ``flush_interval_s``, 0.5 s by default, while data arrives) opens the file, appends the buffered rows, closes
it and fsyncs it (a few ms). So ``kill -9``, SIGTERM, a crash, a pulled cable or a power cut leave a file that plain
``h5py.File(path, "r")`` and HDFView open, holding everything up to the last flush. A file cut short anyway (a copy
interrupted, a disk failure) is salvaged by :func:`recover_recording` / ``sensnake repair``: every whole chunk of
rows that survives is kept, and the report says how much.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import json
import os
import shutil
import time
import traceback
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta, timezone
from functools import cached_property
from pathlib import Path
from typing import Any, Protocol, TextIO

import h5py
import numpy as np

from app.core.calfiles import CONDUCTANCE_COLUMN, FORCE_COLUMN, with_unit_suffixes, write_atomically
from app.core.errors import OutputPathError, RecordingError, RecordingFormatError
from app.core.outputs import (
    check_output,
    create_temporary,
    describe_kind,
    move_into_place,
    open_lock_file,
    temporary_stem,
)
from app.core.run_documents import RUN_START, RUN_STOP, document_text, parse_document, reserve_run_stop

FORMAT = "sensnake-recording"
VERSION = 1
DEFAULT_FLUSH_INTERVAL_S = 0.5
CHUNK_BYTES = 1 << 14
MOCAP_CHUNK_BYTES = 1 << 18  # /mocap's rows are wide (~2.5 kB a frame), and an hour at 960 Hz is 3.5 M of them
DEFAULT_MIN_FREE_BYTES = 16_000_000  # stop before the disk is full: HDF5 cannot recover from a failed write
METADATA_RESERVE_BYTES = 1_000_000
FLUSH_METADATA_RESERVE_BYTES = 256_000  # room reserved for the metadata one flush may add (it adds a few kB)
EVENT_TEXT_BYTES = 256
EVENT_KIND_BYTES = 16
STAT_KEYS = ("crc_errors", "dropped_frames", "resyncs")  # SPEC §3.5's /daq attributes


class DaqBlock(Protocol):
    """What :meth:`RecordingWriter.append_daq` needs from a ``devices.board.SampleBlock`` (read-only, so frozen
    dataclasses fit)."""

    @property
    def counts(self) -> np.ndarray: ...
    @property
    def conductance_s(self) -> np.ndarray: ...
    @property
    def host_time_s(self) -> np.ndarray: ...
    @property
    def seq(self) -> np.ndarray: ...


# -- writer ------------------------------------------------------------------------------------------------------
class _Table:
    """Columns of one group appended together; rows buffered in memory until the next flush, when they are written
    through the file opened for that flush (the writer keeps no HDF5 handle between flushes)."""

    def __init__(self, group: h5py.Group | str, columns: dict[str, tuple[Any, tuple[int, ...]]],
                 attrs: dict[str, Any] | None = None, chunk_bytes: int = CHUNK_BYTES) -> None:
        """``group``: the group to make the datasets in now, or the name of one made at the first flush that has
        rows for it (with ``attrs``): a group only some recordings hold (``/control``) appears only in those.
        ``chunk_bytes``: about how many bytes each dataset's chunks hold."""
        self.columns = dict(columns)
        self.chunk_bytes = int(chunk_bytes)
        self._attrs = dict(attrs or {})
        if isinstance(group, str):
            self.group_name = group
        else:
            self.group_name = group.name
            self._create(group)
        self.pending: dict[str, list[np.ndarray]] = {name: [] for name in columns}
        self.rows = 0  # rows on disk

    def _create(self, group: h5py.Group) -> None:
        for name, (dtype, row_shape) in self.columns.items():
            row_bytes = max(1, int(np.prod(row_shape, dtype=np.int64)) * np.dtype(dtype).itemsize)
            chunk_rows = max(16, self.chunk_bytes // row_bytes)
            group.create_dataset(name, shape=(0, *row_shape), maxshape=(None, *row_shape),
                                 chunks=(chunk_rows, *row_shape), dtype=dtype)
        for key, value in self._attrs.items():
            group.attrs[key] = value

    def append(self, **columns: np.ndarray) -> None:
        for name, values in columns.items():
            self.pending[name].append(values)

    @property
    def pending_rows(self) -> int:
        first = next(iter(self.pending.values()))
        return sum(len(v) for v in first)

    def row_shape(self, name: str) -> tuple[int, ...]:
        return self.columns[name][1]

    def write_pending(self, f: h5py.File, handles: list[Any]) -> None:
        """Append the buffered rows. The datasets opened go into ``handles``: the caller keeps them alive until
        the file is flushed, because closing a dataset writes its chunk cache, and a write failing there (disk
        full) is silently lost inside h5py's deallocator and leaves HDF5 to crash on the next call."""
        n_new = self.pending_rows
        if n_new == 0:
            return
        if self.group_name not in f:
            self._create(f.create_group(self.group_name))
        group = f[self.group_name]
        handles.append(group)
        for name, chunks in self.pending.items():
            values = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
            dataset = group[name]
            handles.append(dataset)
            dataset.resize(self.rows + n_new, axis=0)
            dataset[self.rows:self.rows + n_new] = values
            chunks.clear()
        self.rows += n_new

    def clear_pending(self) -> None:
        for chunks in self.pending.values():
            chunks.clear()


class RecordingWriter:
    """Writes one recording file; see the module docstring.

    Not thread-safe: call it from one thread (:class:`app.core.recorder.Recorder` runs it on a writer thread).
    Time stamps passed in are host ``time.monotonic()`` seconds. After a write failure every call raises
    :class:`RecordingError`.

    The file is built under a hidden name beside ``path`` and moved onto ``path`` by the first flush that holds
    data, so a recording that never receives any (board silent, wrong port) leaves an existing file at ``path``
    untouched; :meth:`close` then removes the hidden file and :attr:`kept` stays False.
    """

    def __init__(self, path: str | Path, config_text: str, channel_names: Sequence[str],
                 calibration_json: str | None = None, with_robot: bool = False, n_joints: int = 12,
                 flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S, t0_monotonic_s: float | None = None,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES, run_start: Mapping[str, Any] | None = None) -> None:
        self.path = Path(path)
        self.min_free_bytes = int(min_free_bytes)
        self.channel_names = tuple(channel_names)
        self.flush_interval_s = flush_interval_s
        now_monotonic_s = time.monotonic()
        self.t0_monotonic_s = now_monotonic_s if t0_monotonic_s is None else t0_monotonic_s
        # ``started`` is the wall-clock instant of t0, so "seconds since started" is the same for both clocks.
        self.started = datetime.now(timezone.utc) - timedelta(seconds=now_monotonic_s - self.t0_monotonic_s)
        self._failed: RecordingError | None = None
        self._closed = False
        self.kept = False  # True once the file holds data at ``path``
        # An unpredictable hidden name, created here and nowhere else (O_EXCL, not through a symlink): in a shared
        # folder nobody can make a recording write into (or truncate) someone else's file (app.core.outputs).
        self._work_path = self.path
        self._lock_fd: int | None = None
        n = len(self.channel_names)
        try:
            check_output(self.path)  # a device, FIFO, socket, folder or link loop is refused, never replaced
            if not self.path.parent.is_dir():
                what = "is not a folder" if self.path.parent.exists() else "does not exist"
                raise FileNotFoundError(f"the folder {self.path.parent} {what}")
            self._lock_fd = _lock_for_writing(self.path)
            fd, self._work_path = create_temporary(self.path, ".partial")
            os.close(fd)
            f = h5py.File(self._work_path, "w", locking=False)
        except RecordingError:
            self._release_lock()
            raise
        except OutputPathError as exc:
            raise RecordingError(f"cannot create recording {self.path}: {exc}") from None
        except OSError as exc:
            self._release_lock()
            if self._work_path != self.path:
                with contextlib.suppress(OSError):
                    self._work_path.unlink()
            raise RecordingError(f"cannot create recording {self.path}: {_os_reason(exc)}") from exc
        try:
            with f:
                f.attrs["format"] = FORMAT
                f.attrs["version"] = VERSION
                f.attrs["started"] = self.started.isoformat(timespec="milliseconds")
                f.attrs["config"] = config_text
                f.attrs["duration_s"] = 0.0
                if run_start is not None:  # the run's RunStart document (app.core.run_documents)
                    f.attrs[RUN_START] = document_text(run_start)
                    reserve_run_stop(f.attrs)  # its RunStop, written once the file is closed, goes here
                daq = f.create_group("daq")
                daq.attrs["channels"] = np.array(self.channel_names, dtype=h5py.string_dtype())
                for key in STAT_KEYS:
                    daq.attrs[key] = np.int64(0)
                self._daq = _Table(daq, {"time_s": (np.float64, ()), "seq": (np.uint32, ()),
                                         "counts": (np.uint16, (n,)), "conductance_S": (np.float64, (n,)),
                                         "board_time_s": (np.float64, ()), "clock_segment": (np.int32, ())})
                self._robot: _Table | None = None
                if with_robot:
                    self._robot = _Table(f.create_group("robot"), {
                        "time_s": (np.float64, ()), "goal_rad": (np.float64, (n_joints,)),
                        "present_rad": (np.float64, (n_joints,)), "current_mA": (np.float64, (n_joints,))})
                self._forces: _Table | None = None
                if calibration_json is not None:
                    forces = f.create_group("forces")
                    forces.attrs["calibration"] = calibration_json
                    self._forces = _Table(forces, {"force_N": (np.float64, (n,)), "status": (np.int8, (n,))})
                self._events = _Table(f.create_group("events"), {
                    "time_s": (np.float64, ()), "kind": (f"S{EVENT_KIND_BYTES}", ()),
                    "text": (f"S{EVENT_TEXT_BYTES}", ())})
        except (OSError, RuntimeError) as exc:
            with contextlib.suppress(OSError):
                self._work_path.unlink()
            raise RecordingError(f"cannot create recording {self.path}: {_os_reason(exc)}") from exc
        self._control: _Table | None = None
        self._n_joints = n_joints
        self._last_flush = time.monotonic()
        self._last_time_s = 0.0
        self._last_flushed_time_s = 0.0
        self._stats: dict[str, int] = {}
        self._stats_written: dict[str, int] = {}
        self._last_segment = 0
        self._mocap: _Table | None = None  # /mocap, made by the first append_mocap
        self._mocap_attrs: dict[str, Any] = {}  # /mocap attributes not yet written

    @property
    def _tables(self) -> tuple[_Table, ...]:
        return tuple(t for t in (self._daq, self._robot, self._forces, self._events, self._control, self._mocap)
                     if t is not None)

    # -- appending ---------------------------------------------------------------------------------------------
    def time_s(self, host_monotonic_s: float | np.ndarray) -> float | np.ndarray:
        """Recording time (seconds since ``started``) of a host ``time.monotonic()`` reading."""
        return np.asarray(host_monotonic_s, dtype=np.float64) - self.t0_monotonic_s

    def append_daq(self, block: DaqBlock) -> None:
        """Append a board :class:`~devices.board.SampleBlock`; its ``gap_before`` flags become gap events and a
        change of ``clock_segment`` (the board restarted its clock) a ``segment`` event."""
        self._check()
        n_rows = len(block.seq)
        if n_rows == 0:
            return
        counts = np.asarray(block.counts, dtype=np.uint16)
        if counts.shape[1] != len(self.channel_names):
            raise ValueError(f"recording {self.path} has {len(self.channel_names)} channels, the block "
                             f"{counts.shape[1]}")
        times = np.asarray(self.time_s(block.host_time_s))
        board_time = getattr(block, "board_time_s", None)
        segment = getattr(block, "clock_segment", None)
        segments = np.zeros(n_rows, dtype=np.int32) if segment is None else np.asarray(segment, dtype=np.int32)
        self._daq.append(time_s=times, seq=np.asarray(block.seq, dtype=np.uint32), counts=counts,
                         conductance_S=np.asarray(block.conductance_s, dtype=np.float64),
                         board_time_s=np.full(n_rows, np.nan) if board_time is None else np.asarray(board_time),
                         clock_segment=segments)
        gap_before = getattr(block, "gap_before", None)
        if gap_before is not None:
            for i in np.flatnonzero(gap_before):
                self._event(float(times[i]), "gap", f"board frames missing before seq {int(block.seq[i])}")
        for i in np.flatnonzero(np.diff(segments, prepend=self._last_segment)):
            self._event(float(times[i]), "segment", f"board clock restarted: clock segment {int(segments[i])} "
                        f"starts at seq {int(block.seq[i])}")
        self._last_segment = int(segments[-1])
        self._last_time_s = max(self._last_time_s, float(times[-1]))
        self._maybe_flush()

    def append_robot(self, time_s: float | np.ndarray, goal_rad: np.ndarray, present_rad: np.ndarray,
                     current_ma: np.ndarray) -> None:
        """Append robot samples: host monotonic ``time_s`` (scalar or (N,)), joint arrays (J,) or (N, J)."""
        self._check()
        if self._robot is None:
            raise RuntimeError(f"recording {self.path} was created without a robot (with_robot=False)")
        times = np.atleast_1d(self.time_s(time_s))
        n_joints = self._robot.row_shape("goal_rad")[0]

        def rows(values: np.ndarray) -> np.ndarray:
            return np.asarray(values, dtype=np.float64).reshape(len(times), n_joints)

        self._robot.append(time_s=times, goal_rad=rows(goal_rad), present_rad=rows(present_rad),
                           current_mA=rows(current_ma))
        self._last_time_s = max(self._last_time_s, float(times[-1]))
        self._maybe_flush()

    def append_control(self, time_s: float | np.ndarray, correction_rad: np.ndarray, controller: str,
                       gains_json: str) -> None:
        """Append what a controller other than feedforward added to the goals (SPEC §3.5 ``/control``): host
        monotonic ``time_s``, ``correction_rad`` (J,) or (N, J). The group, with ``controller`` and ``gains`` as
        attributes (those of the first rows), appears at the first flush after the first rows."""
        self._check()
        times = np.atleast_1d(self.time_s(time_s))
        if self._control is None:
            self._control = _Table("/control", {"time_s": (np.float64, ()),
                                                "correction_rad": (np.float64, (self._n_joints,))},
                                   attrs={"controller": controller, "gains": gains_json})
        self._control.append(time_s=times, correction_rad=np.asarray(correction_rad, dtype=np.float64).reshape(
            len(times), self._n_joints))
        self._maybe_flush()

    def append_forces(self, force_n: np.ndarray, status: np.ndarray | None = None) -> None:
        """Append estimated forces (N×C newtons), one row per board sample appended with :meth:`append_daq`, and
        their :class:`models.sls.ForceStatus` codes (N×C; None: all ok)."""
        self._check()
        if self._forces is None:
            raise RuntimeError(f"recording {self.path} was created without a calibration: no forces to store")
        force = np.asarray(force_n, dtype=np.float64).reshape(-1, len(self.channel_names))
        codes = np.zeros(force.shape, np.int8) if status is None else np.asarray(status, dtype=np.int8).reshape(
            force.shape)
        self._forces.append(force_N=force, status=codes)
        self._maybe_flush()

    def mark_gap(self, host_monotonic_s: float, reason: str) -> None:
        """Log that data is missing from ``host_monotonic_s`` on (e.g. the board was unplugged)."""
        self._check()
        self._event(float(self.time_s(host_monotonic_s)), "gap", reason)
        self._maybe_flush()

    def log_event(self, text: str, host_monotonic_s: float | None = None, kind: str = "event") -> None:
        """Log a line (sensor health change, user note) at ``host_monotonic_s`` (default: now)."""
        self._check()
        when = time.monotonic() if host_monotonic_s is None else host_monotonic_s
        self._event(float(self.time_s(when)), kind, text)
        self._maybe_flush()

    def update_stats(self, crc_errors: int, dropped_frames: int, resyncs: int, **more: int) -> None:
        """The board link's cumulative counters, stored as ``/daq`` attributes at the next flush (SPEC §3.5's
        ``crc_errors``, ``dropped_frames``, ``resyncs``; extra keys such as ``out_of_range_frames`` too)."""
        self._check()
        self._stats = {"crc_errors": int(crc_errors), "dropped_frames": int(dropped_frames),
                       "resyncs": int(resyncs), **{k: int(v) for k, v in more.items()}}

    def append_mocap(self, columns: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
        """Rows of ``/mocap`` (docs/SPEC_EXTENSIONS.md): each column's rows (its first axis), the group made with
        ``attrs`` at the first flush that has rows for it; flushed with the other groups."""
        if self._mocap is None:
            self._mocap = _Table("mocap", {name: (np.asarray(v).dtype, np.asarray(v).shape[1:])
                                           for name, v in columns.items()}, dict(attrs), MOCAP_CHUNK_BYTES)
        self._mocap.append(**{name: np.asarray(v) for name, v in columns.items()})

    def set_mocap_attrs(self, attrs: Mapping[str, Any]) -> None:
        """Attributes of ``/mocap`` (set or replaced) written at the next flush, once the group has rows."""
        self._mocap_attrs.update(attrs)

    def _event(self, time_s: float, kind: str, text: str) -> None:
        self._events.append(time_s=np.array([time_s]),
                            kind=np.array([kind.encode()[:EVENT_KIND_BYTES]], dtype=f"S{EVENT_KIND_BYTES}"),
                            text=np.array([_truncate_utf8(text, EVENT_TEXT_BYTES)], dtype=f"S{EVENT_TEXT_BYTES}"))

    # -- flushing ----------------------------------------------------------------------------------------------
    @property
    def n_daq_samples(self) -> int:
        return self._daq.rows + self._daq.pending_rows

    @property
    def duration_s(self) -> float:
        return self._last_time_s

    @property
    def closed(self) -> bool:
        return self._closed

    def size_bytes(self) -> int:
        try:
            return (self.path if self.kept else self._work_path).stat().st_size
        except OSError:
            return 0

    def _maybe_flush(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.flush()

    def flush(self) -> None:
        """Write everything buffered, close the file and sync it to disk; move it onto ``path`` once it holds data.

        Between flushes no HDF5 handle is open, so ``kill -9``, a crash or a power cut leave a file that plain
        h5py (and HDFView) opens, holding everything up to the last flush. Stops the recording cleanly (file
        closed, :class:`RecordingError` raised) when the disk would be left with less than ``min_free_bytes``:
        HDF5 cannot recover from a failed write, so running out is avoided, not caught.
        """
        self._check()
        self._last_flush = time.monotonic()
        if (not any(t.pending_rows for t in self._tables) and self._stats == self._stats_written
                and not self._mocap_attrs):
            return
        self._check_free_space()
        self._reserve_room()
        # No file locking: a reader holding the file open (HDFView, a second SenSnake) must not stop the
        # recording; between flushes the file is complete, so such a reader sees a consistent file.
        try:
            f = h5py.File(self._work_path, "a", locking=False)
        except OSError as exc:
            self._fail(exc)
        failure = None
        handles: list[Any] = []
        try:
            for table in self._tables:
                table.write_pending(f, handles)
            daq = f["daq"]
            handles.append(daq)
            for key, value in self._stats.items():
                daq.attrs[key] = np.int64(value)
            f.attrs["duration_s"] = float(self._last_time_s)
            del daq
            if self._mocap_attrs and "mocap" in f:
                mocap = f["mocap"]
                for key, value in self._mocap_attrs.items():
                    mocap.attrs[key] = value
                self._mocap_attrs = {}
                del mocap
            f.flush()  # a failed write shows here, where it can be handled, not inside a deallocator
        except (OSError, RuntimeError, KeyError) as exc:
            # HDF5 reports a failed write (ENOSPC, EFBIG, EIO) as OSError or, from H5Fflush, RuntimeError.
            failure = _os_reason(exc)
            traceback.clear_frames(exc.__traceback__)  # frames holding dataset handles would outlive the file
        if failure is not None:
            handles.clear()
            _close_after_failure(f)
            del f
            self._fail(OSError(failure))
        handles.clear()
        f.close()
        _fsync(self._work_path)
        self._stats_written = dict(self._stats)
        self._last_flushed_time_s = self._last_time_s
        if not self.kept and any(t.rows for t in self._tables if t is not self._events):
            self._move_into_place()

    def _move_into_place(self) -> None:
        try:
            move_into_place(self._work_path, self.path)
        except OSError as exc:
            self._closed = True
            why = str(exc) if isinstance(exc, OutputPathError) else _os_reason(exc)
            self._failed = RecordingError(f"recording stopped: cannot move the new recording onto {self.path} "
                                          f"({why}); it is kept as {self._work_path}")
            self._release_lock()
            raise self._failed from exc
        self._work_path = self.path
        self.kept = True

    def _reserve_room(self) -> None:
        """Make the room this flush will write into before HDF5 touches the file: the file is extended (really
        allocated, ``posix_fallocate``) past its end by twice the buffered bytes, a chunk per dataset and the
        metadata reserve. HDF5 then writes inside the file (its end of allocation is below the file's end) and
        cuts the spare off when it closes the file. A disk that is full, a quota or a file-size limit (ENOSPC,
        EDQUOT, EFBIG) fails here, where nothing of the file has changed: the reservation is cut back and the
        recording stops with the file exactly as the last flush left it — it opens, holding all of that. (HDF5
        cannot recover from a write that fails half-way through its metadata; the file would no longer open.)"""
        try:
            fd = os.open(self._work_path, os.O_WRONLY | _NOFOLLOW)
        except FileNotFoundError:
            return  # not created yet (the first flush creates it)
        except OSError as exc:
            self._fail(exc)
        try:
            size = os.fstat(fd).st_size
            n_datasets = sum(len(table.columns) for table in self._tables)
            room = 2 * self._pending_bytes() + n_datasets * CHUNK_BYTES + FLUSH_METADATA_RESERVE_BYTES
            try:
                os.posix_fallocate(fd, size, room)
            except OSError as exc:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, size)  # back to the last good file (shrinking needs no room)
                self._fail(exc)
        finally:
            os.close(fd)

    def _pending_bytes(self) -> int:
        return sum(int(a.nbytes) for table in self._tables for chunks in table.pending.values() for a in chunks)

    def _check_free_space(self) -> None:
        try:
            free = shutil.disk_usage(self.path.parent).free
        except OSError:
            return  # cannot tell (e.g. a network share): let the write itself decide
        needed = self._pending_bytes() + METADATA_RESERVE_BYTES
        if free - needed >= self.min_free_bytes:
            return
        for table in self._tables:
            table.clear_pending()
        self._closed = True
        self._failed = RecordingError(
            f"recording {self.path} stopped: the disk is almost full ({free / 1e6:.1f} MB free, keeping "
            f"{self.min_free_bytes / 1e6:.0f} MB spare). {self._what_is_kept()}; free some space and record again")
        self._discard_if_empty()
        self._release_lock()
        raise self._failed

    def _what_is_kept(self) -> str:
        """What the file at ``path`` holds after a failure, in a user's words."""
        if self.kept:
            return f"The file keeps the first {self._daq.rows} board samples"
        if os.path.lexists(self.path):
            return f"Nothing was recorded; {self.path.name} was left as it was"
        return f"Nothing was recorded; {self.path.name} was not created"

    def close(self) -> None:
        """Flush and close. Idempotent; after a failure it just releases the file. A recording that never held
        data leaves nothing behind (an existing file at ``path`` is untouched)."""
        if self._closed:
            return
        try:
            if self._failed is None:
                self.flush()
        finally:
            self._closed = True
            self._discard_if_empty()
            self._release_lock()

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                _lock_path(self.path).unlink()
                os.close(self._lock_fd)
            self._lock_fd = None

    def _discard_if_empty(self) -> None:
        if not self.kept:
            with contextlib.suppress(OSError):
                self._work_path.unlink()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _check(self) -> None:
        if self._failed is not None:
            raise self._failed
        if self._closed:
            raise RuntimeError(f"recording {self.path} is closed")

    def _fail(self, exc: BaseException) -> None:
        self._closed = True
        for table in self._tables:
            table.clear_pending()
        kept = (f"The file keeps what was saved up to the last flush ({self._last_flushed_time_s:.1f} s) and opens "
                "as it is") if self.kept else self._what_is_kept()
        self._failed = RecordingError(
            f"recording {self.path} stopped: cannot write ({_os_reason(exc)}){_write_advice(exc)}. {kept}")
        self._discard_if_empty()
        self._release_lock()
        raise self._failed from exc


_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)


def _lock_path(path: Path) -> Path:
    return path.with_name(f".{temporary_stem(path.name)}.lock")  # a long name is shortened (app.core.outputs)


def _lock_for_writing(path: Path) -> int | None:
    """Hold an exclusive lock on ``path`` for this writer (a lock file beside it, the writer's pid inside): a second
    recording to the same file, from any process, is refused at once naming the first. None where the platform has
    no ``fcntl`` (Windows), which then relies on the writer's unique hidden file."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        return None
    lock = _lock_path(path)
    for _attempt in range(10):
        fd = open_lock_file(lock)  # a link, FIFO or device planted there is refused naming it
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise RecordingError(f"{path} is being recorded by another process (pid {holder}): choose another file, "
                                 f"or stop that recording first") from None
        try:
            current = os.stat(lock, follow_symlinks=False)
        except FileNotFoundError:
            current = None
        mine = os.fstat(fd)
        if current is not None and (current.st_ino, current.st_dev) == (mine.st_ino, mine.st_dev):
            # A lock file left by a writer that was killed is taken over here (its pid is stale) and removed at close.
            os.ftruncate(fd, 0)
            os.write(fd, str(os.getpid()).encode("ascii"))
            return fd
        os.close(fd)  # the writer before us removed that lock file as we opened it: take the new one
    raise RecordingError(f"cannot lock {path} for recording: its lock file {lock.name} keeps changing")


def _write_advice(exc: BaseException) -> str:
    """What a failed write's errno means for the user, or ``""``."""
    code = getattr(exc, "errno", None)
    if not isinstance(code, int):
        return ""
    return {errno.ENOSPC: ": the disk is full; free some space",
            errno.EDQUOT: ": your disk quota is used up",
            errno.EFBIG: ": the file reached the largest size allowed here (the shell's `ulimit -f`, or the disk's "
                         "own limit); record to several shorter files",
            errno.EIO: ": the disk reported an I/O error; check the disk or the network share"}.get(code, "")


def _os_reason(exc: BaseException) -> str:
    """The OS's words for a failure, without HDF5's internals (``flags = 13, o_flags = 242`` …) or the hidden
    work file's name: h5py puts its whole report into ``strerror``, so the OS's own message is dug out of it."""
    strerror = getattr(exc, "strerror", None)
    text = " ".join(str(strerror or exc).split())
    if "error message = '" in text:
        return text.split("error message = '", 1)[1].split("'", 1)[0]
    for marker in (", errno = ", "errno = "):
        if marker in text:
            code = text.split(marker, 1)[1].split(",", 1)[0].strip()
            if code.isdigit():
                return os.strerror(int(code))
    errno_code = getattr(exc, "errno", None)
    if isinstance(errno_code, int) and ("(" in text or "partial" in text):
        return os.strerror(errno_code)
    return text.split(" (file name")[0][:200]


def _close_after_failure(f: h5py.File) -> None:
    """Release a file whose write failed. HDF5 cannot flush its metadata once a write failed, and closing the
    file normally then crashes (HDF5 2.0 / h5py 3.16 segfault in the id clean-up): close the file id itself."""
    with contextlib.suppress(OSError, RuntimeError, ValueError):
        f.id.close()


def _fsync(path: Path) -> None:
    """Push the closed file's bytes to the disk, so a power cut keeps what the last flush wrote."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems cannot fsync; the data is still in the OS's hands
    finally:
        os.close(fd)


def _truncate_utf8(text: str, max_bytes: int) -> bytes:
    return text.encode("utf-8")[:max_bytes].decode("utf-8", errors="ignore").encode("utf-8")


# -- reader ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RobotRecord:
    time_s: np.ndarray  # (M,)
    goal_rad: np.ndarray  # (M, J)
    present_rad: np.ndarray  # (M, J)
    current_ma: np.ndarray  # (M, J)


@dataclass(frozen=True)
class RecordingEvent:
    time_s: float
    kind: str  # "gap", "health", "event", …
    text: str


@dataclass(frozen=True)
class Recording:
    """A recording read into memory. Times are seconds since ``started``."""

    path: Path
    version: int
    started: str
    config_text: str
    channels: tuple[str, ...]
    time_s: np.ndarray  # (N,)
    seq: np.ndarray  # (N,) uint32
    counts: np.ndarray  # (N, C) uint16
    conductance_s: np.ndarray  # (N, C)
    board_time_s: np.ndarray | None
    crc_errors: int
    dropped_frames: int
    resyncs: int
    robot: RobotRecord | None
    forces_n: np.ndarray | None  # (N, C) when forces were estimated live
    calibration_json: str | None
    events: tuple[RecordingEvent, ...]
    clock_segment: np.ndarray | None = None  # (N,) the board clock's segment (re-plugs, power cycles)
    forces_status: np.ndarray | None = None  # (N, C) int8 ForceStatus codes of forces_n, when the file has them
    recovery: str | None = None  # set when the file was salvaged: how much was recovered

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def gaps(self) -> tuple[RecordingEvent, ...]:
        return tuple(e for e in self.events if e.kind == "gap")

    @cached_property
    def forces_from_defaults(self) -> bool:
        """The stored forces came from no calibration: versions before 2026-11-27 estimated them with a typical
        sensor when no calibration file was loaded (their calibration document says ``"defaults": true``). They are
        not shown or exported as newtons; the conductance is."""
        if self.forces_n is None or not self.calibration_json:
            return False
        try:
            document = json.loads(self.calibration_json)
        except ValueError:
            return False
        return isinstance(document, dict) and document.get("defaults") is True

    @cached_property
    def force_channels(self) -> np.ndarray:
        """(C,) bool: the channels shown and exported in newtons -- a stored force with at least one value (the
        sensor was calibrated when recorded); the others as conductance. None with :attr:`forces_from_defaults`.
        Computed once (a long, wide recording's forces are read at every replayed cursor move); do not modify."""
        mask = np.zeros(len(self.channels), dtype=bool)
        forces = self.forces_n
        if forces is None or self.forces_from_defaults:
            return mask
        n = min(forces.shape[0], self.n_samples)
        columns = min(forces.shape[1], mask.size) if forces.ndim == 2 else 0
        mask[:columns] = np.isfinite(forces[:n, :columns]).any(axis=0)
        return mask

    @property
    def duration_s(self) -> float:
        ends = [self.time_s[-1]] if self.n_samples else []
        if self.robot is not None and self.robot.time_s.size:
            ends.append(self.robot.time_s[-1])
        return float(max(ends)) if ends else 0.0


def open_recording(path: str | Path, recover: bool = False) -> Recording:
    """Read a recording (also one cut short by a crash). Raises :class:`RecordingFormatError` naming the file.

    A file that HDF5 refuses because it is truncated, or that opens but whose last data chunk lies past the end its
    superblock claims (a writer killed in the middle of a flush: its metadata reached the disk, the superblock's new
    end did not), is salvaged when ``recover`` is True (the GUI does this and shows :attr:`Recording.recovery`);
    otherwise the error says to run ``sensnake repair``.
    """
    path = Path(path)
    check_input(path)
    salvageable = _stored_eof(path) is not None
    hint = " — 'sensnake repair' salvages what it can" if salvageable else ""
    try:
        handle = _open_h5(path)
    except OSError as exc:
        if recover and salvageable:
            return recover_recording(path)[0]
        reason = _h5_reason(exc)
        if reason != "not an HDF5 file":
            reason = f"not HDF5, or truncated/corrupt: {reason}"
        raise RecordingFormatError(f"{path} is not a readable SenSnake recording ({reason}){hint}") from exc
    try:
        with handle as f:
            return _read(f, path)
    except RecordingFormatError:
        raise
    except OSError as exc:  # a chunk that does not read: the chunks before it are whole
        if recover and salvageable:
            return recover_recording(path)[0]
        raise RecordingFormatError(f"{path}: damaged SenSnake recording ({_h5_reason(exc)}){hint}") from exc
    except _DAMAGE_ERRORS as exc:  # HDF5's structure itself is damaged (a flipped byte in a header or a heap)
        if recover and salvageable:
            return recover_recording(path)[0]
        raise RecordingFormatError(f"{path}: damaged SenSnake recording ({_h5_reason(exc)}){hint}") from exc


# What h5py raises on a file whose HDF5 structure is damaged, besides OSError.
_DAMAGE_ERRORS = (KeyError, TypeError, ValueError, RuntimeError, AttributeError, IndexError, UnicodeError,
                  OverflowError)


def check_input(path: str | Path) -> Path:
    """``path`` if it is a regular file to read; otherwise an error naming it and the cause: missing
    (FileNotFoundError), a symbolic link loop or one to a missing file, a folder, a device, FIFO or socket (whose
    read would block or never end)."""
    path = Path(path)
    try:
        status = os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            raise FileNotFoundError(f"recording {path} is a symbolic link to {os.readlink(path)}, which does not "
                                    "exist") from None
        raise FileNotFoundError(f"recording {path} does not exist") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise RecordingFormatError(f"recording {path} is a symbolic link loop (it leads back to itself), not a "
                                       "file") from None
        raise OSError(exc.errno, f"cannot read recording {path}: {exc.strerror}") from None
    kind = describe_kind(status.st_mode)
    if kind is not None:
        raise RecordingFormatError(f"recording {path} is {kind}, not a recording file")
    return path


def _open_h5(path: Path) -> h5py.File:
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        if "already open for write" not in str(exc):
            raise
        # Written by an older SenSnake (SWMR mode) that was killed: its SWMR flag is set and only a SWMR reader
        # may open it. Plain mode goes first because a SWMR reader retries bad checksums for a long time, which a
        # truncated file would turn into a hang.
        return h5py.File(path, "r", libver="latest", swmr=True)


def _h5_reason(exc: BaseException) -> str:
    """HDF5's refusal in a user's words (never "Unable to synchronously open file (… errno = …)")."""
    text = " ".join(str(getattr(exc, "strerror", None) or exc).split())
    if "truncated file" in text:
        return "truncated file"
    if "file signature not found" in text:
        return "not an HDF5 file"
    if "error message = '" in text or "errno = " in text:
        return _os_reason(exc)
    if (text.startswith("Unable to") or "synchronously" in text) and "(" in text:
        text = text.split("(", 1)[1].rsplit(")", 1)[0]  # the reason HDF5 gives inside its own report
    elif isinstance(exc, KeyError) and text.startswith("'") and text.endswith("'"):
        text = text[1:-1]
    return text.split(" (file name")[0][:160]


# -- salvage -----------------------------------------------------------------------------------------------------
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
OPTIONAL_COLUMNS = ("daq/board_time_s", "daq/clock_segment", "forces/status")  # extras a salvage drops rather than cut rows for


@dataclass(frozen=True)
class RecoveryReport:
    """What :func:`recover_recording` could read from a damaged file. ``rows`` maps each group (``daq``,
    ``robot``, ``forces``, ``events``) to (rows recovered, rows the file's metadata claimed)."""

    path: Path
    file_bytes: int
    claimed_bytes: int
    rows: dict[str, tuple[int, int]]
    duration_s: float

    @property
    def text(self) -> str:
        got, claimed = self.rows.get("daq", (0, 0))
        share = f"{got / claimed:.1%}" if claimed else "none"
        extra = "; ".join(f"{name} {g}/{c}" for name, (g, c) in self.rows.items() if name != "daq")
        what = (f"is truncated ({self.file_bytes} of {self.claimed_bytes} bytes)" if self.file_bytes < self.claimed_bytes
                else "was cut off in the middle of a write (its last data lies past the end its header claims)")
        return (f"{self.path.name} {what}: recovered {got} of {claimed} board samples ({share}, "
                f"{self.duration_s:.1f} s)" + (f"; {extra}" if extra else ""))


def _stored_eof(path: Path) -> int | None:
    """The end-of-file address the HDF5 superblock claims, or None if ``path`` is not HDF5 (superblock at 0)."""
    try:
        with path.open("rb") as handle:
            head = handle.read(64)
    except OSError:
        return None
    if len(head) < 48 or head[:8] != HDF5_SIGNATURE:
        return None
    version = head[8]
    if version in (0, 1):
        size_of_offsets = head[13]
        eof_at = (24 if version == 0 else 28) + 2 * size_of_offsets
    elif version in (2, 3):
        size_of_offsets = head[9]
        eof_at = 12 + 2 * size_of_offsets
    else:
        return None
    if size_of_offsets not in (4, 8) or eof_at + size_of_offsets > len(head):
        return None
    return int.from_bytes(head[eof_at:eof_at + size_of_offsets], "little")


def recover_recording(path: str | Path) -> tuple[Recording, RecoveryReport]:
    """Salvage a recording that was cut short (copy interrupted, disk failure): every row whose data chunk lies
    wholly inside the bytes that survive is kept, the rest is dropped, never guessed. Raises
    :class:`RecordingFormatError` when not even the file's structure survives."""
    import tempfile

    path = check_input(path)
    claimed = _stored_eof(path)
    size = path.stat().st_size
    if claimed is None:
        raise RecordingFormatError(f"{path} is not an HDF5 file: nothing to recover")
    with tempfile.TemporaryDirectory(prefix="sensnake-repair-") as folder:
        padded = Path(folder) / "padded.h5"
        # HDF5 refuses a file shorter than its superblock says; zero-padding it back makes the surviving
        # structure readable, and the chunk check below makes sure no padded (zero) byte reaches the data.
        shutil.copyfile(path, padded)
        if claimed > size:
            with padded.open("r+b") as handle:
                handle.truncate(claimed)
        try:
            handle5 = _open_h5(padded)
        except OSError as exc:
            raise RecordingFormatError(f"{path} is damaged beyond repair (HDF5: {_h5_reason(exc)})") from exc
        limits: dict[str, int] = {}
        claimed_rows: dict[str, int] = {}
        try:
            with handle5 as f:
                for group_name in ("daq", "robot", "forces", "events"):
                    if not _present(f, group_name, salvage=group_name != "daq"):
                        continue
                    try:
                        lengths, intact = _group_rows(f[group_name], group_name, min(size, claimed), limits)
                    except (OSError, *_DAMAGE_ERRORS):
                        if group_name == "daq":
                            _refuse_broken_links(f, path, group_name)  # named for what it is, not as damage
                            raise
                        limits[group_name] = 0  # an optional group whose structure was lost: left out
                        continue
                    if lengths:
                        claimed_rows[group_name] = min(lengths)
                        limits[group_name] = min(intact)
                recording = _read(f, path, limits)
        except RecordingFormatError:
            raise
        except (OSError, *_DAMAGE_ERRORS) as exc:
            raise RecordingFormatError(f"{path} is damaged beyond repair ({_h5_reason(exc)})") from exc
    rows = {name: (limits[name], claimed_rows[name]) for name in claimed_rows}
    report = RecoveryReport(path=path, file_bytes=size, claimed_bytes=claimed, rows=rows,
                            duration_s=recording.duration_s)
    return replace(recording, recovery=report.text), report


def _group_rows(group: h5py.Group, group_name: str, good_bytes: int,
                limits: dict[str, int]) -> tuple[list[int], list[int]]:
    """Each column's rows and intact rows in ``group`` (``limits`` gets every column's intact rows)."""
    lengths, intact = [], []
    for name in group:
        dataset = group[name]
        if not isinstance(dataset, h5py.Dataset) or dataset.shape == ():
            continue
        intact_rows = _intact_rows(dataset, good_bytes)
        limits[f"{group_name}/{name}"] = intact_rows
        if f"{group_name}/{name}" in OPTIONAL_COLUMNS:
            continue  # dropped below if shorter than the rest, never a reason to lose rows
        lengths.append(dataset.shape[0])
        intact.append(intact_rows)
    return lengths, intact


def _present(parent: h5py.Group, name: str, salvage: bool) -> bool:
    """``name in parent``. When salvaging, a link HDF5 cannot even check (its header lay in the part of the file that
    was lost) is absent; otherwise that damage is raised."""
    try:
        return name in parent
    except (OSError, *_DAMAGE_ERRORS):
        if salvage:
            return False
        raise


def _intact_rows(dataset: h5py.Dataset, good_bytes: int) -> int:
    """Leading rows of a chunked dataset whose chunks all lie inside the first ``good_bytes`` of the file."""
    if dataset.chunks is None:
        offset = dataset.id.get_offset()
        nbytes = dataset.id.get_storage_size()
        return dataset.shape[0] if offset is not None and offset + nbytes <= good_bytes else 0
    chunk_rows = dataset.chunks[0]
    chunks = sorted((dataset.id.get_chunk_info(i) for i in range(dataset.id.get_num_chunks())),
                    key=lambda c: c.chunk_offset[0])
    rows = 0
    for chunk in chunks:
        if chunk.chunk_offset[0] != rows or chunk.byte_offset is None or chunk.byte_offset + chunk.size > good_bytes:
            break
        rows = min(dataset.shape[0], rows + chunk_rows)
    return rows


def repair_recording(path: str | Path, out: str | Path) -> RecoveryReport:
    """Write what :func:`recover_recording` salvages from ``path`` to a new, clean file ``out`` (moved into place
    only when complete; ``path`` itself is never changed unless ``out`` names it). Returns the report."""
    path, out = Path(path), Path(out)
    try:
        recording, report = recover_recording(path)
    except RecordingFormatError:
        raise
    except OSError as exc:
        raise RecordingFormatError(f"cannot read {path}: {exc.strerror or exc}") from exc
    write_recording(recording, out)
    return report


def write_recording(recording: Recording, out: str | Path) -> Path:
    """Write a whole :class:`Recording` (read or salvaged) as a SPEC §3.5 file at ``out`` (atomically)."""
    out = Path(out)
    with _written_into_place(out) as work, h5py.File(work, "w", locking=False) as f:
        f.attrs["format"] = FORMAT
        f.attrs["version"] = VERSION
        f.attrs["started"] = recording.started
        f.attrs["config"] = recording.config_text
        f.attrs["duration_s"] = recording.duration_s
        if recording.recovery:
            f.attrs["recovered"] = recording.recovery
        daq = f.create_group("daq")
        daq.attrs["channels"] = np.array(recording.channels, dtype=h5py.string_dtype())
        for key, value in (("crc_errors", recording.crc_errors), ("dropped_frames", recording.dropped_frames),
                           ("resyncs", recording.resyncs)):
            daq.attrs[key] = np.int64(value)
        daq["time_s"] = recording.time_s
        daq["seq"] = recording.seq.astype(np.uint32)
        daq["counts"] = recording.counts.astype(np.uint16)
        daq["conductance_S"] = recording.conductance_s
        if recording.board_time_s is not None:
            daq["board_time_s"] = recording.board_time_s
        if recording.clock_segment is not None:
            daq["clock_segment"] = recording.clock_segment.astype(np.int32)
        if recording.robot is not None:
            robot = f.create_group("robot")
            robot["time_s"] = recording.robot.time_s
            robot["goal_rad"] = recording.robot.goal_rad
            robot["present_rad"] = recording.robot.present_rad
            robot["current_mA"] = recording.robot.current_ma
        if recording.forces_n is not None:
            forces = f.create_group("forces")
            forces.attrs["calibration"] = recording.calibration_json or ""
            forces["force_N"] = recording.forces_n
            if recording.forces_status is not None:
                forces["status"] = recording.forces_status.astype(np.int8)
        events = f.create_group("events")
        events["time_s"] = np.array([e.time_s for e in recording.events], dtype=np.float64)
        events["kind"] = np.array([e.kind.encode()[:EVENT_KIND_BYTES] for e in recording.events],
                                  dtype=f"S{EVENT_KIND_BYTES}")
        events["text"] = np.array([_truncate_utf8(e.text, EVENT_TEXT_BYTES) for e in recording.events],
                                  dtype=f"S{EVENT_TEXT_BYTES}")
    return out


def write_reestimated(path: str | Path, out: str | Path, force_n: np.ndarray, status: np.ndarray,
                      calibration_json: str, note: str) -> Path:
    """A copy of the recording ``path`` at ``out`` (everything kept: daq, robot, control, events, attributes) whose
    ``/forces`` is replaced: ``force_N`` (N, C; NaN for a channel without calibration), ``status`` (N, C) int8
    :class:`models.sls.ForceStatus` codes, the calibration JSON as the attribute ``calibration`` and ``note`` (what
    was re-estimated, with what) as ``reestimated``. Written beside ``out`` under a hidden name and moved into place
    complete; ``path`` is never changed."""
    path, out = Path(path), Path(out)
    with _written_into_place(out) as work:
        _copy_file(path, work)
        with h5py.File(work, "r+", locking=False) as f:
            if "forces" in f:
                del f["forces"]
            forces = f.create_group("forces")
            forces.attrs["calibration"] = calibration_json
            forces.attrs["reestimated"] = note
            forces.create_dataset("force_N", data=np.asarray(force_n, dtype=np.float64), chunks=True)
            forces.create_dataset("status", data=np.asarray(status, dtype=np.int8), chunks=True)
    return out


def _copy_file(path: Path, work: Path) -> None:
    with open(path, "rb") as source, open(work, "wb") as target:
        shutil.copyfileobj(source, target, 8 << 20)


def copy_recording(path: str | Path, out: str | Path) -> Path:
    """An undamaged recording copied as it is, byte for byte (every group, its /sim, /control, /mocap and
    attributes included), beside ``out`` under a hidden name and moved into place complete."""
    path, out = Path(path), Path(out)
    with _written_into_place(out) as work:
        _copy_file(path, work)
    return out


def carry_groups(source: str | Path, copy: str | Path) -> tuple[list[str], list[str]]:
    """Copy into ``copy`` (a salvaged recording) the top-level groups of ``source`` it lacks (/sim, /control,
    /mocap, …) that read whole; returns (carried, lost): the groups copied and those the damage made unreadable."""
    carried: list[str] = []
    lost: list[str] = []
    try:
        src = h5py.File(source, "r", locking=False)
    except OSError:
        return carried, lost
    with src, h5py.File(copy, "a", locking=False) as dst:
        for name in list(src):
            if name in dst:
                continue
            try:
                src.copy(src[name], dst, name=name)
                carried.append(f"/{name}")
            except _DAMAGE_ERRORS + (OSError,):
                with contextlib.suppress(KeyError, OSError):
                    del dst[name]
                lost.append(f"/{name}")
    return carried, lost


@contextlib.contextmanager
def _written_into_place(out: Path) -> Iterator[Path]:
    """A hidden work file beside ``out`` (:func:`app.core.outputs.create_temporary`: exclusive, never through a
    symlink) that becomes ``out`` (synced, with ``out``'s mode if it existed) when the block ends; on an OSError it
    is removed and a :class:`RecordingError` names ``out`` and the reason. ``out`` must be a regular file or new."""
    check_output(out)
    work: Path | None = None
    try:
        fd, work = create_temporary(out, ".partial")
        os.close(fd)
        yield work
        _fsync(work)
        move_into_place(work, out)
    except BaseException as exc:
        if work is not None:
            with contextlib.suppress(OSError):
                work.unlink()
        if isinstance(exc, OSError) and not isinstance(exc, OutputPathError):
            raise RecordingError(f"cannot write {out}: {_os_reason(exc)}") from exc
        raise


def _attr_text(value: Any) -> str:
    """An attribute as text a user (and a UTF-8 file) can take: undecodable bytes become U+FFFD, never a surrogate
    that would stop the text from being written again (a damaged ``config`` attribute in ``sensnake repair``)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.shape == ():
        return _attr_text(value.item())
    text = str(value)
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
    except UnicodeEncodeError:
        return text.encode("utf-8", "replace").decode("utf-8", "replace")


# What each dataset a reader takes must be: (numpy kinds, dimensions, its columns in words). Anything else is refused
# naming the file, the dataset and this, instead of failing later as numpy's or HDF5's words (or, for complex
# numbers, as a warning and a silently wrong result).
_FLOAT, _INTEGER, _TEXT = "f", "iu", "SO"
_KIND_WORDS = {_FLOAT: "real numbers (float)", _INTEGER: "whole numbers (integer)", _TEXT: "text"}


def _describe_dataset(dataset: h5py.Dataset) -> str:
    kind = dataset.dtype
    what = ("compound records" if kind.fields else "complex numbers" if kind.kind == "c" else
            "text" if kind.kind in "SUO" else "real numbers" if kind.kind == "f" else
            "whole numbers" if kind.kind in "iu" else f"{kind} values")
    shape = ("a single value" if dataset.shape == () else f"{dataset.shape[0]} rows" if dataset.ndim == 1 else
             " × ".join(str(n) for n in dataset.shape))
    return f"{what}, {shape}"


def _refuse_broken_links(f: h5py.File, file: Path, group: str) -> None:
    """:class:`RecordingFormatError` naming the first soft link of ``group`` that leads nowhere or loops back on
    itself (a file made so on purpose, not a damaged one); nothing when there is none."""
    try:
        names = list(f[group].keys())
    except (KeyError, RuntimeError, OSError, ValueError):
        return
    for name in names:
        try:
            link = f[group].get(name, getlink=True)
        except (KeyError, RuntimeError, OSError, ValueError):
            continue
        if not isinstance(link, h5py.SoftLink):
            continue
        try:
            f[f"{group}/{name}"]
        except (KeyError, RuntimeError, OSError, ValueError):
            raise RecordingFormatError(f"{file}: /{group}/{name} cannot be read: a link that leads nowhere or loops "
                                       "back on itself") from None


def _dataset(f: h5py.File, file: Path, name: str, kinds: str, ndim: int, columns: int | None = None,
             columns_are: str = "") -> h5py.Dataset:
    """The dataset ``name`` of ``f``, checked: a dataset in this file (not a group, not a link that loops or leads
    out of the file), of one of numpy's ``kinds``, with ``ndim`` dimensions and ``columns`` columns when given.
    :class:`RecordingFormatError` names the file, the dataset and what was expected."""
    where = f"{file}: /{name}"
    try:
        link = f.get(name, getlink=True)
    except (KeyError, RuntimeError, OSError, ValueError) as exc:
        raise RecordingFormatError(f"{where} cannot be read ({_h5_reason(exc)}): a damaged recording") from exc
    if link is None:
        raise RecordingFormatError(f"{where} is missing: a damaged or incomplete recording")
    if isinstance(link, h5py.ExternalLink):
        raise RecordingFormatError(f"{where} is a link to another file ({link.filename}): a recording holds its own "
                                   "data")
    try:
        dataset = f[name]
    except (KeyError, RuntimeError, OSError, ValueError) as exc:
        why = ("a link that leads nowhere or loops back on itself" if isinstance(link, h5py.SoftLink) else
               _h5_reason(exc))
        raise RecordingFormatError(f"{where} cannot be read: {why}") from exc
    if not isinstance(dataset, h5py.Dataset):
        raise RecordingFormatError(f"{where} is a group, expected a dataset")
    shape_words = ("one value per row" if ndim == 1 else
                   f"rows × {columns} columns{f' ({columns_are})' if columns_are else ''}" if columns is not None else
                   "rows × columns")
    expected = f"expected {_KIND_WORDS[kinds]}, {shape_words}"
    if dataset.dtype.fields or dataset.dtype.kind not in kinds:
        raise RecordingFormatError(f"{where} holds {_describe_dataset(dataset)}; {expected}")
    if dataset.ndim != ndim or (columns is not None and dataset.shape[1] != columns):
        raise RecordingFormatError(f"{where} holds {_describe_dataset(dataset)}; {expected}")
    _refuse_hollow(dataset, where)
    return dataset


# A dataset that declares more than this and holds data for less than half of it (chunks never written: HDF5 reads
# them as zeros) is refused before it is read: a forged 11 kB file declaring 10⁹ rows would fill the memory.
_HOLLOW_BYTES = 256 << 20


def _refuse_hollow(dataset: h5py.Dataset, where: str) -> None:
    declared = int(dataset.size) * dataset.dtype.itemsize
    if declared <= _HOLLOW_BYTES or dataset.compression is not None or dataset.chunks is None:
        return
    try:
        stored = int(dataset.id.get_storage_size())
    except (RuntimeError, OSError, ValueError):
        return
    if stored < declared // 2:
        raise RecordingFormatError(f"{where} declares {dataset.shape[0]:,} rows ({declared / 1e9:.3g} GB) but the file "
                                   f"holds data for {stored / 1e6:.3g} MB of them: a damaged or forged recording, not "
                                   "read")


def _int_attr(attrs: h5py.AttributeManager, file: Path, where: str, key: str, default: int) -> int:
    """A whole-number attribute (a link counter, the version); RecordingFormatError naming it otherwise."""
    value = attrs.get(key, default)
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value.item()
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
        raise RecordingFormatError(f"{file}: {where} attribute '{key}' is {_attr_text(value)[:40]!r}, expected a "
                                   "whole number")
    return int(value)


def _channel_names(daq: h5py.Group, file: Path) -> tuple[str, ...]:
    raw = daq.attrs.get("channels")
    if raw is None:
        raise RecordingFormatError(f"{file}: /daq has no 'channels' attribute (the channel names)")
    values = np.asarray(raw)
    if values.ndim != 1 or values.dtype.kind not in "SUO":
        raise RecordingFormatError(f"{file}: the 'channels' attribute of /daq is {_attr_text(raw)[:40]!r}; expected "
                                   "a list of channel names")
    return tuple(_attr_text(c) for c in values)


def _read(f: h5py.File, path: Path, limits: dict[str, int] | None = None) -> Recording:
    """The recording in ``f``; ``limits`` caps the rows read per group (salvage). Every dataset read is checked
    (:func:`_dataset`), so a hostile or damaged file is refused naming the dataset, never read as numbers."""
    cap = limits or {}
    salvage = limits is not None
    big = np.iinfo(np.int64).max
    fmt = _attr_text(f.attrs.get("format", ""))
    if fmt != FORMAT:
        raise RecordingFormatError(f"{path} is not a SenSnake recording (format {fmt!r}, expected {FORMAT!r})")
    version = _int_attr(f.attrs, path, "root", "version", -1)
    if version != VERSION:
        raise RecordingFormatError(f"{path} is a version-{version} recording; this program reads version {VERSION}"
                                   " — update SenSnake Studio")
    daq_link = f.get("daq", getlink=True)
    if daq_link is None or not isinstance(f.get("daq"), h5py.Group):
        raise RecordingFormatError(f"{path}: damaged SenSnake recording (no /daq group)")
    daq = f["daq"]
    channels = _channel_names(daq, path)
    n_channels = len(channels)
    per_channel = "one per channel name"
    columns = {"time_s": _dataset(f, path, "daq/time_s", _FLOAT, 1),
               "seq": _dataset(f, path, "daq/seq", _INTEGER, 1),
               "counts": _dataset(f, path, "daq/counts", _INTEGER, 2, n_channels, per_channel),
               "conductance_S": _dataset(f, path, "daq/conductance_S", _FLOAT, 2, n_channels, per_channel)}
    # A crash between two dataset resizes leaves columns of different lengths: keep the rows all of them have.
    n = min(min(d.shape[0] for d in columns.values()), cap.get("daq", big))
    lengths = {name: d.shape[0] for name, d in columns.items()}
    stop = parse_document(f.attrs.get(RUN_STOP)) if len(set(lengths.values())) > 1 and not salvage else None
    if stop is not None and stop.get("exit_status") in ("success", "abort"):
        # ... but a recording closed normally (its run_stop written after the file was complete) has none (a run cut
        # short is given a "fail" run_stop later, on a file as the crash left it)
        told = ", ".join(f"{name} {rows}" for name, rows in lengths.items())
        raise RecordingFormatError(f"{path}: damaged SenSnake recording (its /daq columns differ in length: {told} "
                                   "rows, in a recording that was closed normally)")
    if not salvage:  # a time that is no time (NaN, inf) or that runs backwards: damage, never read as data
        times = columns["time_s"][:n]
        bad = np.flatnonzero(~np.isfinite(times))
        if bad.size:
            raise RecordingFormatError(f"{path}: damaged SenSnake recording (/daq/time_s row {int(bad[0])} is "
                                       f"{float(times[bad[0]])}; {bad.size} row(s) not a time)")
        back = np.flatnonzero(np.diff(times) < 0)
        if back.size:
            k = int(back[0]) + 1
            raise RecordingFormatError(f"{path}: damaged SenSnake recording (/daq/time_s runs backwards at row {k}: "
                                       f"{float(times[k - 1]):.6g} then {float(times[k]):.6g} s)")
    forces = calibration = None
    status = None
    if _present(f, "forces", salvage) and cap.get("forces", big) > 0:
        calibration = _attr_text(f["forces"].attrs.get("calibration", ""))
        force_set = _dataset(f, path, "forces/force_N", _FLOAT, 2, n_channels, per_channel)
        forces = force_set[:min(n, force_set.shape[0], cap.get("forces", big))]
        if _present(f["forces"], "status", salvage):
            status_set = _dataset(f, path, "forces/status", _INTEGER, 2, n_channels, per_channel)
            if min(status_set.shape[0], cap.get("forces/status", big)) >= len(forces):
                status = status_set[:len(forces)]
    board_time = segment = None
    if _present(daq, "board_time_s", salvage) and cap.get("daq/board_time_s", big) >= n:
        board_time = _dataset(f, path, "daq/board_time_s", _FLOAT, 1)[:n]
    if _present(daq, "clock_segment", salvage) and cap.get("daq/clock_segment", big) >= n:
        segment = _dataset(f, path, "daq/clock_segment", _INTEGER, 1)[:n]
    robot = None
    if _present(f, "robot", salvage) and cap.get("robot", big) > 0:
        robot_sets = {"time_s": _dataset(f, path, "robot/time_s", _FLOAT, 1)}
        goal = _dataset(f, path, "robot/goal_rad", _FLOAT, 2)
        for name in ("goal_rad", "present_rad", "current_mA"):
            robot_sets[name] = _dataset(f, path, f"robot/{name}", _FLOAT, 2, goal.shape[1], "one per joint")
        m = min(min(d.shape[0] for d in robot_sets.values()), cap.get("robot", big))
        robot = RobotRecord(time_s=robot_sets["time_s"][:m], goal_rad=robot_sets["goal_rad"][:m],
                            present_rad=robot_sets["present_rad"][:m], current_ma=robot_sets["current_mA"][:m])
    events: tuple[RecordingEvent, ...] = ()
    if _present(f, "events", salvage) and cap.get("events", big) > 0:
        event_sets = {"time_s": _dataset(f, path, "events/time_s", _FLOAT, 1),
                      "kind": _dataset(f, path, "events/kind", _TEXT, 1),
                      "text": _dataset(f, path, "events/text", _TEXT, 1)}
        m = min(min(d.shape[0] for d in event_sets.values()), cap.get("events", big))
        events = tuple(RecordingEvent(float(t), _attr_text(k), _attr_text(x)) for t, k, x in
                       zip(event_sets["time_s"][:m], event_sets["kind"][:m], event_sets["text"][:m]))
    return Recording(
        path=path, version=version, started=_attr_text(f.attrs.get("started", "")),
        config_text=_attr_text(f.attrs.get("config", "")), channels=channels,
        time_s=columns["time_s"][:n], seq=columns["seq"][:n], counts=columns["counts"][:n],
        conductance_s=columns["conductance_S"][:n], board_time_s=board_time, clock_segment=segment,
        crc_errors=_int_attr(daq.attrs, path, "/daq", "crc_errors", 0),
        dropped_frames=_int_attr(daq.attrs, path, "/daq", "dropped_frames", 0),
        resyncs=_int_attr(daq.attrs, path, "/daq", "resyncs", 0),
        robot=robot, forces_n=forces, calibration_json=calibration, events=events, forces_status=status)


# -- export ------------------------------------------------------------------------------------------------------
def export_csv(recording: Recording, out: str | Path, unit_suffixes: bool = False) -> Path:
    """Write ``time_s`` then one column per channel: forces (N) if stored from a calibration, else conductance (S);
    ``unit_suffixes``: columns ``<name>_N`` / ``<name>_uS`` (µS) instead of the bare SPEC names. Returns ``out``."""
    out = Path(out)
    values = recording.conductance_s
    quantity = CONDUCTANCE_COLUMN
    if recording.forces_n is not None and not recording.forces_from_defaults:
        values, quantity = recording.forces_n, FORCE_COLUMN
    n = min(values.shape[0], recording.n_samples)
    names = list(recording.channels)
    block = values[:n]
    if unit_suffixes:
        names, block = with_unit_suffixes(names, block, quantity)
    table = np.column_stack([recording.time_s[:n], block])
    def write(handle: TextIO) -> None:
        csv.writer(handle).writerow(["time_s", *names])
        np.savetxt(handle, table, delimiter=",", fmt="%.10g")

    # All or nothing: a failure (disk full, a folder at OUT) never leaves half a CSV over an earlier export.
    write_atomically(out, write)
    return out

