"""Force-feedback plays in the app on a busy machine: the simulated lab and the control loop in their own processes
(as ``sensnake gui`` runs them), the Forces tab estimating and publishing to the shared force page, the Gait tab
playing a taught shape with Controller → feedback, and ``--load`` busy processes beside them (one ``while True``
process each: ``--load 10`` on 2 cores is a load of about 10, a lab PC running motion capture and a browser).

For each play: how it ended (finished, or the fault the Gait tab reported), the control loop's missed 50 Hz ticks
during it, and how many ticks fell back to the feedforward because the forces were older than 100 ms (stale: the
price of the load, said and counted, never a fault). Target: every play ends as planned (0 faults), 0 missed ticks in
at least 9 of 10 plays.

``python -m benchmarks.bench_feedback_under_load [--plays 10] [--seconds 60] [--load 10]`` (offscreen Qt)
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from typing import Any


def run(plays: int, seconds: float, load: int) -> list[dict[str, Any]]:
    from dataclasses import replace

    from app.core.force_control import FeedbackProgress
    from app.core.shapes import Shape
    from app.gui.robot_bridge import MOTION_RUNNING
    from benchmarks.app_session import app_session
    from devices.config import LabConfig, SimLabConfig

    config = replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))
    angles = [0.0] * 12
    for joint in (2, 4, 6, 8):
        angles[joint] = -0.3
    results: list[dict[str, Any]] = []
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        with app_session("bench_feedback_under_load", config,
                         Shape("wave", tuple(config.robot.axes), tuple(angles))) as (lab, _forces, gait, pump):
            gait.panel.set_mode("follow")
            gait.panel.speed_spin.setValue(0.1)
            gait.panel.controller_combo.setCurrentIndex(gait.panel.controller_combo.findData("feedback"))
            for _ in range(plays):
                before = lab.robot.loop_stats()
                gait.panel.play_button.click()
                pump(20_000, until=lambda: lab.robot.motion_state == MOTION_RUNNING)
                stale = ticks = 0
                last = None
                end = time.monotonic() + seconds
                while time.monotonic() < end and lab.robot.motion_state == MOTION_RUNNING:
                    pump(5)
                    progress = getattr(gait.source, "progress", None)
                    if isinstance(progress, FeedbackProgress) and progress is not last:
                        last = progress
                        ticks += 1
                        stale += any("no force estimate" in why for _, why in progress.fallback)
                state = lab.robot.motion_state
                if state == MOTION_RUNNING:
                    lab.robot.stop_motion()
                    pump(3_000, until=lambda: lab.robot.motion_state != MOTION_RUNNING)
                after = lab.robot.loop_stats()
                missed = (after.missed_ticks - before.missed_ticks) if before is not None and after is not None \
                    else -1
                status = gait.panel.status_label.text() if hasattr(gait.panel, "status_label") else ""
                results.append(dict(state=state, status=status, missed=missed, stale=stale, ticks=ticks))
    finally:
        for process in busy:
            process.kill()
            process.wait()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--plays", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=60.0, help="each play runs this long at most (wall s)")
    parser.add_argument("--load", type=int, default=10, help="busy processes beside the app")
    args = parser.parse_args()
    results = run(args.plays, args.seconds, args.load)
    print(f"feedback plays under load: {args.plays} plays of at most {args.seconds:.0f} s, {args.load} busy processes")
    faults = 0
    for k, r in enumerate(results, 1):
        fault = "cannot start" in r["status"] or "stopped:" in r["status"] or r["state"] == "fault"
        faults += fault
        print(f"  play {k:2d}: {r['state']:<9} missed ticks {r['missed']:4d}  stale-force ticks {r['stale']:4d} of "
              f"{r['ticks']}  {r['status'] if fault else ''}")
    clean = sum(1 for r in results if r["missed"] == 0)
    print(f"faults {faults} (target 0); plays with 0 missed ticks {clean} of {len(results)} (target ≥ 9 of 10)")


if __name__ == "__main__":
    main()
