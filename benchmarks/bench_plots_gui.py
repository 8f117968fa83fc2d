"""Plots dock benchmark: what a plot panel of 8 live series costs the app as ``sensnake gui`` runs it, on a real X
display (its own Xvfb, Qt's xcb platform).

The app: the main window on the physics lab, the simulated lab and the control loop each in their own process (as
``sensnake gui``), the robot playing a travelling wave at 50 Hz (goals change every tick), the board streaming 36
channels at 30 Hz, the Forces tab visible with the simulated sensors' own calibration (every sensor in newtons), all
12 segment plots on screen (window 1600×1000). Windows of ``seconds`` each, in turn in the same session:

- **dock hidden**: the Forces tab alone (the dock subscribes to nothing while hidden);
- **8 live series**: View ▸ Plots open beside the tab with 4 stacked plots on linked time axes — joint 5's goal and
  present angle, joint 5's and joint 3's current, S06B's, S06L's and S04B's force, S06B's conductance.

Measured in each window: paint events reaching each on-screen Forces plot (frames: the paints of one flush counted
once, as ``tests/realdisplay/probe.py`` counts them; target ≥ 25/s per plot) and the Plots dock's; the app's process
CPU (target ≤ 30 % of one core; the GUI thread apart) and the lab's and the loop's processes; the control loop's
ticks, missed ticks (target 0) and late ticks. Paints are counted by an event filter on each counted view only.
Offscreen (no Xvfb) it says so: paint counts then mean nothing.

``python -m benchmarks.bench_plots_gui [--quick] [--seconds S] [--pairs N] [--offscreen]``; ``run(quick)`` for
``sensnake bench`` (quick: one pair of 8 s windows, else 3 pairs of 20 s, the dock hidden and shown in turn so that
the shared machine's changing load falls on both alike).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

if "--offscreen" in sys.argv:
    os.environ["QT_QPA_PLATFORM"] = "offscreen"
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

import numpy as np  # noqa: E402

import widgets  # noqa: E402,F401 - installs the PySide6 refcount guard before Qt is used

WINDOW_SIZE = (1600, 1000)
SERIES: tuple[tuple[str, ...], ...] = (
    ("robot/J5/goal_rad", "robot/J5/present_rad"),
    ("robot/J5/current_mA", "robot/J3/current_mA"),
    ("forces/S06B/force_N", "forces/S06L/force_N", "forces/S04B/force_N"),
    ("daq/S06B/conductance_uS",),
)
FRAME_GAP_S = 0.005  # paints of one view closer than this are one frame (one flush of the window)


class FrameCounter:
    """Frames painted on each of some widgets: an event filter on each (cheap, unlike an application filter)."""

    def __init__(self, views: Sequence[Any]) -> None:
        from PySide6.QtCore import QEvent, QObject

        paint = QEvent.Type.Paint
        self.frames = [0] * len(views)
        last = [-1.0] * len(views)
        frames = self.frames

        class Filter(QObject):
            index = 0

            def eventFilter(self, obj: Any, event: Any) -> bool:  # noqa: N802 - Qt override
                if event.type() == paint:
                    now = time.monotonic()
                    if now - last[self.index] > FRAME_GAP_S:
                        frames[self.index] += 1
                    last[self.index] = now
                return False

        self._filters = []
        for index, view in enumerate(views):
            f = Filter()
            f.index = index
            view.installEventFilter(f)
            self._filters.append((view, f))

    def reset(self) -> None:
        self.frames[:] = [0] * len(self.frames)

    def remove(self) -> None:
        for view, f in self._filters:
            view.removeEventFilter(f)


class DockCost:
    """The GUI thread's CPU time (``time.thread_time``, which the machine's load does not inflate) spent by the dock:
    its redraws (reading the rings, decimating, building the lines) and its view's paint events (Qt drawing the
    plots; the X server's own work is not in it)."""

    def __init__(self) -> None:
        from app.gui.plots_dock import PlotsDock
        from widgets.plots_view import PlotArea

        self.spent = {"redraw": 0.0, "paint": 0.0}
        self.count = {"redraw": 0, "paint": 0}
        self._patched = [(PlotsDock, "redraw", PlotsDock.redraw), (PlotArea, "paintEvent", PlotArea.paintEvent)]
        spent, count = self.spent, self.count

        def timed(original: Callable[..., Any], label: str) -> Callable[..., Any]:
            def wrapper(*args: Any, **kwargs: Any) -> Any:
                start = time.thread_time()
                try:
                    return original(*args, **kwargs)
                finally:
                    spent[label] += time.thread_time() - start
                    count[label] += 1
            return wrapper

        PlotsDock.redraw = timed(PlotsDock.redraw, "redraw")  # type: ignore[method-assign]
        PlotArea.paintEvent = timed(PlotArea.paintEvent, "paint")  # type: ignore[method-assign]

    def reset(self) -> None:
        for key in self.spent:
            self.spent[key], self.count[key] = 0.0, 0

    def restore(self) -> None:
        for owner, name, original in self._patched:
            setattr(owner, name, original)


