"""Motion capture numerics: segment poses from labelled markers, joint angles from segment poses, and the take's
clock found from the motion itself. Pure numpy/scipy: no I/O, no clock; any thread may call.

Frames and units (docs/MOCAP.md): positions in metres in the capture's world frame. Each segment's frame has its
origin at the segment's centre on its long axis, x toward the head, z up when the body lies straight and upright,
y = z × x (the robot's left); ``marker_layout_m`` gives each marker's position in its segment's frame. A pose is the
rotation R (columns: the segment's x, y, z in the world) and the centre c with ``marker ≈ R @ layout + c``.

What is never done: a pose from fewer than 3 seen markers (NaN, not invented), a pose carried over or interpolated
across a gap, a fit whose residual is too large to be the segment's rigid markers (NaN, flagged).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from models.errors import MocapLayoutError, OffsetRefusedError

N_SEGMENTS = 12
MIN_MARKERS = 3  # a rigid pose needs three markers not on one line
# A fit this far (RMS) from the layout is not the segment's rigid markers: a marker swapped, a reflection taken for
# a marker, a holder bent. PhaseSpace's LEDs are seen to well under a millimetre; 4 mm leaves room for a layout
# measured by hand to ±2 mm per marker.
MAX_RESIDUAL_M = 0.004
# Three markers closer than this to one line do not fix the roll about it: refused in a layout.
MIN_TRIANGLE_HEIGHT_M = 0.01


class FitFlag(IntEnum):
    """What the fit of one segment in one frame found (``/mocap/fit_flag``)."""

    OK = 0
    OUTLIER_DROPPED = 1  # one marker was far from the others' rigid fit: left out, the pose from the rest
    SWAPPED = 2  # two of the segment's markers carried each other's labels: the pose from them swapped back
    BAD_FIT = 3  # no rigid fit within the residual limit: pose NaN
    TOO_FEW = 4  # fewer than 3 markers seen: pose NaN


# Every relabelling of these four (a swap, a cycle) leaves a rigid fit ≥ 15 mm RMS: see default_marker_layout_m.
DEFAULT_MARKER_LAYOUT_M = (
    (0.032, 0.000, 0.062),  # 1: front post, on the top line, 26 mm above the shell
    (-0.012, 0.012, 0.051),  # 2: left of the top line, a little behind the middle, 15 mm post
    (-0.032, 0.010, 0.062),  # 3: back post, 26 mm
    (-0.015, -0.022, 0.046),  # 4: right, 10 mm post
)


def default_marker_layout_m() -> np.ndarray:
    """(4, 3) marker positions (m) in a segment's frame: LED markers on posts above the rigid top of the shell.

    What it rests on: SenSnake v2's segment, 0.08 m long with a 0.036 m radius shell whose upper part is rigid PLA
    carrying 3-D printed marker holders (paper, Sec. III-B; four LED markers a segment, Sec. III-C). The paper gives
    no positions; these are ours, chosen so that (1) every marker lies within the segment's length (|x| ≤ 32 mm)
    and above the shell (posts 10 to 26 mm), (2) the four are not in one plane and every two are a different
    distance apart (23 to 65 mm, no two within 5 mm of each other), so any relabelling of them — two swapped, three
    or four in a cycle — leaves a residual of at least 15 mm, far above :data:`MAX_RESIDUAL_M`, instead of a wrong
    pose that fits, and (3) no three are within 12 mm of one line. Measure your holders and set ``[mocap]
    marker_layout_m``."""
    return np.array(DEFAULT_MARKER_LAYOUT_M, dtype=float)


def check_layout(layout_m: np.ndarray | Sequence[Sequence[float]], n_segments: int = N_SEGMENTS) -> np.ndarray:
    """The layout as (n_segments, K, 3): one (K, 3) layout is used for every segment. Raises
    :class:`MocapLayoutError` naming the problem: fewer than 3 markers, non-finite values, three markers near one
    line (no roll)."""
    layout = np.asarray(layout_m, dtype=float)
    one_for_all = layout.ndim == 2
    if one_for_all:
        layout = np.broadcast_to(layout, (n_segments, *layout.shape)).copy()
    if layout.ndim != 3 or layout.shape[0] != n_segments or layout.shape[2] != 3:
        raise MocapLayoutError(f"marker_layout_m has shape {layout.shape}: give K rows of [x, y, z] (m) for every "
                               f"segment alike, or {n_segments} such lists")
    if layout.shape[1] < MIN_MARKERS:
        raise MocapLayoutError(f"marker_layout_m has {layout.shape[1]} marker(s) a segment: a segment's pose needs "
                               f"at least {MIN_MARKERS} markers")
    if not np.all(np.isfinite(layout)):
        raise MocapLayoutError("marker_layout_m has a value that is not a finite number")
    for s in range(1 if one_for_all else n_segments):  # (one layout for all: its first copy says it for every one)
        for trio in itertools.combinations(range(layout.shape[1]), 3):
            height = _triangle_height_m(layout[s, list(trio)])
            if height < MIN_TRIANGLE_HEIGHT_M:
                names = ", ".join(str(k + 1) for k in trio)
                raise MocapLayoutError(
                    f"marker_layout_m: markers {names} of segment {s + 1} lie within {height * 1000:.1f} mm of one "
                    f"line (at least {MIN_TRIANGLE_HEIGHT_M * 1000:g} mm needed): seen alone they would not fix the "
                    "segment's roll")
    return layout


def _triangle_height_m(points: np.ndarray) -> float:
    """The smallest height of the triangle ``points`` (3, 3): how far the three are from lying on one line."""
    a, b, c = points
    area2 = float(np.linalg.norm(np.cross(b - a, c - a)))
    longest = max(float(np.linalg.norm(b - a)), float(np.linalg.norm(c - a)), float(np.linalg.norm(c - b)))
    return area2 / longest if longest > 0 else 0.0


def swap_residual_m(layout_m: np.ndarray) -> float:
    """The smallest RMS residual of a rigid fit of one segment's layout (K, 3) to itself with two labels swapped:
    how clearly a swap shows. A symmetric layout gives ~0 (a swap would fit as a wrong pose)."""
    layout = np.asarray(layout_m, dtype=float)
    best = math.inf
    for i, j in itertools.combinations(range(len(layout)), 2):
        swapped = layout.copy()
        swapped[[i, j]] = swapped[[j, i]]
        _, _, rms = rigid_fit(layout, swapped, np.ones(len(layout), dtype=bool))
        best = min(best, float(rms))
    return best


# ----------------------------------------------------------------------------------------------------------------
# Rigid fits
# ----------------------------------------------------------------------------------------------------------------
def rigid_fit(model_m: np.ndarray, seen_m: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                   np.ndarray]:
    """Kabsch's least-squares rotation and translation of ``model_m`` (..., K, 3) onto ``seen_m`` (..., K, 3) over
    the markers where ``weight`` (..., K) is true, batched over the leading axes: ``seen ≈ R @ model + t``.

    Returns R (..., 3, 3) (proper: det +1), t (..., 3) and the RMS residual (..., ) in metres over the used markers.
    Where fewer than 3 markers are used, all three are NaN. Values of unused markers (NaN) are never read."""
    model = np.asarray(model_m, dtype=float)
    w = np.asarray(weight, dtype=bool)
    seen = np.where(w[..., None], np.asarray(seen_m, dtype=float), 0.0)
    model, seen = np.broadcast_arrays(model, seen)
    wf = w.astype(float)
    count = wf.sum(axis=-1)
    enough = count >= MIN_MARKERS
    safe = np.where(enough, count, 1.0)[..., None]
    model_mean = (wf[..., None] * model).sum(axis=-2) / safe
    seen_mean = (wf[..., None] * seen).sum(axis=-2) / safe
    p = (model - model_mean[..., None, :]) * wf[..., None]
    q = (seen - seen_mean[..., None, :]) * wf[..., None]
    h = np.einsum("...ki,...kj->...ij", p, q)
    u, _, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, -1, -2)
    d = np.sign(np.linalg.det(v @ np.swapaxes(u, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    correction = np.ones((*d.shape, 3))
    correction[..., 2] = d
    rotation = (v * correction[..., None, :]) @ np.swapaxes(u, -1, -2)
    translation = seen_mean - np.einsum("...ij,...j->...i", rotation, model_mean)
    fitted = np.einsum("...ij,...kj->...ki", rotation, model) + translation[..., None, :]
    squared = (((fitted - seen) ** 2).sum(axis=-1) * wf).sum(axis=-1)
    rms = np.sqrt(squared / safe[..., 0])
    rotation = np.where(enough[..., None, None], rotation, np.nan)
    translation = np.where(enough[..., None], translation, np.nan)
    rms = np.where(enough, rms, np.nan)
    return rotation, translation, rms


@dataclass(frozen=True)
class SegmentFit:
    """Each segment's pose in each frame (M frames, S segments, K markers a segment)."""

    center_m: np.ndarray  # (M, S, 3) the segment's centre; NaN where no pose
    rotation: np.ndarray  # (M, S, 3, 3) columns: the segment's x (to the head), y (left), z (up); NaN where no pose
    residual_m: np.ndarray  # (M, S) RMS distance of the used markers from the fitted layout; NaN with < 3 seen
    n_used: np.ndarray  # (M, S) markers the pose was fitted to
    flag: np.ndarray  # (M, S) int8 FitFlag
    left_out: np.ndarray  # (M, S, K) bool: a seen marker the pose does not use (outlier, or a bad fit's)

    def flagged(self, flag: FitFlag) -> int:
        """How many (frame, segment) fits carry ``flag``."""
        return int(np.count_nonzero(self.flag == flag))


