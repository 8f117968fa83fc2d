"""PlotsView: any series on stacked plots with linked time axes, or as X–Y — a searchable tree to pick them from.

A passive view (widgets import neither devices nor app). It shows:

- a tree of the series it is given (objects with ``key``, ``group``, ``item``, ``name`` and ``unit``, as
  :class:`app.core.series.SeriesInfo`), filtered by the search line (every word must appear), the plotted ones in
  bold. A double click adds a series to the plot last clicked (a new plot when there is none), the context menu to a
  new time or X–Y plot or to any plot; series are dragged onto a plot, or onto the strip below the plots for a new
  one (drag and drop carries their keys as :data:`SERIES_MIME`);
- the plots it is told to show (:meth:`PlotsView.set_plots`), top to bottom in one graphics view (one repaint draws
  them all): time plots share one time axis (linked; the numbers only under the bottom one), an X–Y plot draws its
  other series against its first. On a recording a time cursor (a vertical line on every time plot) is dragged, or
  put where the user clicks, and :attr:`PlotsView.cursor_moved` says where; the time axes pan and zoom together
  (:attr:`PlotsView.time_range_changed`). Live, the time axis is "seconds before the newest sample", fixed, so no
  axis is regenerated per frame;
- the data the app draws into it, curve by curve (:meth:`PlotsView.set_curve`), then :meth:`PlotsView.finish_frame`:
  each plot's y range follows its data with hysteresis (it grows at once, shrinks only when the data use less than
  40 % of it), so the axes are not regenerated every frame either.

It emits what the user asks for (add, remove, open, save, …); the app keeps the layout and the data. GUI thread only.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QMimeData, QPointF, QRectF, QSize, Qt, QTimer, Signal
from PySide6.QtGui import (
    QAction,
    QDragEnterEvent,
    QDragMoveEvent,
    QDropEvent,
    QFont,
    QPainter,
    QPainterPath,
    QPolygonF,
    QResizeEvent,
)
from PySide6.QtWidgets import (
    QAbstractItemView,
    QComboBox,
    QGraphicsItem,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QMenu,
    QSizePolicy,
    QSplitter,
    QToolButton,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

SERIES_MIME = "application/x-sensnake-series"  # the dragged series' keys, one per line (UTF-8)
NEW_PLOT = -1  # add to a new time plot
CURRENT_PLOT = -2  # add to the plot last clicked or dropped on (a new one when there is none)
NEW_XY_PLOT = -3  # add to a new X–Y plot
TIME, XY = "time", "xy"
KEY_ROLE = int(Qt.ItemDataRole.UserRole)
SHRINK_BELOW = 0.4  # a plot's y range shrinks once its data span less than this fraction of it
RANGE_MARGIN = 0.08  # of the data's span, above and below
MIN_SPAN = 1e-9
CURSOR_COLOR = "#444444"
PEN_PAD_PX = 2.0  # a curve's bounds reach this far past its data (the pen and rounding)
LIVE_AXIS_LABEL = "time before newest (s)"
RECORDED_AXIS_LABEL = "time (s)"
HINT = "Double-click a series on the left, or drag it here"
NEW_PLOT_STRIP = "drop a series here for a new plot"


class SeriesEntry(Protocol):
    """What the view reads of a series (as :class:`app.core.series.SeriesInfo`)."""

    @property
    def key(self) -> str: ...

    @property
    def group(self) -> str: ...

    @property
    def item(self) -> str: ...

    @property
    def name(self) -> str: ...

    @property
    def unit(self) -> str: ...


@dataclass(frozen=True)
class CurveSpec:
    """One drawn series: its key, its label with unit (``"J5 current (mA)"``), whether the source shown holds it."""

    key: str
    text: str
    available: bool = True
    steps: bool = False


@dataclass(frozen=True)
class PlotViewSpec:
    """One plot as the view draws it: ``kind`` (``time`` / ``xy``) and its curves (for X–Y the first is x)."""

    kind: str
    curves: tuple[CurveSpec, ...]


def entry_text(entry: SeriesEntry) -> str:
    return f"{entry.item} {entry.name} ({entry.unit})"


def matches(entry: SeriesEntry, query: str) -> bool:
    """Every word of ``query`` appears (case-insensitive) in the series' group, item, name, unit or key."""
    haystack = f"{entry.group} {entry.item} {entry.name} {entry.unit} {entry.key}".lower()
    return all(word in haystack for word in query.lower().split())


