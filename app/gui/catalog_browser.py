"""File ▸ Open recording…: the run catalog (:mod:`app.core.catalog`) browsed in :class:`widgets.catalog_view.
CatalogView`, the chosen recording opened in the 3-D replay, a series' trials overlaid in the Forces tab.

The catalog is read on a worker thread of this browser (a :class:`app.core.catalog.Catalog` of its own: SQLite
connections stay on their thread), never on the GUI thread: :meth:`CatalogBrowser.refresh` first reads again every
recording in the recordings folder that is new or changed (as ``sensnake runs list`` does) and forgets the files that
are gone, then lists; a change of filter only lists (``--where`` pairs and ``--since``, in SQL). The results reach the
GUI thread through the one :class:`app.gui.thread_bridge.ThreadBridge`; a listing overtaken by a newer one is
dropped. The worker runs at the lowest CPU priority and pauses after each file it reads, so a long indexing gives
way to the control loop (measured in tests/app/test_trials_panel.py). Closing the dialog stops the worker between
two files. GUI thread only (the worker excepted).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, Qt, Signal

from app.core import user_folders
from app.core.catalog import Catalog, unreadable_words
from app.gui.thread_bridge import ThreadBridge
from widgets import theme
from widgets.catalog_view import FILTERS, CatalogView

MAX_ROWS_SHOWN = 2000  # the newest ones; more would slow the table, and the filters narrow a long list
YIELD_S = 0.002  # the worker's pause after each file it reads (1,000 new files: +2 s)
PROGRESS_EVERY_S = 0.5  # how often a long reading says how far it got (the worker yields to everything: beside busy
# programs on every core, 1,000 new recordings took over a minute)
BACKGROUND_NICE = 19


@dataclass(frozen=True)
class Listing:
    """What one read of the catalog gives the view."""

    rows: list[dict[str, Any]]
    total: int
    choices: dict[str, list[str]] | None = None  # the filters' values (on a refresh)
    read: int = 0  # recordings read again
    forgotten: int = 0
    notes: list[str] = field(default_factory=list)


def read_catalog(folder: Path | None, where: Sequence[str], since: str | None, sync: bool,
                 cancelled: threading.Event, progress: Callable[[int, int], None] | None = None) -> Listing:
    """On the worker thread: (with ``sync``) the recordings folder read again where it changed (``progress(done,
    total)`` told along the way, as :meth:`app.core.catalog.Catalog.sync` does), then the matching recordings,
    newest :data:`MAX_ROWS_SHOWN`."""
    notes: list[str] = []
    read = forgotten = 0
    with Catalog() as catalog:
        if catalog.note:
            notes.append(catalog.note)
        choices = None
        if sync:
            if folder is not None and folder.is_dir():
                # a pause between files (the wait releases the GIL): an in-process control loop keeps its ticks
                read, forgotten = catalog.sync(folder, cancelled=lambda: cancelled.wait(YIELD_S), progress=progress)
                if catalog.unreadable:
                    notes.append(unreadable_words(catalog.unreadable))
            forgotten += catalog.prune()
            everything = catalog.query()
            choices = {key: sorted({str(r[key]) for r in everything if r.get(key) not in (None, "")})
                       for key, _title in FILTERS}
        rows = catalog.query(where=list(where), since=since)
    return Listing(rows[-MAX_ROWS_SHOWN:], len(rows), choices, read, forgotten, notes)


def background_priority() -> None:
    """The worker thread at the lowest CPU priority (Linux: ``nice`` 19 for this thread alone): reading a thousand
    recordings gives way to every other process, the control loop's first (elsewhere: as it is)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BACKGROUND_NICE)