def _process_cpu_s(pid: int | None) -> float | None:
    """CPU seconds (user + system) process ``pid`` has used (Linux /proc), None if unknown."""
    if pid is None:
        return None
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass
class Window:
    """One measured window."""

    name: str
    seconds: float
    forces_paints: list[float]
    dock_paints: float
    app_cpu_pct: float
    gui_cpu_pct: float
    lab_cpu_pct: float
    loop_cpu_pct: float
    ticks: int
    missed: int
    late: int
    load: tuple[float, float]
    dock_bytes: int
    dock_redraw_ms: float = float("nan")  # GUI-thread CPU per dock redraw
    dock_paint_ms: float = float("nan")  # GUI-thread CPU per paint event of the dock's view
    dock_cpu_pct: float = float("nan")  # both, as % of one core


def _pump(ms: float, until: Callable[[], bool] | None = None) -> None:
    from PySide6.QtCore import QEventLoop, QTimer

    loop = QEventLoop()
    deadline = time.monotonic() + ms / 1000
    while time.monotonic() < deadline:
        QTimer.singleShot(int(min(50.0, 1000 * (deadline - time.monotonic())) + 1), loop.quit)
        loop.exec()
        if until is not None and until():
            return


def _measure(name: str, seconds: float, window: Any, forces: Any, dock_view: Any | None,
             cost: DockCost | None = None) -> Window:
    lab = window.lab
    viewport = forces.plots.scroll_area.viewport()
    views = [plot.plot_widget.viewport() for plot in forces.plots.plots if plot.on_screen(viewport)]
    if dock_view is not None:
        views.append(dock_view.graphics.viewport())
    counter = FrameCounter(views)
    pids = {"lab": getattr(__import__("devices.factory", fromlist=["x"]).installed_sim_lab(), "pid", None),
            "loop": getattr(lab.robot.controller, "pid", None)}
    others0 = {k: _process_cpu_s(pid) for k, pid in pids.items()}
    s0 = lab.robot.loop_stats()
    load0 = os.getloadavg()[0]
    if cost is not None:
        cost.reset()
    wall0, cpu0, gui0 = time.monotonic(), time.process_time(), time.thread_time()
    _pump(seconds * 1000)
    wall = time.monotonic() - wall0
    cpu, gui = time.process_time() - cpu0, time.thread_time() - gui0
    s1 = lab.robot.loop_stats()
    others1 = {k: _process_cpu_s(pid) for k, pid in pids.items()}
    counter.remove()
    frames = [f / wall for f in counter.frames]

    def pct(k: str) -> float:
        a, b = others0[k], others1[k]
        return float("nan") if a is None or b is None else 100 * (b - a) / wall

    forces_frames = frames[:-1] if dock_view is not None else frames
    dock = window.plots_dock
    result = Window(name, wall, forces_frames, frames[-1] if dock_view is not None else float("nan"),
                    100 * cpu / wall, 100 * gui / wall, pct("lab"), pct("loop"),
                    (s1.ticks - s0.ticks) if s0 and s1 else 0,
                    (s1.missed_ticks - s0.missed_ticks) if s0 and s1 else 0,
                    (s1.late_ticks - s0.late_ticks) if s0 and s1 else 0, (load0, os.getloadavg()[0]),
                    dock.live.nbytes if dock.live is not None else 0)
    if cost is not None and dock_view is not None:
        result.dock_redraw_ms = 1e3 * cost.spent["redraw"] / max(1, cost.count["redraw"])
        result.dock_paint_ms = 1e3 * cost.spent["paint"] / max(1, cost.count["paint"])
        result.dock_cpu_pct = 100 * (cost.spent["redraw"] + cost.spent["paint"]) / wall
    return result


