"""Gaits in the app on the real-port path on a busy machine: the independent XM430-chain emulator and the independent
board emulator (tests/emulators), each its own process on a pseudo-terminal, named in the lab config as real ports
are; the app's window (MainWindow, the Gait, Forces and Hardware tabs shown in turn), the control loop in its own
process (the app's choice on a real port), the Forces tab estimating the emulated board's forces and publishing them
to the control loop's process; ``--busy N`` processes spinning (``while True``) beside it all.

The Gait tab plays a taught shape follow-the-leader (``--gait follow``, feedforward) or with force feedback
(``--gait feedback``) again and again for ``--minutes``; the loop's ticks are counted over the whole window (the plays
and the moments between them). Target: 0 missed ticks, period p99 ≤ 22 ms, no fault, no servo blamed.

``--no-realtime`` runs the app with ``SENSNAKE_REALTIME=0`` (the loop at normal priority, as without the privilege);
the emulators keep their own real-time priority either way (they stand for hardware, which answers on time).

``--tty-workers-rt`` raises the kernel's unbound worker threads (``kworker/u*``) to SCHED_FIFO for the window and
sets them back afterwards: Linux hands every byte a tty receives (a pty's either way, a USB-serial adapter's from
the device) to such a worker, which runs at normal priority and waits behind the machine's load (see
docs/BENCHMARKS.md "The tty layer's worker"). New workers are raised as they appear (checked every 0.5 s). Needs
root; changes the whole machine while it runs.

``--trace DIR``: the late-tick trace (benchmarks/late_tick_trace) of the window: why each late tick was late.

Measured on the 2-core machine, Xvfb/xcb, 10 minutes beside the 2 busy processes only (load 0.8-3.4), tty
workers as the kernel runs them: real-time priority, feedback 0 missed of 30,011 ticks, period p99 20.06 ms;
follow-the-leader 0 of 30,043, p99 20.06 ms. ``--no-realtime`` (0.1 ms time slice), follow-the-leader: 101 of 29,922
missed, p99 20.86 ms, every stall reported as the loop's. All figures and what each late tick was:
docs/BENCHMARKS.md and docs/REALTIME.md.

    QT_QPA_PLATFORM=xcb DISPLAY=:N python -m benchmarks.bench_gait_real_port --gait follow --minutes 10 --busy 2
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

TTY_WORKER_PREFIX = "kworker/u"
TTY_WORKER_PRIORITY = 25  # above the loop's bus thread (20): the bytes it waits for come first


def _kworkers() -> list[int]:
    tids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if (entry / "comm").read_text().startswith(TTY_WORKER_PREFIX):
                tids.append(int(entry.name))
    return tids


@contextlib.contextmanager
def tty_workers_rt(enabled: bool) -> Iterator[list[int]]:
    """While inside: every ``kworker/u*`` thread at SCHED_FIFO ``TTY_WORKER_PRIORITY`` (new ones raised within
    0.5 s); afterwards back to SCHED_OTHER. Yields the list of threads raised (grows)."""
    raised: list[int] = []
    if not enabled:
        yield raised
        return
    stop = threading.Event()

    def keep_raised() -> None:
        while not stop.is_set():
            for tid in _kworkers():
                if tid in raised:
                    continue
                with contextlib.suppress(OSError):
                    os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(TTY_WORKER_PRIORITY))
                    raised.append(tid)
            stop.wait(0.5)

    thread = threading.Thread(target=keep_raised, name="tty-workers-rt", daemon=True)
    thread.start()
    try:
        yield raised
    finally:
        stop.set()
        thread.join()
        for tid in raised:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


def _calibration(path: Path) -> None:
    """Every channel's sensor model: the scripted simulated board's own (what calibrating 36 sensors gives)."""
    from devices.config import LabConfig, SimLabConfig
    from devices.sim.lab import SimLab

    lab = SimLab(dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="scripted")), seed=1)
    try:
        path.write_text(json.dumps(lab.board.ground_truth_calibration()), encoding="utf-8")
    finally:
        lab.close()


def run(gait: str, minutes: float, busy: int, rotate_s: float, trace_dir: str | None, tty_rt: bool) -> dict:
    from PySide6.QtCore import QEventLoop, QTimer
    from PySide6.QtWidgets import QApplication

    import widgets  # noqa: F401 - installs the PySide6 refcount guard before Qt is used
    from app.core.force_control import FeedbackProgress
    from app.core.shapes import Shape, ShapeLibrary
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from app.gui.robot_bridge import MOTION_RUNNING
    from benchmarks import late_tick_trace
    from devices.config import LabConfig
    from tests.emulators.board_emulator import EmulatedBoard
    from tests.emulators.xm430_emulator import EmulatorProcess

    app = QApplication.instance() or QApplication([])
    loop = QEventLoop()

    def spin(seconds: float, until: Callable[[], bool] = lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            QTimer.singleShot(20, loop.quit)
            loop.exec()

    tracing = late_tick_trace.start(trace_dir) if trace_dir else None
    result: dict = {"gait": gait, "minutes": minutes, "busy": busy,
                    "realtime": os.environ.get("SENSNAKE_REALTIME", "1") != "0", "tty_workers_rt": tty_rt}
    busy_processes: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory(prefix="sensnake-gait-bench-") as tmp:
        folder = Path(tmp)
        emulator = EmulatorProcess()
        board = EmulatedBoard(folder, rate_hz=30)
        config = LabConfig().with_ports(robot=emulator.path, board=board.path)
        shape = np.zeros(config.robot.n_joints)
        shape[[2, 4, 6, 8]] = -0.3
        library = ShapeLibrary(folder / "shapes")
        library.save(Shape("bench", tuple(config.robot.axes), tuple(float(a) for a in shape)))
        cal = folder / "cal.json"
        _calibration(cal)
        lab = LabContext(config)
        window = MainWindow(lab)
        try:
            window.show()
            lab.connect_all()
            spin(20.0, lambda: lab.robot.is_connected and lab.robot.latest_state is not None)
            if not lab.robot.is_connected:
                raise SystemExit("bench_gait_real_port: the robot did not connect within 20 s")
            result["loop_where"] = lab.robot.loop_where
            result["scheduling"] = getattr(lab.robot.controller, "scheduling", "")
            forces: Any = window.show_tab("forces")
            if not forces.load_calibration(cal):
                raise SystemExit("bench_gait_real_port: the calibration did not load")
            spin(30.0, lambda: not forces.is_loading_calibration)
            tabs = ("gait", "forces", "hardware")
            for name in tabs:  # each tab is built on its first show, before the window is measured
                window.show_tab(name)
                spin(1.0)
            gait_tab: Any = window.show_tab("gait")
            gait_tab.library = library  # the bench's own shape library, not the user's
            gait_tab.refresh_shapes()
            panel = gait_tab.panel
            panel.set_mode("follow")
            panel.shape_combo.setCurrentText("bench")
            panel.speed_spin.setValue(0.1)
            panel.controller_combo.setCurrentIndex(panel.controller_combo.findData(
                "feedback" if gait == "feedback" else "feedforward"))
            errors: list[str] = []
            events: list[str] = []
            lab.robot.error.connect(errors.append)
            if hasattr(lab.robot, "event"):
                lab.robot.event.connect(events.append)
            statuses: list[str] = []
            feedback = [0, 0, 0]  # feedback progress samples, of which without a fresh force estimate, never any
            ages: list[float] = []  # the force estimate's age at each sample (s)
            busy_processes = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
            spin(2.0)
            with tty_workers_rt(tty_rt) as raised:
                load0 = os.getloadavg()[0]
                if tracing is not None:
                    late_tick_trace.start_probes(tracing, minutes * 60 + 5.0)
                s0 = lab.robot.loop_stats()
                taken, chunks = s0.ticks, []
                t0 = time.monotonic()
                plays = finished = 0
                shown = 0
                next_rotate = t0 + rotate_s
                loads = [load0]
                while time.monotonic() - t0 < minutes * 60:
                    if lab.robot.controller is None:
                        break
                    if lab.robot.motion_state != MOTION_RUNNING:
                        text = panel.status_label.text() if hasattr(panel, "status_label") else ""
                        if plays:
                            statuses.append(text)
                            finished += text.endswith("finished")
                        panel.play_button.click()
                        plays += 1
                        spin(10.0, lambda: lab.robot.motion_state == MOTION_RUNNING)
                    spin(1.0)
                    progress = getattr(gait_tab.source, "progress", None)
                    if isinstance(progress, FeedbackProgress):  # sampled once a second: forces reach the loop?
                        feedback[0] += 1
                        feedback[1] += any("no force estimate" in why for _, why in progress.fallback)
                        feedback[2] += any("no force estimate yet" in why for _, why in progress.fallback)
                        ages.append(float(getattr(progress, "force_age_s", float("nan"))))
                    if time.monotonic() >= next_rotate:
                        shown += 1
                        window.show_tab(tabs[shown % len(tabs)])
                        next_rotate += rotate_s
                        loads.append(os.getloadavg()[0])
                    s = lab.robot.loop_stats()
                    chunks.append(lab.robot.controller.recent_periods_s(s.ticks - taken))
                    taken = s.ticks
                t1 = time.monotonic()
                s1 = lab.robot.loop_stats()
                if lab.robot.controller is not None:
                    chunks.append(lab.robot.controller.recent_periods_s(s1.ticks - taken))
                result["tty_workers_raised"] = len(raised)
            lab.robot.stop_motion()
            spin(2.0)
            periods = np.concatenate(chunks) if chunks else np.zeros(0)
            result.update(
                wall_s=t1 - t0, ticks=s1.ticks - s0.ticks, missed=s1.missed_ticks - s0.missed_ticks,
                late=s1.late_ticks - s0.late_ticks, failed_reads=s1.failed_reads - s0.failed_reads,
                late_reads=getattr(s1, "late_reads", 0) - getattr(s0, "late_reads", 0),
                health_given_up=getattr(s1, "health_reads_given_up", 0) - getattr(s0, "health_reads_given_up", 0),
                period_p50_ms=float(np.median(periods) * 1e3) if periods.size else float("nan"),
                period_p99_ms=float(np.percentile(periods, 99) * 1e3) if periods.size else float("nan"),
                period_max_ms=float(periods.max() * 1e3) if periods.size else float("nan"),
                plays=plays, finished=finished, errors=errors,
                stall_events=[e for e in events if "has not ticked" in e],
                faults=[s for s in statuses if "stopped:" in s or "cannot start" in s],
                statuses=sorted(set(statuses)), feedback_ticks=feedback[0], stale_force_ticks=feedback[1],
                no_force_yet_ticks=feedback[2],
                force_age_p50_ms=float(np.nanmedian(ages) * 1e3) if ages else float("nan"),
                force_age_p90_ms=float(np.nanpercentile(ages, 90) * 1e3) if ages else float("nan"),
                load_min=min(loads), load_max=max(loads), load_end=os.getloadavg()[0])
        finally:
            for process in busy_processes:
                process.kill()
                process.wait()
            window.close()
            lab.close()
            board.stop()
            emulator.close()
            if tracing is not None:
                late_tick_trace.stop(tracing)
                late_tick_trace.report(tracing, t0, t1) if "t1" in locals() else None
    del app
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gait", choices=("follow", "feedback"), default="follow")
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--busy", type=int, default=2, help="busy processes beside the app (default 2)")
    parser.add_argument("--rotate", type=float, default=20.0, help="seconds each tab is shown (gait, forces, hardware)")
    parser.add_argument("--no-realtime", action="store_true", help="the app without real-time priority "
                        "(SENSNAKE_REALTIME=0; the emulators keep theirs)")
    parser.add_argument("--tty-workers-rt", action="store_true", help="the kernel's unbound workers at SCHED_FIFO "
                        "during the window (root; the whole machine)")
    parser.add_argument("--trace", metavar="DIR", help="trace the late ticks into DIR and say why each was late")
    parser.add_argument("--json", metavar="FILE", help="also write the result as JSON")
    args = parser.parse_args()
    if args.no_realtime:
        os.environ["SENSNAKE_REALTIME"] = "0"
    print(f"machine load average (1 min) at the start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; "
          f"other processes using CPU now: {_top_others()}", flush=True)
    r = run(args.gait, args.minutes, args.busy, args.rotate, args.trace, args.tty_workers_rt)
    print(f"{r['gait']} gait in the app on the pty real-port path, {r['wall_s'] / 60:.1f} min, {r['busy']} busy "
          f"processes, loop {'with' if r['realtime'] else 'without'} real-time priority ({r['scheduling']}), tty "
          f"workers {'at SCHED_FIFO' if r['tty_workers_rt'] else 'as the kernel runs them'}; load "
          f"{r['load_min']:.1f}-{r['load_max']:.1f}")
    print(f"  ticks {r['ticks']}, missed {r['missed']}, late {r['late']}, failed feedback reads {r['failed_reads']} "
          f"(given up at the tick's deadline, replies late: {r['late_reads']}), health reads given up at the next "
          f"slot {r['health_given_up']}; "
          f"period p50 {r['period_p50_ms']:.2f} ms, p99 {r['period_p99_ms']:.2f} ms, max {r['period_max_ms']:.2f} ms")
    print(f"  plays {r['plays']} ({r['finished']} finished), faults {len(r['faults'])}, robot errors "
          f"{len(r['errors'])}, loop-stall events {len(r['stall_events'])}")
    if r["gait"] == "feedback":
        print(f"  feedback progress sampled {r['feedback_ticks']}× (once a second), without a force estimate "
              f"{r['stale_force_ticks']}× (of which never any {r['no_force_yet_ticks']}×); force age p50 "
              f"{r['force_age_p50_ms']:.0f} ms, p90 {r['force_age_p90_ms']:.0f} ms (the loop falls back to the "
              "feedforward when older than 100 ms)")
    print(f"  how the plays ended: {' | '.join(r['statuses'])}")
    for text in r["faults"] + r["errors"] + r["stall_events"]:
        print(f"    {text}")
    print(f"machine load average (1 min) at the end: {os.getloadavg()[0]:.2f}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1), encoding="utf-8")


def _top_others(n: int = 6) -> str:
    """The processes using the most CPU right now (``ps``), so a result says what load was present."""
    try:
        out = subprocess.run(["ps", "-eo", "pcpu,comm,args", "--sort=-pcpu", "--no-headers"], capture_output=True,
                             text=True, timeout=10).stdout.splitlines()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return "; ".join(" ".join(line.split()[:1] + [" ".join(line.split()[2:])[:70]]) for line in out[:n])


if __name__ == "__main__":
    main()
