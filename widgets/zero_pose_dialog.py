"""The "Set zero pose" dialog: each joint's angle now and after, and the offsets that make the present pose read 0.

Passive: it shows the numbers it is given and returns whether the user accepted. GUI thread only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QAbstractItemView,
    QDialog,
    QDialogButtonBox,
    QHeaderView,
    QLabel,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

COLUMNS = ("Joint", "ID", "Axis", "Reads now (°)", "Offset now (rad)", "Offset after (rad)", "Reads after (°)")
LARGE_DEG = 30.0  # a joint this far from straight is probably not laid straight: said above the table


class ZeroPoseDialog(QDialog):
    """Preview of a zero-pose write; ``exec()`` is Accepted when the user presses the write button."""

    def __init__(self, servo_ids: Sequence[int], axes: Sequence[str], present_rad: Sequence[float],
                 old_offsets_rad: Sequence[float], new_offsets_rad: Sequence[float], target: str,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Set zero pose")
        layout = QVBoxLayout(self)
        far = [k + 1 for k, a in enumerate(present_rad) if abs(math.degrees(a)) > LARGE_DEG]
        text = ("Lay the robot straight on the floor (every joint at the angle you want to call 0), then write. "
                f"The offsets go into <b>{target}</b>; the file as it is now is kept beside it (.bak-N).")
        if far:
            text += (f"<br><span style='color:#c0392b'>Joint(s) {', '.join(str(j) for j in far)} read more than "
                     f"{LARGE_DEG:.0f}° now: is the robot really straight?</span>")
        self.intro = QLabel(text)
        self.intro.setWordWrap(True)
        layout.addWidget(self.intro)
        self.table = QTableWidget(len(servo_ids), len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        for k, sid in enumerate(servo_ids):
            after_deg = round(math.degrees(present_rad[k] + new_offsets_rad[k] - old_offsets_rad[k]), 1) + 0.0
            cells = (str(k + 1), str(sid), axes[k] if k < len(axes) else "", f"{math.degrees(present_rad[k]):+.1f}",
                     f"{old_offsets_rad[k]:+.4f}", f"{new_offsets_rad[k]:+.4f}", f"{after_deg:+.1f}")
            for col, cell in enumerate(cells):
                item = QTableWidgetItem(cell)
                item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.table.setItem(k, col, item)
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.verticalHeader().setDefaultSectionSize(22)
        self.table.setMinimumWidth(640)
        self.table.setMinimumHeight(22 * len(servo_ids) + 30)
        layout.addWidget(self.table)
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Cancel)
        self.write_button = buttons.addButton("Write zero offsets", QDialogButtonBox.ButtonRole.AcceptRole)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        layout.addWidget(buttons)

    def cell(self, row: int, column: int) -> str:
        item = self.table.item(row, column)
        return item.text() if item is not None else ""
