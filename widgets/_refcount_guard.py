"""Guard against a PySide6 refcount bug that aborts the app: ``Fatal Python error: none_dealloc``.

PySide6 6.12.0 under CPython 3.11 drops references to ``None`` and ``True`` it never took: every
``QObject.property()`` of an unset property, every pyqtgraph ``PlotDataItem.setData`` (≈ 10 per call), every
``ViewBox.setXRange``, ``QLabel.setText``, many signal emissions. A live plot at 30 Hz drains ``None``'s refcount in
minutes and CPython aborts the process. CPython 3.12+ makes these singletons immortal (PEP 683), so the bug is harmless
there; on 3.11 we do by hand what 3.12 does: give the singletons a refcount no leak can exhaust (2⁴⁰ ≈ 10¹²,
months at 10⁵ lost references per second). They are never freed anyway, so this changes nothing else.

Imported once by ``widgets/__init__.py`` so every GUI entry point (app, tests, benchmarks, tools) is covered.
Remove when the project requires Python ≥ 3.12 or a PySide6 without the bug.
"""

from __future__ import annotations

import ctypes
import platform
import sys

_PIN_REFS = 1 << 40


def pin_singletons() -> bool:
    """Raise the refcount of None/True/False/Ellipsis/NotImplemented on CPython < 3.12; True if it did."""
    if sys.version_info >= (3, 12) or platform.python_implementation() != "CPython":
        return False
    for singleton in (None, True, False, Ellipsis, NotImplemented):
        # ob_refcnt is the first field of every CPython object (Py_ssize_t), at the object's address.
        ctypes.c_ssize_t.from_address(id(singleton)).value += _PIN_REFS
    return True


PINNED = pin_singletons()