def fit_segments(markers_m: np.ndarray, layout_m: np.ndarray,
                 max_residual_m: float = MAX_RESIDUAL_M) -> SegmentFit:
    """Every segment's pose in every frame from its labelled markers ``markers_m`` (M, S, K, 3), NaN where a marker
    was not seen, and the layout (S, K, 3) (:func:`check_layout`).

    A fit within ``max_residual_m`` (RMS) is the pose. Beyond it, with 4 or more markers seen, the fit leaving out
    the one marker that makes it worst is tried (an outlier: a reflection, a marker knocked off its post); then the
    fits with two labels swapped back. Whatever fits within the limit is the pose, flagged (:class:`FitFlag`); else
    the pose is NaN, flagged BAD_FIT, its residual kept so the size of the misfit shows."""
    markers = np.asarray(markers_m, dtype=float)
    layout = np.asarray(layout_m, dtype=float)
    if markers.ndim != 4 or markers.shape[1:] != layout.shape:
        raise ValueError(f"markers of shape {markers.shape} for a layout of shape {layout.shape}: expected "
                         f"(frames, {layout.shape[0]}, {layout.shape[1]}, 3)")
    seen = np.all(np.isfinite(markers), axis=-1)
    rotation, center, residual = rigid_fit(layout[None], markers, seen)
    n_seen = seen.sum(axis=-1)
    n_used = n_seen.copy()
    flag = np.where(n_seen < MIN_MARKERS, FitFlag.TOO_FEW, FitFlag.OK).astype(np.int8)
    left_out = np.zeros(seen.shape, dtype=bool)
    bad = (n_seen >= MIN_MARKERS) & ~(residual <= max_residual_m)
    if bad.any():
        frames, segments = np.nonzero(bad)
        fixes = _repair(markers[frames, segments], seen[frames, segments], layout[segments], max_residual_m)
        ok, how, r_fix, c_fix, res_fix, out_fix = fixes
        rotation[frames, segments] = np.where(ok[:, None, None], r_fix, np.nan)
        center[frames, segments] = np.where(ok[:, None], c_fix, np.nan)
        residual[frames, segments] = np.where(ok, res_fix, residual[frames, segments])
        flag[frames, segments] = np.where(ok, how, FitFlag.BAD_FIT)
        left_out[frames, segments] = np.where(ok[:, None], out_fix, seen[frames, segments])
        n_used[frames, segments] = np.where(ok, (seen[frames, segments] & ~out_fix).sum(axis=-1), 0)
    return SegmentFit(center, rotation, residual, n_used, flag, left_out)


