"""models.mocap: segment poses from labelled markers (Kabsch), joint angles, and the take's clock from the motion."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from models.errors import MocapLayoutError, OffsetRefusedError
from models.kinematics import forward_kinematics
from models.mocap import (
    MAX_RESIDUAL_M,
    FitFlag,
    check_layout,
    default_marker_layout_m,
    find_clock_offset,
    fit_segments,
    joint_angles,
    markers_from_poses,
    rigid_fit,
)

AXES = ("pitch", "yaw") * 6


def body_poses(angles: np.ndarray, heading_rad: float = 0.4, origin=(0.3, -0.2, 0.05)):
    """Segment centres (M, 12, 3) and rotations (M, 12, 3, 3) of the kinematic chain, turned and moved in the world."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    world = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    centers, rotations = [], []
    for row in angles:
        pose = forward_kinematics(row, AXES)
        centers.append(pose.segment_midpoints_m @ world.T + np.asarray(origin))
        rotations.append(world @ pose.frames)
    return np.array(centers), np.array(rotations)


def smooth_motion(time_s: np.ndarray, seed: int = 3) -> np.ndarray:
    """(M, 12) joint angles: a few random slow sinusoids a joint, not periodic over the span."""
    rng = np.random.default_rng(seed)
    out = np.zeros((len(time_s), 12))
    for j in range(12):
        for _ in range(3):
            f, phase, amp = rng.uniform(0.05, 0.6), rng.uniform(0, 2 * np.pi), rng.uniform(0.05, 0.2)
            out[:, j] += amp * np.sin(2 * np.pi * f * time_s + phase)
    return out


def test_every_relabelling_of_the_default_layout_shows_as_a_residual_far_above_the_limit():
    layout = default_marker_layout_m()
    check_layout(layout)
    for perm in itertools.permutations(range(4)):
        if perm != (0, 1, 2, 3):
            _, _, rms = rigid_fit(layout, layout[list(perm)], np.ones(4, dtype=bool))
            assert rms > 3 * MAX_RESIDUAL_M


@pytest.mark.parametrize(("layout", "words"), [
    ([[0.03, 0, 0.05], [-0.03, 0, 0.05]], "2 marker(s) a segment"),
    ([[0.03, 0, 0.05], [0.0, 0, 0.05], [-0.03, 0.001, 0.05]], "of one line"),
    ([[0.03, 0, 0.05], [0.0, 0.02, np.nan], [-0.03, 0, 0.05]], "finite"),
])
def test_a_layout_that_cannot_give_a_pose_is_refused_naming_why(layout, words):
    with pytest.raises(MocapLayoutError, match=words.replace("(", r"\(").replace(")", r"\)")):
        check_layout(layout)


