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
if no file is there: an existing file is never replaced. Called from one thread (the CLI's).
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


def place_markers(path: Path, labels_in_file: Sequence[str], xyz: np.ndarray, mocap: MocapConfig,
                   n_segments: int) -> tuple[np.ndarray, tuple[str, ...], tuple[str, ...], int]:
    """The file's marker trajectories ``xyz`` (M, P, 3), named ``labels_in_file``, in the layout's order
    (M, S, K, 3). Refused (naming the file) when no layout label is there, or a segment has fewer than 3."""
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
    markers = np.full((xyz.shape[0], n_segments, len(expected[0]), 3), np.nan)
    for s, row in enumerate(expected):
        for m, label in enumerate(row):
            column = index.get(_key(label))
            if column is not None:
                markers[:, s, m] = xyz[:, column]
    lost = np.all(markers == 0.0, axis=-1)
    markers[lost] = np.nan
    missing = tuple(label for label in flat if _key(label) not in index)
    ignored = len({_key(x) for x in labels_in_file} - {_key(x) for x in flat})
    return markers, tuple(flat), missing, ignored


def _units_scale(path: Path, units: str, where: str) -> float:
    scale = UNITS_TO_M.get(units.strip().lower())
    if scale is None:
        raise MocapFileError(f"{path}: {where} = {units!r} is not a length unit this reads (mm, cm or m): cannot "
                             "tell where the markers are")
    return scale


def read_c3d(path: str | Path, mocap: MocapConfig, n_segments: int) -> Take:
    """A C3D take (ezc3d), its points scaled by POINT:UNITS to metres, timed by POINT:RATE from 0 at its first
    stored frame. Raises :class:`MocapFileError` naming the file and the cause."""
    import ezc3d

    path = Path(path)
    if not path.is_file():
        raise MocapFileError(f"{path}: no such take (C3D file)")
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
    units_value = point.get("UNITS", {}).get("value", [])
    if not len(units_value) or not str(units_value[0]).strip():
        raise MocapFileError(f"{path}: no POINT:UNITS: cannot tell millimetres from metres")
    units = str(units_value[0]).strip()
    scale = _units_scale(path, units, "POINT:UNITS")
    rate_value = point.get("RATE", {}).get("value", [])
    rate = float(rate_value[0]) if len(rate_value) else float(c3d["header"]["points"]["frame_rate"])
    if not np.isfinite(rate) or rate <= 0:
        raise MocapFileError(f"{path}: POINT:RATE = {rate!r} is not a frame rate")
    points = np.asarray(c3d["data"]["points"], dtype=float)  # (4, P, M)
    if points.ndim != 3 or points.shape[2] < 2:
        raise MocapFileError(f"{path}: fewer than two frames of points")
    labels = labels[:points.shape[1]]
    try:
        layout = c3d_frames.point_layout(path, c3d)
    except (KeyError, TypeError, ValueError, IndexError, OSError) as exc:
        raise MocapFileError(f"{path}: cannot tell how many frames it holds ({type(exc).__name__}: {exc})") from exc
    note = ""
    if layout.frames > points.shape[2]:  # ezc3d stops at 65,535 frames: the rest is read from the data section
        xyz = c3d_frames.read_points(path, layout, check=points) * scale
        note = f"{layout.frames} frames (from {layout.how})"
    else:
        xyz = np.transpose(points[:3], (2, 1, 0)) * scale  # (M, P, 3)
        residuals = c3d["data"].get("meta_points", {}).get("residuals")
        if residuals is not None and np.shape(residuals)[-2:] == points.shape[1:]:
            xyz[np.transpose(np.asarray(residuals)[0]) < 0] = np.nan
    del points, c3d
    markers, flat, missing, ignored = place_markers(path, labels, xyz, mocap, n_segments)
    time_s = np.arange(xyz.shape[0]) / rate
    return Take(path, "C3D", time_s, markers, flat, rate, units, missing, ignored, note=note)


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
    group.create_dataset("markers_m", data=take.markers_m.reshape(m, s * k, 3), chunks=True, compression=compression)
    group.create_dataset("segment_center_m", data=fit.center_m, chunks=True, compression=compression)
    group.create_dataset("segment_rotation", data=fit.rotation, chunks=True, compression=compression)
    group.create_dataset("residual_m", data=fit.residual_m, chunks=True, compression=compression)
    group.create_dataset("joint_angle_rad", data=result.joint_rad, chunks=True, compression=compression)
    group.create_dataset("fit_flag", data=fit.flag.astype(np.int8), chunks=True, compression=compression)
    group.create_dataset("markers_used", data=fit.n_used.astype(np.int8), chunks=True, compression=compression)
    attrs = group.attrs
    attrs["labels"] = np.array(take.labels, dtype=h5py.string_dtype())
    attrs["source"] = take.source
    attrs["rate_hz"] = float(take.rate_hz)
    attrs["clock_offset_s"] = float(result.clock_offset_s)
    attrs["marker_layout_m"] = result.layout_m
    attrs["take_start_s"] = result.take_start_s
    attrs["clock_offset_how"] = result.how
    found = result.offset
    attrs["clock_offset_confidence"] = found.confidence if found is not None else np.nan
    attrs["clock_offset_uncertainty_s"] = found.uncertainty_s if found is not None else np.nan
    attrs["max_residual_m"] = float(result.max_residual_m)
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
    with h5py.File(path, "r") as f:
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


def summary_lines(result: MocapResult) -> list[str]:
    """What the import found, a few lines for a person."""
    fit = result.fit
    n = fit.flag.size
    posed = np.isfinite(fit.center_m[..., 0])
    lines = [f"{len(result.time_s)} frames at {result.take.rate_hz:g} Hz ({result.take.units}), "
             f"{result.take_start_s:+.3f} … {result.time_s[-1]:+.3f} s on the recording's clock; "
             f"poses in {posed.mean():.1%} of segment-frames"]
    counts = {flag: fit.flagged(flag) for flag in FitFlag if flag != FitFlag.OK}
    lines.append("not posed: " + ", ".join(f"{counts[f]} {f.name.lower().replace('_', ' ')}" for f in
                                           (FitFlag.TOO_FEW, FitFlag.BAD_FIT)) +
                 f"; posed with a flag: {counts[FitFlag.OUTLIER_DROPPED]} outlier dropped, "
                 f"{counts[FitFlag.SWAPPED]} swap undone (of {n})")
    worst = np.nanmax(fit.residual_m[posed]) if posed.any() else float("nan")
    lines.append(f"fit residual: median {np.nanmedian(fit.residual_m[posed]) * 1000:.2f} mm, worst posed "
                 f"{worst * 1000:.2f} mm (limit {result.max_residual_m * 1000:g} mm)")
    if result.take.missing_labels:
        lines.append(f"labels not in the take (unseen throughout): {', '.join(result.take.missing_labels)}")
    return lines

