"""Inside a subprocess on a real X display (QT_QPA_PLATFORM=xcb): open the app on the simulated lab, stage one live
view, count the paint events reaching it and read its pixels back from the X server. Prints one JSON line.

    DISPLAY=:N QT_QPA_PLATFORM=xcb python -m tests.realdisplay.probe forces|teach|gait|calibration|hardware [seconds]

Reusable pieces (import them in another probe): :class:`PaintCounter`, :func:`grab`, :func:`measure`,
:func:`pump_until`, :func:`open_app`, :class:`Wiggle`. GUI thread only.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QCoreApplication, QEvent, QEventLoop, QObject, QPoint, QSettings, QTimer
from PySide6.QtGui import QGuiApplication, QImage
from PySide6.QtWidgets import QApplication, QWidget

WINDOW_SIZE = (1280, 800)
GRAB_EVERY_MS = 100
WAIT_S = 20.0


class PaintCounter(QObject):
    """Counts paint events reaching each registered widget or any widget inside it (an application event filter:
    install once; a QGraphicsView's paints arrive at its viewport, a table's at its viewport, both children)."""

    FRAME_GAP_S = 0.005  # paints of one view closer than this belong to one frame (one flush of the window)

    def __init__(self) -> None:
        super().__init__()
        self.views: dict[QWidget, str] = {}
        self.counts: dict[str, int] = {}
        self.frames: dict[str, int] = {}
        self._last: dict[str, float] = {}
        QApplication.instance().installEventFilter(self)

    def watch(self, views: dict[str, QWidget]) -> None:
        self.views = {widget: name for name, widget in views.items()}
        self.counts = dict.fromkeys(views, 0)
        self.frames = dict.fromkeys(views, 0)
        self._last = dict.fromkeys(views, -1.0)

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt override
        if event.type() == QEvent.Type.Paint and self.views:
            widget = obj
            while isinstance(widget, QWidget):
                name = self.views.get(widget)
                if name is not None:
                    self.counts[name] += 1
                    now = time.monotonic()
                    if now - self._last[name] > self.FRAME_GAP_S:
                        self.frames[name] += 1
                    self._last[name] = now
                    break
                widget = widget.parentWidget()
        return False


def grab(widget: QWidget) -> QImage:
    """The widget's pixels as the X server shows them (not re-rendered: grabWindow reads the root window)."""
    top_left = widget.mapToGlobal(QPoint(0, 0))
    screen = QGuiApplication.primaryScreen()
    return screen.grabWindow(0, top_left.x(), top_left.y(), widget.width(), widget.height()).toImage()


def pump(ms: float) -> None:
    """Run the event loop for ``ms`` milliseconds."""
    loop = QEventLoop()
    QTimer.singleShot(int(ms), loop.quit)
    loop.exec()


