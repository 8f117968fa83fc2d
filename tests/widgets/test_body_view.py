"""BodyView: draws the pose from angles, overlays the goal, colours sensors, turns drags into joint angles."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtCore import QPointF, Qt
from PySide6.QtGui import QMouseEvent
from PySide6.QtWidgets import QApplication

from models.kinematics import forward_kinematics
from widgets import theme
from widgets.body_view import DEFAULT_AXES, BodyView


@pytest.fixture
def view(qtbot):
    # pyqtgraph drops mouse moves closer than 10 ms apart; synthetic drags arrive all at once
    previous = pg.getConfigOption("mouseRateLimit")
    pg.setConfigOption("mouseRateLimit", -1)
    widget = BodyView()
    widget.resize(700, 560)
    qtbot.addWidget(widget)
    widget.show()
    qtbot.waitExposed(widget)
    yield widget
    pg.setConfigOption("mouseRateLimit", previous)


def test_draws_present_and_goal_from_angles(view):
    angles = np.zeros(12)
    angles[2] = 0.4
    goal = np.zeros(12)
    goal[4] = -0.3
    view.set_angles(angles, goal)
    x, z = view._body_items["side"].getData()
    expected = forward_kinematics(angles, DEFAULT_AXES).side_view()
    np.testing.assert_allclose(np.c_[x, z], expected)
    gx, gz = view._goal_items["side"].getData()
    np.testing.assert_allclose(np.c_[gx, gz], forward_kinematics(goal, DEFAULT_AXES).side_view())
    view.set_goal(None)
    assert len(view._goal_items["top"].getData()[0] or []) == 0
    with pytest.raises(ValueError, match="11 joint angles"):
        view.set_angles(np.zeros(11))


def test_sensor_forces_colour_and_health(view):
    forces = np.zeros(36)
    forces[3 * 5 + 2] = 10.0  # S06B at full scale
    flags = np.zeros(36, dtype=int)
    flags[3 * 2 + 2] = 4  # S03B unhealthy
    view.set_sensor_forces(forces, flags, full_scale_n=10.0)
    side = view.sensor_brushes("side")  # bottom sensors, segment order
    assert side[5].color().name().upper() == theme.FORCE_FULL_COLOR.upper()
    assert side[0].color().name().upper() == theme.FORCE_ZERO_COLOR.upper()
    assert side[2].color().alpha() == 0  # hollow
    assert len(view.sensor_brushes("top")) == 24
    with pytest.raises(ValueError, match="35 forces for 36 sensors"):
        view.set_sensor_forces(np.zeros(35))


def _drag(widget, start, end, steps=6):
    viewport = widget.canvas.viewport()
    gv = widget.canvas
    p0 = gv.mapFromScene(start)
    p1 = gv.mapFromScene(end)
    left, none = Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier

    def send(kind, pos, buttons):
        event = QMouseEvent(kind, QPointF(pos), QPointF(viewport.mapToGlobal(pos)), left, buttons, none)
        QApplication.sendEvent(viewport, event)

    send(QMouseEvent.Type.MouseButtonPress, p0, left)
    for i in range(1, steps + 1):
        send(QMouseEvent.Type.MouseMove, p0 + (p1 - p0) * (i / steps), left)
    send(QMouseEvent.Type.MouseButtonRelease, p1, Qt.MouseButton.NoButton)


def test_drag_turns_the_nearest_yaw_joint_in_top_view(view, qtbot):
    view.set_drag_enabled(True)
    pts = view.body_points("top")
    got = []
    view.joint_dragged.connect(lambda j, a: got.append((j, a)))
    start = view.view_point_to_scene("top", *pts[6])  # end of segment 6 → yaw joint 6 (index 5)
    end = view.view_point_to_scene("top", pts[6][0], pts[6][1] + 0.06)
    with qtbot.waitSignal(view.drag_finished, timeout=2000):
        _drag(view, start, end)
    assert got, "no joint_dragged signal"
    joint, angle = got[-1]
    assert joint == 5 and DEFAULT_AXES[joint] == "yaw"
    assert angle < -0.3  # pulled toward +y (the robot's left) → negative yaw


def test_no_drag_when_disabled(view, qtbot):
    got = []
    view.joint_dragged.connect(lambda j, a: got.append(j))
    pts = view.body_points("side")
    start = view.view_point_to_scene("side", *pts[4])
    end = view.view_point_to_scene("side", pts[4][0], pts[4][1] + 0.05)
    _drag(view, start, end)
    assert got == []


def test_encoder_noise_does_not_redraw(view):
    angles = np.full(12, 0.1)
    view.set_angles(angles)
    before = view._body_items["side"].getData()[1].copy()
    view.set_angles(angles + 0.0005)  # a third of a servo tick
    np.testing.assert_array_equal(view._body_items["side"].getData()[1], before)
    view.set_angles(angles + 0.01)
    assert not np.array_equal(view._body_items["side"].getData()[1], before)
