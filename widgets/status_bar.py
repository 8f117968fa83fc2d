"""The main window's status bar: robot, board and recording state, a message area, the event log's button and STOP.

Passive view: the app sets texts and levels and listens to :attr:`LabStatusBar.stop_requested` and
:attr:`LabStatusBar.log_requested` (the message area or the **Log** button clicked: the app shows that message whole
in the event log). The STOP button is always visible (a permanent widget, never hidden behind a message). GUI thread
only.
"""

from __future__ import annotations

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QMouseEvent, QResizeEvent
from PySide6.QtWidgets import QLabel, QPushButton, QSizePolicy, QStatusBar, QToolButton, QWidget

from widgets import theme

MESSAGE_KEEP_MS = {theme.OK: 6000, theme.IDLE: 6000, theme.WARN: 15000, theme.ERROR: 0}  # 0: until replaced


class StateLabel(QLabel):
    """A small rounded label coloured by status level."""

    def __init__(self, text: str, parent: QWidget | None = None) -> None:
        super().__init__(text, parent)
        self.level = theme.IDLE
        self.set_state(text, theme.IDLE)

    def set_state(self, text: str, level: str, tooltip: str = "") -> None:
        self.level = level
        self.setText(text)
        self.setStyleSheet(theme.status_style(level))
        self.setToolTip(tooltip or text)


class ElidedLabel(QLabel):
    """A one-line label that ends in "…" when its text does not fit; the full text is in the tooltip. A click on it
    emits :attr:`clicked`."""

    clicked = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.full_text = ""
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)

    def mousePressEvent(self, event: QMouseEvent) -> None:  # noqa: N802 - Qt override
        if event.button() == Qt.MouseButton.LeftButton:
            self.clicked.emit()
        super().mousePressEvent(event)

    def set_full_text(self, text: str) -> None:
        self.full_text = text
        self.setToolTip(text)
        self._elide()

    def resizeEvent(self, event: QResizeEvent) -> None:  # noqa: N802 - Qt override
        super().resizeEvent(event)
        self._elide()

    def _elide(self) -> None:
        one_line = " ".join(self.full_text.split())
        self.setText(self.fontMetrics().elidedText(one_line, Qt.TextElideMode.ElideRight, max(self.width(), 0)))


class LabStatusBar(QStatusBar):
    """Status of the lab's devices, the latest message and STOP."""

    stop_requested = Signal()
    log_requested = Signal()  # the message or the Log button was clicked: show the event log (at that message)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setSizeGripEnabled(True)

        self.message_label = ElidedLabel()
        self.message_label.setObjectName("status_message")
        self.message_level = theme.IDLE
        self._message_timer = QTimer(self)
        self._message_timer.setSingleShot(True)
        self._message_timer.timeout.connect(self.clear_message)
        self.message_label.setCursor(Qt.CursorShape.PointingHandCursor)
        self.message_label.clicked.connect(self.log_requested)
        self.addWidget(self.message_label, 1)
        self.log_button = QToolButton()
        self.log_button.setObjectName("status_log")
        self.log_button.setText("Log")
        self.log_button.setToolTip("The event log: every message, warning, fault and operator action with its time "
                                   "(a click on the message shows it there, whole)")
        self.log_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.log_button.clicked.connect(self.log_requested)
        self.addWidget(self.log_button)

        self.robot_label = StateLabel("Robot: not connected")
        self.robot_label.setObjectName("status_robot")
        self.board_label = StateLabel("Board: not connected")
        self.board_label.setObjectName("status_board")
        self.recording_label = StateLabel("Not recording")
        self.recording_label.setObjectName("status_recording")
        for label in (self.robot_label, self.board_label, self.recording_label):
            self.addPermanentWidget(label)

        self.stop_button = QPushButton("STOP  (Esc)")
        self.stop_button.setObjectName("stop_button")
        self.stop_button.setToolTip("Emergency stop: halts motion within one control tick; torque stays on and "
                                    "every joint holds where it is. Esc does the same from anywhere in the app.")
        self.stop_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)  # never steals keyboard focus from the tab
        self.stop_button.setMinimumHeight(30)
        self.stop_button.setMinimumWidth(120)
        self.stop_button.setStyleSheet(
            f"QPushButton {{ background: {theme.STOP_RED}; color: white; font-weight: bold;"
            " border: 1px solid #7F0000; border-radius: 4px; padding: 3px 14px; }"
            f" QPushButton:pressed {{ background: {theme.STOP_RED_PRESSED}; }}"
        )
        self.stop_button.clicked.connect(self.stop_requested)
        self.addPermanentWidget(self.stop_button)

    def set_robot_state(self, text: str, level: str, tooltip: str = "") -> None:
        self.robot_label.set_state(text, level, tooltip)

    def set_board_state(self, text: str, level: str, tooltip: str = "") -> None:
        self.board_label.set_state(text, level, tooltip)

    def set_recording_state(self, text: str, active: bool) -> None:
        self.recording_label.set_state(text, theme.ERROR if active else theme.IDLE)

    def set_log_count(self, faults: int, warnings: int) -> None:
        """The Log button's badge: faults (red) and warnings not yet looked at."""
        parts = [f"{faults} fault{'s' * (faults != 1)}" if faults else "",
                 f"{warnings} warning{'s' * (warnings != 1)}" if warnings else ""]
        badge = ", ".join(p for p in parts if p)
        self.log_button.setText(f"Log · {badge}" if badge else "Log")
        level = theme.ERROR if faults else theme.WARN if warnings else None
        self.log_button.setStyleSheet(f"QToolButton {{ color: {theme.STATUS_COLORS[level]}; font-weight: bold; }}"
                                      if level else "")

    def show_message(self, text: str, level: str = theme.IDLE) -> None:
        """Show ``text`` in the message area; errors stay until replaced, others fade after a few seconds."""
        self.message_level = level
        self.message_label.set_full_text(text)
        self.message_label.setStyleSheet(f"color: {theme.STATUS_COLORS[level]};")
        keep_ms = MESSAGE_KEEP_MS[level]
        if keep_ms:
            self._message_timer.start(keep_ms)
        else:
            self._message_timer.stop()

    def shutdown(self) -> None:
        """The window is closing: stop the message's fade timer (the text stays)."""
        self._message_timer.stop()

    def clear_message(self) -> None:
        self._message_timer.stop()
        self.message_level = theme.IDLE
        self.message_label.set_full_text("")

    @property
    def message(self) -> str:
        """The whole current message (the label may show it shortened)."""
        return self.message_label.full_text
