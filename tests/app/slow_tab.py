"""A tab module whose import waits for the test (``GATE``) and notes which thread imported it: stands in for a tab
module whose import takes seconds (the Calibration tab's brings the fitting stack)."""

from __future__ import annotations

import threading

from tests.app import slow_tab_gate

slow_tab_gate.IMPORTED_ON.append(threading.current_thread())
assert slow_tab_gate.GATE.wait(30), "the test never let the import finish"


def create_tab(_lab: object):
    from PySide6.QtWidgets import QLabel

    return QLabel("the slow tab")