def pump_until(predicate: Callable[[], bool], timeout_s: float = WAIT_S, what: str = "") -> None:
    """Run the event loop until ``predicate()``; exit the probe with a message after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            fail(f"timed out after {timeout_s:.0f} s waiting for {what or 'a condition'}")
        pump(20)


def measure(views: dict[str, QWidget], counter: PaintCounter, seconds: float = 2.0, grabs_on: bool = True) -> dict:
    """Paint events per second reaching each view (the view and every widget inside it), frames per second (paints
    in one flush counted once), the fraction of 100-ms intervals in which its pixels on the X
    server changed, and the CPU (fraction of one core) of the whole process and of the GUI thread over the same
    ``seconds``."""
    grabs: dict[str, list[QImage]] = {name: [grab(w)] for name, w in views.items()}
    counter.watch(views)
    t0, cpu0, gui0 = time.monotonic(), time.process_time(), time.thread_time()
    deadline = t0 + seconds
    while time.monotonic() < deadline:
        pump(GRAB_EVERY_MS)
        if grabs_on:  # off when measuring CPU: reading pixels back costs more than drawing them
            for name, widget in views.items():
                grabs[name].append(grab(widget))
    wall, cpu, gui = time.monotonic() - t0, time.process_time() - cpu0, time.thread_time() - gui0
    counts, frames = dict(counter.counts), dict(counter.frames)
    counter.watch({})
    result: dict = {"seconds": wall, "cpu": cpu / wall, "gui_cpu": gui / wall, "views": {}}
    for name, widget in views.items():
        images = grabs[name]
        changed = sum(a != b for a, b in zip(images, images[1:])) / max(1, len(images) - 1)
        result["views"][name] = {"paints_per_s": counts[name] / wall, "frames_per_s": frames[name] / wall,
                                 "changed": changed,
                                 "size": [widget.width(), widget.height()], "visible": widget.isVisible()}
    return result


def fail(message: str) -> None:
    print(message, flush=True)  # noqa: T201 - the test shows the probe's output
    os._exit(2)


class Wiggle(QObject):
    """Bends the limp simulated robot by hand in a slow travelling wave (``rate_hz`` poses per second): live views of
    the robot have changing data without any tab commanding a motion."""

    def __init__(self, joint_ids, rate_hz: float = 20.0, amplitude_rad: float = 0.3) -> None:
        super().__init__()
        from devices.factory import sim_lab

        self.chain = sim_lab().chain
        self.joint_ids = list(joint_ids)
        self.amplitude_rad = amplitude_rad
        self.t0 = time.monotonic()
        self.timer = QTimer(self)
        self.timer.setInterval(int(1000 / rate_hz))
        self.timer.timeout.connect(self.step)

    def step(self) -> None:
        t = time.monotonic() - self.t0
        for k, servo_id in enumerate(self.joint_ids):
            angle = self.amplitude_rad * math.sin(2 * math.pi * (0.5 * t - k / len(self.joint_ids)))
            with contextlib.suppress(ValueError):  # that joint holds torque: it stays where it is
                self.chain.set_limp_position(servo_id, 2048 + angle * 4096 / (2 * math.pi))

    def start(self) -> None:
        self.timer.start()

    def stop(self) -> None:
        self.timer.stop()


def open_app(tmp: Path, tab: str):
    """The main window on the simulated lab (settings, shapes, recordings in ``tmp``), shown, devices connecting,
    on tab ``tab``; returns (window, page)."""
    os.environ["XDG_DATA_HOME"] = str(tmp / "data")
    os.environ["SENSNAKE_RECORDINGS_DIR"] = str(tmp / "recordings")
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from devices.config import SIM_PORT, load_config

    config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    from dataclasses import replace

    # The 3-D view draws the physics lab (the default). The other views are measured on the scripted lab, whose data
    # keeps changing: the physics lab's robot lies still or hangs in the air, so several sensors read constant.
    config = replace(config, lab=replace(config.lab, physics="mujoco" if tab == "scene" else "scripted"))
    lab = LabContext(config)
    window = MainWindow(lab, settings=QSettings(str(tmp / "settings.ini"), QSettings.Format.IniFormat))
    window.resize(*WINDOW_SIZE)
    window.move(0, 0)
    page = window.show_tab(tab.split("_")[0])
    window.show()
    window.raise_()
    pump_until(lambda: window.windowHandle() is not None and window.windowHandle().isExposed(), what="the window")
    lab.connect_all()
    return window, page


# -- scenarios: each returns the measurement dict --------------------------------------------------------------------
def scenario_forces(window, page, seconds: float) -> dict:
    pump_until(lambda: len(page.force_history) > 0 and page.force_history.span()[1] > 1.0, what="board data")
    pump(1000)  # the plots settle their y ranges
    viewport = page.plots.scroll_area.viewport()
    views = {f"plot{i}": plot.plot_widget for i, plot in enumerate(page.plots.plots) if plot.on_screen(viewport)}
    if page.body is not None:
        views["body_map"] = page.body
    wiggle = Wiggle(page.lab.config.robot.joint_ids)
    wiggle.start()
    return measure(views, PaintCounter(), seconds)


def scenario_forces_cost(window, page, seconds: float) -> dict:
    """The cost case: 36 channels at 30 Hz, Forces tab visible, robot at rest, nobody reading pixels."""
    pump_until(lambda: len(page.force_history) > 0 and page.force_history.span()[1] > 1.0, what="board data")
    pump(1000)
    viewport = page.plots.scroll_area.viewport()
    views = {f"plot{i}": plot.plot_widget for i, plot in enumerate(page.plots.plots) if plot.on_screen(viewport)}
    if page.body is not None:
        views["body_map"] = page.body
    return measure(views, PaintCounter(), seconds, grabs_on=False)


def scenario_teach(window, page, seconds: float) -> dict:
    pump_until(lambda: page.robot.latest_state is not None, what="the robot's first state")
    counter = PaintCounter()
    wiggle = Wiggle(page.config.joint_ids)
    wiggle.start()
    pump(500)
    moving = measure({"body_view": page.panel.body_view, "sliders": page.panel.sliders}, counter, seconds)
    wiggle.stop()
    pump_until(_lab_at_rest, what="the simulated robot to come to rest")  # the physics lab: held by the hand
    pump(800)  # the robot comes to rest
    idle = measure({"panel": page.panel}, counter, seconds)
    return {**moving, "idle": idle}


def _lab_at_rest() -> bool:
    """The simulated lab's robot lies still: always with the scripted lab; the physics lab once its world rests."""
    from devices.factory import sim_lab

    physics = getattr(sim_lab(), "physics", None)
    return physics is None or physics.world.resting


