"""Motion capture in the app, on a real X screen: the physics lab with ``[lab] mocap = true``, a serpenoid gait
playing, a few seconds recorded from the Forces tab while the 3-D tab shows the motion capture. The X server's pixels
show the markers drawn over the simulated body and the kinematics panel moving; the recording holds ``/mocap``
stamped at capture, every sample of the 960 Hz stream. (``benchmarks/bench_mocap_gui.py`` runs the same for 60 s and
counts the control loop's missed ticks.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.realdisplay.xserver import PROBE_TIMEOUT_S, ROOT, probe_env

pytestmark = [pytest.mark.realdisplay, pytest.mark.slow]

SECONDS = 6.0


def test_the_3d_tab_and_the_kinematics_plot_show_the_motion_capture_while_it_records(x_display, tmp_path):
    pytest.importorskip("devices.sim.physics.world")
    env = probe_env(x_display)
    env["PROBE_PICTURES"] = str(tmp_path)
    assert "LSLAPICFG" in os.environ  # tests/conftest.py: LSL discovery stays on this machine, in the probe too
    done = subprocess.run([sys.executable, "-m", "tests.realdisplay.mocap_probe", str(SECONDS)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=PROBE_TIMEOUT_S + 240)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert done.returncode == 0 and lines, f"probe failed (exit {done.returncode}):\n{done.stdout[-2000:]}\n" \
                                           f"{done.stderr[-3000:]}"
    result = json.loads(lines[-1])
    pictures = f"(pictures in {tmp_path}; {result})"
    assert result["picker"].startswith("Mocap: simulated") and "following" in result["mocap_status"], pictures
    # the 3-D picture: live, and the motion-captured markers drawn over the simulated body (the only blue there)
    scene = result["views"]["scene"]
    assert not result["render_error"] and scene["visible"] and scene["changed"] >= 0.3, pictures
    assert result["mocap_pixels"]["scene"] >= 100, pictures
    # the kinematics panel: the side view draws the body and its markers; the positions against time move
    assert result["mocap_pixels"]["kinematics_body"] >= 300, pictures
    time_plot = result["views"]["kinematics_time"]
    assert time_plot["visible"] and time_plot["changed"] >= 0.5 and time_plot["frames_per_s"] >= 2.0, pictures
    assert result["mocap_pixels"]["kinematics_time"] > 0 or result["live_poses"] > 0, pictures
    # the recording: /mocap stamped at capture, every sample the 960 Hz stream sent while it recorded
    assert result["has_mocap"] and "stamped at capture" in result["clock_offset_how"], pictures
    assert "mocap:" in result["stopped"] and "written to" in result["stopped"], pictures
    span = result["mocap_span_s"][1] - result["mocap_span_s"][0]
    assert result["mocap_rate_hz"] == 960.0 and result["mocap_samples"] >= 0.97 * 960.0 * span, pictures
    assert span >= 0.9 * SECONDS and result["max_gap_s"] < 2.5 / 960.0, pictures
    assert result["posed_fraction"] > 0.95, pictures
    assert result["ticks"] >= 0.8 * 50.0 * SECONDS, pictures  # the loop ran at its 50 Hz throughout
