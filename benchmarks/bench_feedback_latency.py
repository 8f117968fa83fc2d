"""Force-feedback latency in the app as ``sensnake gui`` runs it: the simulated lab in its own process, the control
loop in another, the GUI (Forces tab estimating, Gait tab playing with feedback) in neither.

The latency: from a board frame's arrival at the host to the goal it changes, i.e. to the first
control tick that uses it (``FeedbackProgress.frame_latency_s``; the goal is written in that tick). Target: at most
one board period plus one control tick (33 + 20 = 53 ms at 30 Hz and 50 Hz). It includes the GUI's drain of the
board (every 17 ms for a 30 Hz board, ``board_bridge``), the estimate and the wait for the tick. Also printed: how
old the forces are at every tick (``force_age_s``; a frame serves ~1.7 ticks, so this adds up to a board period).

``python -m benchmarks.bench_feedback_latency [--seconds S]`` (offscreen Qt; the lab's processes are real).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

TARGET_MS = 1000 / 30 + 1000 / 50  # one board period plus one control tick


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
    latencies: list[float] = []
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
                if math.isfinite(progress.frame_latency_s):
                    latencies.append(progress.frame_latency_s)
    return {**_figures("", latencies), **_figures("age_", ages)}


def _figures(prefix: str, seconds: list[float]) -> dict[str, float]:
    values = np.array(seconds) * 1000
    some = len(values) > 0
    return {f"{prefix}count": float(len(values)),
            f"{prefix}p50_ms": float(np.percentile(values, 50)) if some else math.nan,
            f"{prefix}p95_ms": float(np.percentile(values, 95)) if some else math.nan,
            f"{prefix}p99_ms": float(np.percentile(values, 99)) if some else math.nan,
            f"{prefix}over_target": float(np.mean(values > TARGET_MS)) if some else math.nan,
            f"{prefix}max_ms": float(values.max()) if some else math.nan}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    figures = run(parser.parse_args().seconds)
    print("force-feedback latency, board frame's arrival at the host → the first tick that uses it (writes the goal "
          "it changes); lab and loop in their own processes; target ≤ 53 ms (one board period + one tick)")
    print(f"frames {figures['count']:.0f}  median {figures['p50_ms']:.1f} ms  p95 {figures['p95_ms']:.1f} ms  "
          f"p99 {figures['p99_ms']:.1f} ms  max {figures['max_ms']:.1f} ms  over the target "
          f"{100 * figures['over_target']:.1f} %")
    print(f"age of the forces at every tick: ticks {figures['age_count']:.0f}  median {figures['age_p50_ms']:.1f} ms  "
          f"p95 {figures['age_p95_ms']:.1f} ms  max {figures['age_max_ms']:.1f} ms")


if __name__ == "__main__":
    main()
