"""A C3D file's header and parameters, how many frames it holds, and its points read a block of frames at a time
straight from the data section.

A C3D header keeps the first and last frame in 16-bit words, so a take longer than 65,535 frames (68 s at 960 Hz:
shorter than one of the paper's obstacle runs) states its length elsewhere: ``TRIAL:ACTUAL_START_FIELD`` and
``TRIAL:ACTUAL_END_FIELD`` (two 16-bit words each, low word first: Vicon, Qualisys), or ``POINT:LONG_FRAMES`` (a
float or an integer: Motion Analysis, C3Dserver). Some writers (ezc3d's among them) state neither and write every
frame anyway, leaving ``POINT:FRAMES`` at 65,535: then the data section's size tells. ezc3d 1.7 reads at most
65,535 frames whatever the file says, without a word; :func:`read_frames` reads every frame.

The data section (C3D.org, "The C3D File Format User Guide"): from 512-byte block ``POINT:DATA_START`` on, frame after
frame, each ``POINT:USED`` points of four values (X, Y, Z, and a word whose sign says whether the point was seen),
then the analog samples of that frame; values are 32-bit floats when ``POINT:SCALE`` is negative (the coordinates
then in the file's units), else 16-bit integers times ``|POINT:SCALE|``. The byte order is the processor's named in
the parameter section's fourth byte: 84 Intel (little-endian), 86 MIPS (big-endian); 85 (DEC floats) is not read
here.

:func:`read_head` reads the header and the parameter section alone (ezc3d reads every frame up to 65,535 when it
opens a file: ~0.7 GB of objects for a take that long), so a take is read a block of frames at a time
(:func:`read_frames`) and never held whole. The parameter section (same guide, "Parameter section"): a 4-byte header
(its fourth byte the processor), then groups and parameters one after the other, each its name's length (a signed
byte, negative when locked), its id (negative: a group; positive: a parameter of that group), its name, a 16-bit
offset to the next entry (0: the last), then for a parameter its type (-1 characters, 1 byte, 2 16-bit integer,
4 float), its dimensions and its values (column-major), and a description.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.core.errors import MocapFileError

BLOCK = 512
HEADER_FRAMES_MAX = 65535
PROCESSORS = {84: "<", 86: ">"}  # Intel, MIPS; 85 is DEC (VAX floats)


@dataclass(frozen=True)
class PointLayout:
    """Where the points are in a C3D file's data section."""

    frames: int  # frames the file holds (as stated, or as its size gives when 65,535 was stated)
    points: int
    start_byte: int
    frame_bytes: int
    value: str  # numpy dtype of a stored value ("<f4", ">i2", ...)
    scale: float  # stored integer × scale = coordinate in the file's units (1 for floats)
    how: str  # where the frame count came from
    header_frames: int = 0  # what the header's 16-bit first and last frame say


def _value(parameters: dict, group: str, name: str) -> list[Any]:
    entry = parameters.get(group, {}).get(name, {})
    value = entry.get("value", []) if isinstance(entry, dict) else []
    return list(np.ravel(value))


def _two_words(words: list[Any]) -> int | None:
    if len(words) < 2:
        return None
    return (int(words[0]) & 0xFFFF) + ((int(words[1]) & 0xFFFF) << 16)


