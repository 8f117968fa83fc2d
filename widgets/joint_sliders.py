"""JointSliders: one row per joint — select box, name/axis, slider, angle in degrees and radians.

A passive view: :meth:`set_angles` shows live angles (never emits), a user moving a slider or spin box emits
``angle_changed(index, angle_rad)``; the select boxes emit ``selection_changed()``. Rows whose ``editable`` flag is
off show the angle but cannot be moved (e.g. joints holding torque while posing). GUI thread only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QDoubleSpinBox,
    QGridLayout,
    QLabel,
    QSlider,
    QWidget,
)

from widgets import theme

SLIDER_STEPS_PER_RAD = 1000  # the slider works in milliradians


class JointSliders(QWidget):
    angle_changed = Signal(int, float)  # joint index (0-based), angle in rad
    selection_changed = Signal()

    def __init__(self, joint_ids: Sequence[int], axes: Sequence[str], min_rad: Sequence[float],
                 max_rad: Sequence[float], selectable: bool = True, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._ids = tuple(joint_ids)
        self._updating = False
        grid = QGridLayout(self)
        grid.setContentsMargins(0, 0, 0, 0)
        grid.setHorizontalSpacing(6)
        grid.setVerticalSpacing(1)
        self.checks: list[QCheckBox] = []
        self.sliders: list[QSlider] = []
        self.spins: list[QDoubleSpinBox] = []
        self._rad_labels: list[QLabel] = []
        header = ["", "joint", "", "deg", "rad"]
        for col, text in enumerate(header):
            label = QLabel(f"<small>{text}</small>")
            grid.addWidget(label, 0, col)
        for row, (sid, axis, lo, hi) in enumerate(zip(joint_ids, axes, min_rad, max_rad), start=1):
            check = QCheckBox()
            check.setToolTip(f"select joint {sid} (torque off only the selected joints)")
            check.setVisible(selectable)
            check.toggled.connect(lambda _on: self.selection_changed.emit())
            name = QLabel(f"J{sid} <span style='color:{theme.AXIS_COLORS[axis]}'>{axis}</span>")
            slider = QSlider(Qt.Orientation.Horizontal)
            slider.setRange(int(math.floor(lo * SLIDER_STEPS_PER_RAD)), int(math.ceil(hi * SLIDER_STEPS_PER_RAD)))
            slider.setMinimumWidth(120)
            spin = QDoubleSpinBox()
            spin.setDecimals(1)
            spin.setRange(math.degrees(lo), math.degrees(hi))
            spin.setSuffix("°")
            spin.setSingleStep(0.1)  # arrow keys / wheel pose a joint to a tenth of a degree
            spin.setToolTip("angle in degrees: type it, or step 0.1° with the arrow keys or the wheel "
                            "(PgUp/PgDn: 1°)")
            spin.setKeyboardTracking(False)
            spin.setFixedWidth(78)
            rad = QLabel("+0.000")
            rad.setMinimumWidth(52)
            rad.setStyleSheet(f"font-family: {theme.MONOSPACE_FAMILY};")
            index = row - 1
            slider.valueChanged.connect(lambda value, i=index: self._from_slider(i, value))
            spin.valueChanged.connect(lambda value, i=index: self._from_spin(i, value))
            for col, widget in enumerate((check, name, slider, spin, rad)):
                grid.addWidget(widget, row, col)
            self.checks.append(check)
            self.sliders.append(slider)
            self.spins.append(spin)
            self._rad_labels.append(rad)
        grid.setColumnStretch(2, 1)
        self._angles = np.zeros(len(self._ids))

    # -- API -------------------------------------------------------------------------------------------------------
    def set_angles(self, angles_rad: Sequence[float] | np.ndarray) -> None:
        """Show angles (rad) without emitting; a row the user is dragging keeps the user's value."""
        angles = np.asarray(angles_rad, dtype=float)
        self._updating = True
        try:
            for i, angle in enumerate(angles):
                if self.sliders[i].isSliderDown() or self.spins[i].hasFocus():
                    continue
                self._show(i, float(angle))
        finally:
            self._updating = False

    def angles_rad(self) -> np.ndarray:
        return self._angles.copy()

    def selected_ids(self) -> list[int]:
        return [sid for sid, check in zip(self._ids, self.checks) if check.isChecked()]

    def set_selected_ids(self, ids: Sequence[int]) -> None:
        wanted = set(ids)
        for sid, check in zip(self._ids, self.checks):
            check.setChecked(sid in wanted)

    def set_editable(self, editable: Sequence[bool] | bool) -> None:
        """Which rows a user may move (all, none, or per joint)."""
        flags = [bool(editable)] * len(self._ids) if isinstance(editable, bool) else [bool(e) for e in editable]
        for slider, spin, flag in zip(self.sliders, self.spins, flags):
            slider.setEnabled(flag)
            spin.setEnabled(flag)

    # -- internals -------------------------------------------------------------------------------------------------
    def _show(self, i: int, angle: float) -> None:
        self._angles[i] = angle
        slider_value = int(round(angle * SLIDER_STEPS_PER_RAD))
        degrees = round(math.degrees(angle), self.spins[i].decimals())
        # Touch a widget only when what it shows changes: QDoubleSpinBox.setValue repaints its line edit (and, on
        # X, the parents under it) even for the same value, and set_angles runs 20×/s while the robot rests.
        if self.sliders[i].value() != slider_value:
            self.sliders[i].blockSignals(True)
            self.sliders[i].setValue(slider_value)
            self.sliders[i].blockSignals(False)
        if self.spins[i].value() != degrees:
            self.spins[i].blockSignals(True)
            self.spins[i].setValue(degrees)
            self.spins[i].blockSignals(False)
        self._rad_labels[i].setText(f"{angle:+.3f}")

    def _from_slider(self, i: int, value: int) -> None:
        if self._updating:
            return
        angle = value / SLIDER_STEPS_PER_RAD
        self._show(i, angle)
        self.angle_changed.emit(i, angle)

    def _from_spin(self, i: int, value_deg: float) -> None:
        if self._updating:
            return
        angle = math.radians(value_deg)
        self._show(i, angle)
        self.angle_changed.emit(i, angle)
