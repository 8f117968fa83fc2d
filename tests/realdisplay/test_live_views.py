"""Every live view changes on a real X screen while its data changes, and repaints at a live rate.

Each test runs the app in a subprocess on Xvfb with Qt's xcb platform (``probe.py``), counts the paint events that
reach the view and compares 100-ms screen grabs read back from the X server. Rates are floors well under the
measured ones (the machine is shared); ``benchmarks/bench_forces_gui.py`` measures the targets themselves.
"""

from __future__ import annotations

import pytest

from tests.realdisplay.xserver import run_probe

pytestmark = pytest.mark.realdisplay

MOVING = 0.6  # the pixels changed in at least this fraction of the 100-ms intervals


def _check_live(result: dict, name: str, min_frames_per_s: float, min_changed: float = MOVING) -> None:
    view = result["views"][name]
    assert view["visible"], f"{name} is not visible"
    assert view["changed"] >= min_changed, (
        f"{name}: the X server's pixels changed in only {100 * view['changed']:.0f} % of 100-ms intervals "
        f"(>= {100 * min_changed:.0f} % expected while its data changes): {view}")
    assert view["frames_per_s"] >= min_frames_per_s, (
        f"{name}: {view['frames_per_s']:.1f} paints/s reach it on X (>= {min_frames_per_s} expected): {view}")


def test_forces_plots_and_body_map_repaint_on_x(x_display):
    result = run_probe(x_display, "forces")
    plots = [name for name in result["views"] if name.startswith("plot")]
    assert len(plots) >= 6, f"too few plots on screen: {plots}"
    for name in plots:
        _check_live(result, name, min_frames_per_s=12.0)  # a ±1e15 trace rect gives ~0.4/s here
    _check_live(result, "body_map", min_frames_per_s=2.0)


def test_teach_live_joints_and_shape_repaint_on_x_and_rest_when_idle(x_display):
    result = run_probe(x_display, "teach")
    _check_live(result, "body_view", min_frames_per_s=5.0)
    _check_live(result, "sliders", min_frames_per_s=5.0)
    idle = result["idle"]["views"]["panel"]
    assert idle["changed"] == 0.0, f"the idle Teach panel's pixels kept changing: {idle}"
    assert idle["frames_per_s"] <= 2.0, f"the Teach panel repaints while nothing changes: {idle}"


def test_gait_progress_repaints_on_x(x_display):
    result = run_probe(x_display, "gait")
    for name in ("body_view", "progress", "joint_table"):
        _check_live(result, name, min_frames_per_s=5.0)


def test_calibration_live_trace_repaints_on_x(x_display):
    result = run_probe(x_display, "calibration")
    _check_live(result, "live_trace", min_frames_per_s=2.0, min_changed=0.4)  # samples arrive at a few Hz


def test_hardware_status_repaints_on_x(x_display):
    result = run_probe(x_display, "hardware")
    _check_live(result, "servo_table", min_frames_per_s=5.0)


def test_the_3d_lab_repaints_on_x_while_the_simulated_body_moves(x_display):
    pytest.importorskip("devices.sim.physics.world")
    result = run_probe(x_display, "scene")
    # Rendered at most 10 Hz (offscreen GL, ~0.1 s a frame under load here): floors well under that.
    _check_live(result, "scene", min_frames_per_s=2.0, min_changed=0.3)


def _overlap(a: list[int], b: list[int]) -> bool:
    return not (a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1])


def test_forces_layout_on_x_history_legends_axes_and_readout(x_display, tmp_path, monkeypatch):
    """The Forces tab as a new user meets it, on X (pictures saved in the test's tmp folder, named in failures):
    it opens with the past the board already sent; legends never cover the data; with one sensor calibrated only
    that sensor's plot has two axes and the others keep their µS on the left; the cursor readout covers no axis."""
    monkeypatch.setenv("PROBE_PICTURES", str(tmp_path))
    result = run_probe(x_display, "forces_layout")
    pictures = f"(pictures in {tmp_path})"
    streamed, on_open = result["streamed_s"], result["history_on_open_s"]
    assert on_open is not None and on_open[1] - on_open[0] >= 0.8 * (streamed[1] - streamed[0]), (
        f"the tab opened with {on_open} of the {streamed} s the board had sent {pictures}")
    plots = result["plots"]
    assert len(plots) == 12, pictures
    for plot in plots:
        assert not _overlap(plot["legend"], plot["data"]), f"{plot['title']}: legend over the data {pictures}"
        assert plot["legend"][3] < plot["data"][1], plot
    segment6 = next(p for p in plots if p["title"] == "Segment 6")
    assert segment6["left_label"] == "N" and segment6["right_visible"] and "µS" in segment6["right_label"], segment6
    for plot in plots:
        if plot["title"] != "Segment 6":
            assert plot["left_label"] == "µS" and not plot["right_visible"], f"{plot} {pictures}"
    for readout in result["readouts"]:
        assert readout["visible"] and "S06B" in readout["text"], readout
        # Inside the data area (the axes, their labels and numbers, are all outside it; their bounding boxes
        # reach a few pixels in with the tick marks).
        box, data = readout["readout"], readout["data"]
        assert data[0] <= box[0] and box[2] <= data[2] + 1 and data[1] <= box[1], (
            f"the readout is not inside the data area, so it covers an axis: {readout} {pictures}")
        for axis in readout["axes"]:
            outside = [max(axis[0], data[2] + 2), axis[1], axis[2], axis[3]] if axis[0] > data[0] else (
                [axis[0], axis[1], min(axis[2], data[0] - 2), axis[3]])
            if axis[1] > data[3] - 20:  # the bottom axis: its part below the data
                outside = [axis[0], max(axis[1], data[3] + 2), axis[2], axis[3]]
            assert not _overlap(box, outside), f"the readout covers an axis: {readout} {pictures}"


def test_the_gait_drawing_and_the_event_log_both_stay_readable_at_1280x800_on_x(x_display, tmp_path, monkeypatch):
    """Opening the event log under the Gait tab at the default window size squeezed the body drawing to a sliver on
    a real display: with its aspect locked, each view then spanned ±60 m across and the robot was a dot."""
    monkeypatch.setenv("PROBE_PICTURES", str(tmp_path))
    result = run_probe(x_display, "gait_log")
    pictures = f"(picture in {tmp_path}; {result})"
    for name, (x0, x1, _y0, _y1) in result["ranges"].items():
        before = result["ranges_before"][name]
        assert x1 - x0 <= 1.5 * (before[1] - before[0]) + 0.01, f"the {name} view spans {x1 - x0:.1f} m {pictures}"
    assert result["log_height"] >= 120, f"the event log is left too little room {pictures}"
    assert result["play_visible"], pictures
