"""Python's cyclic garbage collection on the GUI thread only.

Automatic collection runs in whichever thread happens to allocate when a generation's threshold is crossed: the
board reader, the rig runner, the bus thread. If that collection frees a Qt object (a widget, a plot's menu, an
action left in a reference cycle by a closed tab or window), its C++ destructor runs on that worker thread, takes
Qt's object mutex and then waits for the interpreter lock, while the GUI thread, holding the interpreter lock,
deletes a neighbouring object and waits for that mutex: both wait forever. Seen in this project's test suite as a
Calibration-tab test frozen for minutes (py-spy: the board reader in ``QObject::~QObject`` →
``Shiboken::GilState::acquire``, the main thread in ``QMenu::~QMenu`` → ``QBasicMutex::lockInternal``); the same
can freeze the app. pyqtgraph documents the remedy (``pyqtgraph.util.garbage_collector``): turn automatic
collection off and collect from a timer on the GUI thread, generation by generation as the interpreter would.

A collection holds the interpreter lock for as long as it walks its generations, and every thread waits: with the
robot loop in the app's process (the simulated lab) a 36 ms walk is 3-4 missed ticks at 100 Hz. The app's ~45 000
long-lived objects (the window, the tabs, the plots) made the first generation-1 collection after start-up and every
full collection cost 32-36 ms (measured). :meth:`GuiThreadCollector.settle` moves what exists at a quiet moment (the
window built, a tab's first build) to the interpreter's permanent generation (``gc.freeze``): later collections walk
only what was made since (< 0.1 ms measured). The cost: a cycle among those objects that becomes garbage while the
window is open is freed when it closes (:meth:`GuiThreadCollector.stop` unfreezes and collects).

GUI thread only.
"""

from __future__ import annotations

import gc

from PySide6.QtCore import QObject, QTimer

INTERVAL_MS = 100  # often enough that generation 0 stays small (each pass costs well under a millisecond)


class GuiThreadCollector(QObject):
    """While started, automatic collection is off and :meth:`collect_due` runs every :data:`INTERVAL_MS` on the
    thread that owns this object; :meth:`stop` collects once more and restores automatic collection as it was."""

    def __init__(self, parent: QObject | None = None, interval_ms: int = INTERVAL_MS) -> None:
        super().__init__(parent)
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self.collect_due)
        self._was_enabled = gc.isenabled()
        self.collections = 0
        self.settled = 0  # settle() passes

    @property
    def active(self) -> bool:
        return self._timer.isActive()

    def start(self) -> None:
        if self._timer.isActive():
            return
        self._was_enabled = gc.isenabled()
        gc.disable()
        self._timer.start()

    def settle(self) -> None:
        """Collect what is garbage now, then take everything left out of later collections (``gc.freeze``): call
        once what exists will live as long as the window (after it is built, after a tab's first build)."""
        if not self._timer.isActive():
            return
        gc.collect()
        gc.freeze()
        self.settled += 1

    def stop(self) -> None:
        if not self._timer.isActive():
            return
        self._timer.stop()
        gc.unfreeze()  # what settle() set aside is collectable again
        gc.collect()  # here, on the GUI thread: nothing Qt is left for another thread to free
        if self._was_enabled:
            gc.enable()

    def collect_due(self) -> None:
        """Collect the generations whose thresholds are crossed, as the interpreter's automatic collection would."""
        count0, count1, count2 = gc.get_count()
        limit0, limit1, limit2 = gc.get_threshold()
        if count0 <= limit0:
            return
        generation = 0
        if count1 > limit1:
            generation = 2 if count2 > limit2 else 1
        gc.collect(generation)
        self.collections += 1
