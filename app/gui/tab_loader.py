"""The tabs' modules imported on a worker thread after the window is up, so opening a tab does not wait for them.

Importing a tab's module is most of what its first opening used to cost: the Calibration tab's brings the fitting
stack (scipy.optimize and more: 1.5-2.5 s), the Forces tab's h5py (0.3 s). :class:`ModuleLoader` imports them one
after the other on its own thread; the GUI thread asks :meth:`ModuleLoader.is_ready` before it builds a tab (the
window shows "Opening…" meanwhile and builds the tab when ``on_ready(name)`` arrives), or :meth:`ModuleLoader.wait`
when a caller needs the page at once. A module whose import fails is "ready" too: the GUI thread's own import then
raises the error where the tab's placeholder says it.

No module of a tab makes Qt objects when imported (they do in their constructors), so none is owned by this thread.
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Callable, Sequence

log = logging.getLogger(__name__)


class ModuleLoader:
    """Imports ``names`` in order on a daemon thread; ``on_ready(name)`` is called from that thread after each (post
    it to the GUI thread). :meth:`start` and :meth:`close`: GUI thread; the rest: any thread."""

    def __init__(self, names: Sequence[str], on_ready: Callable[[str], None]) -> None:
        self._names = list(names)
        self._on_ready = on_ready
        self._ready = {name: threading.Event() for name in self._names}
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="tab-modules", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        for name in self._names:
            if self._closing.is_set():
                break
            try:
                importlib.import_module(name)
            # The GUI thread imports it again when it builds the tab, and shows what failed there.
            except ImportError as exc:
                log.warning("tab module %s not imported ahead: %s", name, exc)
            finally:
                self._ready[name].set()
            self._on_ready(name)
        for event in self._ready.values():
            event.set()

    def is_ready(self, name: str) -> bool:
        """True when ``name`` is imported (or failed to), or is not one this loader imports."""
        event = self._ready.get(name)
        return event is None or event.is_set()

    def wait(self, name: str) -> None:
        """Block until :meth:`is_ready` (an import under way cannot be interrupted; a loader never started is not
        waited for)."""
        event = self._ready.get(name)
        if event is not None and self._thread is not None:
            event.wait()

    def close(self) -> None:
        """Import nothing more; wait for the import under way (a thread must not outlive the window)."""
        self._closing.set()
        thread = self._thread
        if thread is not None:
            thread.join()