class CatalogBrowser(QObject):
    """See the module docstring. ``folder``: the recordings folder read again on a refresh (default: the data
    folder's ``recordings/``)."""

    listed = Signal(int)  # rows shown, after each listing arrives
    open_requested = Signal(str)
    overlay_requested = Signal(object)

    def __init__(self, view: CatalogView, folder: str | Path | None = None, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.view = view
        self.folder = Path(folder) if folder is not None else user_folders.recordings_dir()
        self._bridge = ThreadBridge(self)
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="catalog", initializer=background_priority)
        self._cancelled = threading.Event()
        self._token = 0
        self._reading = f"the recordings in {self.folder}"  # what the status line says the worker is reading
        self.last: Listing | None = None
        view.filters_changed.connect(lambda _filters: self.list())
        view.refresh_requested.connect(self.refresh)
        view.open_requested.connect(self.open_requested)
        view.overlay_requested.connect(self.overlay_requested)
        view.finished.connect(lambda _result: self.close())

    def refresh(self) -> None:
        """Read the recordings folder again where it changed, then list (the filters' choices updated)."""
        self._reading = f"reading new and changed recordings in {self.folder}"
        self.view.set_status(f"{self._reading}…")
        self._submit(sync=True)

    def list(self) -> None:
        """List with the view's filters (no file is read)."""
        self._submit(sync=False)

    def _submit(self, sync: bool) -> None:
        if self._cancelled.is_set():
            return
        self._token += 1
        token = self._token
        filters = self.view.filters()
        future = self._executor.submit(read_catalog, self.folder, filters["where"], filters["since"], sync,
                                       self._cancelled, self._progress_from_worker(token) if sync else None)
        self._bridge.when_done(future, lambda listing: self._show(token, listing), self._failed)

    def _progress_from_worker(self, token: int) -> Callable[[int, int], None]:
        """A progress callback for the worker: at most every :data:`PROGRESS_EVERY_S`, and the last, to the view."""
        told = [-float("inf")]
        show = self._bridge.emitter(self._show_progress)

        def progress(done: int, total: int) -> None:
            now = time.monotonic()
            if now - told[0] >= PROGRESS_EVERY_S or done == total:
                told[0] = now
                show(token, done, total)

        return progress

    def _show_progress(self, token: int, done: int, total: int) -> None:
        if token == self._token:
            self.view.set_status(f"{self._reading}: {done:,} of {total:,}…")

    def _show(self, token: int, listing: Listing) -> None:
        if token != self._token:
            return  # a newer listing is on its way
        self.last = listing
        if listing.choices is not None:
            self.view.set_choices(listing.choices)
        self.view.set_rows(listing.rows, listing.total)
        if listing.read or listing.forgotten or listing.notes:
            said = [f"{listing.read} recording(s) read again, {listing.forgotten} gone forgotten", *listing.notes]
            self.view.set_status(f"{self._reading}… · {'; '.join(said)}")
        self.listed.emit(len(listing.rows))

    def _failed(self, exc: BaseException) -> None:
        self.view.set_status(f"the catalog could not be read: {' '.join(str(exc).split())}", theme.ERROR)

    def close(self) -> None:
        """Stop the worker (between two files) and wait for it; nothing more reaches the view."""
        self._cancelled.set()
        self._bridge.close()
        self._executor.shutdown(wait=True, cancel_futures=True)


def show_catalog_browser(host: Any, browser: CatalogBrowser | None = None) -> CatalogBrowser:
    """File ▸ Open recording…: the catalog's browser over ``host`` (the main window: ``show_tab(name)``), a new one
    or ``browser`` raised when it is still open. A recording chosen opens in the 3-D lab's replay; recordings chosen
    for an overlay go to the Forces tab's trial overlay; either closes the browser."""
    if browser is not None:
        with contextlib.suppress(RuntimeError):  # its dialog was closed: Qt deleted it
            if browser.view.isVisible():
                browser.view.raise_()
                browser.view.activateWindow()
                return browser
    view = CatalogView(host)
    view.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
    browser = CatalogBrowser(view, parent=view)

    def open_in_replay(path: str) -> None:
        page = host.show_tab("scene")
        opened = getattr(page, "open_replay", None)
        if opened is None or not opened(path):
            view.set_status(f"{Path(path).name} could not be replayed in 3-D (the 3-D lab says why)", theme.ERROR)
            return
        view.close()

    def overlay(paths: list[str]) -> None:
        page = host.show_tab("forces")
        add = getattr(page, "add_overlay_files", None)
        added = add(paths) if add is not None else 0
        if not added:
            view.set_status("nothing could be overlaid (the Forces tab says why)", theme.ERROR)
            return
        views = getattr(page, "views", None)
        if views is not None:  # the Forces tab's "Trial overlay" page
            for index in range(views.count()):
                if views.tabText(index) == "Trial overlay":
                    views.setCurrentIndex(index)
        view.close()

    browser.open_requested.connect(open_in_replay)
    browser.overlay_requested.connect(overlay)
    view.show()
    browser.refresh()
    return browser
