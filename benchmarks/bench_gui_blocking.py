"""How long the app's window stops answering: the GUI thread's event loop blocked while a calibration loads into the
Forces tab, while each tab is opened the first time, and while the Calibration tab fits trials.

The app as ``sensnake gui`` runs it (the simulated lab in its own process, the robot connected, the board streaming,
the window shown). A 5 ms ``QTimer`` ticks on the GUI thread throughout; blocked time is the longest gap between two
of its ticks, minus the 5 ms, while the action runs (the window answers no click, paints nothing, for that long).
Target: < 100 ms for each action.

- **First opening of a tab**: the tab is switched to from the event loop, as a click does; measured until the page
  is built and 1 s after (its first paints and timers).
- **Calibration load**: after ``--history`` seconds of live data, the simulated sensors' calibration (all 36) is
  loaded into the Forces tab, as File → Calibration… does; measured until the tab shows forces from it, and 1 s after.
  Also printed: how much of the plots' history is still there afterwards (the oldest time held, before and after).
- **Fit**: the Calibration tab fits 4 simulated paper-protocol trials (370 s holds at 6 Hz), as its Fit button does;
  measured until the fit's result is on screen.
- Beside the blocked time: the most CPU the GUI thread spent between two ticks, all the CPU it spent on the action
  until 1 s after it was done (work removed shows there whatever the machine's load), and the blocked time less what
  the GUI thread waited in the kernel's run queue for a CPU within that gap (Linux's schedstat): on a machine busy
  with other jobs, what is left is the app's own stall (its work, its waits for the interpreter lock).

``python -m benchmarks.bench_gui_blocking [--history 70] [--load 0] [--offscreen]``; ``run(quick)`` (``sensnake bench``)
uses 10 s of history. On a private Xvfb with Qt's xcb platform unless ``--offscreen`` or no Xvfb can start.
``--load N`` starts N busy processes beside the app (``while True: pass``, as benchmarks/bench_feedback_under_load.py).
``--why`` also prints, for each action, where the GUI thread was (its Python stack, sampled every 2 ms from another
thread) while a tick was more than 30 ms late, what the app's other threads were doing in those samples (a worker
holding the interpreter lock, or a kernel lock the GUI thread needs, is seen there, not on the GUI thread's stack),
and what took its CPU (cProfile with the thread's CPU clock), so an action over target names its cause.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

if "--offscreen" in sys.argv:
    os.environ["QT_QPA_PLATFORM"] = "offscreen"
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

TICK_MS = 5
TARGET_MS = 100.0
AFTER_S = 1.0  # measured on after an action is done: its first paints and the timers it started


def _queued_s() -> float:
    """Time the calling thread has waited runnable for a CPU in all (s): the kernel's schedstat, Linux; 0 elsewhere."""
    try:
        with open("/proc/thread-self/schedstat", encoding="ascii") as stat:
            return int(stat.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return 0.0


class LoopWatch:
    """A ``TICK_MS`` timer on the GUI thread that keeps the longest gap between its ticks since :meth:`reset`, in wall
    time and in the GUI thread's own CPU time (what a busy machine does not stretch: the work the thread did between
    two ticks)."""

    def __init__(self) -> None:
        from PySide6.QtCore import Qt, QTimer

        self._timer = QTimer()
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.setInterval(TICK_MS)
        self._timer.timeout.connect(self._tick)
        self._last = self._last_cpu = self.worst_gap_s = self.worst_cpu_s = self._cpu_at_reset = 0.0
        self._last_queued = self.worst_unqueued_s = 0.0
        self.reset()
        self._timer.start()

    def _tick(self) -> None:
        now, cpu, queued = time.perf_counter(), time.thread_time(), _queued_s()
        self.worst_gap_s = max(self.worst_gap_s, now - self._last)
        self.worst_cpu_s = max(self.worst_cpu_s, cpu - self._last_cpu)
        self.worst_unqueued_s = max(self.worst_unqueued_s, now - self._last - (queued - self._last_queued))
        self._last, self._last_cpu, self._last_queued = now, cpu, queued

    @property
    def last_tick_s(self) -> float:
        """``time.perf_counter()`` of the last tick (read from the sampler's thread)."""
        return self._last

    def reset(self) -> None:
        self._last, self._last_cpu, self._last_queued = time.perf_counter(), time.thread_time(), _queued_s()
        self._cpu_at_reset = self._last_cpu
        self.worst_gap_s = self.worst_cpu_s = self.worst_unqueued_s = 0.0

    @property
    def blocked_ms(self) -> float:
        return max(0.0, (self.worst_gap_s * 1000.0) - TICK_MS)

    @property
    def blocked_unqueued_ms(self) -> float:
        """:attr:`blocked_ms` less the time the GUI thread waited in the kernel's run queue for a CPU within that gap
        (Linux; the blocked time itself elsewhere): what is left of a stall when the machine's load is taken out —
        the thread's own work and its waits for the interpreter lock or other threads."""
        return max(0.0, (self.worst_unqueued_s * 1000.0) - TICK_MS)

    @property
    def busy_ms(self) -> float:
        """The most CPU the GUI thread spent between two ticks (ms)."""
        return self.worst_cpu_s * 1000.0

    @property
    def total_cpu_ms(self) -> float:
        """All the CPU the GUI thread spent since :meth:`reset` (ms; GUI thread): work done at all, wherever it fell,
        which neither the machine's load nor another thread holding the interpreter lock changes much."""
        return (time.thread_time() - self._cpu_at_reset) * 1000.0

    def stop(self) -> None:
        self._timer.stop()


STALL_S = 0.030  # a tick this late: the sampler records where the GUI thread is
SAMPLE_S = 0.002


class StallSampler:
    """A daemon thread that, while the watch's last tick is more than ``STALL_S`` old, records the GUI thread's
    Python stack every ``SAMPLE_S`` (what it waits in or works on while the window does not answer). A stack is the
    innermost frame of the project's own code with its callers in the project, and the innermost frame of all."""

    def __init__(self, watch: LoopWatch) -> None:
        self._watch = watch
        self._main = threading.get_ident()  # made on the GUI thread
        self._stop = threading.Event()
        self.samples: Counter[str] = Counter()
        self.others: Counter[str] = Counter()  # the other threads' innermost frames in the same samples
        self._thread = threading.Thread(target=self._run, name="stall-sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        root = str(Path(__file__).resolve().parents[1])
        while not self._stop.wait(SAMPLE_S):
            if time.perf_counter() - self._watch.last_tick_s <= STALL_S:
                continue
            frames = sys._current_frames()  # noqa: SLF001 - the sampler's whole point
            frame = frames.get(self._main)
            if frame is None:
                continue
            # A worker can hold the GUI thread without being on its stack (the interpreter lock, a lock of the
            # kernel's): what each other thread was doing meanwhile names it.
            names = {thread.ident: thread.name for thread in threading.enumerate()}
            for ident, other in frames.items():
                if ident not in (self._main, threading.get_ident()):
                    self.others[f"{names.get(ident, ident)}: {Path(other.f_code.co_filename).name}:"
                                f"{other.f_lineno} {other.f_code.co_name}"] += 1
            leaf = f"{Path(frame.f_code.co_filename).name}:{frame.f_lineno} {frame.f_code.co_name}"
            ours: list[str] = []
            while frame is not None and len(ours) < 6:
                name = frame.f_code.co_filename
                if name.startswith(root) and "bench_gui_blocking" not in name:
                    ours.append(f"{os.path.relpath(name, root)}:{frame.f_lineno} {frame.f_code.co_name}")
                frame = frame.f_back
            self.samples[" < ".join(ours or ["(event loop)"]) + f"  [leaf {leaf}]"] += 1

    def take(self) -> tuple[Counter[str], Counter[str]]:
        """(the GUI thread's stacks, the other threads' innermost frames) since the last call."""
        samples, self.samples = self.samples, Counter()
        others, self.others = self.others, Counter()
        return samples, others

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def _pump(ms: float, until: Callable[[], bool] | None = None) -> bool:
    """Run the event loop for at most ``ms`` (until ``until()``); True if ``until`` came true."""
    from PySide6.QtCore import QCoreApplication, QEventLoop

    deadline = time.monotonic() + ms / 1000
    while time.monotonic() < deadline:
        QCoreApplication.processEvents(QEventLoop.ProcessEventsFlag.AllEvents, 10)
        if until is not None and until():
            return True
        time.sleep(0.001)  # a benchmark's own loop: the watch's timer still fires every 5 ms
    return until is not None and until()


class Why:
    """``--why``: per action, the stall sampler's stacks and the GUI thread's CPU by function (cProfile)."""

    def __init__(self, watch: LoopWatch) -> None:
        self.sampler = StallSampler(watch)
        self.reports: dict[str, str] = {}

    @contextlib.contextmanager
    def around(self, name: str) -> Iterator[None]:
        import cProfile
        import io
        import pstats

        self.sampler.take()
        profile = cProfile.Profile(time.thread_time)  # this (the GUI) thread's CPU clock
        profile.enable()
        try:
            yield
        finally:
            profile.disable()
            lines = [f"--- {name}: where the GUI thread was while a tick was > {STALL_S * 1000:.0f} ms late "
                     f"({SAMPLE_S * 1000:.0f} ms samples)"]
            samples, others = self.sampler.take()
            lines += [f"{count:5d}  {stack}" for stack, count in samples.most_common(8)]
            lines.append(f"--- {name}: the other threads meanwhile (innermost frame; one waiting in select, a lock or a "
                         "queue holds nothing)")
            lines += [f"{count:5d}  {where}" for where, count in others.most_common(8)]
            text = io.StringIO()
            pstats.Stats(profile, stream=text).sort_stats("cumulative").print_stats(25)
            lines.append(f"--- {name}: the GUI thread's CPU by function (cumulative s)")
            lines += [line for line in text.getvalue().splitlines() if line.strip()][4:]
            self.reports[name] = "\n".join(lines)


def _measure(watch: LoopWatch, action: Callable[[], None], done: Callable[[], bool],
             limit_s: float = 120.0, why: Why | None = None, name: str = "",
             ) -> tuple[float, float, float, float, float]:
    """Run ``action`` from the event loop (as a click does), pump until ``done()`` and ``AFTER_S`` more; returns
    (blocked ms, its GUI-thread CPU ms, wall s until done, the GUI thread's CPU ms in all until ``AFTER_S`` after,
    blocked ms less the GUI thread's wait for a CPU)."""
    from PySide6.QtCore import QTimer

    _pump(200)
    with why.around(name) if why is not None else contextlib.nullcontext():
        watch.reset()
        started = time.perf_counter()
        QTimer.singleShot(0, action)
        finished = _pump(limit_s * 1000, until=done)
        wall_s = time.perf_counter() - started
        _pump(AFTER_S * 1000)
        total_cpu_ms = watch.total_cpu_ms
    if not finished:
        raise RuntimeError(f"bench_gui_blocking: not done within {limit_s:g} s")
    return watch.blocked_ms, watch.busy_ms, wall_s, total_cpu_ms, watch.blocked_unqueued_ms


def _trial_files(folder: Path) -> list[Path]:
    from app.core import calfiles
    from models.physics import PhysicsConstants
    from models.synthetic import TYPICAL_TRUTH, paper_protocol

    trials = paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=3, forces_n=(1.75, 3.0, 4.0, 5.25), repeats=1,
                            noise_rel=0.002)
    paths = []
    for trial in trials:
        path = folder / f"{trial.name}.csv"
        calfiles.write_trial_csv(path, trial.time_s, trial.force_n, trial.conductance_s)
        paths.append(path)
    return paths


@contextlib.contextmanager
def _data_dir(folder: Path) -> Iterator[None]:
    """``$SENSNAKE_DATA_DIR`` is ``folder`` meanwhile (never the user's), and as it was afterwards (``sensnake bench``
    runs the next benchmark in this process)."""
    previous = os.environ.get("SENSNAKE_DATA_DIR")
    os.environ["SENSNAKE_DATA_DIR"] = str(folder)
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop("SENSNAKE_DATA_DIR", None)
        else:
            os.environ["SENSNAKE_DATA_DIR"] = previous


@contextlib.contextmanager
def _busy(load: int) -> Iterator[None]:
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        yield
    finally:
        for process in busy:
            process.kill()
            process.wait()


def measure(history_s: float, load: int = 0, why: bool = False) -> dict[str, Any]:
    """Run every scenario once; returns {action: (blocked ms, GUI CPU ms, wall s)} plus the history kept across a
    calibration load."""
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QApplication

    import widgets  # noqa: F401 - installs the PySide6 refcount guard before Qt is used

    app = QApplication.instance() or QApplication([])
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="sensnake-bench-gui-") as tmp, _busy(load), \
            _data_dir(Path(tmp) / "data"):
        from app.gui.lab import LabContext
        from app.gui.main_window import TABS, MainWindow
        from devices import factory
        from devices.config import load_config

        config = load_config(None)
        lab = LabContext(config, lab_process=True)
        window = MainWindow(lab, settings=QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat))
        window.resize(1280, 800)
        window.show()
        lab.connect_all()
        watch = LoopWatch()
        explain = Why(watch) if why else None
        try:
            _pump(60_000, until=lambda: lab.robot.is_connected and lab.board is not None and lab.board.is_connected)
            watch.reset()
            _pump(2_000)
            results["idle (2 s, nothing asked)"] = (watch.blocked_ms, watch.busy_ms, 0.0, watch.total_cpu_ms,
                                                    watch.blocked_unqueued_ms)
            for index, spec in enumerate(TABS):
                if window.tab_widget(spec.name) is not None:
                    continue

                def open_tab(i: int = index) -> None:
                    window.tabs.setCurrentIndex(i)

                def built(name: str = spec.name) -> bool:
                    complete = getattr(window, "tab_is_complete", None)  # (a window that builds tabs in one go)
                    return complete(name) if complete is not None else window.tab_widget(name) is not None

                name = f"first opening: {spec.title}"
                results[name] = _measure(watch, open_tab, built, why=explain, name=name)
            forces: Any = window.show_tab("forces")
            board = lab.board
            _pump(history_s * 1000, until=lambda: board.history.span()[1] - board.history.span()[0] >= history_s)
            cal = Path(tmp) / "simulated.json"
            cal.write_text(json.dumps(factory.simulated_sensors_calibration(config)), encoding="utf-8")
            oldest_before, newest_before = forces.force_history.span()
            results["calibration load"] = _measure(
                watch, lambda: forces.load_calibration(cal),
                lambda: forces.pipeline.calibration_source == str(cal)
                and not getattr(forces, "is_loading_calibration", False), why=explain, name="calibration load")
            oldest_after, newest_after = forces.force_history.span()
            results["history"] = (newest_before - oldest_before, newest_after - oldest_before,
                                  oldest_after - oldest_before)
            calibration: Any = window.show_tab("calibration")
            _pump(500)
            calibration.add_trial_files(_trial_files(Path(tmp)))
            results["fit (4 trials)"] = _measure(
                watch, calibration.start_fit,
                lambda: not calibration.is_fitting and calibration.result is not None, why=explain,
                name="fit (4 trials)")
        finally:
            if explain is not None:
                explain.sampler.stop()
                results["why"] = explain.reports
            watch.stop()
            window.close()
            lab.close()
            app.processEvents()
    return results


