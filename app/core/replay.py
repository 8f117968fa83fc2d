"""A recording's bodies and contact forces on its timeline, for the 3-D tab's replay.

What a recording can show of the robot's body (SPEC §3.5 and its extensions):

- ``/sim`` (a physics-lab run): the simulated body, ``points_m`` (T, n+1, 3) head tip first and, when recorded,
  ``segment_rotation`` (T, n, 3, 3), with the true normal force on every sheet ``sheet_true_N`` (T, C);
- ``/mocap`` (a motion-capture take lined up on the recording's clock): each segment's centre ``segment_center_m``
  (M, n, 3) and orientation ``segment_rotation`` (M, n, 3, 3), the body the cameras saw; of a take longer than
  :data:`MAX_MOCAP_FRAMES` frames (3.5 min at 960 Hz) every k-th, the fewest that keep within it (an hour at 960 Hz:
  every 18th, 53 Hz), so that an hour's take opens without holding it whole;
- ``/robot``: the commanded joint angles ``goal_rad`` (N, J), drawn by forward kinematics from the head frame
  (:mod:`models.kinematics`) when the recording has neither of the two above.

Contact forces: the forces estimated live (``/forces/force_N`` on ``/daq/time_s``), else the simulation's true sheet
forces. :meth:`Replay.frame_at` gives what is shown at a time: of each source the last frame at or before it (a
replay shows recorded frames, never invented in-between ones). Only the groups the replay needs are read (never the
raw counts or conductances): a one-hour recording opens in well under a second on a laptop
(``benchmarks/bench_replay.py``). Qt-free; any thread may read a :class:`Replay` (it is not changed after loading).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from app.core.errors import RecordingFormatError
from app.core.mocap import frame_step
from app.core.recording import check_input
from models.kinematics import SEGMENT_LENGTH_M, SEGMENT_RADIUS_M, BodyPose, forward_kinematics, sensor_points

SIM, MOCAP, COMMANDED = "sim", "mocap", "commanded"
MAX_MOCAP_FRAMES = 200_000  # of a longer take every k-th frame is replayed (~300 MB at most; 3.5 min at 960 Hz whole)
SOURCE_TITLES = {SIM: "simulated body (/sim)", MOCAP: "motion-captured body (/mocap)",
                 COMMANDED: "commanded pose (/robot goal, from the head)"}


@dataclass(frozen=True)
class BodyTrack:
    """One source of body poses: ``time_s`` (K,) ascending; ``points_m`` (K, n+1, 3) or None (then ``angles_rad``
    (K, J) give the pose by forward kinematics); ``rotations`` (K, n, 3, 3) or None."""

    source: str
    time_s: np.ndarray
    points_m: np.ndarray | None = None
    rotations: np.ndarray | None = None
    angles_rad: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.time_s.shape[0])

    def index_at(self, t_s: float) -> int:
        """The frame shown at ``t_s``: the last at or before it (the first before the track starts)."""
        return max(0, min(int(np.searchsorted(self.time_s, t_s, side="right")) - 1, self.n_frames - 1))


@dataclass(frozen=True)
class BodyFrame:
    """A body as drawn: ``points_m`` (n+1, 3) head tip first; ``sensors_m`` (3n, 3) the sensor centres in channel
    order; ``index`` and ``time_s`` of the frame in its track."""

    source: str
    index: int
    time_s: float
    points_m: np.ndarray
    sensors_m: np.ndarray


@dataclass(frozen=True)
class ReplayFrame:
    """What the replay shows at ``t_s``: the bodies (simulated and motion-captured, or the commanded pose) and the
    contact forces (C,) in N at the sensors of the first body (None without forces)."""

    t_s: float
    bodies: tuple[BodyFrame, ...]
    forces_n: np.ndarray | None
    force_time_s: float | None


@dataclass(frozen=True)
class Replay:
    """A recording opened for replay (see the module docstring)."""

    path: Path
    tracks: tuple[BodyTrack, ...]
    force_time_s: np.ndarray | None
    forces_n: np.ndarray | None  # (F, C)
    forces_source: str  # "measured (/forces)", "simulated truth (/sim)" or ""
    channels: tuple[str, ...]
    axes: tuple[str, ...]
    segment_length_m: float
    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    @property
    def primary(self) -> BodyTrack:
        """The track whose frames the timeline steps through (the first: sim, else mocap, else commanded)."""
        return self.tracks[0]

    def step(self, t_s: float, frames: int) -> float:
        """The time of the frame ``frames`` frames after (negative: before) the primary track's frame at ``t_s``."""
        track = self.primary
        index = max(0, min(track.index_at(t_s) + frames, track.n_frames - 1))
        return float(track.time_s[index])

    def frame_at(self, t_s: float) -> ReplayFrame:
        bodies = tuple(self._body(track, track.index_at(t_s)) for track in self.tracks)
        forces = force_time = None
        if self.forces_n is not None and self.force_time_s is not None and self.force_time_s.size:
            k = max(0, min(int(np.searchsorted(self.force_time_s, t_s, side="right")) - 1,
                           self.force_time_s.size - 1))
            forces, force_time = self.forces_n[k], float(self.force_time_s[k])
        return ReplayFrame(float(t_s), bodies, forces, force_time)

    def _body(self, track: BodyTrack, index: int) -> BodyFrame:
        if track.points_m is not None:
            points = np.asarray(track.points_m[index], dtype=float)
            if track.rotations is not None:
                frames = np.asarray(track.rotations[index], dtype=float)
            else:
                frames = _frames_from_points(points)
        else:
            assert track.angles_rad is not None
            pose = forward_kinematics(np.nan_to_num(track.angles_rad[index]), self.axes, self.segment_length_m)
            points, frames = pose.points_m, pose.frames
        sensors = sensor_points(BodyPose(points, frames), SEGMENT_RADIUS_M)
        return BodyFrame(track.source, index, float(track.time_s[index]), points, sensors)


