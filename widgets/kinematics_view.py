"""KinematicsView: live motion capture — a side view of the motion-captured body, and each segment's position against
time (the paper's Fig. 6D/7A).

A passive view: the owner gives it the newest segment centres and markers (:meth:`KinematicsView.show_body`) and the
history of the centres (:meth:`KinematicsView.show_positions`), both in metres, the history on the owner's clock in
seconds; a segment without a pose (NaN) is a gap, never filled. One colour per segment, head dark to tail light
(:func:`segment_colour`, the same as ``scripts/kinematics_figure.py``). Redrawn with ``setData`` by the owner's timer,
never per sample. GUI thread only.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Signal
from PySide6.QtWidgets import QComboBox, QHBoxLayout, QLabel, QVBoxLayout, QWidget

from widgets import theme

MOCAP_COLOR = "#0072B2"  # the motion-captured body, as in the 3-D replay (widgets.replay_view)
COORDINATES = (("x", "forward position x"), ("y", "lateral position y"), ("z", "height z"))


def segment_colour(k: int, n: int) -> tuple[int, int, int]:
    """Segment ``k`` (0 = head) of ``n``: dark purple through viridis to yellow-green (its palest yellow left out:
    white paper)."""
    rgba = pg.colormap.get("viridis").map(0.88 * k / max(n - 1, 1), mode="byte")
    return (int(rgba[0]), int(rgba[1]), int(rgba[2]))


class KinematicsView(QWidget):
    """See the module docstring. ``coordinate_changed(str)``: "x" or "z", the user's choice."""

    coordinate_changed = Signal(str)

    def __init__(self, n_segments: int, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.n_segments = n_segments
        self.coordinate = "x"
        self.frames_drawn = 0
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        bar = QHBoxLayout()
        self.status = QLabel("")
        self.status.setWordWrap(True)
        bar.addWidget(self.status, 1)
        bar.addWidget(QLabel("Plot"))
        self.coordinate_combo = QComboBox()
        for key, text in COORDINATES:
            self.coordinate_combo.addItem(text, key)
        self.coordinate_combo.currentIndexChanged.connect(self._coordinate_picked)
        bar.addWidget(self.coordinate_combo)
        layout.addLayout(bar)

        self.body_plot = pg.PlotWidget(title="motion capture, side view (x forward, z up)")
        self.body_plot.setBackground("w")
        self.body_plot.setAspectLocked(True)
        self.body_plot.setMenuEnabled(False)
        for side, text in (("bottom", "x (m)"), ("left", "z (m)")):
            self.body_plot.setLabel(side, text)
            theme.no_si_prefix(self.body_plot.getAxis(side))
        self._ground = pg.PlotDataItem(pen=pg.mkPen("#B0B0B0", width=1))
        self._body = pg.PlotDataItem(pen=pg.mkPen(MOCAP_COLOR, width=3), connect="finite")
        self._centres = pg.ScatterPlotItem(size=8, pen=pg.mkPen("w", width=1), brush=pg.mkBrush(MOCAP_COLOR))
        self._markers = pg.ScatterPlotItem(size=4, pen=None, brush=pg.mkBrush(MOCAP_COLOR))
        for item in (self._ground, self._body, self._centres, self._markers):
            self.body_plot.addItem(item)
        layout.addWidget(self.body_plot, 2)

        self.time_plot = pg.PlotWidget()
        self.time_plot.setBackground("w")
        self.time_plot.setMenuEnabled(False)
        self.time_plot.setLabel("bottom", "time (s)")
        theme.no_si_prefix(self.time_plot.getAxis("bottom"))
        theme.no_si_prefix(self.time_plot.getAxis("left"))
        self._curves = []
        for k in range(n_segments):
            curve = self.time_plot.plot(pen=pg.mkPen(segment_colour(k, n_segments), width=2), connect="finite")
            curve.setClipToView(True)
            curve.setDownsampling(auto=True, method="peak")
            self._curves.append(curve)
        layout.addWidget(self.time_plot, 3)
        self._set_titles()

    def _coordinate_picked(self, index: int) -> None:
        self.coordinate = str(self.coordinate_combo.itemData(index))
        self._set_titles()
        self.coordinate_changed.emit(self.coordinate)

    def _set_titles(self) -> None:
        word = dict(COORDINATES)[self.coordinate]
        self.time_plot.setTitle(f"each segment's {word} (head dark → tail light)")
        self.time_plot.setLabel("left", f"segment centre {self.coordinate} (m)")

    def set_status(self, text: str, level: str = theme.OK) -> None:
        """The line above the plots: where the motion capture comes from, how it fares."""
        if self.status.text() != text:
            self.status.setText(text)
        style = theme.status_style(level)
        if self.status.styleSheet() != style:
            self.status.setStyleSheet(style)

    def show_body(self, centers_m: np.ndarray | None, markers_m: np.ndarray | None) -> None:
        """The newest pose, side view: segment centres (S, 3) joined head to tail, markers (…, 3) as dots."""
        if centers_m is None or markers_m is None:
            for item in (self._body, self._centres, self._markers, self._ground):
                item.setData([], [])
            return
        centers = np.asarray(centers_m, dtype=float)
        markers = np.asarray(markers_m, dtype=float).reshape(-1, 3)
        markers = markers[np.isfinite(markers).all(axis=1)]
        self._body.setData(centers[:, 0], centers[:, 2])
        posed = centers[np.isfinite(centers).all(axis=1)]
        self._centres.setData(posed[:, 0], posed[:, 2])
        self._markers.setData(markers[:, 0], markers[:, 2])
        seen = np.concatenate([posed[:, 0], markers[:, 0]])
        if seen.size:
            self._ground.setData([seen.min() - 0.1, seen.max() + 0.1], [0.0, 0.0])
        self.frames_drawn += 1

    def show_positions(self, time_s: np.ndarray, centers_m: np.ndarray) -> None:
        """Each segment's centre (N, S, 3) at ``time_s`` (N,): the chosen coordinate against time."""
        axis = "xyz".index(self.coordinate)
        times = np.asarray(time_s, dtype=float)
        centers = np.asarray(centers_m, dtype=float)
        for k, curve in enumerate(self._curves):
            if k < centers.shape[1] and times.size:
                curve.setData(times, centers[:, k, axis])
            else:
                curve.setData([], [])
