"""A long ``/mocap`` added to a recording in blocks, laid out as the recorder writes a live take (chunked,
uncompressed, ~256 kB chunks), so that a test or a benchmark can make a take of any length without holding it.

Every segment's centre is a known function of the frame index (:func:`centers_at`), so a reader's values can be
checked at whichever frames it returns: the body slides forward at :data:`SPEED_M_S` with a 7 Hz, 0.5 mm tremor (a
value read between frames differs from the one at a frame) and sways sideways, segment 7
has no pose in 20 of every 1,000 frames (NaN), and frame i is at ``i / RATE_HZ`` s on the recording's clock.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

RATE_HZ = 960.0
N_SEGMENTS = 12
N_MARKERS = 48
SPEED_M_S = 0.05
CHUNK_BYTES = 1 << 18  # as app.core.recording.MOCAP_CHUNK_BYTES


def centers_at(frames: np.ndarray) -> np.ndarray:
    """(F, 12, 3) segment centres (m) at frame indices ``frames``."""
    t = np.asarray(frames, dtype=float) / RATE_HZ
    s = np.arange(N_SEGMENTS, dtype=float)
    out = np.empty((len(t), N_SEGMENTS, 3))
    out[..., 0] = SPEED_M_S * t[:, None] - 0.08 * s[None, :] + 5e-4 * np.sin(2 * np.pi * 7.0 * t[:, None])
    out[..., 1] = 0.02 * np.sin(2 * np.pi * 0.5 * t[:, None] - 0.5 * s[None, :])
    out[..., 2] = 0.036 + 1e-4 * s[None, :]
    out[np.asarray(frames) % 1000 < 20, 6] = np.nan
    return out


def _dataset(group: h5py.Group, name: str, frames: int, row_shape: tuple[int, ...], dtype: type) -> h5py.Dataset:
    row_bytes = int(np.prod(row_shape, dtype=int)) * np.dtype(dtype).itemsize
    chunk_rows = max(1, min(frames, CHUNK_BYTES // row_bytes))
    fill = np.nan if np.dtype(dtype).kind == "f" else 0
    return group.create_dataset(name, shape=(frames, *row_shape), chunks=(chunk_rows, *row_shape), dtype=dtype,
                                fillvalue=fill)


def add_long_take(path: str | Path, frames: int, *, whole: bool = False, block_frames: int = 50_000) -> None:
    """Add ``/mocap`` of ``frames`` frames to the file at ``path`` (made if missing). ``time_s``,
    ``segment_center_m`` and ``residual_m`` are written; ``markers_m``, ``segment_rotation`` and the rest are
    written too when ``whole`` (else declared at full size and left unwritten: they read as NaN and take no disk)."""
    with h5py.File(path, "a") as f:
        group = f.create_group("mocap")
        group.attrs["source"] = "generated long take"
        group.attrs["rate_hz"] = RATE_HZ
        group.attrs["clock_offset_s"] = 0.0
        time_s = _dataset(group, "time_s", frames, (), np.float64)
        center = _dataset(group, "segment_center_m", frames, (N_SEGMENTS, 3), np.float64)
        residual = _dataset(group, "residual_m", frames, (N_SEGMENTS,), np.float64)
        markers = _dataset(group, "markers_m", frames, (N_MARKERS, 3), np.float64)
        rotation = _dataset(group, "segment_rotation", frames, (N_SEGMENTS, 3, 3), np.float64)
        joints = _dataset(group, "joint_angle_rad", frames, (N_SEGMENTS,), np.float64)
        for start in range(0, frames, block_frames):
            rows = np.arange(start, min(start + block_frames, frames))
            block = slice(rows[0], rows[-1] + 1)
            c = centers_at(rows)
            time_s[block] = rows / RATE_HZ
            center[block] = c
            residual[block] = np.where(np.isnan(c[..., 0]), np.nan, 2e-4)
            if whole:
                markers[block] = np.repeat(c, N_MARKERS // N_SEGMENTS, axis=1)
                rotation[block] = np.broadcast_to(np.eye(3), (len(rows), N_SEGMENTS, 3, 3))
                joints[block] = 0.0