def report(results: dict[str, Any], history_s: float, load: int) -> None:
    platform = os.environ.get("QT_QPA_PLATFORM", "")
    print(f"GUI thread blocked (longest gap between {TICK_MS} ms ticks, minus {TICK_MS} ms; target < {TARGET_MS:g} ms)"
          f", the most CPU the GUI thread spent between two ticks (its own work, which a busy machine does not "
          f"stretch) and its CPU in all until {AFTER_S:g} s after (the idle window's: over 2 s) — Qt {platform or 'default'} platform, {load} busy process(es), {os.cpu_count()} cores, load "
          f"average {os.getloadavg()[0]:.1f} at the end")
    print(f"{'action':<34} {'blocked ms':>11} {'most CPU ms':>11} {'done after s':>13} {'CPU in all ms':>14} "
          f"{'blocked, not CPU-queued ms':>27}")
    for name, value in results.items():
        if name in ("history", "why"):
            continue
        blocked_ms, busy_ms, wall_s, total_cpu_ms, unqueued_ms = value
        flag = "" if blocked_ms < TARGET_MS else "  (over target)"
        print(f"{name:<34} {blocked_ms:>11.0f} {busy_ms:>11.0f} {wall_s:>13.2f} {total_cpu_ms:>14.0f} "
              f"{unqueued_ms:>27.0f}{flag}")
    held_before, held_after_from_old, trimmed_s = results["history"]
    print(f"plots' history across the calibration load: {held_before:.0f} s held before; afterwards it reaches back "
          f"to {trimmed_s:+.0f} s of the old oldest sample ({'kept' if trimmed_s <= 1.0 else 'dropped'}); "
          f"{history_s:g} s of live data before the load")
    del held_after_from_old
    for text in results.get("why", {}).values():
        print(text)


