"""widgets/force_plots.py ForcePlotGrid built directly on a TraceHistory (no devices)."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import QEvent, QObject, QPoint, QPointF, Qt
from PySide6.QtWidgets import QLabel, QWidget

from devices.config import default_sensor_names
from widgets.force_plots import ForcePlotGrid, _Legend, groups_from_names
from widgets.ring_plot import TraceHistory, append_with_gaps

NAMES = default_sensor_names()


@pytest.fixture
def grid(qtbot):
    grid = ForcePlotGrid(NAMES)
    qtbot.addWidget(grid)
    grid.resize(1400, 1100)
    grid.show()
    qtbot.waitExposed(grid)
    return grid


def fill(history: TraceHistory, seconds: float, rate_hz: float = 30.0, t0: float = 0.0) -> np.ndarray:
    t = t0 + np.arange(int(seconds * rate_hz)) / rate_hz
    history.append(t, np.abs(np.sin(t[:, None] + np.arange(history.n_channels))) * 3.0)
    return t


def drawn_points(grid: ForcePlotGrid) -> list[int]:
    return [0 if c.xData is None else len(c.xData) for p in grid.plots for c in p.curves]


def test_groups_by_segment_and_other_names():
    groups = groups_from_names(NAMES)
    assert [g.title for g in groups][:2] == ["Segment 1", "Segment 2"] and len(groups) == 12
    assert groups[9].names == ("S10L", "S10R", "S10B") and groups[9].channels == (27, 28, 29)
    odd = groups_from_names(["a", "b", "c", "d"])
    assert [g.channels for g in odd] == [(0, 1, 2), (3,)]


def test_drawing_cost_does_not_grow_with_history(grid):
    history = TraceHistory.for_budget(36, 20_000_000)
    grid.set_history(history, "N")
    grid.set_window_s(600.0)
    fill(history, 60.0)
    grid.refresh()
    short = max(drawn_points(grid))
    fill(history, 540.0, t0=60.0)
    grid.refresh()
    long = max(drawn_points(grid))
    width = int(grid.plots[0].viewbox.width())
    assert long <= 4 * width + 8  # ≤ two points (low, high) per pixel bucket, whatever the history length
    assert long > short / 2


def test_collapsed_and_hidden_are_not_redrawn(grid):
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 10.0)
    grid.set_collapsed(3, True)
    grid.set_side_visible("R", False)
    before = [[None if c.xData is None else c.xData.copy() for c in p.curves] for p in grid.plots]
    fill(history, 5.0, t0=10.0)
    grid.refresh()
    after = [[c.xData for c in p.curves] for p in grid.plots]
    assert np.array_equal(after[3][0], before[3][0])  # collapsed segment untouched
    assert np.array_equal(after[0][1], before[0][1])  # hidden right trace untouched
    assert after[0][0][0] < before[0][0][0]  # visible traces moved on (x is "seconds before newest" live)
    assert not grid.plots[0].curves[1].isVisible()


def test_user_zoom_pauses_and_scrollbar_scrolls_back(qtbot, grid):
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 120.0)
    grid.refresh()
    with qtbot.waitSignal(grid.paused_changed) as paused:
        grid.plots[2].viewbox.scaleBy(x=0.5)
        grid.plots[2].viewbox.sigRangeChangedManually.emit([True, False])
    assert paused.args == [True]
    grid.time_bar.setSliderPosition(0)
    grid.time_bar.sliderMoved.emit(0)
    x0, x1 = grid.visible_range()
    assert x0 < 1.0 and x1 == pytest.approx(x0 + grid.window_s)
    grid.set_paused(False)
    grid.refresh()
    assert grid.visible_range()[1] == pytest.approx(history.span()[1])


def test_gap_breaks_the_line(grid):
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    t = np.arange(20) / 10.0
    gap = np.zeros(20, dtype=bool)
    gap[10] = True
    append_with_gaps(history, t, np.ones((20, 36)), gap)
    grid.refresh()
    y = grid.plots[0].curves[0].yData
    assert np.isnan(y).sum() == 1 and len(y) == 21


def test_a_trace_with_gaps_draws_only_between_neighbouring_samples(grid):
    """A trace with gaps is drawn as the segments between neighbouring finite samples (one native call): nothing
    across a gap, nothing for a sample alone between two gaps; the bounds are the segments'."""
    from widgets.force_plots import _Segments

    segments = _Segments()
    x = np.arange(8.0)
    y = np.array([0.0, 1.0, np.nan, 3.0, np.nan, 5.0, 6.0, 4.0])
    assert segments.set(x, y)
    assert segments.lines.ndarray().tolist() == [[0, 0, 1, 1], [5, 5, 6, 6], [6, 6, 7, 4]]
    rect = segments.boundingRect()
    assert (rect.left(), rect.right(), rect.top(), rect.bottom()) == (0, 7, 0, 6)
    assert not segments.set(x[:3], np.array([np.nan, 2.0, np.nan]))  # one sample between gaps: nothing to draw

    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    grid.set_window_s(10.0)
    t = np.arange(300) / 30.0
    values = np.full((300, 36), 3.0)
    values[:, 0] = 1.0
    values[100:200, 0] = np.nan  # S01L: a gap over the middle third of the window (its neighbours elsewhere)
    history.append(t, values)
    grid.refresh(force=True)
    plot = grid.plots[0]
    assert any(isinstance(line, _Segments) for _pen, line in plot.bundle._lines)
    image = plot.plot_widget.grab().toImage()
    color = plot.curves[0].opts["pen"].color()
    box = plot.viewbox

    def drawn_at(x_view: float) -> bool:
        """A pixel of S01L's colour in the column of view x (session time before the newest sample)."""
        point = plot.plot_widget.mapFromScene(box.mapViewToScene(QPointF(x_view, 1.0)))
        return any(image.pixelColor(point.x(), row) == color
                   for row in range(max(0, point.y() - 3), min(image.height(), point.y() + 4)))

    newest = float(t[-1])
    assert drawn_at(1.5 - newest) and drawn_at(8.5 - newest)  # before and after the gap
    assert not drawn_at(5.0 - newest)  # inside it


