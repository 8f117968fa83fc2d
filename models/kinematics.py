"""Forward kinematics of the snake: joint angles → segment points in 3-D, and the side/top projections.

Convention (fixed here so every view agrees):

* The head frame is the world: x forward (the robot crawls toward +x), y to the robot's left, z up.
* The body trails backward from the head tip at the origin: segment i (1 = head … 12 = tail) runs from point
  ``p[i-1]`` to ``p[i]`` along its local −x, ``segment_length_m`` long.
* Joint i sits at the front of segment i (``p[i-1]``) and turns segment i and everything behind it relative to
  segment i−1 (the head frame for i = 1): a pitch joint about the local y axis, a yaw joint about the local z axis,
  right-handed. So a positive pitch angle lifts what is behind the joint; a positive yaw swings it to the right.

Pure numpy; any thread may call.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

SEGMENT_LENGTH_M = 0.08
SEGMENT_RADIUS_M = 0.036  # SenSnake v2 (paper, Sec. III)
SENSOR_SIDES = ("L", "R", "B")


@dataclass(frozen=True)
class BodyPose:
    """``points_m`` (n+1, 3): head tip first; ``frames`` (n, 3, 3): each segment's rotation (columns = local axes)."""

    points_m: np.ndarray
    frames: np.ndarray

    @property
    def segment_midpoints_m(self) -> np.ndarray:
        return 0.5 * (self.points_m[:-1] + self.points_m[1:])

    def side_view(self) -> np.ndarray:
        """(n+1, 2) points projected on the x–z plane (looking at the robot's left side)."""
        return self.points_m[:, [0, 2]]

    def top_view(self) -> np.ndarray:
        """(n+1, 2) points projected on the x–y plane (looking down)."""
        return self.points_m[:, [0, 1]]


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    if axis == "pitch":  # about local y
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    if axis == "yaw":  # about local z
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    raise ValueError(f"unknown joint axis {axis!r}; expected 'pitch' or 'yaw'")


def forward_kinematics(angles_rad: Sequence[float] | np.ndarray, axes: Sequence[str],
                       segment_length_m: float = SEGMENT_LENGTH_M) -> BodyPose:
    """Segment points (m) and frames for joint angles (rad, joint order head first)."""
    angles = np.asarray(angles_rad, dtype=float)
    if angles.shape != (len(axes),):
        raise ValueError(f"{angles.size} joint angles for {len(axes)} joint axes")
    n = len(axes)
    points = np.zeros((n + 1, 3))
    frames = np.zeros((n, 3, 3))
    rotation = np.eye(3)
    backward = np.array([-segment_length_m, 0.0, 0.0])
    for i, (axis, angle) in enumerate(zip(axes, angles)):
        rotation = rotation @ _rot(axis, float(angle))
        frames[i] = rotation
        points[i + 1] = points[i] + rotation @ backward
    return BodyPose(points, frames)


def sensor_points(pose: BodyPose, radius_m: float = SEGMENT_RADIUS_M) -> np.ndarray:
    """(3n, 3) sensor centres in channel order S01L, S01R, S01B, S02L, … (SPEC §2): left, right, bottom of each
    segment's midpoint, ``radius_m`` out from the body axis."""
    mids = pose.segment_midpoints_m
    out = np.empty((3 * len(mids), 3))
    for side_index, local in enumerate(([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0])):
        offsets = pose.frames @ (np.asarray(local) * radius_m)
        out[side_index::3] = mids + offsets
    return out


def joint_points(pose: BodyPose) -> np.ndarray:
    """(n, 3) where each joint sits: joint i at the front of segment i."""
    return pose.points_m[:-1]


def bend_for_point(angles_rad: np.ndarray, axes: Sequence[str], joint_index: int, target_xy: Sequence[float],
                   view: str, segment_length_m: float = SEGMENT_LENGTH_M, point_index: int | None = None) -> float:
    """The angle of ``joint_index`` (0-based) that turns body point ``point_index`` toward ``target_xy`` in a view.

    ``point_index`` (into ``BodyPose.points_m``, behind the joint) defaults to the end of the joint's own segment.
    ``view`` is "side" (x–z) or "top" (x–y). Used to pose the drawn body by dragging. The direction joint → point in
    the projection turns with the joint; a short Newton search on the projected angle handles the 3-D case where the
    joint axis is not perpendicular to the view. Returns radians.
    """
    point = joint_index + 1 if point_index is None else int(point_index)
    if point <= joint_index:
        raise ValueError(f"point {point} is not behind joint index {joint_index}")
    cols = [0, 2] if view == "side" else [0, 1]
    target = np.asarray(target_xy, dtype=float)

    def error(theta: float) -> float:
        trial = np.array(angles_rad, dtype=float)
        trial[joint_index] = theta
        pose = forward_kinematics(trial, axes, segment_length_m)
        a, b = pose.points_m[joint_index, cols], pose.points_m[point, cols]
        seg, want = b - a, target - a
        return float(np.arctan2(seg[0] * want[1] - seg[1] * want[0], seg @ want))

    theta = float(angles_rad[joint_index])
    for _ in range(8):
        e = error(theta)
        if abs(e) < 1e-6:
            break
        h = 1e-4
        slope = (error(theta + h) - error(theta - h)) / (2 * h)
        if abs(slope) < 1e-3:  # joint axis lies in the view plane: dragging here cannot turn it
            break
        # dragging only ever asks for the nearest solution; limit the step to keep it stable
        theta -= float(np.clip(e / slope, -0.5, 0.5))
    return float(np.clip(theta, -np.pi, np.pi))
