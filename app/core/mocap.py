"""Motion-capture takes beside a recording: read a C3D or an XDF take, fit every segment's pose, put the take on the
recording's clock and write a copy of the recording with ``/mocap`` added (docs/MOCAP.md, SPEC §3.5 extension).

``/mocap``: ``time_s`` (M, the recording's clock), ``markers_m`` (M×K×3, NaN where unseen, in the order of the
``labels`` attribute: segment 1's markers 1…k, then segment 2's, …), ``segment_center_m`` (M×12×3),
``segment_rotation`` (M×12×3×3, columns: the segment's x to the head, y left, z up), ``residual_m`` (M×12, RMS of
the fit), and ``joint_angle_rad`` (M×12; joint 1 NaN: the head piece carries no markers), ``fit_flag`` (M×12,
:class:`models.mocap.FitFlag`), ``markers_used`` (M×12); attributes ``labels``, ``source``, ``rate_hz``,
``clock_offset_s`` (recording time − source time), ``marker_layout_m`` (12×k×3), ``take_start_s`` (the take's first
frame on the recording's clock), ``clock_offset_how`` (given, or found from the motion with its numbers),
``clock_offset_confidence`` and ``clock_offset_uncertainty_s`` (NaN when given), ``max_residual_m``, ``units``
(the source's), ``fit_flags`` (the flag legend).

Source time: a C3D's first stored frame is 0 s, frame i is i / POINT:RATE; an XDF stream's time is its LSL time
stamps (pyxdf's clock-synchronised ones). A marker is unseen where its coordinates are NaN, where a C3D gives it a
negative residual, or where it sits exactly at (0, 0, 0) (what several systems send for a lost marker).

The input recording is only read. The copy is built in a hidden file beside the output and linked into place only
if no file is there: an existing file is never replaced. :func:`import_take` reads, fits and writes a take a block
of frames at a time, keeping only its joint angles and times whole (for the clock offset): a C3D take is never held
whole (:func:`open_c3d`); an XDF one is, as pyxdf loads it. Called from one thread (the CLI's).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import secrets
import shutil
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core import c3d_frames
from app.core.errors import MocapFileError
from app.core.outputs import remove_stale_temporaries, temporary_stem
from app.core.recording import MOCAP_CHUNK_BYTES
from devices.config import MocapConfig
from models.mocap import (
    ClockOffset,
    FitFlag,
    SegmentFit,
    check_layout,
    find_clock_offset,
    fit_segments,
    joint_angles,
    markers_from_poses,
    resample_poses,
)

UNITS_TO_M = {"mm": 1e-3, "millimeter": 1e-3, "millimeters": 1e-3, "millimetre": 1e-3, "millimetres": 1e-3,
              "cm": 1e-2, "m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0}
FLAG_LEGEND = "; ".join(f"{flag.value} {flag.name.lower()}" for flag in FitFlag)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)


def row_chunks(frames: int, row_shape: tuple[int, ...], dtype: Any) -> tuple[int, ...]:
    """``/mocap``'s chunks for ``frames`` rows: whole rows, ~``MOCAP_CHUNK_BYTES`` each (at most ``frames``), as the
    recorder writes a live take. Not h5py's guess, which splits a long take's rows into columns ((27000, 1, 1) for
    30 minutes' markers): a reader of frames then decompresses every column's chunk, and a writer of a block of
    frames rewrites each of them many times (a 30-minute import ran past 11 minutes so)."""
    row_bytes = int(np.prod(row_shape, dtype=int)) * np.dtype(dtype).itemsize
    return (max(1, min(int(frames), max(16, MOCAP_CHUNK_BYTES // max(row_bytes, 1)))), *row_shape)


@dataclass(frozen=True)
class Take:
    """A take's markers in the layout's order: ``markers_m`` (M, S, K, 3) NaN where unseen, at ``time_s`` (M,) on
    the source's clock."""

    path: Path
    kind: str  # "C3D" or "XDF"
    time_s: np.ndarray
    markers_m: np.ndarray
    labels: tuple[str, ...]  # S·K labels, segment-major
    rate_hz: float
    units: str
    missing_labels: tuple[str, ...]  # layout labels the file does not have (unseen throughout)
    ignored_labels: int  # the file's labels that are not in the layout
    note: str = ""

    @property
    def source(self) -> str:
        """What the take came from, for the ``source`` attribute."""
        return f"{self.kind} {self.path.name}" + (f" ({self.note})" if self.note else "")


def layout_labels(mocap: MocapConfig, n_segments: int) -> list[list[str]]:
    """The expected labels, ``[segment][marker]``."""
    k = len(mocap.marker_layout_m)
    return [[mocap.label(s + 1, m + 1) for m in range(k)] for s in range(n_segments)]


def _key(label: str) -> str:
    """A label as matched: a leading ``Subject:`` prefix dropped (Vicon, Nexus), case and outer spaces ignored."""
    return label.strip().rsplit(":", 1)[-1].strip().lower()


def marker_columns(path: Path, labels_in_file: Sequence[str], mocap: MocapConfig, n_segments: int
                   ) -> tuple[np.ndarray, tuple[str, ...], tuple[str, ...], int]:
    """Where each layout marker is among the file's ``labels_in_file``: columns (S, K), −1 where the file does not
    have it; the layout's labels, those missing, and how many of the file's are not the layout's. Refused (naming the
    file) when no layout label is there, or a segment has fewer than 3."""
    expected = layout_labels(mocap, n_segments)
    index: dict[str, int] = {}
    for i, label in enumerate(labels_in_file):
        index.setdefault(_key(label), i)
    flat = [label for row in expected for label in row]
    found = [label for label in flat if _key(label) in index]
    if not found:
        shown = ", ".join(list(labels_in_file)[:6]) + (" …" if len(labels_in_file) > 6 else "")
        raise MocapFileError(
            f"{path}: none of the layout's marker labels ({flat[0]} … {flat[-1]}, [mocap] labels = "
            f"{mocap.labels!r}) is in the file (it has {len(labels_in_file)}: {shown or 'none'}); set [mocap] labels "
            "to the pattern the take uses")
    for s, row in enumerate(expected):
        have = [label for label in row if _key(label) in index]
        if len(have) < 3:
            raise MocapFileError(
                f"{path}: segment {s + 1} has {len(have)} of its {len(row)} markers labelled in the file "
                f"({', '.join(have) or 'none'}): a segment's pose needs 3; label them {', '.join(row)} (or set "
                "[mocap] labels and marker_layout_m)")
    columns = np.array([[index.get(_key(label), -1) for label in row] for row in expected], dtype=int)
    missing = tuple(label for label in flat if _key(label) not in index)
    ignored = len({_key(x) for x in labels_in_file} - {_key(x) for x in flat})
    return columns, tuple(flat), missing, ignored


def arrange_markers(xyz: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The file's trajectories ``xyz`` (M, P, 3) in the layout's order (M, S, K, 3) (``columns`` from
    :func:`marker_columns`), NaN where the file has no such marker or gives it at exactly (0, 0, 0)."""
    n_segments, k = columns.shape
    markers = np.full((xyz.shape[0], n_segments, k, 3), np.nan)
    for s in range(n_segments):
        for m in range(k):
            if columns[s, m] >= 0:
                markers[:, s, m] = xyz[:, columns[s, m]]
    lost = np.all(markers == 0.0, axis=-1)
    markers[lost] = np.nan
    return markers


def place_markers(path: Path, labels_in_file: Sequence[str], xyz: np.ndarray, mocap: MocapConfig,
                   n_segments: int) -> tuple[np.ndarray, tuple[str, ...], tuple[str, ...], int]:
    """The file's marker trajectories ``xyz`` (M, P, 3), named ``labels_in_file``, in the layout's order
    (M, S, K, 3). Refused (naming the file) when no layout label is there, or a segment has fewer than 3."""
    columns, flat, missing, ignored = marker_columns(path, labels_in_file, mocap, n_segments)
    return arrange_markers(xyz, columns), flat, missing, ignored


def _units_scale(path: Path, units: str, where: str) -> float:
    scale = UNITS_TO_M.get(units.strip().lower())
    if scale is None:
        raise MocapFileError(f"{path}: {where} = {units!r} is not a length unit this reads (mm, cm or m): cannot "
                             "tell where the markers are")
    return scale


@dataclass(frozen=True)
class TakeFrames:
    """A take read a block of frames at a time: ``read(start, stop)`` gives frames ``start`` … ``stop`` − 1 as
    markers (n, S, K, 3) in metres in the layout's order, NaN where unseen; ``time_s`` (M,) on the source's clock.
    Everything a refusal needs (labels, units, rate, the file's length) was checked when it was opened."""

    path: Path
    kind: str  # "C3D" or "XDF"
    time_s: np.ndarray
    labels: tuple[str, ...]
    rate_hz: float
    units: str
    missing_labels: tuple[str, ...]
    ignored_labels: int
    read: Callable[[int, int], np.ndarray]
    note: str = ""

    @property
    def frames(self) -> int:
        return len(self.time_s)

    @property
    def source(self) -> str:
        return f"{self.kind} {self.path.name}" + (f" ({self.note})" if self.note else "")


def frames_of(take: Take) -> TakeFrames:
    """A take already in memory (an XDF stream: pyxdf loads the whole file) read as blocks of its frames."""
    return TakeFrames(take.path, take.kind, take.time_s, take.labels, take.rate_hz, take.units, take.missing_labels,
                      take.ignored_labels, lambda start, stop: take.markers_m[start:stop], take.note)


def open_c3d(path: str | Path, mocap: MocapConfig, n_segments: int) -> TakeFrames:
    """A C3D take, its header and parameters read (:func:`c3d_frames.read_head`) and checked, its frames read when
    asked for, straight from the data section: points scaled by POINT:UNITS to metres, timed by POINT:RATE from 0 at
    its first stored frame. Raises :class:`MocapFileError` naming the file and the cause. A DEC-format file (rare)
    is read whole by ezc3d, at most 65,535 frames."""
    path = Path(path)
    if not path.is_file():
        raise MocapFileError(f"{path}: no such take (C3D file)")
    try:
        head = c3d_frames.read_head(path)
    except OSError as exc:
        raise MocapFileError(f"{path} is not a readable C3D file ({exc.strerror or exc})") from exc
    if head is None:
        return frames_of(_read_c3d_whole(path, mocap, n_segments))
    point = head["parameters"].get("POINT", {})
    labels: list[str] = []
    for name in ("LABELS", *(f"LABELS{i}" for i in range(2, 10))):
        if name in point:
            labels += [str(x) for x in point[name]["value"]]
    units, scale, rate = _units_and_rate(path, point, head["header"]["points"]["frame_rate"])
    try:
        layout = c3d_frames.point_layout(path, head)
    except (KeyError, TypeError, ValueError, IndexError, OSError) as exc:
        if isinstance(exc, MocapFileError):
            raise
        raise MocapFileError(f"{path}: cannot tell how many frames it holds ({type(exc).__name__}: {exc})") from exc
    if layout.frames < 2:
        raise MocapFileError(f"{path}: fewer than two frames of points")
    columns, flat, missing, ignored = marker_columns(path, labels[:layout.points], mocap, n_segments)
    note = f"{layout.frames} frames (from {layout.how})" if layout.frames > layout.header_frames else ""

    def read(start: int, stop: int) -> np.ndarray:
        return arrange_markers(c3d_frames.read_frames(path, layout, start, stop) * scale, columns)

    time_s = np.arange(layout.frames) / rate
    return TakeFrames(path, "C3D", time_s, flat, rate, units, missing, ignored, read, note=note)


def _units_and_rate(path: Path, point: dict[str, Any], header_rate: float) -> tuple[str, float, float]:
    units_value = point.get("UNITS", {}).get("value", [])
    if not len(units_value) or not str(units_value[0]).strip():
        raise MocapFileError(f"{path}: no POINT:UNITS: cannot tell millimetres from metres")
    units = str(units_value[0]).strip()
    scale = _units_scale(path, units, "POINT:UNITS")
    rate_value = point.get("RATE", {}).get("value", [])
    rate = float(rate_value[0]) if len(rate_value) else float(header_rate)
    if not np.isfinite(rate) or rate <= 0:
        raise MocapFileError(f"{path}: POINT:RATE = {rate!r} is not a frame rate")
    return units, scale, rate


def read_c3d(path: str | Path, mocap: MocapConfig, n_segments: int) -> Take:
    """A C3D take whole (:func:`open_c3d`, every frame read). Raises :class:`MocapFileError` naming the file and the
    cause. For a short take or a test: the import reads a take a block at a time."""
    frames = open_c3d(path, mocap, n_segments)
    markers = frames.read(0, frames.frames)
    return Take(frames.path, frames.kind, frames.time_s, markers, frames.labels, frames.rate_hz, frames.units,
                frames.missing_labels, frames.ignored_labels, note=frames.note)


def _read_c3d_whole(path: Path, mocap: MocapConfig, n_segments: int) -> Take:
    """A DEC-format C3D take (VAX floats), read whole by ezc3d: at most 65,535 frames, a longer one refused."""
    import ezc3d

    try:
        c3d = ezc3d.c3d(str(path))
    except (RuntimeError, ValueError, OSError, IndexError) as exc:
        raise MocapFileError(f"{path} is not a readable C3D file ({' '.join(str(exc).split()) or type(exc).__name__})"
                             ) from exc
    point = c3d["parameters"].get("POINT", {})
    labels: list[str] = []
    for name in ("LABELS", *(f"LABELS{i}" for i in range(2, 10))):
        if name in point:
            labels += [str(x) for x in point[name]["value"]]
    units, scale, rate = _units_and_rate(path, point, float(c3d["header"]["points"]["frame_rate"]))
    points = np.asarray(c3d["data"]["points"], dtype=float)  # (4, P, M)
    if points.ndim != 3 or points.shape[2] < 2:
        raise MocapFileError(f"{path}: fewer than two frames of points")
    try:
        layout = c3d_frames.point_layout(path, c3d)
    except (KeyError, TypeError, ValueError, IndexError, OSError) as exc:
        if isinstance(exc, MocapFileError):
            raise
        raise MocapFileError(f"{path}: cannot tell how many frames it holds ({type(exc).__name__}: {exc})") from exc
    if layout.frames > points.shape[2]:
        raise MocapFileError(f"{path}: {layout.frames} frames, more than 65,535, in a DEC-format C3D: this reader "
                             "reads Intel and MIPS files only that long; export the take again as an Intel (PC) C3D")
    xyz = np.transpose(points[:3], (2, 1, 0)) * scale  # (M, P, 3)
    residuals = c3d["data"].get("meta_points", {}).get("residuals")
    if residuals is not None and np.shape(residuals)[-2:] == points.shape[1:]:
        xyz[np.transpose(np.asarray(residuals)[0]) < 0] = np.nan
    del points, c3d
    markers, flat, missing, ignored = place_markers(path, labels[:xyz.shape[1]], xyz, mocap, n_segments)
    return Take(path, "C3D", np.arange(xyz.shape[0]) / rate, markers, flat, rate, units, missing, ignored)


_AXIS = re.compile(r"^(?P<name>.*?)[\s_.:/-]*(?P<axis>[XYZxyz])$")


def _xdf_text(value: Any) -> str:
    """pyxdf's parsed XML keeps every value in a list."""
    while isinstance(value, list):
        value = value[0] if value else ""
    return str(value or "")


def read_xdf(path: str | Path, mocap: MocapConfig, n_segments: int) -> Take:
    """The first stream of type MoCap in an XDF file (pyxdf, clocks synchronised): each channel named by its
    ``marker`` and ``type`` (PositionX/Y/Z) or by a label ending in X, Y or Z (``SEG01_1_X``), in its ``unit``.
    Raises :class:`MocapFileError` naming the file and the cause."""
    import pyxdf

    path = Path(path)
    if not path.is_file():
        raise MocapFileError(f"{path}: no such XDF file")
    try:
        streams, _ = pyxdf.load_xdf(str(path))
    except (ValueError, OSError, EOFError, KeyError, IndexError, RuntimeError) as exc:
        raise MocapFileError(f"{path} is not a readable XDF file ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())[:160]})") from exc
    mocap_streams = [s for s in streams if _xdf_text(s["info"].get("type")).strip().lower() == "mocap"]
    if not mocap_streams:
        kinds = ", ".join(f"{_xdf_text(s['info'].get('name'))} ({_xdf_text(s['info'].get('type')) or 'no type'})"
                          for s in streams)
        raise MocapFileError(f"{path}: no stream of type MoCap (it has {len(streams)}: {kinds or 'none'})")
    stream = mocap_streams[0]
    name = _xdf_text(stream["info"].get("name"))
    desc = stream["info"].get("desc") or [None]
    channels: list[dict[str, Any]] = []
    if isinstance(desc[0], dict):
        block = desc[0].get("channels") or [None]
        if isinstance(block[0], dict):
            channels = list(block[0].get("channel") or [])
    data = np.asarray(stream["time_series"], dtype=float)
    stamps = np.asarray(stream["time_stamps"], dtype=float)
    if data.ndim != 2 or len(stamps) < 2:
        raise MocapFileError(f"{path}: MoCap stream {name!r} has fewer than two samples")
    if len(channels) != data.shape[1]:
        raise MocapFileError(f"{path}: MoCap stream {name!r} describes {len(channels)} channels but carries "
                             f"{data.shape[1]}: its channel labels (desc/channels) are needed to know the markers")
    coordinates: dict[str, dict[str, int]] = {}
    units: set[str] = set()
    for i, channel in enumerate(channels):
        label = _xdf_text(channel.get("label"))
        marker = _xdf_text(channel.get("marker"))
        kind = _xdf_text(channel.get("type"))
        axis = kind[-1].upper() if marker and kind.lower().startswith("position") and kind[-1:].upper() in "XYZ" \
            else ""
        if not axis:
            match = _AXIS.match(label)
            if not match or not match.group("name"):
                continue  # not a marker coordinate (a condition, a rigid body's quaternion): not ours
            marker, axis = match.group("name"), match.group("axis").upper()
        coordinates.setdefault(marker, {})[axis] = i
        units.add(_xdf_text(channel.get("unit")).strip() or "?")
    whole = {m: c for m, c in coordinates.items() if set(c) == {"X", "Y", "Z"}}
    if not whole:
        raise MocapFileError(f"{path}: MoCap stream {name!r} has no marker with X, Y and Z channels")
    if len(units) != 1:
        raise MocapFileError(f"{path}: MoCap stream {name!r} mixes units {sorted(units)}: one length unit needed")
    unit = units.pop()
    if unit == "?":
        raise MocapFileError(f"{path}: MoCap stream {name!r} does not give its channels' unit: cannot tell "
                             "millimetres from metres")
    scale = _units_scale(path, unit, "channel unit")
    names = list(whole)
    xyz = np.stack([data[:, [whole[m]["X"], whole[m]["Y"], whole[m]["Z"]]] for m in names], axis=1) * scale
    order = np.argsort(stamps, kind="stable")
    nominal = float(_xdf_text(stream["info"].get("nominal_srate")) or 0.0)
    effective = float(stream["info"].get("effective_srate") or 0.0)
    rate = nominal if nominal > 0 else effective
    markers, flat, missing, ignored = place_markers(path, names, xyz[order], mocap, n_segments)
    return Take(path, "XDF", stamps[order], markers, flat, rate, unit, missing, ignored, note=f"stream {name!r}")


# ----------------------------------------------------------------------------------------------------------------
# Fitting and the clock
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MocapResult:
    """A take fitted and placed on a recording's clock."""

    take: Take
    layout_m: np.ndarray  # (S, K, 3)
    fit: SegmentFit
    joint_rad: np.ndarray  # (M, S)
    clock_offset_s: float  # recording time − source time
    offset: ClockOffset | None  # how it was found (None: given, or stamped at capture)
    max_residual_m: float
    stamped: str = ""  # how the samples were stamped at capture on the recording's clock (live), else ""

    @property
    def time_s(self) -> np.ndarray:
        """The take's frames on the recording's clock."""
        return self.take.time_s + self.clock_offset_s

    @property
    def take_start_s(self) -> float:
        return float(self.time_s[0])

    @property
    def how(self) -> str:
        if self.stamped:
            return self.stamped
        if self.offset is None:
            return f"given: the take's first frame at {self.take_start_s:+.4f} s on the recording's clock"
        return "found from the motion: " + self.offset.describe()


def fit_take(take: Take, mocap: MocapConfig, axes: Sequence[str]) -> tuple[np.ndarray, SegmentFit, np.ndarray]:
    """The layout (S, K, 3), every segment's pose in every frame and the joint angles (M, S) of ``take``."""
    layout = check_layout(mocap.marker_layout_m, len(axes))
    fit = fit_segments(take.markers_m, layout, mocap.max_residual_m)
    angles, _ = joint_angles(fit.rotation, axes)
    return layout, fit, angles


def place_take(take: Take, mocap: MocapConfig, axes: Sequence[str], robot_time_s: np.ndarray | None,
               robot_rad: np.ndarray | None, take_start_s: float | None = None) -> MocapResult:
    """Fit ``take`` and put it on the recording's clock: at ``take_start_s`` (the recording time of its first frame)
    when given, else where its joint angles line up with the recording's (``robot_rad`` at ``robot_time_s``).
    Raises :class:`models.errors.OffsetRefusedError` when the motion cannot fix it, ValueError without robot data."""
    layout, fit, angles = fit_take(take, mocap, axes)
    if take_start_s is not None:
        return MocapResult(take, layout, fit, angles, float(take_start_s) - float(take.time_s[0]), None,
                           mocap.max_residual_m)
    if robot_time_s is None or robot_rad is None or len(robot_time_s) < 2:
        raise MocapFileError("the recording has no /robot joint angles to line the take up with: give --offset S "
                             "(the recording time of the take's first frame)")
    offset = find_clock_offset(take.time_s, angles, robot_time_s, robot_rad)
    return MocapResult(take, layout, fit, angles, offset.offset_s, offset, mocap.max_residual_m)


# ----------------------------------------------------------------------------------------------------------------
# The copy with /mocap
# ----------------------------------------------------------------------------------------------------------------
CHUNK_FRAMES = 2_048  # frames read, fitted and written at a time by import_take: ~30 MB of working arrays (the fit's
# scratch is ~14 kB a frame; 1,024 to 8,192 frames a block cost the same CPU)
_MEDIAN_BITS = 44  # a residual's float64 bits >> this: its exponent and 8 mantissa bits, 2**20 bins


@dataclass(frozen=True)
class ImportedTake:
    """What :func:`import_take` wrote to ``/mocap``, for a person: counts over every (frame, segment) fit."""

    source: str
    frames: int
    rate_hz: float
    units: str
    take_start_s: float
    take_end_s: float
    clock_offset_s: float
    how: str
    offset: ClockOffset | None
    segment_frames: int
    posed: int
    flag_counts: dict[FitFlag, int]
    median_residual_m: float  # of the posed fits; NaN when none
    worst_residual_m: float  # of the posed fits; NaN when none
    max_residual_m: float
    missing_labels: tuple[str, ...]

    @classmethod
    def of(cls, result: MocapResult) -> ImportedTake:
        """The same counts of a take fitted whole (:func:`place_take`)."""
        fit = result.fit
        posed = np.isfinite(fit.center_m[..., 0])
        return cls(result.take.source, len(result.time_s), result.take.rate_hz, result.take.units,
                   result.take_start_s, float(result.time_s[-1]), result.clock_offset_s, result.how, result.offset,
                   int(fit.flag.size), int(posed.sum()), {flag: fit.flagged(flag) for flag in FitFlag},
                   float(np.nanmedian(fit.residual_m[posed])) if posed.any() else float("nan"),
                   float(np.nanmax(fit.residual_m[posed])) if posed.any() else float("nan"),
                   result.max_residual_m, result.take.missing_labels)


def import_take(take: TakeFrames, recording: str | Path, out: str | Path, mocap: MocapConfig, axes: Sequence[str],
                robot_time_s: np.ndarray | None, robot_rad: np.ndarray | None, take_start_s: float | None = None,
                chunk_frames: int = CHUNK_FRAMES, compression: str | None = "gzip",
                progress: Callable[[int, int], None] | None = None) -> ImportedTake:
    """A copy of ``recording`` at ``out`` with ``/mocap`` of ``take``, read, fitted and written ``chunk_frames`` at a
    time; only the joint angles (M × S float64) and the take's times are kept whole, for the clock offset. Placed
    at ``take_start_s`` (the recording time of its first frame) when given, else where its joint angles line up with
    the recording's (``robot_rad`` at ``robot_time_s``). The same datasets, bit for bit, as :func:`place_take` then
    :func:`write_with_mocap` make of the whole take. ``out`` must not exist and is written only complete: a refusal
    (:class:`models.errors.OffsetRefusedError`, :class:`MocapFileError`) leaves nothing there. ``progress(done,
    total)``: called (on this thread) after each block with the frames fitted and written so far."""
    layout = check_layout(mocap.marker_layout_m, len(axes))
    if take_start_s is None and (robot_time_s is None or robot_rad is None or len(robot_time_s) < 2):
        raise MocapFileError("the recording has no /robot joint angles to line the take up with: give --offset S "
                             "(the recording time of the take's first frame)")
    made: list[ImportedTake] = []

    def fill(f: h5py.File) -> None:
        made.append(_fill_in_chunks(f, take, layout, mocap, axes, robot_time_s, robot_rad, take_start_s,
                                    max(int(chunk_frames), 1), compression, progress))

    write_copy_with(recording, out, fill)
    return made[0]


def _fill_in_chunks(f: h5py.File, take: TakeFrames, layout: np.ndarray, mocap: MocapConfig, axes: Sequence[str],
                    robot_time_s: np.ndarray | None, robot_rad: np.ndarray | None, take_start_s: float | None,
                    chunk_frames: int, compression: str | None,
                    progress: Callable[[int, int], None] | None = None) -> ImportedTake:
    m, (s, k) = take.frames, layout.shape[:2]
    if "mocap" in f:
        del f["mocap"]
    group = f.create_group("mocap")
    time_ds = group.create_dataset("time_s", shape=(m,), dtype=np.float64)
    rows = {name: group.create_dataset(name, shape=(m, *shape), dtype=dtype, chunks=row_chunks(m, shape, dtype),
                                       compression=compression)
            for name, shape, dtype in (("markers_m", (s * k, 3), np.float64), ("segment_center_m", (s, 3), np.float64),
                                       ("segment_rotation", (s, 3, 3), np.float64), ("residual_m", (s,), np.float64),
                                       ("joint_angle_rad", (s,), np.float64), ("fit_flag", (s,), np.int8),
                                       ("markers_used", (s,), np.int8))}
    angles = np.empty((m, s))
    posed = 0
    flags = dict.fromkeys(FitFlag, 0)
    worst = -np.inf
    bins = np.zeros(1 << (64 - _MEDIAN_BITS), dtype=np.int64)
    for start in range(0, m, chunk_frames):
        stop = min(m, start + chunk_frames)
        markers = take.read(start, stop)
        fit = fit_segments(markers, layout, mocap.max_residual_m)
        angles[start:stop], _ = joint_angles(fit.rotation, axes)
        rows["markers_m"][start:stop] = markers.reshape(stop - start, s * k, 3)
        rows["segment_center_m"][start:stop] = fit.center_m
        rows["segment_rotation"][start:stop] = fit.rotation
        rows["residual_m"][start:stop] = fit.residual_m
        rows["joint_angle_rad"][start:stop] = angles[start:stop]
        rows["fit_flag"][start:stop] = fit.flag.astype(np.int8)
        rows["markers_used"][start:stop] = fit.n_used.astype(np.int8)
        here = np.isfinite(fit.center_m[..., 0])
        posed += int(here.sum())
        for flag in FitFlag:
            flags[flag] += fit.flagged(flag)
        if here.any():
            worst = max(worst, float(np.nanmax(fit.residual_m[here])))
            bins += np.bincount(_median_keys(fit.residual_m[here]), minlength=len(bins))
        if progress is not None:
            progress(stop, m)
    if take_start_s is not None:
        clock_offset_s, found = float(take_start_s) - float(take.time_s[0]), None
    else:
        assert robot_time_s is not None and robot_rad is not None  # import_take refused it otherwise
        found = find_clock_offset(take.time_s, angles, robot_time_s, robot_rad)
        clock_offset_s = found.offset_s
    del angles
    for start in range(0, m, chunk_frames):
        time_ds[start:start + chunk_frames] = take.time_s[start:start + chunk_frames] + clock_offset_s
    take_start = float(take.time_s[0] + clock_offset_s)
    how = (f"given: the take's first frame at {take_start:+.4f} s on the recording's clock" if found is None else
           "found from the motion: " + found.describe())
    _write_take_attrs(group.attrs, take, clock_offset_s, layout, take_start, how, found, mocap.max_residual_m)
    median = _median_posed(rows["residual_m"], rows["segment_center_m"], bins, posed, chunk_frames)
    return ImportedTake(take.source, m, take.rate_hz, take.units, take_start,
                        float(take.time_s[-1] + clock_offset_s), clock_offset_s, how, found, m * s, posed, flags,
                        median, worst if posed else float("nan"), mocap.max_residual_m, take.missing_labels)


def _median_keys(residual_m: np.ndarray) -> np.ndarray:
    """Residuals (≥ 0, finite) as bins that sort as they do: the top bits of their float64 patterns."""
    return (np.abs(np.ascontiguousarray(residual_m, dtype=np.float64)).view(np.int64) >> _MEDIAN_BITS).ravel()


def _median_posed(residual: h5py.Dataset, center: h5py.Dataset, bins: np.ndarray, posed: int,
                  chunk_frames: int) -> float:
    """The exact median of the posed fits' residuals (as ``np.median`` gives it) without holding them: the bins
    counted while they were written say which one or two bins hold the middle; those bins' values are read back."""
    if not posed:
        return float("nan")
    ranks = ((posed - 1) // 2, posed // 2)
    below = np.cumsum(bins)
    wanted = sorted({int(np.searchsorted(below, rank, side="right")) for rank in ranks})
    values: list[np.ndarray] = []
    for start in range(0, residual.shape[0], chunk_frames):
        r = residual[start:start + chunk_frames]
        r = r[np.isfinite(center[start:start + chunk_frames, :, 0])]
        values.append(r[np.isin(_median_keys(r), wanted)])
    middle = np.sort(np.concatenate(values))
    first = int(below[wanted[0] - 1]) if wanted[0] > 0 else 0
    low, high = middle[ranks[0] - first], middle[ranks[1] - first]
    return float(np.mean([low, high]))


def write_with_mocap(recording: str | Path, out: str | Path, result: MocapResult) -> Path:
    """A copy of ``recording`` at ``out`` with ``/mocap`` (replacing one it had). ``out`` must not exist;
    ``recording`` is only read."""
    return write_copy_with(recording, out, lambda f: fill_mocap(f, result))


def write_in_place(recording: str | Path, result: MocapResult, compression: str | None = "gzip") -> None:
    """``/mocap`` written into ``recording`` itself: a live recording, closed, that the take was stamped into."""
    with h5py.File(recording, "a") as f:
        fill_mocap(f, result, compression)


def fill_mocap(f: h5py.File, result: MocapResult, compression: str | None = "gzip") -> None:
    """The ``/mocap`` group of ``result`` in the open file ``f`` (one it had is replaced); its arrays compressed
    with ``compression`` (an h5py filter name, None for none)."""
    take = result.take
    fit = result.fit
    m, s, k, _ = take.markers_m.shape
    if "mocap" in f:
        del f["mocap"]
    group = f.create_group("mocap")
    group.create_dataset("time_s", data=result.time_s)
    for name, data in (("markers_m", take.markers_m.reshape(m, s * k, 3)), ("segment_center_m", fit.center_m),
                       ("segment_rotation", fit.rotation), ("residual_m", fit.residual_m),
                       ("joint_angle_rad", result.joint_rad), ("fit_flag", fit.flag.astype(np.int8)),
                       ("markers_used", fit.n_used.astype(np.int8))):
        group.create_dataset(name, data=data, chunks=row_chunks(m, data.shape[1:], data.dtype), compression=compression)
    _write_take_attrs(group.attrs, take, result.clock_offset_s, result.layout_m, result.take_start_s, result.how,
                      result.offset, result.max_residual_m)


def _write_take_attrs(attrs: Any, take: Take | TakeFrames, clock_offset_s: float, layout: np.ndarray, take_start_s: float,
                      how: str, found: ClockOffset | None, max_residual_m: float) -> None:
    """``/mocap``'s attributes (SPEC): the take's labels, source, rate and units, where it lies on the recording's
    clock and how that was found, the marker layout and fit limit, the flags' legend, the take file's hash."""
    attrs["labels"] = np.array(take.labels, dtype=h5py.string_dtype())
    attrs["source"] = take.source
    attrs["rate_hz"] = float(take.rate_hz)
    attrs["clock_offset_s"] = float(clock_offset_s)
    attrs["marker_layout_m"] = layout
    attrs["take_start_s"] = take_start_s
    attrs["clock_offset_how"] = how
    attrs["clock_offset_confidence"] = found.confidence if found is not None else np.nan
    attrs["clock_offset_uncertainty_s"] = found.uncertainty_s if found is not None else np.nan
    attrs["max_residual_m"] = float(max_residual_m)
    attrs["units"] = take.units
    attrs["fit_flags"] = FLAG_LEGEND
    if take.path.is_file():
        attrs["source_sha256"] = _sha256(take.path)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_copy_with(recording: str | Path, out: str | Path, fill: Callable[[h5py.File], None]) -> Path:
    """Copy ``recording`` to ``out``, ``fill`` adding to the copy; ``recording`` is only read and an existing
    ``out`` is never replaced (refused, :class:`MocapFileError`). Built in a hidden file beside ``out`` and linked
    into place complete."""
    source, out = Path(recording), Path(out)
    refuse_existing(out, source)
    with _hidden_beside(out) as work:
        with open(source, "rb") as reader, open(work, "wb") as writer:
            shutil.copyfileobj(reader, writer, 8 << 20)
        with h5py.File(work, "r+", locking=False) as f:
            fill(f)
        with open(work, "rb+") as handle:
            os.fsync(handle.fileno())
        try:
            os.link(work, out)  # fails if anything is at out: never replaces it
        except FileExistsError:
            raise MocapFileError(f"{out} appeared while it was being written: left as it is; choose another "
                                 "--out") from None
        except OSError:  # a file system without hard links: claim the name exclusively, then move onto our claim
            os.close(os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o644))
            os.replace(work, out)
    return out


def refuse_existing(out: Path, source: Path | None = None, what: str = "the copy with /mocap") -> None:
    """:class:`MocapFileError` when ``out`` is the input or any file is there already (never replaced)."""
    if source is not None and out.exists() and source.exists() and os.path.samefile(out, source):
        raise MocapFileError(f"--out {out} is the input recording: {what} goes to a new file")
    if os.path.lexists(out):
        raise MocapFileError(f"--out {out} exists: {what} goes to a new file (an existing one is never replaced)")


@contextlib.contextmanager
def _hidden_beside(out: Path, suffix: str = "") -> Iterator[Path]:
    remove_stale_temporaries(out)  # a killed writer's hidden file (app.core.outputs)
    work = out.with_name(f".{temporary_stem(out.name)}.{os.getpid()}.{secrets.token_hex(4)}.partial{suffix}")
    try:
        os.close(os.open(work, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o644))
    except OSError as exc:
        raise MocapFileError(f"cannot write {out}: {exc.strerror or exc}") from exc
    try:
        yield work
    except OSError as exc:
        raise MocapFileError(f"cannot write {out}: {exc.strerror or exc}") from exc
    finally:
        with contextlib.suppress(OSError):
            work.unlink()


# ----------------------------------------------------------------------------------------------------------------
# Reading /mocap and /sim back
# ----------------------------------------------------------------------------------------------------------------
PLOT_FRAMES = 4_000  # a figure of positions against time: more points than it has pixels across, no more
RECORD_FRAMES = 50_000  # read_mocap's bound: /mocap's rows are wide (~2.5 kB a frame), so ~125 MB at most


def frame_step(rows: int, max_frames: int | None) -> int:
    """The stride k that reads at most ``max_frames`` of ``rows`` frames, every k-th from the first (1: all of them;
    ``max_frames`` None: no bound). Read so (``ds[::k]``), a long take is never held whole."""
    if max_frames is None or rows <= max_frames:
        return 1
    return -(-rows // max(int(max_frames), 1))


def thinning_words(rows: int, step: int, rate_hz: float) -> str:
    """What :func:`frame_step`'s stride did to a take, for a caption: "" when every frame was read."""
    if step <= 1:
        return ""
    kept = -(-rows // step)
    rate = f", {rate_hz / step:.3g} Hz" if rate_hz > 0 else ""
    return f"one frame in {step} shown ({kept:,} of {rows:,}{rate})"


@dataclass(frozen=True)
class MocapRecord:
    """A recording's ``/mocap`` group: of a take longer than asked for, every ``frame_step``-th frame."""

    time_s: np.ndarray
    segment_center_m: np.ndarray
    segment_rotation: np.ndarray
    residual_m: np.ndarray
    markers_m: np.ndarray
    attrs: dict[str, Any]
    frame_step: int = 1  # every k-th frame of the file's (1: all)
    frames_in_file: int = 0


def read_mocap(path: str | Path, max_frames: int | None = RECORD_FRAMES) -> MocapRecord | None:
    """The ``/mocap`` group of a recording, or None when it has none: a take of at most ``max_frames`` frames whole,
    a longer one every k-th frame (:func:`frame_step`; ``max_frames`` None: whole, whatever its length)."""
    with h5py.File(path, "r") as f:
        if "mocap" not in f:
            return None
        group = f["mocap"]
        names = ("time_s", "segment_center_m", "segment_rotation", "residual_m", "markers_m")
        rows = min(int(group[name].shape[0]) for name in names)
        step = frame_step(rows, max_frames)
        time_s, center, rotation, residual, markers = (group[name][:rows:step] for name in names)
        return MocapRecord(time_s, center, rotation, residual, markers, dict(group.attrs), step, rows)


def segment_positions(path: str | Path, source: str = "auto", max_frames: int | None = PLOT_FRAMES
                      ) -> tuple[np.ndarray, np.ndarray, str]:
    """Each segment's centre in a recording, for a figure against time: times (T,), centres (T, S, 3) and where
    they came from, in words. ``source``: "mocap" (``/mocap``, refused without one), "sim" (the physics lab's
    simulated body, the truth) or "auto" (``/mocap`` when there, else ``/sim``). Of more than ``max_frames`` frames
    every k-th is read (:func:`frame_step`; None: every frame), and the words say so. ValueError naming what is
    missing."""
    with h5py.File(path, "r") as f:
        if source in ("auto", "mocap") and "mocap" in f:
            group = f["mocap"]
            rate = float(group.attrs.get("rate_hz", 0))
            what = f"motion capture ({group.attrs.get('source', '?')}, {rate:g} Hz)"
            time_ds, data_ds = group["time_s"], group["segment_center_m"]
            rows = min(int(time_ds.shape[0]), int(data_ds.shape[0]))
            step = frame_step(rows, max_frames)
            centers = data_ds[:rows:step]
        elif source == "mocap":
            raise ValueError("no /mocap group: add a take with 'sensnake mocap import', or use --source sim")
        elif "sim" in f:
            what, rate = "the simulated body (/sim, truth)", 0.0
            time_ds, data_ds = f["sim/time_s"], f["sim/points_m"]
            rows = min(int(time_ds.shape[0]), int(data_ds.shape[0]))
            step = frame_step(rows, max_frames)
            points = data_ds[:rows:step]
            centers = 0.5 * (points[:, :-1] + points[:, 1:])
        else:
            raise ValueError("neither /mocap nor /sim: no segment positions to draw")
        thinned = thinning_words(rows, step, rate)
        return time_ds[:rows:step], centers, what + (f"; {thinned}" if thinned else "")


def sim_segment_poses(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The physics lab's true segment poses from a recording's ``/sim``: times (T,), centres (T, S, 3) (midway
    between each segment's ends in ``points_m``) and rotations (T, S, 3, 3) (``segment_rotation``)."""
    if not Path(path).is_file():
        raise MocapFileError(f"recording {path} does not exist")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        why = re.findall(r"\(([^()]*)\)", str(exc))  # h5py: "Unable to synchronously open file (the reason)"
        raise MocapFileError(f"{path} is not a readable HDF5 recording ({why[-1] if why else type(exc).__name__})"
                             ) from exc
    with f:
        if "sim" not in f:
            raise MocapFileError(f"{path} has no /sim group: only a physics-lab recording ('sensnake experiment run') "
                                 "has the simulated body to make a take of")
        sim = f["sim"]
        if "segment_rotation" not in sim:
            raise MocapFileError(f"{path}: /sim has no segment_rotation (recorded by an older version): run the "
                                 "experiment again to get the segments' orientations")
        times, points, rotations = sim["time_s"][:], sim["points_m"][:], sim["segment_rotation"][:]
    return times, 0.5 * (points[:, :-1] + points[:, 1:]), rotations


# ----------------------------------------------------------------------------------------------------------------
# A simulated take
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimulatedTake:
    """What :func:`simulated_take` made: the C3D, where its first frame lies on the recording's clock, and the
    segment hidden (0-based) over ``hidden_s`` (recording clock)."""

    path: Path
    take_start_s: float
    n_frames: int
    hidden_segment: int
    hidden_s: tuple[float, float]
    dropped_fraction: float


def simulated_take(recording: str | Path, out: str | Path, *, lead_s: float = 1.5, rate_hz: float = 960.0,
                   noise_m: float = 0.0003, dropout_fraction: float = 0.02, hidden_segment: int = 6,
                   hidden_for_s: float = 0.5, mocap: MocapConfig | None = None, seed: int = 0) -> SimulatedTake:
    """A C3D take of a physics-lab recording's simulated body, as a PhaseSpace system would give it: the segments'
    true poses (``/sim``) resampled at ``rate_hz``, the layout's markers on them in millimetres with Gaussian noise
    (``noise_m`` s.d. a coordinate), dropouts in bursts (about ``dropout_fraction`` of every marker's frames), one
    segment (``hidden_segment``, 0-based) hidden for ``hidden_for_s`` in the middle of the recording, and the take
    started ``lead_s`` before the recording (the body held its first recorded pose then). Writes ``out`` (must not
    exist)."""
    import ezc3d

    out = Path(out)
    refuse_existing(out, what="the take")
    mocap = mocap or MocapConfig()
    times, centers, rotations = sim_segment_poses(recording)
    n_seg = centers.shape[1]
    layout = check_layout(mocap.marker_layout_m, n_seg)
    rng = np.random.default_rng(seed)
    frames_t = -lead_s + np.arange(int(np.floor((times[-1] + lead_s) * rate_hz)) + 1) / rate_hz
    c, r = resample_poses(times, centers, rotations, frames_t)
    markers = markers_from_poses(c, r, layout) + rng.normal(0.0, noise_m, (len(frames_t), *layout.shape))
    m, _, k, _ = markers.shape
    seen = np.ones((m, n_seg, k), dtype=bool)
    burst = max(int(0.02 * rate_hz), 1)  # 20 ms a dropout: an LED turned away from every camera
    for s in range(n_seg):
        for j in range(k):
            for start in rng.integers(0, m, int(dropout_fraction * m / burst) + 1):
                seen[start:start + rng.integers(1, 2 * burst), s, j] = False
    middle = 0.5 * times[-1]
    hidden = (float(middle), float(middle + hidden_for_s))
    seen[(frames_t >= hidden[0]) & (frames_t < hidden[1]), hidden_segment] = False
    markers[~seen] = np.nan
    points = np.ones((4, n_seg * k, m))
    points[:3] = np.transpose(markers.reshape(m, n_seg * k, 3), (2, 1, 0)) * 1000.0  # mm
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate_hz]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(label for row in layout_labels(mocap, n_seg)
                                                          for label in row)
    c3d.add_parameter("POINT", "UNITS", "mm")
    if m > c3d_frames.HEADER_FRAMES_MAX:  # the header's 16 bits cannot say it: where C3D readers look instead
        c3d.add_parameter("TRIAL", "ACTUAL_START_FIELD", [1, 0])
        c3d.add_parameter("TRIAL", "ACTUAL_END_FIELD", [m & 0xFFFF, m >> 16])
    c3d["data"]["points"] = points
    with _hidden_beside(out, ".c3d") as work:  # ezc3d adds .c3d to a name without it
        c3d.write(str(work))
        try:
            os.link(work, out)
        except FileExistsError:
            raise MocapFileError(f"{out} appeared while it was being written: left as it is") from None
    return SimulatedTake(out, float(frames_t[0]), m, hidden_segment, hidden, float(1.0 - seen.mean()))


def summary_lines(imported: ImportedTake) -> list[str]:
    """What the import found, a few lines for a person."""
    n = imported.segment_frames
    counts = imported.flag_counts
    lines = [f"{imported.frames} frames at {imported.rate_hz:g} Hz ({imported.units}), "
             f"{imported.take_start_s:+.3f} … {imported.take_end_s:+.3f} s on the recording's clock; "
             f"poses in {imported.posed / n if n else float('nan'):.1%} of segment-frames"]
    lines.append("not posed: " + ", ".join(f"{counts[f]} {f.name.lower().replace('_', ' ')}" for f in
                                           (FitFlag.TOO_FEW, FitFlag.BAD_FIT)) +
                 f"; posed with a flag: {counts[FitFlag.OUTLIER_DROPPED]} outlier dropped, "
                 f"{counts[FitFlag.SWAPPED]} swap undone (of {n})")
    lines.append(f"fit residual: median {imported.median_residual_m * 1000:.2f} mm, worst posed "
                 f"{imported.worst_residual_m * 1000:.2f} mm (limit {imported.max_residual_m * 1000:g} mm)")
    if imported.missing_labels:
        lines.append(f"labels not in the take (unseen throughout): {', '.join(imported.missing_labels)}")
    return lines
