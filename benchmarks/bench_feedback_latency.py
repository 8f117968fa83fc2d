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
import json
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")


def run(seconds: float) -> dict[str, float]:
    from dataclasses import replace

    from PySide6.QtCore import QCoreApplication, QEventLoop
    from PySide6.QtWidgets import QApplication

    import widgets  # noqa: F401 - installs the PySide6 refcount guard before Qt is used
    from app.core.force_control import FeedbackProgress
    from app.core.shapes import Shape, ShapeLibrary
    from app.gui.lab import LabContext
    from app.gui.tabs.forces import ForcesTab
    from app.gui.tabs.gait import GaitTab
    from devices import factory
    from devices.config import LabConfig, SimLabConfig

    app = QApplication.instance() or QApplication([])
    config = replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))

    def pump(ms: float, until=None) -> None:
        deadline = time.monotonic() + ms / 1000
        while time.monotonic() < deadline:
            QCoreApplication.processEvents(QEventLoop.ProcessEventsFlag.AllEvents, 20)
            if until is not None and until():
                return
            time.sleep(0.005)  # a benchmark's own loop, not a test

    with tempfile.TemporaryDirectory() as tmp:
        lab = LabContext(config, lab_process=True)
        try:
            lab.robot.connect_robot()
            lab.board.start()
            pump(30_000, until=lambda: lab.robot.is_connected and lab.robot.latest_state is not None)
            library = ShapeLibrary(Path(tmp) / "shapes")
            angles = [0.0] * 12
            for joint in (2, 4, 6, 8):
                angles[joint] = -0.3
            library.save(Shape("wave", tuple(config.robot.axes), tuple(angles)))
            forces, gait = ForcesTab(lab), GaitTab(lab, library)
            cal = Path(tmp) / "sim.json"
            # the simulated board's own sensor models (the lab's process answers by name)
            cal.write_text(json.dumps(factory.sim_lab().board.ground_truth_calibration()), encoding="utf-8")
            if not forces.load_calibration(cal):
                raise SystemExit("bench_feedback_latency: the simulated sensors' calibration did not load")
            gait.panel.set_mode("follow")
            gait.panel.speed_spin.setValue(0.1)
            gait.panel.controller_combo.setCurrentIndex(gait.panel.controller_combo.findData("feedback"))
            gait.panel.play_button.click()
            pump(20_000, until=lambda: isinstance(getattr(gait.source, "progress", None), FeedbackProgress))
            ages: list[float] = []
            last = None
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                pump(5)
                progress = getattr(gait.source, "progress", None)
                if isinstance(progress, FeedbackProgress) and progress is not last:
                    last = progress
                    if math.isfinite(progress.force_age_s):
                        ages.append(progress.force_age_s)
            lab.robot.stop_motion()
            pump(2000)
        finally:
            lab.close()
            app.processEvents()
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
