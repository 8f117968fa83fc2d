"""The Hardware tab's view: connection, scan, per-servo live status and controls, link check, timing warnings.

Passive: it shows what it is given (numpy arrays in joint order, ServoHealth/ServoInfo-like dataclasses read by
attribute) and emits signals for what the user asks; it never talks to a device. GUI thread only.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QBrush, QFont
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QProgressBar,
    QPushButton,
    QSizePolicy,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from widgets import theme
from widgets.tables import cell_item

# Dynamixel X-series baud rates (control table item 8), most common first.
DXL_BAUDS_BPS: tuple[int, ...] = (1_000_000, 57_600, 115_200, 2_000_000, 3_000_000, 4_000_000, 4_500_000, 9_600)
TEMPERATURE_WARN_C = 70.0  # XM430 shuts down at 80 °C by default
VOLTAGE_RANGE_V = (10.0, 14.8)  # XM430-W350 recommended supply range
ROW_HEIGHT_PX = 26  # twelve servos fit without scrolling at the default window size
SERVO_TABLE_HEIGHT_PX = 12 * ROW_HEIGHT_PX + 64  # rows + header + the group's title and margins
SMALL_ROW_HEIGHT_PX = 22
# After a click, the servo's reported state lags the request by a health poll or two; until it agrees (or this
# long has passed) the button keeps showing what was asked instead of flicking back.
PENDING_REQUEST_S = 1.5

SERVO_COLUMNS: tuple[str, ...] = ("ID", "Axis", "Position (rad)", "Position (°)", "Velocity (rad/s)",
                                  "Current (mA)", "Temp (°C)", "Voltage (V)", "Hardware errors",
                                  "Torque", "LED", "")
COL_ID, COL_AXIS, COL_RAD, COL_DEG, COL_VEL, COL_CUR, COL_TEMP, COL_VOLT, COL_ERR, COL_TORQUE, COL_LED, COL_REBOOT = (
    range(len(SERVO_COLUMNS)))
LIVE_COLUMNS: tuple[int, ...] = (COL_RAD, COL_DEG, COL_VEL, COL_CUR, COL_TEMP, COL_VOLT)
# Widest text each live column is sized for up front (XM430: position within ±π in joint mode, velocity under
# 10 rad/s, current under 3.3 A, 80 °C shutdown). A longer text widens its column once (HardwarePanel._fit_column).
LIVE_SAMPLE_TEXT: dict[int, str] = {COL_RAD: "+3.142", COL_DEG: "-180.0", COL_VEL: "+9.999", COL_CUR: "-3209",
                                    COL_TEMP: "100", COL_VOLT: "16.0"}
UNKNOWN_TEXT = "?"  # a torque or LED button while the servo's state is unknown (link down, no reply)
SCAN_COLUMNS: tuple[str, ...] = ("ID", "Model", "Firmware", "Baud")
LINK_COLUMNS: tuple[str, ...] = ("ID", "RTT mean (ms)", "RTT max (ms)", "No reply", "CRC err", "Result")


class LinkCheckRow(Protocol):
    """One servo's link-check result as the panel shows it: round-trip times of the pings that answered, and the
    failures (``devices.bus_commands.LinkCheckRow`` is one; widgets do not import devices)."""

    @property
    def servo_id(self) -> int: ...
    @property
    def rtt_mean_ms(self) -> float | None: ...
    @property
    def rtt_max_ms(self) -> float | None: ...
    @property
    def no_reply(self) -> int: ...
    @property
    def crc_errors(self) -> int: ...
    @property
    def other_errors(self) -> tuple[str, ...]: ...
    @property
    def ok(self) -> bool: ...


def _item(text: str, align_right: bool = True) -> QTableWidgetItem:
    item = QTableWidgetItem(text)
    item.setFlags(Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable)
    if align_right:
        item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
    return item


def _set_label(label: QLabel, text: str, style: str) -> None:
    """Set a label's text and style sheet only where they change (a style sheet change re-polishes the widget)."""
    if label.text() != text:
        label.setText(text)
    if label.styleSheet() != style:
        label.setStyleSheet(style)


def _toggle_button(text_on: str, text_off: str) -> QPushButton:
    button = QPushButton(text_off)
    button.setCheckable(True)
    button.setProperty("text_on", text_on)
    button.setProperty("text_off", text_off)
    button.toggled.connect(lambda on, b=button: b.setText(b.property("text_on" if on else "text_off")))
    button.setFocusPolicy(Qt.FocusPolicy.TabFocus)
    return button


# Scan, link check and timing check all work disconnected too (the bridge opens the port for the call).
LINK_CHECK_TIP = ("Ping every configured servo 5 times: round-trip time, missing replies and CRC errors per servo "
                  "(connected or not: a quiet bus shows the link alone)")
