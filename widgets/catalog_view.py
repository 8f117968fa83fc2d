"""The run catalog's browser (File ▸ Open recording…): every catalogued recording in a table, filtered by scene,
controller, plan, series, outcome and date, opened in the 3-D replay or overlaid in the Forces tab.

A passive dialog: it shows the rows and the filter choices it is given (:meth:`CatalogView.set_rows`,
:meth:`CatalogView.set_choices`) and emits what the user asks for; the catalog is read by app/gui/catalog_browser.py
off the GUI thread. Double-click (or Enter) opens a recording in the 3-D replay; "Select the series" selects every
trial of the selected recording's series, for "Overlay in Forces". GUI thread only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import PurePath
from typing import Any

from PySide6.QtCore import QDate, Qt, Signal
from PySide6.QtGui import QKeyEvent
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QDateEdit,
    QDialog,
    QGridLayout,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

ANY = "any"
# (catalog column, title) of each filter, and of each column shown.
FILTERS: tuple[tuple[str, str], ...] = (("scene", "Scene"), ("controller", "Controller"), ("plan_name", "Plan"),
                                        ("series_uid", "Series"), ("outcome", "Outcome"))
COLUMNS: tuple[tuple[str, str], ...] = (("started", "Started"), ("file", "File"), ("plan_name", "Plan"),
                                        ("scene", "Scene"), ("controller", "Controller"), ("series_uid", "Series"),
                                        ("trial", "Trial"), ("outcome", "Outcome"), ("exit_status", "Status"),
                                        ("duration_s", "Duration s"), ("note", "Note"))
PATH_ROLE = Qt.ItemDataRole.UserRole
SERIES_ROLE = Qt.ItemDataRole.UserRole + 1


def _cell(key: str, row: Mapping[str, Any]) -> str:
    if key == "file":
        return PurePath(str(row.get("path", ""))).name
    value = row.get(key)
    if value is None:
        return ""
    if key == "series_uid":
        return str(value)[:8]
    if key == "trial":
        return str(int(value) + 1)
    if key == "duration_s":
        return f"{float(value):.1f}"
    if key == "started":
        return str(value)[:19].replace("T", " ")
    return str(value)


class CatalogView(QDialog):
    """See the module docstring."""

    filters_changed = Signal(object)  # dict: the ``runs list --where`` pairs and ``since`` (ISO date or None)
    refresh_requested = Signal()
    open_requested = Signal(str)  # a recording's path: into the 3-D replay
    overlay_requested = Signal(object)  # list of paths: into the Forces tab's trial overlay

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Open recording — the run catalog")
        self.resize(1100, 560)
        layout = QVBoxLayout(self)
        grid = QGridLayout()
        self.filter_combos: dict[str, QComboBox] = {}
        for i, (key, title) in enumerate(FILTERS):
            combo = QComboBox()
            combo.addItem(ANY, None)
            combo.setObjectName(f"filter_{key}")
            combo.setMinimumContentsLength(10)
            combo.currentIndexChanged.connect(lambda _i: self._emit_filters())
            grid.addWidget(QLabel(title), 0, i)
            grid.addWidget(combo, 1, i)
            self.filter_combos[key] = combo
        self.since_check = QCheckBox("Since")
        self.since_edit = QDateEdit(QDate.currentDate().addDays(-7))
        self.since_edit.setCalendarPopup(True)
        self.since_edit.setDisplayFormat("yyyy-MM-dd")
        self.since_edit.setEnabled(False)
        self.since_check.toggled.connect(self.since_edit.setEnabled)
        self.since_check.toggled.connect(lambda _on: self._emit_filters())
        self.since_edit.dateChanged.connect(lambda _d: self._emit_filters() if self.since_check.isChecked() else None)
        grid.addWidget(self.since_check, 0, len(FILTERS))
        grid.addWidget(self.since_edit, 1, len(FILTERS))
        layout.addLayout(grid)

        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setObjectName("catalog_table")
        self.table.setHorizontalHeaderLabels([title for _key, title in COLUMNS])
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.table.verticalHeader().setVisible(False)
        self.table.horizontalHeader().setSectionResizeMode(len(COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)
        self.table.itemDoubleClicked.connect(lambda _item: self._open_selected())
        self.table.itemSelectionChanged.connect(self._selection_changed)
        layout.addWidget(self.table, 1)
        self.status_label = QLabel("reading the catalog…")
        self.status_label.setWordWrap(True)
        layout.addWidget(self.status_label)

        buttons = QHBoxLayout()
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.setToolTip("Read again every recording that is new or changed in the recordings folder")
        self.refresh_button.clicked.connect(self.refresh_requested)
        buttons.addWidget(self.refresh_button)
        self.series_button = QPushButton("Select the series")
        self.series_button.setToolTip("Select every trial of the selected recording's series")
        self.series_button.clicked.connect(self.select_series)
        buttons.addWidget(self.series_button)
        buttons.addStretch(1)
        self.overlay_button = QPushButton("Overlay in Forces")
        self.overlay_button.setToolTip("The selected recordings in the Forces tab's trial overlay")
        self.overlay_button.clicked.connect(lambda: self.overlay_requested.emit(self.selected_paths()))
        buttons.addWidget(self.overlay_button)
        self.open_button = QPushButton("Open in 3-D replay")
        self.open_button.setDefault(True)
        self.open_button.clicked.connect(self._open_selected)
        buttons.addWidget(self.open_button)
        self.close_button = QPushButton("Close")
        self.close_button.clicked.connect(self.close)
        buttons.addWidget(self.close_button)
        layout.addLayout(buttons)
        self._selection_changed()

    # -- what the face shows ----------------------------------------------------------------------------------------
    def set_choices(self, choices: Mapping[str, Sequence[str]]) -> None:
        """The values each filter offers (``any`` first); the current choice is kept where it still exists."""
        for key, combo in self.filter_combos.items():
            current = combo.currentData()
            combo.blockSignals(True)
            combo.clear()
            combo.addItem(ANY, None)
            for value in choices.get(key, ()):
                combo.addItem(str(value)[:8] + "…" if key == "series_uid" else str(value), str(value))
            index = combo.findData(current) if current is not None else 0
            combo.setCurrentIndex(max(index, 0))
            combo.blockSignals(False)

    def set_rows(self, rows: Sequence[Mapping[str, Any]], total: int | None = None) -> None:
        """The recordings to list (newest last, as the catalog gives them); ``total``: how many matched, when more
        than are shown."""
        self.table.setSortingEnabled(False)
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for c, (key, _title) in enumerate(COLUMNS):
                item = QTableWidgetItem(_cell(key, row))
                item.setData(PATH_ROLE, str(row.get("path", "")))
                item.setData(SERIES_ROLE, row.get("series_uid") or "")
                if key == "outcome" and row.get("outcome"):
                    level = {"traversed": theme.OK, "failed": theme.WARN, "not traversed": theme.WARN,
                             "aborted": theme.ERROR, "invalid": theme.ERROR}.get(str(row["outcome"]))
                    if level is not None:
                        item.setForeground(theme.qcolor(theme.STATUS_COLORS[level]))
                if row.get("problem"):
                    item.setToolTip(str(row["problem"]))
                self.table.setItem(r, c, item)
        self.table.resizeColumnsToContents()
        self.table.horizontalHeader().setSectionResizeMode(len(COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)
        if rows:
            self.table.scrollToBottom()
        shown = f"{len(rows)} recordings" if total is None or total <= len(rows) else \
            f"the newest {len(rows)} of {total} recordings (narrow the filters to see the others)"
        self.set_status(shown)
        self._selection_changed()

    def set_status(self, text: str, level: str = theme.IDLE) -> None:
        self.status_label.setText(text)
        self.status_label.setStyleSheet(theme.status_style(level) if level != theme.IDLE else "")

    def filters(self) -> dict[str, Any]:
        """``{"where": ["scene=paper_obstacle", …], "since": "2026-12-01" or None}``."""
        where = [f"{key}={combo.currentData()}" for key, combo in self.filter_combos.items()
                 if combo.currentData() is not None]
        since = self.since_edit.date().toString("yyyy-MM-dd") if self.since_check.isChecked() else None
        return {"where": where, "since": since}

    def selected_paths(self) -> list[str]:
        rows = sorted({index.row() for index in self.table.selectedIndexes()})
        paths = []
        for r in rows:
            item = self.table.item(r, 0)
            if item is not None:
                paths.append(str(item.data(PATH_ROLE)))
        return paths

    def select_series(self) -> None:
        """Select every listed trial of the selected recording's series."""
        rows = sorted({index.row() for index in self.table.selectedIndexes()})
        if not rows:
            return
        first = self.table.item(rows[0], 0)
        series = first.data(SERIES_ROLE) if first is not None else ""
        if not series:
            self.set_status("the selected recording is not part of a series", theme.WARN)
            return
        self.table.clearSelection()
        mode = self.table.selectionMode()
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.MultiSelection)
        for r in range(self.table.rowCount()):
            item = self.table.item(r, 0)
            if item is not None and item.data(SERIES_ROLE) == series:
                self.table.selectRow(r)
        self.table.setSelectionMode(mode)

    # -- requests -----------------------------------------------------------------------------------------------------
    def _emit_filters(self) -> None:
        self.filters_changed.emit(self.filters())

    def _open_selected(self) -> None:
        paths = self.selected_paths()
        if paths:
            self.open_requested.emit(paths[0])

    def _selection_changed(self) -> None:
        count = len(self.selected_paths())
        self.open_button.setEnabled(count == 1)
        self.overlay_button.setEnabled(count >= 1)
        self.series_button.setEnabled(count >= 1)

    def keyPressEvent(self, event: QKeyEvent) -> None:  # noqa: N802 - Qt override
        """Enter opens the selected recording (Esc closes the dialog, as every dialog's)."""
        if event.key() in (Qt.Key.Key_Return, Qt.Key.Key_Enter) and len(self.selected_paths()) == 1:
            self._open_selected()
            return
        super().keyPressEvent(event)