def scenario_gait(window, page, seconds: float) -> dict:
    pump_until(lambda: page.robot.is_connected, what="the robot to connect")
    panel = page.panel
    panel.set_mode("serpenoid")
    pump_until(panel.play_button.isEnabled, what="Play to be enabled")
    panel.play_button.click()
    pump_until(lambda: page.source is not None and page.source.progress.fraction > 0.0, what="the gait to start")
    return measure({"body_view": panel.body_view, "progress": panel.progress_bar, "joint_table": panel.joint_table},
                   PaintCounter(), seconds)


def scenario_calibration(window, page, seconds: float) -> dict:
    form = page.protocol_form
    form.forces_edit.setText("2.0")
    form.trials_spin.setValue(1)
    form.hold_spin.setValue(max(10.0, seconds + 4))
    form.baseline_spin.setValue(0.5)
    form.ramp_spin.setValue(1.0)
    form.rest_spin.setValue(0.3)
    form.folder_edit.setText(str(Path(os.environ["XDG_DATA_HOME"]) / "runs"))
    if not page.start_run():
        fail(f"the rig run did not start: {form.message_label.text()}")
    pump_until(lambda: page.live_plot.n_samples > 3, what="live trial samples")
    result = measure({"live_trace": page.live_plot}, PaintCounter(), seconds)
    return result


def scenario_hardware(window, page, seconds: float) -> dict:
    pump_until(lambda: page.robot.is_connected and page.panel.servo_table.rowCount() > 0, what="the servo table")
    wiggle = Wiggle(page.lab.config.robot.joint_ids)
    wiggle.start()
    pump(500)
    return measure({"servo_table": page.panel.servo_table}, PaintCounter(), seconds)


def scenario_scene(window, page, seconds: float) -> dict:
    pump_until(lambda: page.view.frames_shown > 0 or bool(page.render_error), what="the first 3-D frame")
    if page.render_error:
        fail(f"no 3-D rendering: {page.render_error}")
    wiggle = Wiggle(page.lab.config.robot.joint_ids)  # limp joints posed by the hand move the simulated body
    wiggle.start()
    pump(500)
    return measure({"scene": page.view.picture}, PaintCounter(), seconds)


def _global_rect(widget: QWidget, rect=None) -> list[int]:
    """``rect`` (in ``widget``'s coordinates; default its whole area) on the screen: [left, top, right, bottom]."""
    from PySide6.QtCore import QRect

    rect = QRect(rect) if rect is not None else widget.rect()
    top_left = widget.mapToGlobal(rect.topLeft())
    return [top_left.x(), top_left.y(), top_left.x() + rect.width() - 1, top_left.y() + rect.height() - 1]


def _data_area(plot) -> list[int]:
    widget = plot.plot_widget
    return _global_rect(widget, widget.mapFromScene(plot.viewbox.sceneBoundingRect()).boundingRect())


def _save(image: QImage, name: str) -> str:
    folder = os.environ.get("PROBE_PICTURES")
    if not folder:
        return ""
    path = Path(folder) / f"{name}.png"
    image.save(str(path))
    return str(path)


