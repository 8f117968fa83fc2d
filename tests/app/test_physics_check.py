"""app.core.physics_check on recordings written here with known answers (not by the physics lab): the weight checks,
the jump and reversal counts, and the estimate's error."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from app.core.physics_check import check_recording
from devices.config import LabConfig
from devices.scene import channel_map
from models.sls import ForceStatus

CHANNELS = LabConfig().board.channel_names
ROWS, SEGMENTS = channel_map(CHANNELS, 12)
WEIGHT_N = 23.544
TICK_S = 0.02


def _write(path, true_n: np.ndarray, points_m: np.ndarray, estimated_n: np.ndarray | None = None,
           tick_s: float = TICK_S) -> None:
    t = np.arange(len(true_n)) * tick_s
    with h5py.File(path, "w") as f:
        sim = f.create_group("sim")
        sim["time_s"], sim["sheet_true_N"], sim["points_m"] = t, true_n, points_m
        sim.attrs["weight_N"] = WEIGHT_N
        f["robot/time_s"] = t + 100.0  # the robot's clock starts elsewhere: the check lines them up
        daq_t = np.arange(0.0, t[-1], 1 / 30) + 100.0
        f["daq/time_s"] = daq_t
        f["daq"].attrs["channels"] = [c.encode() for c in CHANNELS]
        if estimated_n is not None:
            f["forces/force_N"] = np.column_stack([np.interp(daq_t - 100.0, t, estimated_n[:, c])
                                                   for c in range(len(CHANNELS))])


def _straight(ticks: int) -> np.ndarray:
    x = -0.08 * np.arange(13)
    return np.repeat(np.column_stack([x, np.zeros(13), np.full(13, 0.036)])[None], ticks, axis=0)


def test_a_straight_body_carrying_its_weight_on_its_bottom_sheets_passes_every_weight_check(tmp_path):
    true = np.zeros((300, 36))
    true[:, ROWS == 0] = WEIGHT_N / 12
    _write(tmp_path / "r.h5", true, _straight(300), estimated_n=true + 0.1)
    check = check_recording(tmp_path / "r.h5")
    assert check.bottom_within_10pct == check.vertical_within_10pct == check.all_sheets_within_10pct == 1.0
    assert check.median_bottom_n == pytest.approx(WEIGHT_N)
    assert check.true_jump_frames == check.estimated_jump_frames == 0.0
    assert check.median_rms_n == pytest.approx(0.1) and check.worst_p99_n == pytest.approx(0.1)


def test_a_body_rolled_onto_its_side_carries_its_weight_on_every_sheet_but_not_on_its_bottom(tmp_path):
    true = np.zeros((300, 36))
    true[:, ROWS == 1] = WEIGHT_N / 12
    _write(tmp_path / "r.h5", true, _straight(300))
    check = check_recording(tmp_path / "r.h5")
    assert check.all_sheets_within_10pct == 1.0
    assert check.bottom_within_10pct == check.vertical_within_10pct == 0.0


def test_a_tilted_body_counts_only_the_vertical_part_of_its_bottom_forces(tmp_path):
    points = _straight(300)
    points[:, :, 2] = 0.036 - np.arange(13) * 0.08 * np.sin(0.5)  # pitched by 0.5 rad
    points[:, :, 0] = -np.arange(13) * 0.08 * np.cos(0.5)
    true = np.zeros((300, 36))
    true[:, ROWS == 0] = WEIGHT_N / 12  # the normals sum to the weight: their vertical part is cos(0.5) of it
    _write(tmp_path / "r.h5", true, points)
    check = check_recording(tmp_path / "r.h5")
    assert check.bottom_within_10pct == 1.0 and check.vertical_within_10pct == 0.0
    assert check.median_vertical_n == pytest.approx(WEIGHT_N * np.cos(0.5), rel=1e-6)


def test_chatter_is_counted_as_jumps_that_reverse_and_a_fast_ramp_as_jumps_that_do_not(tmp_path):
    tick = 1 / 300  # fine ticks, so that the 30 Hz frames see the steps whole
    t = np.arange(3000) * tick
    true = np.zeros((3000, 36))
    true[:, ROWS == 0] = WEIGHT_N / 12
    chatter = true.copy()
    chatter[:, 5] += 1.5 * (np.floor(t * 30 + 0.5) % 2)  # +1.5 N on every other board frame
    _write(tmp_path / "c.h5", chatter, _straight(3000), estimated_n=chatter, tick_s=tick)
    check = check_recording(tmp_path / "c.h5")
    assert check.true_jump_frames > 0.9 and check.true_reversal_frames > 0.9
    assert check.estimated_jump_frames > 0.9 and check.estimated_reversal_frames > 0.9
    ramp = true.copy()
    ramp[:, 5] += np.clip((t - 4.0) * 40.0, 0.0, 20.0)  # 40 N/s for 0.5 s: 1.33 N per frame, one way
    _write(tmp_path / "r.h5", ramp, _straight(3000), tick_s=tick)
    check = check_recording(tmp_path / "r.h5")
    assert 0.03 < check.true_jump_frames < 0.06 and check.true_reversal_frames == 0.0
    assert np.isnan(check.estimated_jump_frames) and np.isnan(check.median_rms_n)  # no /forces: not judged


def test_jumps_while_the_body_falls_are_told_apart_from_jumps_while_it_creeps(tmp_path):
    tick = 1 / 300
    t = np.arange(3000) * tick
    true = np.zeros((3000, 36))
    true[:, ROWS == 0] = WEIGHT_N / 12
    falling = (t >= 4.0) & (t < 4.3)
    true[falling, 5] += 1.5 * (np.floor(t[falling] * 30 + 0.5) % 2)  # a landing's bounce, 9 frames
    points = _straight(3000)
    points[:, :, 2] -= 0.5 * np.clip(t - 4.0, 0.0, 0.3)[:, None]  # the body drops at 0.5 m/s meanwhile
    _write(tmp_path / "fall.h5", true, points, tick_s=tick)
    check = check_recording(tmp_path / "fall.h5")
    assert 0.02 < check.true_jump_frames < 0.04 and check.true_reversal_frames > 0.02
    assert 0.03 < check.fast_frames < 0.05  # the drop, and a tick either side of it
    assert check.true_jump_frames_slow == check.true_reversal_frames_slow == 0.0
    points = _straight(3000)  # the same jumps with the body still: chatter
    _write(tmp_path / "still.h5", true, points, tick_s=tick)
    check = check_recording(tmp_path / "still.h5")
    assert check.fast_frames == 0.0
    assert check.true_jump_frames_slow == check.true_jump_frames and check.true_reversal_frames_slow > 0.02


def test_a_force_flagged_at_the_readout_ceiling_is_a_lower_bound_left_out_of_the_error(tmp_path):
    true = np.zeros((300, 36))
    true[:, ROWS == 0] = WEIGHT_N / 12
    true[:, 5] += 10.0  # S02B carries more than its readout can say …
    estimated = true.copy()
    estimated[:, 5] -= 3.0  # … and its estimate stops at the ceiling
    path = tmp_path / "r.h5"
    _write(path, true, _straight(300), estimated_n=estimated)
    assert check_recording(path).worst_rms_n == pytest.approx(3.0)  # without flags: an error like any other
    with h5py.File(path, "a") as f:
        status = np.zeros(f["forces/force_N"].shape, np.int8)
        status[:, 5] = ForceStatus.READOUT_SATURATED
        f["forces/status"] = status
    check = check_recording(path)
    assert check.worst_rms_n == pytest.approx(0.0, abs=1e-9) and check.estimated_saturated_frames == 1.0


def test_the_whole_contact_forces_check_newton_where_the_sheets_readings_exceed_the_weight(tmp_path):
    ticks = 300
    true = np.zeros((ticks, 36))
    true[:, ROWS == 0] = 1.2 * WEIGHT_N / 12  # a curve: the normals add up to more than the weight
    support = np.zeros((ticks, 36))
    support[:, ROWS == 0] = 0.97 * WEIGHT_N / 12  # their whole forces' upward part: the weight less the ends' share
    total = np.full(ticks, WEIGHT_N)
    total[100:106] = 2.0 * WEIGHT_N  # the head landing on the floor: the body accelerates for six ticks
    path = tmp_path / "r.h5"
    _write(path, true, _straight(ticks))
    with h5py.File(path, "a") as f:
        f["sim/sheet_support_N"], f["sim/support_N"] = support, total
    check = check_recording(path)
    assert check.bottom_within_10pct == 0.0
    assert check.bottom_support_within_10pct == 1.0
    assert check.median_bottom_support_n == pytest.approx(0.97 * WEIGHT_N)
    assert check.support_within_10pct == pytest.approx(1.0 - 6 / ticks)
    _write(tmp_path / "old.h5", true, _straight(ticks))  # a recording from before: not known, not a pass
    old = check_recording(tmp_path / "old.h5")
    assert np.isnan(old.support_within_10pct) and np.isnan(old.median_bottom_support_n)
