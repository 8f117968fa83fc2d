"""Every plot's numbers stay in its axis's own unit (widgets.theme.no_si_prefix), whatever range it showed when its
unit was set: a Forces plot whose unit was set while it held only micro-newtons drew 2 N as "2e+06"."""

from __future__ import annotations

import pyqtgraph as pg

from widgets import theme


def test_numbers_stay_in_the_unit_after_a_micro_range(qtbot):
    axis = pg.AxisItem("left")
    axis.setLabel("force", units="N")
    axis.setRange(0.0, 6.5e-7)  # an unloaded sensor's sub-micronewton wiggle, when the unit is set
    theme.no_si_prefix(axis)
    axis.setRange(0.0, 2.2)  # then a loaded one
    assert axis.autoSIPrefixScale == 1.0 and axis.labelUnitPrefix == ""
    assert axis.tickStrings([0.5, 1.0, 2.0], axis.autoSIPrefixScale, 0.5) == ["0.5", "1.0", "2.0"]


def test_the_forces_grid_reads_newtons_as_newtons_after_a_unit_change(qtbot):
    from widgets.force_plots import ForcePlotGrid

    names = [f"S{k:02d}{side}" for k in range(1, 13) for side in "LRB"]
    grid = ForcePlotGrid(names)
    qtbot.addWidget(grid)
    for plot in grid.plots:
        plot.plot_widget.getPlotItem().getAxis("left").setRange(0.0, 6.5e-7)
    grid.set_units("µS")
    grid.set_units("N")
    for plot in grid.plots:
        axis = plot.plot_widget.getPlotItem().getAxis("left")
        axis.setRange(0.0, 2.2)
        assert axis.autoSIPrefixScale == 1.0, plot