def scenario_forces_layout(window, page, seconds: float) -> dict:
    """The Forces tab opened after the board has streamed for a while (it is built when first shown), then one
    sensor calibrated and the cursor over a plot: where each piece lands on the X screen, with the grabs saved
    (``PROBE_PICTURES``)."""
    lab = window.lab
    pump_until(lambda: len(lab.board.history) > 0 and lab.board.history.span()[1] > 3.0, what="3 s of board data")
    streamed = lab.board.history.span()
    forces = window.show_tab("forces")
    result: dict = {"streamed_s": list(streamed), "history_on_open_s": list(forces.force_history.span())
                    if len(forces.force_history) else None}
    pump(300)
    result["open_picture"] = _save(grab(window), "forces-on-open")
    from tests.calibration_files import typical_sensor_entry, write_calibration

    cal = write_calibration(Path(tempfile.mkdtemp()) / "one.json", {"S06B": typical_sensor_entry()})
    forces.load_calibration(cal)
    pump_until(lambda: not forces.is_loading_calibration, what="the calibration applied")
    pump(1500)
    plots = []
    for plot in forces.plots.plots:
        if not plot.on_screen():
            continue
        item = plot.plot_widget.getPlotItem()
        plots.append({"title": plot.group.title, "legend": _global_rect(plot.legend), "data": _data_area(plot),
                      "left_label": item.getAxis("left").labelText,
                      "right_visible": item.getAxis("right").isVisible(),
                      "right_label": item.getAxis("right").labelText})
    result["plots"] = plots
    result["calibrated_picture"] = _save(grab(window), "forces-one-calibrated")
    t_newest = forces.force_history.span()[1]
    forces.plots.set_paused(True)  # the cursor stays over the same samples while the grabs are taken
    from PySide6.QtGui import QCursor

    QCursor.setPos(WINDOW_SIZE[0] + 100, WINDOW_SIZE[1] + 100)  # the X pointer off the window: only hover_at moves it
    pump(100)
    readouts = []
    for fraction in (0.25, 0.9):
        lo, hi = forces.force_history.span()  # over data (the 30-s view is wider than the history yet)
        forces.plots.hover_at(5, lo + fraction * (hi - lo))
        pump(200)
        plot = forces.plots.plots[5]
        item = plot.plot_widget.getPlotItem()
        axis_rects = []
        for name in ("left", "right", "bottom"):
            axis = item.getAxis(name)
            if axis.isVisible():
                rect = plot.plot_widget.mapFromScene(axis.sceneBoundingRect()).boundingRect()
                axis_rects.append(_global_rect(plot.plot_widget, rect))
        readouts.append({"readout": _global_rect(plot.readout), "visible": plot.readout.isVisible(),
                         "data": _data_area(plot), "axes": axis_rects, "text": plot.readout.text(),
                         "picture": _save(grab(window), f"forces-readout-{int(100 * fraction)}")})
    result["readouts"] = readouts
    result["newest_s"] = t_newest
    return result


def scenario_gait_log(window, page, seconds: float) -> dict:
    """The Gait tab at the window's default size with the event log opened below it: how much room the body
    drawing keeps (with its aspect locked, a view squeezed to a sliver spans tens of metres and the robot is a dot)
    and the log's list."""
    del seconds
    pump_until(lambda: page.robot.is_connected, what="the robot to connect")
    before = {name: list(box) for name, box in page.panel.body_view.shown_ranges().items()}
    window.log_dock.show()
    pump_until(lambda: window.log_dock.isVisible(), what="the event log")
    # A user drags the log's edge up to read more of it (the window keeps the dock's height from the last run).
    from PySide6.QtCore import Qt

    window.resizeDocks([window.log_dock], [500], Qt.Orientation.Vertical)
    pump(500)
    view = page.panel.body_view
    picture = _save(grab(window), "gait_log")
    return {"picture": picture, "ranges_before": before, "ranges": {name: list(box) for name, box in view.shown_ranges().items()},
            "side_by_side": view.side_by_side,
            "drawing_height": view.height(), "log_height": window.log_view.height(),
            "window": [window.width(), window.height()],
            "play_visible": page.panel.play_button.isVisible() and not page.panel.play_button.visibleRegion().isEmpty()}


SCENARIOS = {"forces": scenario_forces, "forces_layout": scenario_forces_layout, "forces_cost": scenario_forces_cost, "teach": scenario_teach, "gait": scenario_gait, "gait_log": scenario_gait_log,
             "calibration": scenario_calibration, "hardware": scenario_hardware, "scene": scenario_scene}


OPENS_ON = {"forces_layout": "teach"}  # the tab shown first, when it is not the scenario's own


def main(argv: list[str]) -> int:
    name = argv[0]
    seconds = float(argv[1]) if len(argv) > 1 else 2.0
    if os.environ.get("QT_QPA_PLATFORM") != "xcb":
        fail("run this on an X display with QT_QPA_PLATFORM=xcb (tests.realdisplay.xserver.run_probe does)")
    app = QApplication.instance() or QApplication([sys.argv[0]])
    QTimer.singleShot(int(1000 * (WAIT_S * 3 + seconds * 3)), lambda: fail("probe timed out"))
    with tempfile.TemporaryDirectory(prefix="sensnake-xprobe-") as tmp:
        window, page = open_app(Path(tmp), OPENS_ON.get(name, name))
        if os.environ.get("PROBE_PROFILE"):  # cProfile of the GUI thread over the scenario, to that file
            import cProfile

            profiler = cProfile.Profile()
            result = profiler.runcall(SCENARIOS[name], window, page, seconds)
            profiler.dump_stats(os.environ["PROBE_PROFILE"])
        else:
            result = SCENARIOS[name](window, page, seconds)
        result["scenario"] = name
        print(json.dumps(result), flush=True)  # noqa: T201 - the result for the test
        window.close()
        QCoreApplication.processEvents()  # one turn for the close's deferred deletes before the probe exits
    del app
    os._exit(0)  # device threads were closed with the window; skip Qt's teardown at exit


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
