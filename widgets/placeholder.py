"""A page standing in for a tab that is not built yet: it says what the tab will do.

Passive view; create and use on the GUI thread only.
"""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QHBoxLayout, QLabel, QSizePolicy, QVBoxLayout, QWidget

TEXT_WIDTH_PX = 640  # a comfortable reading width, centred in the page


class PlaceholderPage(QWidget):
    """Title, a description of the tab's purpose and an optional note (e.g. why it could not be loaded)."""

    def __init__(self, title: str, description: str, note: str = "", parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName(f"placeholder_{title.lower()}")
        outer = QHBoxLayout(self)
        outer.setContentsMargins(48, 48, 48, 48)
        # Word-wrapped labels take the width they are given: a fixed-width column keeps them from collapsing.
        column = QWidget()
        column.setFixedWidth(TEXT_WIDTH_PX)
        column.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Preferred)
        outer.addStretch(1)
        outer.addWidget(column)
        outer.addStretch(1)
        layout = QVBoxLayout(column)
        layout.setSpacing(12)
        layout.addStretch(1)

        # Each label is made inside the column: a label without a parent that is made visible is a window of its own
        # (shown for a moment, it takes the focus from the main window, and keys go nowhere).
        self.title_label = QLabel(title, column)
        font = self.title_label.font()
        font.setPointSizeF(font.pointSizeF() * 1.6)
        font.setBold(True)
        self.title_label.setFont(font)
        self.title_label.setAlignment(Qt.AlignmentFlag.AlignHCenter)
        self.title_label.setWordWrap(True)

        self.description_label = QLabel(description, column)
        self.description_label.setWordWrap(True)
        self.description_label.setAlignment(Qt.AlignmentFlag.AlignHCenter)

        self.note_label = QLabel(note, column)
        self.note_label.setWordWrap(True)
        self.note_label.setAlignment(Qt.AlignmentFlag.AlignHCenter)
        self.note_label.setStyleSheet("color: #6B6B6B;")
        self.note_label.setVisible(bool(note))
        self.note_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)

        for label in (self.title_label, self.description_label, self.note_label):
            layout.addWidget(label)
        layout.addStretch(2)

    @property
    def description(self) -> str:
        return self.description_label.text()
