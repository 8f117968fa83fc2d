"""Per-segment force plots: a scrollable grid of collapsible pyqtgraph plots, one per segment (L/R/B traces).

Passive view: it draws a :class:`widgets.ring_plot.TraceHistory` it is given and emits signals; it knows nothing of
boards or recordings. Drawing follows pyqtgraph's rules for dense live data, measured and tightened for this grid:
one QTimer (≤ 60 Hz) redraws, and only when new data arrived or the view changed; clipping to the view and peak
(min/max) downsampling happen once per redraw in ``TraceHistory.window()`` for all drawn channels, at one bucket per
pixel column, so drawing cost does not grow with the session length; antialiasing off; each plot's traces are drawn
by one fixed-bounds item (:class:`_TraceBundle`) instead of one PlotCurveItem each (5× cheaper per frame); axes are
painted from pixmap caches and legends are strips of text in each plot's header, outside the data; live, the x axis is "seconds
before the newest sample" so no axis is regenerated per frame. Collapsed plots, hidden traces and plots scrolled out
of view are not redrawn at all.
Benchmark: ``benchmarks/bench_forces_gui.py``.

Layout: the plots fill the grid's view. When every row fits at a readable height (the 12 segments at the default
window size, 4 columns by 3 rows), all of them are on screen at once and grow with the window; when they do not
(a 1024-channel board's 64 plots, a small window) each plot keeps a fixed height and the grid scrolls, and a plot
scrolled out of view is really hidden (``isVisible()`` false: nothing paints it, nothing counts it as on screen) until it
is scrolled back in, when it is shown and drawn at once.

Interaction: the plots follow the newest data (live) until the user pauses, drags, zooms or scrolls back with the
scroll bar; the readout under the mouse shows every trace's value at the cursor and keeps updating while streaming.

GUI thread only.
"""

from __future__ import annotations