def measure_app(seconds: float, pairs: int = 2, warmup_s: float = 3.0) -> tuple[list[Window], dict]:
    """``pairs`` × (dock hidden, 8 live series) windows in one app session; and facts about the session."""
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QApplication

    from app.core import series as sr
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from benchmarks.sources import Wave
    from devices import factory
    from devices.config import SIM_PORT, load_config

    app = QApplication.instance() or QApplication([])
    config = load_config(None).with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    facts: dict = {"platform": QApplication.platformName(), "physics": config.lab.physics}
    windows: list[Window] = []
    cost = DockCost()
    with tempfile.TemporaryDirectory(prefix="sensnake-bench-plots-") as tmp:
        os.environ.setdefault("SENSNAKE_DATA_DIR", tmp)
        lab = LabContext(config, lab_process=True)  # as `sensnake gui`: the simulated lab in its own process
        window = MainWindow(lab, settings=QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat))
        try:
            window.resize(*WINDOW_SIZE)
            window.move(0, 0)
            window.show()
            lab.connect_all()
            _pump(60_000, lambda: lab.robot.is_connected and lab.board is not None and lab.board.is_connected)
            if not lab.robot.is_connected:
                raise SystemExit("bench_plots_gui: the robot did not connect within 60 s")
            facts["lab_where"], facts["loop_where"] = lab.lab_where, lab.robot.loop_where
            forces: Any = window.show_tab("forces")
            if not forces.load_simulated_truth():
                raise SystemExit("bench_plots_gui: the simulated sensors' calibration did not load")
            _pump(60_000, lambda: not getattr(forces, "is_loading_calibration", False))
            lab.robot.set_torque(True).result(timeout=30)
            lab.robot.run_motion(Wave(), "bench wave")
            _pump(warmup_s * 1000)
            dock = window.plots_dock
            layout = sr.PlotLayout()
            for plot in SERIES:
                layout = layout.adding_plot()
                for key in plot:
                    layout = layout.adding(key, len(layout.plots) - 1)
            dock.set_layout(layout)  # drawn only while the dock is shown
            facts["series"] = len(layout.series_keys())
            # Hidden and shown windows alternate, so a change in the shared machine's load falls on both alike.
            for _pair in range(pairs):
                if dock.isVisible():
                    window.plots_action.trigger()
                _pump(1000)
                windows.append(_measure("dock hidden", seconds, window, forces, None))
                window.plots_action.trigger()
                _pump(30_000, lambda: all(item.yData is not None and np.isfinite(item.yData).sum() > 20
                                          for plot in dock.view.plots for item in plot.curves))
                _pump(1000)
                windows.append(_measure(f"{facts['series']} live series", seconds, window, forces, dock.view, cost))
            viewport = forces.plots.scroll_area.viewport()
            facts["forces_plots_on_screen"] = sum(p.on_screen(viewport) for p in forces.plots.plots)
            facts["dock_size"] = [dock.width(), dock.height()]
            facts["dock_redraws"] = dock.redraws
            lab.robot.stop_motion()
            _pump(500)
        finally:
            window.close()
            app.processEvents()
            running = factory.installed_sim_lab()
            factory.install_sim_lab(None)
            close = getattr(running, "close", None)
            if callable(close):
                close()
            cost.restore()
    return windows, facts