def point_layout(path: str | Path, c3d: Any) -> PointLayout:
    """The data section's layout from ``c3d`` (:func:`read_head` of ``path``, or an ezc3d object of it: its
    parameters and header) and the file.
    Raises :class:`MocapFileError` naming the file when the layout cannot be read or the file is cut short."""
    path = Path(path)
    parameters = c3d["parameters"]
    header = c3d["header"]["points"]
    with open(path, "rb") as handle:
        head = handle.read(BLOCK)
        if len(head) < 2:
            raise MocapFileError(f"{path}: not a C3D file (no header)")
        handle.seek((head[0] - 1) * BLOCK + 3)
        processor_byte = handle.read(1)
    processor = processor_byte[0] if processor_byte else 0
    points = int(header["size"])
    scale_words = _value(parameters, "POINT", "SCALE")
    scale = float(scale_words[0]) if scale_words else -1.0
    width = 4 if scale < 0 else 2
    analog_used = int((_value(parameters, "ANALOG", "USED") or [0])[0])
    analog_rate = float((_value(parameters, "ANALOG", "RATE") or [0.0])[0])
    point_rate = float(header["frame_rate"]) or 1.0
    per_frame = round(analog_rate / point_rate) if analog_used and analog_rate > 0 else 0
    frame_bytes = width * (4 * points + analog_used * per_frame)
    start_words = _value(parameters, "POINT", "DATA_START")
    start_block = int(start_words[0]) & 0xFFFF if start_words else 0
    if start_block < 2 or frame_bytes <= 0:
        raise MocapFileError(f"{path}: its POINT:DATA_START ({start_block}) or point count ({points}) does not "
                             "describe a data section")
    start_byte = (start_block - 1) * BLOCK
    held = max(os.path.getsize(path) - start_byte, 0) // frame_bytes
    stated_first, stated_last = int(header["first_frame"]), int(header["last_frame"])
    frames, how = stated_last - stated_first + 1, "the header"
    first, last = _two_words(_value(parameters, "TRIAL", "ACTUAL_START_FIELD")), \
        _two_words(_value(parameters, "TRIAL", "ACTUAL_END_FIELD"))
    long_frames = _value(parameters, "POINT", "LONG_FRAMES")
    if first is not None and last is not None and last >= first:
        frames, how = last - first + 1, "TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD"
    elif long_frames and float(long_frames[0]) > 0:
        frames, how = int(round(float(long_frames[0]))), "POINT:LONG_FRAMES"
    elif frames >= HEADER_FRAMES_MAX and held > frames:
        frames, how = int(held), "the size of its data section (65,535 frames stated, more written)"
    if frames > held:
        raise MocapFileError(f"{path}: {how} says {frames} frames but the file holds {held}: it was cut short "
                             "(copy it again from the capture computer)")
    order = PROCESSORS.get(processor)
    value = "" if order is None else f"{order}{'f4' if width == 4 else 'i2'}"
    return PointLayout(frames, points, start_byte, frame_bytes, value, 1.0 if width == 4 else abs(scale), how,
                       stated_last - stated_first + 1)


def read_frames(path: str | Path, layout: PointLayout, start: int, stop: int) -> np.ndarray:
    """Frames ``start`` … ``stop`` − 1 (0-based) of the data section: (n, P, 3) coordinates in the file's units, NaN
    where a point was not seen (its fourth word negative). Reads those frames' bytes only."""
    path = Path(path)
    if not layout.value:
        raise MocapFileError(f"{path}: a DEC-format C3D: this reader reads Intel and MIPS files only; export the take "
                             "again as an Intel (PC) C3D")
    start, stop = max(int(start), 0), min(int(stop), layout.frames)
    n = max(stop - start, 0)
    stride = layout.frame_bytes // np.dtype(layout.value).itemsize
    with open(path, "rb") as handle:
        handle.seek(layout.start_byte + start * layout.frame_bytes)
        raw = np.fromfile(handle, dtype=layout.value, count=n * stride)
    if raw.size != n * stride:
        raise MocapFileError(f"{path}: frames {start + 1}-{stop} lie past the end of the file: it was cut short while "
                             "being read")
    block = np.asarray(raw.reshape(n, stride)[:, :4 * layout.points], dtype=float).reshape(n, layout.points, 4)
    xyz = block[..., :3] * layout.scale
    xyz[block[..., 3] < 0] = np.nan
    return xyz


