"""The Plots dock on a real X screen: a user puts joint 5's current and S06B's force on linked time axes, live and on
a reopened recording, and the layout reopens — read back from the X server (``probe_plots.py``)."""

from __future__ import annotations

import pytest

from tests.realdisplay.xserver import run_probe

pytestmark = pytest.mark.realdisplay

J5_CURRENT, S06B_FORCE = "robot/J5/current_mA", "forces/S06B/force_N"
MIN_TRACE_PIXELS = 40  # a drawn trace across a plot colours hundreds of pixels; an empty plot none


def test_joint_5_current_and_s06b_force_live_and_recorded_on_linked_axes_and_the_layout_reopens(x_display):
    result = run_probe(x_display, "plots", "3", module="tests.realdisplay.probe_plots", timeout_s=240.0)
    assert result["keys_live"] == [[J5_CURRENT], [S06B_FORCE]] and result["linked"], result
    assert "J5 current (mA)" in result["headers_live"][0] and "S06B force (N)" in result["headers_live"][1]
    live = result["live"]
    assert live["visible"]
    # live: the dock repaints as the data arrive and its pixels on the X server change (floors well under the
    # measured ~30/s: the machine is shared)
    assert live["frames_per_s"] >= 8.0, live
    assert live["changed"] >= 0.6, live
    assert all(n >= MIN_TRACE_PIXELS for n in result["live_pixels"]), result["live_pixels"]
    # the recording reopened in the same plots draws both series
    assert result["source_recorded"].startswith("Recording:"), result["source_recorded"]
    assert result["keys_recorded"] == [[J5_CURRENT], [S06B_FORCE]]
    assert all(n >= MIN_TRACE_PIXELS for n in result["recorded_pixels"]), result["recorded_pixels"]
    # the layout saved beside it, the plots emptied, the recording opened again: the layout and its traces are back
    assert [p["series"] for p in result["layout_file"]["plots"]] == [[J5_CURRENT], [S06B_FORCE]]
    assert result["cleared_plots"] == 0
    assert result["keys_reopened"] == [[J5_CURRENT], [S06B_FORCE]], result["message"]
    assert "plots.json opened" in result["message"]
    assert all(n >= MIN_TRACE_PIXELS for n in result["reopened_pixels"]), result["reopened_pixels"]
