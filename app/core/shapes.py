"""Shape files (SPEC §3.4), shape transforms and the per-user shape library.

A shape is the robot's taught pose: 12 joint angles (rad, joint 1 = head first, SPEC §2 convention), the axis of
each joint, and optionally a list of keyframes ``{"t_s", "angles_rad"}`` for teach-and-replay. Readers reject a file
whose ``format``/``version`` they do not know and name the file and the key at fault.

Any thread may call these functions (they touch only the files named).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from app.core import user_folders
from app.core.errors import OutputPathError, ShapeFormatError
from app.core.outputs import check_output, move_into_place, temporary_beside
from devices.toml_files import read_json_file

SHAPE_FORMAT = "sensnake-shape"
SHAPE_VERSION = 1


@dataclass(frozen=True)
class Keyframe:
    """One taught pose at ``t_s`` seconds. ``name`` is ours (an extra key readers may ignore)."""

    t_s: float
    angles_rad: tuple[float, ...]
    name: str = ""


@dataclass(frozen=True)
class Shape:
    name: str
    axes: tuple[str, ...]
    angles_rad: tuple[float, ...]
    keyframes: tuple[Keyframe, ...] = ()
    created: str = field(default_factory=lambda: _now_iso())

    @property
    def n_joints(self) -> int:
        return len(self.angles_rad)


def _now_iso() -> str:
    return datetime.now(timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")


# ----------------------------------------------------------------------------------------------------------------
# JSON
# ----------------------------------------------------------------------------------------------------------------
def shape_to_dict(shape: Shape) -> dict[str, Any]:
    data: dict[str, Any] = {
        "format": SHAPE_FORMAT, "version": SHAPE_VERSION, "name": shape.name, "created": shape.created,
        "axes": list(shape.axes), "angles_rad": [float(a) for a in shape.angles_rad],
    }
    if shape.keyframes:
        frames = []
        for kf in shape.keyframes:
            item: dict[str, Any] = {"t_s": float(kf.t_s), "angles_rad": [float(a) for a in kf.angles_rad]}
            if kf.name:
                item["name"] = kf.name
            frames.append(item)
        data["keyframes"] = frames
    return data


def _angles(value: Any, n: int | None, where: str) -> tuple[float, ...]:
    if not isinstance(value, list):
        raise ShapeFormatError(f"{where} must be a list of angles in radians")
    if n is not None and len(value) != n:
        raise ShapeFormatError(f"{where} has {len(value)} angles, expected {n} (one per joint)")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ShapeFormatError(f"{where}[{i}] = {v!r} is not a finite number of radians")
        out.append(float(v))
    return tuple(out)


def shape_from_dict(data: Any, source: str = "<shape>") -> Shape:
    """Validate and build a :class:`Shape`; errors name ``source`` and the key."""
    if not isinstance(data, dict):
        raise ShapeFormatError(f"{source}: a shape file holds a JSON object")
    if data.get("format") != SHAPE_FORMAT:
        raise ShapeFormatError(f"{source}: format is {data.get('format')!r}, expected {SHAPE_FORMAT!r}")
    if data.get("version") != SHAPE_VERSION:
        raise ShapeFormatError(f"{source}: shape version {data.get('version')!r} is not supported "
                               f"(this program reads version {SHAPE_VERSION})")
    for key in ("axes", "angles_rad"):
        if key not in data:
            raise ShapeFormatError(f"{source}: missing key {key!r}")
    axes = data["axes"]
    if not isinstance(axes, list) or not axes:
        raise ShapeFormatError(f"{source}: 'axes' must be a non-empty list of 'pitch'/'yaw'")
    for i, axis in enumerate(axes):
        if axis not in ("pitch", "yaw"):
            raise ShapeFormatError(f"{source}: axes[{i}] = {axis!r} must be 'pitch' or 'yaw'")
    n = len(axes)
    angles = _angles(data["angles_rad"], n, f"{source}: angles_rad")
    name = data.get("name", "")
    if not isinstance(name, str):
        raise ShapeFormatError(f"{source}: 'name' must be a string")
    created = data.get("created", "")
    keyframes = []
    raw_frames = data.get("keyframes", [])
    if not isinstance(raw_frames, list):
        raise ShapeFormatError(f"{source}: 'keyframes' must be a list")
    for j, item in enumerate(raw_frames):
        where = f"{source}: keyframes[{j}]"
        if not isinstance(item, dict) or "t_s" not in item or "angles_rad" not in item:
            raise ShapeFormatError(f"{where} must be an object with 't_s' and 'angles_rad'")
        t = item["t_s"]
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise ShapeFormatError(f"{where}.t_s = {t!r} is not a finite number of seconds")
        kf_name = item.get("name", "")
        keyframes.append(Keyframe(float(t), _angles(item["angles_rad"], n, f"{where}.angles_rad"),
                                  kf_name if isinstance(kf_name, str) else ""))
    return Shape(name, tuple(axes), angles, tuple(keyframes), str(created))


# The largest shape file read: a pose and its keyframes are a few hundred bytes each (16 MB: ~50 000 keyframes).
MAX_SHAPE_BYTES = 16_000_000


def read_shape(path: str | Path) -> Shape:
    """The shape in the JSON file ``path``. Only a regular file of at most :data:`MAX_SHAPE_BYTES` is read (a FIFO
    would block the read for ever, ``/dev/zero`` fill the memory): ShapeFormatError naming the file and the cause."""
    path = Path(path)
    if not os.path.lexists(path):
        raise ShapeFormatError(f"cannot read shape file {path}: no such file")
    return shape_from_dict(read_json_file(path, "shape file", ShapeFormatError, MAX_SHAPE_BYTES), str(path))


def write_shape(shape: Shape, path: str | Path) -> Path:
    """Write atomically (a hidden temporary moved into place, :mod:`app.core.outputs`), so a crash never leaves half
    a shape; only a regular file is ever replaced (a device, FIFO or socket at ``path`` is refused)."""
    path = check_output(path)
    text = json.dumps(shape_to_dict(shape), indent=2) + "\n"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with temporary_beside(path, ".tmp") as (fd, work):
            with os.fdopen(fd, "w", encoding="utf-8") as handle:
                handle.write(text)
            move_into_place(work, path)
    except OutputPathError:
        raise
    except OSError as exc:
        raise OSError(f"cannot write shape file {path}: {exc.strerror or exc}") from exc
    return path


# ----------------------------------------------------------------------------------------------------------------
# Transforms (each returns a new Shape; keyframes are transformed alike)
# ----------------------------------------------------------------------------------------------------------------
def _map_poses(shape: Shape, fn: Callable[[Sequence[float]], Sequence[float]]) -> Shape:
    return replace(shape, angles_rad=tuple(fn(shape.angles_rad)),
                   keyframes=tuple(replace(k, angles_rad=tuple(fn(k.angles_rad))) for k in shape.keyframes))


def mirror(shape: Shape) -> Shape:
    """Left ↔ right: yaw angles change sign, pitch angles stay."""
    return _map_poses(shape, lambda a: [-v if ax == "yaw" else v for v, ax in zip(a, shape.axes)])


def scale(shape: Shape, factor: float, axis: str | None = None) -> Shape:
    """Multiply the bending amplitude by ``factor`` (only ``axis``'s joints if given)."""
    if not math.isfinite(factor):
        raise ValueError(f"scale factor must be finite, got {factor}")
    return _map_poses(shape, lambda a: [v * factor if axis in (None, ax) else v for v, ax in zip(a, shape.axes)])


def shift(shape: Shape, joints: int) -> Shape:
    """Slide the shape along the body by ``joints`` joints of each axis (positive = toward the tail).

    Like a follow-the-leader shift: the axis's i-th joint takes g_{i−joints}; joints uncovered become straight.
    """

    def fn(a: Sequence[float]) -> list[float]:
        out = [0.0] * len(a)
        for axis in ("pitch", "yaw"):
            idx = [i for i, ax in enumerate(shape.axes) if ax == axis]
            for pos, i in enumerate(idx):
                src = pos - joints
                if 0 <= src < len(idx):
                    out[i] = a[idx[src]]
        return out

    return _map_poses(shape, fn)


# ----------------------------------------------------------------------------------------------------------------
# Library on disk
# ----------------------------------------------------------------------------------------------------------------
def default_library_dir() -> Path:
    """The per-user shape folder (``shapes/`` in the one user data folder, see :mod:`app.core.user_folders`)."""
    return user_folders.shapes_dir()


_SAFE = re.compile(r"[^A-Za-z0-9._-]+")


def file_stem(name: str) -> str:
    """A file-system-safe stem for a shape name (spaces and symbols become '-')."""
    stem = _SAFE.sub("-", name.strip()).strip("-.")
    if not stem:
        raise ValueError(f"shape name {name!r} has no usable characters; use letters, digits, '-' or '_'")
    return stem


class ShapeLibrary:
    """Shapes saved as ``<root>/<name>.json``."""

    def __init__(self, root: str | Path | None = None) -> None:
        self.root = Path(root) if root is not None else default_library_dir()

    def path(self, name: str) -> Path:
        return self.root / f"{file_stem(name)}.json"

    def names(self) -> list[str]:
        if not self.root.is_dir():
            return []
        return sorted(p.stem for p in self.root.glob("*.json"))

    def save(self, shape: Shape, overwrite: bool = True) -> Path:
        path = self.path(shape.name)
        if path.exists() and not overwrite:
            raise FileExistsError(f"a shape named {shape.name!r} already exists in {self.root}")
        return write_shape(shape, path)

    def load(self, name: str) -> Shape:
        path = self.path(name)
        if not path.exists():
            raise FileNotFoundError(f"no shape named {name!r} in {self.root}")
        return read_shape(path)

    def delete(self, name: str) -> None:
        try:
            self.path(name).unlink()
        except FileNotFoundError as exc:
            raise FileNotFoundError(f"no shape named {name!r} in {self.root}") from exc