def test_warnings_show_on_the_plot_header(grid):
    warnings = [""] * 36
    warnings[28] = "noisy (loose?)"
    grid.set_channel_warnings(warnings)
    assert grid.plots[9].warning.text() == "S10R: noisy (loose?)"
    assert all(not p.warning.text() for i, p in enumerate(grid.plots) if i != 9)


def test_nothing_new_means_no_redraw_but_expanding_redraws(grid):
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 10.0)
    grid.refresh()
    count = grid.redraw_count
    grid.refresh()
    assert grid.redraw_count == count  # same data, same view: skipped
    grid.set_collapsed(4, True)
    fill(history, 2.0, t0=10.0)
    grid.refresh()
    stale = grid.plots[4].curves[0].yData.copy()
    grid.set_collapsed(4, False)
    assert grid.redraw_count > count + 1
    assert len(grid.plots[4].curves[0].yData) != len(stale) or not np.array_equal(grid.plots[4].curves[0].yData, stale)


def _entry_x(legend: _Legend, index: int) -> int:
    """The x (in the legend) of the middle of entry ``index``'s name, from the same text as drawn."""
    from PySide6.QtGui import QTextDocument

    entries = legend.html.split("&nbsp;&nbsp; ")
    document = QTextDocument()
    document.setDefaultFont(legend.font())
    document.setDocumentMargin(0.0)
    document.setHtml("&nbsp;&nbsp; ".join(entries[:index]) + ("&nbsp;&nbsp; " if index else ""))
    before = document.idealWidth() if index else 0.0
    document.setHtml(entries[index])
    return int(legend.contentsMargins().left() + before + 0.6 * document.idealWidth())