def _frames_from_points(points: np.ndarray) -> np.ndarray:
    """Segment frames from the points alone (x toward the head, z as near up as it can be): for a ``/sim`` written
    before ``segment_rotation`` was recorded."""
    forward = points[:-1] - points[1:]
    forward /= np.maximum(np.linalg.norm(forward, axis=1, keepdims=True), 1e-12)
    up = np.array([0.0, 0.0, 1.0])
    left = np.cross(up, forward)
    left /= np.maximum(np.linalg.norm(left, axis=1, keepdims=True), 1e-12)
    top = np.cross(forward, left)
    return np.stack([forward, left, top], axis=2)


def _mocap_points(centers: np.ndarray, rotations: np.ndarray, segment_length_m: float) -> np.ndarray:
    """(M, n+1, 3) head tip then each segment's back end, from the segments' centres and orientations."""
    half = 0.5 * segment_length_m * rotations[..., :, 0]  # each segment's x axis (toward the head), half a length
    tip = centers[:, :1] + half[:, :1]
    return np.concatenate([tip, centers - half], axis=1)


def _config_robot(config_text: str) -> tuple[tuple[str, ...] | None, float | None]:
    """The joint axes and segment length of the config stored in the recording (None where it says nothing)."""
    if not config_text.strip():
        return None, None
    try:
        from devices.config import parse_config

        robot = parse_config(config_text).robot
    except (ValueError, LookupError, TypeError):
        return None, None
    return tuple(robot.axes), float(robot.segment_length_m)


