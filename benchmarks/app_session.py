"""The app as ``sensnake gui`` runs it on the physics lab, for the benchmarks that drive its tabs from a script: the
simulated lab and the control loop in their own processes, the robot connected, the board streaming, a Forces tab
estimating with the simulated sensors' own calibration and a Gait tab with a shape library of its own.

    with app_session("bench_x", config, shape) as (lab, forces, gait, pump): ...

``pump(ms, until)`` runs the Qt event loop for at most ``ms`` milliseconds (until ``until()`` is true). Offscreen Qt
unless the caller set a platform. One thread: the caller's (the GUI thread).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

Pump = Callable[..., None]


@contextlib.contextmanager
def app_session(who: str, config: Any, shape: Any) -> Iterator[tuple[Any, Any, Any, Pump]]:
    """(lab, forces tab, gait tab, pump) with ``shape`` (an :class:`app.core.shapes.Shape`) in the Gait tab's
    library; everything closed afterwards. ``who`` names the caller in a failure."""
    from PySide6.QtCore import QCoreApplication, QEventLoop
    from PySide6.QtWidgets import QApplication

    import widgets  # noqa: F401 - installs the PySide6 refcount guard before Qt is used
    from app.core.shapes import ShapeLibrary
    from app.gui.lab import LabContext
    from app.gui.tabs.forces import ForcesTab
    from app.gui.tabs.gait import GaitTab
    from devices import factory

    app = QApplication.instance() or QApplication([])

    def pump(ms: float, until: Callable[[], bool] | None = None) -> None:
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
            library.save(shape)
            forces, gait = ForcesTab(lab), GaitTab(lab, library)
            cal = Path(tmp) / "sim.json"
            # the simulated board's own sensor models (the lab's process answers by name)
            cal.write_text(json.dumps(factory.sim_lab().board.ground_truth_calibration()), encoding="utf-8")
            if not forces.load_calibration(cal):
                raise SystemExit(f"{who}: the simulated sensors' calibration did not load")
            pump(30_000, until=lambda: not forces.is_loading_calibration)
            yield lab, forces, gait, pump
            lab.robot.stop_motion()
            pump(2_000)
        finally:
            lab.close()
            app.processEvents()