def test_legend_click_hides_a_trace_at_the_next_redraw(grid, qtbot):
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 5.0)
    grid.refresh()
    plot = grid.plots[2]
    assert len(plot.bundle._lines) == 3
    assert "S03R" in plot.legend.html and plot.legend.isVisible()
    qtbot.mouseClick(plot.legend, Qt.MouseButton.LeftButton,
                     pos=QPoint(_entry_x(plot.legend, 1), plot.legend.height() // 2))  # S03R
    assert not plot.curves[1].isVisible() and plot.curves[0].isVisible() and plot.curves[2].isVisible()
    assert _Legend.HIDDEN_COLOR in plot.legend.html.split("&nbsp;&nbsp; ")[1]  # its entry is greyed
    grid.refresh()  # no new data, yet the picture changed: it redraws
    assert len(plot.bundle._lines) == 2
    assert [pen for pen, _ in plot.bundle._lines] == [plot.curves[0].opts["pen"], plot.curves[2].opts["pen"]]
    plot.legend.toggle(1)  # clicked again: back
    grid.refresh()
    assert len(plot.bundle._lines) == 3 and _Legend.HIDDEN_COLOR not in plot.legend.html


def test_the_legend_is_a_strip_outside_the_data_and_follows_labels_and_warnings(grid):
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 5.0)
    grid.refresh()
    for plot in grid.plots:
        # Outside the plot widget (above it), so no trace is ever under it.
        legend = plot.legend.geometry()
        assert legend.bottom() < plot.plot_widget.geometry().top() and legend.height() < 30
        assert not plot.plot_widget.geometry().intersects(legend)
    plot = grid.plots[0]
    assert not plot.legend.short and "S01L" in plot.legend.html and "S01B" in plot.legend.html
    grid.set_channel_labels([f"{name} (µS, uncal.)" for name in grid.channel_names])
    assert plot.legend.labels()[0] == "S01L (µS, uncal.)"
    # Too long for the strip at this width: the names, full labels in the tooltip.
    assert plot.legend.short and "S01L (µS, uncal.)" in plot.legend.toolTip()
    assert "S01L (µS, uncal.)" in plot.legend.overlay_html()  # the exported picture keeps the full labels
    warnings = [""] * 36
    warnings[1] = "saturated"
    grid.set_channel_warnings(warnings)
    entries = plot.legend.html.split("&nbsp;&nbsp; ")
    assert "┅┅" in entries[1] and "━━" in entries[0]  # the warned trace's line is dotted, in the legend too


def test_uncalibrated_sensors_get_their_own_microsiemens_axis_and_readout(grid):
    """One calibrated sensor (S06B, ~2 N) among uncalibrated ones (S06L/S06R in µS, ~300): the µS never land on
    the axis labelled N, and the cursor reads them in µS."""
    history = TraceHistory(len(NAMES), 4096)
    t = np.arange(300) / 30.0
    values = np.full((t.size, len(NAMES)), 300.0) + np.sin(t)[:, None]  # µS-sized numbers everywhere…
    values[:, 17] = 2.0 + 0.5 * np.sin(t)  # …but S06B is a force in N
    history.append(t, values)
    grid.set_history(history, "N")
    grid.set_channel_units(["N" if i == 17 else "µS" for i in range(len(NAMES))])
    grid.refresh(force=True)
    plot = grid.plots[5]  # Segment 6: S06L S06R S06B
    assert plot.alt is not None, "no separate axis for the µS channels"
    item = plot.plot_widget.getPlotItem()
    assert item.getAxis("right").isVisible() and "µS" in item.getAxis("right").labelText
    assert item.getAxis("left").labelText == "N"
    assert len(plot.bundle._lines) == 1 and len(plot.alt[1]._lines) == 2
    (_x0, _x1), (y0, y1) = plot.viewbox.viewRange()
    assert y0 < 1.5 and 2.5 < y1 < 10, f"the N axis was stretched by µS values: {y0}..{y1}"
    (_x0, _x1), (a0, a1) = plot.alt[0].viewRange()
    assert a0 < 299 and a1 > 301
    grid.hover_at(5, float(t[150]))
    text = plot.readout.text()
    assert "S06L:" in text and "µS" in text.split("S06L:")[1].splitlines()[0]
    assert " N" in text.split("S06B:")[1].splitlines()[0]
    # The readout sits inside the data area, over no axis (here the cursor is left of centre: top right).
    area = plot.plot_widget.mapFromScene(plot.viewbox.sceneBoundingRect()).boundingRect()
    box = plot.readout.geometry()
    assert area.left() <= box.left() and box.right() <= area.right() + 1 and box.top() >= area.top()
    assert box.right() < plot.plot_widget.width() - item.getAxis("right").width()
    grid.hover_at(5, float(t[-10]))  # cursor right of centre: the readout moves to the left, still off the axes
    box = plot.readout.geometry()
    assert area.left() <= box.left() and box.right() < area.center().x() + 1
    # A segment with no calibrated sensor: its left axis is in µS, with no empty N axis beside it.
    other = grid.plots[0]
    other_item = other.plot_widget.getPlotItem()
    assert other.units == "µS" and other_item.getAxis("left").labelText == "µS"
    assert not other_item.getAxis("right").isVisible() and len(other.bundle._lines) == 3
    (_x0, _x1), (o0, o1) = other.viewbox.viewRange()
    assert o0 < 299 and o1 > 301
    assert "S06L µS" in plot.legend.html or not plot.legend.short  # a shortened entry names its other unit
    grid.set_channel_units(None)
    assert not item.getAxis("right").isVisible()
    assert other.units == "N" and other_item.getAxis("left").labelText == "N"


def test_every_plot_saves_png_and_vector_svg_with_its_units(grid, qtbot, tmp_path):
    import xml.etree.ElementTree as ET

    from PySide6.QtGui import QImage
    from PySide6.QtWidgets import QGraphicsItem

    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 20.0)
    grid.refresh(force=True)
    asked: list[tuple[int, str]] = []
    grid.image_requested.connect(lambda index, kind: asked.append((index, kind)))
    actions = grid.plots[4].image_button.menu().actions()
    assert [a.text() for a in actions] == ["Save as PNG…", "Save as SVG…"]
    actions[1].trigger()
    assert asked == [(4, "svg")]

    png = grid.export_image(4, tmp_path / "seg5.png")
    image = QImage(str(png))
    plot = grid.plots[4].plot_widget
    assert image.width() >= plot.width() and image.height() > plot.height()
    colours = {image.pixelColor(x, y).name() for x in range(0, image.width(), 3) for y in range(0, image.height(), 3)}
    assert len(colours) > 5, "the PNG is blank"

    svg = grid.export_image(4, tmp_path / "seg5.svg")
    text = svg.read_text(encoding="utf-8")
    root = ET.fromstring(text)  # well-formed XML
    assert root.tag.endswith("svg")
    texts = [" ".join(e.itertext()).strip() for e in root.iter() if e.tag.endswith("text")]
    # Vector text, not a picture of it: the title, both axes with their units and the legend are SVG text.
    assert any(t.startswith("Segment 5") for t in texts)
    assert "N" in texts and "time before newest (s)" in texts
    assert {"S05L", "S05R", "S05B"} <= set(texts)
    assert "<path" in text or "<polyline" in text
    # The pixmap caches are back afterwards (live drawing stays cheap).
    axis = grid.plots[4].plot_widget.getPlotItem().getAxis("left")
    assert axis.cacheMode() == QGraphicsItem.CacheMode.DeviceCoordinateCache

    with pytest.raises(ValueError, match="png or .svg"):
        grid.export_image(4, tmp_path / "seg5.jpg")
    with pytest.raises(OSError, match="cannot write"):
        grid.export_image(4, tmp_path / "missing" / "seg5.png")


