"""How many frames a C3D file holds, and its points read straight from the data section when a reader stopped short.

A C3D header keeps the first and last frame in 16-bit words, so a take longer than 65,535 frames (68 s at 960 Hz:
shorter than one of the paper's obstacle runs) states its length elsewhere: ``TRIAL:ACTUAL_START_FIELD`` and
``TRIAL:ACTUAL_END_FIELD`` (two 16-bit words each, low word first: Vicon, Qualisys), or ``POINT:LONG_FRAMES`` (a
float or an integer: Motion Analysis, C3Dserver). Some writers (ezc3d's among them) state neither and write every
frame anyway, leaving ``POINT:FRAMES`` at 65,535: then the data section's size tells. ezc3d 1.7 reads at most
65,535 frames whatever the file says, without a word; :func:`read_points` reads the rest.

The data section (C3D.org, "The C3D File Format User Guide"): from 512-byte block ``POINT:DATA_START`` on, frame after
frame, each ``POINT:USED`` points of four values (X, Y, Z, and a word whose sign says whether the point was seen),
then the analog samples of that frame; values are 32-bit floats when ``POINT:SCALE`` is negative (the coordinates
then in the file's units), else 16-bit integers times ``|POINT:SCALE|``. The byte order is the processor's named in
the parameter section's fourth byte: 84 Intel (little-endian), 86 MIPS (big-endian); 85 (DEC floats) is not read
here.
"""

from __future__ import annotations

import os
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


def _value(parameters: dict, group: str, name: str) -> list[Any]:
    entry = parameters.get(group, {}).get(name, {})
    value = entry.get("value", []) if isinstance(entry, dict) else []
    return list(np.ravel(value))


def _two_words(words: list[Any]) -> int | None:
    if len(words) < 2:
        return None
    return (int(words[0]) & 0xFFFF) + ((int(words[1]) & 0xFFFF) << 16)


def point_layout(path: str | Path, c3d: Any) -> PointLayout:
    """The data section's layout from ``c3d`` (an ezc3d object of ``path``: its parameters and header) and the file.
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
    return PointLayout(frames, points, start_byte, frame_bytes, value, 1.0 if width == 4 else abs(scale), how)


def read_points(path: str | Path, layout: PointLayout, check: np.ndarray | None = None,
                chunk_frames: int = 16_384) -> np.ndarray:
    """(M, P, 3) coordinates in the file's units, NaN where a point was not seen (its fourth word negative), read
    in chunks of ``chunk_frames``. ``check``: the (3, P, F) first frames another reader gave — the two must agree,
    or :class:`MocapFileError` (this reading of the format is then not trusted)."""
    path = Path(path)
    if not layout.value:
        raise MocapFileError(f"{path}: {layout.frames} frames, more than 65,535, in a DEC-format C3D: this reader "
                             "reads Intel and MIPS files only; export the take again as an Intel (PC) C3D")
    stride = layout.frame_bytes // np.dtype(layout.value).itemsize
    data = np.memmap(path, dtype=layout.value, mode="r", offset=layout.start_byte, shape=(layout.frames, stride))
    out = np.empty((layout.frames, layout.points, 3))
    try:
        for start in range(0, layout.frames, chunk_frames):
            block = np.asarray(data[start:start + chunk_frames, :4 * layout.points], dtype=float)
            block = block.reshape(len(block), layout.points, 4)
            xyz = block[..., :3] * layout.scale
            xyz[block[..., 3] < 0] = np.nan
            out[start:start + len(block)] = xyz
    finally:
        del data
    if check is not None:
        n = min(check.shape[-1], layout.frames, 1000)
        theirs = np.transpose(np.asarray(check, dtype=float)[:3, :, :n], (2, 1, 0))
        seen = np.isfinite(out[:n]) & np.isfinite(theirs)
        if n and not np.allclose(out[:n][seen], theirs[seen], rtol=1e-6, atol=1e-6 * max(layout.scale, 1.0)):
            raise MocapFileError(f"{path}: {layout.frames} frames, more than 65,535; its data section could not be "
                                 "read beyond them in agreement with the C3D reader's first frames: not imported")
    return out
