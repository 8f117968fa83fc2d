"""Shared with :mod:`tests.app.slow_tab`: the event its import waits for, and the threads that imported it."""

from __future__ import annotations

import threading

GATE = threading.Event()
IMPORTED_ON: list[threading.Thread] = []
