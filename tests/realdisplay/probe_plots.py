"""Inside a subprocess on a real X display (QT_QPA_PLATFORM=xcb): the Plots dock as a user drives it, read back from
the X server. Prints one JSON line.

    DISPLAY=:N QT_QPA_PLATFORM=xcb python -m tests.realdisplay.probe_plots plots [seconds]

``plots``: the app on the simulated lab with the Forces tab shown and a calibration loaded, joint 5 swinging; the
user opens View ▸ Plots, finds joint 5's current by searching and double-clicks it, drags S06B's force below it (a
second plot, its time axis linked); the dock's paints and pixels are measured live. Then a recording is made, opened
in the dock, its layout saved beside it, the plots emptied, the recording opened again (the layout comes back with
it). At each step the pixels of each plot's data area in the traces' colours are counted on the X server's screen.
GUI thread only.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PySide6.QtCore import QCoreApplication, QPointF, QRect, Qt, QTimer
from PySide6.QtGui import QColor, QDropEvent, QImage
from PySide6.QtWidgets import QApplication

from tests.realdisplay.probe import (
    WAIT_S,
    PaintCounter,
    _save,
    fail,
    grab,
    measure,
    open_app,
    pump,
    pump_until,
)

J5_CURRENT, S06B_FORCE = "robot/J5/current_mA", "forces/S06B/force_N"


class SwingJoint5:
    """Joint 5 swings ±0.25 rad at 0.5 Hz for ``duration_s`` (its current changes with it)."""

    def __init__(self, duration_s: float = 120.0) -> None:
        self.duration_s = duration_s
        self.start: np.ndarray | None = None

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        if t_s > self.duration_s:
            return None
        if self.start is None:
            self.start = present_rad.copy()
        goal = self.start.copy()
        goal[4] += 0.25 * math.sin(2 * math.pi * 0.5 * t_s)
        return goal


def colour_pixels(image: QImage, rect: QRect, colour: str, tolerance: int = 40) -> int:
    """Pixels of ``image`` inside ``rect`` within ``tolerance`` (per channel) of ``colour``."""
    image = image.convertToFormat(QImage.Format.Format_RGB32)
    width, height = image.width(), image.height()
    data = np.frombuffer(image.constBits(), dtype=np.uint8, count=image.sizeInBytes())
    pixels = data.reshape(height, image.bytesPerLine() // 4, 4)[:, :width, :3].astype(int)  # B, G, R
    target = QColor(colour)
    bgr = np.array([target.blue(), target.green(), target.red()])
    box = rect.intersected(QRect(0, 0, width, height))
    area = pixels[box.top():box.bottom() + 1, box.left():box.right() + 1]
    return int(np.sum(np.all(np.abs(area - bgr) <= tolerance, axis=2)))


def plot_pixels(view) -> list[int]:
    """For each plot of the view: pixels of its data area in its first trace's colour, on the X screen."""
    from widgets import theme

    viewport = view.graphics.viewport()
    image = grab(viewport)
    counts = []
    for plot in view.plots:
        rect = view.graphics.mapFromScene(plot.vb.sceneBoundingRect()).boundingRect()
        counts.append(colour_pixels(image, rect, theme.series_color(0)))
    return counts


def drop_on_new_plot(view, key: str) -> None:
    mime = view.picker.tree.mimeData([view.picker.leaf(key)])
    point = view.graphics.mapFromScene(view._strip.sceneBoundingRect().center())  # noqa: SLF001 - the strip
    event = QDropEvent(QPointF(point), Qt.DropAction.CopyAction, mime, Qt.MouseButton.LeftButton,
                       Qt.KeyboardModifier.NoModifier)
    view.graphics.dropEvent(event)


