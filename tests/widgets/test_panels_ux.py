"""What a new user meets in the passive panels: buttons enabled only when they can work (the tooltip says what is
missing), keyboard shortcuts, labels that cannot be misread. No devices: the panels are built directly."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLineEdit

from devices.config import LabConfig
from widgets.force_plots import ForcePlotGrid
from widgets.forces_panel import RECORD_TEXT, STOP_RECORDING_TEXT, ForcesControls
from widgets.gait_panel import GaitPanel
from widgets.ring_plot import TraceHistory
from widgets.teach_panel import TeachPanel

ROBOT = LabConfig().robot


def show_active(qtbot, widget) -> None:
    """Shortcuts reach the active window only; offscreen, a shown window is not activated by itself."""
    widget.show()
    qtbot.waitExposed(widget)
    widget.activateWindow()
    qtbot.waitUntil(widget.isActiveWindow)


@pytest.fixture
def teach_panel(qtbot):
    panel = TeachPanel(ROBOT.joint_ids, ROBOT.axes, ROBOT.joint_min_rad, ROBOT.joint_max_rad)
    qtbot.addWidget(panel)
    return panel


def test_teach_library_buttons_need_a_pose_a_name_and_a_saved_shape(teach_panel):
    p = teach_panel
    assert not p.save_button.isEnabled() and "Capture" in p.save_button.toolTip()
    assert not p.load_button.isEnabled() and "No shape saved" in p.load_button.toolTip()
    assert not any(b.isEnabled() for b in (p.mirror_button, p.scale_button, p.shift_button))

    p.set_keyframes([("pose 1", 0.0)], 0)
    assert not p.save_button.isEnabled() and "name" in p.save_button.toolTip()
    assert all(b.isEnabled() for b in (p.mirror_button, p.scale_button, p.shift_button))
    p.name_edit.setText("   ")
    assert not p.save_button.isEnabled()  # blanks are not a name
    p.name_edit.setText("bump")
    assert p.save_button.isEnabled()

    p.set_library(["bump"], "/tmp/shapes")
    assert p.load_button.isEnabled() and p.library_combo.isEnabled()
    p.set_keyframes([])
    assert not p.save_button.isEnabled() and not p.mirror_button.isEnabled()


def test_ctrl_enter_captures_while_the_teach_panel_is_shown(teach_panel, qtbot):
    p = teach_panel
    captured: list[int] = []
    p.capture_requested.connect(lambda: captured.append(1))
    show_active(qtbot, p)
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Return, Qt.KeyboardModifier.ControlModifier)
    assert captured == [1]
    qtbot.keyClick(p.sliders.spins[0], Qt.Key.Key_Enter, Qt.KeyboardModifier.ControlModifier)  # keypad Enter
    assert captured == [1, 1]
    p.set_connected(False)  # the button is disabled: the shortcut does nothing either
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Return, Qt.KeyboardModifier.ControlModifier)
    assert captured == [1, 1]
    p.hide()
    p.set_connected(True)
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Return, Qt.KeyboardModifier.ControlModifier)
    assert captured == [1, 1]  # a hidden tab's shortcut is inert


def test_gait_play_says_why_it_cannot_play(qtbot):
    panel = GaitPanel(ROBOT.axes, rate_hz=50.0)
    qtbot.addWidget(panel)
    panel.set_mode("follow")
    panel.set_shapes([])
    assert not panel.play_button.isEnabled() and "Teach tab" in panel.play_button.toolTip()
    panel.set_mode("serpenoid")  # a parametric gait needs no shape
    assert panel.play_button.isEnabled()
    panel.set_connected(False)
    assert not panel.play_button.isEnabled() and "Hardware tab" in panel.play_button.toolTip()
    panel.set_connected(True)
    panel.set_mode("keyframes")
    panel.set_shapes(["bump"])
    assert panel.play_button.isEnabled()
    panel.set_motion_state("running")
    assert not panel.play_button.isEnabled()
    panel.set_motion_state("stopped")
    assert panel.play_button.isEnabled()


def test_gait_defaults_are_the_labs_and_space_pauses_and_resumes(qtbot):
    panel = GaitPanel(ROBOT.axes, max_speed_rad_s=ROBOT.max_joint_speed_rad_s, rate_hz=50.0)
    qtbot.addWidget(panel)
    assert panel.speed_spin.value() == pytest.approx(0.034)  # SPEC §1: sensnake play's defaults
    assert panel.rate_spin.value() == pytest.approx(50.0)
    asked: list[str] = []
    panel.pause_requested.connect(lambda: asked.append("pause"))
    panel.resume_requested.connect(lambda: asked.append("resume"))
    show_active(qtbot, panel)
    qtbot.keyClick(panel, Qt.Key.Key_Space)
    assert asked == []  # idle: nothing to pause
    panel.set_motion_state("running")
    qtbot.keyClick(panel.body_view, Qt.Key.Key_Space)
    assert asked == ["pause"]
    panel.set_motion_state("paused")
    qtbot.keyClick(panel, Qt.Key.Key_Space)
    assert asked == ["pause", "resume"]


def test_forces_space_pauses_but_types_in_the_path_field(qtbot):
    controls = ForcesControls()
    qtbot.addWidget(controls)
    show_active(qtbot, controls)
    with qtbot.waitSignal(controls.pause_toggled) as blocker:
        qtbot.keyClick(controls.window_combo, Qt.Key.Key_Space)
    assert blocker.args == [True] and controls.pause.text() == "Resume"
    qtbot.keyClick(controls, Qt.Key.Key_Space)
    assert not controls.pause.isChecked()
    controls.path.setText("trial")
    controls.path.setFocus()
    qtbot.keyClick(controls.path, Qt.Key.Key_Space)
    assert controls.path.text() == "trial " and not controls.pause.isChecked()
    assert isinstance(controls.path, QLineEdit)


def test_record_button_is_not_a_second_stop_and_export_says_what_it_needs(qtbot):
    controls = ForcesControls()
    qtbot.addWidget(controls)
    assert not controls.export.isEnabled() and "Open a recording" in controls.export.toolTip()
    controls.set_recording(True, "0:00:01")
    assert controls.record.text() == STOP_RECORDING_TEXT != "■ Stop"
    controls.set_recording(False, "not recording")
    assert controls.record.text() == RECORD_TEXT
    controls.set_viewing_file("trial.h5")
    assert controls.export.isEnabled() and "CSV" in controls.export.toolTip()


def test_small_forces_are_labelled_in_newtons_and_not_blown_up(qtbot):
    names = [f"S01{side}" for side in "LRB"]
    grid = ForcePlotGrid(names)
    qtbot.addWidget(grid)
    grid.resize(900, 300)
    grid.show()
    history = TraceHistory(len(names), 256)
    t_s = np.linspace(0.0, 2.0, 100)
    history.append(t_s, np.column_stack([0.001 + 0.002 * np.sin(t_s)] * 3))  # mN-sized loads
    grid.set_history(history, "N")
    grid.refresh(force=True)
    axis = grid.plots[0].plot_widget.getPlotItem().getAxis("left")
    assert axis.autoSIPrefixScale == 1.0
    assert "x0.001" not in axis.labelString() and "N" in axis.labelString()
    y0, y1 = grid.plots[0].viewbox.viewRange()[1]
    assert y1 - y0 >= 0.1  # an unloaded sensor's mN wiggle is drawn as the flat line it is, not full scale
    assert y0 <= 0.001 - 0.002 and y1 >= 0.001 + 0.002


def test_ctrl_z_and_ctrl_shift_z_undo_and_redo_while_the_teach_panel_is_shown(teach_panel, qtbot):
    p = teach_panel
    asked: list[str] = []
    p.undo_requested.connect(lambda: asked.append("undo"))
    p.redo_requested.connect(lambda: asked.append("redo"))
    show_active(qtbot, p)
    p.set_undo_state(True, True, "capture pose 1", "delete pose 2")
    assert "Ctrl+Z" in p.undo_button.toolTip() and "Ctrl+Shift+Z" in p.redo_button.toolTip()
    ctrl, shift = Qt.KeyboardModifier.ControlModifier, Qt.KeyboardModifier.ShiftModifier
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Z, ctrl)
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Z, ctrl | shift)
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Y, ctrl)
    assert asked == ["undo", "redo", "redo"]
    p.set_undo_state(False, False)  # nothing to undo: the keys do nothing either
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Z, ctrl)
    assert asked == ["undo", "redo", "redo"]
    p.set_undo_state(True, False, "capture pose 1")
    p.name_edit.setFocus()
    p.name_edit.setText("bump")
    qtbot.keyClick(p.name_edit, Qt.Key.Key_Z, ctrl)  # typing a name: Ctrl+Z is the text field's own undo
    assert asked == ["undo", "redo", "redo"]
    p.hide()
    qtbot.keyClick(p.keyframe_table, Qt.Key.Key_Z, ctrl)
    assert asked == ["undo", "redo", "redo"]  # a hidden tab's shortcut is inert


def test_gait_progress_line_fits_its_column_and_keeps_the_time_left(qtbot):
    panel = GaitPanel(ROBOT.axes, rate_hz=50.0)
    qtbot.addWidget(panel)
    panel.resize(1280, 800)
    panel.show()
    qtbot.waitExposed(panel)
    label = panel.progress_label
    short = "cycle 1/3   4.0 / 15.0 s   11.0 s left"
    panel.set_progress(short, 0.3)
    assert label.text() == short  # fits: shown as is
    long = "shift 11/12   move 100%   12345.6 / 23456.7 s   11111.1 s left"
    panel.set_progress(long, 0.5)
    assert label.text() == long  # the line heads the drawing's column, wide at 1280×800
    panel.resize(800, 800)  # a narrow window: the line no longer fits
    qtbot.waitUntil(lambda: label.contentsRect().width() < label.fontMetrics().horizontalAdvance(long))
    panel.set_progress(long, 0.5)
    metrics = label.fontMetrics()
    assert metrics.horizontalAdvance(label.text()) <= label.contentsRect().width(), label.text()
    assert label.text() != long, "the column is narrower than this line: it must be shortened, not widen the column"
    assert label.text().endswith("11111.1 s left") and label.text().startswith("shift 11/12")
    assert label.toolTip() == long  # all of it, on hover


def test_the_feedback_gains_the_panel_starts_with_are_the_laws_defaults_and_within_its_safe_ranges(qtbot):
    from models.force_feedback import GAIN_RANGES, FeedbackGains

    panel = GaitPanel(ROBOT.axes, rate_hz=50.0)
    qtbot.addWidget(panel)
    defaults = FeedbackGains()
    for key, spin in panel.gain_spins.items():
        assert spin.value() == pytest.approx(getattr(defaults, key)), key
        assert (spin.minimum(), spin.maximum()) == pytest.approx(GAIN_RANGES[key]), key
    assert {"conform_gain", "push_gain", "target_n", "lead_gain"} <= set(panel.gain_spins)


def test_the_feedback_readout_shows_the_lead_only_when_it_is_on(qtbot):
    panel = GaitPanel(ROBOT.axes, rate_hz=50.0)
    qtbot.addWidget(panel)
    rows = [("J3", 5.0, 2.5, 0.1, ""), ("J5", 5.0, float("nan"), 0.0, "S05B: uncalibrated")]
    panel.set_feedback_readout(rows, lead=(0.0, 0.123))
    text = panel.feedback_label.text()
    assert "lead front" in text and "0.0 N" in text and "+0.123 rad" in text
    panel.set_feedback_readout(rows, lead=(float("nan"), 0.0))
    assert "lead front      —" in panel.feedback_label.text()  # not sensed: a dash, never a number
    panel.set_feedback_readout(rows)
    assert "lead" not in panel.feedback_label.text()


def test_the_torque_line_names_one_joint_or_several(qtbot):
    from widgets.teach_panel import TeachPanel

    panel = TeachPanel(ROBOT.joint_ids, ROBOT.axes, ROBOT.joint_min_rad, ROBOT.joint_max_rad)
    qtbot.addWidget(panel)
    n = len(ROBOT.joint_ids)
    panel.set_limp([i == 2 for i in range(n)], posable=True)
    assert panel.torque_label.text() == f"torque: OFF for joint {ROBOT.joint_ids[2]}"
    panel.set_limp([i in (2, 4) for i in range(n)], posable=True)
    assert panel.torque_label.text() == f"torque: OFF for joints {ROBOT.joint_ids[2]}, {ROBOT.joint_ids[4]}"
