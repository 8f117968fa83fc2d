"""Forces tab benchmark: the real tab on a real X display (its own Xvfb, Qt's xcb platform), fed by the simulated
board at the wire in real time.

Paints are the paint events that reach each on-screen plot's viewport (what the X server is sent), not ``refresh()``
calls: offscreen, a view can "refresh" without ever being repainted on a real screen. Without Xvfb the benchmark says
so and runs offscreen (paint counts are then not meaningful).

Scenarios
- The app as a user opens it: ``sensnake gui`` on the simulated lab, Forces tab visible, 36 channels at 30 Hz, robot at
  rest (``tests/realdisplay/probe.py forces_cost``): paints/s per plot (target ≥ 25) and the whole process's CPU,
  simulated lab included (target ≤ 30 % of one core).
- 36 channels at 30 Hz with 10 minutes of history already in the plots, 10-minute window: redraw rate (target
  ≥ 30 fps), GUI-thread CPU (target < 25 % of one core), sample-to-screen latency.
- 1024 channels at 100 Hz (64 plots of 16 traces): frames lost anywhere between the board and the GUI (target 0),
  event-loop stalls (responsiveness), redraw rate, CPU, latency.
- Memory: a plot history fed one hour of data stays at its fixed size (RSS before/after).

CPU is measured two ways: the GUI thread alone (``time.thread_time``: drain, estimation, health, redraw) and the whole
process (adds the board reader thread and the simulated board, which a real board does not cost).
Latency is from the host receiving a frame's bytes to the end of the redraw that first shows it. "GUI ms/frame" is
GUI-thread CPU divided by redraws (it includes draining, estimation and health, which run once per block): it does not
depend on how busy the rest of the machine is, unlike fps, which a loaded machine holds down.

``run(quick)``: quick runs each live scenario for ~3 s. ``python -m benchmarks.bench_forces_gui [--quick] [--offscreen]``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np

if "--offscreen" in sys.argv:
    os.environ["QT_QPA_PLATFORM"] = "offscreen"
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

import widgets  # noqa: E402,F401 - installs the PySide6 refcount guard before Qt is used


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as handle:
            pages = int(handle.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def _prefill(history, seconds: float, rate_hz: float, chunk_s: float = 10.0) -> None:
    """Synthetic past data at negative session times (the live data starts at t ≈ 0)."""
    rng = np.random.default_rng(0)
    n = history.n_channels
    phases = rng.uniform(0, 2 * np.pi, n)
    t = -seconds
    while t < -1.0 / rate_hz:
        t_block = t + np.arange(int(chunk_s * rate_hz)) / rate_hz
        t_block = t_block[t_block < 0]
        values = 2.0 + 1.5 * np.sin(0.3 * t_block[:, None] + phases) + 0.05 * rng.standard_normal((t_block.size, n))
        history.append(t_block, values)
        t += chunk_s


class _PaintCount:
    """Counts paint events reaching some widgets (an event filter on each: cheap, unlike an application filter)."""

    def __init__(self, widgets_: list) -> None:
        from PySide6.QtCore import QEvent, QObject

        paint = QEvent.Type.Paint
        counts = self.counts = [0] * len(widgets_)

        class Filter(QObject):
            index = 0  # which widget this filter counts for

            def eventFilter(self, obj, event, _paint=paint):  # noqa: N802 - Qt override
                if event.type() == _paint:
                    counts[self.index] += 1
                return False

        self._filters = []
        for index, widget in enumerate(widgets_):
            f = Filter()
            f.index = index
            widget.installEventFilter(f)
            self._filters.append((widget, f))

    def reset(self) -> None:
        self.counts[:] = [0] * len(self.counts)


class _LongestOps:
    """The GUI thread's longest single operations (its own CPU time, ``time.thread_time``) by kind: the board drain
    (with the force estimation and health it triggers), a plot-grid redraw, one view's paint event. Patches the
    classes for the scenario only; ``reset()`` after the warm-up (first blocks load compiled code, first shows)."""

    def __init__(self) -> None:
        import pyqtgraph as pg

        from app.gui.board_bridge import BoardBridge
        from widgets.force_plots import ForcePlotGrid

        self.longest: dict[str, float] = {}
        self._patched = [(BoardBridge, "drain", "drain"), (ForcePlotGrid, "refresh", "redraw"),
                         (pg.GraphicsView, "paintEvent", "paint")]
        self._originals = []
        for owner, name, label in self._patched:
            original = getattr(owner, name)
            self._originals.append((owner, name, original))
            setattr(owner, name, self._timed(original, label))

    def _timed(self, original, label: str):
        longest = self.longest

        def timed(*args, **kwargs):
            start = time.thread_time()
            try:
                return original(*args, **kwargs)
            finally:
                spent = time.thread_time() - start
                if spent > longest.get(label, 0.0):
                    longest[label] = spent
        return timed

    def reset(self) -> None:
        self.longest.clear()

    def worst(self) -> tuple[str, float]:
        return max(self.longest.items(), key=lambda item: item[1], default=("-", float("nan")))

    def restore(self) -> None:
        for owner, name, original in self._originals:
            setattr(owner, name, original)


def _live_scenario(app, n_channels: int, rate_hz: float, prefill_s: float, window_s: float, run_s: float,
                   baud: int, board_port: str | None = None) -> dict:
    """One live scenario; ``board_port``: read the board there (a pty of the board emulator in its own process)
    instead of the in-process simulated board."""
    from PySide6.QtCore import QEventLoop, QTimer

    from app.gui.lab import LabContext
    from app.gui.tabs.forces import ForcesTab
    from devices import factory
    from devices.config import BoardConfig, LabConfig, SimLabConfig, default_sensor_names
    from devices.sim.lab import SimLab

    names = default_sensor_names() if n_channels == 36 else tuple(f"C{i:04d}" for i in range(n_channels))
    board_config = replace(BoardConfig(), channel_names=names, rate_hz=rate_hz, baud=baud)
    if board_port:
        board_config = replace(board_config, port=board_port)
    config = LabConfig(board=board_config, lab=SimLabConfig(physics="scripted"))  # the plots' cost, not the lab's
    previous = factory.install_sim_lab(SimLab(config, seed=7, speed=1.0))
    ops = _LongestOps()  # before the tab exists: its timers connect to the timed methods
    lab = LabContext(config)
    tab = ForcesTab(lab)
    tab.resize(1600, 1000)
    tab.show()
    try:
        _prefill(tab.force_history, prefill_s, rate_hz)
        _prefill(lab.board.history, prefill_s, rate_hz)
        tab.controls.window_combo.setCurrentIndex(tab.controls.window_combo.findData(window_s))
        board = lab.board
        board.start()
        deadline = time.monotonic() + 10
        while not board.is_connected and time.monotonic() < deadline:
            app.processEvents()
        latencies: list[float] = []
        tab.plots.redrawn.connect(
            lambda: latencies.append(time.monotonic() - (board.t0_monotonic_s + tab.plots.last_redraw_s)))
        stalls: dict[str, Any] = {"last": time.monotonic(), "last_cpu": time.thread_time(), "max": 0.0, "max_busy": 0.0, "gaps": []}
        tick_s = 0.005

        def tick() -> None:
            # A gap between ticks is a stall; the GUI thread's CPU time over the gap says how much of it was the
            # app's own work (the rest: the thread was runnable but the shared cores were busy elsewhere).
            now, cpu = time.monotonic(), time.thread_time()
            gap = now - stalls["last"] - tick_s
            stalls["max"] = max(stalls["max"], gap)
            stalls["max_busy"] = max(stalls["max_busy"], cpu - stalls["last_cpu"])
            stalls["gaps"].append(gap)
            stalls["last"], stalls["last_cpu"] = now, cpu

        ticker = QTimer()
        ticker.setInterval(int(tick_s * 1000))
        ticker.timeout.connect(tick)
        # warm-up, then measure
        loop = QEventLoop()
        QTimer.singleShot(1000, loop.quit)
        loop.exec()
        latencies.clear()
        viewport = tab.plots.scroll_area.viewport()
        shown = [plot.plot_widget.viewport() for plot in tab.plots.plots if plot.on_screen(viewport)]
        paints = _PaintCount(shown)
        stats0 = board.stats
        samples0 = board.bridge_stats.samples
        redraws0 = tab.plots.redraw_count
        ticker.start()
        ops.reset()
        stalls.update(last=time.monotonic(), last_cpu=time.thread_time(), max=0.0, max_busy=0.0, gaps=[])
        wall0, gui0, proc0 = time.monotonic(), time.thread_time(), time.process_time()
        QTimer.singleShot(int(run_s * 1000), loop.quit)
        loop.exec()
        wall = time.monotonic() - wall0
        gui_cpu = (time.thread_time() - gui0) / wall
        proc_cpu = (time.process_time() - proc0) / wall
        ticker.stop()
        board.drain()
        stats = board.stats
        frames = stats.frames - stats0.frames
        lost = ((stats.overflow_frames - stats0.overflow_frames) + (stats.dropped_frames - stats0.dropped_frames)
                + (stats.crc_errors - stats0.crc_errors))
        lat = np.array(latencies) if latencies else np.array([np.nan])
        where = ", board in own process" if board_port else ""
        return {
            "scenario": f"{n_channels} ch @ {rate_hz:g} Hz, {prefill_s / 60:g} min history, {window_s / 60:g} min "
                        f"window{where}",
            "fps": (tab.plots.redraw_count - redraws0) / wall,
            "paints_per_plot": float(np.mean(paints.counts)) / wall if shown else float("nan"),
            "min_paints_per_plot": float(np.min(paints.counts)) / wall if shown else float("nan"),
            "gui_cpu_pct": 100 * gui_cpu,
            "proc_cpu_pct": 100 * proc_cpu,
            "latency_ms_mean": 1e3 * float(np.nanmean(lat)),
            "latency_ms_p95": 1e3 * float(np.nanpercentile(lat, 95)),
            "frames": frames,
            "expected_frames": int(round(wall * rate_hz)),
            "delivered": board.bridge_stats.samples - samples0,
            "lost_frames": lost,
            "max_stall_ms": 1e3 * stalls["max"],
            "max_busy_stall_ms": 1e3 * stalls["max_busy"],
            "stalls_over_100ms": int(np.sum(np.array(stalls["gaps"]) > 0.1)),
            "plots": len(tab.plots.plots),
            "longest_op": ops.worst(),
        }
    finally:
        tab.shutdown()
        lab.close()
        tab.deleteLater()
        factory.install_sim_lab(previous)
        ops.restore()


def _memory_scenario(n_channels: int, rate_hz: float, hours: float) -> dict:
    from app.gui.tabs.forces import FORCE_HISTORY_BUDGET_BYTES
    from widgets.ring_plot import TraceHistory

    rss0 = _rss_mb()
    history = TraceHistory.for_budget(n_channels, FORCE_HISTORY_BUDGET_BYTES)
    rss_alloc = _rss_mb()
    block = np.ones((int(rate_hz), n_channels))
    seconds = int(hours * 3600)
    t0 = time.perf_counter()
    for second in range(seconds):
        history.append(second + np.arange(block.shape[0]) / rate_hz, block)
    append_s = time.perf_counter() - t0
    rss1 = _rss_mb()
    oldest, newest = history.span()
    return {"scenario": f"{n_channels} ch @ {rate_hz:g} Hz, {hours:g} h of data", "history_mb": history.nbytes / 1e6,
            "rss_growth_mb": rss1 - rss0, "rss_after_alloc_mb": rss_alloc - rss0,
            "browsable_s": newest - oldest, "full_rate_s": len(history) / rate_hz,
            "append_us_per_sample": 1e6 * append_s / max(1, seconds * block.shape[0])}


@contextlib.contextmanager
def _board_emulator(n_channels: int, rate_hz: float, baud: int) -> Iterator[str | None]:
    """The independent board emulator (tests/emulators, SPEC §4 on a pty) in its own process, like a real board:
    its path, or None where it cannot run (no pty, no tests package)."""
    import tempfile

    if not hasattr(os, "openpty"):
        yield None
        return
    with tempfile.TemporaryDirectory(prefix="sensnake-bench-board-") as tmp:
        link = os.path.join(tmp, "board")
        try:
            process = subprocess.Popen(
                [sys.executable, "-m", "tests.emulators.board_emulator", "--link", link, "--channels", str(n_channels),
                 "--rate-hz", f"{rate_hz:g}", "--baud", str(baud)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        except OSError:
            yield None
            return
        try:
            ready = process.stdout.readline() if process.stdout is not None else ""
            yield link if ready.startswith("READY") else None
        finally:
            process.terminate()
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def _app_scenario(seconds: float) -> dict | None:
    """``tests/realdisplay/probe.py forces_cost`` in a subprocess on this display (xcb only)."""
    if os.environ.get("QT_QPA_PLATFORM") != "xcb":
        return None
    from tests.realdisplay.xserver import run_probe

    result = run_probe(os.environ["DISPLAY"], "forces_cost", str(seconds))
    plots = [v for name, v in result["views"].items() if name.startswith("plot")]
    return {"paints_per_plot": float(np.mean([v["frames_per_s"] for v in plots])),
            "min_paints_per_plot": float(np.min([v["frames_per_s"] for v in plots])),
            "body_map_paints": result["views"].get("body_map", {}).get("frames_per_s", float("nan")),
            "proc_cpu_pct": 100 * result["cpu"], "gui_cpu_pct": 100 * result["gui_cpu"], "plots": len(plots)}


def run(quick: bool) -> None:
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication([])
    platform = QApplication.platformName()
    run_s = 3.0 if quick else 15.0
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"Qt platform: {platform}; load average {load:.1f} on {os.cpu_count()} cores (CPU and rates are noisy "
          "on a shared machine)")
    app_result = _app_scenario(run_s)
    if app_result is not None:
        r = app_result
        print("The app on the simulated lab, Forces tab visible, 36 ch @ 30 Hz, robot at rest (X display)")
        print(f"  paints/s per plot: mean {r['paints_per_plot']:.1f}, min {r['min_paints_per_plot']:.1f} "
              f"(target >= 25) over {r['plots']} plots; body map {r['body_map_paints']:.1f}/s")
        print(f"  process CPU {r['proc_cpu_pct']:.0f} % of one core (target <= 30 %), GUI thread {r['gui_cpu_pct']:.0f} %")
        print()
    print(f"Forces tab, live (real widgets on {platform}, simulated board at the wire, real time)")
    header = (f"{'scenario':<50} {'plots':>5} {'fps':>6} {'paints/s':>8} {'GUI ms/frame':>12} {'GUI CPU%':>9} "
              f"{'proc CPU%':>9} {'lat ms':>7} {'p95 ms':>7} {'frames':>7} {'expected':>8} {'lost':>5} {'stall ms':>8} {'busy ms':>7} {'>100ms':>6} "
              f"{'longest op ms':>16}")
    print(header)
    print("-" * len(header))
    scenarios = [(36, 30.0, 600.0, 600.0, 2_000_000, False),
                 (1024, 100.0, 60.0 if quick else 600.0, 30.0, 4_000_000, False),
                 (1024, 100.0, 60.0 if quick else 600.0, 30.0, 4_000_000, True)]
    for n_channels, rate_hz, prefill_s, window_s, baud, own_process in scenarios:
        if own_process:
            with _board_emulator(n_channels, rate_hz, baud) as port:
                if port is None:
                    print("(board emulator in its own process: not available here)")
                    continue
                r = _live_scenario(app, n_channels, rate_hz, prefill_s, window_s, run_s, baud, board_port=port)
        else:
            r = _live_scenario(app, n_channels, rate_hz, prefill_s, window_s, run_s, baud)
        per_frame_ms = 10 * r["gui_cpu_pct"] / r["fps"] if r["fps"] else float("nan")
        print(f"{r['scenario']:<50} {r['plots']:>5} {r['fps']:>6.1f} {r['min_paints_per_plot']:>8.1f} "
              f"{per_frame_ms:>12.1f} {r['gui_cpu_pct']:>9.1f} "
              f"{r['proc_cpu_pct']:>9.1f} {r['latency_ms_mean']:>7.1f} {r['latency_ms_p95']:>7.1f} {r['frames']:>7} "
              f"{r['expected_frames']:>8} {r['lost_frames']:>5} {r['max_stall_ms']:>8.1f} {r['max_busy_stall_ms']:>7.1f} "
              f"{r['stalls_over_100ms']:>6} {1e3 * r['longest_op'][1]:>9.1f} {r['longest_op'][0]:<6}")
    print("(paints/s: the least-painted on-screen plot; stall: the longest the event loop did not run, target "
          "< 100 ms at 1024 ch;\n busy: the GUI thread's own CPU time within one stall — a stall much longer than "
          "that is the thread waiting for a shared core; >100ms: how many stalls passed 100 ms;\n longest op: the "
          "longest single GUI-thread operation, CPU ms, and which: a board drain with the estimation it runs, a redraw, "
          "one view's paint)")
    print()
    print("Plot history memory (fixed at construction; one hour of data appended)")
    header = (f"{'scenario':<34} {'history MB':>10} {'RSS growth MB':>13} {'full-rate s':>11} {'browsable s':>11} "
              f"{'append µs/sample':>16}")
    print(header)
    print("-" * len(header))
    for n_channels, rate_hz, hours in ((36, 30.0, 1.0), (1024, 100.0, 0.1 if quick else 1.0)):
        m = _memory_scenario(n_channels, rate_hz, hours)
        print(f"{m['scenario']:<34} {m['history_mb']:>10.1f} {m['rss_growth_mb']:>13.1f} {m['full_rate_s']:>11.0f} "
              f"{m['browsable_s']:>11.0f} {m['append_us_per_sample']:>16.2f}")


def on_x_display(argv: list[str], module: str) -> int | None:
    """Re-run ``python -m module argv`` on a private Xvfb with Qt's xcb platform; None when already on xcb (run
    here) or when no Xvfb can start (then it says so and the caller runs offscreen)."""
    if os.environ.get("QT_QPA_PLATFORM") == "xcb":
        return None
    from tests.realdisplay.xserver import XServer, XUnavailable, probe_env

    try:
        server = XServer.start()
    except XUnavailable as exc:
        print(f"NOTE: no X display ({exc}); running offscreen, where paint counts mean nothing")
        return None
    try:
        return subprocess.call([sys.executable, "-m", module, *argv], env=probe_env(server.display))
    finally:
        server.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a few seconds per scenario")
    parser.add_argument("--offscreen", action="store_true", help="do not start an X server (paints not counted)")
    args = parser.parse_args()
    if not args.offscreen:
        code = on_x_display(sys.argv[1:], "benchmarks.bench_forces_gui")
        if code is not None:
            sys.exit(code)
    run(args.quick)


if __name__ == "__main__":
    main()
