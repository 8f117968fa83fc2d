"""The Hardware tab's "Servo settings" page: one servo's whole control table with live values, edited in place, and
the changes the app made (a write, a restore, the lab's ``[servos]`` profile on connect).

Passive, like :mod:`widgets.hardware_panel`: it shows the rows and values it is given (plain tuples and dicts;
widgets do not import devices) and emits what the user asks; range checks against the row's limits happen here so a
value out of range never leaves the page. GUI thread only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QBrush
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

COLUMNS = ("Addr", "Item", "Size", "Access", "Memory", "Unit", "Range", "Value")
COL_ADDR, COL_NAME, COL_SIZE, COL_ACCESS, COL_MEMORY, COL_UNIT, COL_RANGE, COL_VALUE = range(len(COLUMNS))
CHANGE_COLUMNS = ("Servo", "Item", "Before", "After", "")
LIVE_INTERVAL_MS = 500  # 2 Hz: a person reads it; one table read per poll


@dataclass(frozen=True)
class TableRow:
    """One control-table item as the page shows it."""

    address: int
    name: str
    size: int
    writable: bool
    eeprom: bool
    unit: str
    minimum: int
    maximum: int


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
        header.setSectionResizeMode(COL_NAME, QHeaderView.ResizeMode.Stretch)
        self.table.itemChanged.connect(self._edited)
        splitter.addWidget(self.table)

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
        splitter.addWidget(changes_box)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 2)
        layout.addWidget(splitter, 1)

        self.message = QLabel("Double-click a value to change it: the range is checked, an EEPROM item is written "
                              "with torque off, every write is read back.")
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
                     f"{row.minimum} … {row.maximum}" if row.writable else "", "")
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                flags = Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable
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
            if item is None or (editing and self.table.currentRow() == k):
                continue  # never overwrite what the user is typing
            text = str(value)
            if item.text() != text:
                item.setText(text)
        self._filling = False

    def restore_value(self, name: str) -> None:
        """Show again the value the servo was last read holding in ``name``'s cell (a write refused or declined:
        the cell must not keep the value that was not written), even while its editor is closing."""
        k = self._row_of.get(name)
        item = self.table.item(k, COL_VALUE) if k is not None else None
        if item is None:
            return
        self._filling = True
        shown = self.values.get(name)
        item.setText("" if shown is None else str(shown))
        self._filling = False

    def value_text(self, name: str) -> str:
        item = self.table.item(self._row_of[name], COL_VALUE)
        return item.text() if item is not None else ""

    def set_enabled(self, connected: bool, why: str = "") -> None:
        for widget in (self.read_button, self.live_check, self.save_button, self.restore_button,
                       self.restore_all_button, self.zero_button, self.direction_button, self.reset_button,
                       self.table):
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

    def _edited(self, item: QTableWidgetItem) -> None:
        if self._filling or item.column() != COL_VALUE or self.servo_id is None:
            return
        row = self.rows[item.row()]
        shown = self.values.get(row.name)
        text = item.text().strip()
        try:
            value = int(text, 0)
        except ValueError:
            self._revert(item, shown, f"{row.name}: {text!r} is not a whole number (units of {row.unit or '1'})")
            return
        if not row.minimum <= value <= row.maximum:
            self._revert(item, shown, f"{row.name} = {value} is out of its range {row.minimum} … {row.maximum}"
                         + (f" ({row.unit} units)" if row.unit else "") + ": not written")
            return
        if value == shown:
            self.set_message(f"{row.name} already holds {value}: not written (read before write)", theme.IDLE)
            return
        self.write_requested.emit(self.servo_id, row.name, value)

    def _revert(self, item: QTableWidgetItem, shown: int | None, why: str) -> None:
        self._filling = True
        item.setText("" if shown is None else str(shown))
        self._filling = False
        self.set_message(why, theme.ERROR)
