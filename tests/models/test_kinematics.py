"""Forward kinematics: lengths, straight body, bending direction conventions, sensors, drag inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.kinematics import bend_for_point, forward_kinematics, sensor_points

AXES = tuple("pitch" if i % 2 == 1 else "yaw" for i in range(1, 13))


def test_straight_body_is_twelve_segments_along_minus_x():
    pose = forward_kinematics(np.zeros(12), AXES)
    np.testing.assert_allclose(pose.points_m[:, 0], -0.08 * np.arange(13))
    np.testing.assert_allclose(pose.points_m[:, 1:], 0.0)
    assert pose.side_view().shape == (13, 2) and pose.top_view().shape == (13, 2)


def test_segment_lengths_preserved_for_any_pose():
    rng = np.random.default_rng(3)
    pose = forward_kinematics(rng.uniform(-1.5, 1.5, 12), AXES)
    np.testing.assert_allclose(np.linalg.norm(np.diff(pose.points_m, axis=0), axis=1), 0.08)
    for frame in pose.frames:
        np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)


def test_pitch_bends_in_side_view_and_yaw_in_top_view():
    angles = np.zeros(12)
    angles[2] = 0.5  # joint 3 pitch: lifts segments 3… (positive z behind it)
    pose = forward_kinematics(angles, AXES)
    assert np.all(pose.points_m[3:, 2] > 0) and np.allclose(pose.points_m[:3, 2], 0)
    assert np.allclose(pose.points_m[:, 1], 0)  # nothing sideways
    np.testing.assert_allclose(pose.points_m[3, 2], 0.08 * math.sin(0.5))
    angles = np.zeros(12)
    angles[3] = 0.5  # joint 4 yaw: swings the rest to the right (−y)
    pose = forward_kinematics(angles, AXES)
    assert np.all(pose.points_m[4:, 1] < 0) and np.allclose(pose.points_m[:, 2], 0)


def test_sensors_sit_left_right_bottom_of_each_segment():
    pose = forward_kinematics(np.zeros(12), AXES)
    s = sensor_points(pose, radius_m=0.03)
    assert s.shape == (36, 3)
    np.testing.assert_allclose(s[0], [-0.04, 0.03, 0.0])   # S01L
    np.testing.assert_allclose(s[1], [-0.04, -0.03, 0.0])  # S01R
    np.testing.assert_allclose(s[35], [-0.92, 0.0, -0.03])  # S12B


@pytest.mark.parametrize(("joint", "view", "want"), [(3, "top", 0.4), (2, "side", -0.3), (0, "side", 0.7)])
def test_drag_inverse_recovers_the_angle(joint, view, want):
    angles = np.zeros(12)
    angles[1] = 0.2
    target = angles.copy()
    target[joint] = want
    pose = forward_kinematics(target, AXES)
    cols = [0, 2] if view == "side" else [0, 1]
    end = pose.points_m[joint + 1, cols] + 0.5 * (pose.points_m[joint + 1, cols] - pose.points_m[joint, cols])
    got = bend_for_point(angles, AXES, joint, end, view)
    assert got == pytest.approx(want, abs=1e-4)


def test_wrong_angle_count_is_refused():
    with pytest.raises(ValueError, match="11 joint angles for 12"):
        forward_kinematics(np.zeros(11), AXES)


def test_drag_a_point_further_down_the_body():
    angles = np.zeros(12)
    target = angles.copy()
    target[4] = 0.3
    pose = forward_kinematics(target, AXES)
    got = bend_for_point(angles, AXES, 4, pose.points_m[9, [0, 2]], "side", point_index=9)
    assert got == pytest.approx(0.3, abs=1e-4)
