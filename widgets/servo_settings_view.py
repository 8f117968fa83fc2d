"""The Hardware tab's "Servo settings" page: one servo's whole control table with live values, decoded as Dynamixel
Wizard 2.0 shows them, edited in place, and the changes the app made (a write, a restore, the lab's ``[servos]``
profile on connect).

Each row shows the raw value and what it means: an enumeration by name (Baud Rate 3 → "1 Mbps"), a bit field by the
names of its bits set (Shutdown 52 → "Overheating Error, Electrical Shock Error, Overload Error"), a quantity in its
unit (Goal Position 2048 → "180.00 °"). The selected item's panel edits it in either form: the raw number, or its
name (a list), its bits (named check boxes) or its value in its unit, converted to the raw value before it is sent.

Passive, like :mod:`widgets.hardware_panel`: it shows the rows and values it is given (plain tuples and dicts, each
row carrying its decoding as data; widgets do not import devices) and emits what the user asks; range checks against
the row's limits, and the enumeration's and bit field's own values, happen here so a value that is none of the item's
never leaves the page. GUI thread only.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QBrush
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

COLUMNS = ("Addr", "Item", "Size", "Access", "Memory", "Unit", "Range", "Value", "Meaning")
COL_ADDR, COL_NAME, COL_SIZE, COL_ACCESS, COL_MEMORY, COL_UNIT, COL_RANGE, COL_VALUE, COL_MEANING = range(len(COLUMNS))
CHANGE_COLUMNS = ("Servo", "Item", "Before", "After", "")
LIVE_INTERVAL_MS = 500  # 2 Hz: a person reads it; one table read per poll


@dataclass(frozen=True)
class TableRow:
    """One control-table item as the page shows it. Its decoding: ``names`` ((value, name), …) for an enumeration,
    ``bits`` ((bit, name), …) for a bit field, else ``scale`` units of ``quantity_unit`` per raw unit (0: a plain
    number); ``notes``: a remark shown with the item."""

    address: int
    name: str
    size: int
    writable: bool
    eeprom: bool
    unit: str
    minimum: int
    maximum: int
    names: tuple[tuple[int, str], ...] = ()
    bits: tuple[tuple[int, str], ...] = ()
    scale: float = 0.0
    quantity_unit: str = ""
    notes: str = ""

    @property
    def decimals(self) -> int:
        """Decimals that tell one raw step from the next (0.088 → 2, 0.1 → 1, 2.69 → 0)."""
        if not self.scale or self.scale >= 1:
            return 0
        return min(3, int(math.ceil(-math.log10(self.scale) - 1e-9)))

    def meaning(self, raw: int) -> str:
        """``raw`` in words: its name, the names of its bits set, or its value in its unit."""
        if self.names:
            return dict(self.names).get(raw, f"{raw}: not a value of {self.name}")
        if self.bits:
            named = [label for bit, label in self.bits if raw & (1 << bit)]
            unknown = raw & ~sum(1 << bit for bit, _label in self.bits)
            if unknown:
                named.append(f"unknown bits 0x{unknown:02X}")
            return ", ".join(named) if named else "none"
        if self.scale:
            return f"{raw * self.scale:.{self.decimals}f} {self.quantity_unit}"
        return ""

    def refusal(self, value: int) -> str | None:
        """Why ``value`` may not be written into this item (out of range, or none of its values), or None."""
        if not self.minimum <= value <= self.maximum:
            return (f"{self.name} = {value} is out of its range {self.minimum} … {self.maximum}"
                    + (f" ({self.unit} units)" if self.unit else "") + ": not written")
        if self.names and value not in dict(self.names):
            return (f"{self.name} = {value} is not one of its values ("
                    + ", ".join(f"{v} {t}" for v, t in self.names) + "): not written")
        if self.bits and value & ~sum(1 << bit for bit, _label in self.bits):
            return (f"{self.name} = {value} sets a bit it does not have ("
                    + ", ".join(f"bit {b} {t}" for b, t in self.bits) + "): not written")
        return None

    def raw_from_text(self, text: str) -> int:
        """The raw value a user typed in the Meaning column: a name (any case), a number in the item's unit (the
        unit may follow), or a raw whole number; ValueError saying what is accepted."""
        cleaned = " ".join(text.split())
        if self.names:
            for value, label in self.names:
                if label.lower() == cleaned.lower():
                    return value
            try:
                return int(cleaned, 0)
            except ValueError:
                raise ValueError(f"{self.name}: {text!r} is none of its values ("
                                 + ", ".join(t for _v, t in self.names) + ")") from None
        if self.scale:
            number = cleaned.removesuffix(self.quantity_unit).strip()
            try:
                return int(round(float(number) / self.scale))
            except ValueError:
                raise ValueError(f"{self.name}: {text!r} is not a number of {self.quantity_unit}") from None
        raise ValueError(f"{self.name} has no named values or unit: type its raw value in the Value column")


class ServoSettingsView(QWidget):
    """See the module docstring."""

    read_requested = Signal(int)  # servo ID
    live_toggled = Signal(bool)
    write_requested = Signal(int, str, int)  # servo ID, item name, value (already range-checked)
    save_requested = Signal()
    restore_requested = Signal(int)  # servo ID, or 0 for every servo
    zero_requested = Signal()
    direction_requested = Signal(int)  # servo ID: move its joint a little and ask which way it went
    reset_requested = Signal(int)  # servo ID: factory settings, ID and baud kept

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.rows: tuple[TableRow, ...] = ()
        self._row_of: dict[str, int] = {}
        self.values: dict[str, int] = {}
        self._filling = False  # the page is writing cells: their change is not the user's edit

        layout = QVBoxLayout(self)
        layout.setContentsMargins(8, 8, 8, 8)
        bar = QHBoxLayout()
        bar.addWidget(QLabel("Servo"))
        self.servo_combo = QComboBox()
        self.servo_combo.setMinimumWidth(90)
        self.servo_combo.currentIndexChanged.connect(lambda _i: self._ask_read())
        bar.addWidget(self.servo_combo)
        self.read_button = QPushButton("Read")
        self.read_button.setToolTip("Read every item of this servo in one request")
        self.read_button.clicked.connect(self._ask_read)
        bar.addWidget(self.read_button)
        self.live_check = QCheckBox(f"Live ({1000 // LIVE_INTERVAL_MS} Hz)")
        self.live_check.setToolTip("Re-read the table while this page is shown (one read per poll, between the "
                                   "control loop's ticks)")
        self.live_check.toggled.connect(self.live_toggled)
        bar.addWidget(self.live_check)
        bar.addStretch(1)
        self.save_button = QPushButton("Save servo settings…")
        self.save_button.setToolTip("Back up every servo's control table to a file (sensnake-servos JSON)")
        self.save_button.clicked.connect(self.save_requested)
        bar.addWidget(self.save_button)
        self.restore_button = QPushButton("Restore…")
        self.restore_button.setToolTip("Write a saved file back onto this servo (only the items that differ)")
        self.restore_button.clicked.connect(lambda: self.restore_requested.emit(self.servo_id or 0))
        bar.addWidget(self.restore_button)
        self.restore_all_button = QPushButton("Restore all…")
        self.restore_all_button.setToolTip("Write a saved file back onto every servo it holds")
        self.restore_all_button.clicked.connect(lambda: self.restore_requested.emit(0))
        bar.addWidget(self.restore_all_button)
        self.zero_button = QPushButton("Set zero pose…")
        self.zero_button.setToolTip("Lay the robot straight, then make this pose read 0 rad on every joint (written "
                                    "into your lab config, the old file kept)")
        self.zero_button.clicked.connect(self.zero_requested)
        bar.addWidget(self.zero_button)
        self.direction_button = QPushButton("Check direction…")
        self.direction_button.setToolTip("Move this servo's joint a little the positive way and back, then say whether "
                                          "it went the way the app expects (a wrong sign is fixed in your lab config)")
        self.direction_button.clicked.connect(lambda: self.direction_requested.emit(self.servo_id or 0))
        bar.addWidget(self.direction_button)
        self.reset_button = QPushButton("Factory reset…")
        self.reset_button.setToolTip("Factory settings on this servo, keeping its ID and baud rate (save its settings "
                                     "first: gains, limits and Return Delay Time go back to the factory's)")
        self.reset_button.clicked.connect(lambda: self.reset_requested.emit(self.servo_id or 0))
        bar.addWidget(self.reset_button)
        layout.addLayout(bar)

        splitter = QSplitter(Qt.Orientation.Horizontal)
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().setVisible(False)
        self.table.verticalHeader().setDefaultSectionSize(22)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.DoubleClicked
                                   | QAbstractItemView.EditTrigger.EditKeyPressed)
        header = self.table.horizontalHeader()
        for col in range(len(COLUMNS)):
            header.setSectionResizeMode(col, QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(COL_MEANING, QHeaderView.ResizeMode.Stretch)  # the long one: gets what is left
        self.table.itemChanged.connect(self._edited)
        self.table.currentCellChanged.connect(lambda row, _c, _pr, _pc: self._select_row(row))
        splitter.addWidget(self.table)
        side = QWidget()
        side_layout = QVBoxLayout(side)
        side_layout.setContentsMargins(0, 0, 0, 0)
        side_layout.addWidget(self._build_item_panel())

        changes_box = QGroupBox("Changes made")
        changes_layout = QVBoxLayout(changes_box)
        self.changes_title = QLabel("Writes, restores and the lab's [servos] profile show here.")
        self.changes_title.setWordWrap(True)
        changes_layout.addWidget(self.changes_title)
        self.changes = QTableWidget(0, len(CHANGE_COLUMNS))
        self.changes.setHorizontalHeaderLabels(CHANGE_COLUMNS)
        self.changes.verticalHeader().setVisible(False)
        self.changes.verticalHeader().setDefaultSectionSize(22)
        self.changes.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        change_header = self.changes.horizontalHeader()
        for col in range(len(CHANGE_COLUMNS)):
            change_header.setSectionResizeMode(col, QHeaderView.ResizeMode.ResizeToContents)
        change_header.setSectionResizeMode(1, QHeaderView.ResizeMode.Stretch)
        changes_layout.addWidget(self.changes)
        side_layout.addWidget(changes_box, 1)
        splitter.addWidget(side)
        splitter.setStretchFactor(0, 2)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([880, 400])
        layout.addWidget(splitter, 1)

        self.message = QLabel("Double-click a value or its meaning to change it, or edit the selected item by name, "
                              "bits or unit on the right: the range is checked, an EEPROM item is written with torque "
                              "off, every write is read back.")
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        layout.addWidget(self.message)
        self.set_enabled(False)

    # -- what it shows ---------------------------------------------------------------------------------------------
    @property
    def servo_id(self) -> int | None:
        data = self.servo_combo.currentData()
        return int(data) if data is not None else None

    def set_servos(self, servo_ids: Sequence[int], axes: Sequence[str] = ()) -> None:
        self.servo_combo.blockSignals(True)
        self.servo_combo.clear()
        for k, sid in enumerate(servo_ids):
            axis = f" ({axes[k]})" if k < len(axes) else ""
            self.servo_combo.addItem(f"{sid}{axis}", sid)
        self.servo_combo.blockSignals(False)

    def set_rows(self, rows: Iterable[TableRow]) -> None:
        """The items of the servo's model, in address order."""
        self.rows = tuple(rows)
        self._row_of = {row.name: k for k, row in enumerate(self.rows)}
        self._filling = True
        self.table.setRowCount(len(self.rows))
        idle = QBrush(theme.qcolor(theme.STATUS_COLORS[theme.IDLE]))
        for k, row in enumerate(self.rows):
            cells = (str(row.address), row.name, str(row.size), "RW" if row.writable else "R",
                     "EEPROM" if row.eeprom else "RAM", row.unit,
                     f"{row.minimum} … {row.maximum}" if row.writable else "", "", "")
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                flags = Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable
                if col == COL_MEANING and row.writable and (row.names or row.scale):
                    flags |= Qt.ItemFlag.ItemIsEditable
                    item.setToolTip("double-click to change: " + ("type one of its names" if row.names else
                                                                   f"type a value in {row.quantity_unit}"))
                if col == COL_VALUE and row.writable:
                    flags |= Qt.ItemFlag.ItemIsEditable
                    item.setToolTip(f"double-click to change ({row.minimum} … {row.maximum}"
                                    + (f", {row.unit} units" if row.unit else "") + ")"
                                    + ("; EEPROM: written with torque off" if row.eeprom else ""))
                item.setFlags(flags)
                if col in (COL_ADDR, COL_SIZE, COL_VALUE):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                if not row.writable and col != COL_VALUE:
                    item.setForeground(idle)
                self.table.setItem(k, col, item)
        self._filling = False
        if self.rows:
            self.select_item(self.rows[0].name)

    def set_values(self, servo_id: int, values: Mapping[str, int]) -> None:
        """The servo's table as just read (a read of another servo than the one shown is dropped)."""
        if servo_id != self.servo_id:
            return
        self.values = dict(values)
        editing = self.table.state() == QAbstractItemView.State.EditingState
        self._filling = True
        for name, value in values.items():
            k = self._row_of.get(name)
            if k is None:
                continue
            item = self.table.item(k, COL_VALUE)
            meaning = self.table.item(k, COL_MEANING)
            if item is None or meaning is None or (editing and self.table.currentRow() == k):
                continue  # never overwrite what the user is typing
            text = str(value)
            if item.text() != text:
                item.setText(text)
            described = self.rows[k].meaning(value)
            if meaning.text() != described:
                meaning.setText(described)
                meaning.setToolTip(described)
        self._filling = False
        if not self._panel_touched:
            self._show_item_value()

    def restore_value(self, name: str) -> None:
        """Show again the value the servo was last read holding in ``name``'s cell (a write refused or declined:
        the cell must not keep the value that was not written), even while its editor is closing."""
        k = self._row_of.get(name)
        if k is None:
            return
        item = self.table.item(k, COL_VALUE)
        if item is None:
            return
        self._filling = True
        shown = self.values.get(name)
        item.setText("" if shown is None else str(shown))
        meaning = self.table.item(k, COL_MEANING)
        if meaning is not None:
            meaning.setText("" if shown is None else self.rows[k].meaning(shown))
        self._filling = False
        if self.selected is not None and self.selected.name == name:
            self._panel_touched = False
            self._show_item_value()

    def value_text(self, name: str) -> str:
        item = self.table.item(self._row_of[name], COL_VALUE)
        return item.text() if item is not None else ""

    def meaning_text(self, name: str) -> str:
        """What item ``name``'s value means as the Meaning column shows it ("1 Mbps", …)."""
        item = self.table.item(self._row_of[name], COL_MEANING)
        return item.text() if item is not None else ""

    def set_enabled(self, connected: bool, why: str = "") -> None:
        for widget in (self.read_button, self.live_check, self.save_button, self.restore_button,
                       self.restore_all_button, self.zero_button, self.direction_button, self.reset_button,
                       self.table, self.item_box):
            widget.setEnabled(connected)
        if not connected and why:
            self.set_message(why, theme.IDLE)

    def set_message(self, text: str, level: str = theme.IDLE) -> None:
        self.message.setText(text)
        self.message.setStyleSheet(theme.status_style(level))

    def show_changes(self, title: str, changes: Sequence[Any]) -> None:
        """Changes (``servo_id, item, before, after, written`` by attribute), newest set first."""
        self.changes_title.setText(title)
        self.changes.setRowCount(len(changes))
        written_brush = QBrush(theme.qcolor(theme.STATUS_COLORS[theme.OK]))
        same_brush = QBrush(theme.qcolor(theme.STATUS_COLORS[theme.IDLE]))
        for k, change in enumerate(changes):
            cells = (str(change.servo_id), change.item, str(change.before), str(change.after),
                     "written ✔" if change.written else "already so")
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setForeground(written_brush if change.written else same_brush)
                self.changes.setItem(k, col, item)

    def change_lines(self) -> list[str]:
        """The changes table as text, for tests."""
        return [" | ".join(self.changes.item(r, c).text() for c in range(len(CHANGE_COLUMNS)))  # type: ignore[union-attr]
                for r in range(self.changes.rowCount())]

    # -- what the user asks ----------------------------------------------------------------------------------------
    def _ask_read(self) -> None:
        if self.servo_id is not None:
            self.read_requested.emit(self.servo_id)

    def edit(self, name: str, text: str) -> None:
        """Type ``text`` into ``name``'s value cell, as a user would (tests and the keyboard use this)."""
        item = self.table.item(self._row_of[name], COL_VALUE)
        if item is not None:
            item.setText(text)

    def edit_meaning(self, name: str, text: str) -> None:
        """Type ``text`` into ``name``'s Meaning cell (a name, or a value in its unit), as a user would."""
        item = self.table.item(self._row_of[name], COL_MEANING)
        if item is not None:
            item.setText(text)

    def _edited(self, item: QTableWidgetItem) -> None:
        if self._filling or item.column() not in (COL_VALUE, COL_MEANING) or self.servo_id is None:
            return
        row = self.rows[item.row()]
        text = item.text().strip()
        if item.column() == COL_MEANING:
            try:
                value = row.raw_from_text(text)
            except ValueError as exc:
                self._revert(row.name, str(exc))
                return
        else:
            try:
                value = int(text, 0)
            except ValueError:
                self._revert(row.name, f"{row.name}: {text!r} is not a whole number (units of {row.unit or '1'})")
                return
        self._request_write(row, value)

    def _request_write(self, row: TableRow, value: int) -> None:
        """Send ``value`` for ``row`` unless it is none of the item's values or already held."""
        refusal = row.refusal(value)
        if refusal:
            self._revert(row.name, refusal)
            return
        if value == self.values.get(row.name):
            self.restore_value(row.name)
            self.set_message(f"{row.name} already holds {value}: not written (read before write)", theme.IDLE)
            return
        if self.servo_id is not None:
            self.write_requested.emit(self.servo_id, row.name, value)

    def _revert(self, name: str, why: str) -> None:
        self.restore_value(name)
        self.set_message(why, theme.ERROR)

    # -- the selected item's panel: edit by name, bits or unit ------------------------------------------------------
    def _build_item_panel(self) -> QGroupBox:
        self.item_box = QGroupBox("Item")
        box_layout = QVBoxLayout(self.item_box)
        self.item_title = QLabel("")
        self.item_title.setWordWrap(True)
        self.item_title.setStyleSheet("font-weight: bold;")
        box_layout.addWidget(self.item_title)
        self.item_about = QLabel("")
        self.item_about.setWordWrap(True)
        box_layout.addWidget(self.item_about)
        form = QFormLayout()
        self.raw_spin = QSpinBox()
        self.raw_spin.setToolTip("the raw value the servo holds")
        self.raw_spin.valueChanged.connect(self._raw_changed)
        form.addRow("Raw", self.raw_spin)
        self.name_combo = QComboBox()
        self.name_combo.setToolTip("the item's values by name (e-manual)")
        self.name_combo.activated.connect(self._name_chosen)
        form.addRow("Value", self.name_combo)
        self.quantity_spin = QDoubleSpinBox()
        self.quantity_spin.setToolTip("the value in its unit; sent as the nearest raw value")
        self.quantity_spin.setKeyboardTracking(False)
        self.quantity_spin.valueChanged.connect(self._quantity_changed)
        form.addRow("In its unit", self.quantity_spin)
        self.bits_widget = QWidget()
        self.bits_layout = QVBoxLayout(self.bits_widget)
        self.bits_layout.setContentsMargins(0, 0, 0, 0)
        self.bits_layout.setSpacing(2)
        form.addRow("Bits", self.bits_widget)
        self._form = form
        box_layout.addLayout(form)
        buttons = QHBoxLayout()
        buttons.addStretch(1)
        self.item_revert = QPushButton("Revert")
        self.item_revert.setToolTip("show again what the servo holds")
        self.item_revert.clicked.connect(self._revert_panel)
        buttons.addWidget(self.item_revert)
        self.item_write = QPushButton("Write")
        self.item_write.setToolTip("write this value (range-checked; an EEPROM item with torque off; read back)")
        self.item_write.clicked.connect(self.write_selected)
        buttons.addWidget(self.item_write)
        box_layout.addLayout(buttons)
        self.bit_boxes: dict[int, QCheckBox] = {}
        self.selected: TableRow | None = None
        self._panel_touched = False  # the user changed the panel: live reads do not overwrite it
        self._panel_filling = False
        return self.item_box

    def select_item(self, name: str) -> None:
        """Select item ``name``'s row and show it in the panel."""
        k = self._row_of[name]
        if self.table.currentRow() != k:
            self.table.setCurrentCell(k, COL_NAME)
        else:
            self._select_row(k)

    def _select_row(self, k: int) -> None:
        if not 0 <= k < len(self.rows):
            return
        row = self.rows[k]
        self.selected = row
        self._panel_touched = False
        access = "read and write" if row.writable else "read only"
        memory = "EEPROM: written with torque off" if row.eeprom else "RAM"
        self.item_title.setText(f"{row.name} — address {row.address}, {row.size} byte{'s' * (row.size > 1)}, "
                                f"{access}, {memory}")
        about = [f"range {row.minimum} … {row.maximum}" if row.writable else ""]
        if row.scale:
            about.append(f"1 raw unit = {row.scale:g} {row.quantity_unit}")
        about.append(row.notes)
        self.item_about.setText("; ".join(a for a in about if a))
        self._panel_filling = True
        low, high = (row.minimum, row.maximum) if row.writable else (-(1 << 31), (1 << 31) - 1)
        self.raw_spin.setRange(low, high)
        self.raw_spin.setEnabled(row.writable)
        self.name_combo.clear()
        for value, label in row.names:
            self.name_combo.addItem(f"{label}  ({value})", value)
        self.name_combo.setEnabled(row.writable)
        self.quantity_spin.setDecimals(row.decimals)
        if row.scale:
            self.quantity_spin.setRange(low * row.scale, high * row.scale)
        self.quantity_spin.setSingleStep(row.scale or 1.0)
        self.quantity_spin.setSuffix(f" {row.quantity_unit}" if row.quantity_unit else "")
        self.quantity_spin.setEnabled(row.writable)
        for box in self.bit_boxes.values():
            self.bits_layout.removeWidget(box)
            box.deleteLater()
        self.bit_boxes = {}
        for bit, label in row.bits:
            box = QCheckBox(f"{label}  (bit {bit})")
            box.setEnabled(row.writable)
            box.toggled.connect(lambda on, b=bit: self._bit_toggled(b, on))
            self.bits_layout.addWidget(box)
            self.bit_boxes[bit] = box
        self._form.setRowVisible(self.name_combo, bool(row.names))
        self._form.setRowVisible(self.quantity_spin, bool(row.scale))
        self._form.setRowVisible(self.bits_widget, bool(row.bits))
        self.item_write.setVisible(row.writable)
        self.item_revert.setVisible(row.writable)
        self._panel_filling = False
        self._show_item_value()

    def _show_item_value(self) -> None:
        """The panel shows what the servo holds in the selected item."""
        row = self.selected
        if row is None:
            return
        value = self.values.get(row.name)
        self._panel_filling = True
        if value is not None:
            self._show_raw_in_editors(row, value, from_raw=True)
        self._panel_filling = False
        self.item_write.setEnabled(False)

    def _show_raw_in_editors(self, row: TableRow, value: int, from_raw: bool = False) -> None:
        was = self._panel_filling
        self._panel_filling = True
        if from_raw or self.raw_spin.value() != value:
            self.raw_spin.setValue(value)
        if row.names:
            index = self.name_combo.findData(value)
            self.name_combo.setCurrentIndex(index)
        if row.scale:
            self.quantity_spin.setValue(value * row.scale)
        for bit, box in self.bit_boxes.items():
            box.setChecked(bool(value & (1 << bit)))
        self._panel_filling = was

    def _panel_value_changed(self, value: int) -> None:
        row = self.selected
        if self._panel_filling or row is None:
            return
        self._panel_touched = True
        self._show_raw_in_editors(row, value)
        self.item_write.setEnabled(value != self.values.get(row.name))

    def _raw_changed(self, value: int) -> None:
        self._panel_value_changed(value)

    def _name_chosen(self, index: int) -> None:
        data = self.name_combo.itemData(index)
        if data is not None:
            self._panel_value_changed(int(data))

    def _quantity_changed(self, quantity: float) -> None:
        row = self.selected
        if row is not None and row.scale and not self._panel_filling:
            raw = int(round(quantity / row.scale))
            self._panel_value_changed(min(max(raw, self.raw_spin.minimum()), self.raw_spin.maximum()))

    def _bit_toggled(self, bit: int, on: bool) -> None:
        if self._panel_filling:
            return
        raw = self.raw_spin.value()
        self._panel_value_changed(raw | (1 << bit) if on else raw & ~(1 << bit))

    def panel_value(self) -> int:
        """The raw value the panel holds now."""
        return self.raw_spin.value()

    def choose_name(self, label: str) -> None:
        """Pick ``label`` in the panel's list, as a user would (tests and the keyboard use this)."""
        for index in range(self.name_combo.count()):
            if self.name_combo.itemText(index).split("  (")[0].lower() == label.lower():
                self.name_combo.setCurrentIndex(index)
                self._name_chosen(index)
                return
        raise LookupError(f"no value called {label!r} in the list")

    def write_selected(self) -> None:
        """Write the panel's value into the selected item."""
        row = self.selected
        if row is None or not row.writable:
            return
        self._panel_touched = False
        self._request_write(row, self.raw_spin.value())

    def _revert_panel(self) -> None:
        self._panel_touched = False
        self._show_item_value()
