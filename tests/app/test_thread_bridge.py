"""The one thread → GUI bridge: callables and signals posted from worker threads run on the GUI thread, in order,
never re-entrantly; futures' outcomes arrive there; nothing is delivered after close or deletion; coalesced streams
arrive as ordered lists."""

from __future__ import annotations

import threading
from concurrent.futures import Future

from PySide6.QtCore import QObject, Signal

from app.gui.thread_bridge import Coalescer, ThreadBridge


class _Source(QObject):
    value = Signal(object, object)


def _in_thread(fn) -> None:
    worker = threading.Thread(target=fn, name="bridge-test-worker")
    worker.start()
    worker.join()


def test_posts_from_a_worker_run_on_the_gui_thread_in_order(qtbot):
    bridge = ThreadBridge()
    seen: list[tuple[int, threading.Thread]] = []
    _in_thread(lambda: [bridge.post(lambda i=i: seen.append((i, threading.current_thread()))) for i in range(50)])
    qtbot.waitUntil(lambda: len(seen) == 50)
    assert [i for i, _ in seen] == list(range(50))
    assert all(thread is threading.main_thread() for _, thread in seen)


def test_a_post_from_the_gui_thread_is_deferred_not_reentrant(qtbot):
    bridge = ThreadBridge()
    calls: list[str] = []
    bridge.post(calls.append, "posted")
    calls.append("caller continued")
    qtbot.waitUntil(lambda: len(calls) == 2)
    assert calls == ["caller continued", "posted"]


def test_emitter_emits_the_signal_with_its_values_on_the_gui_thread(qtbot):
    bridge, source = ThreadBridge(), _Source()
    received: list[tuple[object, object, threading.Thread]] = []
    source.value.connect(lambda a, b: received.append((a, b, threading.current_thread())))
    forward = bridge.emitter(source.value)
    _in_thread(lambda: forward("progress", 3))
    qtbot.waitUntil(lambda: len(received) == 1)
    assert received == [("progress", 3, threading.main_thread())]


def test_when_done_delivers_result_error_or_nothing_for_a_cancelled_future(qtbot):
    bridge = ThreadBridge()
    results: list[object] = []
    errors: list[BaseException] = []
    ok, failed, cancelled = Future(), Future(), Future()
    for future in (ok, failed, cancelled):
        bridge.when_done(future, results.append, errors.append)
    boom = ValueError("servo 5 refused")
    _in_thread(lambda: (ok.set_result(42), failed.set_exception(boom)))
    cancelled.cancel()
    qtbot.waitUntil(lambda: bool(results and errors))
    marker: list[bool] = []
    bridge.post(marker.append, True)  # queued after anything the cancelled future could have posted
    qtbot.waitUntil(lambda: marker == [True])
    assert results == [42] and errors == [boom]


def test_nothing_is_delivered_after_close_or_after_the_owner_is_deleted(qtbot):
    owner = QObject()
    bridge = ThreadBridge(owner)
    calls: list[int] = []
    bridge.post(calls.append, 1)
    bridge.close()  # the queued call is dropped too
    bridge.post(calls.append, 2)
    live = ThreadBridge(owner)
    live.post(calls.append, 3)
    qtbot.waitUntil(lambda: calls == [3])
    owner.deleteLater()
    qtbot.waitUntil(lambda: not _alive(live))
    _in_thread(lambda: live.post(calls.append, 4))  # a worker finishing after the window closed: no exception
    assert calls == [3] and not live.is_open


def _alive(obj: QObject) -> bool:
    try:
        obj.objectName()
    except RuntimeError:
        return False
    return True


def test_coalescer_hands_over_everything_pushed_in_order_as_lists(qtbot):
    delivered: list[list[int]] = []
    coalescer = Coalescer(delivered.append, interval_ms=16, backlog_max=10_000)
    coalescer.start()
    _in_thread(lambda: [coalescer.push(i) for i in range(5000)])
    assert coalescer.latest == 4999
    qtbot.waitUntil(lambda: sum(map(len, delivered)) == 5000)
    coalescer.stop()
    assert [v for chunk in delivered for v in chunk] == list(range(5000))
    assert all(delivered), "an empty delivery"
    assert len(delivered) < 5000, "delivered per value, not coalesced"


def test_coalescer_keeps_the_newest_values_when_the_gui_stalls(qtbot):
    delivered: list[list[int]] = []
    coalescer = Coalescer(delivered.append, backlog_max=100)
    for i in range(1000):  # timer not started: the GUI is "stalled"
        coalescer.push(i)
    coalescer.flush()
    coalescer.flush()  # nothing new: no empty delivery
    assert delivered == [list(range(900, 1000))]