import html
import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QEvent, QLineF, QPointF, QRectF, Qt, QTimer, Signal
from PySide6.QtGui import QFont, QPainterPath, QPolygonF, QShowEvent, QTextDocument
from PySide6.QtWidgets import (
    QGraphicsItem,
    QGraphicsWidget,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QMenu,
    QScrollArea,
    QScrollBar,
    QSizePolicy,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from widgets.image_export import IMAGE_FORMATS, save_widget_image
from widgets.ring_plot import TraceHistory
from widgets.theme import no_si_prefix

try:  # the shell engineer's shared palette; the fallback keeps this view usable on its own
    from widgets.theme import SIDE_COLORS, STATUS_COLORS
except ImportError:  # pragma: no cover - only while widgets/theme.py is absent
    SIDE_COLORS = {"L": "#0072B2", "R": "#D55E00", "B": "#009E73"}
    STATUS_COLORS = {"ok": "#1B7F3B", "warn": "#B36B00", "error": "#C62828", "idle": "#6B6B6B"}

MAX_REDRAW_HZ = 60.0
DEFAULT_REDRAW_HZ = 30.0
PLOT_HEIGHT_PX = 170  # a plot's height when the grid scrolls (the rows do not all fit)
FIT_MIN_PLOT_HEIGHT_PX = 120  # the rows are fitted to the view (no scrolling) only if each plot gets this much
MIN_PLOT_WIDTH_PX = 200  # columns: as many as fit at this width, up to MAX_COLUMNS
MAX_COLUMNS = 4
SCROLL_MAX_COLUMNS = 3  # when the plots do not all fit and the grid scrolls
LIVE_TIME_LABEL = "time before newest"  # + " (s)": fits under a 200-px plot (the longer "… sample (s)" was cut off)
# Smallest y range shown, per unit: an unloaded sensor's sub-mN wiggle drawn across a whole plot reads as a load
# (seen in the lab walkthrough: "0.0005 N" full scale). 0.1 N is the body map's step; conductance keeps a tiny floor.
MIN_Y_SPAN = {"N": 0.1}
DEFAULT_MIN_Y_SPAN = 1e-3
SCROLL_STEPS = 10_000
PEN_PAD_PX = 2.0  # a trace's bounds reach this far past its data (the pen and rounding)
BUCKETS_PER_PIXEL = 1.0  # history buckets per plot pixel (each drawn as its low and high)
AXIS_COLOR = "#444444"
OTHER_UNITS_COLOR = "#7A5C00"  # the right-hand axis (uncalibrated sensors' µS): told apart from the plot's own
OTHER_COLORS = ("#444444", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442")

_SEGMENT_NAME = re.compile(r"^S(\d+)([A-Za-z])$")


@dataclass(frozen=True)
class PlotGroup:
    """One plot: a title and the channel indices (into the history) it draws, with their names."""

    title: str
    channels: tuple[int, ...]
    names: tuple[str, ...]


def groups_from_names(names: Sequence[str], per_plot: int | None = None) -> list[PlotGroup]:
    """Group channels by segment (``S06L S06R S06B`` → "Segment 6"); other names go ``per_plot`` to a plot
    (default 3, or 16 when there are more than 48 of them, so a 1024-channel board makes 64 plots, not 342)."""
    by_segment: dict[int, list[int]] = {}
    others: list[int] = []
    for i, name in enumerate(names):
        match = _SEGMENT_NAME.match(name)
        if match:
            by_segment.setdefault(int(match.group(1)), []).append(i)
        else:
            others.append(i)
    groups = [PlotGroup(f"Segment {seg}", tuple(idx), tuple(names[i] for i in idx))
              for seg, idx in sorted(by_segment.items())]
    if per_plot is None:
        per_plot = 3 if len(others) <= 48 else 16
    for start in range(0, len(others), per_plot):
        idx = others[start:start + per_plot]
        groups.append(PlotGroup(f"Channels {idx[0]}–{idx[-1]}", tuple(idx), tuple(names[i] for i in idx)))
    return groups


def trace_color(name: str, position: int) -> str:
    """Colour of a trace: by sensor side (L/R/B) when the name ends in one, else by position in its plot."""
    side = name[-1:].upper()
    return SIDE_COLORS.get(side, OTHER_COLORS[position % len(OTHER_COLORS)])


def side_of(name: str) -> str:
    side = name[-1:].upper()
    return side if side in SIDE_COLORS else ""


def native_geometry(item: QGraphicsWidget) -> None:
    """Let Qt take ``item``'s boundingRect and shape from C++ (its geometry), not from pyqtgraph's Python overrides.

    Qt asks every item in a repainted area for its bounds on every paint; pyqtgraph's GraphicsWidget answers in
    Python (the same rect, from its geometry), about 12 calls per plot per frame in the live grid. A bound C++ method
    set on the instance is found by PySide's virtual-call lookup and is not a Python method, so Qt calls C++ directly.
    Only for items whose pyqtgraph override returns exactly the C++ rect (plain GraphicsWidgets: the plot item, the
    legend, its samples and labels; not axes or view boxes, which pad theirs)."""
    item.boundingRect = QGraphicsWidget.boundingRect.__get__(item)  # type: ignore[method-assign]
    item.shape = QGraphicsWidget.shape.__get__(item)  # type: ignore[method-assign]


def cache_subtree(item: QGraphicsItem) -> None:
    """Paint ``item`` and its children from a device pixmap (GUI thread): axes repaint only when they change."""
    item.setCacheMode(QGraphicsItem.CacheMode.DeviceCoordinateCache)
    for child in item.childItems():
        cache_subtree(child)


class _ElidedLabel(QLabel):
    """A one-line label that never widens its column: text that does not fit is replaced by its ``short`` form (e.g.
    only the sensor names), and that ends in "…" if it does not fit either; the whole text is in the tooltip (a plot
    header's sensor warning; the Forces tab's health list shows it in full too). ``text()`` is the whole text."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._full = ""
        self._short = ""
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)

    def setText(self, text: str, short: str = "") -> None:  # noqa: N802 - Qt override
        self._full = text
        self._short = short or text
        self.setToolTip(text)
        self._elide()

    def text(self) -> str:
        return self._full

    def resizeEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().resizeEvent(event)
        self._elide()

    def _elide(self) -> None:
        metrics, width = self.fontMetrics(), max(0, self.width())
        text = self._full if metrics.horizontalAdvance(self._full) <= width else self._short
        shown = metrics.elidedText(text, Qt.TextElideMode.ElideRight, width)
        if shown != super().text():
            super().setText(shown)


class _Trace(pg.PlotDataItem):
    """One trace's legend entry, pen and visibility (the legend toggles it). It is never added to the plot: the
    plot's :class:`_TraceBundle` draws every trace. ``xData``/``yData`` are what was drawn last (view x)."""

    def __init__(self, pen, name: str) -> None:
        super().__init__(pen=pen, name=name)
        self.drawn_x: np.ndarray | None = None  # what the plot drew last (the bundle draws it; set by the grid)
        self.drawn_y: np.ndarray | None = None

    @property
    def xData(self) -> np.ndarray | None:  # noqa: N802 - pyqtgraph's attribute name
        return self.drawn_x

    @property
    def yData(self) -> np.ndarray | None:  # noqa: N802 - pyqtgraph's attribute name
        return self.drawn_y


class _Legend(QLabel):
    """A plot's legend: a strip in the plot's header, one entry per trace (a line in the trace's colour and style,
    then its label) side by side — never over the data. A click on an entry shows or hides that trace; a hidden one
    is greyed. When the labels do not fit the strip's width, each entry is shortened to the trace's name (and its
    unit when it is on the right-hand axis); the full labels are in the tooltip.

    It sits in the header, outside the plot, so a repaint of the traces never repaints it: plain rich text is enough
    (it was a translucent pixmap when it lay over the data). For an image export, :meth:`overlay_html` gives the
    same entries one per line, drawn over the plot's top-left corner in the exported picture."""

    HIDDEN_COLOR = "#AAAAAA"

    def __init__(self, parent: QWidget, traces: Sequence[_Trace], labels: Sequence[str],
                 names: Sequence[str] | None = None) -> None:
        super().__init__(parent)
        self._traces = list(traces)
        self._labels = list(labels)
        self._names = list(names) if names is not None else list(labels)
        self._short_units: list[str] = [""] * len(self._traces)  # a unit shown beside a shortened entry
        self.html = ""
        self.short = False
        self._font = QFont(self.font())
        self._font.setPointSizeF(8.0)
        self.setFont(self._font)
        self.setTextFormat(Qt.TextFormat.RichText)
        self.setCursor(Qt.CursorShape.PointingHandCursor)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Fixed)
        self.setMinimumWidth(0)
        self.linkActivated.connect(lambda href: self.toggle(int(href)))
        for trace in self._traces:
            trace.visibleChanged.connect(self.render_entries)
        self.render_entries()

    def labels(self) -> list[str]:
        return list(self._labels)

    def set_labels(self, labels: Sequence[str]) -> None:
        self._labels = list(labels)
        self.render_entries()

    def set_short_units(self, units: Sequence[str]) -> None:
        """Per trace, a unit to name in a shortened entry (``""``: the plot's own unit, none shown)."""
        if list(units) != self._short_units:
            self._short_units = list(units)
            self.render_entries()

    def toggle(self, index: int) -> None:
        """Show or hide trace ``index`` (what a click on its entry does)."""
        trace = self._traces[index]
        trace.setVisible(not trace.isVisible())

    def _entries(self, texts: Sequence[str], links: bool) -> list[str]:
        entries = []
        for index, (trace, text) in enumerate(zip(self._traces, texts)):
            pen = trace.opts["pen"]
            shown = trace.isVisible()
            color = pen.color().name() if shown else self.HIDDEN_COLOR
            glyph = "━━" if pen.style() == Qt.PenStyle.SolidLine else "┅┅"
            text_color = AXIS_COLOR if shown else self.HIDDEN_COLOR
            body = (f'<span style="color: {color};">{glyph}</span>'
                    f'<span style="color: {text_color};">&nbsp;{html.escape(text)}</span>')
            if links:
                body = f'<a href="{index}" style="text-decoration: none;">{body}</a>'
            entries.append(body)
        return entries

    def _short_texts(self) -> list[str]:
        return [f"{name} {unit}" if unit else name for name, unit in zip(self._names, self._short_units)]

    def _fits(self, markup: str) -> bool:
        document = QTextDocument()
        document.setDefaultFont(self._font)
        document.setDocumentMargin(0.0)
        document.setHtml(markup)
        return document.idealWidth() <= max(1, self.width())

    def overlay_html(self) -> str:
        """The entries one per line (full labels), for a legend drawn over an exported picture."""
        return "<br>".join(self._entries(self._labels, links=False))

    def render_entries(self) -> None:
        """Redraw the entries from the traces' pens, visibility and the labels (call after a pen changes)."""
        spacer = "&nbsp;&nbsp; "
        full = spacer.join(self._entries(self._labels, links=True))
        self.short = not self._fits(full)
        markup = spacer.join(self._entries(self._short_texts(), links=True)) if self.short else full
        self.setToolTip("Click a name to show or hide its trace"
                        + ("<br>" + "<br>".join(html.escape(label) for label in self._labels) if self.short else ""))
        if markup != self.html:
            self.html = markup
            self.setText(markup)

    def resizeEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().resizeEvent(event)
        self.render_entries()


class _TraceBundle(pg.GraphicsObject):
    """Draws all of one plot's traces in a single item whose bounding rect is the drawn data's (plus the pen).

    Why not one PlotCurveItem per trace: each setData there changes the item's geometry (prepareGeometryChange,
    scene index update, bounds from nanmin/nanmax, pixel padding) and that, not the line drawing, is most of the
    frame: 36 PlotCurveItems cost 15–18 ms per frame against ~3 ms for 12 bundles drawing the same paths
    (measured offscreen). Here the bounds come once per frame from the paths Qt already built (C++), and the
    geometry changes only when they do.

    Why bounds from the data and not a huge fixed rect: Qt maps the rect to the view to find what to repaint; at
    ±1e15 that arithmetic overflowed and a real X display repainted the plot ~0.4×/s (offscreen hid it), and any
    fixed rect makes every frame repaint the whole plot, axes and legend included.
    """

    def __init__(self) -> None:
        super().__init__()
        self._lines: list[tuple[object, QPolygonF | QPainterPath | _Segments]] = []
        self._bounds = QRectF()
        self._polygons: dict[int, tuple[QPolygonF, np.ndarray]] = {}  # per trace position: reused buffers
        self._segments: dict[int, _Segments] = {}  # per trace position, for traces with gaps

    def set_traces(self, traces: Sequence[tuple[object, np.ndarray, np.ndarray] | tuple[object, np.ndarray,
                                                                                            np.ndarray, bool]],
                   pad: tuple[float, float] = (0.0, 0.0)) -> None:
        """``(pen, x, y)`` or ``(pen, x, y, finite)`` per trace to draw (view coordinates); NaN breaks a line (a gap
        in the data; ``finite``: the caller already knows there is none). ``pad`` (view units, x and y) widens the
        bounds by the pen's reach: about 2 pixels."""
        lines: list[tuple[object, QPolygonF | QPainterPath | _Segments]] = []
        bounds = QRectF()
        polygons = self._polygons
        for position, trace in enumerate(traces):
            pen, x, y = trace[0], trace[1], trace[2]
            if not x.size:
                continue
            if trace[3] if len(trace) > 3 else np.isfinite(y).all():
                # A polyline straight from the arrays: half the cost of a QPainterPath (no element copy), and its
                # bounds come from C++. Its buffer is reused while the point count stays (most frames).
                held = polygons.get(position)
                if held is None or held[1].shape[0] != x.size:
                    line = pg.functions.create_qpolygonf(x.size)
                    held = (line, pg.functions.ndarray_from_qpolygonf(line))
                    polygons[position] = held
                line, points = held
                points[:, 0] = x
                points[:, 1] = y
            else:
                # Gaps: the segments between neighbouring finite points, drawn by one native call. A QPainterPath of
                # separate runs (pg.arrayToQPath, connect="finite") cost ~3× as much to build, and a live force
                # trace has gaps in most frames (a rejected sample, a skipped frame): with it, building the paths
                # was half of the plots' redraw (2.3-2.7 ms a redraw of 12 plots in the app, 1.2-1.3 ms with
                # segments; drawing them costs ~0.01 ms a plot more).
                held_segments = self._segments.get(position)
                if held_segments is None:
                    held_segments = self._segments[position] = _Segments()
                if not held_segments.set(x, y):
                    continue
                line = held_segments
            lines.append((pen, line))
            bounds = bounds.united(line.boundingRect())
        if not bounds.isNull():
            bounds = bounds.adjusted(-pad[0], -pad[1], pad[0], pad[1])
        self._lines = lines
        if bounds != self._bounds:
            self.prepareGeometryChange()  # Qt repaints the old and the new rect
            self._bounds = bounds
        self.update()

    def boundingRect(self) -> QRectF:  # noqa: N802 - Qt override
        return self._bounds

    def dataBounds(self, ax, frac=1.0, orthoRange=None):  # noqa: N802,N803 - pyqtgraph's auto-range hook
        return (None, None)  # never part of auto-range: the grid sets the ranges itself

    def paint(self, painter, *_args) -> None:
        for pen, line in self._lines:
            painter.setPen(pen)
            if isinstance(line, QPolygonF):
                painter.drawPolyline(line)
            elif isinstance(line, _Segments):
                painter.drawLines(*line.lines.drawargs())
            else:
                painter.drawPath(line)


class _Segments:
    """A trace with gaps as line segments, each joining two neighbouring finite points, in a reused native QLineF
    array (pyqtgraph's ``PrimitiveArray``, drawn by ``QPainter.drawLines`` in one call). A point between two gaps
    draws nothing, as in a path of separate runs."""

    def __init__(self) -> None:
        self.lines = pg.Qt.internals.PrimitiveArray(QLineF, 4)
        self._bounds = QRectF()

    def set(self, x: np.ndarray, y: np.ndarray) -> bool:
        """The segments of (x, y), NaN breaking the line; False when there is none."""
        finite = np.isfinite(x) & np.isfinite(y)
        starts = np.flatnonzero(finite[:-1] & finite[1:])
        if not starts.size:
            return False
        self.lines.resize(starts.size)
        array = self.lines.ndarray()
        array[:, 0] = x[starts]
        array[:, 1] = y[starts]
        array[:, 2] = x[starts + 1]
        array[:, 3] = y[starts + 1]
        x0, x1 = float(min(array[:, 0].min(), array[:, 2].min())), float(max(array[:, 0].max(), array[:, 2].max()))
        y0, y1 = float(min(array[:, 1].min(), array[:, 3].min())), float(max(array[:, 1].max(), array[:, 3].max()))
        self._bounds = QRectF(x0, y0, x1 - x0, y1 - y0)
        return True

    def boundingRect(self) -> QRectF:  # noqa: N802 - as QPolygonF's
        return self._bounds


def _pen_pad(box: pg.ViewBox) -> tuple[float, float]:
    """How far (view units, x and y) a trace's bounds reach past its data in ``box``: PEN_PAD_PX pixels."""
    (x0, x1), (y0, y1) = box.viewRange()
    size = box.size()
    return (PEN_PAD_PX * (x1 - x0) / max(size.width(), 1.0), PEN_PAD_PX * (y1 - y0) / max(size.height(), 1.0))


class _SegmentPlot(QWidget):
    """A collapsible box holding one PlotWidget and its curves."""

    collapsed_changed = Signal(bool)
    image_requested = Signal(str)  # "png" or "svg"

    def __init__(self, group: PlotGroup, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.group = group
        self.channels = np.asarray(group.channels, dtype=np.intp)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(0)
        header = QHBoxLayout()
        self.toggle = QToolButton(self)
        self.toggle.setText(group.title)
        self.toggle.setCheckable(True)
        self.toggle.setChecked(True)
        self.toggle.setArrowType(Qt.ArrowType.DownArrow)
        self.toggle.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.toggle.setAutoRaise(True)
        self.toggle.toggled.connect(self._on_toggled)
        self.warning = _ElidedLabel(self)
        self.warning.setStyleSheet(f"color: {STATUS_COLORS['error']};")
        self.image_button = QToolButton(self)
        self.image_button.setText("Image…")
        self.image_button.setAutoRaise(True)
        self.image_button.setToolTip(f"Save this plot ({group.title}) as an image: PNG, or SVG (vector)")
        self.image_button.setPopupMode(QToolButton.ToolButtonPopupMode.InstantPopup)
        image_menu = QMenu(self.image_button)
        for kind in IMAGE_FORMATS:
            image_menu.addAction(f"Save as {kind.upper()}…", partial(self.image_requested.emit, kind))
        self.image_button.setMenu(image_menu)
        header.addWidget(self.toggle)
        header.addWidget(self.warning, 1)
        header.addWidget(self.image_button)
        layout.addLayout(header)
        self.curves: list[_Trace] = []
        for position, name in enumerate(group.names):
            self.curves.append(_Trace(pg.mkPen(trace_color(name, position), width=1), name))
        # The legend: a strip under the header, outside the data (a legend over the traces hid the newest data
        # or the largest values, whichever corner it took).
        self.legend = _Legend(self, self.curves, group.names, group.names)
        self.legend.setContentsMargins(6, 0, 4, 1)
        layout.addWidget(self.legend)
        self.plot_widget = pg.PlotWidget(self, background="w")
        policy = QSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
        policy.setRetainSizeWhenHidden(True)  # scrolled out of view: hidden, its place in the grid kept
        self.plot_widget.setSizePolicy(policy)
        self.plot_widget.setFixedHeight(PLOT_HEIGHT_PX)
        # Shown only once the grid has placed it inside its view (ForcePlotGrid._update_in_view): a 64-plot grid
        # must not show (polish, lay out, paint) every plot at first.
        self.in_view = False
        self.plot_widget.hide()
        layout.addWidget(self.plot_widget)
        item = self.plot_widget.getPlotItem()
        # Clip-to-view and peak downsampling happen in TraceHistory.window() (once per plot, for the exact view
        # and pixel width), so pyqtgraph's per-curve versions are not used; see the curves below.
        # No grid: pyqtgraph draws grid lines as part of the axis picture, and replaying it costs ~5 ms per plot
        # per frame on a software raster — most of a 30 fps budget for 12 plots.
        item.setMenuEnabled(False)
        item.disableAutoRange()  # x follows the history window, y has its own hysteresis: ForcePlotGrid._fit_y
        item.hideButtons()
        for axis_name in ("left", "bottom"):
            axis = item.getAxis(axis_name)
            axis.setPen(pg.mkPen(AXIS_COLOR))
            axis.setTextPen(pg.mkPen(AXIS_COLOR))
        item.getAxis("left").setWidth(48)

        self.bundle = _TraceBundle()
        item.addItem(self.bundle)
        for plain in (item, item.titleLabel):
            native_geometry(plain)
        # The view box draws nothing itself (no border): Qt need not call its Python paint() every frame.
        item.getViewBox().setFlag(QGraphicsItem.GraphicsItemFlag.ItemHasNoContents, True)
        # Axes rarely change in live mode: paint them (text included, hence every child item) from a pixmap instead
        # of re-rendering them each frame: -20 % frame time measured on 12 plots.
        for cached in (item.getAxis("left"), item.getAxis("bottom")):
            cache_subtree(cached)
        self.cursor_line = pg.InfiniteLine(angle=90, movable=False, pen=pg.mkPen("#888888", style=Qt.PenStyle.DashLine))
        self.cursor_line.setZValue(10)
        self.cursor_line.hide()
        item.addItem(self.cursor_line, ignoreBounds=True)
        # A plain label over the plot, not a scene item: it must stay readable whatever the zoom.
        self.readout = QLabel(self.plot_widget)
        self.readout.setStyleSheet("background: rgba(255,255,255,220); color: #222; border: 1px solid #bbb;"
                                   "font-size: 8pt; padding: 1px 3px;")
        self.readout.hide()
        self._labels = list(group.names)
        self.units = ""  # the left axis's unit (set_units)
        self.alt: tuple[pg.ViewBox, _TraceBundle] | None = None  # right-hand axis for channels in other units
        self.auto_y = True  # off once the user zooms this plot; back on when the view resumes following

    @property
    def viewbox(self) -> pg.ViewBox:
        return self.plot_widget.getPlotItem().getViewBox()

    def other_axis(self, units: str) -> tuple[pg.ViewBox, _TraceBundle]:
        """The right-hand axis (its own view box and trace bundle, same time axis) for the channels of this plot that
        are in ``units`` rather than the plot's: an uncalibrated sensor's µS never share an axis labelled N.
        Created the first time it is needed."""
        if self.alt is None:
            item = self.plot_widget.getPlotItem()
            box = pg.ViewBox(enableMenu=False)
            box.setMouseEnabled(x=False, y=False)
            item.scene().addItem(box)
            item.showAxis("right")
            axis = item.getAxis("right")
            axis.linkToView(box)
            no_si_prefix(axis)
            axis.setPen(pg.mkPen(OTHER_UNITS_COLOR))
            axis.setTextPen(pg.mkPen(OTHER_UNITS_COLOR))
            axis.setWidth(44)
            box.setXLink(self.viewbox)
            bundle = _TraceBundle()
            box.addItem(bundle)

            def follow() -> None:
                box.setGeometry(self.viewbox.sceneBoundingRect())
                box.linkedViewChanged(self.viewbox, box.XAxis)

            self.viewbox.sigResized.connect(follow)
            follow()
            self.alt = (box, bundle)
        box, bundle = self.alt
        item = self.plot_widget.getPlotItem()
        if item.getAxis("right").labelText != units:
            item.setLabel("right", units, color=OTHER_UNITS_COLOR)
        item.showAxis("right")
        box.show()
        return self.alt

    def hide_other_axis(self) -> None:
        if self.alt is not None:
            self.alt[1].set_traces([])
            self.alt[0].hide()
            self.plot_widget.getPlotItem().hideAxis("right")

    def set_units(self, units: str) -> None:
        """The left axis's unit: the grid's, or this plot's channels' own when none of them is in the grid's."""
        if units != self.units:
            self.units = units
            self.plot_widget.setLabel("left", units)

    @property
    def collapsed(self) -> bool:
        return not self.toggle.isChecked()

    def _on_toggled(self, expanded: bool) -> None:
        self.toggle.setArrowType(Qt.ArrowType.DownArrow if expanded else Qt.ArrowType.RightArrow)
        self._apply_shown()
        self.collapsed_changed.emit(not expanded)

    def set_in_view(self, in_view: bool) -> bool:
        """The grid says whether this plot's place is inside its view; returns True when that changed."""
        if in_view == self.in_view:
            return False
        self.in_view = in_view
        self._apply_shown()
        return True

    def _apply_shown(self) -> None:
        """Shown when expanded and in view. Collapsed: its room is freed; scrolled out: its room is kept."""
        expanded = self.toggle.isChecked()
        policy = self.plot_widget.sizePolicy()
        if policy.retainSizeWhenHidden() != expanded:
            policy.setRetainSizeWhenHidden(expanded)
            self.plot_widget.setSizePolicy(policy)
        self.plot_widget.setVisible(expanded and self.in_view)

    def header_height(self) -> int:
        layout = self.layout()
        header = layout.itemAt(0) if layout is not None else None
        height = header.sizeHint().height() if header is not None else 0
        return height + self.legend.sizeHint().height()  # and the legend strip under it

    def set_labels(self, labels: Sequence[str]) -> None:
        if list(labels) == self._labels:
            return
        self._labels = list(labels)
        self.legend.set_labels(labels)

    def on_screen(self, viewport: QWidget | None = None) -> bool:
        """True when the plot is expanded, inside the grid's view and shown (``viewport``: unused, kept for
        callers of the older signature)."""
        return not self.collapsed and self.in_view and self.plot_widget.isVisible()


class _PlotScrollArea(QScrollArea):
    """A scroll area that says when its viewport changes size (the window resized, a scroll bar came or went)."""

    viewport_resized = Signal()

    def viewportEvent(self, event: QEvent) -> bool:  # noqa: N802 - Qt override
        if event.type() == QEvent.Type.Resize:
            self.viewport_resized.emit()
        return super().viewportEvent(event)


class ForcePlotGrid(QWidget):
    """The grid of segment plots over one :class:`TraceHistory`.

    Signals: ``paused_changed(bool)`` when following the newest data stops or resumes (also when the user drags or
    zooms a plot), ``cursor_moved(float)`` with the time (s) under the mouse, ``redrawn()`` after every redraw that
    drew something (tests and benchmarks count these), ``image_requested(int, str)`` when the user asks to save plot
    ``index`` as ``png``/``svg`` (the owner picks the file and calls :meth:`export_image`).
    """

    paused_changed = Signal(bool)
    cursor_moved = Signal(float)
    redrawn = Signal()
    image_requested = Signal(int, str)  # plot index, "png" or "svg": the owner asks where and calls export_image

    def __init__(self, channel_names: Sequence[str], columns: int | None = None,
                 parent: QWidget | None = None, build_plots: bool = True) -> None:
        """``columns``: a fixed number of columns; None (default) chooses them from the view's width.
        ``build_plots=False``: no plot yet; :meth:`add_next_plot` builds them one at a time (~40 ms each), each
        taking on what the grid was told before it existed (units, labels, notes, warnings, hidden sides)."""
        super().__init__(parent)
        self.channel_names = tuple(channel_names)
        self.groups = groups_from_names(self.channel_names)
        self._history: TraceHistory | None = None
        self._units = "N"
        self._channel_units: tuple[str, ...] | None = None  # per channel, when some differ from _units
        self._window_s = 30.0
        self._paused = False
        # Live, the x axis is "seconds before the newest sample": the view range stays put and only the data moves,
        # so no axis is regenerated and no linked view re-laid out per frame (that cost ~50 ms per frame for 12
        # plots). Paused, x is session time. view x + _x_offset_s = session time.
        self._x_offset_s = 0.0
        self._live_range_s: float | None = None
        self._drawn_key: tuple | None = None
        self._hidden_sides: set[str] = set()
        self._hover: tuple[_SegmentPlot, QPointF] | None = None
        self._cursor_s: float | None = None  # a time cursor shared with another view (set_cursor), session time
        self._setting_range = False
        self.redraw_count = 0
        self.last_redraw_s = 0.0
        self._last_refresh_s = 0.0
        self._refresh_posted = False
        self._fixed_columns = columns
        self.columns = 0  # set by _fit_layout
        self.plot_height = PLOT_HEIGHT_PX
        self.fits_view = False  # every plot on screen at once (no scrolling)
        # What the grid was told per channel, for plots built after (add_next_plot).
        self._channel_labels: tuple[str, ...] | None = None
        self._channel_notes: tuple[str, ...] | None = None
        self._channel_warnings: tuple[str, ...] | None = None

        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.scroll_area = _PlotScrollArea(self)
        self.scroll_area.setWidgetResizable(True)
        self.scroll_area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        inner = QWidget(self.scroll_area)
        self._inner = inner
        self._grid = QGridLayout(inner)
        self._grid.setContentsMargins(4, 4, 4, 4)
        self._grid.setHorizontalSpacing(6)
        self._grid.setVerticalSpacing(2)
        self.plots: list[_SegmentPlot] = []
        self._empty_slots: list[QWidget] = []  # the first row's places of plots not built yet (_place)
        for _group in self.groups if build_plots else ():
            self._create_plot()
        self._place(columns or 3)
        self.scroll_area.setWidget(inner)
        # Plots scrolled into view are shown and drawn now (hidden ones are not redrawn); a resized view refits.
        self.scroll_area.verticalScrollBar().valueChanged.connect(lambda _v: self._update_in_view())
        self.scroll_area.viewport_resized.connect(self._fit_layout)
        layout.addWidget(self.scroll_area, 1)
        self.time_bar = QScrollBar(Qt.Orientation.Horizontal, self)
        self.time_bar.setRange(0, SCROLL_STEPS)
        self.time_bar.setValue(SCROLL_STEPS)
        self.time_bar.setToolTip("Scroll back through the whole session (moving it pauses the live view)")
        self.time_bar.sliderMoved.connect(self._on_time_bar)
        layout.addWidget(self.time_bar)
        # Every plot's time axis is labelled with its unit: a plot seen on its own (the grid scrolled, one plot
        # exported) must say what its x is. Live the axis does not move, so the cached label costs nothing per frame.
        for plot in self.plots:
            plot.plot_widget.setLabel("bottom", LIVE_TIME_LABEL, units="s")
        self.set_units("N")

        self._timer = QTimer(self)
        self._timer.setInterval(int(1000 / DEFAULT_REDRAW_HZ))
        self._timer.timeout.connect(self.refresh)

    def _create_plot(self) -> _SegmentPlot:
        """The next segment's plot, connected to the grid (its x axis linked to the first plot's)."""
        i = len(self.plots)
        plot = _SegmentPlot(self.groups[i], self._inner)
        self.plots.append(plot)
        plot.collapsed_changed.connect(self._on_collapsed_changed)
        plot.image_requested.connect(lambda kind, index=i: self.image_requested.emit(index, kind))
        plot.viewbox.sigRangeChangedManually.connect(lambda mask, p=plot: self._on_user_range(p, mask))
        for trace in plot.curves:  # a legend click shows/hides a trace: redraw at the next tick
            trace.visibleChanged.connect(self._forget_drawn)
        plot.plot_widget.scene().sigMouseMoved.connect(lambda pos, p=plot: self._on_mouse(p, pos))
        if i:
            plot.plot_widget.setXLink(self.plots[0].plot_widget)
        return plot

    @property
    def plots_pending(self) -> int:
        """Plots not built yet (a grid made with ``build_plots=False``)."""
        return len(self.groups) - len(self.plots)

    def add_next_plot(self) -> bool:
        """Build the next plot of a grid made with ``build_plots=False``, placed and told what the grid was told;
        returns whether plots remain to be built. GUI thread: the Forces tab builds one per turn of the event loop,
        so opening it never holds the window for the whole grid (~0.5 s for 12 plots)."""
        if not self.plots_pending:
            return False
        plot = self._create_plot()
        plot.plot_widget.setLabel("bottom", "time" if self._paused else LIVE_TIME_LABEL, units="s")
        plot.plot_widget.setFixedHeight(self.plot_height)
        channel_units = self._channel_units
        self.set_units(self._units)
        if channel_units is not None:
            self.set_channel_units(channel_units)
        for curve, name in zip(plot.curves, plot.group.names):
            curve.setVisible(side_of(name) not in self._hidden_sides)
        for told, apply in ((self._channel_labels, self.set_channel_labels),
                            (self._channel_notes, self.set_channel_notes),
                            (self._channel_warnings, self.set_channel_warnings)):
            if told is not None:
                apply(told)
        self._place(self.columns or 3)
        self._fit_layout()
        self.invalidate()
        if not self.plots_pending:  # the grid's height held in reserve is let go: which plots are in view, once laid out
            QTimer.singleShot(0, self, self._update_in_view)
        return bool(self.plots_pending)

    # -- layout ----------------------------------------------------------------------------------------------------
    def _place(self, columns: int) -> None:
        """Put the plots in ``columns`` columns (row by row), the spare height below them."""
        grid = self._grid
        for row in range(grid.rowCount()):
            grid.setRowStretch(row, 0)
        for widget in (*self.plots, *self._empty_slots):
            grid.removeWidget(widget)
        for i, plot in enumerate(self.plots):
            grid.addWidget(plot, i // columns, i % columns, Qt.AlignmentFlag.AlignTop)
        # A column of the first row that no plot reaches yet (a grid built one plot at a time) holds an empty widget:
        # an empty column gets no spacing beside it, and its plots would narrow by a few pixels as the row fills.
        while len(self._empty_slots) < columns:
            self._empty_slots.append(QWidget(self._inner))
        for column, slot in enumerate(self._empty_slots):
            empty = len(self.plots) <= column < columns
            if empty:
                grid.addWidget(slot, 0, column)
            slot.setVisible(empty)
        # Shown now (all in their places: showing one lays the grid out), not at the layout's next turn: a plot made
        # after the grid was shown (add_next_plot) is hidden until then, and the layout activated meanwhile
        # (_update_in_view) would count its column empty.
        for plot in self.plots:
            plot.show()
        for column in range(max(columns, grid.columnCount())):
            grid.setColumnStretch(column, 1 if column < columns else 0)
        grid.setRowStretch(-(-len(self.groups) // columns), 1)
        self.columns = columns

    def _fit_layout(self) -> None:
        """Choose the columns from the view's width and the plots' height: every row in view at once when each plot
        gets at least FIT_MIN_PLOT_HEIGHT_PX, else PLOT_HEIGHT_PX each and the grid scrolls. Chosen for every plot
        of the grid, built or not: a grid built one plot at a time puts each where it stays, so adding one never
        resizes the plots already shown (which re-laid out and redrew them all, each step)."""
        if not self.plots:
            return
        viewport = self.scroll_area.viewport()
        grid = self._grid
        margins = grid.contentsMargins()
        spacing = grid.horizontalSpacing()
        usable = viewport.width() - margins.left() - margins.right() + spacing
        count = len(self.groups)
        columns = self._fixed_columns or max(1, min(MAX_COLUMNS, count, usable // (MIN_PLOT_WIDTH_PX + spacing)))
        rows = -(-count // columns)
        room = viewport.height() - margins.top() - margins.bottom() - (rows - 1) * grid.verticalSpacing()
        fitted = room // rows - self.plots[0].header_height() - 1
        self.fits_view = fitted >= FIT_MIN_PLOT_HEIGHT_PX
        if not self.fits_view and not self._fixed_columns:
            # Scrolling anyway: fewer, wider plots (more time resolution; fewer on screen to draw per frame).
            columns = min(columns, SCROLL_MAX_COLUMNS)
        if columns != self.columns:
            self._place(columns)
        height = fitted if self.fits_view else PLOT_HEIGHT_PX
        if height != self.plot_height:
            self.plot_height = height
            for plot in self.plots:
                plot.plot_widget.setFixedHeight(height)
        # While plots are still to be built, the grid is as tall as it will be: the scroll bar it will need is there
        # from the first plot (its coming later would narrow every plot built before it).
        pitch = self.plots[0].sizeHint().height() + grid.verticalSpacing()
        whole = rows * pitch - grid.verticalSpacing() + margins.top() + margins.bottom()
        self._inner.setMinimumHeight(whole if self.plots_pending and not self.fits_view else 0)
        self._update_in_view()

    def _on_collapsed_changed(self, _collapsed: bool) -> None:
        self._update_in_view()  # the plots below it moved
        self.invalidate()  # an expanded plot is drawn at once

    def _update_in_view(self) -> None:
        """Show the plots whose place is inside the scroll area's view, hide the others; draw the newly shown."""
        inner = self.scroll_area.widget()
        if inner is None:
            return
        self._grid.activate()  # the plots' places as they will be shown, not as they were
        view = self.scroll_area.viewport().rect().translated(-inner.pos())
        changed = False
        for plot in self.plots:
            changed |= plot.set_in_view(plot.geometry().intersects(view))
        if changed:
            self.invalidate()

    def shown_plots(self) -> list[int]:
        """Indices of the plots on screen now (expanded, in view, shown)."""
        return [i for i, plot in enumerate(self.plots) if plot.on_screen()]

    def scroll_to_plot(self, index: int) -> None:
        """Scroll the grid so plot ``index`` is in view (it is then shown and drawn)."""
        self.scroll_area.ensureWidgetVisible(self.plots[index], 0, 0)
        self._update_in_view()

    # -- configuration ---------------------------------------------------------------------------------------------
    def export_image(self, index: int, path: str | Path, kind: str | None = None) -> Path:
        """Save plot ``index`` as drawn now (traces, both axes with their units, legend) to ``path``: ``.png`` or
        ``.svg`` (``kind``, by default by the suffix), titled with the segment and the time shown. ValueError /
        OSError name the problem."""
        plot = self.plots[index]
        self.refresh(force=True, include=index)
        x0, x1 = self.visible_range()
        title = f"{plot.group.title} · t = {x0:.2f} … {x1:.2f} s (session time)"
        # The picture stands alone: its legend is drawn over the data area's top-left corner, as text (an SVG
        # keeps it as text), one entry per line with the full labels.
        overlay = QLabel(plot.plot_widget)
        overlay.setTextFormat(Qt.TextFormat.RichText)
        overlay.setStyleSheet("background: rgba(255,255,255,170); font-size: 8pt; padding: 2px;")
        overlay.setText(plot.legend.overlay_html())
        overlay.adjustSize()
        corner = plot.plot_widget.mapFromScene(plot.viewbox.sceneBoundingRect().topLeft())
        overlay.move(corner.x() + 4, corner.y() + 2)
        overlay.show()
        try:
            return save_widget_image(plot.plot_widget, path, title, kind)
        finally:
            overlay.deleteLater()
            overlay.hide()

    def set_history(self, history: TraceHistory | None, units: str | None = None) -> None:
        """Draw ``history`` (channels in the order of ``channel_names``); ``units`` labels the y axes."""
        if history is not None and history.n_channels != len(self.channel_names):
            raise ValueError(f"history has {history.n_channels} channels, the plots {len(self.channel_names)}")
        self._history = history
        if units is not None:
            self.set_units(units)
        self.refresh(force=True)

    @property
    def history(self) -> TraceHistory | None:
        return self._history

    @property
    def units(self) -> str:
        """The plots' y-axis units (see :meth:`set_units`)."""
        return self._units

    def set_units(self, units: str) -> None:
        """Y-axis units, e.g. ``"N"`` or ``"µS"`` (every channel; see :meth:`set_channel_units`)."""
        self._units = units
        self._channel_units = None
        for plot in self.plots:
            plot.hide_other_axis()
            # No automatic SI prefix: it labelled small ranges "N (x0.001)", and neighbouring plots in different
            # scales are misread; every plot stays in the units named here.
            no_si_prefix(plot.plot_widget.getPlotItem().getAxis("left"))
            plot.set_units(units)
            plot.legend.set_short_units([""] * len(plot.curves))

    def set_channel_units(self, units: Sequence[str] | None) -> None:
        """Units per channel (``channel_names`` order), or None for all in the plots' units. Channels whose unit
        differs from the plots' (an uncalibrated sensor's µS among forces in N) are drawn on each plot's own
        right-hand axis labelled with their unit, never on the left axis, and read out in their unit."""
        if units is not None and len(units) != len(self.channel_names):
            raise ValueError(f"{len(units)} units for {len(self.channel_names)} channels")
        units = None if units is None or all(u == self._units for u in units) else tuple(units)
        if units == self._channel_units:
            return
        self._channel_units = units
        self._drawn_key = None
        for plot in self.plots:
            mine = [self._units if units is None else units[i] for i in plot.group.channels]
            # A plot's left axis is in the grid's units when one of its channels is; otherwise (every sensor of
            # the segment uncalibrated, say) in its channels' own unit, with no empty axis beside it.
            primary = self._units if self._units in mine or not mine else mine[0]
            plot.set_units(primary)
            if all(unit == primary for unit in mine):
                plot.hide_other_axis()
            plot.legend.set_short_units(["" if unit == primary else unit for unit in mine])
        self.refresh(force=True)

    def channel_unit(self, index: int) -> str:
        """The unit channel ``index`` is drawn and read out in."""
        return self._units if self._channel_units is None else self._channel_units[index]

    def set_window_s(self, window_s: float) -> None:
        """Width of the live window in seconds (5 s … 10 min in the Forces tab)."""
        if not window_s > 0:
            raise ValueError(f"window must be positive, got {window_s}")
        self._window_s = float(window_s)
        self.refresh(force=True)

    @property
    def window_s(self) -> float:
        return self._window_s

    def set_paused(self, paused: bool) -> None:
        """Stop (True) or resume (False) following the newest data; the data keeps arriving either way."""
        if paused == self._paused:
            return
        if paused:
            # Keep exactly what is on screen, switching its x from "before now" to session time.
            t0, t1 = self.visible_range()
            self._x_offset_s = 0.0
            self._set_view_x(t0, t1)
            self._set_time_label("time", "s")
        else:
            self.time_bar.setValue(SCROLL_STEPS)
            for plot in self.plots:
                plot.auto_y = True
            self._live_range_s = None
            self._set_time_label(LIVE_TIME_LABEL, "s")
        self._paused = paused
        self.paused_changed.emit(paused)
        self.refresh(force=True)

    def _set_view_x(self, x0: float, x1: float) -> None:
        self._setting_range = True
        try:
            self.plots[0].viewbox.setXRange(x0, x1, padding=0)
        finally:
            self._setting_range = False

    def _set_time_label(self, text: str, units: str) -> None:
        for plot in self.plots:
            if plot.plot_widget.getPlotItem().getAxis("bottom").labelText:
                plot.plot_widget.setLabel("bottom", text, units=units)

    @property
    def paused(self) -> bool:
        return self._paused

    def set_side_visible(self, side: str, visible: bool) -> None:
        """Show or hide every trace of one side (``L``, ``R``, ``B``) — the legend toggles."""
        if visible:
            self._hidden_sides.discard(side)
        else:
            self._hidden_sides.add(side)
        for plot in self.plots:
            for curve, name in zip(plot.curves, plot.group.names):
                curve.setVisible(side_of(name) not in self._hidden_sides)
        self.refresh(force=True)

    def set_channel_labels(self, labels: Sequence[str]) -> None:
        """Legend text per channel (e.g. ``"S06B · calibrated"``), in ``channel_names`` order."""
        self._channel_labels = tuple(labels)
        for plot in self.plots:
            plot.set_labels([labels[i] for i in plot.group.channels])

    def set_channel_notes(self, notes: Sequence[str]) -> None:
        """A note per channel (e.g. its calibration status), listed in the tooltip of its plot's header."""
        self._channel_notes = tuple(notes)
        for plot in self.plots:
            lines = [f"{plot.group.names[k]}: {notes[i]}" for k, i in enumerate(plot.group.channels) if notes[i]]
            plot.toggle.setToolTip("\n".join(lines))

    def set_channel_warnings(self, warnings: Sequence[str]) -> None:
        """A warning per channel (empty = fine) shown in red on the plot's header and as the trace style."""
        self._channel_warnings = tuple(warnings)
        for plot in self.plots:
            parts = [f"{plot.group.names[k]}: {warnings[i]}" for k, i in enumerate(plot.group.channels)
                     if warnings[i]]
            text = "; ".join(parts)
            if plot.warning.text() != text:
                short = "⚠ " + ", ".join(plot.group.names[k] for k, i in enumerate(plot.group.channels)
                                         if warnings[i]) if parts else ""
                plot.warning.setText(text, short)
                for k, i in enumerate(plot.group.channels):
                    style = Qt.PenStyle.DotLine if warnings[i] else Qt.PenStyle.SolidLine
                    color = trace_color(plot.group.names[k], k)
                    plot.curves[k].setPen(pg.mkPen(color, width=1, style=style))
                plot.legend.render_entries()
                self._drawn_key = None

    def set_collapsed(self, index: int, collapsed: bool) -> None:
        self.plots[index].toggle.setChecked(not collapsed)

    # -- live redraw -----------------------------------------------------------------------------------------------
    def start(self, rate_hz: float = DEFAULT_REDRAW_HZ) -> None:
        """Start the one redraw timer at ``rate_hz`` (capped at 60 Hz)."""
        rate_hz = min(max(rate_hz, 1.0), MAX_REDRAW_HZ)
        self._timer.setInterval(int(round(1000 / rate_hz)))
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()

    def data_arrived(self) -> None:
        """New samples are in the history (the owner calls this as they arrive): redraw now, unless the last redraw
        is under one redraw period old — then the timer's next tick draws them. Drawing on arrival, not only on a
        free-running timer, keeps the plots in step with the data: a timer at the data's own rate beats against it
        (a tick with nothing new, then one with two samples) and paints were lost."""
        if not self._timer.isActive() or self._refresh_posted:
            return
        if time.monotonic() - self._last_refresh_s >= 0.75 * self._timer.interval() / 1000.0:
            # Posted, not run here: the caller (the board drain, the force estimation) and the redraw are then two
            # short turns of the event loop instead of one long one (1024 channels: ~6 + ~5 ms, up to ~40 ms).
            self._refresh_posted = True
            QTimer.singleShot(0, self, self._posted_refresh)

    def _posted_refresh(self) -> None:
        self._refresh_posted = False
        if self._timer.isActive():
            self.refresh()

    @property
    def running(self) -> bool:
        return self._timer.isActive()

    def visible_range(self) -> tuple[float, float]:
        """The session-time range (s) the plots show."""
        if not self.plots:
            return (0.0, 0.0)
        (x0, x1), _ = self.plots[0].viewbox.viewRange()
        return (float(x0) + self._x_offset_s, float(x1) + self._x_offset_s)

    def _forget_drawn(self) -> None:
        self._drawn_key = None

    def invalidate(self) -> None:
        """Redraw at once even if no new data arrived (a plot was expanded or scrolled into view)."""
        self._drawn_key = None
        self.refresh()

    def refresh(self, force: bool = False, include: int | None = None) -> None:
        """Redraw the plots on screen from the history (the timer calls this). ``force``: even if nothing changed,
        and every expanded plot when the grid itself is hidden; ``include``: that plot too, even if not shown."""
        history = self._history
        if history is None or len(history) == 0 or not self.plots:
            return
        if not force and not self.isVisible():
            return
        self._last_refresh_s = time.monotonic()
        # Nothing new and the same view: the picture would not change (paused, or the board is quiet).
        key = (id(history), history.total_samples, self.visible_range(), self._paused, self._window_s)
        if not force and key == self._drawn_key:
            return
        oldest, newest = history.span()
        if self._paused:
            t0, t1 = self.visible_range()
        else:
            t1 = newest
            t0 = t1 - self._window_s
            self._x_offset_s = newest
            if self._live_range_s != self._window_s:
                self._live_range_s = self._window_s
                self._set_view_x(-self._window_s, 0.0)
        offset = self._x_offset_s
        every_plot = force and not self.isVisible()
        jobs = []  # (plot, indices of its visible curves)
        for index, plot in enumerate(self.plots):
            if plot.collapsed or not (every_plot or index == include or plot.plot_widget.isVisible()):
                continue
            visible = [k for k, curve in enumerate(plot.curves) if curve.isVisible()]
            if visible:
                jobs.append((plot, visible))
        drawn = bool(jobs)
        if jobs:
            # One history query for every channel drawn (one pass over the window, not one per plot).
            channels = np.concatenate([plot.channels[visible] for plot, visible in jobs])
            width_px = max(100, int(BUCKETS_PER_PIXEL * max(int(plot.viewbox.width()) for plot, _ in jobs)))
            window = history.window(t0, t1, width_px, channels=channels)
            x = window.t_s - offset if offset else window.t_s
            if window.level:
                x = np.repeat(x, 2)
            # Every column at once (numpy over the whole window), then only per-plot bookkeeping in Python: the y
            # of each trace (its bucket lows and highs interleaved), whether it has gaps, and each column's extremes
            # for the y ranges.
            lows, highs = window.low, window.high
            if window.level:
                ys = np.empty((x.size, lows.shape[1]), dtype=np.result_type(lows.dtype, np.float64))
                ys[0::2] = lows
                ys[1::2] = highs
            else:
                ys = lows
            finite: np.ndarray = np.asarray(np.isfinite(ys).all(axis=0))
            column_lo = np.fmin.reduce(lows, axis=0)  # NaN (a gap) ignored; NaN only for a column of gaps
            column_hi = np.fmax.reduce(highs, axis=0)
            per_channel_units = self._channel_units
            column = 0
            for plot, visible in jobs:
                # Channels in the plots' units on the left axis; others (µS of uncalibrated sensors) on the right.
                by_units: dict[str, tuple[list, list[int]]] = {}
                for k in visible:
                    y = ys[:, column]
                    trace = plot.curves[k]
                    trace.drawn_x, trace.drawn_y = x, y
                    units = self._units if per_channel_units is None else per_channel_units[plot.channels[k]]
                    traces, columns = by_units.setdefault(units, ([], []))
                    traces.append((trace.opts["pen"], x, y, bool(finite[column])))
                    columns.append(column)
                    column += 1
                for units, (traces, columns) in by_units.items():
                    box, bundle = (plot.viewbox, plot.bundle) if units == plot.units else plot.other_axis(units)
                    bundle.set_traces(traces, _pen_pad(box))
                    if plot.auto_y or box is not plot.viewbox:
                        self._fit_y(box, float(np.fmin.reduce(column_lo[columns])),
                                    float(np.fmax.reduce(column_hi[columns])),
                                    MIN_Y_SPAN.get(units, DEFAULT_MIN_Y_SPAN))
                if plot.units not in by_units:
                    plot.bundle.set_traces([])
                if plot.alt is not None and len(by_units) == 1 and plot.units in by_units:
                    plot.alt[1].set_traces([])
        self._update_time_bar(oldest, newest, t1)
        self._update_readout()
        self._drawn_key = (id(history), history.total_samples, self.visible_range(), self._paused, self._window_s)
        if drawn:
            self.redraw_count += 1
            self.last_redraw_s = float(newest)
            self.redrawn.emit()

    @staticmethod
    def _fit_y(box: pg.ViewBox, lo: float, hi: float, min_span: float = 1e-3) -> None:
        """Keep the data (``lo`` … ``hi``, NaN when there is none) in view, but change the y range only when the data
        leaves it or uses under 40 % of it: a y range that moves every frame would regenerate the y axis every frame.
        ``min_span`` (data units) is the smallest range shown, so an unloaded sensor's noise stays a flat line."""
        if not (math.isfinite(lo) and math.isfinite(hi)):
            return
        # A nearly flat trace still gets a sensible range, so sensor noise does not rescale it every frame.
        span = max(hi - lo, min_span, 0.05 * max(abs(lo), abs(hi)))
        (_x0, _x1), (y0, y1) = box.viewRange()
        if y0 <= lo and hi <= y1 and span >= 0.4 * (y1 - y0):
            return
        center = (lo + hi) / 2
        half = 0.65 * span
        box.setYRange(center - half, center + half, padding=0)

    # -- interaction -----------------------------------------------------------------------------------------------
    def _on_user_range(self, plot: _SegmentPlot, mask) -> None:
        if self._setting_range:
            return
        if len(mask) > 1 and mask[1]:
            plot.auto_y = False  # the user set this plot's y range: keep it
        self.set_paused(True)

    def _update_time_bar(self, oldest: float, newest: float, t1: float) -> None:
        if self.time_bar.isSliderDown():
            return
        span = newest - oldest
        value = SCROLL_STEPS if span <= 0 else int(round((t1 - oldest) / span * SCROLL_STEPS))
        self.time_bar.blockSignals(True)
        self.time_bar.setValue(min(SCROLL_STEPS, max(0, value)))
        self.time_bar.blockSignals(False)

    def _on_time_bar(self, value: int) -> None:
        if self._history is None or len(self._history) == 0:
            return
        oldest, newest = self._history.span()
        t1 = oldest + (newest - oldest) * value / SCROLL_STEPS
        self.show_range(t1 - self._window_s, t1)

    def show_range(self, t0_s: float, t1_s: float) -> None:
        """Pause and show [t0, t1] (seconds)."""
        self.set_paused(True)
        self._set_view_x(t0_s, t1_s)
        self.refresh(force=True)

    def _on_mouse(self, plot: _SegmentPlot, scene_pos: QPointF) -> None:
        if plot.plot_widget.getPlotItem().sceneBoundingRect().contains(scene_pos):
            self._hover = (plot, QPointF(scene_pos))
        else:
            self._hover = None
            plot.readout.hide()
            self._place_cursor_lines(self._cursor_s)  # a shared cursor stays where the mouse left it
        self._update_readout()

    def cursor_readout(self) -> tuple[float, dict[str, float]] | None:
        """(time s, {channel name: value}) under the mouse, or None when the mouse is not over a plot."""
        if self._hover is None or self._history is None:
            return None
        plot, scene_pos = self._hover
        t_s = float(plot.viewbox.mapSceneToView(scene_pos).x()) + self._x_offset_s
        found = self._history.value_at(t_s)
        if found is None:
            return None
        t_found, values = found
        return t_found, {name: float(values[i]) for name, i in zip(plot.group.names, plot.group.channels)}

    def _update_readout(self) -> None:
        readout = self.cursor_readout()
        if readout is None or self._hover is None:
            return
        plot, _ = self._hover
        t_s, values = readout
        lines = [f"t = {t_s:.2f} s"]
        for (name, value), index in zip(values.items(), plot.group.channels):
            units = self.channel_unit(index)
            lines.append(f"{name}: {('{:.3f}' if units == 'N' else '{:.4g}').format(value)} {units}")
        plot.readout.setText("\n".join(lines))
        plot.readout.adjustSize()
        # Inside the data area, never over an axis: in its top corner away from the cursor (the cursor's own
        # point stays visible).
        area = plot.plot_widget.mapFromScene(plot.viewbox.sceneBoundingRect()).boundingRect()
        cursor_x = plot.plot_widget.mapFromScene(self._hover[1]).x()
        if cursor_x > area.center().x():
            x = area.left() + 4
        else:
            x = area.right() - plot.readout.width() - 3
        plot.readout.move(max(area.left() + 1, x), area.top() + 2)
        plot.readout.show()
        plot.readout.raise_()
        if self._cursor_s is not None:
            self._cursor_s = t_s
        self._place_cursor_lines(t_s)
        self.cursor_moved.emit(t_s)

    def _place_cursor_lines(self, t_s: float | None) -> None:
        for other in self.plots:
            if t_s is None:
                other.cursor_line.hide()
            else:
                other.cursor_line.setPos(t_s - self._x_offset_s)
                other.cursor_line.setVisible(not other.collapsed)

    @property
    def cursor_s(self) -> float | None:
        """The shared time cursor (session time, s; None: none): set by :meth:`set_cursor`, then moved by the mouse
        over a plot as well."""
        return self._cursor_s

    def set_cursor(self, t_s: float | None) -> None:
        """Another view's time cursor (the Plots dock's, on the recording shown here) at session time ``t_s``: the
        dashed line on every plot, which stays when the mouse leaves (the mouse moves it too); a paused view is panned
        by its width to keep it in sight. None: back to a cursor only under the mouse. No signal."""
        self._cursor_s = t_s
        if t_s is not None and self._paused and self.plots:
            t0, t1 = self.visible_range()
            if not t0 <= t_s <= t1:
                self.show_range(t_s - 0.5 * (t1 - t0), t_s + 0.5 * (t1 - t0))
        if self._hover is None:
            self._place_cursor_lines(t_s)

    def hover_at(self, plot_index: int, t_s: float) -> None:
        """Put the readout cursor at session time ``t_s`` on plot ``plot_index`` as if the mouse were there."""
        plot = self.plots[plot_index]
        (_x0, _x1), (y0, y1) = plot.viewbox.viewRange()
        scene_pos = plot.viewbox.mapViewToScene(QPointF(t_s - self._x_offset_s, (y0 + y1) / 2))
        self._hover = (plot, QPointF(scene_pos))
        self._update_readout()


class TrialOverlayPlot(QWidget):
    """Several trials of one sensor drawn on a common time zero (the paper's repeatability figure). GUI thread.

    Its plot is made when first needed (shown, given trials, or asked for): it sits on a page the Forces tab does not
    show at first, and a plot costs ~30 ms of the tab's first opening."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._layout = QVBoxLayout(self)
        self._layout.setContentsMargins(0, 0, 0, 0)
        self._plot_widget: pg.PlotWidget | None = None
        self._legend: pg.LegendItem | None = None
        self.curves: list[pg.PlotDataItem] = []
        self._cursor: pg.InfiniteLine | None = None
        self.cursor_s: float | None = None  # a time cursor shared with another view (time from zero), or None
        self._setting_cursor = False

    @property
    def plot_widget(self) -> pg.PlotWidget:
        if self._plot_widget is None:
            self._plot_widget = pg.PlotWidget(self, background="w")
            item = self._plot_widget.getPlotItem()
            item.setClipToView(True)
            item.setDownsampling(auto=True, mode="peak")
            item.showGrid(x=True, y=True, alpha=0.2)
            item.setLabel("bottom", "time from zero", units="s")
            # Bottom right: overlaid trials rise to a plateau, so the top right is where the traces are.
            self._legend = item.addLegend(offset=(-4, -4), labelTextSize="8pt")
            self._layout.addWidget(self._plot_widget)
        return self._plot_widget

    @property
    def legend(self) -> pg.LegendItem:
        self.plot_widget  # noqa: B018 - made with the plot
        assert self._legend is not None
        return self._legend

    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt override
        self.plot_widget  # noqa: B018 - made when first shown
        super().showEvent(event)

    def set_trials(self, trials: Sequence[tuple[str, np.ndarray, np.ndarray]], units: str) -> None:
        """Draw ``(label, t_s (N,) already shifted to the common zero, values (N,))`` per trial."""
        item = self.plot_widget.getPlotItem()
        for curve in self.curves:
            item.removeItem(curve)
        self.legend.clear()
        self.curves = []
        colors = pg.colormap.get("viridis").getLookupTable(0.0, 0.85, max(2, len(trials)))
        for k, (label, t_s, values) in enumerate(trials):
            pen = pg.mkPen(colors[k], width=1)
            self.curves.append(item.plot(t_s, values, pen=pen, name=label, antialias=False))
        no_si_prefix(item.getAxis("left"))  # same units as the segment plots, never "(x0.001)"
        item.setLabel("left", units)

    def set_cursor(self, t_s: float | None) -> None:
        """Another view's time cursor (the Plots dock's, on one of the trials) at ``t_s`` from the common zero: a
        line the user drags to move it (:attr:`cursor_s` follows); None hides it. No signal."""
        self.cursor_s = t_s
        if t_s is None and self._cursor is None:
            return
        if self._cursor is None:
            self._cursor = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen("#888888", width=1))
            self._cursor.setZValue(10)
            self._cursor.sigPositionChanged.connect(self._cursor_dragged)
            self.plot_widget.getPlotItem().addItem(self._cursor, ignoreBounds=True)
        self._setting_cursor = True
        try:
            if t_s is not None:
                self._cursor.setValue(t_s)
            self._cursor.setVisible(t_s is not None)
        finally:
            self._setting_cursor = False

    def _cursor_dragged(self, line: pg.InfiniteLine) -> None:
        if not self._setting_cursor:
            self.cursor_s = float(line.value())
