"""Force feedback in the app: the Gait tab's feedback mode on the simulated lab, the Forces tab publishing the
estimated forces on the lab's force page, the loop reading them each tick (pytest-qt; waits on conditions)."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from app.core.force_control import FeedbackProgress, ForcePage
from app.core.shapes import Shape, ShapeLibrary
from app.gui.lab import LabContext
from app.gui.robot_bridge import MOTION_RUNNING, MOTION_STOPPED
from app.gui.tabs.forces import ForcesTab
from app.gui.tabs.gait import GaitTab
from devices.config import LabConfig

WAIT_MS = 8000
AXES = LabConfig().robot.axes


@pytest.fixture
def lab(qtbot, sim_lab_fast):
    context = LabContext(LabConfig())
    with qtbot.waitSignal(context.robot.connected, timeout=WAIT_MS):
        context.robot.connect_robot()
    context.board.start()
    yield context
    context.close()


def _tabs(qtbot, lab, tmp_path):
    library = ShapeLibrary(tmp_path / "shapes")
    angles = (0.0, 0.0, -0.3, 0.0, -0.3, 0.0, -0.3, 0.0, 0.0, 0.0, 0.0, 0.0)  # wraps nodes J5 (and J3/J7 ends)
    library.save(Shape("wrap", AXES, angles))
    forces = ForcesTab(lab)
    gait = GaitTab(lab, library)
    for tab in (forces, gait):
        qtbot.addWidget(tab)
    gait.show()
    gait.panel.set_mode("follow")
    gait.panel.speed_spin.setValue(0.2)
    gait.panel.controller_combo.setCurrentIndex(gait.panel.controller_combo.findData("feedback"))
    return forces, gait


def _play(qtbot, lab, gait):
    with qtbot.waitSignal(lab.robot.motion_changed, timeout=WAIT_MS, check_params_cb=lambda s: s == MOTION_RUNNING):
        gait.panel.play_button.click()
    qtbot.waitUntil(lambda: isinstance(gait.source.progress, FeedbackProgress)
                    and gait.source.progress.elapsed_s > 0.5, timeout=WAIT_MS)


def test_without_a_calibration_every_node_stays_on_feedforward_and_says_why(qtbot, lab, tmp_path):
    forces, gait = _tabs(qtbot, lab, tmp_path)
    _play(qtbot, lab, gait)
    # on a loaded machine a tick may find the page a little stale first (its own, also named, reason): wait for one
    # that has the latest frame
    qtbot.waitUntil(lambda: all("uncalibrated" in why for _, why in gait.source.progress.fallback), timeout=WAIT_MS)
    progress = gait.source.progress
    assert progress.node_joints == (2, 4, 6, 8)
    assert dict(progress.fallback).keys() == {2, 4, 6, 8}
    assert np.allclose(progress.correction_rad, 0.0)
    gait.refresh()
    assert "ff:" in gait.panel.feedback_label.text() and "uncalibrated" in gait.panel.feedback_label.text()
    lab.robot.stop_motion()
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_STOPPED, timeout=WAIT_MS)


def test_with_calibrated_sensors_the_loop_corrects_from_fresh_forces_and_stops_on_stop(qtbot, lab, tmp_path,
                                                                                       sim_lab_fast):
    forces, gait = _tabs(qtbot, lab, tmp_path)
    path = tmp_path / "sim.json"
    path.write_text(json.dumps(sim_lab_fast.board.ground_truth_calibration()), encoding="utf-8")
    with qtbot.waitSignal(forces.calibration_applied, timeout=WAIT_MS):
        assert forces.load_calibration(path)
    qtbot.waitUntil(lambda: math.isfinite(lab.force_page.read()[0]), timeout=WAIT_MS)
    gait.panel.gain_spins["push_gain"].setValue(0.3)
    gait.panel.gain_spins["lead_reach"].setValue(2)
    _play(qtbot, lab, gait)
    qtbot.waitUntil(lambda: any(math.isfinite(v) for v in gait.source.progress.node_load_n), timeout=WAIT_MS)
    progress = gait.source.progress
    # the forces the tick used were fresh: at most a board period and a control tick old (wall time; the lab runs
    # 20x faster than real time, the GUI's drain every 33 ms is the slowest step here)
    ages = []
    for _ in range(20):
        qtbot.waitUntil(lambda p=gait.source.progress: gait.source.progress is not p, timeout=WAIT_MS)
        ages.append(gait.source.progress.force_age_s)
    assert np.median(ages) < 1 / 30 + 1 / 50 + 0.02
    assert json.loads(progress.gains_json)["push_gain"] == pytest.approx(0.3)  # the panel's gains reached the loop
    assert json.loads(progress.gains_json)["lead_reach"] == pytest.approx(2.0)
    # live adjustment: a new gain reaches the running motion through the page
    gait.panel.gain_spins["target_n"].setValue(7.5)
    qtbot.waitUntil(lambda: gait.source.progress.target_n == pytest.approx(7.5), timeout=WAIT_MS)
    # STOP (Esc) ends a feedback motion like any other: goals frozen, no more corrections written
    lab.emergency_stop()
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_STOPPED, timeout=WAIT_MS)


def test_the_force_page_is_read_whole_across_processes(tmp_path):
    import subprocess
    import sys

    page = ForcePage.create(36, folder=tmp_path)
    try:
        assert page.read()[0] == -math.inf  # nothing published yet
        forces = np.arange(36, dtype=float)
        trusted = np.arange(36) % 3 != 0
        page.publish(12.5, forces, trusted)
        code = ("import sys, numpy as np; from app.core.force_control import ForcePage; "
                f"p = ForcePage({str(page.path)!r}); t, f, ok = p.read(); "
                "print(t, f.sum(), int(ok.sum()))")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
        assert out.stdout.split() == ["12.5", str(float(forces.sum())), "24"]
    finally:
        page.close()
    assert not page.path.exists()  # the writer's side removes it


def test_a_stale_page_falls_back_to_feedforward_within_100_ms():
    from app.core.force_control import ForceFeedbackMotion
    from devices.controller import HoldPose

    class Page:
        arrival = 0.0

        def read(self):
            return self.arrival, np.full(36, 1.5), np.ones(36, bool)

    now = [0.0]
    page = Page()
    motion = ForceFeedbackMotion(HoldPose(np.zeros(12)), AXES, LabConfig().board.channel_names, page=page,
                                 clock=lambda: now[0])
    for k in range(10):
        now[0] = page.arrival = k * 0.02
        motion.goal_at(k * 0.02, np.zeros(12))
    assert motion.law.fallback == {}
    now[0] += 0.2  # the board went quiet: 200 ms without a new estimate
    motion.goal_at(0.4, np.zeros(12))
    assert set(motion.law.fallback) == {2, 4, 6, 8}
    assert "no force estimate for 200 ms" in motion.law.fallback[4]


def test_the_frame_latency_is_taken_at_the_first_tick_that_uses_a_frame():
    from app.core.force_control import ForceFeedbackMotion
    from models.trajectory import FollowTheLeader

    class Page:
        arrival = -math.inf

        def read(self):
            return self.arrival, np.full(36, 1.5), np.ones(36, bool)

    now = [0.0]
    page = Page()
    shape = np.zeros(12)
    shape[[2, 4, 6]] = -0.3
    motion = ForceFeedbackMotion(FollowTheLeader(shape, AXES, 0.2), AXES, LabConfig().board.channel_names, page=page,
                                 clock=lambda: now[0])
    frames = np.arange(0.005, 1.0, 1 / 30)  # board frames every 33 ms, ticks every 20 ms
    expected, got = [], []
    for k in range(50):
        now[0] = k * 0.02
        arrived = frames[frames <= now[0]]
        new = arrived.size and arrived[-1] != page.arrival
        if arrived.size:
            page.arrival = arrived[-1]
        motion.goal_at(now[0], np.zeros(12))
        latency = motion.progress.frame_latency_s
        got.append(latency)
        expected.append(now[0] - page.arrival if new else math.nan)
        if arrived.size:
            assert motion.progress.force_age_s == pytest.approx(now[0] - page.arrival)
    np.testing.assert_allclose(got, expected)  # NaN where the tick reused a frame
    fresh = np.isfinite(got)
    assert 25 <= fresh.sum() <= 31 and max(np.array(got)[fresh]) < 0.02 + 1e-9  # each frame once, within a tick


def test_a_feedback_motion_crosses_to_the_loop_process_by_pickling_and_opens_the_page_there(tmp_path):
    import pickle

    from app.core.force_control import ForceFeedbackMotion
    from models.trajectory import FollowTheLeader

    page = ForcePage.create(36, folder=tmp_path)
    try:
        shape = np.zeros(12)
        shape[[2, 4, 6]] = -0.3
        motion = ForceFeedbackMotion(FollowTheLeader(shape, AXES, 0.2), AXES, LabConfig().board.channel_names,
                                     page_path=str(page.path))
        page.publish(time.monotonic(), np.full(36, 1.0), np.ones(36, bool))
        motion.goal_at(0.0, np.zeros(12))  # opens the page here
        copy = pickle.loads(pickle.dumps(motion))  # what the loop process receives
        assert copy.page is None and copy.page_path == str(page.path)
        page.publish(time.monotonic(), np.full(36, 1.0), np.ones(36, bool))
        goal = copy.goal_at(0.02, np.zeros(12))
        assert goal is not None and copy.law.fallback == {}  # it read fresh forces through its own mapping
        assert isinstance(copy.progress, FeedbackProgress)
    finally:
        page.close()


def test_robot_states_with_a_correction_are_recorded_in_the_control_group(tmp_path):
    import h5py

    from app.core.recording import RecordingWriter
    from devices.servo_chain import ChainState

    names = LabConfig().board.channel_names
    t0 = time.monotonic()
    path = tmp_path / "rec.h5"
    with RecordingWriter(path, "", names, with_robot=True, t0_monotonic_s=t0) as writer:
        from app.core.recorder import _append_robot

        plain = [ChainState(t0 + 0.02 * k, np.zeros(12), np.zeros(12), np.zeros(12), goal_rad=np.zeros(12))
                 for k in range(3)]
        _append_robot(writer, plain)
        writer.flush()
        with h5py.File(path, "r", locking=False) as f:
            assert "control" not in f  # feedforward only: no /control (SPEC §3.5)
        fed = [ChainState(t0 + 0.02 * k, np.zeros(12), np.zeros(12), np.zeros(12), goal_rad=np.zeros(12),
                          correction_rad=np.full(12, 0.01 * k), controller="feedback",
                          controller_gains='{"push_gain": 0.1}') for k in range(3, 6)]
        _append_robot(writer, fed)
    with h5py.File(path, "r") as f:
        assert f["robot/time_s"].shape == (6,)
        assert f["control/correction_rad"].shape == (3, 12)
        assert f["control/correction_rad"][-1, 0] == pytest.approx(0.05)
        assert f["control/time_s"][0] == pytest.approx(0.06)
        assert f["control"].attrs["controller"] == "feedback"
        assert json.loads(f["control"].attrs["gains"]) == {"push_gain": 0.1}


def test_at_the_end_of_a_play_the_correction_goes_back_to_the_feedforward_at_the_rate_limit():
    from app.core.force_control import ForceFeedbackMotion
    from models.force_feedback import FeedbackGains
    from models.trajectory import FollowTheLeader

    class Page:  # a fresh frame every tick, nothing under the front: the lead bends it all play long
        def __init__(self):
            self.arrival = 0.0

        def read(self):
            return self.arrival, np.zeros(36), np.ones(36, bool)

    now = [0.0]
    page = Page()
    shape = np.zeros(12)
    shape[[2, 4]] = -0.2
    # the tail guard off: with nothing under the whole body it would close the lead this test needs open
    gains = FeedbackGains(lead_gain=0.2, max_rate_rad_s=0.25, tail_guard_n=0.0)
    motion = ForceFeedbackMotion(FollowTheLeader(shape, AXES, 0.5), AXES, LabConfig().board.channel_names, page=page,
                                 clock=lambda: now[0], gains=gains)
    goals, handing_back = [], []
    for k in range(5000):
        now[0] = page.arrival = k * 0.02
        goal = motion.goal_at(now[0], np.zeros(12))
        if goal is None:
            break
        goals.append(goal)
        handing_back.append(motion.progress.handing_back)
        np.testing.assert_allclose(motion.correction_rad, motion.progress.correction_rad)  # what /control records
    else:
        pytest.fail("the motion never ended")
    goals = np.array(goals)
    plain = FollowTheLeader(shape, AXES, 0.5)
    feedforward = []
    for k in range(len(goals)):
        goal = plain.goal_at(k * 0.02, np.zeros(12))
        if goal is None:
            break
        feedforward.append(goal)
    played = len(feedforward)
    assert played < len(goals)  # it went on after the feedforward's last goal …
    correction = goals[played - 1] - feedforward[-1]
    assert np.abs(correction).max() > 0.1  # … with a bend to hand back (the lead's)
    after = goals[played:] - feedforward[-1]
    steps = np.abs(np.diff(np.vstack([correction, after]), axis=0))
    assert steps.max() <= 0.25 * 0.02 + 1e-12  # never faster than max_rate_rad_s
    np.testing.assert_allclose(goals[-1], feedforward[-1], atol=1e-12)  # and ends in the feedforward's final pose
    assert len(after) <= int(np.abs(correction).max() / (0.25 * 0.02)) + 2
    assert not any(handing_back[:played]) and all(handing_back[played:])  # the Gait tab says so while it lasts