def test_trace_bounds_come_from_the_data_drawn(grid):
    """By design, not a fixed huge rect: each plot's traces are bounded by what they draw (plus the pen), so Qt's
    update-region arithmetic stays exact on a real display (±1e15 lost every exposed area on xcb)."""
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    fill(history, 20.0)
    grid.refresh(force=True)
    for plot in grid.plots:
        rect = plot.bundle.boundingRect()
        (x0, x1), (y0, y1) = plot.viewbox.viewRange()
        xs = np.concatenate([c.xData for c in plot.curves if c.xData is not None])
        ys = np.concatenate([c.yData for c in plot.curves if c.yData is not None])
        pad_x, pad_y = 0.05 * (x1 - x0), 0.05 * (y1 - y0)
        assert rect.left() >= xs.min() - pad_x and rect.right() <= xs.max() + pad_x, (plot.group.title, rect)
        assert rect.top() >= ys.min() - pad_y and rect.bottom() <= ys.max() + pad_y, (plot.group.title, rect)
        assert rect.contains(float(xs[len(xs) // 2]), float(ys[len(ys) // 2]))


class _Paints:
    """Paint events reaching each plot's viewport (what a real screen is sent)."""

    def __init__(self, grid: ForcePlotGrid) -> None:
        from PySide6.QtCore import QEvent, QObject

        counts = self.counts = [0] * len(grid.plots)

        class Filter(QObject):
            def __init__(self, index: int) -> None:
                super().__init__()
                self.index = index

            def eventFilter(self, obj, event):  # noqa: N802 - Qt override
                if event.type() == QEvent.Type.Paint:
                    counts[self.index] += 1
                return False

        self._filters = [Filter(i) for i in range(len(grid.plots))]
        for plot, f in zip(grid.plots, self._filters):
            plot.plot_widget.viewport().installEventFilter(f)


def test_the_twelve_segments_are_all_on_screen_at_the_default_window_size(qtbot):
    """The Forces tab's plot area at the default 1280×800 window (~880×590): every segment at once, 4 columns by 3
    rows, each a readable size; no scrolling, so nothing is out of view."""
    grid = ForcePlotGrid(NAMES)
    qtbot.addWidget(grid)
    grid.resize(880, 590)
    grid.show()
    qtbot.waitExposed(grid)
    qtbot.waitUntil(lambda: grid.shown_plots() == list(range(12)), timeout=10_000)
    assert grid.fits_view and grid.columns == 4
    for plot in grid.plots:
        assert plot.plot_widget.isVisible()
        assert plot.plot_widget.width() >= 180 and plot.plot_widget.height() >= 120, plot.plot_widget.size()
    qtbot.waitUntil(lambda: not grid.scroll_area.verticalScrollBar().isVisible(), timeout=10_000)
    grid.resize(1400, 1000)  # a bigger window: bigger plots, still all of them
    qtbot.waitUntil(lambda: grid.plots[0].plot_widget.height() > 200, timeout=10_000)
    assert grid.shown_plots() == list(range(12))


def test_plots_scrolled_out_of_view_are_hidden_not_painted_and_shown_when_scrolled_in(qtbot):
    grid = ForcePlotGrid(NAMES)
    qtbot.addWidget(grid)
    grid.resize(900, 380)  # too low for 3 rows of readable plots: fixed-height plots in a scrolling grid
    grid.show()
    qtbot.waitExposed(grid)
    qtbot.waitUntil(lambda: 0 < len(grid.shown_plots()) < 12, timeout=10_000)
    assert not grid.fits_view
    shown = grid.shown_plots()
    assert 0 in shown and 11 not in shown
    hidden = [i for i in range(12) if i not in shown]
    assert all(not grid.plots[i].plot_widget.isVisible() for i in hidden)  # really hidden, not merely covered
    history = TraceHistory.for_budget(36, 4_000_000)
    grid.set_history(history, "N")
    grid.start(30.0)
    paints = _Paints(grid)
    t0 = 0.0
    for _ in range(5):
        fill(history, 1.0, t0=t0)
        t0 += 1.0
        redraws = grid.redraw_count
        qtbot.waitUntil(lambda before=redraws: grid.redraw_count > before, timeout=10_000)
    qtbot.waitUntil(lambda: all(paints.counts[i] >= 3 for i in shown), timeout=10_000)
    assert all(paints.counts[i] == 0 for i in hidden), paints.counts
    stale = grid.plots[11].curves[0].xData
    assert stale is None  # never drawn while out of view

    grid.scroll_area.verticalScrollBar().setValue(grid.scroll_area.verticalScrollBar().maximum())
    qtbot.waitUntil(lambda: 11 in grid.shown_plots(), timeout=10_000)
    assert grid.plots[11].plot_widget.isVisible() and not grid.plots[0].plot_widget.isVisible()
    # Drawn at once with the newest data, and painted.
    assert grid.plots[11].curves[0].xData is not None and len(grid.plots[11].curves[0].xData) > 10
    qtbot.waitUntil(lambda: paints.counts[11] > 0, timeout=10_000)
    grid.stop()


def test_a_wide_board_shows_only_the_plots_in_view(qtbot):
    """1024 channels make 64 plots: only the few in view are shown (and so polished, laid out and painted)."""
    names = [f"C{i:04d}" for i in range(1024)]
    grid = ForcePlotGrid(names)
    qtbot.addWidget(grid)
    grid.resize(1200, 700)
    grid.show()
    qtbot.waitExposed(grid)
    qtbot.waitUntil(lambda: len(grid.shown_plots()) > 0, timeout=10_000)
    assert len(grid.plots) == 64 and not grid.fits_view
    assert 4 <= len(grid.shown_plots()) <= 16
    assert sum(p.plot_widget.isVisible() for p in grid.plots) == len(grid.shown_plots())
    grid.scroll_to_plot(63)
    qtbot.waitUntil(lambda: 63 in grid.shown_plots(), timeout=10_000)
    assert 0 not in grid.shown_plots()


def test_collapsing_a_plot_frees_its_room_and_the_next_row_moves_up(qtbot):
    grid = ForcePlotGrid(NAMES, columns=1)
    qtbot.addWidget(grid)
    grid.resize(600, 500)
    grid.show()
    qtbot.waitExposed(grid)
    qtbot.waitUntil(lambda: len(grid.shown_plots()) > 0, timeout=10_000)
    before = grid.shown_plots()
    top_of_second = grid.plots[1].y()
    grid.set_collapsed(0, True)
    qtbot.waitUntil(lambda: grid.plots[1].y() < top_of_second, timeout=10_000)
    assert not grid.plots[0].plot_widget.isVisible()
    qtbot.waitUntil(lambda: len(grid.shown_plots()) >= len(before), timeout=10_000)  # one more row came into view
    grid.set_collapsed(0, False)
    qtbot.waitUntil(lambda: grid.plots[0].plot_widget.isVisible(), timeout=10_000)


def test_a_long_warning_does_not_widen_its_column_and_is_kept_whole_in_the_tooltip(qtbot):
    grid = ForcePlotGrid(NAMES)
    qtbot.addWidget(grid)
    grid.resize(880, 590)
    grid.show()
    qtbot.waitExposed(grid)
    qtbot.waitUntil(lambda: grid.shown_plots() == list(range(12)), timeout=10_000)
    warnings = [""] * 36
    warnings[35] = "flat-lined, saturated, noisy (loose?), drifting below its rest level"
    grid.set_channel_warnings(warnings)
    qtbot.waitUntil(lambda: grid.plots[11].warning.width() > 0, timeout=10_000)
    widths = [plot.plot_widget.width() for plot in grid.plots]
    assert max(widths) - min(widths) <= 4, widths  # seen: the warning's column 335 px, the others 190
    label = grid.plots[11].warning
    assert label.text() == label.toolTip() == f"S12B: {warnings[35]}"
    assert label.fontMetrics().horizontalAdvance(QLabel.text(label)) <= label.width()  # what is shown fits


class _Resizes(QObject):
    """Counts the resizes of each plot's PlotWidget (an event filter)."""

    def __init__(self) -> None:
        super().__init__()
        self.counts: dict[int, int] = {}

    def watch(self, index: int, widget: QWidget) -> None:
        self.counts.setdefault(index, 0)
        widget.installEventFilter(self)
        widget.setProperty("plot_index", index)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt override
        # A plot's first size (from none: a plot out of view gets it when it is first laid out) is not a resize.
        if event.type() == QEvent.Type.Resize and event.oldSize().isValid():
            self.counts[watched.property("plot_index")] += 1
        return False


@pytest.mark.parametrize("size", [(880, 590), (900, 380)], ids=["rows fitted to the view", "scrolling"])
def test_a_grid_built_a_plot_at_a_time_never_resizes_the_plots_already_there(qtbot, size):
    """The Forces tab builds its plots one per turn of the event loop: each is put where it stays and at its size, so
    the plots already shown are not laid out and redrawn again at each step; the whole grid is then as one built at
    once."""
    whole = ForcePlotGrid(NAMES)
    qtbot.addWidget(whole)
    whole.resize(*size)
    whole.show()
    qtbot.waitExposed(whole)
    grid = ForcePlotGrid(NAMES, build_plots=False)
    qtbot.addWidget(grid)
    grid.resize(*size)
    grid.show()
    qtbot.waitExposed(grid)
    resizes = _Resizes()
    more = True
    while more:
        more = grid.add_next_plot()
        newest = len(grid.plots) - 1
        qtbot.wait(20)  # the step's layout and paints, as a turn of the event loop after a step
        resizes.watch(newest, grid.plots[newest].plot_widget)
    assert resizes.counts == dict.fromkeys(range(12), 0)  # no plot resized after the step that built it
    qtbot.waitUntil(lambda: whole.shown_plots() == grid.shown_plots(), timeout=10_000)
    assert (grid.columns, grid.plot_height, grid.fits_view) == (whole.columns, whole.plot_height, whole.fits_view)
    assert grid._inner.minimumHeight() == whole._inner.minimumHeight()  # noqa: SLF001 - no height held in reserve
    qtbot.waitUntil(lambda: [p.geometry() for p in grid.plots] == [p.geometry() for p in whole.plots], timeout=10_000)
    assert [p.plot_widget.size() for p in grid.plots] == [p.plot_widget.size() for p in whole.plots]