def _line(w: Window) -> str:
    f = np.array(w.forces_paints) if w.forces_paints else np.array([np.nan])
    return (f"{w.name:<16} {f.mean():>7.1f} {f.min():>6.1f} {w.dock_paints:>7.1f} {w.app_cpu_pct:>6.0f} "
            f"{w.gui_cpu_pct:>6.0f} {w.lab_cpu_pct:>6.0f} {w.loop_cpu_pct:>6.0f} {w.ticks:>6} {w.missed:>6} "
            f"{w.late:>5} {w.dock_bytes / 1e6:>7.1f} {w.dock_redraw_ms:>8.2f} {w.dock_paint_ms:>8.2f} "
            f"{w.dock_cpu_pct:>7.1f}   load {w.load[0]:.1f}→{w.load[1]:.1f}")


def run(quick: bool, seconds: float | None = None, pairs: int | None = None) -> None:
    from PySide6.QtWidgets import QApplication

    seconds = seconds if seconds is not None else (8.0 if quick else 20.0)
    pairs = pairs if pairs is not None else (1 if quick else 3)
    app = QApplication.instance() or QApplication([])
    if QApplication.platformName() != "xcb":
        print("NOTE: not on an X display (xcb): paint counts below mean nothing; run "
              "`python -m benchmarks.bench_plots_gui` for the real figures")
    del app
    windows, facts = measure_app(seconds, pairs)
    print(f"The app as `sensnake gui` runs it ({facts['platform']}, {facts['physics']} lab in {facts['lab_where']}, "
          f"loop in {facts['loop_where']}), wave at 50 Hz, 36 ch @ 30 Hz, Forces tab with "
          f"{facts['forces_plots_on_screen']} segment plots on screen; {seconds:g} s windows, the dock hidden and "
          "shown in turn")
    header = (f"{'window':<16} {'Forces':>7} {'min':>6} {'dock':>7} {'app %':>6} {'GUI %':>6} {'lab %':>6} "
              f"{'loop %':>6} {'ticks':>6} {'missed':>6} {'late':>5} {'dock MB':>7} {'redraw':>8} {'paint':>8} "
              f"{'dock %':>7}")
    print(header)
    print("-" * len(header))
    for w in windows:
        print(_line(w))
    for name in dict.fromkeys(w.name for w in windows):
        group = [w for w in windows if w.name == name]
        paints = [float(np.mean(w.forces_paints)) for w in group if w.forces_paints]
        print(f"{name}: Forces {min(paints):.1f}-{max(paints):.1f} paints/s per plot, app "
              f"{min(w.app_cpu_pct for w in group):.0f}-{max(w.app_cpu_pct for w in group):.0f} % of a core, "
              f"missed ticks {sum(w.missed for w in group)} of {sum(w.ticks for w in group)}, late "
              f"{sum(w.late for w in group)}")
    print("(Forces: paints/s per on-screen segment plot, mean and least-painted; dock: the Plots dock's paints/s; "
          "% of one core: the app's process, its GUI thread, the simulated lab's and the control loop's processes; "
          "ticks, missed and late: the 50 Hz control loop's over the window; dock MB: its live rings;\n redraw, "
          "paint: the GUI thread's CPU ms per dock redraw and per paint of its view, dock %: both as % of a core, "
          "CPU time, which the machine's load does not inflate)")
    print(f"targets with the dock: Forces >= 25 paints/s per plot, app <= 30 % of a core, 0 missed ticks; "
          f"facts: {json.dumps(facts)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8 s per window")
    parser.add_argument("--seconds", type=float, default=None, help="seconds per window (default 20; quick 8)")
    parser.add_argument("--pairs", type=int, default=None, help="hidden/shown window pairs (default 3; quick 1)")
    parser.add_argument("--offscreen", action="store_true", help="do not start an X server (paints not counted)")
    args = parser.parse_args()
    if not args.offscreen:
        from benchmarks.bench_forces_gui import on_x_display

        code = on_x_display(sys.argv[1:], "benchmarks.bench_plots_gui")
        if code is not None:
            sys.exit(code)
    run(args.quick, args.seconds, args.pairs)


if __name__ == "__main__":
    main()