def scenario_plots(window, page, seconds: float) -> dict:
    lab = window.lab
    from tests.calibration_files import write_typical_calibration

    cal = write_typical_calibration(Path(tempfile.mkdtemp()) / "typical.json", lab.config.board.channel_names)
    page.load_calibration(cal)
    pump_until(lambda: not getattr(page, "is_loading_calibration", False), what="the calibration")
    pump_until(lambda: lab.robot.is_connected, what="the robot")
    lab.robot.set_torque(True).result(timeout=30)
    lab.robot.run_motion(SwingJoint5(), "swing joint 5")
    dock = window.plots_dock
    view = dock.view
    window.plots_action.trigger()  # View ▸ Plots
    pump_until(lambda: dock.isVisible() and dock.subscribed, what="the Plots dock")
    view.picker.search.setText("J5 current")
    view.picker.tree.itemDoubleClicked.emit(view.picker.leaf(J5_CURRENT), 0)
    view.picker.search.setText("S06B force")
    drop_on_new_plot(view, S06B_FORCE)
    view.picker.search.setText("")

    def drawn(plot: int) -> int:
        item = view.plots[plot].curves[0]
        return 0 if item.yData is None else int(np.isfinite(item.yData).sum())

    pump_until(lambda: len(view.plots) == 2 and drawn(0) > 30 and drawn(1) > 30, what="both live series drawn")
    pump(1500)  # the y ranges settle
    result: dict = {"keys_live": [p.keys for p in view.plots],
                    "linked": view.plots[1].vb.linkedView(0) is view.plots[0].vb,
                    "headers_live": [view.header_text(i) for i in range(len(view.plots))]}
    live = measure({"plots": view.graphics}, PaintCounter(), seconds)
    result["live"] = live["views"]["plots"]
    result["live_pixels"] = plot_pixels(view)
    result["live_picture"] = _save(grab(window), "plots-live")

    page.controls.record.click()
    session = page.session
    pump_until(lambda: session.n_daq_samples > 90 and session.n_robot_samples > 100, what="a few seconds recorded")
    page.controls.record.click()
    path = Path(session.path)
    dock.ask_open_path = lambda _title, _folder, _filter: str(path)
    view.open_button.click()
    pump(500)
    result["keys_recorded"] = [p.keys for p in view.plots]
    result["recorded_pixels"] = plot_pixels(view)
    result["source_recorded"] = view.source_label.text()
    dock.ask_save_path = lambda _title, suggested: suggested
    view.save_action.trigger()
    beside = path.with_name(path.stem + ".plots.json")
    result["layout_file"] = json.loads(beside.read_text()) if beside.is_file() else None
    view.clear_action.trigger()
    pump(300)
    result["cleared_plots"] = len(view.plots)
    view.live_button.click()
    pump(300)
    view.open_button.click()  # the recording again: its layout opens with it
    pump(500)
    result["keys_reopened"] = [p.keys for p in view.plots]
    result["reopened_pixels"] = plot_pixels(view)
    result["reopened_picture"] = _save(grab(window), "plots-reopened")
    result["message"] = view.message.text()
    lab.robot.stop_motion()
    return result


SCENARIOS = {"plots": scenario_plots}


def main(argv: list[str]) -> int:
    name = argv[0]
    seconds = float(argv[1]) if len(argv) > 1 else 2.0
    if os.environ.get("QT_QPA_PLATFORM") != "xcb":
        fail("run this on an X display with QT_QPA_PLATFORM=xcb (tests.realdisplay.xserver.run_probe does)")
    app = QApplication.instance() or QApplication([sys.argv[0]])
    QTimer.singleShot(int(1000 * (WAIT_S * 4 + seconds * 3)), lambda: fail("probe timed out"))
    with tempfile.TemporaryDirectory(prefix="sensnake-xprobe-") as tmp:
        window, page = open_app(Path(tmp), "forces")
        started = time.monotonic()
        result = SCENARIOS[name](window, page, seconds)
        result["scenario"], result["seconds"] = name, time.monotonic() - started
        print(json.dumps(result), flush=True)  # noqa: T201 - the result for the test
        window.close()
        QCoreApplication.processEvents()  # one turn for the close's deferred deletes before the probe exits
    del app
    os._exit(0)  # device threads were closed with the window; skip Qt's teardown at exit


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
