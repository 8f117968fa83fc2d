"""The keyboard and the enabled states a lab user relies on, in the whole window on the simulated lab."""

from __future__ import annotations

import pytest
from PySide6.QtCore import QSettings, Qt

from app.core.force_control import FeedbackProgress
from app.gui.lab import LabContext
from app.gui.main_window import SHORTCUTS_TEXT, MainWindow
from app.gui.robot_bridge import MOTION_PAUSED, MOTION_RUNNING
from app.gui.tabs.gait import progress_text
from devices.config import SIM_PORT, load_config
from models.trajectory import Progress

CONNECT_TIMEOUT_MS = 10_000


@pytest.fixture
def window(qtbot, sim_lab_fast, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))  # an empty shape library
    config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    lab = LabContext(config)
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.show()
    qtbot.waitExposed(win)
    win.activateWindow()  # shortcuts reach the active window only; offscreen, showing does not activate
    qtbot.waitUntil(win.isActiveWindow)
    with qtbot.waitSignal(lab.robot.connected, timeout=CONNECT_TIMEOUT_MS) as blocker:
        lab.robot.connect_robot()
    assert blocker.args == [True]
    yield win
    win.close()


def test_space_acts_on_the_tab_on_screen_only(window, qtbot):
    forces = window.show_tab("forces")
    gait = window.show_tab("gait")
    panel = gait.panel
    panel.set_mode("serpenoid")
    panel.cycles_spin.setValue(50)
    robot = window.lab.robot
    # Play is one bus-thread command now: wait until the bus thread has really started the motion.
    with qtbot.waitSignal(robot.event, timeout=CONNECT_TIMEOUT_MS, check_params_cb=lambda text: "started" in text):
        panel.play_button.click()
    assert robot.motion_state == MOTION_RUNNING
    with qtbot.waitSignal(robot.motion_changed, check_params_cb=lambda s: s == MOTION_PAUSED):
        qtbot.keyClick(window.focusWidget() or window, Qt.Key.Key_Space)
    assert not forces.plots.paused  # the hidden Forces tab ignored the key

    window.show_tab("forces")
    qtbot.keyClick(window.focusWidget() or window, Qt.Key.Key_Space)
    assert forces.plots.paused and robot.motion_state == MOTION_PAUSED
    qtbot.keyClick(window.focusWidget() or window, Qt.Key.Key_Space)
    assert not forces.plots.paused
    robot.stop_motion()


def test_ctrl_enter_captures_a_keyframe_in_teach(window, qtbot):
    teach = window.show_tab("teach")
    qtbot.keyClick(window.focusWidget() or window, Qt.Key.Key_Return, Qt.KeyboardModifier.ControlModifier)
    qtbot.waitUntil(lambda: len(teach.keyframes) == 1, timeout=CONNECT_TIMEOUT_MS)
    assert teach.panel.save_button.toolTip().startswith("Type a name")  # next step named, not a dead button
    assert "Ctrl+Enter" in SHORTCUTS_TEXT and "Space" in SHORTCUTS_TEXT


def test_gait_play_follows_the_connection(window, qtbot):
    panel = window.show_tab("gait").panel
    panel.set_mode("serpenoid")
    assert panel.play_button.isEnabled()
    robot = window.lab.robot
    with qtbot.waitSignal(robot.connected, timeout=CONNECT_TIMEOUT_MS):
        robot.disconnect_robot()
    assert not panel.play_button.isEnabled() and "Hardware tab" in panel.play_button.toolTip()
    with qtbot.waitSignal(robot.connected, timeout=CONNECT_TIMEOUT_MS):
        robot.connect_robot()
    assert panel.play_button.isEnabled()


