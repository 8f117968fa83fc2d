"""ReplayView: a recording's robot in 3-D on a timeline — scrub, play, pause, speed, step frame by frame — with the
contact forces drawn on the body.

A passive view: the owner gives it the timeline (:meth:`ReplayView.set_timeline`), the time shown and the bodies to
draw (:meth:`ReplayView.show_frame`: points in metres, head tip first; sensor centres and their forces in N) and
listens to what the user asks (:attr:`time_requested`, :attr:`play_toggled`, :attr:`step_requested`,
:attr:`speed_changed`). The 3-D scene is projected orthographically onto a pyqtgraph plot (it needs no OpenGL, so it
draws on any machine and under test); the camera turns with the azimuth and elevation sliders or the presets. Forces
are drawn as arrows pushing into the body at each sensor, their length to the scale shown, and as the sensor's
colour. One ``setData`` per drawn item per frame. GUI thread only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSlider,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

SPEEDS = (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
SLIDER_STEPS_PER_S = 1000  # the time slider's resolution: 1 ms
BODY_COLORS = {"sim": "#222222", "mocap": "#0072B2", "commanded": "#7F7F7F"}
BODY_WIDTHS = {"sim": 7, "mocap": 3, "commanded": 5}  # the motion-captured body drawn thin over the simulated one
BODY_LABELS = {"sim": "simulated", "mocap": "motion capture", "commanded": "commanded"}
VIEW_PRESETS = {"3/4": (-60.0, 25.0), "Side": (-90.0, 0.0), "Top": (-90.0, 89.0), "Front": (0.0, 10.0)}
ARROW_M_PER_N = 0.01  # an arrow 1 cm long per newton (the scale bar says so)
FORCE_FULL_SCALE_N = 5.0  # the colour reaches full red here
GROUND_HALF_WIDTH_M = 0.3


def camera_axes(azimuth_deg: float, elevation_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The screen's right and up directions in the world (x forward, y left, z up) for a camera at ``azimuth_deg``
    about z (0: looking from the front, −90: from the robot's right side) and ``elevation_deg`` above the ground."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    toward_camera = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.cross([0.0, 0.0, 1.0], toward_camera)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([0.0, -1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(toward_camera, right)
    return right, up


def force_colors(forces_n: np.ndarray, full_scale_n: float = FORCE_FULL_SCALE_N) -> list[pg.QtGui.QBrush]:
    """Each force's brush: light grey at 0 N to dark red at ``full_scale_n`` and above (the body map's colours)."""
    zero_color, full_color = theme.qcolor(theme.FORCE_ZERO_COLOR), theme.qcolor(theme.FORCE_FULL_COLOR)
    zero = np.array([zero_color.red(), zero_color.green(), zero_color.blue()], dtype=float)
    full = np.array([full_color.red(), full_color.green(), full_color.blue()], dtype=float)
    fraction = np.clip(np.nan_to_num(forces_n) / full_scale_n, 0.0, 1.0)[:, None]
    rgb = (zero + fraction * (full - zero)).astype(int)
    return [pg.mkBrush(int(r), int(g), int(b)) for r, g, b in rgb]


class ReplayView(QWidget):
    """See the module docstring."""

    time_requested = Signal(float)  # the user moved the time slider (s on the recording's clock)
    play_toggled = Signal(bool)
    step_requested = Signal(int)  # -1 / +1: one frame back / forward
    speed_changed = Signal(float)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._start_s = 0.0
        self._end_s = 0.0
        self._azimuth, self._elevation = VIEW_PRESETS["3/4"]
        self._last: tuple[Sequence[tuple[str, np.ndarray]], np.ndarray | None, np.ndarray | None] = ((), None, None)
        self.frames_drawn = 0

        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.title = QLabel("")
        self.title.setWordWrap(True)
        layout.addWidget(self.title)

        self.plot = pg.PlotWidget()
        self.plot.setBackground("w")
        self.plot.setAspectLocked(True)
        self.plot.hideAxis("left")
        self.plot.hideAxis("bottom")
        self.plot.setMenuEnabled(False)
        self.plot.setAntialiasing(True)
        self._ground = pg.PlotDataItem(pen=pg.mkPen("#D0D0D0", width=1), connect="pairs")
        self.plot.addItem(self._ground)
        self._arrows = pg.PlotDataItem(pen=pg.mkPen(theme.FORCE_FULL_COLOR, width=2), connect="pairs")
        self.plot.addItem(self._arrows)
        self._bodies: dict[str, pg.PlotDataItem] = {}
        for source, color in BODY_COLORS.items():
            item = pg.PlotDataItem(pen=pg.mkPen(color, width=BODY_WIDTHS[source]), symbol="o", symbolSize=6,
                                   connect="finite",
                                   symbolBrush=pg.mkBrush(color), symbolPen=None,
                                   name=BODY_LABELS[source])
            self.plot.addItem(item)
            self._bodies[source] = item
        self._sensors = pg.ScatterPlotItem(size=9, pen=pg.mkPen("#555555", width=0.5))
        self.plot.addItem(self._sensors)
        self.legend = QLabel("")
        self.bodies_legend = QLabel("")
        layout.addWidget(self.bodies_legend)
        layout.addWidget(self.plot, 1)

        camera = QHBoxLayout()
        camera.addWidget(QLabel("View"))
        for name in VIEW_PRESETS:
            button = QToolButton()
            button.setText(name)
            button.clicked.connect(lambda _c=False, n=name: self.set_camera(*VIEW_PRESETS[n]))
            camera.addWidget(button)
        camera.addWidget(QLabel("azimuth"))
        self.azimuth_slider = QSlider(Qt.Orientation.Horizontal)
        self.azimuth_slider.setRange(-180, 180)
        self.azimuth_slider.valueChanged.connect(self._camera_moved)
        camera.addWidget(self.azimuth_slider, 1)
        camera.addWidget(QLabel("elevation"))
        self.elevation_slider = QSlider(Qt.Orientation.Horizontal)
        self.elevation_slider.setRange(0, 89)
        self.elevation_slider.valueChanged.connect(self._camera_moved)
        camera.addWidget(self.elevation_slider, 1)
        camera.addWidget(self.legend)
        layout.addLayout(camera)

        bar = QHBoxLayout()
        self.back_button = QToolButton()
        self.back_button.setText("◀|")
        self.back_button.setToolTip("one frame back")
        self.back_button.clicked.connect(lambda: self.step_requested.emit(-1))
        bar.addWidget(self.back_button)
        self.play_button = QPushButton("Play")
        self.play_button.setCheckable(True)
        self.play_button.toggled.connect(self._play_toggled)
        bar.addWidget(self.play_button)
        self.forward_button = QToolButton()
        self.forward_button.setText("|▶")
        self.forward_button.setToolTip("one frame forward")
        self.forward_button.clicked.connect(lambda: self.step_requested.emit(1))
        bar.addWidget(self.forward_button)
        self.slider = QSlider(Qt.Orientation.Horizontal)
        self.slider.setTracking(True)
        self.slider.valueChanged.connect(self._slider_moved)
        bar.addWidget(self.slider, 1)
        self.time_label = QLabel("")
        self.time_label.setMinimumWidth(150)
        bar.addWidget(self.time_label)
        bar.addWidget(QLabel("speed"))
        self.speed_combo = QComboBox()
        for speed in SPEEDS:
            self.speed_combo.addItem(f"{speed:g}×", speed)
        self.speed_combo.setCurrentIndex(SPEEDS.index(1.0))
        self.speed_combo.currentIndexChanged.connect(lambda i: self.speed_changed.emit(float(SPEEDS[i])))
        bar.addWidget(self.speed_combo)
        layout.addLayout(bar)
        self._setting_slider = False
        self.set_camera(*VIEW_PRESETS["3/4"])

    # -- timeline --------------------------------------------------------------------------------------------------
    def set_timeline(self, start_s: float, end_s: float, title: str) -> None:
        """The recording's span (s on its clock) and a line naming what is shown."""
        self._start_s, self._end_s = float(start_s), float(max(end_s, start_s))
        self._setting_slider = True
        self.slider.setRange(0, int(round((self._end_s - self._start_s) * SLIDER_STEPS_PER_S)))
        self._setting_slider = False
        self.title.setText(title)
        self.set_time(start_s)

    def set_time(self, t_s: float) -> None:
        """Move the slider and the label to ``t_s`` (no :attr:`time_requested`)."""
        self._setting_slider = True
        self.slider.setValue(int(round((t_s - self._start_s) * SLIDER_STEPS_PER_S)))
        self._setting_slider = False
        self.time_label.setText(f"{t_s:8.3f} s / {self._end_s:.1f} s")

    def set_playing(self, playing: bool) -> None:
        self.play_button.blockSignals(True)
        self.play_button.setChecked(playing)
        self.play_button.blockSignals(False)
        self.play_button.setText("Pause" if playing else "Play")

    @property
    def speed(self) -> float:
        return float(SPEEDS[self.speed_combo.currentIndex()])

    def set_speed(self, speed: float) -> None:
        self.speed_combo.setCurrentIndex(min(range(len(SPEEDS)), key=lambda i: abs(SPEEDS[i] - speed)))

    def _slider_moved(self, value: int) -> None:
        if not self._setting_slider:
            t_s = self._start_s + value / SLIDER_STEPS_PER_S
            self.time_label.setText(f"{t_s:8.3f} s / {self._end_s:.1f} s")
            self.time_requested.emit(t_s)

    def _play_toggled(self, on: bool) -> None:
        self.play_button.setText("Pause" if on else "Play")
        self.play_toggled.emit(on)

    # -- camera ----------------------------------------------------------------------------------------------------
    def set_camera(self, azimuth_deg: float, elevation_deg: float) -> None:
        for slider, value in ((self.azimuth_slider, azimuth_deg), (self.elevation_slider, elevation_deg)):
            slider.blockSignals(True)
            slider.setValue(int(round(value)))
            slider.blockSignals(False)
        self._azimuth, self._elevation = float(azimuth_deg), float(elevation_deg)
        self._redraw(refit=True)

    def _camera_moved(self, _value: int) -> None:
        self._azimuth, self._elevation = float(self.azimuth_slider.value()), float(self.elevation_slider.value())
        self._redraw(refit=True)

    def _project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        right, up = camera_axes(self._azimuth, self._elevation)
        return points @ right, points @ up

    # -- drawing ---------------------------------------------------------------------------------------------------
    def show_frame(self, bodies: Sequence[tuple[str, np.ndarray]], sensors_m: np.ndarray | None = None,
                   forces_n: np.ndarray | None = None, refit: bool = False) -> None:
        """Draw ``bodies`` ((source, points (n+1, 3)), … with source "sim", "mocap" or "commanded"), and at
        ``sensors_m`` (C, 3) the forces ``forces_n`` (C,) as colours and arrows (None: no forces)."""
        self._last = (tuple(bodies), sensors_m, forces_n)
        self._redraw(refit=refit)
        self.frames_drawn += 1

    def _redraw(self, refit: bool = False) -> None:
        bodies, sensors, forces = self._last
        shown = {source for source, _points in bodies}
        all_points = [np.asarray(points, float) for _source, points in bodies]
        for source, points in bodies:
            u, v = self._project(np.asarray(points, float))
            self._bodies[source].setData(u, v)
        for source, item in self._bodies.items():
            if source not in shown:
                item.setData([], [])
        legend = " ".join(f'<span style="color:{BODY_COLORS[s]}">━━</span> {BODY_LABELS[s]}'
                          for s in BODY_COLORS if s in shown)
        if self.bodies_legend.text() != legend:
            self.bodies_legend.setText(legend)
        if sensors is not None and forces is not None and len(sensors) == len(forces) and bodies:
            sensors = np.asarray(sensors, float)
            forces = np.nan_to_num(np.asarray(forces, float))
            body = np.asarray(bodies[0][1], float)
            axis_points = np.repeat(0.5 * (body[:-1] + body[1:]), 3, axis=0)[: len(sensors)]
            outward = sensors - axis_points
            outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-12)
            pressed = forces > 0.05
            tails = sensors + outward * (np.clip(forces, 0.0, None) * ARROW_M_PER_N)[:, None]
            pairs = np.empty((2 * int(pressed.sum()), 3))
            pairs[0::2], pairs[1::2] = tails[pressed], sensors[pressed]
            u, v = self._project(pairs)
            self._arrows.setData(u, v)
            su, sv = self._project(sensors)
            self._sensors.setData(su, sv, brush=force_colors(forces))
            self.legend.setText(f"forces: colour 0 → {FORCE_FULL_SCALE_N:g} N, arrow 1 cm per N "
                                f"(peak {forces.max(initial=0.0):.2f} N)")
        else:
            self._arrows.setData([], [])
            self._sensors.setData([], [])
            self.legend.setText("no contact forces in this recording" if bodies else "")
        ground = self._ground_lines(all_points)
        if ground is not None:
            u, v = self._project(ground)
            self._ground.setData(u, v)
        if refit and all_points:
            self.plot.autoRange(padding=0.08)

    def _ground_lines(self, bodies: list[np.ndarray]) -> np.ndarray | None:
        """A grid on the ground (z = 0) around the bodies, 10 cm apart, as line pairs."""
        if not bodies:
            return None
        stacked = np.concatenate(bodies)
        stacked = stacked[np.isfinite(stacked).all(axis=1)]  # a motion-capture frame may lack a segment
        if not stacked.size:
            return None
        x0, x1 = math.floor(stacked[:, 0].min() * 10 - 2) / 10, math.ceil(stacked[:, 0].max() * 10 + 2) / 10
        y0, y1 = math.floor(stacked[:, 1].min() * 10 - 2) / 10, math.ceil(stacked[:, 1].max() * 10 + 2) / 10
        lines = [((x, y0, 0.0), (x, y1, 0.0)) for x in np.arange(x0, x1 + 1e-9, 0.1)]
        lines += [((x0, y, 0.0), (x1, y, 0.0)) for y in np.arange(y0, y1 + 1e-9, 0.1)]
        return np.asarray(lines, float).reshape(-1, 3)
