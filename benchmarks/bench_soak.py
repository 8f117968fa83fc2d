"""Soak benchmark: the app streams for ≥ 30 simulated minutes with the Forces tab visible; CPU and memory must stay flat.

A long session used to climb (CPU 73-81 % of a core, memory 170 → 312 MB). Here the simulated lab runs ``--speed``×
faster than real time (every device, the board's frame rate included), so 30 simulated minutes take 30/speed wall
minutes and push speed× the data a real session would through the same code. Each simulated minute the benchmark
records the process's CPU (fraction of one core over that minute's wall time), the GUI thread's CPU and the resident
memory, and what the work costs whatever share of the 2 shared cores the process got: process CPU per sample delivered
to the GUI and GUI-thread CPU per plot redraw. From the 5th minute on, none may drift by more than 10 % (median of the
last ten minutes against the first ten) and memory must stay within 10 % of its 5th-minute value. The largest
single-minute CPU deviation is printed too: on a shared machine it follows the neighbours' load.

Runs on its own Xvfb with Qt's xcb platform (real paints), like ``bench_forces_gui``; ``--offscreen`` skips X.
    python -m benchmarks.bench_soak [--minutes 30] [--speed 10] [--tab forces]
``sensnake bench`` runs it as 30 simulated minutes at 6× (``--quick``: 8 at 12×).
CPU figures are noisy on a shared machine: the load average is printed with them.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

if "--offscreen" in sys.argv:
    os.environ["QT_QPA_PLATFORM"] = "offscreen"
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

import widgets  # noqa: E402,F401 - installs the PySide6 refcount guard before Qt is used

FLAT_FROM_MINUTE = 5
FLAT_TOLERANCE = 0.10


def _rss_mb() -> float:
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def soak(minutes: float, speed: float, tab: str) -> list[dict]:
    """Stream ``minutes`` simulated minutes with ``tab`` visible; one row per simulated minute."""
    from PySide6.QtCore import QEventLoop, QSettings, QTimer
    from PySide6.QtWidgets import QApplication

    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from devices import factory
    from devices.config import SIM_PORT, load_config
    from devices.sim.lab import SimLab

    app = QApplication.instance() or QApplication([])
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="sensnake-soak-") as tmp:
        os.environ["XDG_DATA_HOME"] = str(Path(tmp) / "data")
        config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
        # The scripted lab: its clock runs faster than real time here, which the physics lab does not keep up with.
        config = replace(config, lab=replace(config.lab, physics="scripted"))
        previous = factory.install_sim_lab(SimLab(config, seed=11, speed=speed))
        lab = LabContext(config)
        window = MainWindow(lab, settings=QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat))
        window.resize(1280, 800)
        page = window.show_tab(tab)
        window.show()
        lab.connect_all()
        minute_wall_s = 60.0 / speed
        plots = getattr(page, "plots", None)

        def counters() -> tuple[int, int]:
            """(samples delivered to the GUI, plot redraws) so far."""
            return lab.board.bridge_stats.samples, (plots.redraw_count if plots is not None else 0)

        samples0, redraws0 = counters()
        state = {"wall": time.monotonic(), "cpu": time.process_time(), "gui": time.thread_time(),
                 "samples": samples0, "redraws": redraws0}
        loop = QEventLoop()

        profile_dir = os.environ.get("SOAK_PROFILE")  # a cProfile of minutes 2 and the last-but-one, to compare
        profiler = None

        def sample() -> None:
            nonlocal profiler
            now, cpu, gui = time.monotonic(), time.process_time(), time.thread_time()
            if profiler is not None:
                profiler.disable()
                profiler.dump_stats(str(Path(profile_dir) / f"soak-minute-{len(rows) + 1}.prof"))
                profiler = None
            if profile_dir and len(rows) + 2 in (2, int(minutes) - 1):
                import cProfile

                profiler = cProfile.Profile()
                profiler.enable()
            wall = now - state["wall"]
            samples, redraws = counters()
            n_samples, n_redraws = samples - state["samples"], redraws - state["redraws"]
            rows.append({"minute": len(rows) + 1, "cpu": (cpu - state["cpu"]) / wall,
                         "gui_cpu": (gui - state["gui"]) / wall, "rss_mb": _rss_mb(),
                         "load": os.getloadavg()[0],
                         # What the work costs, whatever share of the cores the shared machine gave us:
                         "cpu_ms_per_sample": 1e3 * (cpu - state["cpu"]) / max(1, n_samples),
                         "gui_ms_per_redraw": 1e3 * (gui - state["gui"]) / max(1, n_redraws),
                         "fps": n_redraws / wall})
            state.update(wall=now, cpu=cpu, gui=gui, samples=samples, redraws=redraws)
            r = rows[-1]
            print(f"  minute {r['minute']:>3}: process CPU {100 * r['cpu']:5.1f} %  GUI {100 * r['gui_cpu']:5.1f} %  "
                  f"RSS {r['rss_mb']:6.1f} MB  CPU/sample {r['cpu_ms_per_sample']:.3f} ms  "
                  f"GUI/redraw {r['gui_ms_per_redraw']:5.2f} ms  {r['fps']:4.1f} fps  (load {r['load']:.1f})",
                  flush=True)
            if len(rows) >= minutes:
                loop.quit()

        timer = QTimer()
        timer.setInterval(int(minute_wall_s * 1000))
        timer.timeout.connect(sample)
        timer.start()
        loop.exec()
        timer.stop()
        window.close()
        app.processEvents()
        factory.install_sim_lab(previous)
    return rows


def _drift(values) -> float:
    """Relative change from the first ten to the last ten minutes (medians; fewer in a short run): a cost creeping
    up over the session shows here, a busy neighbour for a minute or two does not."""
    import numpy as np

    values = np.asarray(values, dtype=float)
    k = min(10, max(1, len(values) // 2))
    first, last = float(np.median(values[:k])), float(np.median(values[-k:]))
    return (last - first) / first if first else float("nan")


def flatness(rows: list[dict]) -> dict:
    """From the 5th minute on: drift (last ten minutes against the first ten, medians) of process CPU, of the CPU
    per delivered sample and per redraw (what the work costs: independent of how busy the shared machine is), and of
    RSS; plus the largest single-minute deviation of process CPU from its median (which a loaded machine inflates)."""
    import numpy as np

    later = [r for r in rows if r["minute"] >= FLAT_FROM_MINUTE]
    if not later:
        return {"cpu_dev": float("nan"), "rss_dev": float("nan")}
    cpu = np.array([r["cpu"] for r in later])
    rss = np.array([r["rss_mb"] for r in later])
    return {"cpu_dev": float(np.max(np.abs(cpu - np.median(cpu))) / np.median(cpu)),
            "rss_dev": float(np.max(np.abs(rss - rss[0])) / rss[0]),
            "cpu_drift": _drift(cpu),
            "per_sample_drift": _drift([r["cpu_ms_per_sample"] for r in later]),
            "per_redraw_drift": _drift([r["gui_ms_per_redraw"] for r in later]),
            "cpu_median": float(np.median(cpu)), "rss_first": float(rss[0]), "rss_last": float(rss[-1]),
            "per_sample_ms": float(np.median([r["cpu_ms_per_sample"] for r in later])),
            "per_redraw_ms": float(np.median([r["gui_ms_per_redraw"] for r in later])),
            "load": float(np.median([r["load"] for r in later]))}


def run(quick: bool) -> None:
    """For ``sensnake bench``: the soak in its own process (its own Xvfb, Qt on xcb): 30 simulated minutes at 6×
    (5 wall minutes), or with ``quick`` 8 simulated minutes at 12× (40 s: too short to judge, shows it runs)."""
    import subprocess

    minutes, speed = ("8", "12") if quick else ("30", "6")
    code = subprocess.call([sys.executable, "-m", "benchmarks.bench_soak", "--minutes", minutes, "--speed", speed])
    if code not in (0, 1):  # 1 = ran, not flat: the table says why
        raise RuntimeError(f"bench_soak exited with {code}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="simulated minutes to stream (default 30)")
    parser.add_argument("--speed", type=float, default=10.0, help="simulated lab speed-up (default 10)")
    parser.add_argument("--tab", default="forces", help="tab kept visible (default forces)")
    parser.add_argument("--offscreen", action="store_true", help="do not start an X server")
    args = parser.parse_args()
    if not args.offscreen:
        from benchmarks.bench_forces_gui import on_x_display

        code = on_x_display(sys.argv[1:], "benchmarks.bench_soak")
        if code is not None:
            sys.exit(code)
    print(f"Soak: {args.minutes:g} simulated minutes at {args.speed:g}× on the simulated lab, {args.tab} tab visible, "
          f"Qt {os.environ.get('QT_QPA_PLATFORM', '?')}, {os.cpu_count()} cores")
    rows = soak(args.minutes, args.speed, args.tab)
    f = flatness(rows)
    tol = 100 * FLAT_TOLERANCE
    drifts = (f["cpu_drift"], f["per_sample_drift"], f["per_redraw_drift"])
    ok = all(abs(d) <= FLAT_TOLERANCE for d in drifts) and f["rss_dev"] <= FLAT_TOLERANCE
    print(f"From minute {FLAT_FROM_MINUTE} (load average {f['load']:.1f} on {os.cpu_count()} cores):")
    print(f"  process CPU median {100 * f['cpu_median']:.1f} % of one core, drift {100 * f['cpu_drift']:+.1f} % "
          f"(|drift| <= {tol:.0f} %); largest single-minute deviation {100 * f['cpu_dev']:.1f} % (load-driven)")
    print(f"  CPU per delivered sample {f['per_sample_ms']:.3f} ms, drift {100 * f['per_sample_drift']:+.1f} %; "
          f"GUI per redraw {f['per_redraw_ms']:.2f} ms, drift {100 * f['per_redraw_drift']:+.1f} %")
    print(f"  RSS {f['rss_first']:.0f} → {f['rss_last']:.0f} MB, largest deviation {100 * f['rss_dev']:.1f} % "
          f"(<= {tol:.0f} %)")
    print("FLAT" if ok else "NOT FLAT")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