@pytest.mark.parametrize(("progress", "expected"), [
    (Progress("cycle", 0, 3, 0.8, 0.27, 4.0, 15.0), "cycle 1/3   4.0 / 15.0 s   11.0 s left"),
    (Progress("cycle", 2, 3, 1.0, 1.0, 15.0, 15.0, done=True), "cycle 3/3   15.0 / 15.0 s   done"),
    (Progress("keyframe", 0, 4, 0.5, 0.1, 1.0, 10.0), "keyframe 1/4   1.0 / 10.0 s   9.0 s left"),
    (Progress("shift", 2, 7, 0.32, 0.3, 2.4, 7.0), "shift 2/6   move  32%   2.4 / 7.0 s   4.6 s left"),
    (FeedbackProgress("shift", 6, 7, 1.0, 1.0, 7.0, 7.0, handing_back=True),
     "shift 6/6   move 100%   7.0 / 7.0 s   easing the correction back to the taught pose"),
])
def test_gait_progress_counts_like_a_person(progress, expected):
    assert progress_text(progress) == expected


def test_gait_idle_shows_no_goal_and_every_joint_row_whole(window, qtbot):
    """Idle, nothing is commanded: no goal drawn or listed (a goal preview reads as a command); at the default window
    size the joint table shows J1 … J12 whole, none clipped."""
    window.resize(1280, 800)
    panel = window.show_tab("gait").panel
    robot = window.lab.robot
    qtbot.waitUntil(lambda: robot.latest_state is not None and panel.joint_table.item(11, 1) is not None
                    and panel.joint_table.item(11, 1).text() != "", timeout=CONNECT_TIMEOUT_MS)
    assert panel.body_view._goal is None
    assert all(panel.joint_table.item(r, 0) is None or panel.joint_table.item(r, 0).text() == ""
               for r in range(panel.joint_table.rowCount()))
    table = panel.joint_table
    viewport = table.viewport().rect()
    last = table.visualRect(table.model().index(table.rowCount() - 1, 0))
    assert table.verticalHeaderItem(11) is None or table.verticalHeaderItem(11).text() == "J12"
    assert viewport.contains(last), f"J12's row {last} is cut by the table's viewport {viewport}"
    assert panel.progress_label.text() == "idle"


def test_gait_controls_fit_1280x800_and_feedback_moves_neither_play_nor_the_progress_line(window, qtbot):
    window.resize(1280, 800)
    panel = window.show_tab("gait").panel
    panel.set_mode("follow")
    qtbot.waitUntil(lambda: window.size().width() == 1280 and panel.play_button.isVisible())

    def places() -> tuple:
        for widget in (panel.play_button, panel.progress_label):
            assert widget.isVisible() and not widget.visibleRegion().isEmpty()
            box = widget.rect().translated(widget.mapTo(window, widget.rect().topLeft()))
            assert window.rect().contains(box), f"{widget.objectName() or widget.text()} at {box} is off the window"
        return (panel.play_button.mapTo(window, panel.play_button.rect().topLeft()),
                panel.progress_label.mapTo(window, panel.progress_label.rect().topLeft()))

    before = places()
    assert panel.settings_scroll.verticalScrollBar().maximum() == 0  # no scrolling at 1280×800
    panel.controller_combo.setCurrentIndex(panel.controller_combo.findData("feedback"))
    # what a feedback play shows: every node's line, some on feedforward with the reason, and a long status
    panel.set_feedback_readout([(f"J{j}", 8.0, 3.0, 0.01, "S05B: uncalibrated") for j in (3, 5, 7, 9, 11)],
                               lead=(1.0, 0.1))
    panel.set_status("follow bump (feedback) stopped: servo 5 overload: reboot it from the Hardware tab; it comes "
                     "back with torque off, so support the robot first", "error")
    qtbot.waitUntil(lambda: panel.feedback_box.isEnabled())
    assert places() == before
    assert panel.settings_scroll.verticalScrollBar().maximum() == 0
    scroll = panel.settings_scroll
    for mode in ("follow", "keyframes", "serpenoid", "sidewinding"):
        panel.set_mode(mode)
        needed = scroll.widget().minimumSizeHint().height()
        assert needed <= scroll.viewport().height(), f"{mode}: {needed} px of settings in {scroll.viewport().height()}"
