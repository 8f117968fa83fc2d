"""The placeholder page shown while a tab is not built yet."""

from __future__ import annotations

from PySide6.QtWidgets import QApplication, QWidget

from widgets.placeholder import PlaceholderPage


def _visible_windows() -> set[int]:
    return {id(w) for w in QApplication.topLevelWidgets() if w.isVisible()}


def test_a_note_makes_no_window_of_its_own_and_the_main_window_keeps_the_keys(qtbot):
    """Its note label was made without a parent and then made visible: for a moment a window of its own, which took
    the focus from the main window (Space and the other shortcuts then reached nothing)."""
    host = QWidget()
    qtbot.addWidget(host)
    host.show()
    qtbot.waitExposed(host)
    host.activateWindow()
    qtbot.waitUntil(host.isActiveWindow)
    before = _visible_windows()
    page = PlaceholderPage("Forces", "Contact forces, live.", "Opening…")
    qtbot.addWidget(page)
    assert _visible_windows() == before
    assert not any(label.isWindow() for label in (page.title_label, page.description_label, page.note_label))
    qtbot.wait(50)  # Deliberate: a stray window would take the focus on a later turn of the event loop; none may
    assert host.isActiveWindow()
    page.show()
    assert page.note_label.isVisible() and page.note_label.text() == "Opening…"
    empty = PlaceholderPage("Gait", "Replays a shape.")
    qtbot.addWidget(empty)
    empty.show()
    assert not empty.note_label.isVisible()