class ElidedLabel(QLabel):
    """A one-line label that never widens the dock: text that does not fit ends in "…", the whole text in its
    tooltip. ``text()`` is the whole text."""

    def __init__(self, text: str = "", parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._full = ""
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        self.setMinimumWidth(40)
        self.setText(text)

    def setText(self, text: str) -> None:  # noqa: N802 - Qt override
        self._full = text
        self.setToolTip(text)
        self._elide()

    def text(self) -> str:
        return self._full

    def resizeEvent(self, event: QResizeEvent) -> None:  # noqa: N802 - Qt override
        super().resizeEvent(event)
        self._elide()

    def _elide(self) -> None:
        shown = self.fontMetrics().elidedText(self._full, Qt.TextElideMode.ElideRight, max(0, self.width()))
        if shown != super().text():
            super().setText(shown)


def _keys_from(mime: QMimeData) -> list[str]:
    if not mime.hasFormat(SERIES_MIME):
        return []
    text = bytes(mime.data(SERIES_MIME).data()).decode("utf-8", "replace")
    return [line for line in text.splitlines() if line]


class _SeriesTree(QTreeWidget):
    """The tree; a drag carries the selected series' keys."""

    def mimeData(self, items: Sequence[QTreeWidgetItem]) -> QMimeData:  # noqa: N802 - Qt override
        mime = QMimeData()
        keys = [k for k in (item.data(0, KEY_ROLE) for item in items) if k]
        mime.setData(SERIES_MIME, "\n".join(keys).encode("utf-8"))
        mime.setText("\n".join(keys))
        return mime

    def mimeTypes(self) -> list[str]:  # noqa: N802 - Qt override
        return [SERIES_MIME]


class SeriesPicker(QWidget):
    """The searchable tree of series. ``add_requested(keys, plot)``: ``plot`` a plot index or one of
    :data:`NEW_PLOT`, :data:`CURRENT_PLOT`, :data:`NEW_XY_PLOT`."""

    add_requested = Signal(list, int)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.search = QLineEdit(self)
        self.search.setPlaceholderText("Search series (e.g. J5 current, S06B force)")
        self.search.setClearButtonEnabled(True)
        self.search.textChanged.connect(self.apply_filter)
        layout.addWidget(self.search)
        self.tree = _SeriesTree(self)
        self.tree.setHeaderHidden(True)
        self.tree.setIndentation(10)  # three levels in a narrow dock: the names keep the room
        self.tree.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.tree.setDragEnabled(True)
        self.tree.setDragDropMode(QAbstractItemView.DragDropMode.DragOnly)
        self.tree.itemDoubleClicked.connect(self._double_clicked)
        self.tree.setContextMenuPolicy(Qt.ContextMenuPolicy.CustomContextMenu)
        self.tree.customContextMenuRequested.connect(self._context_menu)
        layout.addWidget(self.tree, 1)
        self._leaves: dict[str, QTreeWidgetItem] = {}
        self._entries: dict[str, SeriesEntry] = {}
        self._plotted: set[str] = set()
        self.plot_titles: list[str] = []  # for the context menu's "Add to plot k"

    def set_entries(self, entries: Sequence[SeriesEntry]) -> None:
        """Show ``entries`` grouped as group ▸ item ▸ name (unit); the search stays applied."""
        self.tree.clear()
        self._leaves.clear()
        self._entries = {e.key: e for e in entries}
        groups: dict[str, QTreeWidgetItem] = {}
        items: dict[tuple[str, str], QTreeWidgetItem] = {}
        for entry in entries:
            group = groups.get(entry.group)
            if group is None:
                group = groups[entry.group] = QTreeWidgetItem(self.tree, [entry.group])
                group.setFlags(Qt.ItemFlag.ItemIsEnabled)
            parent = items.get((entry.group, entry.item))
            if parent is None:
                parent = items[(entry.group, entry.item)] = QTreeWidgetItem(group, [entry.item])
                parent.setFlags(Qt.ItemFlag.ItemIsEnabled)
            leaf = QTreeWidgetItem(parent, [f"{entry.name} ({entry.unit})"])
            leaf.setData(0, KEY_ROLE, entry.key)
            leaf.setToolTip(0, f"{entry_text(entry)} — {entry.key}; double-click to plot it, or drag it onto a plot")
            leaf.setFlags(Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable | Qt.ItemFlag.ItemIsDragEnabled)
            self._leaves[entry.key] = leaf
        self.set_plotted(self._plotted)
        self.apply_filter()

    def keys(self) -> list[str]:
        return list(self._leaves)

    def leaf(self, key: str) -> QTreeWidgetItem | None:
        return self._leaves.get(key)

    def visible_keys(self) -> list[str]:
        """The series the search leaves shown."""
        return [key for key, leaf in self._leaves.items() if not leaf.isHidden()]

    def set_plotted(self, keys: set[str] | Sequence[str]) -> None:
        """Show the series on some plot in bold."""
        self._plotted = set(keys)
        for key, leaf in self._leaves.items():
            font = leaf.font(0)
            font.setBold(key in self._plotted)
            leaf.setFont(0, font)

    def apply_filter(self, *_args: object) -> None:
        query = self.search.text().strip()
        for key, leaf in self._leaves.items():
            leaf.setHidden(bool(query) and not matches(self._entries[key], query))
        for g in range(self.tree.topLevelItemCount()):
            group = self.tree.topLevelItem(g)
            if group is None:
                continue
            any_group = False
            for i in range(group.childCount()):
                item = group.child(i)
                if item is None:
                    continue
                shown = any(not leaf.isHidden() for leaf in (item.child(k) for k in range(item.childCount()))
                            if leaf is not None)
                item.setHidden(not shown)
                any_group |= shown
                item.setExpanded(bool(query) and shown)
            group.setHidden(not any_group)
            group.setExpanded(bool(query) or self.tree.topLevelItemCount() <= 2)

    def _selected_keys(self) -> list[str]:
        return [k for k in (i.data(0, KEY_ROLE) for i in self.tree.selectedItems()) if k]

    def _double_clicked(self, item: QTreeWidgetItem, _column: int) -> None:
        key = item.data(0, KEY_ROLE)
        if key:
            self.add_requested.emit([key], CURRENT_PLOT)

    def _context_menu(self, position: Any) -> None:
        keys = self._selected_keys()
        if not keys:
            return
        menu = QMenu(self)
        menu.addAction("Add to a new plot", partial(self.add_requested.emit, keys, NEW_PLOT))
        menu.addAction("Add to a new X–Y plot (first selected on x)",
                       partial(self.add_requested.emit, keys, NEW_XY_PLOT))
        for index, title in enumerate(self.plot_titles):
            menu.addAction(f"Add to plot {index + 1}: {title}", partial(self.add_requested.emit, keys, index))
        menu.exec(self.tree.viewport().mapToGlobal(position))


def _button(text: str, parent: QWidget) -> QToolButton:
    """A text button without a push button's 80-px minimum: the dock fits beside a wide tab at 1280 px."""
    button = QToolButton(parent)
    button.setText(text)
    button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
    return button


def _no_plot(_point: QPointF) -> int:
    return NEW_PLOT


class PlotArea(pg.GraphicsLayoutWidget):
    """The plots' graphics view; series dropped on it: ``dropped(keys, plot index or NEW_PLOT)``."""

    dropped = Signal(list, int)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setAcceptDrops(True)
        self.plot_at: Callable[[QPointF], int] = _no_plot  # set by PlotsView: scene point → plot index

    def dragEnterEvent(self, event: QDragEnterEvent) -> None:  # noqa: N802 - Qt override
        if event.mimeData().hasFormat(SERIES_MIME):
            event.acceptProposedAction()
        else:
            event.ignore()

    def dragMoveEvent(self, event: QDragMoveEvent) -> None:  # noqa: N802 - Qt override
        if event.mimeData().hasFormat(SERIES_MIME):
            event.acceptProposedAction()
        else:
            event.ignore()

    def dropEvent(self, event: QDropEvent) -> None:  # noqa: N802 - Qt override
        keys = _keys_from(event.mimeData())
        if not keys:
            event.ignore()
            return
        event.acceptProposedAction()
        self.dropped.emit(keys, int(self.plot_at(self.mapToScene(event.position().toPoint()))))


class _Curve:
    """One drawn series: its pen and what the plot drew last (``xData``/``yData``, view coordinates)."""

    def __init__(self, pen: Any) -> None:
        self.pen = pen
        self.xData: np.ndarray | None = None  # noqa: N815 - pyqtgraph's attribute names, which tests read
        self.yData: np.ndarray | None = None  # noqa: N815


class _CurveBundle(pg.GraphicsObject):
    """Every curve of one plot drawn by one item whose bounding rect is the drawn data's (plus the pen).

    The reason, measured in the Forces tab's plots (widgets/force_plots.py does the same): a PlotCurveItem per
    series recomputes its bounds with numpy and its pixel padding whenever Qt asks, several times a frame; here the
    bounds come once per frame from the polylines Qt builds (C++), and the geometry changes only when they do."""

    def __init__(self, curves: Sequence[_Curve]) -> None:
        super().__init__()
        self.curves = list(curves)
        self._lines: list[tuple[Any, QPolygonF | QPainterPath]] = []
        self._bounds = QRectF()
        self._buffers: dict[int, tuple[QPolygonF, np.ndarray]] = {}

    def rebuild(self, pad: tuple[float, float]) -> None:
        """Lines from the curves' data; ``pad`` (view units, x and y): how far the pen reaches past the data."""
        lines: list[tuple[Any, QPolygonF | QPainterPath]] = []
        bounds = QRectF()
        for position, curve in enumerate(self.curves):
            x, y = curve.xData, curve.yData
            if x is None or y is None or not x.size:
                continue
            finite = np.isfinite(y)
            if not finite.any():
                continue  # nothing to draw (a sensor without a force, a quantity not sent)
            line: QPolygonF | QPainterPath
            if finite.all() and np.isfinite(x).all():
                held = self._buffers.get(position)
                if held is None or held[1].shape[0] != x.size:  # a polyline straight from the arrays, reused
                    polygon = pg.functions.create_qpolygonf(x.size)
                    held = (polygon, pg.functions.ndarray_from_qpolygonf(polygon))
                    self._buffers[position] = held
                line, points = held
                points[:, 0] = x
                points[:, 1] = y
            else:
                line = pg.arrayToQPath(x, y, connect="finite")  # gaps: separate runs
            lines.append((curve.pen, line))
            bounds = bounds.united(line.boundingRect())
        if not bounds.isNull():
            bounds = bounds.adjusted(-pad[0], -pad[1], pad[0], pad[1])
        self._lines = lines
        if bounds != self._bounds:
            self.prepareGeometryChange()
            self._bounds = bounds
        self.update()

    def boundingRect(self) -> QRectF:  # noqa: N802 - Qt override
        return self._bounds

    def dataBounds(self, ax: int, frac: float = 1.0, orthoRange: Any = None) -> tuple[None, None]:  # noqa: N802,N803
        return (None, None)  # never part of pyqtgraph's auto-range: the view fits the ranges itself

    def paint(self, painter: QPainter, *_args: Any) -> None:
        for pen, line in self._lines:
            painter.setPen(pen)
            if isinstance(line, QPolygonF):
                painter.drawPolyline(line)
            else:
                painter.drawPath(line)


class _Header(pg.LabelItem):
    """A plot's legend line; unlike pyqtgraph's label it never makes the plots wider than the dock (a long legend
    is cut at the plot's edge; the whole of it is the item's tooltip)."""

    def updateMin(self) -> None:  # noqa: N802 - pyqtgraph's name
        super().updateMin()
        self.setMinimumWidth(0)
        height = self.itemRect().height()
        self._sizeHint = {Qt.SizeHint.MinimumSize: (0, height), Qt.SizeHint.PreferredSize: (0, height),
                          Qt.SizeHint.MaximumSize: (-1, -1), Qt.SizeHint.MinimumDescent: (0, 0)}
        self.updateGeometry()


def _cache_subtree(item: QGraphicsItem) -> None:
    """Paint ``item`` and its children from a pixmap: an axis is re-rendered only when it changes."""
    item.setCacheMode(QGraphicsItem.CacheMode.DeviceCoordinateCache)
    for child in item.childItems():
        _cache_subtree(child)


class _Plot:
    """One plot of the stack: its PlotItem, header label, curves and (time plots) cursor line. Drawn as the Forces
    tab's plots are, for the same measured reasons (widgets/force_plots.py): no grid (replaying the grid with the
    axis picture costs milliseconds a frame on a software raster), axes painted from a pixmap cache, the view box
    flagged as drawing nothing, every curve in one item."""

    def __init__(self, spec: PlotViewSpec, index: int) -> None:
        self.spec = spec
        self.index = index
        self.kind = spec.kind
        self.keys = [c.key for c in spec.curves]
        self.item = pg.PlotItem()
        self.item.setMenuEnabled(True)
        self.item.hideButtons()
        self.vb = self.item.getViewBox()
        self.vb.disableAutoRange()
        self.vb.setFlag(QGraphicsItem.GraphicsItemFlag.ItemHasNoContents, True)
        for side in ("left", "bottom"):  # "N (x0.001)" read as kilonewtons: the numbers stay in the unit shown
            axis = self.item.getAxis(side)
            theme.no_si_prefix(axis)
            _cache_subtree(axis)
        self.item.getAxis("left").setWidth(52)  # the stacked plots' data areas line up
        self.header = _Header(justify="left", size="9pt")
        self.header.setText(self._header_html())
        self.header.setToolTip(", ".join(c.text for c in spec.curves))
        drawn = spec.curves[1:] if self.kind == XY else spec.curves
        self.curves = [_Curve(pg.mkPen(theme.series_color(position), width=1)) for position in range(len(drawn))]
        self.bundle = _CurveBundle(self.curves)
        self.item.addItem(self.bundle)
        self.dirty = False
        self.marker: pg.ScatterPlotItem | None = None
        self.cursor: pg.InfiniteLine | None = None
        if self.kind == XY:
            self.marker = pg.ScatterPlotItem(size=8, pen=pg.mkPen(CURSOR_COLOR), brush=pg.mkBrush(None))
            self.item.addItem(self.marker)
            first = spec.curves[0].text if spec.curves else "drop the x series here"
            self.item.setLabel("bottom", html.escape(first))
        else:
            self.cursor = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen(CURSOR_COLOR, width=1))
            self.cursor.setZValue(10)
            self.item.addItem(self.cursor, ignoreBounds=True)
        units = sorted({c.text.rsplit("(", 1)[-1].rstrip(")") for c in drawn if "(" in c.text})
        self.item.setLabel("left", " · ".join(units))
        self.y_range: tuple[float, float] | None = None
        self.x_range: tuple[float, float] | None = None

    def pen_pad(self) -> tuple[float, float]:
        """PEN_PAD_PX pixels in view units (x, y)."""
        (x0, x1), (y0, y1) = self.vb.viewRange()
        size = self.vb.size()
        return (PEN_PAD_PX * (x1 - x0) / max(size.width(), 1.0), PEN_PAD_PX * (y1 - y0) / max(size.height(), 1.0))

    def _header_html(self) -> str:
        if not self.spec.curves:
            return f"<span style='color:{theme.STATUS_COLORS[theme.IDLE]}'>{html.escape(HINT)}</span>"
        parts = []
        drawn = self.spec.curves[1:] if self.kind == XY else self.spec.curves
        if self.kind == XY:
            parts.append(f"<b>X–Y</b> against {html.escape(self.spec.curves[0].text)}:")
            if not drawn:
                parts.append(" drop the y series here")
        for position, curve in enumerate(drawn):
            color = theme.series_color(position) if curve.available else theme.STATUS_COLORS[theme.IDLE]
            missing = "" if curve.available else " — not in what is shown"
            parts.append(f"<span style='color:{color}'>━ {html.escape(curve.text)}{missing}</span>")
        return "&nbsp;&nbsp;".join(parts)