def read_head(path: str | Path) -> dict[str, Any] | None:
    """The header and the parameters of a C3D file, shaped as ezc3d gives them (``["header"]["points"]`` with
    ``size``, ``frame_rate``, ``first_frame`` and ``last_frame`` 0-based; ``["parameters"][GROUP][NAME]["value"]``,
    character parameters as lists of strings with trailing spaces dropped), read without its frames. None for a DEC
    file (its floats are not IEEE: ezc3d reads those). :class:`MocapFileError` naming the file when it is not a C3D
    file this can read."""
    path = Path(path)
    with open(path, "rb") as handle:
        head = handle.read(BLOCK)
        if len(head) < 24 or head[1] != 0x50 or head[0] < 2:
            raise MocapFileError(f"{path} is not a readable C3D file (no C3D header: its second byte is not 80)")
        handle.seek((head[0] - 1) * BLOCK)
        section = handle.read(4)
        if len(section) < 4:
            raise MocapFileError(f"{path} is not a readable C3D file (its parameter section is missing)")
        if section[3] == 85:
            return None
        order = PROCESSORS.get(section[3])
        if order is None:
            raise MocapFileError(f"{path} is not a readable C3D file (processor byte {section[3]}: not 84, 85 or 86)")
        data_start, = struct.unpack(f"{order}H", head[16:18])
        # the section's stated block count, or (when a writer left it short) every block up to the data
        body = section + handle.read(max(section[2], data_start - head[0], 1) * BLOCK - 4)
    words = struct.unpack(f"{order}HHHHH", head[2:12])
    scale, = struct.unpack(f"{order}f", head[12:16])
    rate, = struct.unpack(f"{order}f", head[20:24])
    header = {"size": words[0], "first_frame": words[2] - 1, "last_frame": words[3] - 1, "frame_rate": float(rate),
              "scale": float(scale), "data_start": data_start}
    try:
        parameters = _parameters(body, order)
    except (struct.error, ValueError, IndexError, UnicodeDecodeError) as exc:
        raise MocapFileError(f"{path} is not a readable C3D file (its parameter section does not parse: {exc})"
                             ) from exc
    return {"header": {"points": header}, "parameters": parameters, "processor": section[3]}


def _parameters(body: bytes, order: str) -> dict[str, dict[str, dict[str, Any]]]:
    groups: dict[int, str] = {}
    found: list[tuple[int, str, Any]] = []
    position = 4
    while position + 2 <= len(body):
        length, owner = struct.unpack("bb", body[position:position + 2])
        if length == 0:
            break
        name_end = position + 2 + abs(length)
        name = body[position + 2:name_end].decode("latin-1").strip().upper()
        offset, = struct.unpack(f"{order}h", body[name_end:name_end + 2])
        cursor = name_end + 2
        if owner < 0:
            groups[-owner] = name
        elif owner > 0:
            kind, n_dims = struct.unpack("bB", body[cursor:cursor + 2])
            dims = list(body[cursor + 2:cursor + 2 + n_dims])
            cursor += 2 + n_dims
            count = int(np.prod(dims)) if dims else 1
            raw = body[cursor:cursor + count * abs(kind)]
            if len(raw) < count * abs(kind):
                raise ValueError(f"parameter {name} runs past the section")
            value: Any
            if kind == -1:
                width = dims[0] if dims else 1
                value = [raw[i:i + width].decode("latin-1").rstrip(" \x00") for i in range(0, len(raw), width)] \
                    if width else [""] * int(np.prod(dims[1:]))
            elif kind in (1, 2, 4):
                value = np.frombuffer(raw, dtype={1: "i1", 2: f"{order}i2", 4: f"{order}f4"}[kind]).tolist()
            else:
                raise ValueError(f"parameter {name} has type {kind}")
            found.append((owner, name, value))
        if offset <= 0:
            break
        position = name_end + offset
    parameters: dict[str, dict[str, dict[str, Any]]] = {name: {} for name in groups.values()}
    for owner, name, value in found:
        parameters.setdefault(groups.get(owner, f"GROUP{owner}"), {})[name] = {"value": value}
    return parameters
