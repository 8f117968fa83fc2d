"""``sensnake experiment obstacle`` (the paper's Sec. III-C in the physics lab) and Teach in the physics lab.

One experiment run is shared by the module's tests (module fixture): settle 4 s, follow-the-leader at 0.1 rad/s
(3× the paper's 0.034, to keep the suite fast), about 30 simulated seconds.
"""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from app.cli import main  # noqa: E402
from app.core.recording import open_recording  # noqa: E402
from devices.config import LabConfig, SimLabConfig  # noqa: E402

WEIGHT_N = 2.4 * 9.81


@pytest.fixture(scope="module")
def obstacle_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("experiment") / "obstacle.h5"
    code = main(["experiment", "obstacle", "--out", str(out), "--speed", "0.1", "--settle", "4"])
    assert code == 0
    return out


def test_the_recording_is_a_sensnake_recording_with_forces_robot_and_body(obstacle_run):
    recording = open_recording(obstacle_run)
    assert recording.n_samples > 500  # 30 Hz board over ~26 s of play
    assert recording.forces_n is not None and recording.forces_n.shape == (recording.n_samples, 36)
    assert recording.robot is not None and recording.robot.present_rad.shape[1] == 12
    with h5py.File(obstacle_run) as f:
        assert f["sim/points_m"].shape[1:] == (13, 3)
        assert f["sim/time_s"].shape[0] == f["robot/time_s"].shape[0]
        assert f.attrs["config"].startswith("# sensnake experiment obstacle")
        assert f["sim"].attrs["weight_N"] == pytest.approx(WEIGHT_N)


def test_the_bottom_sensors_carry_the_weight(obstacle_run):
    recording = open_recording(obstacle_run)
    bottom = np.array([name.endswith("B") for name in recording.channels])
    total = np.nansum(recording.forces_n[:, bottom], axis=1)
    assert np.median(total) == pytest.approx(WEIGHT_N, rel=0.20)


def test_the_robot_advances_and_the_force_pattern_travels_backward_along_the_body(obstacle_run):
    with h5py.File(obstacle_run) as f:
        points = f["sim/points_m"][:]
        true_bottom = f["sim/bottom_true_N"][:]
    centroid_x = points[:, :, 0].mean(axis=1)
    assert centroid_x[-1] - centroid_x[0] > 0.01  # forward (+x) over the obstacle
    assert points[-1, 0, 0] - points[0, 0, 0] > 0.05  # the head most of all
    recording = open_recording(obstacle_run)
    bottom = np.array([name.endswith("B") for name in recording.channels])
    forces = np.nan_to_num(recording.forces_n[:, bottom])
    # From the first shift on (before it the limp drape is spread evenly) until the body tips over the top and its
    # head comes down on the ground ahead (then segment 1 presses hard, in front of the obstacle's contacts).
    landed = np.flatnonzero(forces[:, 0] > 0.15 * WEIGHT_N)
    end_s = recording.time_s[landed[0]] if landed.size else np.inf
    moving = (recording.time_s >= 1.0) & (recording.time_s < end_s)
    assert moving.sum() > 200
    pressing = forces[moving] > 0.15 * WEIGHT_N
    assert pressing.any(axis=1).all()
    front = np.argmax(pressing, axis=1) + 1  # the foremost segment pressing hard (the obstacle's front contact)
    slope = np.polyfit(recording.time_s[moving], front, 1)[0]
    # Fig. 6E: the force pattern travels backward relative to the body (toward the tail, higher segment numbers).
    assert slope > 0.05  # segments per second
    assert np.median(front[-30:]) - np.median(front[:30]) >= 2
    # The same seen from the sensor pressed hardest (the obstacle's top contact; robust to the head touching down).
    most = np.argmax(forces[moving], axis=1) + 1
    assert np.polyfit(recording.time_s[moving], most, 1)[0] > 0.05
    assert np.median(most[-30:]) - np.median(most[:30]) >= 2
    assert true_bottom.shape[1] == 12


def test_a_bad_height_ratio_is_one_line(tmp_path, capsys):
    code = main(["experiment", "obstacle", "--out", str(tmp_path / "x.h5"), "--height-ratio", "2"])
    assert code == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--height-ratio" in err


def test_teach_captures_the_limp_robot_settled_over_the_obstacle(install_fast_sim_lab, tmp_path, capsys):
    config = dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))
    lab = install_fast_sim_lab(config, speed=3.0)
    out = tmp_path / "conform.json"
    # The servos power up limp: the robot drapes over the obstacle while teach waits (2 wall s = 6 simulated s).
    code = main(["teach", "--robot", "sim", "--after", "2", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    angles = np.asarray(json.loads(out.read_text())["angles_rad"])
    scene = lab.physics.world.scene
    wrap = -2 * scene.segment_length_m / (scene.obstacle_height_m + scene.segment_radius_m)
    assert angles[[2, 4, 6, 8]] == pytest.approx(np.full(4, wrap), abs=0.1)  # conformed to the obstacle
    assert np.abs(angles[1::2]).max() < 0.05  # yaw joints stay straight
    assert all(lab.chain.register(sid, "Torque Enable") == 1 for sid in config.robot.joint_ids)  # then holds


def test_a_short_run_prints_progress_and_a_summary(tmp_path, capsys):
    out = tmp_path / "short.h5"
    code = main(["experiment", "obstacle", "--out", str(out), "--seconds", "1", "--settle", "1"])
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("t = ") and "real time" in line and "shift" in line for line in lines)  # progress
    summary = "\n".join(lines)
    assert "real time" in summary and "while playing (until 1.0 s)" in summary  # 1 s settle + 1 s played, …
    assert "at rest from " in summary  # … then held until the body rested, the outcome judged there
    assert "median total bottom force" in summary and f"wrote {out}" in summary
    with h5py.File(out, "r") as f:
        at_rest_s = float(f["sim"].attrs["at_rest_s"])
    assert 1.0 + 2.0 <= at_rest_s <= 1.0 + 30.0  # still for 2 s after the motion, within the 30 s cap
    assert open_recording(out).time_s[-1] == pytest.approx(at_rest_s, abs=0.1)