def test_poses_are_fitted_to_noise_level_and_never_from_fewer_than_three_markers():
    rng = np.random.default_rng(0)
    centers, rotations = body_poses(smooth_motion(np.linspace(0, 2, 40)))
    layout = check_layout(default_marker_layout_m())
    markers = markers_from_poses(centers, rotations, layout)
    noisy = markers + rng.normal(0, 0.0003, markers.shape)
    noisy[5, 3, :2] = np.nan  # segment 4 sees only 2 markers in frame 5
    noisy[6, 7, 0] = np.nan  # segment 8 sees 3 in frame 6
    fit = fit_segments(noisy, layout)
    assert fit.flag[5, 3] == FitFlag.TOO_FEW and np.isnan(fit.center_m[5, 3]).all()
    assert np.isnan(fit.rotation[5, 3]).all() and np.isnan(fit.residual_m[5, 3])
    ok = fit.flag == FitFlag.OK
    assert ok.sum() == 40 * 12 - 1 and fit.n_used[6, 7] == 3
    error = np.linalg.norm(fit.center_m[ok] - centers[ok], axis=-1)
    assert np.sqrt(np.mean(error ** 2)) < 0.001  # the centre lies ~5 cm below the markers: their noise × ~2.4
    assert np.nanmax(fit.residual_m) < 0.001
    angle_error = np.arccos(np.clip((np.trace(np.einsum("nji,njk->nik", fit.rotation[ok], rotations[ok]),
                                              axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert angle_error.max() < 0.05  # a 3-marker frame's worst


def test_an_outlier_is_left_out_a_swap_is_undone_and_a_bad_three_marker_fit_is_nan():
    centers, rotations = body_poses(smooth_motion(np.linspace(0, 1, 4)))
    layout = check_layout(default_marker_layout_m())
    markers = markers_from_poses(centers, rotations, layout)
    markers[0, 2, 1] += [0.02, 0.0, 0.0]  # a reflection 2 cm off: segment 3, marker 2
    markers[1, 5, [0, 2]] = markers[1, 5, [2, 0]]  # segment 6's markers 1 and 3 swap labels
    markers[2, 9, 3] = np.nan
    toward = markers[2, 9, 2] - markers[2, 9, 0]
    markers[2, 9, 0] += 0.015 * toward / np.linalg.norm(toward)  # segment 10: three seen, one of them 15 mm off
    fit = fit_segments(markers, layout)
    assert fit.flag[0, 2] == FitFlag.OUTLIER_DROPPED and fit.left_out[0, 2].tolist() == [False, True, False, False]
    assert np.allclose(fit.center_m[0, 2], centers[0, 2], atol=1e-9) and fit.n_used[0, 2] == 3
    assert fit.flag[1, 5] == FitFlag.SWAPPED and np.allclose(fit.center_m[1, 5], centers[1, 5], atol=1e-9)
    assert fit.flag[2, 9] == FitFlag.BAD_FIT and np.isnan(fit.center_m[2, 9]).all()
    assert fit.residual_m[2, 9] > MAX_RESIDUAL_M  # the misfit's size is kept
    assert fit.flagged(FitFlag.OK) == 4 * 12 - 3


def test_joint_angles_from_segment_rotations_are_the_chains_angles_and_joint_one_is_not_measured():
    angles = smooth_motion(np.linspace(0, 5, 30)) * 3  # up to ~1.5 rad
    _, rotations = body_poses(angles)
    measured, off_axis = joint_angles(rotations, AXES)
    assert np.isnan(measured[:, 0]).all()
    assert np.allclose(measured[:, 1:], angles[:, 1:], atol=1e-9)
    assert np.nanmax(off_axis) < 1e-6
    wrong_axes, twist = joint_angles(rotations, ("yaw", "pitch") * 6)  # the other axes: the twist shows
    assert np.nanmax(twist) > 0.3


def _series(offset_s: float, motion, rec_seconds: float = 20.0, lead_s: float = 1.4, seed: int = 1):
    """A 960 Hz take (source clock from 0) that starts ``lead_s`` before a 50 Hz recording, of the same motion."""
    rng = np.random.default_rng(seed)
    take_t = np.arange(0, rec_seconds + lead_s - 0.5, 1 / 960)
    rec_t = np.arange(0, rec_seconds, 1 / 50)
    take = motion(take_t + offset_s) + rng.normal(0, 0.004, (len(take_t), 12))
    take[:, 0] = np.nan
    take[3000:3480, 4] = np.nan  # a segment hidden for 0.5 s
    rec = np.round(motion(rec_t) / (2 * np.pi / 4096)) * (2 * np.pi / 4096)  # servo ticks
    return take_t, take, rec_t, rec


def test_the_offset_is_found_from_the_motion_within_a_millisecond():
    take_t, take, rec_t, rec = _series(-1.4, smooth_motion)
    found = find_clock_offset(take_t, take, rec_t, rec)
    assert found.offset_s == pytest.approx(-1.4, abs=0.001)
    assert found.uncertainty_s < 0.002 and found.confidence > 0.9 and found.correlation > 0.95
    assert 1 not in found.joints and len(found.joints) == 11
    assert found.describe().startswith(f"clock offset {found.offset_s:+.4f} s ± 0.0") and "confidence 1.00" in \
        found.describe()


def test_finding_the_offset_holds_about_two_copies_of_the_takes_angles() -> None:
    """A long take's angles are smoothed column by column, read at the moving joints in place: the heap's peak is
    about twice the angles handed in (the smoothed joints, the grids), not seven times (copies of the whole)."""
    import tracemalloc

    take_t, take, rec_t, rec = _series(-1.4, smooth_motion, rec_seconds=40.0)
    tracemalloc.start()
    try:
        found = find_clock_offset(take_t, take, rec_t, rec)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert found.offset_s == pytest.approx(-1.4, abs=0.001)
    assert peak < 3.0 * take.nbytes, f"peak {peak / take.nbytes:.1f} times the take's angles"


@pytest.mark.parametrize(("motion", "words"), [
    (lambda t: np.zeros((len(t), 12)) + 0.3, "no motion"),
    (lambda t: 0.3 * np.sin(2 * np.pi * t[:, None] / 2.0 + np.arange(12)), "ambiguous"),
])
def test_an_offset_the_motion_cannot_fix_is_refused_with_the_reason(motion, words):
    take_t, take, rec_t, rec = _series(-1.4, motion)
    with pytest.raises(OffsetRefusedError, match=words):
        find_clock_offset(take_t, take, rec_t, rec)


def test_a_take_of_another_motion_is_refused():
    take_t, take, rec_t, _ = _series(-1.4, smooth_motion)
    _, _, _, other = _series(0.0, lambda t: smooth_motion(t, seed=11))
    with pytest.raises(OffsetRefusedError, match="do not match"):
        find_clock_offset(take_t, take, rec_t, other)
