"""A C3D take of any length written a block of frames at a time, and a recording whose servo angles it matches, for
tests and benchmarks of ``sensnake mocap import`` that must not hold the take whole to make it.

The body's joint angles are a seeded smooth random walk (linear between knots every 0.5 s, ±0.3 rad): never
periodic, so the clock offset from the motion is unique. Segment 1's pose turns slowly about z and slides along x;
each next segment hangs off the one before through its joint (``[robot] axes``), so the take's joint angles are the
recording's ``/robot/present_rad`` at the same instant. Markers are the layout on those poses in mm with 0.2 mm of
noise, and the fit's every path is exercised: segment 7's markers 1 and 2 unseen (NaN) in 60 of every 5,000 frames
(too few), segment 3's marker 3 at exactly (0, 0, 0) in 40 of every 3,000 (lost), segment 4's markers 1 and 2
swapped in 15 of every 7,000 (a swap undone), segment 2's marker 4 moved 30 mm in 15 of every 6,000 (an outlier).

The C3D: ezc3d writes the first block (header and parameters, ``TRIAL:ACTUAL_START_FIELD``/``ACTUAL_END_FIELD``
stating the whole length), then every further frame is appended to its data section as Intel floats.
"""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from devices.config import LabConfig, MocapConfig

RATE_HZ = 960.0
ROBOT_HZ = 50.0
KNOT_S = 0.5
FIRST_BLOCK = 2_000


