"""SPEC §5 follow-the-leader and keyframe planning, checked exactly; parametric gaits and their blend."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from models.errors import TrajectoryError
from models.trajectory import (
    FollowTheLeader,
    Keyframes,
    SerpenoidParams,
    SidewindingParams,
    axis_groups,
    follow_the_leader_targets,
    plan_follow_the_leader,
    plan_keyframes,
    serpenoid,
    sidewinding,
)

AXES = tuple("pitch" if i % 2 == 1 else "yaw" for i in range(1, 13))
SHAPE = np.array([0.30, -0.10, 0.25, 0.05, -0.20, 0.12, 0.10, -0.02, 0.05, 0.08, -0.04, 0.01])


def expected_target(shape, axes, k):
    """The SPEC §5 formula written the slow way: g_{i-k} if i-k >= 1 else 0, per axis, 1-based."""
    out = np.zeros(len(axes))
    for axis in ("pitch", "yaw"):
        joints = [j for j, a in enumerate(axes) if a == axis]
        g = {i + 1: shape[j] for i, j in enumerate(joints)}
        for i, j in enumerate(joints, start=1):
            out[j] = g[i - k] if i - k >= 1 else 0.0
    return out


def test_targets_per_shift_match_spec_formula():
    targets = follow_the_leader_targets(SHAPE, AXES)
    assert targets.shape == (7, 12)  # K defaults to m = 6 joints per axis → shifts 0…6
    for k in range(7):
        np.testing.assert_array_equal(targets[k], expected_target(SHAPE, AXES, k))
    np.testing.assert_array_equal(targets[0], SHAPE)  # shift 0 is the taught shape
    np.testing.assert_array_equal(targets[-1], np.zeros(12))  # K = m: the shape has left through the tail


def test_shift_moves_each_axis_by_one_joint_of_that_axis():
    targets = follow_the_leader_targets(SHAPE, AXES, shifts=2)
    # pitch joints are 1,3,5,…: at shift 1 joint 3 holds what joint 1 held, joint 1 is straight
    assert targets[1, 0] == 0.0 and targets[1, 2] == SHAPE[0] and targets[1, 4] == SHAPE[2]
    # yaw joints 2,4,6,…: at shift 2 joint 6 holds g_1 of the yaw axis (joint 2)
    assert targets[2, 5] == SHAPE[1] and targets[2, 1] == 0.0 and targets[2, 3] == 0.0


def test_uneven_axes_and_explicit_shifts():
    axes = ("pitch", "pitch", "pitch", "yaw", "yaw")
    shape = np.array([0.1, 0.2, 0.3, -0.4, -0.5])
    targets = follow_the_leader_targets(shape, axes)
    assert len(targets) == 4  # K = the larger group (3)
    for k in range(4):
        np.testing.assert_array_equal(targets[k], expected_target(shape, axes, k))
    assert len(follow_the_leader_targets(shape, axes, shifts=10)) == 11


def test_move_durations_fastest_joint_at_speed_and_zero_moves_skipped():
    speed = 0.034
    present = np.zeros(12)
    plan = plan_follow_the_leader(present, SHAPE, AXES, speed)
    previous = np.vstack([present, plan.targets_rad[:-1]])
    for k, (a, b, d) in enumerate(zip(previous, plan.targets_rad, plan.durations_s)):
        assert d == pytest.approx(np.max(np.abs(b - a)) / speed, rel=1e-12), f"shift {k}"
    rate = 50.0
    t, goals = plan.sample(rate)
    np.testing.assert_allclose(np.diff(t), 1 / rate)
    per_tick = np.abs(np.diff(goals, axis=0))  # rad per tick
    assert per_tick.max() <= speed / rate * (1 + 1e-9)  # no joint faster than speed, ever
    # within each move, every full tick moves the fastest joint by exactly speed / rate
    ends = np.cumsum(plan.tick_counts(rate))
    starts = ends - plan.tick_counts(rate)
    for m, (s0, e0) in enumerate(zip(starts, ends)):
        if e0 - s0 >= 2:
            fastest = per_tick[s0:e0 - 1].max(axis=1)
            np.testing.assert_allclose(fastest, speed / rate, rtol=1e-9, err_msg=f"move {m}")
        # the move's last tick sends its target exactly
        np.testing.assert_array_equal(goals[e0], plan.targets_rad[m])
    assert len(goals) == plan.total_ticks(rate) + 1
    np.testing.assert_array_equal(goals[0], present)


def test_each_move_takes_ceil_of_T_times_rate_ticks():
    plan = plan_follow_the_leader(np.zeros(12), SHAPE, AXES, speed_rad_s=0.07)
    for rate in (50.0, 100.0, 200.0):
        np.testing.assert_array_equal(plan.tick_counts(rate), np.ceil(plan.durations_s * rate - 1e-9))  # all T > 0
        assert plan.total_ticks(rate) / rate - plan.total_s < len(plan.durations_s) / rate


def test_zero_duration_moves_take_no_time():
    # present pose already at shift 0 → the first move has T = 0 and is skipped
    plan = plan_follow_the_leader(SHAPE, SHAPE, AXES, speed_rad_s=1.0)
    assert plan.durations_s[0] == 0.0 and plan.tick_counts(50)[0] == 0
    assert plan.progress_at_tick(1, 50).index == 1  # the first tick already works on shift 1
    t, goals = plan.sample(50)
    assert not np.array_equal(goals[1], SHAPE)  # no tick is spent sitting on shift 0
    # a shape that is straight everywhere: every move is T = 0, the plan takes no time at all
    flat = plan_follow_the_leader(np.zeros(12), np.zeros(12), AXES, speed_rad_s=1.0)
    assert flat.total_s == 0.0 and flat.total_ticks(50) == 0
    t, goals = flat.sample(50.0)
    assert len(t) == 1


def test_progress_reports_shift_index_and_fraction():
    plan = plan_follow_the_leader(np.zeros(12), SHAPE, AXES, speed_rad_s=0.5)
    rate = 50.0
    counts = plan.tick_counts(rate)
    ends = np.cumsum(counts)
    mid = int(ends[2] + counts[3] // 2)
    p = plan.progress_at_tick(mid, rate)
    assert (p.kind, p.index, p.count) == ("shift", 3, 7)
    assert p.move_fraction == pytest.approx((mid - ends[2]) / (plan.durations_s[3] * rate))
    assert p.fraction == pytest.approx(mid / plan.total_ticks(rate))
    assert plan.progress_at_tick(plan.total_ticks(rate), rate).done


def test_motion_source_plans_from_present_and_ends_on_target_then_none():
    source = FollowTheLeader(SHAPE, AXES, speed_rad_s=0.5, shifts=1, rate_hz=50.0)
    present = np.full(12, 0.05)
    np.testing.assert_allclose(source.goal_at(0.0, present), present)
    plan = source.plan
    # timing jitter does not change the step: t is rounded to the tick
    np.testing.assert_array_equal(source.goal_at(0.02 + 0.004, present), plan.goal_at_tick(1, 50.0))
    np.testing.assert_array_equal(source.goal_at(0.04 - 0.006, present), plan.goal_at_tick(2, 50.0))
    # a missed deadline (t jumps 3 ticks) advances one tick only: no double step
    np.testing.assert_array_equal(source.goal_at(0.10, present), plan.goal_at_tick(3, 50.0))
    total_ticks = plan.total_ticks(50.0)
    t = 0.10
    sent = []
    while (goal := source.goal_at(t, present)) is not None:
        sent.append(goal)
        t += 0.02
    assert len(sent) == total_ticks - 3  # ticks 4 … total, each sent once
    np.testing.assert_array_equal(sent[-1], plan.targets_rad[-1])
    assert source.progress.done


def test_bad_requests_are_refused_with_clear_errors():
    with pytest.raises(TrajectoryError, match="11 angles, expected 12"):
        follow_the_leader_targets(SHAPE[:11], AXES)
    with pytest.raises(TrajectoryError, match="speed must be a positive"):
        FollowTheLeader(SHAPE, AXES, speed_rad_s=0.0)
    with pytest.raises(TrajectoryError, match="joint 3 has axis 'roll'"):
        axis_groups(("pitch", "yaw", "roll"))


def test_keyframes_interpolate_in_time_after_approach():
    times = [0.0, 2.0, 5.0]
    poses = np.array([np.zeros(12), np.full(12, 0.2), np.full(12, -0.1)])
    present = np.full(12, 0.1)
    plan = plan_keyframes(present, times, poses, time_scale=2.0, approach_speed_rad_s=0.05, velocity_limit_rad_s=1)
    np.testing.assert_allclose(plan.durations_s, [0.1 / 0.05, 4.0, 6.0])
    t_first = plan.move_end_times_s[0]
    np.testing.assert_allclose(plan.goal_at(t_first + 2.0), np.full(12, 0.1))  # halfway to keyframe 2
    first_ticks = plan.tick_counts(50.0)[0]
    np.testing.assert_allclose(plan.goal_at_tick(first_ticks + 100, 50.0), np.full(12, 0.1))
    assert plan.progress_at_tick(first_ticks + 250, 50.0).index == 2


def test_keyframe_too_fast_is_refused_naming_keyframe_and_joint():
    poses = np.zeros((3, 12))
    poses[2, 6] = 0.9  # joint ID 7 moves 0.9 rad in 0.5 s = 1.8 rad/s
    with pytest.raises(TrajectoryError, match=r"keyframe 3 .*joint 7 .*1\.800 rad/s.*velocity limit 1\.000"):
        Keyframes([0.0, 1.0, 1.5], poses, velocity_limit_rad_s=1.0)
    # the same step slowed down by the time scale is accepted
    Keyframes([0.0, 1.0, 1.5], poses, velocity_limit_rad_s=1.0, time_scale=2.0)
    with pytest.raises(TrajectoryError, match="keyframe 2 .* comes before"):
        Keyframes([1.0, 0.5], np.zeros((2, 12)), velocity_limit_rad_s=1.0)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.2, 1.2), min_size=12, max_size=12),
       st.lists(st.floats(-1.2, 1.2), min_size=12, max_size=12),
       st.floats(0.01, 2.0), st.integers(0, 8))
# T·rate a hair above a whole number of ticks: the move's last tick must still be its target exactly.
@example(shape=[0.0, 0.0, 1e-14] + [0.0] * 9, present=[0.0, 0.0, -1.0] + [0.0] * 9, speed=1.0, shifts=1)
def test_follow_the_leader_never_exceeds_speed(shape, present, speed, shifts):
    plan = plan_follow_the_leader(present, shape, AXES, speed, shifts)
    t, goals = plan.sample(50.0)
    if len(t) > 1:
        per_tick = np.abs(np.diff(goals, axis=0)) / np.diff(t)[:, None]
        assert per_tick.max() <= speed * (1 + 1e-9)
    for end, target in zip(np.cumsum(plan.tick_counts(50.0)), plan.targets_rad):
        np.testing.assert_array_equal(goals[end], target)
    np.testing.assert_array_equal(plan.targets_rad, follow_the_leader_targets(shape, AXES, shifts))


def test_serpenoid_blends_from_present_without_jump_and_ends_straight():
    params = SerpenoidParams(amplitude_rad=0.6, spatial_rad=math.pi / 3, frequency_hz=0.5, cycles=2, ramp_s=1.0)
    gait = serpenoid(AXES, params)
    present = np.linspace(-0.2, 0.2, 12)
    t = np.arange(0, gait.duration_s + 0.02, 0.02)
    goals = []
    for x in t:
        g = gait.goal_at(float(x), present)
        if g is None:
            break
        goals.append(g)
    goals = np.array(goals)
    np.testing.assert_allclose(goals[0], present)
    assert np.abs(np.diff(goals, axis=0)).max() < 0.1  # smooth at 50 Hz
    pitch = [i for i, a in enumerate(AXES) if a == "pitch"]
    yaw = [i for i, a in enumerate(AXES) if a == "yaw"]
    mid = goals[len(goals) // 2]
    assert np.allclose(mid[pitch], 0.0) and np.abs(mid[yaw]).max() > 0.3
    np.testing.assert_allclose(goals[-1], 0.0, atol=1e-9)
    assert gait.progress.done and gait.progress.count == 2


def test_sidewinding_pitch_wave_lags_yaw_by_phase():
    params = SidewindingParams(yaw=SerpenoidParams(amplitude_rad=0.5, spatial_rad=0.5, frequency_hz=1.0,
                                                   cycles=4, ramp_s=0.0),
                               pitch_amplitude_rad=0.5, pitch_spatial_rad=0.5, phase_rad=math.pi / 2)
    gait = sidewinding(AXES, params, blend_s=0.0)
    pose = gait.pose_at(1.0)  # whole periods: yaw_i = 0.5 sin(-0.5 i), pitch_i = 0.5 sin(-0.5 i + π/2)
    i = np.arange(6)
    np.testing.assert_allclose(pose[1::2], 0.5 * np.sin(-0.5 * i), atol=1e-12)
    np.testing.assert_allclose(pose[0::2], 0.5 * np.cos(-0.5 * i), atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.floats(-1.0, 1.0), min_size=12, max_size=12), min_size=1, max_size=5),
       st.lists(st.floats(0.05, 3.0), min_size=4, max_size=4), st.floats(0.2, 3.0))
def test_accepted_keyframes_never_exceed_the_velocity_limit(poses, gaps, scale):
    poses = np.array(poses)
    times = np.concatenate([[0.0], np.cumsum(gaps)])[: len(poses)]
    limit = 1.0
    try:
        plan = plan_keyframes(np.zeros(12), times, poses, time_scale=scale, approach_speed_rad_s=0.5,
                              velocity_limit_rad_s=limit)
    except TrajectoryError as exc:
        assert "velocity limit" in str(exc)
        return
    t, goals = plan.sample(50.0)
    if len(t) > 1:
        assert (np.abs(np.diff(goals, axis=0)) / np.diff(t)[:, None]).max() <= limit * (1 + 1e-9)
    for end, target in zip(np.cumsum(plan.tick_counts(50.0)), plan.targets_rad):
        np.testing.assert_array_equal(goals[end], target)