def _repair(markers: np.ndarray, seen: np.ndarray, layout: np.ndarray, limit_m: float) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The bad fits (B, K, 3): leave one marker out (when 4+ are seen), else swap two labels back. Returns (ok,
    flag, R, c, residual, left_out) per fit; the best variant within ``limit_m`` wins, leaving-out first."""
    b, k = seen.shape
    ok = np.zeros(b, dtype=bool)
    how = np.full(b, FitFlag.BAD_FIT, dtype=np.int8)
    rotation = np.full((b, 3, 3), np.nan)
    center = np.full((b, 3), np.nan)
    residual = np.full(b, np.nan)
    left_out = np.zeros((b, k), dtype=bool)
    # leave one out: K variants
    drop = ~np.eye(k, dtype=bool)  # (K variants, K markers)
    weights = seen[:, None, :] & drop[None]
    r_v, c_v, res_v = rigid_fit(layout[:, None], markers[:, None], weights)
    res_v = np.where(np.isfinite(res_v), res_v, np.inf)
    best = np.argmin(res_v, axis=1)
    rows = np.arange(b)
    good = (seen.sum(axis=1) > MIN_MARKERS) & (res_v[rows, best] <= limit_m)
    ok |= good
    how[good] = FitFlag.OUTLIER_DROPPED
    rotation[good], center[good], residual[good] = r_v[rows, best][good], c_v[rows, best][good], res_v[rows, best][good]
    left_out[good] = ~drop[best][good] & seen[good]
    # swap two labels back: K(K-1)/2 variants, all seen markers used
    pairs = list(itertools.combinations(range(k), 2))
    if pairs and not ok.all():
        order = np.tile(np.arange(k), (len(pairs), 1))
        for v, (i, j) in enumerate(pairs):
            order[v, [i, j]] = order[v, [j, i]]
        swapped = markers[:, order]  # (B, variants, K, 3)
        weights_s = seen[:, order]
        r_s, c_s, res_s = rigid_fit(layout[:, None], swapped, weights_s)
        res_s = np.where(np.isfinite(res_s), res_s, np.inf)
        best_s = np.argmin(res_s, axis=1)
        good_s = ~ok & (res_s[rows, best_s] <= limit_m)
        ok |= good_s
        how[good_s] = FitFlag.SWAPPED
        rotation[good_s] = r_s[rows, best_s][good_s]
        center[good_s] = c_s[rows, best_s][good_s]
        residual[good_s] = res_s[rows, best_s][good_s]
    return ok, how, rotation, center, residual, left_out


def markers_from_poses(center_m: np.ndarray, rotation: np.ndarray, layout_m: np.ndarray) -> np.ndarray:
    """Where the markers are: (M, S, K, 3) from centres (M, S, 3), rotations (M, S, 3, 3) and the layout (S, K, 3)."""
    return np.einsum("msij,skj->mski", rotation, layout_m) + center_m[:, :, None, :]


def resample_poses(time_s: np.ndarray, center_m: np.ndarray, rotation: np.ndarray,
                   new_time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (M, S, 3) and (M, S, 3, 3) at ``time_s`` (M,) resampled at ``new_time_s``: centres linearly, rotations
    by spherical linear interpolation; before the first and after the last time the first/last pose is held."""
    from scipy.spatial.transform import Rotation, Slerp

    t = np.asarray(time_s, dtype=float)
    new_t = np.clip(np.asarray(new_time_s, dtype=float), t[0], t[-1])
    n_seg = center_m.shape[1]
    centers = np.empty((len(new_t), n_seg, 3))
    rotations = np.empty((len(new_t), n_seg, 3, 3))
    for s in range(n_seg):
        for axis in range(3):
            centers[:, s, axis] = np.interp(new_t, t, center_m[:, s, axis])
        rotations[:, s] = Slerp(t, Rotation.from_matrix(rotation[:, s]))(new_t).as_matrix()
    return centers, rotations


