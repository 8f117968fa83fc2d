"""BodyView: the robot drawn from its joint angles, side (x–z) and top (x–y), sensors coloured by force.

Shared by the Teach, Gait and Forces tabs. A passive view: it takes numpy arrays and emits signals.

* :meth:`BodyView.set_angles` draws the present pose, and optionally a goal pose overlaid (dashed grey);
* :meth:`BodyView.set_sensor_forces` colours the 36 sensors (``forces_n`` (36,) in SPEC §2 channel order S01L, S01R,
  S01B, …) on a grey → red ramp; sensors with a non-zero health flag are drawn hollow in the error colour, sensors
  without a force (NaN: uncalibrated, or a rejected sample) hollow in their side's colour — never as 0 N.
  The side view shows the bottom sensors, the top view the left and right ones (each where it can be seen);
* with :meth:`BodyView.set_drag_enabled`, dragging a point of the body turns the nearest joint in front of it that
  bends in that view (pitch in the side view, yaw in the top view) and emits ``joint_dragged(index, angle_rad)``:
  the view does not change its own angles, the owner decides (e.g. set a limp servo in sim, then the new state comes
  back through :meth:`set_angles`).

Geometry is :mod:`models.kinematics` (head at the origin facing +x, the body trailing toward −x).
GUI thread only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPointF, Qt, QTimer, Signal
from PySide6.QtGui import QHideEvent, QResizeEvent
from PySide6.QtWidgets import QVBoxLayout, QWidget

from models.kinematics import SEGMENT_LENGTH_M, bend_for_point, forward_kinematics, sensor_points
from widgets import theme
from widgets.force_plots import cache_subtree

DEFAULT_AXES = tuple("pitch" if i % 2 == 1 else "yaw" for i in range(1, 13))
DEFAULT_FULL_SCALE_N = 10.0
GRAB_RADIUS_PX = 14.0
# The two views stand one above the other, or side by side where the drawing is this many times wider than high
# (a short window, the event log open below the tab): stacked there, each view a strip with its aspect locked, they
# spanned tens of metres across and the robot was a dot.
SIDE_BY_SIDE_RATIO = 3.0
MIN_HEIGHT_PX = 170  # side by side, each view keeps ~100 px of drawing under its title and above its axis
# 1 mrad turns the tail by < 1 mm: below a pixel at the drawing's scale, and below the ±1 tick (1.5 mrad)
# encoder noise of a servo holding torque, so a robot standing still costs no redraws.
REDRAW_TOLERANCE_RAD = 1e-3
# When a bent body leaves the drawn range, the range grows past it by this fraction of the body length, and it
# shrinks back (to the drawing plus this headroom) only after being more than twice the headroom too wide for
# RANGE_SHRINK_AFTER_S: a gait settles on its envelope and the axes stay put (see BodyView._set_ranges).
RANGE_HEADROOM = 0.1
RANGE_SHRINK_AFTER_S = 3.0
VIEWS = ("side", "top")
# Sensor colours: the force ramp drawn in FORCE_LEVELS steps (5 % of full scale each; finer steps are not visible),
# and a sensor changes step only once its force is a whole step from the one drawn (so what is drawn is never more
# than one step off), so sensor noise near a step boundary does not repaint the map (it did: ~19 % of the GUI thread
# at 36 ch).
FORCE_LEVELS = 20
LEVEL_HYSTERESIS = 1.0
NO_ESTIMATE_LEVEL = -1.0  # the level of a sensor without a force (NaN): drawn hollow


def _contains(outer: tuple[float, float, float, float], inner: tuple[float, float, float, float]) -> bool:
    return outer[0] <= inner[0] and outer[1] >= inner[1] and outer[2] <= inner[2] and outer[3] >= inner[3]


def _union(a: tuple[float, float, float, float], b: tuple[float, float, float, float]
           ) -> tuple[float, float, float, float]:
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))


def _grown(box: tuple[float, float, float, float], pad: float) -> tuple[float, float, float, float]:
    return (box[0] - pad, box[1] + pad, box[2] - pad, box[3] + pad)


class _BodyViewBox(pg.ViewBox):
    """A ViewBox that turns left-button drags into joint drags when its owner allows it."""

    def __init__(self, owner: BodyView, view: str) -> None:
        super().__init__(lockAspect=True, enableMenu=False)
        self._owner = owner
        self._view = view
        self.setMouseEnabled(x=False, y=False)

    def mouseDragEvent(self, ev, axis=None) -> None:  # noqa: N802 - pyqtgraph's override name
        if not self._owner.drag_enabled or ev.button() != Qt.MouseButton.LeftButton:
            ev.ignore()
            return
        ev.accept()
        position = self.mapSceneToView(ev.scenePos())
        if ev.isStart():
            self._owner.begin_drag(self._view, self.mapSceneToView(ev.buttonDownScenePos()), self)
        self._owner.drag_to(self._view, position)
        if ev.isFinish():
            self._owner.end_drag()


class BodyView(QWidget):
    """Side and top views of the snake. See the module docstring for the API."""

    joint_dragged = Signal(int, float)  # joint index (0-based, joint order of the config), angle in rad
    drag_finished = Signal()

    def __init__(self, axes: Sequence[str] = DEFAULT_AXES, segment_length_m: float = SEGMENT_LENGTH_M,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._axes = tuple(axes)
        self._length_m = float(segment_length_m)
        self._present = np.zeros(len(self._axes))
        self._goal: np.ndarray | None = None
        self._forces_n: np.ndarray | None = None
        self._levels: np.ndarray | None = None  # colour step drawn per sensor (0…FORCE_LEVELS)
        self.sensor_redraws = 0  # how often the sensors were drawn (tests: noise must not redraw them)
        self._health: np.ndarray | None = None
        self._full_scale_n = DEFAULT_FULL_SCALE_N
        self._highlight: set[int] = set()
        self.drag_enabled = False
        self._drag: tuple[int, int] | None = None  # (joint index, point index) while dragging
        self._style_cache: dict = {}
        self._sensor_style_cache: dict = {}
        self._brush_cache: dict = {}
        self._pen_cache: dict = {}
        self.range_changes = 0  # how often the views' ranges were set (each one redraws the axes)
        # What was drawn since the range first looked too wide; when shrink_timer fires, the range shrinks to it
        self._envelope: dict[str, tuple[float, float, float, float]] | None = None
        self.shrink_timer = QTimer(self)
        self.shrink_timer.setSingleShot(True)
        self.shrink_timer.setInterval(int(RANGE_SHRINK_AFTER_S * 1000))
        self.shrink_timer.timeout.connect(self._shrink_ranges)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self._canvas = pg.GraphicsLayoutWidget()
        self._canvas.setBackground("w")
        self._canvas.ci.setSpacing(2)
        layout.addWidget(self._canvas)
        self.setMinimumHeight(MIN_HEIGHT_PX)
        self._plots: dict[str, pg.PlotItem] = {}
        self._goal_items: dict[str, pg.PlotDataItem] = {}
        self._body_items: dict[str, pg.PlotDataItem] = {}
        self._joint_items: dict[str, pg.ScatterPlotItem] = {}
        self._sensor_items: dict[str, pg.ScatterPlotItem] = {}
        self._head_items: dict[str, pg.ScatterPlotItem] = {}
        titles = {"side": "Side view (x–z): pitch joints, bottom sensors",
                  "top": "Top view (x–y): yaw joints, left/right sensors"}
        for row, view in enumerate(VIEWS):
            box = _BodyViewBox(self, view)
            plot = self._canvas.addPlot(row=row, col=0, viewBox=box)
            plot.setTitle(titles[view], size="9pt", color="#444")
            plot.showGrid(x=True, y=True, alpha=0.15)
            plot.setLabel("bottom", "x (m)")
            plot.setLabel("left", "z (m)" if view == "side" else "y (m)")
            for axis_name in ("left", "bottom"):
                theme.no_si_prefix(plot.getAxis(axis_name))  # metres throughout, no "×0.001"
            plot.hideButtons()
            plot.setMenuEnabled(False)
            # The axes (grid lines, tick labels and title included) change only with the range: paint them from a
            # pixmap, not by replaying their pictures under every frame of a moving body (as the force plots do).
            for axis_name in ("left", "bottom"):
                cache_subtree(plot.getAxis(axis_name))
            self._plots[view] = plot
            goal = pg.PlotDataItem(pen=pg.mkPen(theme.GOAL_COLOR, width=2, style=Qt.PenStyle.DashLine))
            body = pg.PlotDataItem(pen=pg.mkPen(theme.PRESENT_COLOR, width=3))
            joints = pg.ScatterPlotItem(size=9, pxMode=True)
            sensors = pg.ScatterPlotItem(size=11, pxMode=True, symbol="s")
            head = pg.ScatterPlotItem(size=13, pxMode=True, symbol="t2",
                                      brush=pg.mkBrush(theme.PRESENT_COLOR), pen=None)
            for item in (goal, body, sensors, joints, head):
                plot.addItem(item)
            self._goal_items[view], self._body_items[view] = goal, body
            self._joint_items[view], self._sensor_items[view] = joints, sensors
            self._head_items[view] = head
        self.side_by_side = False
        self._set_ranges()
        self._redraw()

    def resizeEvent(self, event: QResizeEvent) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(event)
        self._arrange(event.size().width() >= SIDE_BY_SIDE_RATIO * event.size().height())

    def _arrange(self, side_by_side: bool) -> None:
        """The views one above the other, or side by side (a wide, short drawing)."""
        if side_by_side == self.side_by_side:
            return
        self.side_by_side = side_by_side
        layout = self._canvas.ci
        for plot in self._plots.values():
            layout.removeItem(plot)
        for i, view in enumerate(VIEWS):
            layout.addItem(self._plots[view], row=0 if side_by_side else i, col=i if side_by_side else 0)

    def shown_ranges(self) -> dict[str, tuple[float, float, float, float]]:
        """What each view shows now: (x0, x1, y0, y1) in m, the locked aspect's widening included."""
        shown = {}
        for view, plot in self._plots.items():
            (x0, x1), (y0, y1) = plot.vb.viewRange()
            shown[view] = (float(x0), float(x1), float(y0), float(y1))
        return shown

    # -- public API ------------------------------------------------------------------------------------------------
    @property
    def axes(self) -> tuple[str, ...]:
        return self._axes

    @property
    def present_rad(self) -> np.ndarray:
        return self._present.copy()

    @property
    def goal_rad(self) -> np.ndarray | None:
        return None if self._goal is None else self._goal.copy()

    def set_axes(self, axes: Sequence[str], segment_length_m: float | None = None) -> None:
        self._axes = tuple(axes)
        if segment_length_m is not None:
            self._length_m = float(segment_length_m)
        self._present = np.zeros(len(self._axes))
        self._goal = None
        self._sensor_style_cache.clear()
        self._set_ranges()
        self._redraw()

    def set_angles(self, present_rad: Sequence[float] | np.ndarray | None,
                   goal_rad: Sequence[float] | np.ndarray | None = None) -> None:
        """Draw the present pose (``None`` = straight) and the goal overlay (``None`` hides it). Radians."""
        n = len(self._axes)
        present = np.zeros(n) if present_rad is None else np.asarray(present_rad, dtype=float)
        if present.shape != (n,):
            raise ValueError(f"{present.size} joint angles for a body of {n} joints")
        goal = None if goal_rad is None else np.asarray(goal_rad, dtype=float)
        if goal is not None and goal.shape != (n,):
            raise ValueError(f"{goal.size} goal angles for a body of {n} joints")
        tol = REDRAW_TOLERANCE_RAD
        unchanged = np.max(np.abs(present - self._present), initial=0.0) < tol and (
            (goal is None and self._goal is None) or (goal is not None and self._goal is not None
                                                      and np.max(np.abs(goal - self._goal), initial=0.0) < tol))
        if unchanged:
            return  # nothing moved by a visible amount (encoder noise is ±1 tick): skip the redraw
        self._present, self._goal = present.copy(), None if goal is None else goal.copy()
        self._redraw()

    def set_goal(self, goal_rad: Sequence[float] | np.ndarray | None) -> None:
        self.set_angles(self._present, goal_rad)

    def set_sensor_forces(self, forces_n: Sequence[float] | np.ndarray | None,
                          health_flags: Sequence[int] | np.ndarray | None = None,
                          full_scale_n: float | None = None) -> None:
        """Colour the sensors by force (N, (3·n_joints,) channel order); ``None`` clears them. A NaN force (no
        estimate: the sensor is uncalibrated, or its sample was rejected) is drawn hollow, not as 0 N.

        ``health_flags`` (same length): 0/False = healthy, anything else = a problem (drawn hollow, error colour).
        ``full_scale_n`` sets the force drawn darkest red (default 10 N). Only what visibly changes is redrawn: the
        colours are :data:`FORCE_LEVELS` steps with hysteresis, and a change of colours alone swaps brushes
        without rebuilding the sensor items.
        """
        if full_scale_n is not None:
            if not full_scale_n > 0:
                raise ValueError(f"full_scale_n must be positive, got {full_scale_n}")
            if full_scale_n != self._full_scale_n:
                self._full_scale_n = float(full_scale_n)
                self._levels = None
        if forces_n is None:
            if self._forces_n is None:
                return
            self._forces_n, self._health, self._levels = None, None, None
        else:
            forces = np.asarray(forces_n, dtype=float)
            n_sensors = 3 * len(self._axes)
            if forces.shape != (n_sensors,):
                raise ValueError(f"{forces.size} forces for {n_sensors} sensors")
            flags = None if health_flags is None else np.asarray(health_flags).astype(bool)
            if flags is not None and flags.shape != (n_sensors,):
                raise ValueError(f"{flags.size} health flags for {n_sensors} sensors")
            raw = np.clip(forces / self._full_scale_n, 0.0, 1.0) * FORCE_LEVELS  # NaN stays NaN
            previous = self._levels
            with np.errstate(invalid="ignore"):
                if previous is None:
                    levels = np.round(raw)
                else:
                    levels = np.where(np.abs(raw - previous) < LEVEL_HYSTERESIS, previous, np.round(raw))
            levels = np.where(np.isnan(raw), NO_ESTIMATE_LEVEL, levels)
            same_health = (flags is None and self._health is None) or (
                flags is not None and self._health is not None and np.array_equal(flags, self._health))
            self._forces_n = forces.copy()
            if previous is not None and same_health and np.array_equal(levels, previous):
                return  # no sensor changed colour: nothing to draw
            self._levels, self._health = levels, flags
        self._sensor_style_cache.clear()
        self._draw_sensors(positions=False)

    def set_highlighted_joints(self, indices: Sequence[int]) -> None:
        """Mark joints (0-based), e.g. the ones whose torque is off while posing."""
        self._highlight = {int(i) for i in indices}
        self._redraw()

    def set_drag_enabled(self, enabled: bool) -> None:
        self.drag_enabled = bool(enabled)
        self._drag = None

    def sensor_brushes(self, view: str) -> list:
        """The brushes the sensors of ``view`` are drawn with (for tests and screenshots)."""
        return list(self._sensor_items[view].data["brush"])

    def view_point_to_scene(self, view: str, x_m: float, y_m: float) -> QPointF:
        """Scene coordinates of a point of a view (metres): lets tests and tools aim at the drawing."""
        return self._plots[view].vb.mapViewToScene(QPointF(x_m, y_m))

    def body_points(self, view: str) -> np.ndarray:
        """(n+1, 2) present body points drawn in ``view`` (m)."""
        pose = forward_kinematics(self._present, self._axes, self._length_m)
        return pose.side_view() if view == "side" else pose.top_view()

    @property
    def canvas(self) -> pg.GraphicsLayoutWidget:
        return self._canvas

    # -- drawing ---------------------------------------------------------------------------------------------------
    def _default_box(self) -> tuple[float, float, float, float]:
        length = self._length_m * len(self._axes)
        return (-length - 0.05, 0.08, -0.2 * length, 0.2 * length)

    def _set_ranges(self, points: np.ndarray | None = None) -> None:
        """Show the straight body; grow at once to keep a bent body in view (m).

        pyqtgraph regenerates an axis picture on every range change, which made the axes most of the Gait tab's
        drawing cost, so the range has hysteresis: it grows only when the drawing leaves it (by the side that was
        left, with headroom). When a pose leaves much of the range empty, ``shrink_timer`` starts, and when it fires
        (``RANGE_SHRINK_AFTER_S`` later, also if the body stopped moving meanwhile) the range shrinks to what was
        drawn in that time (the straight body's box if the body stayed in it). So while a gait plays the range
        settles on the gait's envelope and stays put.
        """
        x0, x1, y0, y1 = self._default_box()
        default = self._equalized({view: (x0, x1, y0, y1) for view in VIEWS})
        current = getattr(self, "_boxes", None)
        if points is None or current is None:
            self._apply_ranges(default)
            return
        box = {}
        for view in VIEWS:
            cols = [0, 2] if view == "side" else [0, 1]
            p = points[:, cols]
            margin = 0.05
            box[view] = (min(x0, p[:, 0].min() - margin), max(x1, p[:, 0].max() + margin),
                         min(y0, p[:, 1].min() - margin), max(y1, p[:, 1].max() + margin))
        needed = self._equalized(box)
        pad = RANGE_HEADROOM * self._length_m * len(self._axes)
        if all(_contains(current[v], needed[v]) for v in VIEWS):
            if self.shrink_timer.isActive() and self._envelope is not None:
                self._envelope = {v: _union(self._envelope[v], needed[v]) for v in VIEWS}
            elif self._too_wide(current, needed, default):
                self._envelope = needed
                if self.isVisible():
                    self.shrink_timer.start()
                else:  # nobody sees it (a tab not shown, a closed window): settle now, no timer behind it
                    self._shrink_ranges()
            return
        # The drawing left the range: move out the sides it crossed, with headroom, keep the others.
        grown = {}
        for v in VIEWS:
            c, n = current[v], needed[v]
            grown[v] = (min(c[0], n[0] - pad) if n[0] < c[0] else c[0], max(c[1], n[1] + pad) if n[1] > c[1] else c[1],
                        min(c[2], n[2] - pad) if n[2] < c[2] else c[2], max(c[3], n[3] + pad) if n[3] > c[3] else c[3])
        self._apply_ranges(self._equalized(grown))

    def _snug(self, needed: dict, default: dict) -> dict:
        """The range that fits ``needed`` (equalized boxes, m): the default one, or ``needed`` with headroom."""
        if needed == default:
            return default
        pad = RANGE_HEADROOM * self._length_m * len(self._axes)
        return self._equalized({v: _grown(b, pad) for v, b in needed.items()})

    def _too_wide(self, current: dict, needed: dict, default: dict) -> bool:
        """Is ``current`` more than twice the headroom wider or taller than ``needed`` requires (or not the default
        range for a body inside the straight body's box)?"""
        snug = self._snug(needed, default)
        if snug == default:
            return current != default
        slack = 2 * RANGE_HEADROOM * self._length_m * len(self._axes) + 1e-9
        return any(current[v][1] - current[v][0] > snug[v][1] - snug[v][0] + slack
                   or current[v][3] - current[v][2] > snug[v][3] - snug[v][2] + slack for v in VIEWS)

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt's name
        """Hidden (tab switched, window closed): settle a pending shrink now rather than leave its timer running
        behind a view nobody sees; the range is then already the settled one when the view shows again."""
        if self.shrink_timer.isActive():
            self.shrink_timer.stop()
            self._shrink_ranges()
        super().hideEvent(event)

    def _shrink_ranges(self) -> None:
        """shrink_timer fired: fit the range to what was drawn since it started, if that is much smaller."""
        envelope, self._envelope = self._envelope, None
        if envelope is None:
            return
        x0, x1, y0, y1 = self._default_box()
        default = self._equalized({view: (x0, x1, y0, y1) for view in VIEWS})
        if self._too_wide(self._boxes, envelope, default):
            self._apply_ranges(self._snug(envelope, default))

    def _apply_ranges(self, box: dict[str, tuple[float, float, float, float]]) -> None:
        self.shrink_timer.stop()
        self._envelope = None
        if box == getattr(self, "_boxes", None):
            return
        self._boxes = box
        self.range_changes += 1
        for view, plot in self._plots.items():
            bx0, bx1, by0, by1 = box[view]
            plot.vb.disableAutoRange()
            plot.setRange(xRange=(bx0, bx1), yRange=(by0, by1), padding=0)

    def view_ranges(self) -> dict[str, tuple[float, float, float, float]]:
        """The box each view was last asked to show: (x0, x1, y0, y1) in m (the locked aspect may show more)."""
        return dict(self._boxes)

    @staticmethod
    def _equalized(box: dict[str, tuple[float, float, float, float]]) -> dict[str, tuple[float, float, float, float]]:
        """Both views get the same x range and the same y height (each centred on its own content): with the
        aspect locked and equal plot sizes, a joint then sits at the same x in both views."""
        x_lo, x_hi = min(b[0] for b in box.values()), max(b[1] for b in box.values())
        height = max(b[3] - b[2] for b in box.values())
        return {view: (x_lo, x_hi, 0.5 * (b[2] + b[3] - height), 0.5 * (b[2] + b[3] + height))
                for view, b in box.items()}

    def _redraw(self) -> None:
        present = forward_kinematics(self._present, self._axes, self._length_m)
        goal = None if self._goal is None else forward_kinematics(self._goal, self._axes, self._length_m)
        drawn = present.points_m if goal is None else np.vstack([present.points_m, goal.points_m])
        self._set_ranges(drawn)
        for view in VIEWS:
            pts = present.side_view() if view == "side" else present.top_view()
            self._body_items[view].setData(pts[:, 0], pts[:, 1])
            if goal is None:
                self._goal_items[view].setData([], [])
            else:
                g = goal.side_view() if view == "side" else goal.top_view()
                self._goal_items[view].setData(g[:, 0], g[:, 1])
            brushes, pens, sizes = self._joint_style(view)
            self._joint_items[view].setData(pos=pts[:-1], brush=brushes, pen=pens, size=sizes)
            self._head_items[view].setData(pos=pts[:1])
        self._present_pose = present
        self._draw_sensors()

    def _joint_style(self, view: str) -> tuple[list, list, list]:
        """Brushes, pens and sizes of the joint markers; rebuilt only when the axes or highlights change
        (building Qt pens and brushes for every frame costs more than drawing them)."""
        key = (view, self._axes, frozenset(self._highlight))
        cached = self._style_cache.get(key)
        if cached is None:
            bending = "pitch" if view == "side" else "yaw"
            brushes, pens, sizes = [], [], []
            for i, axis in enumerate(self._axes):
                alpha = 255 if axis == bending else 90
                brushes.append(pg.mkBrush(theme.qcolor(theme.AXIS_COLORS[axis], alpha)))
                highlighted = i in self._highlight
                pens.append(pg.mkPen(theme.STATUS_COLORS[theme.WARN], width=2.5) if highlighted
                            else pg.mkPen("#333", width=1))
                sizes.append(12 if highlighted else 9)
            cached = self._style_cache[key] = (brushes, pens, sizes)
        return cached

    def _sensor_style(self, view: str, index: np.ndarray) -> tuple[list, list]:
        """Brushes and pens of the sensors in ``view``, rebuilt only when forces or health change."""
        key = view
        cached = self._sensor_style_cache.get(key)
        if cached is not None:
            return cached
        brushes, pens = [], []
        for k in index:
            side = "LRB"[k % 3]
            if self._forces_n is None:
                brushes.append(self._brush(theme.FORCE_ZERO_COLOR))
                pens.append(self._pen(theme.SIDE_COLORS[side], 1.5))
            elif self._health is not None and self._health[k]:
                brushes.append(self._brush("#FFFFFF00"))
                pens.append(self._pen(theme.STATUS_COLORS[theme.ERROR], 2.0))
            elif self._levels is not None and self._levels[k] == NO_ESTIMATE_LEVEL:
                brushes.append(self._brush("#FFFFFF00"))
                pens.append(self._pen(theme.SIDE_COLORS[side], 1.5))
            else:
                level = float(self._levels[k]) if self._levels is not None else 0.0
                brushes.append(self._brush(theme.force_color(level / FORCE_LEVELS * self._full_scale_n,
                                                             self._full_scale_n)))
                pens.append(self._pen(theme.SIDE_COLORS[side], 1.5))
        cached = self._sensor_style_cache[key] = (brushes, pens)
        return cached

    def _brush(self, color: str):
        brush = self._brush_cache.get(color)
        if brush is None:
            if len(color) == 9:  # #RRGGBBAA
                brush = pg.mkBrush(theme.qcolor(color[:7], int(color[7:], 16)))
            else:
                brush = pg.mkBrush(color)
            self._brush_cache[color] = brush
        return brush

    def _pen(self, color: str, width: float):
        key = (color, width)
        pen = self._pen_cache.get(key)
        if pen is None:
            pen = self._pen_cache[key] = pg.mkPen(color, width=width)
        return pen

    def _draw_sensors(self, positions: bool = True) -> None:
        """Draw the sensors: where they are (``positions``, after the pose changed) and their colours; with
        ``positions`` False only the brushes and pens are swapped (the points keep their place)."""
        self.sensor_redraws += 1
        n = len(self._axes)
        sensors = sensor_points(self._present_pose, radius_m=0.02) if positions else None
        for view in VIEWS:
            sides = (2,) if view == "side" else (0, 1)
            index = np.array([3 * seg + s for seg in range(n) for s in sides])
            brushes, pens = self._sensor_style(view, index)
            item = self._sensor_items[view]
            if sensors is None and len(item.data) == len(index):
                item.setPen(pens, update=False)
                item.setBrush(brushes)
                continue
            if sensors is None:
                sensors = sensor_points(self._present_pose, radius_m=0.02)
            cols = [0, 2] if view == "side" else [0, 1]
            item.setData(pos=sensors[index][:, cols], brush=brushes, pen=pens)

    # -- dragging --------------------------------------------------------------------------------------------------
    def begin_drag(self, view: str, press: QPointF, box: pg.ViewBox) -> None:
        pts = self.body_points(view)
        press_scene = box.mapViewToScene(press)
        distances = [
            (box.mapViewToScene(QPointF(float(x), float(y))) - press_scene).manhattanLength() for x, y in pts[1:]
        ]
        nearest = int(np.argmin(distances))
        if distances[nearest] > GRAB_RADIUS_PX * 2:
            self._drag = None
            return
        point = nearest + 1
        bending = "pitch" if view == "side" else "yaw"
        candidates = [j for j in range(point) if self._axes[j] == bending]
        self._drag = (candidates[-1], point) if candidates else None

    def drag_to(self, view: str, position: QPointF) -> None:
        if self._drag is None:
            return
        joint, point = self._drag
        angle = bend_for_point(self._present, self._axes, joint, (position.x(), position.y()), view,
                               self._length_m, point_index=point)
        self.joint_dragged.emit(joint, angle)

    def end_drag(self) -> None:
        if self._drag is not None:
            self._drag = None
            self.drag_finished.emit()
