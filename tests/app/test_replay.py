"""3-D replay of a recording: the body of the frame at the time scrubbed to (simulated, motion-captured, or the
commanded pose), the contact forces at its sensors, play / pause / step / speed, on the 3-D tab."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from app.core import replay as replays
from app.core.errors import RecordingFormatError
from models.kinematics import forward_kinematics

N_SEG = 12
AXES = tuple("pitch" if k % 2 == 0 else "yaw" for k in range(N_SEG))


def _write(path, seconds=4.0, sim=True, mocap=False, robot=True):
    """A small recording: /daq + /forces at 30 Hz, /robot at 50 Hz, /sim at 30 Hz (a body crawling along +x and
    waving), /mocap at 100 Hz (the same body 2 cm to the left)."""
    rng = np.random.default_rng(3)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["config"] = ""
        t_daq = np.arange(0, seconds, 1 / 30)
        daq = f.create_group("daq")
        daq.create_dataset("time_s", data=t_daq)
        daq.attrs["channels"] = [f"S{s + 1:02d}{side}" for s in range(N_SEG) for side in "LRB"]
        f.create_group("forces").create_dataset("force_N", data=rng.uniform(0, 4, (t_daq.size, 3 * N_SEG)))
        if robot:
            t_rob = np.arange(0, seconds, 1 / 50)
            goal = 0.3 * np.sin(t_rob[:, None] + np.arange(N_SEG)[None, :])
            g = f.create_group("robot")
            g.create_dataset("time_s", data=t_rob)
            g.create_dataset("goal_rad", data=goal)
        poses = [forward_kinematics(0.2 * np.sin(t + np.arange(N_SEG)), AXES) for t in t_daq]
        points = np.stack([p.points_m for p in poses]) + np.array([1.0, 0, 0]) * t_daq[:, None, None] * 0.01
        frames = np.stack([p.frames for p in poses])
        if sim:
            g = f.create_group("sim")
            g.create_dataset("time_s", data=t_daq)
            g.create_dataset("points_m", data=points)
            g.create_dataset("segment_rotation", data=frames)
            g.create_dataset("sheet_true_N", data=rng.uniform(0, 3, (t_daq.size, 3 * N_SEG)))
            g.attrs["segment_length_m"] = 0.08
        if mocap:
            t_m = np.arange(0, seconds, 1 / 100)
            k = np.minimum(np.searchsorted(t_daq, t_m), t_daq.size - 1)
            g = f.create_group("mocap")
            g.create_dataset("time_s", data=t_m)
            g.create_dataset("segment_center_m", data=0.5 * (points[k, :-1] + points[k, 1:]) + [0, 0.02, 0])
            g.create_dataset("segment_rotation", data=frames[k])
    return path


def test_the_frame_at_t_is_the_last_recorded_at_or_before_it(tmp_path):
    path = _write(tmp_path / "sim.h5", mocap=True)
    replay = replays.open_replay(path)
    assert [t.source for t in replay.tracks] == ["sim", "mocap"]
    assert replay.forces_source == "measured (/forces)"
    with h5py.File(path) as f:
        times, points = f["sim/time_s"][:], f["sim/points_m"][:]
        centers, mocap_t = f["mocap/segment_center_m"][:], f["mocap/time_s"][:]
        forces = f["forces/force_N"][:]
    t = 1.2345
    frame = replay.frame_at(t)
    k = np.flatnonzero(times <= t)[-1]
    sim, cam = frame.bodies
    assert sim.index == k and np.array_equal(sim.points_m, points[k])
    m = np.flatnonzero(mocap_t <= t)[-1]
    assert np.allclose(cam.points_m[1:] + 0.04 * replay.tracks[1].rotations[m][:, :, 0], centers[m])
    assert np.allclose(frame.forces_n, forces[k])
    assert replay.step(t, 1) == pytest.approx(times[k + 1]) and replay.step(t, -1) == pytest.approx(times[k - 1])


def test_without_sim_or_mocap_the_commanded_pose(tmp_path):
    path = _write(tmp_path / "robot.h5", sim=False)
    replay = replays.open_replay(path)
    assert [t.source for t in replay.tracks] == ["commanded"]
    with h5py.File(path) as f:
        goal, times = f["robot/goal_rad"][:], f["robot/time_s"][:]
    frame = replay.frame_at(2.0)
    k = np.flatnonzero(times <= 2.0)[-1]
    assert np.allclose(frame.bodies[0].points_m, forward_kinematics(goal[k], AXES).points_m)
    with pytest.raises(RecordingFormatError, match="no body to replay"):
        replays.open_replay(_write(tmp_path / "none.h5", sim=False, robot=False))


@pytest.fixture
def scene_tab(qtbot):
    from app.gui.lab import LabContext
    from app.gui.tabs.scene import SceneTab
    from devices.config import LabConfig, RobotConfig

    lab = LabContext(LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port")))
    tab = SceneTab(lab)
    qtbot.addWidget(tab)
    tab.resize(900, 600)
    tab.show()
    yield tab
    tab.shutdown()
    lab.close()


def test_the_tab_scrubs_plays_steps_and_draws_the_forces(scene_tab, qtbot, tmp_path):
    path = _write(tmp_path / "sim.h5")
    assert scene_tab.open_replay(path)
    view = scene_tab.replay_view
    with h5py.File(path) as f:
        times, points = f["sim/time_s"][:], f["sim/points_m"][:]
    view.slider.setValue(2500)  # the user scrubs to t = 2.5 s
    k = np.flatnonzero(times <= 2.5)[-1]
    assert scene_tab.replay_time_s == pytest.approx(2.5)
    assert np.array_equal(scene_tab.replay_frame.bodies[0].points_m, points[k])
    u, _v = view._bodies["sim"].getData()
    assert u is not None and len(u) == N_SEG + 1  # drawn
    assert len(view._sensors.data) == 3 * N_SEG and "arrow 1 cm per N" in view.legend.text()
    view.forward_button.click()
    assert scene_tab.replay_frame.bodies[0].index == k + 1
    view.set_speed(10.0)
    view.play_button.click()
    assert scene_tab.playing
    qtbot.waitUntil(lambda: not scene_tab.playing)  # 10× plays the last 1.5 s in ~0.15 s, then stops at the end
    assert scene_tab.replay_time_s == pytest.approx(times[-1])
    scene_tab.show_live()
    assert scene_tab.pages.currentWidget() is scene_tab.live_page and scene_tab.view.isVisibleTo(scene_tab)
