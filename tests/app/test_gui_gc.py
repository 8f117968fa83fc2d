"""Garbage collection happens on the GUI thread only while the app runs (app/gui/gui_gc.py)."""

from __future__ import annotations

import gc
import threading

from app.gui.gui_gc import GuiThreadCollector


class _Cycle:
    def __init__(self) -> None:
        self.me = self
        self.freed_on: list[str] = []

    def __del__(self) -> None:
        self.freed_on.append(threading.current_thread().name)


def test_a_worker_thread_allocating_never_collects_and_the_gui_thread_does(qtbot):
    collector = GuiThreadCollector(interval_ms=10)
    collector.start()
    freed: list[str] = []
    try:
        assert not gc.isenabled()

        def churn() -> None:
            for _ in range(20_000):  # far past generation 0's threshold: automatic collection would run here
                cycle = _Cycle()
                cycle.freed_on = freed
                del cycle

        worker = threading.Thread(target=churn, name="worker")
        worker.start()
        worker.join(timeout=30)
        assert not worker.is_alive()
        assert freed == [] or set(freed) == {"MainThread"}  # nothing was freed by the worker
        qtbot.waitUntil(lambda: len(freed) > 0, timeout=10_000)  # the timer collects on the GUI thread
        assert collector.collections >= 1
        assert set(freed) == {"MainThread"}
    finally:
        collector.stop()
    assert gc.isenabled() is False  # the test fixture's collector is still running: it restores at its end


def test_stop_collects_once_more_and_restores_automatic_collection(qapp):
    assert gc.isenabled()
    collector = GuiThreadCollector()
    collector.start()
    freed: list[str] = []
    cycle = _Cycle()
    cycle.freed_on = freed
    del cycle
    assert not gc.isenabled() and freed == []
    collector.stop()
    assert gc.isenabled() and freed == ["MainThread"]


def _tracked(obj: object) -> bool:
    """Whether a collection would walk ``obj`` (frozen objects are in none of the three generations)."""
    return any(o is obj for o in gc.get_objects())


def test_settle_takes_what_exists_out_of_later_collections_until_stop(qapp):
    """The window's long-lived objects made every full collection walk ~45 000 objects (32-36 ms holding the
    interpreter lock, 3-4 missed ticks of an in-process loop at 100 Hz); settled, they are skipped."""
    collector = GuiThreadCollector()
    collector.start()
    freed: list[str] = []
    try:
        long_lived = _Cycle()
        long_lived.freed_on = freed
        assert _tracked(long_lived)
        collector.settle()
        assert collector.settled == 1 and gc.get_freeze_count() > 0
        assert not _tracked(long_lived)
        made_after = _Cycle()
        assert _tracked(made_after)  # what comes later is collected as usual
        del long_lived
        gc.collect()
        assert freed == []  # a settled cycle that became garbage waits for stop()
    finally:
        collector.stop()
    assert freed == ["MainThread"] and gc.get_freeze_count() == 0


def test_the_window_settles_once_built_and_after_each_new_tab(qtbot, tmp_path):
    from PySide6.QtCore import QSettings

    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from devices.config import SIM_PORT, LabConfig

    lab = LabContext(LabConfig().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT))
    window = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(window)
    collector = window._collector
    qtbot.waitUntil(lambda: collector.settled == 1, timeout=5_000)
    assert not _tracked(window.tabs)
    page = window.show_tab("hardware")
    assert _tracked(page)
    qtbot.waitUntil(lambda: collector.settled == 2, timeout=5_000)
    assert not _tracked(page)
    window.show_tab("teach")
    window.show_tab("hardware")  # both already built: nothing new to settle
    window.show_tab("gait")  # new: its settle runs after any the two before had scheduled (timers fire in order)
    qtbot.waitUntil(lambda: collector.settled >= 3, timeout=5_000)
    assert collector.settled == 3
    window.close()
    assert gc.get_freeze_count() == 0
