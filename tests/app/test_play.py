"""`sensnake play` and the follow-the-leader source on the simulated chain: rate, targets, speed, overload."""

from __future__ import annotations

import csv
import json
import threading

import numpy as np
import pytest

from app.cli import main
from devices.config import RobotConfig
from devices.controller import RobotController
from devices.dxl_wire import SYNC_WRITE
from devices.errors import ServoHardwareError
from devices.servo_chain import ServoChain
from models.trajectory import FollowTheLeader, follow_the_leader_targets
from tests.waiting import wait_until

AXES = RobotConfig().axes
SHAPE = np.array([0.12, -0.06, 0.10, 0.04, -0.08, 0.02, 0.05, 0.0, 0.0, 0.03, 0.0, 0.0])
RAD_PER_TICK = 2 * np.pi / 4096
SPEED = 0.6
RATE = 50.0


def write_shape_file(path, keyframes=None):
    data = {"format": "sensnake-shape", "version": 1, "name": "bump", "created": "2026-11-21T10:00:00Z",
            "axes": list(AXES), "angles_rad": SHAPE.tolist()}
    if keyframes is not None:
        data["keyframes"] = keyframes
    path.write_text(json.dumps(data))
    return path


def read_log(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    data = data[~np.isnan(data[:, 1])]  # states read before the first goal was sent have no goal yet
    assert header[0] == "time_s" and header[1] == "goal_rad_1" and header[13] == "present_rad_1"
    assert header[25] == "current_mA_1" and len(header) == 37
    return data[:, 0], data[:, 1:13], data[:, 13:25], data[:, 25:37]


def test_play_follow_on_sim_hits_every_shift_at_speed(sim_lab_fast, tmp_path, capsys):
    shape = write_shape_file(tmp_path / "bump.json")
    log = tmp_path / "log.csv"
    code = main(["play", str(shape), "--robot", "sim", "--speed", str(SPEED), "--rate", str(RATE),
                 "--shifts", "3", "--log", str(log)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "finished" in out and "p99 error" in out and "shift 3/3" in out
    t, goal, present, current = read_log(log)
    # one row per control tick at the requested rate
    periods = np.diff(t)
    assert np.median(periods) == pytest.approx(1 / RATE, rel=0.05)
    # goals are sent as whole ticks: compare within half a tick (+ CSV rounding)
    tol = RAD_PER_TICK / 2 + 2e-5
    for k, target in enumerate(follow_the_leader_targets(SHAPE, AXES, 3)):
        assert np.min(np.max(np.abs(goal - target), axis=1)) <= tol, f"shift {k} target never sent"
    # no joint ever faster than the speed (per control period, allowing the tick quantisation; a row is
    # missing when the loop missed a deadline, so count the periods between rows) …
    step = np.abs(np.diff(goal, axis=0))
    periods_between = np.maximum(np.rint(np.diff(t) * RATE), 1)[:, None]
    assert np.max(step - periods_between * SPEED / RATE) <= RAD_PER_TICK + 2e-5
    assert step.max() <= SPEED / RATE + RAD_PER_TICK + 2e-5  # and never a double step on one tick
    # … and while moving, the fastest joint moves at it
    moving = step.max(axis=1) > RAD_PER_TICK
    assert np.median(step.max(axis=1)[moving]) == pytest.approx(SPEED / RATE, abs=RAD_PER_TICK)
    # the robot followed: at the end it is straight again (shift 3 of a 6-per-axis shape is not straight,
    # so compare with the last target instead)
    np.testing.assert_allclose(present[-1], follow_the_leader_targets(SHAPE, AXES, 3)[-1], atol=3 * RAD_PER_TICK)


def test_overload_mid_gait_stops_within_one_tick_and_sends_nothing_after(sim_lab_fast):
    robot = RobotConfig()
    controller = RobotController(ServoChain(robot), robot)
    controller.start()
    try:
        source = FollowTheLeader(SHAPE, AXES, speed_rad_s=0.3, rate_hz=robot.control_rate_hz)
        future = controller.run_motion(source, "follow")
        assert wait_until(lambda: source.progress.index >= 1), "the motion never reached shift 1"
        chain = sim_lab_fast.chain
        writes_at_fault = chain.count(SYNC_WRITE)
        chain.inject_overload(7)
        with pytest.raises(ServoHardwareError, match=r"servo 7 overload.*reboot servo 7"):
            future.result(timeout=10.0)
        writes_at_stop = chain.count(SYNC_WRITE)
        assert writes_at_stop - writes_at_fault <= 1  # at most the tick already under way
        ticks_at_stop = controller.stats().ticks
        assert wait_until(lambda: controller.stats().ticks >= ticks_at_stop + 10), "the controller stopped ticking"
        assert chain.count(SYNC_WRITE) == writes_at_stop  # nothing sent afterwards
    finally:
        controller.close()


def test_cli_play_overload_is_one_clear_line(sim_lab_fast, tmp_path, capsys):
    shape = write_shape_file(tmp_path / "bump.json")
    chain = sim_lab_fast.chain
    stop = threading.Event()

    def trip_when_moving():
        while not stop.wait(0.005):
            if chain.count(SYNC_WRITE) >= 15:
                chain.inject_overload(4)
                return

    tripper = threading.Thread(target=trip_when_moving, name="test-overload")
    tripper.start()
    try:
        code = main(["play", str(shape), "--robot", "sim", "--speed", "0.3"])
    finally:
        stop.set()
        tripper.join()
    err = capsys.readouterr().err.strip()
    assert code == 1
    assert err.count("\n") == 0 and "servo 4 overload: motion stopped" in err and "Reboot" in err
    assert "sensnake servo reboot --id 4" in err  # the command line's own way to clear it


def test_play_refusals(sim_lab_fast, tmp_path, capsys):
    shape = write_shape_file(tmp_path / "bump.json")
    assert main(["play", str(shape), "--robot", "sim", "--mode", "keyframes"]) == 1
    assert "no keyframes" in capsys.readouterr().err
    too_fast = [{"t_s": 0.0, "angles_rad": [0.0] * 12}, {"t_s": 0.1, "angles_rad": [0.5] + [0.0] * 11}]
    shape = write_shape_file(tmp_path / "fast.json", too_fast)
    assert main(["play", str(shape), "--robot", "sim", "--mode", "keyframes"]) == 1
    err = capsys.readouterr().err
    assert "keyframe 2" in err and "joint 1" in err and "velocity limit" in err
    assert main(["play", str(tmp_path / "missing.json"), "--robot", "sim"]) == 1
    assert "cannot read shape file" in capsys.readouterr().err


def test_play_keyframes_stretched_by_time_scale(sim_lab_fast, tmp_path, capsys):
    """SPEC §5 --mode keyframes: move to the first keyframe, then linear in time at t_s × --time-scale."""
    poses = [np.zeros(12), np.zeros(12), np.zeros(12)]
    poses[0][0], poses[1][0], poses[2][0] = 0.05, 0.15, 0.05
    keyframes = [{"t_s": t, "angles_rad": p.tolist()} for t, p in zip((0.0, 0.2, 0.4), poses, strict=True)]
    shape = write_shape_file(tmp_path / "kf.json", keyframes)
    log = tmp_path / "log.csv"
    # Without the stretch the 0.1 rad steps in 0.2 s need 0.5 rad/s; the robot's limit is 1 rad/s, so both pass.
    code = main(["play", str(shape), "--robot", "sim", "--mode", "keyframes", "--time-scale", "2", "--speed", "0.5",
                 "--rate", str(RATE), "--log", str(log)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "finished" in out
    t, goal, _, _ = read_log(log)
    tol = RAD_PER_TICK / 2 + 2e-5
    at_peak = np.flatnonzero(np.abs(goal[:, 0] - 0.15) <= tol)
    assert at_peak.size, "the middle keyframe was never sent"
    first_at_start = np.flatnonzero(np.abs(goal[:, 0] - 0.05) <= tol)[0]
    # The motion advances one control tick per logged row, so count ticks (a late tick on a loaded machine shifts
    # the host clock, not the plan). The peak is 0.2 s × 2 after the first keyframe (± a tick of rounding each side)
    assert len(t) == len(goal)
    tick_s = np.arange(len(goal)) / RATE
    assert tick_s[at_peak[0]] - tick_s[first_at_start] == pytest.approx(0.4, abs=2.5 / RATE)
    # and the slope on the way is the stretched one, 0.1 rad / 0.4 s.
    rising = slice(first_at_start, at_peak[0] + 1)
    slope = np.polyfit(tick_s[rising], goal[rising, 0], 1)[0]
    assert slope == pytest.approx(0.25, rel=0.1)
    np.testing.assert_allclose(goal[-1], poses[2], atol=tol)
