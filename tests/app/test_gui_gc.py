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