def _nice_range(low: float, high: float) -> tuple[float, float]:
    span = high - low
    if not math.isfinite(span):
        return (-1.0, 1.0)
    if span < MIN_SPAN:
        pad = max(abs(high) * 0.05, 1e-3)
        return (low - pad, high + pad)
    return (low - RANGE_MARGIN * span, high + RANGE_MARGIN * span)


def follow_range(current: tuple[float, float] | None, low: float, high: float) -> tuple[float, float] | None:
    """The range a plot's axis should show for data in [low, high]: the current one while the data fit it and use
    at least :data:`SHRINK_BELOW` of it; else one fitted to the data with a margin. None: keep it (no data)."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return None
    fitted = _nice_range(low, high)
    if current is not None:
        a, b = current
        if a <= low and high <= b and (fitted[1] - fitted[0]) >= SHRINK_BELOW * (b - a):
            return None
    return fitted


class PlotsView(QWidget):
    """See the module docstring."""

    series_added = Signal(list, int)  # keys, plot index or NEW_PLOT / CURRENT_PLOT / NEW_XY_PLOT
    series_removed = Signal(int, str)  # plot index, key
    plot_removed = Signal(int)
    xy_plot_requested = Signal()
    cursor_moved = Signal(float)  # the user put the time cursor at t (s, on the shown clock)
    time_range_changed = Signal()  # the user panned or zoomed the time axes (a recording)
    open_requested = Signal()
    live_requested = Signal()
    replay_requested = Signal()
    save_layout_requested = Signal()
    open_layout_requested = Signal()
    clear_requested = Signal()
    window_changed = Signal(float)  # the live time window (s)
    pause_toggled = Signal(bool)

    def __init__(self, windows_s: Sequence[float] = (10.0, 30.0, 60.0, 120.0, 300.0, 600.0),
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.live = True
        self.plots: list[_Plot] = []
        self.current_plot = -1
        self._cursor_s: float | None = None
        self._setting_range = False
        self._setting_cursor = False
        self.repaints = 0  # frames drawn (finish_frame calls), for tests and benchmarks

        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        title_bar = QHBoxLayout()
        self.source_label = ElidedLabel("Live", self)
        self.source_label.setToolTip("What the plots show: the live lab or a recording")
        font = QFont(self.source_label.font())
        font.setBold(True)
        self.source_label.setFont(font)
        title_bar.addWidget(self.source_label, 1)
        title_bar.addWidget(QLabel("Window", self))
        self.window_combo = QComboBox(self)
        self.window_combo.setToolTip("How much of the live past the plots show")
        for seconds in windows_s:
            self.window_combo.addItem(f"{seconds:g} s" if seconds < 60 else f"{seconds / 60:g} min", float(seconds))
        self.window_combo.currentIndexChanged.connect(
            lambda _i: self.window_changed.emit(float(self.window_combo.currentData())))
        title_bar.addWidget(self.window_combo)
        self.pause_button = _button("Pause", self)
        self.pause_button.setCheckable(True)
        self.pause_button.setToolTip("Freeze the live plots (the data keep arriving)")
        self.pause_button.toggled.connect(self._pause_toggled)
        title_bar.addWidget(self.pause_button)
        layout.addLayout(title_bar)

        bar = QHBoxLayout()
        self.open_button = _button("Open recording…", self)
        self.open_button.setToolTip("Plot the series of a recording (a layout saved beside it opens with it)")
        self.open_button.clicked.connect(self.open_requested)
        bar.addWidget(self.open_button)
        self.live_button = _button("Live", self)
        self.live_button.setToolTip("Back to the live lab (the same plots)")
        self.live_button.clicked.connect(self.live_requested)
        bar.addWidget(self.live_button)
        self.replay_button = _button("3-D replay", self)
        self.replay_button.setToolTip("Open this recording in the 3-D lab's replay; its timeline and this time "
                                      "cursor then follow each other")
        self.replay_button.clicked.connect(self.replay_requested)
        bar.addWidget(self.replay_button)
        self.layout_button = QToolButton(self)
        self.layout_button.setText("Layout")
        self.layout_button.setToolTip("Save the plots as a layout file, open one, add an X–Y plot, remove them all")
        self.layout_button.setPopupMode(QToolButton.ToolButtonPopupMode.InstantPopup)
        menu = QMenu(self.layout_button)
        self.save_action = QAction("Save layout…", menu)
        self.save_action.triggered.connect(self.save_layout_requested)
        self.open_layout_action = QAction("Open layout…", menu)
        self.open_layout_action.triggered.connect(self.open_layout_requested)
        self.xy_action = QAction("New X–Y plot", menu)
        self.xy_action.triggered.connect(self.xy_plot_requested)
        self.clear_action = QAction("Remove every plot", menu)
        self.clear_action.triggered.connect(self.clear_requested)
        for action in (self.save_action, self.open_layout_action, self.xy_action, self.clear_action):
            menu.addAction(action)
        self.layout_button.setMenu(menu)
        bar.addWidget(self.layout_button)
        bar.addStretch(1)
        layout.addLayout(bar)
        self.message = ElidedLabel("", self)
        self.message.setVisible(False)
        layout.addWidget(self.message)

        splitter = QSplitter(Qt.Orientation.Horizontal, self)
        self.picker = SeriesPicker(splitter)
        self.picker.add_requested.connect(self.series_added)
        right = QWidget(splitter)
        right_layout = QVBoxLayout(right)
        right_layout.setContentsMargins(0, 0, 0, 0)
        self.graphics = PlotArea(right)
        self.graphics.setBackground("w")
        self.graphics.plot_at = self._plot_at
        self.graphics.dropped.connect(self._dropped)
        self.graphics.scene().sigMouseClicked.connect(self._scene_clicked)
        right_layout.addWidget(self.graphics, 1)
        self.readout = QLabel("", right)
        self.readout.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.readout.setWordWrap(True)
        self.readout.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        right_layout.addWidget(self.readout)
        splitter.addWidget(self.picker)
        splitter.addWidget(right)
        splitter.setStretchFactor(0, 1)
        splitter.setStretchFactor(1, 3)
        splitter.setSizes([140, 420])
        layout.addWidget(splitter, 1)
        self._range_timer = QTimer(self)  # panning emits many range changes: the app redraws once they settle
        self._range_timer.setSingleShot(True)
        self._range_timer.setInterval(30)
        self._range_timer.timeout.connect(self.time_range_changed)
        self._strip = pg.LabelItem(NEW_PLOT_STRIP, size="8pt", color=theme.STATUS_COLORS[theme.IDLE])
        self.set_live(True)
        self.set_plots([])

    def sizeHint(self) -> QSize:  # noqa: N802 - Qt override
        return QSize(560, 600)  # beside the tabs at the default 1280×800 without squeezing the Forces tab's grid

    # -- what is shown ---------------------------------------------------------------------------------------------
    def set_catalog(self, entries: Sequence[SeriesEntry], source: str) -> None:
        """The series offered (the tree) and what they come from (``"Live"``, ``"Recording: RUN.h5 (84.2 s)"``)."""
        self.picker.set_entries(entries)
        self.source_label.setText(source)

    def set_live(self, live: bool) -> None:
        """Live (time before the newest sample, fixed window, no cursor) or a recording (its clock, pan and zoom,
        the cursor)."""
        self.live = live
        self.window_combo.setEnabled(live)
        self.pause_button.setEnabled(live)
        self.live_button.setEnabled(not live)
        self.replay_button.setEnabled(not live)
        for plot in self.plots:
            self._apply_mode(plot)

    def _apply_mode(self, plot: _Plot) -> None:
        if plot.kind == XY:
            plot.vb.setMouseEnabled(x=False, y=False)
            return
        plot.vb.setMouseEnabled(x=not self.live, y=False)
        if plot.cursor is not None:
            plot.cursor.setVisible(not self.live and self._cursor_s is not None)
        if plot.index == self._last_time_plot():
            plot.item.setLabel("bottom", LIVE_AXIS_LABEL if self.live else RECORDED_AXIS_LABEL)

    def set_window(self, seconds: float) -> None:
        """Select the live window ``seconds`` in the combo box (no signal)."""
        index = self.window_combo.findData(float(seconds))
        if index < 0:
            self.window_combo.addItem(f"{seconds:g} s", float(seconds))
            index = self.window_combo.count() - 1
        self.window_combo.blockSignals(True)
        self.window_combo.setCurrentIndex(index)
        self.window_combo.blockSignals(False)

    def set_plots(self, specs: Sequence[PlotViewSpec]) -> None:
        """Rebuild the stack: ``specs`` top to bottom; time plots' axes linked; the data are drawn next frame."""
        time_range = self.time_range() if self.plots else None
        layout = self.graphics.ci
        layout.clear()
        self.plots = []
        first_time: _Plot | None = None
        for index, spec in enumerate(specs):
            plot = _Plot(spec, index)
            layout.addItem(plot.header, row=2 * index, col=0)
            layout.addItem(plot.item, row=2 * index + 1, col=0)
            if plot.kind == TIME:
                if first_time is None:
                    first_time = plot
                    plot.vb.sigXRangeChanged.connect(self._x_range_changed)
                else:
                    plot.item.setXLink(first_time.item)
                assert plot.cursor is not None
                plot.cursor.sigPositionChanged.connect(lambda line, p=plot: self._cursor_dragged(p, line))
            self._add_remove_menu(plot)
            self.plots.append(plot)
        last = self._last_time_plot()
        for plot in self.plots:
            if plot.kind == TIME:
                plot.item.getAxis("bottom").setStyle(showValues=plot.index == last)
                if plot.index != last:
                    plot.item.setLabel("bottom", "")
            self._apply_mode(plot)
        layout.addItem(self._strip, row=2 * len(self.plots), col=0)
        if not self.plots:
            self._strip.setText(HINT)
        else:
            self._strip.setText(NEW_PLOT_STRIP)
        self.current_plot = min(self.current_plot, len(self.plots) - 1)
        self.picker.plot_titles = [", ".join(c.text for c in p.spec.curves) or "(empty)" for p in self.plots]
        self.picker.set_plotted({c.key for p in self.plots for c in p.spec.curves})
        if time_range is not None:
            self.set_time_range(*time_range)
        if self._cursor_s is not None:
            self.set_cursor(self._cursor_s)

    def _last_time_plot(self) -> int:
        times = [p.index for p in self.plots if p.kind == TIME]
        return times[-1] if times else -1

    def _add_remove_menu(self, plot: _Plot) -> None:
        menu = plot.vb.menu
        if menu is None:
            return
        menu.addSeparator()
        for key, curve in zip(plot.keys, plot.spec.curves):
            menu.addAction(f"Remove {curve.text}", partial(self.series_removed.emit, plot.index, key))
        menu.addAction("Remove this plot", partial(self.plot_removed.emit, plot.index))

    # -- time axis and cursor --------------------------------------------------------------------------------------
    def set_time_range(self, t0_s: float, t1_s: float) -> None:
        """The linked time axes show [t0, t1] (no signal)."""
        times = [p for p in self.plots if p.kind == TIME]
        if not times or not (math.isfinite(t0_s) and math.isfinite(t1_s)) or t1_s <= t0_s:
            return
        self._setting_range = True
        try:
            times[0].vb.setXRange(t0_s, t1_s, padding=0.0)
        finally:
            self._setting_range = False

    def time_range(self) -> tuple[float, float]:
        """The time the linked axes show (s); (0, 1) without a time plot."""
        times = [p for p in self.plots if p.kind == TIME]
        if not times:
            return (0.0, 1.0)
        low, high = times[0].vb.viewRange()[0]
        return float(low), float(high)

    def _x_range_changed(self, *_args: object) -> None:
        if not self._setting_range and not self.live:
            self._range_timer.start()

    @property
    def cursor_s(self) -> float | None:
        return self._cursor_s

    def set_cursor(self, t_s: float | None) -> None:
        """Put the time cursor at ``t_s`` on every time plot (None: hide it); no signal."""
        self._cursor_s = t_s
        self._setting_cursor = True
        try:
            for plot in self.plots:
                if plot.cursor is not None:
                    if t_s is not None:
                        plot.cursor.setValue(t_s)
                    plot.cursor.setVisible(t_s is not None and not self.live)
        finally:
            self._setting_cursor = False

    def _cursor_dragged(self, plot: _Plot, line: pg.InfiniteLine) -> None:
        if self._setting_cursor or self.live:
            return
        t_s = float(line.value())
        self.set_cursor(t_s)
        self.cursor_moved.emit(t_s)

    def _scene_clicked(self, event: Any) -> None:
        """A click on a time plot puts the cursor there (a recording); any click makes that plot the current one."""
        point = event.scenePos()
        index = self._plot_at(point)
        if index >= 0:
            self.current_plot = index
        if self.live or index < 0 or self.plots[index].kind != TIME:
            return
        t_s = float(self.plots[index].vb.mapSceneToView(point).x())
        self.set_cursor(t_s)
        self.cursor_moved.emit(t_s)

    def put_cursor(self, t_s: float) -> None:
        """As if the user put the cursor at ``t_s`` (tests, keyboard): moved, and said."""
        self.set_cursor(t_s)
        self.cursor_moved.emit(float(t_s))

    # -- drops -----------------------------------------------------------------------------------------------------
    def _plot_at(self, scene_point: QPointF) -> int:
        for plot in self.plots:
            if plot.item.sceneBoundingRect().contains(scene_point) or plot.header.sceneBoundingRect().contains(
                    scene_point):
                return plot.index
        return NEW_PLOT

    def _dropped(self, keys: list[str], plot: int) -> None:
        if plot >= 0:
            self.current_plot = plot
        self.series_added.emit(keys, plot)

    # -- data ------------------------------------------------------------------------------------------------------
    def plot_width_px(self) -> int:
        """How many pixel columns a plot's data area has (the decimation's bucket count)."""
        for plot in self.plots:
            width = int(plot.vb.width())
            if width > 0:
                return width
        return max(100, self.graphics.width() - 60)

    def set_curve(self, plot: int, curve: int, x: np.ndarray, y: np.ndarray) -> None:
        """Curve ``curve`` of plot ``plot`` (for X–Y: of its y series) is ``x``, ``y`` (drawn at
        :meth:`finish_frame`)."""
        target = self.plots[plot]
        item = target.curves[curve]
        item.xData, item.yData = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        target.dirty = True

    def set_marker(self, plot: int, x: np.ndarray, y: np.ndarray) -> None:
        """The X–Y plot's cursor points (where each y series is at the cursor's time)."""
        marker = self.plots[plot].marker
        if marker is not None:
            finite = np.isfinite(x) & np.isfinite(y)
            marker.setData(np.asarray(x)[finite], np.asarray(y)[finite])

    def finish_frame(self) -> None:
        """Fit each plot's y range (and an X–Y plot's x range) to what it draws now, with hysteresis; then draw."""
        self.repaints += 1
        for plot in self.plots:
            if not plot.dirty:
                continue
            plot.dirty = False
            low, high = math.inf, -math.inf
            x_low, x_high = math.inf, -math.inf
            for item in plot.curves:
                xs, ys = item.xData, item.yData
                if ys is None or len(ys) == 0:
                    continue
                finite = ys[np.isfinite(ys)]
                if finite.size:
                    low, high = min(low, float(finite.min())), max(high, float(finite.max()))
                if plot.kind == XY and xs is not None and len(xs):
                    fx = xs[np.isfinite(xs)]
                    if fx.size:
                        x_low, x_high = min(x_low, float(fx.min())), max(x_high, float(fx.max()))
            wanted = follow_range(plot.y_range, low, high)
            if wanted is not None:
                plot.y_range = wanted
                plot.vb.setYRange(*wanted, padding=0.0)
            if plot.kind == XY:
                wanted_x = follow_range(plot.x_range, x_low, x_high)
                if wanted_x is not None:
                    plot.x_range = wanted_x
                    plot.vb.setXRange(*wanted_x, padding=0.0)
            plot.bundle.rebuild(plot.pen_pad())

    def set_readout(self, text: str) -> None:
        if text != self.readout.text():
            self.readout.setText(text)

    def set_message(self, text: str, level: str = theme.IDLE) -> None:
        self.message.setText(text)
        self.message.setVisible(bool(text))
        self.message.setStyleSheet(theme.status_style(level) if text else "")

    @property
    def paused(self) -> bool:
        return self.pause_button.isChecked()

    def _pause_toggled(self, on: bool) -> None:
        self.pause_button.setText("Follow" if on else "Pause")
        self.pause_toggled.emit(on)

    def header_text(self, plot: int) -> str:
        """The header of plot ``plot`` as plain text (its legend)."""
        import re

        return html.unescape(re.sub(r"<[^>]+>", "", self.plots[plot].header.text)).replace("\xa0", " ")
