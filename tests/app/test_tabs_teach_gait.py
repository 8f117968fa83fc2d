"""Teach and Gait tabs on the simulated lab (pytest-qt; waits on conditions and signals, never sleeps)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PySide6.QtCore import Qt

from app.core.shapes import Keyframe, Shape, ShapeLibrary
from app.gui.lab import LabContext
from app.gui.robot_bridge import (
    MOTION_FAULT,
    MOTION_FINISHED,
    MOTION_HALTED,
    MOTION_PAUSED,
    MOTION_RUNNING,
    MOTION_STOPPED,
)
from app.gui.tabs.gait import GaitTab
from app.gui.tabs.teach import TeachTab
from devices.config import LabConfig
from devices.dxl_wire import SYNC_WRITE

RAD_PER_TICK = 2 * math.pi / 4096
WAIT_MS = 5000
AXES = LabConfig().robot.axes


@pytest.fixture
def lab(qtbot, sim_lab_fast):
    context = LabContext(LabConfig())
    with qtbot.waitSignal(context.robot.connected, timeout=WAIT_MS) as blocker:
        context.robot.connect_robot()
    assert blocker.args == [True]
    yield context
    context.close()


@pytest.fixture
def library(tmp_path):
    return ShapeLibrary(tmp_path / "shapes")


def _present(lab):
    return np.asarray(lab.robot.latest_state.position_rad)


def test_teach_tab_pose_capture_edit_undo_save_hold(qtbot, lab, library, sim_lab_fast):
    tab = TeachTab(lab, library)
    qtbot.addWidget(tab)
    tab.resize(1280, 760)
    tab.show()
    panel = tab.panel
    qtbot.mouseClick(panel.torque_off_all_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: all(tab.limp), timeout=WAIT_MS)
    assert panel.body_view.drag_enabled  # in sim, the drawing poses limp joints

    panel.sliders.sliders[2].setValue(300)  # J3 to 0.300 rad "by hand"
    qtbot.waitUntil(lambda: abs(_present(lab)[2] - 0.3) < RAD_PER_TICK, timeout=WAIT_MS)
    qtbot.mouseClick(panel.capture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(tab.keyframes) == 1, timeout=WAIT_MS)
    assert tab.keyframes[0].angles_rad[2] == pytest.approx(0.3, abs=RAD_PER_TICK)

    panel.body_view.joint_dragged.emit(3, -0.25)  # a drag on the top view bends yaw joint J4
    qtbot.waitUntil(lambda: abs(_present(lab)[3] + 0.25) < RAD_PER_TICK, timeout=WAIT_MS)
    qtbot.mouseClick(panel.capture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(tab.keyframes) == 2, timeout=WAIT_MS)
    assert [k.name for k in tab.keyframes] == ["pose 1", "pose 2"]
    assert tab.keyframes[1].t_s == pytest.approx(2.0)

    # reorder, undo, redo
    panel.keyframe_table.selectRow(1)
    qtbot.mouseClick(panel.up_button, Qt.MouseButton.LeftButton)
    assert [k.name for k in tab.keyframes] == ["pose 2", "pose 1"]
    assert [k.t_s for k in tab.keyframes] == [0.0, 2.0]  # times stay in their slots
    qtbot.mouseClick(panel.undo_button, Qt.MouseButton.LeftButton)
    assert [k.name for k in tab.keyframes] == ["pose 1", "pose 2"]
    qtbot.mouseClick(panel.redo_button, Qt.MouseButton.LeftButton)
    assert [k.name for k in tab.keyframes] == ["pose 2", "pose 1"]

    # edit a joint numerically, rename, delete + undo
    panel.keyframe_table.selectRow(0)
    panel.joint_table.item(4, 1).setText("0.2")
    assert tab.keyframes[0].angles_rad[4] == pytest.approx(0.2)
    panel.keyframe_table.item(0, 0).setText("bent")
    assert tab.keyframes[0].name == "bent"
    panel.joint_table.item(5, 1).setText("9.0")  # beyond the joint limit: refused, list unchanged
    assert tab.keyframes[0].angles_rad[5] != 9.0 and "within" in panel.status_label.text()
    qtbot.mouseClick(panel.delete_button, Qt.MouseButton.LeftButton)
    assert len(tab.keyframes) == 1
    panel.undo_button.click()
    assert len(tab.keyframes) == 2 and tab.keyframes[0].name == "bent"

    # mirror flips yaw only
    before = np.array([k.angles_rad for k in tab.keyframes])
    panel.mirror_button.click()
    after = np.array([k.angles_rad for k in tab.keyframes])
    yaw = [i for i, a in enumerate(AXES) if a == "yaw"]
    pitch = [i for i, a in enumerate(AXES) if a == "pitch"]
    np.testing.assert_allclose(after[:, yaw], -before[:, yaw])
    np.testing.assert_allclose(after[:, pitch], before[:, pitch])

    # save and load through the library
    panel.name_edit.setText("two poses")
    panel.save_button.click()
    assert library.names() == ["two-poses"]
    saved = library.load("two poses")
    assert len(saved.keyframes) == 2 and saved.keyframes[0].name == "bent"
    panel.clear_button.click()
    assert tab.keyframes == []
    panel.library_combo.setCurrentText("two-poses")
    panel.load_button.click()
    assert [k.name for k in tab.keyframes] == ["bent", "pose 1"]

    # torque back on, holding the pose without a jump
    held = _present(lab).copy()
    qtbot.mouseClick(panel.hold_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not any(tab.limp), timeout=WAIT_MS)
    chain = sim_lab_fast.chain
    assert all(chain.register(sid, "Torque Enable") == 1 for sid in lab.config.robot.joint_ids)
    qtbot.waitUntil(lambda: lab.robot.latest_state.host_time_s > 0, timeout=WAIT_MS)
    assert np.max(np.abs(_present(lab) - held)) <= 2 * RAD_PER_TICK


def _save_bump(library):
    angles = (0.12, -0.06, 0.10, 0.04, -0.08, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    frames = (Keyframe(0.0, angles, "a"), Keyframe(0.5, tuple(0.5 * a for a in angles), "b"))
    library.save(Shape("bump", AXES, angles, frames))


def _bump_tab(qtbot, lab, library):
    """A shown Gait tab with the 'bump' shape in its library: (tab, panel)."""
    _save_bump(library)
    tab = GaitTab(lab, library)
    qtbot.addWidget(tab)
    tab.show()
    return tab, tab.panel


def test_gait_tab_plays_follow_with_progress_and_pause_resume(qtbot, lab, library, sim_lab_fast):
    tab, panel = _bump_tab(qtbot, lab, library)
    assert panel.shape_combo.currentText() == "bump"
    assert panel.body_view.goal_rad is not None  # the chosen shape is previewed over the body
    panel.set_mode("follow")
    panel.speed_spin.setValue(0.3)
    panel.shifts_spin.setValue(2)
    with qtbot.waitSignal(lab.robot.motion_changed, timeout=WAIT_MS,
                          check_params_cb=lambda s: s == MOTION_RUNNING):
        qtbot.mouseClick(panel.play_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: tab.source.progress.index >= 1, timeout=WAIT_MS)

    qtbot.mouseClick(panel.pause_button, Qt.MouseButton.LeftButton)
    assert lab.robot.motion_state == MOTION_PAUSED
    chain = sim_lab_fast.chain
    writes = chain.count(SYNC_WRITE)
    ticks = lab.robot.controller.stats().ticks
    qtbot.waitUntil(lambda: lab.robot.controller.stats().ticks >= ticks + 5, timeout=WAIT_MS)
    assert chain.count(SYNC_WRITE) - writes <= 1  # paused: no new goals (one tick may have been in flight)
    qtbot.mouseClick(panel.resume_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_FINISHED, timeout=WAIT_MS)
    tab.refresh()
    assert panel.progress_label.text().startswith("shift 2/2")
    assert panel.progress_bar.value() == 1000
    assert "finished" in panel.status_label.text()
    assert panel.play_button.isEnabled() and not panel.stop_button.isEnabled()


def test_gait_tab_overload_message_names_servo_and_stop(qtbot, lab, library, sim_lab_fast):
    tab, panel = _bump_tab(qtbot, lab, library)
    panel.set_mode("keyframes")
    panel.time_scale_spin.setValue(20.0)
    panel.approach_spin.setValue(0.2)
    panel.play_button.click()
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_RUNNING, timeout=WAIT_MS)
    panel.stop_button.click()
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_STOPPED, timeout=WAIT_MS)
    assert "stopped" in panel.status_label.text()

    panel.play_button.click()
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_RUNNING, timeout=WAIT_MS)
    sim_lab_fast.chain.inject_overload(5)
    qtbot.waitUntil(lambda: "servo 5" in panel.status_label.text(), timeout=WAIT_MS)
    text = panel.status_label.text()
    assert "overload" in text and "Reboot" in text
    # The error can reach the tab before the motion's fault state does (two signals): wait for Play to come back.
    qtbot.waitUntil(panel.play_button.isEnabled, timeout=WAIT_MS)


def test_a_motion_stopped_on_a_quiet_bus_shows_stopped_while_its_cause_is_told(qtbot, lab, library, sim_lab_fast,
                                                                               monkeypatch):
    """Every servo stops answering mid-play: the loop's watchdog stops the motion at once (no more goals) and waits
    for the replies it gave up on before naming the cause. From the stop on, the Gait tab shows the motion stopped
    while the cause is told (not running: no Pause, no Stop, no Play yet), and the motion ends as a fault once the
    cause is known (here: the bus answers again without those replies)."""
    from devices import controller as controller_module

    monkeypatch.setattr(controller_module, "SILENCE_VERDICT_WAIT_S", 60.0)  # the verdict waits for the bus here
    tab, panel = _bump_tab(qtbot, lab, library)
    panel.set_mode("follow")  # at the lab's 0.034 rad/s: tens of seconds
    with qtbot.waitSignal(lab.robot.motion_changed, timeout=WAIT_MS, check_params_cb=lambda s: s == MOTION_RUNNING):
        panel.play_button.click()
    qtbot.waitUntil(lambda: tab.source.progress.elapsed_s > 0, timeout=WAIT_MS)
    chain = sim_lab_fast.chain
    ids = lab.config.robot.joint_ids
    for sid in ids:
        chain.set_no_reply(sid)
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_HALTED, timeout=WAIT_MS)
    tab.refresh()
    assert "stopped — checking whether the servos or this computer went quiet" in panel.status_label.text()
    assert panel.progress_label.toolTip().endswith("stopped (checking why)")
    assert not panel.pause_button.isEnabled() and not panel.stop_button.isEnabled()
    assert not panel.play_button.isEnabled() and "wait for the verdict" in panel.play_button.toolTip()
    for sid in ids:
        chain.set_no_reply(sid, False)
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_FAULT, timeout=WAIT_MS)
    # the cause reaches the tab with the motion's result, a moment after its state
    qtbot.waitUntil(lambda: "the bus answers again" in panel.status_label.text(), timeout=WAIT_MS)
    qtbot.waitUntil(panel.play_button.isEnabled, timeout=WAIT_MS)


def test_gait_tab_refuses_too_fast_serpenoid(qtbot, lab, library):
    tab = GaitTab(lab, library)
    qtbot.addWidget(tab)
    panel = tab.panel
    panel.set_mode("serpenoid")
    panel.amplitude_spin.setValue(1.0)
    panel.frequency_spin.setValue(1.0)
    panel.play_button.click()
    assert "exceeds the robot's max joint speed" in panel.status_label.text()
    assert lab.robot.motion_state not in (MOTION_RUNNING,)


def test_gait_panel_request_reflects_the_form(qtbot):
    from widgets.gait_panel import GaitPanel

    panel = GaitPanel(AXES, rate_hz=50.0)
    qtbot.addWidget(panel)
    panel.show()
    request = panel.request()
    assert (request.mode, request.speed_rad_s, request.rate_hz, request.shifts) == ("follow", 0.034, 50.0, None)
    panel.shifts_spin.setValue(4)
    panel.rate_spin.setValue(80.0)  # capped at the control loop's rate
    assert panel.request().shifts == 4 and panel.request().rate_hz == 50.0
    panel.set_mode("sidewinding")
    assert not panel.shape_combo.isVisible() and panel.phase_spin.isVisible()
    panel.set_mode("serpenoid")
    assert not panel.phase_spin.isVisible()
    panel.set_motion_state("running")
    assert not panel.play_button.isEnabled() and panel.pause_button.isEnabled()
    panel.set_motion_state("paused")
    assert panel.resume_button.isEnabled() and panel.stop_button.isEnabled()


def test_a_refused_gait_clears_the_previous_runs_progress(qtbot, lab, library, sim_lab_fast):
    tab, panel = _bump_tab(qtbot, lab, library)
    panel.set_mode("follow")
    panel.speed_spin.setValue(0.3)
    panel.shifts_spin.setValue(1)
    qtbot.mouseClick(panel.play_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: lab.robot.motion_state == MOTION_FINISHED, timeout=WAIT_MS)
    tab.refresh()
    assert panel.progress_bar.value() == 1000
    panel.set_mode("serpenoid")
    panel.amplitude_spin.setValue(1.5)
    panel.frequency_spin.setValue(2.0)  # 18.85 rad/s: refused
    qtbot.mouseClick(panel.play_button, Qt.MouseButton.LeftButton)
    assert "exceeds" in panel.status_label.text()
    tab.refresh()
    assert panel.progress_bar.value() == 0 and panel.progress_label.text() == "idle"


def test_gait_progress_says_stopped_after_stop_not_the_time_left(qtbot, lab, library):
    tab, panel = _bump_tab(qtbot, lab, library)
    panel.set_mode("follow")  # at the lab's 0.034 rad/s: tens of seconds, stopped long before its end
    panel.play_button.click()
    qtbot.waitUntil(lambda: tab.source is not None and tab.source.progress.elapsed_s > 0
                    and "s left" in panel.progress_label.text(), timeout=WAIT_MS)
    lab.emergency_stop()  # what STOP and Esc call
    qtbot.waitUntil(lambda: panel.progress_label.text().endswith("stopped"), timeout=WAIT_MS)
    assert "s left" not in panel.progress_label.text() and "s left" not in panel.progress_label.toolTip()
    assert "stopped" in panel.status_label.text()


def test_a_fault_after_the_gait_started_says_stopped_not_cannot_start(qtbot, lab, library, sim_lab_fast):
    tab, panel = _bump_tab(qtbot, lab, library)
    panel.set_mode("follow")
    panel.play_button.click()
    qtbot.waitUntil(lambda: tab.source is not None and tab.source.progress.elapsed_s > 0, timeout=WAIT_MS)
    sim_lab_fast.chain.inject_overload(5)
    qtbot.waitUntil(lambda: "stopped:" in panel.status_label.text() and panel.play_button.isEnabled(),
                    timeout=WAIT_MS)
    text = panel.status_label.text()
    assert "cannot start" not in text and "servo 5" in text and "overload" in text, text
    assert panel.progress_label.text().endswith("stopped by a fault")


def test_teach_undo_says_what_was_undone(qtbot, library):
    tab = TeachTab(LabContext(LabConfig()), library)  # keyframe edits need no robot
    qtbot.addWidget(tab)
    panel = tab.panel
    pose = tuple(0.1 * (i % 3) for i in range(len(AXES)))
    tab.apply_frames([Keyframe(0.0, pose, "a"), Keyframe(2.0, pose, "b")], 0)
    panel.shift_spin.setValue(1)
    panel.shift_button.click()
    assert panel.status_label.text().startswith("shift +1: applied")
    panel.undo_button.click()
    assert panel.status_label.text() == "undone: shift +1"
    panel.redo_button.click()
    assert panel.status_label.text() == "redone: shift +1"
    tab.lab.close()
