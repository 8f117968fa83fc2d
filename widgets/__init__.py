from widgets import _refcount_guard  # noqa: F401 - must run before any PySide6/pyqtgraph use (see that module)
