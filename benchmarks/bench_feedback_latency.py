"""Force-feedback latency in the app as ``sensnake gui`` runs it: the simulated lab in its own process, the control
loop in another, the GUI (Forces tab estimating, Gait tab playing with feedback) in neither.

Each tick the feedback motion notes how old the forces it used were: from the board frame's arrival at the host to
the tick that read them (``FeedbackProgress.force_age_s``); the goal it changes is written in that same tick. The
target (issue 24): at most one board period plus one control tick (33 + 20 = 53 ms at 30 Hz and 50 Hz). The GUI
drains the board every 33 ms (``board_bridge.DEFAULT_DRAIN_HZ``), which the latency includes.

``python -m benchmarks.bench_feedback_latency [--seconds S]`` (offscreen Qt; the lab's processes are real).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np


def run(seconds: float) -> dict[str, float]:
    from dataclasses import replace

    from app.core.force_control import FeedbackProgress
    from app.core.shapes import Shape
    from benchmarks.app_session import app_session
    from devices.config import LabConfig, SimLabConfig

    config = replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))
    angles = [0.0] * 12
    for joint in (2, 4, 6, 8):
        angles[joint] = -0.3
    ages: list[float] = []
    with app_session("bench_feedback_latency", config, Shape("wave", tuple(config.robot.axes), tuple(angles))) as (
            _lab, _forces, gait, pump):
        gait.panel.set_mode("follow")
        gait.panel.speed_spin.setValue(0.1)
        gait.panel.controller_combo.setCurrentIndex(gait.panel.controller_combo.findData("feedback"))
        gait.panel.play_button.click()
        pump(20_000, until=lambda: isinstance(getattr(gait.source, "progress", None), FeedbackProgress))
        last = None
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            pump(5)
            progress = getattr(gait.source, "progress", None)
            if isinstance(progress, FeedbackProgress) and progress is not last:
                last = progress
                if math.isfinite(progress.force_age_s):
                    ages.append(progress.force_age_s)
    values = np.array(ages) * 1000
    return {"ticks": float(len(values)), "p50_ms": float(np.percentile(values, 50)) if len(values) else math.nan,
            "p95_ms": float(np.percentile(values, 95)) if len(values) else math.nan,
            "max_ms": float(values.max()) if len(values) else math.nan}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    figures = run(parser.parse_args().seconds)
    print("force-feedback latency, board frame's arrival at the host → the tick that writes the goal it changes "
          "(lab and loop in their own processes, GUI draining at 30 Hz); target ≤ 53 ms (one board period + one "
          "tick)")
    print(f"ticks {figures['ticks']:.0f}  median {figures['p50_ms']:.1f} ms  p95 {figures['p95_ms']:.1f} ms  "
          f"max {figures['max_ms']:.1f} ms")


if __name__ == "__main__":
    main()
