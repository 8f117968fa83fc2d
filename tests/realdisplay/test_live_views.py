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
