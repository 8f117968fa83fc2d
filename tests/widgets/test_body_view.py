"""BodyView: draws the pose from angles, overlays the goal, colours sensors, turns drags into joint angles."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtCore import QPointF, Qt
from PySide6.QtGui import QMouseEvent
from PySide6.QtWidgets import QApplication, QGraphicsItem

from models.kinematics import forward_kinematics
from models.trajectory import SerpenoidParams, serpenoid
from widgets import theme
from widgets.body_view import DEFAULT_AXES, RANGE_SHRINK_AFTER_S, BodyView


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


def test_a_sensor_without_a_force_is_drawn_hollow_never_as_0_n(view):
    """NaN (uncalibrated sensor, or a rejected sample) is "no estimate": hollow in the side's colour, and it fills
    again, at its level, once a force comes."""
    forces = np.full(36, np.nan)
    forces[3 * 5 + 2] = 10.0
    view.set_sensor_forces(forces, full_scale_n=10.0)
    side = view.sensor_brushes("side")
    assert side[5].color().name().upper() == theme.FORCE_FULL_COLOR.upper()
    assert [b.color().alpha() for i, b in enumerate(side) if i != 5] == [0] * 11
    forces[:] = 0.0
    view.set_sensor_forces(forces)
    assert {b.color().name().upper() for b in view.sensor_brushes("side")} == {theme.FORCE_ZERO_COLOR.upper()}
    forces[3 * 0 + 2] = np.nan
    view.set_sensor_forces(forces)
    assert view.sensor_brushes("side")[0].color().alpha() == 0


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
    with qtbot.waitSignal(view.drag_finished, timeout=10_000):
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


def test_axes_are_painted_from_a_pixmap(view):
    # Replaying the axes' pictures (grid lines, ticks, labels) under every frame of a moving body was ~40 % of the
    # Gait tab's GUI time; cached, a frame blits them.
    for view_name in ("side", "top"):
        plot = view._plots[view_name]
        for axis_name in ("left", "bottom"):
            axis = plot.getAxis(axis_name)
            assert axis.cacheMode() == QGraphicsItem.CacheMode.DeviceCoordinateCache
            assert all(child.cacheMode() == QGraphicsItem.CacheMode.DeviceCoordinateCache
                       for child in axis.childItems())


def _inside(box, points):
    x0, x1, y0, y1 = box
    return bool(np.all((points[:, 0] >= x0) & (points[:, 0] <= x1) & (points[:, 1] >= y0) & (points[:, 1] <= y1)))


def test_range_settles_on_a_gait_and_keeps_the_body_in_view(view):
    # A range change regenerates every axis picture: while a gait plays, the range must settle on the gait's
    # envelope instead of following each frame, and never cut off the body or the goal.
    gait = serpenoid(DEFAULT_AXES, SerpenoidParams(amplitude_rad=0.7, frequency_hz=0.5, cycles=10, ramp_s=0.0),
                     blend_s=0.0)
    rate_hz, frames_per_cycle = 50, 100
    changes_after_first_cycle = None
    started, fired = None, 0
    for k in range(4 * frames_per_cycle):
        goal = gait.goal_at(k / rate_hz, np.zeros(12))
        view.set_angles(0.9 * goal, goal)
        boxes = view.view_ranges()
        goal_pose = forward_kinematics(goal, DEFAULT_AXES)
        for name in ("side", "top"):
            assert _inside(boxes[name], view.body_points(name)), (k, name)
            assert _inside(boxes[name], goal_pose.side_view() if name == "side" else goal_pose.top_view()), k
        if k == frames_per_cycle:
            changes_after_first_cycle = view.range_changes
        # The frames come faster than the event loop runs here: fire the shrink timer on the gait's clock.
        if not view.shrink_timer.isActive():
            started = None
        elif started is None:
            started = k
        elif (k - started) / rate_hz >= RANGE_SHRINK_AFTER_S:
            view.shrink_timer.stop()
            view.shrink_timer.timeout.emit()
            started, fired = None, fired + 1
    assert fired >= 1  # a pose of the gait left much of the range empty for the whole delay ...
    assert view.range_changes == changes_after_first_cycle  # ... yet three whole cycles without a range change
    assert changes_after_first_cycle < 15  # it grew in a few steps, not once per frame (100 frames)


def test_range_goes_back_to_the_straight_body_after_the_delay(view, qtbot):
    straight = view.view_ranges()
    bent = np.zeros(12)
    bent[0::2] = 0.5  # every yaw joint: the body curls in the top view
    view.set_angles(bent)
    curled = view.view_ranges()
    assert curled["top"][3] - curled["top"][2] > straight["top"][3] - straight["top"][2]
    assert _inside(curled["top"], view.body_points("top"))
    view.set_angles(np.zeros(12))
    assert view.view_ranges() == curled  # not at once: a gait passing through straight would flicker the axes
    assert view.shrink_timer.isActive()
    assert RANGE_SHRINK_AFTER_S >= 1.0
    view.shrink_timer.setInterval(20)  # the test does not wait the full delay
    view.shrink_timer.start()
    qtbot.waitUntil(lambda: view.view_ranges() == straight, timeout=10_000)


def test_sensor_noise_at_a_colour_step_does_not_redraw_but_a_real_change_does(view):
    from widgets.body_view import FORCE_LEVELS

    step_n = 10.0 / FORCE_LEVELS
    forces = np.full(36, 2.5 * step_n)  # right on a step boundary: the worst case for noise
    view.set_sensor_forces(forces, full_scale_n=10.0)
    drawn = view.sensor_redraws
    before = [b.color().name() for b in view.sensor_brushes("top")]
    rng = np.random.default_rng(3)
    for _ in range(200):
        view.set_sensor_forces(forces + rng.normal(0.0, 0.1 * step_n, 36))
    assert view.sensor_redraws == drawn, "sensor noise repainted the body map"
    assert [b.color().name() for b in view.sensor_brushes("top")] == before
    loaded = forces.copy()
    loaded[0] = 10.0  # S01L at full scale: the top view's first sensor turns darkest red
    view.set_sensor_forces(loaded)
    assert view.sensor_redraws == drawn + 1
    assert view.sensor_brushes("top")[0].color().name().upper() == theme.FORCE_FULL_COLOR.upper()
