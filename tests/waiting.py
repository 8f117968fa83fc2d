"""Waiting in tests for a condition that no callback or signal announces (a counter inside a simulator, a motion's
progress read from another thread): poll it briefly, and give up after a timeout so that a test that can never pass
fails with a message instead of hanging until pytest's global timeout. Any thread."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

WAIT_S = 10.0  # generous: the machine running the suite is shared
POLL_S = 0.002


def wait_until(predicate: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    """True as soon as ``predicate()`` is true; False once ``timeout_s`` seconds passed without it. Use as
    ``assert wait_until(lambda: …), "what did not happen"``."""
    deadline = time.monotonic() + timeout_s
    pause = threading.Event()  # never set: wait() is the poll interval without a bare sleep
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        pause.wait(POLL_S)
    return True