# ----------------------------------------------------------------------------------------------------------------
# Joint angles
# ----------------------------------------------------------------------------------------------------------------
def joint_angles(rotation: np.ndarray, axes: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles (M, J) in radians from segment rotations (M, J, 3, 3), with the convention of
    :mod:`models.kinematics`: joint k turns segment k relative to segment k−1 about the latter's y (pitch: + lifts
    what is behind) or z (yaw). Joint 1 turns segment 1 against the head piece, which carries no markers: NaN.

    Also returns the off-axis part (M, J) in radians: how far the measured relative rotation is from any rotation
    about the joint's axis (a twist the joint cannot make: the shells' compliance, a layout mis-measured)."""
    rot = np.asarray(rotation, dtype=float)
    n = rot.shape[1]
    if len(axes) != n:
        raise ValueError(f"{len(axes)} joint axes for {n} segments")
    angles = np.full(rot.shape[:2], np.nan)
    off_axis = np.full(rot.shape[:2], np.nan)
    relative = np.einsum("mjli,mjlk->mjik", rot[:, :-1], rot[:, 1:]) if n > 1 else np.zeros((rot.shape[0], 0, 3, 3))
    for k in range(1, n):
        r = relative[:, k - 1]
        if axes[k] == "pitch":
            theta = np.arctan2(r[:, 0, 2] - r[:, 2, 0], r[:, 0, 0] + r[:, 2, 2])
            c, s = np.cos(theta), np.sin(theta)
            about = np.zeros((len(theta), 3, 3))
            about[:, 0, 0], about[:, 0, 2], about[:, 1, 1], about[:, 2, 0], about[:, 2, 2] = c, s, 1.0, -s, c
        elif axes[k] == "yaw":
            theta = np.arctan2(r[:, 1, 0] - r[:, 0, 1], r[:, 0, 0] + r[:, 1, 1])
            c, s = np.cos(theta), np.sin(theta)
            about = np.zeros((len(theta), 3, 3))
            about[:, 0, 0], about[:, 0, 1], about[:, 1, 0], about[:, 1, 1], about[:, 2, 2] = c, -s, s, c, 1.0
        else:
            raise ValueError(f"joint {k + 1}: unknown axis {axes[k]!r}; expected 'pitch' or 'yaw'")
        rest = np.einsum("mli,mlk->mik", about, r)  # about^T r: what is left after the joint's own rotation
        cos_rest = np.clip((np.trace(rest, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        angles[:, k] = theta
        off_axis[:, k] = np.arccos(cos_rest)
    return angles, off_axis


# ----------------------------------------------------------------------------------------------------------------
# The take's clock from the motion
# ----------------------------------------------------------------------------------------------------------------
GRID_HZ = 100.0  # the correlation's grid: 10 ms steps, then refined to well under a millisecond
MIN_MOTION_RAD = 0.02  # a joint whose recorded angle varies less than this (s.d.) carries no timing
MIN_CORRELATION = 0.5
MIN_CONFIDENCE = 0.5
PEAK_PROMINENCE = 0.02


@dataclass(frozen=True)
class ClockOffset:
    """Where the take sits on the recording's clock: ``offset_s`` = recording time − source time.

    ``correlation``: the pooled correlation of the take's joint angles with the recording's at that offset;
    ``runner_up_correlation`` / ``runner_up_offset_s``: the next separate peak (NaN: none); ``confidence`` =
    1 − (1 − r²)/(1 − r₂²), the share of the next peak's unexplained motion the best peak explains (1: unique and
    exact; 0: two equal peaks); ``uncertainty_s``: the offset's standard error from the residual and the motion's
    speed (statistical only); ``overlap_s``: how long take and recording overlap; ``joints``: the joints (1-based)
    that moved and were used."""

    offset_s: float
    uncertainty_s: float
    correlation: float
    runner_up_correlation: float
    runner_up_offset_s: float
    confidence: float
    overlap_s: float
    joints: tuple[int, ...]
    residual_rad: float  # RMS difference of the aligned angles after each joint's constant bias is removed

    def describe(self) -> str:
        """One line: the offset, its uncertainty and how sure."""
        runner = ("no other peak" if math.isnan(self.runner_up_correlation) else
                  f"next peak {self.runner_up_correlation:.3f} at {self.runner_up_offset_s:+.3f} s")
        return (f"clock offset {self.offset_s:+.4f} s ± {self.uncertainty_s * 1000:.2f} ms (confidence "
                f"{self.confidence:.2f}: correlation {self.correlation:.3f}, {runner}; {self.overlap_s:.1f} s "
                f"overlap, joints {_joint_list(self.joints)}, residual {self.residual_rad:.4f} rad)")


def _joint_list(joints: Sequence[int]) -> str:
    return ",".join(str(j) for j in joints)


def _resample_nan(time_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray, max_gap_s: float) -> np.ndarray:
    """``values`` (N, J) at ``grid_s`` by linear interpolation between finite samples; NaN outside their span and
    inside a gap longer than ``max_gap_s``."""
    out = np.full((len(grid_s), values.shape[1]), np.nan)
    for j in range(values.shape[1]):
        good = np.isfinite(values[:, j]) & np.isfinite(time_s)
        if good.sum() < 2:
            continue
        t, y = time_s[good], values[good, j]
        column = np.interp(grid_s, t, y, left=np.nan, right=np.nan)
        right = np.clip(np.searchsorted(t, grid_s), 1, len(t) - 1)
        gap = t[right] - t[right - 1]
        column[gap > max_gap_s] = np.nan
        out[:, j] = column
    return out


def _box_smooth(values: np.ndarray, width: int, columns: np.ndarray | None = None) -> np.ndarray:
    """NaN-aware moving average over ``width`` samples (odd) along axis 0 of ``values``' ``columns`` (default: all);
    a window with no finite sample is NaN. Column by column: a long take's angles are smoothed with a few columns'
    worth of scratch, not several copies of the whole."""
    picked = np.arange(values.shape[1]) if columns is None else np.asarray(columns)
    if width <= 1:
        return values[:, picked].copy()
    kernel = np.ones(width)
    out = np.empty((values.shape[0], len(picked)))
    for i, j in enumerate(picked):
        finite = np.isfinite(values[:, j])
        sums = np.convolve(np.where(finite, values[:, j], 0.0), kernel, mode="same")
        counts = np.convolve(finite.astype(float), kernel, mode="same")
        with np.errstate(invalid="ignore", divide="ignore"):
            column = sums / counts
        column[~finite] = np.nan  # never fill a frame that was not seen
        out[:, i] = column
    return out


def find_clock_offset(take_time_s: np.ndarray, take_angle_rad: np.ndarray, rec_time_s: np.ndarray,
                      rec_angle_rad: np.ndarray, *, min_overlap_s: float | None = None,
                      search_s: tuple[float, float] | None = None, min_motion_rad: float = MIN_MOTION_RAD,
                      min_correlation: float = MIN_CORRELATION, min_confidence: float = MIN_CONFIDENCE,
                      grid_hz: float = GRID_HZ) -> ClockOffset:
    """The offset (recording time − source time) that lines the take's joint angles (M, J) at its own times up with
    the recording's (``/robot/present_rad``, N × J, at the recording's times).

    Masked normalised cross-correlation on a ``grid_hz`` grid (every joint's own mean removed, the joints pooled),
    then the offset refined between grid steps by least squares on the recording's samples. Refused
    (:class:`OffsetRefusedError`, the reason in words) when the motion cannot fix it: no joint moved, the take and
    the recording overlap too little (default: half the shorter of the two, at least 1 s), the best peak lies at
    the edge of the offsets searched, it correlates below ``min_correlation``, or another peak comes within
    ``min_confidence`` of it (a periodic gait). ``search_s``: (lowest, highest) offset to consider."""
    take_t = np.asarray(take_time_s, dtype=float)
    rec_t = np.asarray(rec_time_s, dtype=float)
    take_a = np.asarray(take_angle_rad, dtype=float)
    rec_a = np.asarray(rec_angle_rad, dtype=float)
    if take_a.shape[1:] != rec_a.shape[1:] or take_a.ndim != 2:
        raise ValueError(f"take angles {take_a.shape} and recording angles {rec_a.shape} differ in joints")
    if len(take_t) < 2 or len(rec_t) < 2:
        raise OffsetRefusedError("the take or the recording has fewer than two samples: nothing to line up")
    moving = np.nanstd(np.where(np.isfinite(rec_a), rec_a, np.nan), axis=0) if np.isfinite(rec_a).any() else \
        np.zeros(rec_a.shape[1])
    seen = np.isfinite(take_a).sum(axis=0) >= 0.2 * len(take_t)
    joints = np.flatnonzero((np.nan_to_num(moving) >= min_motion_rad) & seen)
    if not joints.size:
        most = float(np.nanmax(moving)) if np.isfinite(moving).any() else 0.0
        raise OffsetRefusedError(
            f"no motion to line up on: no joint seen in the take moved more than {min_motion_rad:g} rad (s.d.) in "
            f"the recording (most: {most:.3g} rad)")
    rec_a = rec_a[:, joints]  # the take's angles are only read at the joints' columns: a long take is not copied
    step = 1.0 / grid_hz
    take_dt = float(np.median(np.diff(take_t)))
    rec_dt = float(np.median(np.diff(rec_t)))
    # the take smoothed over one grid step (anti-aliasing the 960 Hz noise), both series on grids of that step
    smooth = _box_smooth(take_a, max(1, int(round(step / take_dt)) | 1), joints)
    take_grid = take_t[0] + step * np.arange(int(math.floor((take_t[-1] - take_t[0]) / step)) + 1)
    rec_grid = rec_t[0] + step * np.arange(int(math.floor((rec_t[-1] - rec_t[0]) / step)) + 1)
    x = _resample_nan(take_t, smooth, take_grid, max(3 * take_dt, 1.5 * step))
    del smooth
    y = _resample_nan(rec_t, rec_a, rec_grid, 3.0 * rec_dt)
    x -= np.nanmean(x, axis=0)
    y -= np.nanmean(y, axis=0)
    mx, my = np.isfinite(x), np.isfinite(y)
    x0, y0 = np.where(mx, x, 0.0), np.where(my, y, 0.0)
    lags = np.arange(len(rec_grid) + len(take_grid) - 1) - (len(take_grid) - 1)
    size = 1 << int(math.ceil(math.log2(len(lags))))

    def corr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Σ_n a[n + lag] b[n] for every lag (a over the recording's grid, b over the take's), by FFT."""
        return np.fft.irfft(np.fft.rfft(a, size) * np.fft.rfft(b[::-1], size), size)[:len(lags)]

    n_all = np.zeros(len(lags))
    cov = np.zeros(len(lags))
    var_x = np.zeros(len(lags))
    var_y = np.zeros(len(lags))
    for j in range(len(joints)):
        mxf, myf = mx[:, j].astype(float), my[:, j].astype(float)
        n = np.round(corr(myf, mxf))
        sx, sy = corr(myf, x0[:, j]), corr(y0[:, j], mxf)
        sxx, syy = corr(myf, x0[:, j] ** 2), corr(y0[:, j] ** 2, mxf)
        sxy = corr(y0[:, j], x0[:, j])
        safe = np.maximum(n, 1.0)
        cov += np.where(n > 1, sxy - sx * sy / safe, 0.0)
        var_x += np.where(n > 1, np.maximum(sxx - sx * sx / safe, 0.0), 0.0)
        var_y += np.where(n > 1, np.maximum(syy - sy * sy / safe, 0.0), 0.0)
        n_all = np.maximum(n_all, n)
    offsets = rec_grid[0] - take_grid[0] + lags * step
    shorter = min(take_t[-1] - take_t[0], rec_t[-1] - rec_t[0])
    need_s = max(1.0, 0.5 * shorter) if min_overlap_s is None else min_overlap_s
    valid = (n_all * step >= need_s) & (var_x > 0) & (var_y > 0)
    if search_s is not None:
        valid &= (offsets >= search_s[0]) & (offsets <= search_s[1])
    if not valid.any():
        raise OffsetRefusedError(
            f"the take ({take_t[-1] - take_t[0]:.1f} s) and the recording ({rec_t[-1] - rec_t[0]:.1f} s) never "
            f"overlap by {need_s:.1f} s with the joints seen moving in both: nothing to line up on")
    r = np.full(len(lags), -1.0)
    r[valid] = cov[valid] / np.sqrt(var_x[valid] * var_y[valid])
    best = int(np.argmax(r))
    first, last = np.flatnonzero(valid)[[0, -1]]
    if best in (first, last) and first != last:
        raise OffsetRefusedError(
            f"the best match (correlation {r[best]:.3f}) lies at the edge of the offsets searched ({offsets[best]:+.2f}"
            " s), where take and recording hardly overlap: the true offset is probably outside; give --offset")
    runner = _runner_up(r, valid, best)
    r1 = float(r[best])
    r2 = float(r[runner]) if runner is not None else math.nan
    confidence = (1.0 - (1.0 - r1 ** 2) / (1.0 - r2 ** 2)) if runner is not None and r2 < 1.0 and r2 > 0 else r1 ** 2
    confidence = float(np.clip(confidence, 0.0, 1.0))
    if r1 < min_correlation:
        raise OffsetRefusedError(
            f"the take's joint angles do not match the recording's at any offset (best correlation {r1:.2f} at "
            f"{offsets[best]:+.2f} s, below {min_correlation:g}): another take, another recording, or the joint "
            "axes or signs differ")
    if confidence < min_confidence:
        raise OffsetRefusedError(
            f"ambiguous: two offsets match nearly as well (correlation {r1:.3f} at {offsets[best]:+.3f} s, "
            f"{r2:.3f} at {offsets[runner]:+.3f} s; confidence {confidence:.2f} < {min_confidence:g}), as a "
            "repeating gait does; give --offset")
    # refine between grid steps: the take's (lightly smoothed, dense) angles at the recording's samples
    coarse = float(offsets[best])
    lo, hi = coarse - 2 * step, coarse + 2 * step
    dense = _box_smooth(take_a, max(1, int(round(0.004 / take_dt)) | 1), joints)  # ~4 ms: the noise, not the motion
    inside = (rec_t - hi >= take_t[0]) & (rec_t - lo <= take_t[-1]) & np.all(np.isfinite(rec_a), axis=1)
    t_r, a_r = rec_t[inside], rec_a[inside]
    usable = np.all(np.isfinite(_resample_nan(take_t, dense, t_r - lo, 3 * take_dt)), axis=1) & \
        np.all(np.isfinite(_resample_nan(take_t, dense, t_r - hi, 3 * take_dt)), axis=1)
    t_r, a_r = t_r[usable], a_r[usable]
    if len(t_r) < 10:
        raise OffsetRefusedError("too few recording samples fall where the take saw every moving joint: cannot "
                                 "refine the offset")

    def sse(offset: float) -> float:
        shifted = _resample_nan(take_t, dense, t_r - offset, 3 * take_dt)
        diff = shifted - a_r
        diff -= np.nanmean(diff, axis=0)
        return float(np.nansum(diff ** 2))

    offset = _golden_minimum(sse, lo, hi, 1e-6)
    h = 0.001
    curvature = (sse(offset + h) - 2.0 * sse(offset) + sse(offset - h)) / h ** 2
    dof = max(a_r.size - len(joints) - 1, 1)
    noise = sse(offset) / dof
    uncertainty = math.sqrt(noise / (curvature / 2.0)) if curvature > 0 else math.inf
    overlap_s = float(n_all[best] * step)
    return ClockOffset(offset, uncertainty, r1, r2, float(offsets[runner]) if runner is not None else math.nan,
                       confidence, overlap_s, tuple(int(j) + 1 for j in joints), math.sqrt(noise))


def _runner_up(r: np.ndarray, valid: np.ndarray, best: int) -> int | None:
    """The highest correlation outside the best peak's lobe, or None. The lobe runs from ``best`` outward on each
    side to the lowest point before the correlation climbs ``PEAK_PROMINENCE`` above it again (a separate peak)."""
    bounds = []
    for direction in (-1, 1):
        i = best
        lowest = best
        while 0 <= i + direction < len(r) and valid[i + direction]:
            i += direction
            if r[i] < r[lowest]:
                lowest = i
            elif r[i] - r[lowest] > PEAK_PROMINENCE:
                break
        bounds.append(lowest)
    outside = valid.copy()
    outside[bounds[0]:bounds[1] + 1] = False
    if not outside.any():
        return None
    candidate = int(np.argmax(np.where(outside, r, -np.inf)))
    return candidate if r[candidate] - min(r[bounds[0]], r[bounds[1]]) > PEAK_PROMINENCE else None


def _golden_minimum(function: Callable[[float], float], low: float, high: float, tolerance: float) -> float:
    """Where ``function`` is smallest on [low, high] (one minimum there), by golden-section search."""
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = low, high
    c, d = b - ratio * (b - a), a + ratio * (b - a)
    fc, fd = function(c), function(d)
    while b - a > tolerance:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - ratio * (b - a)
            fc = function(c)
        else:
            a, c, fc = c, d, fd
            d = a + ratio * (b - a)
            fd = function(d)
    return (a + b) / 2.0
