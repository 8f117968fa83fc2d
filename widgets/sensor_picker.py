"""A schematic of the robot's body for picking a sensor: segments head (left) to tail, each with its left, bottom and
right sensor as a button (SPEC §2 names, ``S06B``); a click picks that sensor. Passive view: names in, ``picked(str)``
out; the sensor being calibrated is highlighted. Names that do not follow the ``S<segment><L|R|B>`` pattern (a bench
channel) are listed after the body."""

from __future__ import annotations

import re
from collections.abc import Sequence

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QGridLayout, QLabel, QToolButton, QWidget

from widgets import theme

_NAME = re.compile(r"^S(\d+)([LRB])$")
ROWS = {"L": 0, "B": 1, "R": 2}  # left on top, bottom in the middle, right below (looking down on the body)


class SensorPicker(QWidget):
    """The body as a grid of sensor buttons; see the module docstring."""

    picked = Signal(str)

    def __init__(self, names: Sequence[str], parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.buttons: dict[str, QToolButton] = {}
        self.setStyleSheet("QToolButton:checked { background: #1f77b4; border: 1px solid #0b3c66; }")
        grid = QGridLayout(self)
        grid.setContentsMargins(0, 0, 0, 0)
        grid.setHorizontalSpacing(1)
        grid.setVerticalSpacing(1)
        for side, row in ROWS.items():
            label = QLabel(side)
            label.setToolTip({"L": "left sensors", "B": "bottom sensors", "R": "right sensors"}[side])
            grid.addWidget(label, row, 0)
        extra_col = None
        for name in names:
            match = _NAME.match(name)
            button = QToolButton()
            button.setCheckable(True)
            button.setAutoRaise(False)
            button.setToolTip(f"calibrate {name}")
            if match:
                button.setFixedSize(18, 14)
            else:
                button.setText(name)
            button.clicked.connect(lambda _checked=False, n=name: self._pick(n))
            if match:
                grid.addWidget(button, ROWS[match.group(2)], int(match.group(1)))
            else:
                extra_col = (extra_col or grid.columnCount()) + 1
                grid.addWidget(button, 0, extra_col, 3, 1)
            self.buttons[name] = button
        head = QLabel("head → tail")
        head.setStyleSheet(f"color: {theme.STATUS_COLORS[theme.IDLE]};")
        grid.addWidget(head, 3, 1, 1, 6)
        self.selected = ""

    def select(self, name: str) -> None:
        """Highlight ``name`` (no signal); an unknown name clears the highlight."""
        self.selected = name if name in self.buttons else ""
        for key, button in self.buttons.items():
            button.setChecked(key == self.selected)

    def _pick(self, name: str) -> None:
        self.select(name)
        self.picked.emit(name)