def _about(axis: str, theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros((len(theta), 3, 3))
    if axis == "pitch":
        r[:, 0, 0], r[:, 0, 2], r[:, 1, 1], r[:, 2, 0], r[:, 2, 2] = c, s, 1.0, -s, c
    else:
        r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, -s, s, c, 1.0
    return r


class Motion:
    """The body's joint angles and poses at any time (s, the take's clock) over ``seconds`` (+ margins)."""

    def __init__(self, seconds: float, seed: int = 0, axes: tuple[str, ...] | None = None) -> None:
        self.axes = axes or LabConfig().robot.axes
        rng = np.random.default_rng(seed)
        self.knots_t = np.arange(-10.0, seconds + 20.0, KNOT_S)
        self.knots = rng.uniform(-0.3, 0.3, (len(self.knots_t), len(self.axes)))

    def angles(self, t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, self.knots_t, self.knots[:, j]) for j in range(len(self.axes))], axis=1)

    def poses(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centres (n, S, 3) and rotations (n, S, 3, 3)."""
        angles = self.angles(t)
        n, s = len(t), len(self.axes)
        rotation = np.empty((n, s, 3, 3))
        center = np.empty((n, s, 3))
        rotation[:, 0] = _about("yaw", 0.05 * np.sin(2 * np.pi * 0.01 * t))
        center[:, 0] = np.stack([0.02 * t, np.zeros(n), np.full(n, 0.036)], axis=1)
        half = np.array([0.04, 0.0, 0.0])
        for k in range(1, s):
            rotation[:, k] = rotation[:, k - 1] @ _about(self.axes[k], angles[:, k])
            center[:, k] = center[:, k - 1] - rotation[:, k - 1] @ half - rotation[:, k] @ half
        return center, rotation


def markers_mm(motion: Motion, frames: np.ndarray, rng: np.random.Generator,
               mocap: MocapConfig | None = None) -> np.ndarray:
    """(n, S·K, 3) marker positions in mm at take frames ``frames`` (NaN unseen), segment-major."""
    layout = np.asarray((mocap or MocapConfig()).marker_layout_m, dtype=float)
    center, rotation = motion.poses(frames / RATE_HZ)
    markers = center[:, :, None, :] + np.einsum("nsij,kj->nski", rotation, layout)
    markers += rng.normal(0.0, 0.0002, markers.shape)
    markers[frames % 5000 < 60, 6, :2] = np.nan
    markers[frames % 3000 < 40, 2, 2] = 0.0
    swap = frames % 7000 < 15
    markers[swap, 3, 0], markers[swap, 3, 1] = markers[swap, 3, 1], markers[swap, 3, 0].copy()
    markers[frames % 6000 < 15, 1, 3, 2] += 0.03
    n, s, k, _ = markers.shape
    return markers.reshape(n, s * k, 3) * 1000.0


def write_c3d(path: str | Path, frames: int, seed: int = 0, block_frames: int = 50_000,
              motion: Motion | None = None) -> Motion:
    """A ``frames``-frame 960 Hz take of :class:`Motion` at ``path`` (mm), written a block at a time."""
    import ezc3d

    from app.core.mocap import layout_labels

    motion = motion or Motion(frames / RATE_HZ, seed)
    rng = np.random.default_rng(seed + 1)
    labels = tuple(label for row in layout_labels(MocapConfig(), len(motion.axes)) for label in row)
    first = min(frames, FIRST_BLOCK)
    points = np.ones((4, len(labels), first))
    points[:3] = np.transpose(markers_mm(motion, np.arange(first), rng), (2, 1, 0))
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [RATE_HZ]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d.add_parameter("POINT", "UNITS", "mm")
    c3d.add_parameter("TRIAL", "ACTUAL_START_FIELD", [1, 0])
    c3d.add_parameter("TRIAL", "ACTUAL_END_FIELD", [frames & 0xFFFF, frames >> 16])
    c3d["data"]["points"] = points
    c3d.write(str(path))
    if frames == first:
        return motion
    from app.core.c3d_frames import BLOCK, read_head

    head = read_head(path)  # the file holds `first` frames, not yet the `frames` it states
    if head is None or head["parameters"]["POINT"]["SCALE"]["value"][0] >= 0:
        raise RuntimeError("ezc3d wrote a data section other than Intel floats")
    start_byte = (int(head["parameters"]["POINT"]["DATA_START"]["value"][0]) - 1) * BLOCK
    frame_bytes = 16 * len(labels)
    with open(path, "r+b") as handle:
        handle.truncate(start_byte + first * frame_bytes)  # ezc3d pads to a block: frames go there
        handle.seek(0, 2)
        for start in range(first, frames, block_frames):
            block = np.arange(start, min(frames, start + block_frames))
            xyz = markers_mm(motion, block, rng)
            values = np.zeros((len(block), len(labels), 4), dtype="<f4")
            values[..., :3] = np.nan_to_num(xyz, nan=0.0)
            values[..., 3] = np.where(np.isnan(xyz[..., 0]), -1.0, 0.0)  # unseen: its fourth word negative
            handle.write(values.tobytes())
    return motion


def write_recording(path: str | Path, motion: Motion, seconds: float, take_start_s: float) -> None:
    """A recording of ``seconds`` whose ``/robot/present_rad`` is ``motion`` with the take's first frame at
    ``take_start_s`` on the recording's clock (a few board frames, no forces)."""
    from app.core.recorder import Recorder
    from devices.board import SampleBlock

    config = LabConfig()
    t0 = time.monotonic()
    recorder = Recorder(path, config.source_text, config.board.channel_names, with_robot=True,
                        n_joints=len(motion.axes), t0_monotonic_s=t0)
    recorder.start()
    n, c = 16, len(config.board.channel_names)
    recorder.add_block(SampleBlock(counts=np.zeros((n, c), np.uint16), conductance_s=np.full((n, c), 1e-6),
                                   board_time_s=np.arange(n) * 0.01, host_time_s=t0 + np.arange(n) * 0.01,
                                   seq=np.arange(n, dtype=np.uint32), saturated=np.zeros((n, c), bool)))
    times = np.arange(int(seconds * ROBOT_HZ)) / ROBOT_HZ
    angles = motion.angles(times - take_start_s)
    for start in range(0, len(times), 5_000):
        block = range(start, min(len(times), start + 5_000))
        recorder.add_robot_states(SimpleNamespace(host_time_s=t0 + times[i], position_rad=angles[i],
                                                  current_ma=np.zeros(len(motion.axes)), goal_rad=angles[i])
                                  for i in block)
    recorder.stop()