TIMING_CHECK_TIP = "Check the USB latency timer and each servo's Return Delay Time again"


class HardwarePanel(QWidget):
    """Dynamixel Wizard's essentials for the robot's bus."""

    connect_requested = Signal(str, int)  # port, baud
    disconnect_requested = Signal()
    scan_requested = Signal(object, object)  # ids: list[int], bauds: list[int]
    torque_requested = Signal(int, bool)  # servo ID, on
    all_torque_requested = Signal(bool)
    led_requested = Signal(int, bool)
    reboot_requested = Signal(int)
    link_check_requested = Signal()
    timing_check_requested = Signal()
    fix_return_delay_requested = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.servo_ids: tuple[int, ...] = ()
        self._row_of_id: dict[int, int] = {}
        self._connected = False
        self._pending: dict[tuple[int, int], tuple[bool, float]] = {}  # (servo ID, column) → (asked, deadline)
        # What the live cells show, so that a refresh only touches cells whose text or colour changed
        self._shown_text: dict[tuple[int, int], str] = {}  # (row, column) → text
        self._shown_warn: dict[tuple[int, int], bool] = {}  # (row, column) → drawn in the warning colour
        self._shown_errors: dict[int, tuple[str, ...]] = {}  # row → hardware error names
        self._errors_by_id: dict[int, tuple[str, ...]] = {}  # servo ID → hardware error names, as last reported
        self._error_advice: Callable[[tuple[str, ...]], str] | None = None
        self._column_chars: dict[int, int] = {}  # column → the longest text (characters) it was sized for
        self._unknown_toggles: set[tuple[int, int]] = set()  # (row, column) of torque/LED buttons showing "?"

        layout = QVBoxLayout(self)
        layout.setContentsMargins(8, 8, 8, 8)
        connection = self._build_connection()
        layout.addWidget(connection)
        servos = self._build_servos()
        # The all-torque buttons sit at the right of the connection row, not on a row of their own: that height
        # goes to the scan and link tables (at 1280×800 the scan list showed only four rows).
        connection_row = connection.layout()
        assert isinstance(connection_row, QHBoxLayout)
        connection_row.addLayout(self._servo_bar)

        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.setChildrenCollapsible(False)
        splitter.addWidget(servos)
        tools = QWidget()
        tools_layout = QHBoxLayout(tools)
        tools_layout.setContentsMargins(0, 0, 0, 0)
        tools_layout.addWidget(self._build_scan(), 5)
        tools_layout.addWidget(self._build_link_check(), 5)
        tools_layout.addWidget(self._build_timing(), 4)
        splitter.addWidget(tools)
        # Extra height goes to scan / link check / timing: the servo table only ever needs its 12 rows (at 1920×1080
        # it used to grow a blank area while the scan and link tables scrolled).
        splitter.setStretchFactor(0, 0)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([SERVO_TABLE_HEIGHT_PX, 240])
        layout.addWidget(splitter, 1)
        self.set_connection(False, "not connected")

    # -- construction ----------------------------------------------------------------------------------------------
    def _build_connection(self) -> QGroupBox:
        box = QGroupBox("Servo bus")
        row = QHBoxLayout(box)
        row.addWidget(QLabel("Port"))
        self.port_edit = QLineEdit()
        self.port_edit.setPlaceholderText("/dev/ttyUSB0, COM3 or sim")
        self.port_edit.setMinimumWidth(180)
        self.port_edit.setToolTip("Serial device of the U2D2 adapter, or 'sim' for the simulated robot")
        row.addWidget(self.port_edit)
        row.addWidget(QLabel("Baud"))
        self.baud_combo = QComboBox()
        self.baud_combo.setEditable(True)
        for baud in DXL_BAUDS_BPS:
            self.baud_combo.addItem(str(baud), baud)
        self.baud_combo.setMinimumWidth(110)
        row.addWidget(self.baud_combo)
        self.connect_button = QPushButton("Connect")
        self.connect_button.setObjectName("connect_button")
        self.connect_button.clicked.connect(self._emit_connect)
        row.addWidget(self.connect_button)
        self.disconnect_button = QPushButton("Disconnect")
        self.disconnect_button.setObjectName("disconnect_button")
        self.disconnect_button.clicked.connect(self.disconnect_requested)
        row.addWidget(self.disconnect_button)
        self.connection_label = QLabel()
        self.connection_label.setObjectName("connection_label")
        row.addWidget(self.connection_label)
        row.addStretch(1)
        return box

    def _build_servos(self) -> QGroupBox:
        box = QGroupBox("Servos")
        column = QVBoxLayout(box)
        bar = QHBoxLayout()
        self.all_torque_on_button = QPushButton("All torque on")
        self.all_torque_on_button.clicked.connect(lambda: self.all_torque_requested.emit(True))
        self.all_torque_on_button.setToolTip("Every servo holds its present position")
        self.all_torque_off_button = QPushButton("All torque off")
        self.all_torque_off_button.setToolTip("The robot goes limp: support it before switching torque off")
        self.all_torque_off_button.clicked.connect(lambda: self.all_torque_requested.emit(False))
        self.servo_summary_label = QLabel("")
        bar.addWidget(self.servo_summary_label)
        bar.addWidget(self.all_torque_on_button)
        bar.addWidget(self.all_torque_off_button)
        self._servo_bar = bar  # placed in the connection row by __init__

        self.servo_table = QTableWidget(0, len(SERVO_COLUMNS))
        self.servo_table.setObjectName("servo_table")
        self.servo_table.setHorizontalHeaderLabels(list(SERVO_COLUMNS))
        self.servo_table.verticalHeader().setVisible(False)
        self.servo_table.verticalHeader().setDefaultSectionSize(ROW_HEIGHT_PX)
        self.servo_table.setStyleSheet("QTableWidget QPushButton { padding: 0px 8px; margin: 1px 3px; }")
        self.servo_table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.servo_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.servo_table.setAlternatingRowColors(True)
        header = self.servo_table.horizontalHeader()
        # Not ResizeToContents: with it, every setText re-measured every cell of the table (~0.6 ms each, 30 ms
        # per state update). Columns are fitted once to the widest expected text (set_servos) and widened when a
        # longer text appears (_fit_column).
        header.setSectionResizeMode(QHeaderView.ResizeMode.Interactive)
        header.setSectionResizeMode(COL_ERR, QHeaderView.ResizeMode.Stretch)
        header.setMinimumSectionSize(48)
        column.addWidget(self.servo_table)
        return box

    def _build_scan(self) -> QGroupBox:
        box = QGroupBox("Scan")
        column = QVBoxLayout(box)
        row = QHBoxLayout()
        row.addWidget(QLabel("IDs"))
        self.scan_id_from = QSpinBox()
        self.scan_id_from.setRange(0, 252)
        self.scan_id_to = QSpinBox()
        self.scan_id_to.setRange(0, 252)
        self.scan_id_to.setValue(252)
        row.addWidget(self.scan_id_from)
        row.addWidget(QLabel("to"))
        row.addWidget(self.scan_id_to)
        self.scan_all_bauds = QCheckBox("all baud rates")
        self.scan_all_bauds.setToolTip("Try every Dynamixel baud rate, not only the one selected above")
        row.addWidget(self.scan_all_bauds)
        row.addStretch(1)
        self.scan_button = QPushButton("Scan")
        self.scan_button.setObjectName("scan_button")
        self.scan_button.clicked.connect(self._emit_scan)
        self.scan_button.setToolTip("Ping every ID in the range (works connected, or opens the port above briefly)")
        row.addWidget(self.scan_button)
        column.addLayout(row)
        self.scan_progress = QProgressBar()
        self.scan_progress.setTextVisible(True)
        self.scan_progress.setRange(0, 1)
        self.scan_progress.setValue(0)
        self.scan_progress.setFormat("idle")
        self.scan_progress.setVisible(False)  # shown while a scan runs; the status line says how it ended
        column.addWidget(self.scan_progress)
        self.scan_table = QTableWidget(0, len(SCAN_COLUMNS))
        self.scan_table.setObjectName("scan_table")
        self.scan_table.setHorizontalHeaderLabels(list(SCAN_COLUMNS))
        self.scan_table.verticalHeader().setVisible(False)
        self.scan_table.verticalHeader().setDefaultSectionSize(SMALL_ROW_HEIGHT_PX)
        self.scan_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.scan_table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.scan_table.horizontalHeader().setSectionResizeMode(1, QHeaderView.ResizeMode.Stretch)
        column.addWidget(self.scan_table, 1)
        self.scan_status_label = QLabel("")
        self.scan_status_label.setWordWrap(True)
        self.scan_status_label.setVisible(False)  # shown when it has something to say
        column.addWidget(self.scan_status_label)
        return box

    def _build_link_check(self) -> QGroupBox:
        box = QGroupBox("Link check")
        column = QVBoxLayout(box)
        row = QHBoxLayout()
        self.link_summary_label = QLabel("Ping every servo and time the round trip.")
        self.link_summary_label.setWordWrap(True)
        row.addWidget(self.link_summary_label, 1)
        self.link_check_button = QPushButton("Check link")
        self.link_check_button.setObjectName("link_check_button")
        self.link_check_button.clicked.connect(self.link_check_requested)
        self.link_check_button.setToolTip(LINK_CHECK_TIP)
        row.addWidget(self.link_check_button)
        column.addLayout(row)
        self.link_table = QTableWidget(0, len(LINK_COLUMNS))
        self.link_table.setObjectName("link_table")
        self.link_table.setHorizontalHeaderLabels(list(LINK_COLUMNS))
        self.link_table.verticalHeader().setVisible(False)
        self.link_table.verticalHeader().setDefaultSectionSize(SMALL_ROW_HEIGHT_PX)
        self.link_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.link_table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.link_table.horizontalHeader().setSectionResizeMode(len(LINK_COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)
        column.addWidget(self.link_table, 1)
        return box

    def _build_timing(self) -> QGroupBox:
        box = QGroupBox("Timing")
        column = QVBoxLayout(box)
        row = QHBoxLayout()
        self.timing_summary_label = QLabel("Latency timer and return delay checks run on connect.")
        self.timing_summary_label.setWordWrap(True)
        row.addWidget(self.timing_summary_label, 1)
        self.timing_check_button = QPushButton("Re-check")
        self.timing_check_button.clicked.connect(self.timing_check_requested)
        self.timing_check_button.setToolTip(TIMING_CHECK_TIP)
        row.addWidget(self.timing_check_button)
        column.addLayout(row)
        self.timing_text = QPlainTextEdit()
        self.timing_text.setObjectName("timing_text")
        self.timing_text.setReadOnly(True)
        self.timing_text.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        column.addWidget(self.timing_text, 1)
        self.loop_label = QLabel("")
        self.loop_label.setObjectName("loop_label")
        self.loop_label.setWordWrap(True)
        # Two lines, fixed: the text changes every refresh, and a word-wrapped label whose height follows its text
        # re-lays out (and so repaints) the whole window each time.
        self.loop_label.setFixedHeight(2 * self.loop_label.fontMetrics().lineSpacing() + 4)
        self.loop_label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Fixed)
        self.loop_label.setToolTip("The robot's control loop since connect: period between tick starts and ticks "
                                   "that missed their deadline (each missed tick delays motion by one period)")
        column.addWidget(self.loop_label)
        self.fix_return_delay_button = QPushButton("Set return delay to 0 µs")
        self.fix_return_delay_button.setObjectName("fix_return_delay_button")
        self.fix_return_delay_button.setToolTip("Writes Return Delay Time = 0 to every servo (EEPROM: torque must be "
                                                "off). Every sync read gets faster.")
        self.fix_return_delay_button.clicked.connect(self.fix_return_delay_requested)
        column.addWidget(self.fix_return_delay_button, 0, Qt.AlignmentFlag.AlignRight)
        return box

    # -- inputs ----------------------------------------------------------------------------------------------------
    @property
    def port(self) -> str:
        return self.port_edit.text().strip()

    @property
    def baud(self) -> int:
        """The baud rate typed or chosen; raises ValueError naming the field if it is not a positive integer."""
        text = self.baud_combo.currentText().strip()
        try:
            baud = int(text)
        except ValueError:
            raise ValueError(f"baud rate {text!r} is not a whole number") from None
        if baud <= 0:
            raise ValueError(f"baud rate {baud} must be positive")
        return baud

    def _emit_connect(self) -> None:
        if not self.port:
            self.connection_label.setText("enter a port first")
            self.connection_label.setStyleSheet(theme.status_style(theme.WARN))
            return
        try:
            baud = self.baud
        except ValueError as exc:
            self.connection_label.setText(str(exc))
            self.connection_label.setStyleSheet(theme.status_style(theme.WARN))
            return
        self.connect_requested.emit(self.port, baud)

    def _emit_scan(self) -> None:
        lo, hi = self.scan_id_from.value(), self.scan_id_to.value()
        if lo > hi:
            lo, hi = hi, lo
        if self.scan_all_bauds.isChecked():
            bauds = list(DXL_BAUDS_BPS)
        else:
            try:
                bauds = [self.baud]
            except ValueError as exc:
                self.scan_status_label.setText(str(exc))
                self.scan_status_label.setVisible(True)
                return
        self.scan_requested.emit(list(range(lo, hi + 1)), bauds)

    # -- outputs ---------------------------------------------------------------------------------------------------
    def set_port_baud(self, port: str, baud: int) -> None:
        self.port_edit.setText(port)
        index = self.baud_combo.findData(baud)
        if index >= 0:
            self.baud_combo.setCurrentIndex(index)
        else:
            self.baud_combo.setEditText(str(baud))

    def set_connection(self, connected: bool, text: str, busy: bool = False, level: str | None = None) -> None:
        """Connection state: enables what makes sense (port/baud fixed while connected). ``level`` overrides the
        label's colour (a connected bus whose link is lost is not green)."""
        self._connected = connected
        self.connection_label.setText(text)
        if level is None:
            level = theme.OK if connected else (theme.WARN if busy else theme.IDLE)
        self.connection_label.setStyleSheet(theme.status_style(level))
        self.connect_button.setEnabled(not connected and not busy)
        self.disconnect_button.setEnabled(connected and not busy)
        self.port_edit.setEnabled(not connected and not busy)
        self.baud_combo.setEnabled(not connected and not busy)
        for widget in (self.all_torque_on_button, self.all_torque_off_button, self.fix_return_delay_button):
            widget.setEnabled(connected)
        for row in range(self.servo_table.rowCount()):
            for col in (COL_TORQUE, COL_LED, COL_REBOOT):
                cell = self.servo_table.cellWidget(row, col)
                if cell is not None:
                    cell.setEnabled(connected)
        if not connected:
            self.clear_live_values()
            self.clear_loop_stats()

    def set_servos(self, servo_ids: Sequence[int], axes: Sequence[str]) -> None:
        """One row per joint, head first."""
        self.servo_ids = tuple(int(i) for i in servo_ids)
        self._row_of_id = {sid: row for row, sid in enumerate(self.servo_ids)}
        table = self.servo_table
        table.setRowCount(len(self.servo_ids))
        for row, (sid, axis) in enumerate(zip(self.servo_ids, axes)):
            table.setItem(row, COL_ID, _item(str(sid)))
            axis_item = _item(axis, align_right=False)
            axis_item.setForeground(QBrush(theme.qcolor(theme.AXIS_COLORS.get(axis, theme.PRESENT_COLOR))))
            table.setItem(row, COL_AXIS, axis_item)
            for col in (COL_RAD, COL_DEG, COL_VEL, COL_CUR, COL_TEMP, COL_VOLT):
                table.setItem(row, col, _item("—"))
            table.setItem(row, COL_ERR, _item("", align_right=False))
            torque = _toggle_button("On", "Off")
            torque.setObjectName(f"torque_{sid}")
            torque.clicked.connect(lambda on, s=sid: self._request(s, COL_TORQUE, on))
            torque.setToolTip(f"Servo {sid} torque: shows the present state; click to switch it")
            table.setCellWidget(row, COL_TORQUE, torque)
            led = _toggle_button("On", "Off")
            led.setObjectName(f"led_{sid}")
            led.clicked.connect(lambda on, s=sid: self._request(s, COL_LED, on))
            led.setToolTip(f"Servo {sid} LED: shows the present state; click to switch it (find the servo on "
                           "the robot)")
            table.setCellWidget(row, COL_LED, led)
            reboot = QPushButton("Reboot")
            reboot.setObjectName(f"reboot_{sid}")
            reboot.setToolTip(f"Reboot servo {sid}: clears a latched hardware error; it comes back with torque off")
            reboot.clicked.connect(lambda _checked=False, s=sid: self.reboot_requested.emit(s))
            table.setCellWidget(row, COL_REBOOT, reboot)
        self._shown_text.clear()
        self._shown_warn.clear()
        self._shown_errors.clear()
        self._unknown_toggles.clear()
        # Size the columns once, for the widest live values and error names expected, then show the placeholders.
        if self.servo_ids:
            for col, sample in LIVE_SAMPLE_TEXT.items():
                cell_item(table, 0, col).setText(sample)
            cell_item(table, 0, COL_ERR).setText("none")
            table.resizeColumnsToContents()
            self._column_chars = {col: len(sample) for col, sample in LIVE_SAMPLE_TEXT.items()}
            for col in LIVE_SAMPLE_TEXT:
                cell_item(table, 0, col).setText("—")
            cell_item(table, 0, COL_ERR).setText("")
        self.set_connection(self._connected, self.connection_label.text())

    def _request(self, servo_id: int, column: int, on: bool) -> None:
        self._pending[(servo_id, column)] = (on, time.monotonic() + PENDING_REQUEST_S)
        (self.torque_requested if column == COL_TORQUE else self.led_requested).emit(servo_id, on)

    def clear_live_values(self) -> None:
        for row in range(self.servo_table.rowCount()):
            for col in LIVE_COLUMNS:
                self._set_cell(row, col, "—", warn=False)

    def set_unknown(self, servo_ids: Iterable[int], why: str, silent: Iterable[int] = ()) -> None:
        """Nothing is known of these servos now (the link is down, or the bus's feedback stopped): their live values
        show "—", their torque and LED "?" (never the last state seen), and the ``silent`` ones "no reply" in the
        error colour; ``why`` goes into the tooltips. The next :meth:`set_state` / :meth:`set_health` shows values
        again. GUI thread."""
        silent = set(silent)
        for servo_id in servo_ids:
            row = self._row_of_id.get(int(servo_id))
            if row is None:
                continue
            for col in LIVE_COLUMNS:
                self._set_cell(row, col, "—", warn=False)
            names = ("no reply",) if servo_id in silent else ("unknown",)
            if self._shown_errors.get(row) != names:
                self._shown_errors[row] = names
                item = cell_item(self.servo_table, row, COL_ERR)
                item.setText(names[0])
                item.setToolTip(why)
                level = theme.ERROR if servo_id in silent else theme.WARN
                item.setForeground(QBrush(theme.qcolor(theme.STATUS_COLORS[level])))
                item.setBackground(QBrush(theme.qcolor(theme.STATUS_BACKGROUNDS[level])))
                item.setFont(QFont())
            self._errors_by_id.pop(int(servo_id), None)
            for col in (COL_TORQUE, COL_LED):
                button = self.servo_table.cellWidget(row, col)
                if isinstance(button, QPushButton) and button.text() != UNKNOWN_TEXT:
                    button.blockSignals(True)
                    button.setChecked(False)
                    button.setText(UNKNOWN_TEXT)
                    button.blockSignals(False)
                    button.setToolTip(f"Servo {servo_id}: unknown — {why}")
                    self._unknown_toggles.add((row, col))

    def _set_cell(self, row: int, col: int, text: str, warn: bool | None = None) -> bool:
        """Show ``text`` (and the warning colour if ``warn``; ``None`` leaves the colour) in a live cell, touching
        the item only if that changes what it shows. True if the text changed. GUI thread."""
        key = (row, col)
        changed = self._shown_text.get(key) != text
        if changed or (warn is not None and self._shown_warn.get(key) != warn):
            item = self.servo_table.item(row, col)
            if item is None:
                return False
            if changed:
                item.setText(text)
                self._shown_text[key] = text
                if len(text) > self._column_chars.get(col, 0):
                    self._fit_column(col, len(text))
            if warn is not None and self._shown_warn.get(key) != warn:
                item.setForeground(QBrush(theme.qcolor(theme.STATUS_COLORS[theme.WARN])) if warn else QBrush())
                self._shown_warn[key] = warn
        return changed

    def _fit_column(self, col: int, n_chars: int) -> None:
        """Widen ``col`` for a text longer than any it was sized for (rare: one re-measure, not one per update)."""
        self._column_chars[col] = n_chars
        self.servo_table.resizeColumnToContents(col)

    def set_state(self, position_rad: np.ndarray, velocity_rad_s: np.ndarray, current_ma: np.ndarray) -> None:
        """Live joint values in joint order (rad, rad/s, mA). Only cells whose text changed are touched, so a robot
        standing still costs next to nothing; the Hardware tab calls this at most 10 times a second. GUI thread."""
        n = min(self.servo_table.rowCount(), len(position_rad))
        set_cell = self._set_cell
        for row in range(n):
            angle = float(position_rad[row])
            set_cell(row, COL_RAD, f"{angle:+.3f}")
            set_cell(row, COL_DEG, f"{math.degrees(angle):+.1f}")
            set_cell(row, COL_VEL, f"{float(velocity_rad_s[row]):+.3f}")
            set_cell(row, COL_CUR, f"{float(current_ma[row]):+.0f}")

    def set_health(self, health: Iterable[Any]) -> None:
        """ServoHealth-like items (servo_id, error_names, temperature_c, voltage_v, torque_on, led_on), °C and V.

        Only cells whose text or colour changed are touched. GUI thread."""
        n_errors = 0
        low, high = VOLTAGE_RANGE_V
        for item in health:
            row = self._row_of_id.get(int(item.servo_id))
            if row is None:
                continue
            temperature_c, voltage_v = float(item.temperature_c), float(item.voltage_v)
            self._set_cell(row, COL_TEMP, f"{temperature_c:.0f}", warn=temperature_c >= TEMPERATURE_WARN_C)
            self._set_cell(row, COL_VOLT, f"{voltage_v:.1f}", warn=not low <= voltage_v <= high)
            self._set_errors(row, tuple(item.error_names))
            self._errors_by_id[int(item.servo_id)] = tuple(item.error_names)
            n_errors += bool(item.error_names)
            self._set_toggle(int(item.servo_id), row, COL_TORQUE, bool(item.torque_on))
            self._set_toggle(int(item.servo_id), row, COL_LED, bool(item.led_on))
        if n_errors:
            first = next(((sid, names) for sid, names in self._errors_by_id.items() if names), None)
            detail = ""
            if first is not None and self._error_advice is not None:
                detail = f" — servo {first[0]}: {self._error_advice(first[1])}"
            _set_label(self.servo_summary_label, f"{n_errors} servo(s) report a hardware error{detail}",
                       theme.status_style(theme.ERROR))
            self.servo_summary_label.setToolTip("\n".join(
                f"servo {sid}: {self._error_advice(names) if self._error_advice else ', '.join(names)}"
                for sid, names in self._errors_by_id.items() if names))
        else:
            _set_label(self.servo_summary_label, "", "")

    def set_error_advice(self, advice: Callable[[tuple[str, ...]], str]) -> None:
        """``advice(error names)`` → one sentence saying what they mean and what to do (the owner knows the
        e-manual's table; this view does not)."""
        self._error_advice = advice

    def _set_errors(self, row: int, names: tuple[str, ...]) -> None:
        if self._shown_errors.get(row) == names:
            return
        self._shown_errors[row] = names
        item = cell_item(self.servo_table, row, COL_ERR)
        item.setText(", ".join(names) if names else "none")
        item.setToolTip(self._error_advice(names) if names and self._error_advice is not None else "")
        if names:
            item.setForeground(QBrush(theme.qcolor("#FFFFFF")))
            item.setBackground(QBrush(theme.qcolor(theme.STATUS_COLORS[theme.ERROR])))
            font = QFont(item.font())
            font.setBold(True)
            item.setFont(font)
        else:
            item.setForeground(QBrush(theme.qcolor(theme.STATUS_COLORS[theme.IDLE])))
            item.setBackground(QBrush())
            item.setFont(QFont())

    def _set_toggle(self, servo_id: int, row: int, col: int, on: bool) -> None:
        pending = self._pending.get((servo_id, col))
        if pending is not None:
            asked, deadline = pending
            if on != asked and time.monotonic() < deadline:
                return
            del self._pending[(servo_id, col)]
        button = self.servo_table.cellWidget(row, col)
        unknown = (row, col) in self._unknown_toggles
        if isinstance(button, QPushButton) and (button.isChecked() != on or unknown):
            # Reflect the servo's real state without echoing a request back to it.
            button.blockSignals(True)
            button.setChecked(on)
            button.setText(button.property("text_on" if on else "text_off"))
            button.blockSignals(False)
            if unknown:
                self._unknown_toggles.discard((row, col))
                what = "torque" if col == COL_TORQUE else "LED"
                button.setToolTip(f"Servo {servo_id} {what}: shows the present state; click to switch it")

    def errors_text(self, servo_id: int) -> str:
        """The hardware-error cell of ``servo_id`` as shown."""
        return cell_item(self.servo_table, self._row_of_id[servo_id], COL_ERR).text()

    def cell_text(self, servo_id: int, column: int) -> str:
        return cell_item(self.servo_table, self._row_of_id[servo_id], column).text()

    def toggle(self, servo_id: int, column: int) -> QPushButton:
        """The torque (COL_TORQUE) or LED (COL_LED) button, or the Reboot button (COL_REBOOT), of a servo."""
        button = self.servo_table.cellWidget(self._row_of_id[servo_id], column)
        if not isinstance(button, QPushButton):
            raise LookupError(f"servo {servo_id} has no button in column {column}")
        return button

    # scan
    def set_scan_running(self, n_steps: int, text: str) -> None:
        self.scan_table.setRowCount(0)
        self.scan_button.setEnabled(False)
        self.scan_progress.setRange(0, max(n_steps, 1))
        self.scan_progress.setValue(0)
        self.scan_progress.setFormat(text)
        self.scan_progress.setVisible(True)
        self.scan_status_label.setText("")
        self.scan_status_label.setStyleSheet("")
        self.scan_status_label.setVisible(False)

    def set_scan_progress(self, done_steps: int, text: str) -> None:
        self.scan_progress.setValue(done_steps)
        self.scan_progress.setFormat(text)

    def add_scan_results(self, infos: Iterable[Any]) -> None:
        """ServoInfo-like items (servo_id, model_name, model_number, firmware, baud)."""
        table = self.scan_table
        for info in infos:
            row = table.rowCount()
            table.insertRow(row)
            table.setItem(row, 0, _item(str(info.servo_id)))
            table.setItem(row, 1, _item(f"{info.model_name} ({info.model_number})", align_right=False))
            table.setItem(row, 2, _item(f"v{info.firmware}"))
            table.setItem(row, 3, _item(str(info.baud)))

    def set_scan_finished(self, text: str, ok: bool = True) -> None:
        self.scan_button.setEnabled(True)
        self.scan_progress.setValue(self.scan_progress.maximum())
        self.scan_progress.setFormat("done" if ok else "stopped")
        self.scan_progress.setVisible(False)
        self.scan_status_label.setText(text)
        self.scan_status_label.setStyleSheet(theme.status_style(theme.OK if ok else theme.ERROR))
        self.scan_status_label.setVisible(bool(text))

    @property
    def scan_result_ids(self) -> list[int]:
        return [int(cell_item(self.scan_table, row, 0).text()) for row in range(self.scan_table.rowCount())]

    # link check
    def set_link_check_running(self) -> None:
        self.link_check_button.setEnabled(False)
        self.link_summary_label.setText("pinging…")
        self.link_summary_label.setStyleSheet("")

    def set_link_report(self, rows: Sequence[LinkCheckRow], rounds: int) -> None:
        table = self.link_table
        table.setRowCount(len(rows))
        for r, result in enumerate(rows):
            table.setItem(r, 0, _item(str(result.servo_id)))
            table.setItem(r, 1, _item("—" if result.rtt_mean_ms is None else f"{result.rtt_mean_ms:.2f}"))
            table.setItem(r, 2, _item("—" if result.rtt_max_ms is None else f"{result.rtt_max_ms:.2f}"))
            table.setItem(r, 3, _item(str(result.no_reply)))
            table.setItem(r, 4, _item(str(result.crc_errors)))
            verdict = "ok" if result.ok else "; ".join(
                [*(["no reply"] if result.no_reply else []), *(["CRC errors"] if result.crc_errors else []),
                 *result.other_errors])
            verdict_item = _item(verdict, align_right=False)
            if not result.ok:
                verdict_item.setForeground(QBrush(theme.qcolor(theme.STATUS_COLORS[theme.ERROR])))
            table.setItem(r, 5, verdict_item)
        answered = sum(1 for row in rows if row.rtt_mean_ms is not None)
        rtts = [row.rtt_mean_ms for row in rows if row.rtt_mean_ms is not None]
        no_reply = sum(row.no_reply for row in rows)
        crc = sum(row.crc_errors for row in rows)
        rtt_text = f", RTT mean {sum(rtts) / len(rtts):.2f} ms" if rtts else ""
        self.link_summary_label.setText(f"{answered}/{len(rows)} servos answered ({rounds} pings each)"
                                        f"{rtt_text}; {no_reply} no reply, {crc} CRC errors")
        ok = all(row.ok for row in rows) and bool(rows)
        self.link_summary_label.setStyleSheet(theme.status_style(theme.OK if ok else theme.ERROR))
        self.link_check_button.setEnabled(True)

    def set_link_check_failed(self, text: str) -> None:
        self.link_summary_label.setText(text)
        self.link_summary_label.setStyleSheet(theme.status_style(theme.ERROR))
        self.link_check_button.setEnabled(True)

    # timing
    def set_loop_stats(self, rate_hz: float, ticks: int, missed_ticks: int, period_p50_s: float,
                       period_p99_s: float, held_ticks: int = 0) -> None:
        """The control loop's timing since connect (periods in s). ``held_ticks``: slots skipped while the app held
        the bus on purpose (scan, reboot, link check): said apart, and not counted against the loop."""
        if ticks == 0:
            self.loop_label.setText("")
            return
        missed_fraction = missed_ticks / max(ticks + missed_ticks, 1)
        level = theme.OK if missed_fraction < 0.01 else theme.WARN if missed_fraction < 0.1 else theme.ERROR
        held = f"; {held_ticks} held on purpose" if held_ticks else ""
        _set_label(self.loop_label, f"Control loop {rate_hz:g} Hz: period p50 {period_p50_s * 1e3:.1f} ms, "
                   f"p99 {period_p99_s * 1e3:.1f} ms; {missed_ticks} of {ticks + missed_ticks} ticks missed{held}",
                   theme.status_style(level))
        self.loop_label.setToolTip(
            f"{held_ticks} control ticks were skipped while the app held the bus on purpose (a scan, a reboot, a "
            "link check); they are not counted as missed and say nothing about the control rate" if held_ticks
            else "Missed: control periods that went by without a tick (the bus or the computer too slow)")

    def clear_loop_stats(self) -> None:
        self.loop_label.setText("")
        self.loop_label.setStyleSheet("")

    def set_timing_warnings(self, warnings: Sequence[str], checked: bool = True, notes: Sequence[str] = ()) -> None:
        """``warnings``: problems a user can act on, each with its fix (counted, amber); ``notes``: findings said
        below them but not counted (e.g. the simulated lab's factory settings)."""
        if not checked:
            self.timing_summary_label.setText("Latency timer and return delay checks run on connect.")
            self.timing_summary_label.setStyleSheet("")
            self.timing_text.setPlainText("")
            return
        if warnings:
            n = len(warnings)
            self.timing_summary_label.setText(f"{n} timing warning{'' if n == 1 else 's'}, each with its fix:")
            self.timing_summary_label.setStyleSheet(theme.status_style(theme.WARN))
            lines = [f"• {w}" for w in warnings]
        else:
            self.timing_summary_label.setText("No timing problems found.")
            self.timing_summary_label.setStyleSheet(theme.status_style(theme.OK))
            lines = [] if notes else ["Latency timer and return delay time are fine for the control rate."]
        self.timing_text.setPlainText("\n\n".join([*lines, *(f"Note: {n}" for n in notes)]))
