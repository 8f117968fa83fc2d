"""The one bridge from core/device threads to the GUI thread.

Core objects (``app.core``) and device drivers (``devices``) run threads of their own and report through plain Python
callbacks called *on those threads*. Qt widgets may only be touched on the GUI thread. :class:`ThreadBridge` is the
single place that crosses that line: a QObject created on (and therefore owned by) the GUI thread, with one private
signal whose connection is always *queued*, so whatever is posted runs later, on the GUI thread, in posting order.

How a GUI-side class uses it (instead of writing its own ``_posted = Signal(object)`` plumbing)::

    class RigSession(QObject):
        progress = Signal(object)

        def __init__(self, parent=None):
            super().__init__(parent)
            self._bridge = ThreadBridge(self)                      # GUI thread
            runner = ProtocolRunner(..., on_progress=self._bridge.emitter(self.progress))   # core thread calls it

        def _worker(self):                                          # worker thread
            outcome = ...
            self._bridge.post(self._on_finished, outcome)           # runs _on_finished(outcome) on the GUI thread

    bridge.when_done(future, on_result, on_error)                   # a Future's outcome, on the GUI thread

- :meth:`ThreadBridge.post` / :meth:`ThreadBridge.emitter` / :meth:`ThreadBridge.when_done`: any thread.
- Delivery is always deferred (queued), even when posting from the GUI thread itself: a callback never runs
  re-entrantly inside the caller.
- After :meth:`ThreadBridge.close` (or once Qt has deleted the bridge with its parent), posts are dropped: a worker
  that finishes after its window closed does not touch dead Qt objects, and it does not raise either.
- :class:`Coalescer` collects values posted at any rate from a core thread and hands them to the GUI thread as one
  list at most every ``interval_ms`` (≤ 60 Hz), for streams the GUI must not be flooded with (robot states).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Generic, TypeVar

from PySide6.QtCore import QObject, Qt, QTimer, Signal, Slot

import widgets  # noqa: F401 - installs the PySide6 6.12 refcount guard before the first cross-thread emit

T = TypeVar("T")

MIN_DELIVERY_INTERVAL_MS = 16  # ≤ 60 Hz to the GUI (STYLE.md)


class ThreadBridge(QObject):
    """Runs callables posted from any thread on the GUI thread (queued, in order). Create it on the GUI thread."""

    _call = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._open = True
        self._call.connect(self._run, Qt.ConnectionType.QueuedConnection)

    @property
    def is_open(self) -> bool:
        return self._open

    def post(self, fn: Callable[..., object], *args: object) -> None:
        """Any thread: call ``fn(*args)`` later on the GUI thread. Dropped once the bridge is closed or deleted."""
        if not self._open:
            return
        try:
            self._call.emit((fn, args))
        except RuntimeError:
            # "Internal C++ object already deleted": the window (our parent) is gone; nobody is listening.
            self._open = False

    def emitter(self, signal: Any) -> Callable[..., None]:
        """A plain callback for a core/device thread that emits ``signal(*values)`` on the GUI thread.

        ``signal`` is a bound Qt signal (``self.progress``) or any callable run on the GUI thread.
        """
        emit = getattr(signal, "emit", signal)

        def forward(*values: object) -> None:
            self.post(emit, *values)

        return forward

    def when_done(self, future: Future, on_result: Callable[[Any], None] | None,
                  on_error: Callable[[BaseException], None] | None = None) -> None:
        """Any thread: on the GUI thread, call ``on_result(result)`` or ``on_error(exception)`` once ``future`` is
        done (at once, queued, if it already is). Cancelled futures call neither. Without ``on_error`` a failure is
        dropped: pass one (the robot bridge reports it through its ``error`` signal)."""

        def finish(done: Future) -> None:
            if done.cancelled():
                return
            exc = done.exception()
            if exc is not None:
                if on_error is not None:
                    on_error(exc)
            elif on_result is not None:
                on_result(done.result())

        future.add_done_callback(lambda done: self.post(finish, done))

    def close(self) -> None:
        """GUI thread: stop delivering; anything posted afterwards (or still queued) is dropped."""
        self._open = False

    @Slot(object)
    def _run(self, call: tuple[Callable[..., object], tuple[object, ...]]) -> None:
        if not self._open:
            return
        fn, args = call
        fn(*args)


class Coalescer(QObject, Generic[T]):
    """Values pushed from any thread, delivered to the GUI thread as one ``list`` per tick (≤ 60 Hz).

    ``Coalescer(deliver, parent, interval_ms=16, backlog_max=4096)``: :meth:`push` from the producing thread keeps
    at most ``backlog_max`` values (the oldest go first if the GUI stalls); while started, a GUI-thread timer calls
    ``deliver(values)`` with everything pushed since the last call, in order, and only when there is something.
    :attr:`latest` is the newest value pushed (any thread).
    """

    def __init__(self, deliver: Callable[[list[T]], None], parent: QObject | None = None,
                 interval_ms: int = MIN_DELIVERY_INTERVAL_MS, backlog_max: int = 4096) -> None:
        super().__init__(parent)
        self._deliver = deliver
        self._lock = threading.Lock()
        self._backlog: deque[T] = deque(maxlen=backlog_max)
        self._latest: T | None = None
        self._timer = QTimer(self)
        self._timer.setInterval(max(int(interval_ms), MIN_DELIVERY_INTERVAL_MS))
        self._timer.timeout.connect(self.flush)

    @property
    def latest(self) -> T | None:
        with self._lock:
            return self._latest

    def push(self, value: T) -> None:
        """Any thread: queue ``value`` for the next delivery."""
        with self._lock:
            self._latest = value
            self._backlog.append(value)

    def start(self) -> None:
        """GUI thread: deliver every ``interval_ms`` from now on."""
        self._timer.start()

    def stop(self) -> None:
        """GUI thread: stop the timer (values pushed meanwhile wait for :meth:`flush` or the next :meth:`start`)."""
        self._timer.stop()

    def flush(self) -> None:
        """GUI thread: deliver what is queued now (nothing is delivered when nothing was pushed)."""
        with self._lock:
            if not self._backlog:
                return
            values = list(self._backlog)
            self._backlog.clear()
        self._deliver(values)