def run(quick: bool = False) -> None:
    """``sensnake bench``: offscreen unless a display is set up already."""
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    history_s = 10.0 if quick else 70.0
    report(measure(history_s), history_s, 0)


def on_x_display(argv: list[str]) -> int | None:
    """Re-run this module on a private Xvfb with Qt's xcb platform; None when already on xcb or none can start."""
    if os.environ.get("QT_QPA_PLATFORM") == "xcb":
        return None
    from tests.realdisplay.xserver import XServer, XUnavailable, probe_env

    try:
        server = XServer.start()
    except XUnavailable as exc:
        print(f"NOTE: no X display ({exc}); running offscreen")
        os.environ["QT_QPA_PLATFORM"] = "offscreen"
        return None
    try:
        return subprocess.call([sys.executable, "-m", "benchmarks.bench_gui_blocking", *argv],
                               env=probe_env(server.display))
    finally:
        server.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--history", type=float, default=70.0, help="seconds of live data before the load")
    parser.add_argument("--load", type=int, default=0, help="busy processes beside the app")
    parser.add_argument("--offscreen", action="store_true", help="offscreen Qt instead of a private Xvfb")
    parser.add_argument("--why", action="store_true", help="where the GUI thread was in each stall, and its CPU")
    args = parser.parse_args()
    if not args.offscreen:
        code = on_x_display(sys.argv[1:])
        if code is not None:
            sys.exit(code)
    report(measure(args.history, args.load, args.why), args.history, args.load)


if __name__ == "__main__":
    main()