def _text(value: object) -> str:
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def open_replay(path: str | Path, axes: tuple[str, ...] | None = None,
                segment_length_m: float | None = None) -> Replay:
    """Read what the replay of ``path`` needs. ``axes``/``segment_length_m`` (the lab's) are used when the recording
    stores no config. :class:`RecordingFormatError` when the file cannot be read or has no body to show."""
    path = check_input(path)
    try:
        with h5py.File(path, "r") as f:
            return _read(f, path, axes, segment_length_m)
    except (OSError, KeyError, ValueError, TypeError) as exc:
        if isinstance(exc, RecordingFormatError):
            raise
        raise RecordingFormatError(f"{path}: cannot be replayed ({exc})") from exc


def _read(f: h5py.File, path: Path, axes: tuple[str, ...] | None, segment_length_m: float | None) -> Replay:
    stored_axes, stored_length = _config_robot(_text(f.attrs.get("config", "")))
    axes = stored_axes or axes or tuple("pitch" if k % 2 == 0 else "yaw" for k in range(12))
    length = float(f["sim"].attrs.get("segment_length_m", 0.0)) if "sim" in f else 0.0
    length = length or stored_length or segment_length_m or SEGMENT_LENGTH_M
    tracks: list[BodyTrack] = []
    if "sim" in f and "points_m" in f["sim"] and f["sim/points_m"].shape[0]:
        sim = f["sim"]
        rotations = sim["segment_rotation"][:] if "segment_rotation" in sim else None
        tracks.append(BodyTrack(SIM, np.asarray(sim["time_s"][:], float), np.asarray(sim["points_m"][:], float),
                                rotations))
    if "mocap" in f and "segment_center_m" in f["mocap"] and f["mocap/segment_center_m"].shape[0]:
        mocap = f["mocap"]
        rows = mocap["segment_center_m"].shape[0]
        step = frame_step(rows, MAX_MOCAP_FRAMES)  # a long take: every step-th frame, read so (never whole)
        centers = np.asarray(mocap["segment_center_m"][::step], float)
        rotations = np.asarray(mocap["segment_rotation"][::step], float)
        tracks.append(BodyTrack(MOCAP, np.asarray(mocap["time_s"][::step], float),
                                _mocap_points(centers, rotations, length), rotations))
    if not tracks and "robot" in f and "goal_rad" in f["robot"] and f["robot/goal_rad"].shape[0]:
        robot = f["robot"]
        goal = np.asarray(robot["goal_rad"][:], float)
        if goal.shape[1] != len(axes):
            raise RecordingFormatError(f"{path}: /robot has {goal.shape[1]} joints, its config {len(axes)} axes")
        tracks.append(BodyTrack(COMMANDED, np.asarray(robot["time_s"][:], float), angles_rad=goal))
    if not tracks:
        raise RecordingFormatError(f"{path} has no body to replay: no /sim, no /mocap and no /robot joint goals "
                                   "(a recording made without the robot shows its forces in the Forces tab)")
    channels: tuple[str, ...] = ()
    if "daq" in f:
        channels = tuple(_text(c) for c in f["daq"].attrs.get("channels", ()))
    force_time = forces = None
    source = ""
    if "forces" in f and "force_N" in f["forces"] and "daq" in f and f["forces/force_N"].shape[0]:
        forces = np.asarray(f["forces/force_N"][:], dtype=np.float32)
        force_time = np.asarray(f["daq/time_s"][: forces.shape[0]], float)
        forces = forces[: force_time.shape[0]]
        source = "measured (/forces)"
    elif "sim" in f and "sheet_true_N" in f["sim"] and f["sim/sheet_true_N"].shape[0]:
        forces = np.asarray(f["sim/sheet_true_N"][:], dtype=np.float32)
        force_time = tracks[0].time_s[: forces.shape[0]] if tracks[0].source == SIM else None
        source = "simulated truth (/sim)" if force_time is not None else ""
        forces = forces if force_time is not None else None
    starts = [float(t.time_s[0]) for t in tracks]
    ends = [float(t.time_s[-1]) for t in tracks]
    return Replay(path, tuple(tracks), force_time, forces, source, channels, tuple(axes), length, min(starts),
                  max(ends))
