"""EventLogView: the event log as a table — filter by kind, search, copy, save — with the selected entry's whole text.

A passive view (widgets import neither devices nor app): it shows the entries it is given (objects with ``number``,
``kind``, ``source``, ``text``, ``recording_time_s``, ``time_text()`` and ``line()``, as
:class:`app.core.event_log.LogEntry`) and emits :attr:`EventLogView.save_requested` with the entries shown; the app
writes the file. Rows are added as they come (no per-row widgets: one model, one proxy that filters). GUI thread only.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, Protocol

from PySide6.QtCore import (
    QAbstractTableModel,
    QItemSelectionModel,
    QModelIndex,
    QPersistentModelIndex,
    QSortFilterProxyModel,
    Qt,
    Signal,
)
from PySide6.QtGui import QBrush, QGuiApplication, QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QPushButton,
    QSizePolicy,
    QSplitter,
    QTableView,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from widgets import theme

COLUMNS = ("#", "Time", "Kind", "Source", "Message")
COL_NUMBER, COL_TIME, COL_KIND, COL_SOURCE, COL_TEXT = range(len(COLUMNS))
KIND_LEVELS = {"info": theme.IDLE, "warning": theme.WARN, "fault": theme.ERROR, "action": theme.OK,
               "recorded": theme.IDLE}
MESSAGE_PREVIEW_CHARS = 300  # the table cell shows this much of a long message; the detail pane shows all of it

ModelIndex = QModelIndex | QPersistentModelIndex


class Entry(Protocol):
    """What the view reads of a log entry."""

    number: int
    kind: str
    source: str
    text: str
    recording_time_s: float | None

    def time_text(self, with_date: bool = False) -> str: ...

    def line(self) -> str: ...


class EntryModel(QAbstractTableModel):
    """The entries, oldest first, as a table model."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.entries: list[Any] = []
        self._brushes = {kind: QBrush(theme.qcolor(theme.STATUS_COLORS[level]))
                         for kind, level in KIND_LEVELS.items()}

    def rowCount(self, parent: ModelIndex = QModelIndex()) -> int:  # noqa: N802, B008 - Qt's name and default
        return 0 if parent.isValid() else len(self.entries)

    def columnCount(self, parent: ModelIndex = QModelIndex()) -> int:  # noqa: N802, B008 - Qt's name and default
        return 0 if parent.isValid() else len(COLUMNS)

    def headerData(self, section: int, orientation: Qt.Orientation,  # noqa: N802 - Qt's name
                   role: int = Qt.ItemDataRole.DisplayRole) -> Any:
        if orientation == Qt.Orientation.Horizontal and role == Qt.ItemDataRole.DisplayRole:
            return COLUMNS[section]
        return None

    def data(self, index: ModelIndex, role: int = Qt.ItemDataRole.DisplayRole) -> Any:
        if not index.isValid():
            return None
        entry = self.entries[index.row()]
        column = index.column()
        if role == Qt.ItemDataRole.DisplayRole:
            if column == COL_NUMBER:
                return entry.number
            if column == COL_TIME:
                return entry.time_text()
            if column == COL_KIND:
                return entry.kind
            if column == COL_SOURCE:
                at = entry.recording_time_s
                return entry.source if at is None else f"{entry.source} t={at:.2f} s"
            one_line = " ".join(entry.text.split())
            return one_line if len(one_line) <= MESSAGE_PREVIEW_CHARS else one_line[:MESSAGE_PREVIEW_CHARS] + "…"
        if role == Qt.ItemDataRole.ToolTipRole and column == COL_TEXT:
            return entry.text
        if role == Qt.ItemDataRole.ForegroundRole and column in (COL_KIND, COL_TEXT):
            return self._brushes.get(entry.kind)
        return None

    def append(self, entries: Sequence[Any]) -> None:
        if not entries:
            return
        first = len(self.entries)
        self.beginInsertRows(QModelIndex(), first, first + len(entries) - 1)
        self.entries.extend(entries)
        self.endInsertRows()

    def reset(self, entries: Iterable[Any]) -> None:
        self.beginResetModel()
        self.entries = list(entries)
        self.endResetModel()


class KindSearchFilter(QSortFilterProxyModel):
    """Rows whose kind is ticked and whose message, source or time holds the search text (any case)."""

    def __init__(self, kinds: Iterable[str], parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.kinds = set(kinds)
        self.search = ""

    def set_filter(self, kinds: Iterable[str], search: str) -> None:
        # Qt 6.10 brought begin/endFilterChange and deprecated invalidateRowsFilter; the project supports 6.5 on.
        begin = getattr(self, "beginFilterChange", None)
        if begin is not None:
            begin()
        self.kinds = set(kinds)
        self.search = search.strip().lower()
        if begin is not None:
            self.endFilterChange(QSortFilterProxyModel.Direction.Rows)
        else:
            self.invalidateRowsFilter()

    def filterAcceptsRow(self, source_row: int, source_parent: ModelIndex) -> bool:  # noqa: N802 - Qt's name
        model = self.sourceModel()
        assert isinstance(model, EntryModel)
        entry = model.entries[source_row]
        if entry.kind not in self.kinds:
            return False
        needle = self.search
        return (not needle or needle in entry.text.lower() or needle in entry.source.lower()
                or needle in entry.time_text())


class EventLogView(QWidget):
    """See the module docstring."""

    save_requested = Signal(object)  # list of the entries shown (filtered), oldest first

    def __init__(self, kinds: Sequence[str] = tuple(KIND_LEVELS), parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.kinds = tuple(kinds)
        self.model = EntryModel(self)
        self.proxy = KindSearchFilter(self.kinds, self)
        self.proxy.setSourceModel(self.model)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        bar = QHBoxLayout()
        bar.addWidget(QLabel("Show"))
        self.kind_buttons: dict[str, QToolButton] = {}
        for kind in self.kinds:
            button = QToolButton()
            button.setText(kind)
            button.setCheckable(True)
            button.setChecked(True)
            button.setToolTip(f"show the {kind} entries")
            button.setStyleSheet(f"QToolButton:checked {{ color: {theme.STATUS_COLORS[KIND_LEVELS.get(kind, theme.IDLE)]};"
                                 " font-weight: bold; }")
            button.toggled.connect(lambda _on: self._apply_filter())
            self.kind_buttons[kind] = button
            bar.addWidget(button)
        self.search = QLineEdit()
        self.search.setPlaceholderText("Search messages, sources, times…")
        self.search.setClearButtonEnabled(True)
        self.search.textChanged.connect(lambda _t: self._apply_filter())
        bar.addWidget(self.search, 1)
        self.shown_label = QLabel("")
        bar.addWidget(self.shown_label)
        self.copy_button = QPushButton("Copy")
        self.copy_button.setToolTip("Copy the selected entries (or the entry shown below) to the clipboard, one "
                                    "tab-separated line each (Ctrl+C)")
        self.copy_button.clicked.connect(self.copy_selected)
        bar.addWidget(self.copy_button)
        self.save_button = QPushButton("Save CSV…")
        self.save_button.setToolTip("Save the entries shown (filter and search applied) as CSV, to a new file")
        self.save_button.clicked.connect(lambda: self.save_requested.emit(self.visible_entries()))
        bar.addWidget(self.save_button)
        layout.addLayout(bar)

        splitter = QSplitter(Qt.Orientation.Vertical)
        self.table = QTableView()
        self.table.setModel(self.proxy)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.verticalHeader().setVisible(False)
        self.table.verticalHeader().setDefaultSectionSize(20)
        self.table.setWordWrap(False)
        header = self.table.horizontalHeader()
        for column in (COL_NUMBER, COL_TIME, COL_KIND, COL_SOURCE):
            header.setSectionResizeMode(column, QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(COL_TEXT, QHeaderView.ResizeMode.Stretch)
        self.table.selectionModel().currentRowChanged.connect(lambda current, _previous: self._show_detail(current))
        splitter.addWidget(self.table)
        self.detail = QPlainTextEdit()
        self.detail.setReadOnly(True)
        self.detail.setPlaceholderText("Select an entry: its whole message shows here (select and copy any part).")
        # A short dock (a small window) keeps most of its height for the list: the detail pane's own size hint
        # (several lines of an empty editor) would otherwise take more than the rows.
        self.detail.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Ignored)
        self.detail.setMinimumHeight(36)
        splitter.addWidget(self.detail)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([300, 80])
        layout.addWidget(splitter, 1)
        copy = QShortcut(QKeySequence.StandardKey.Copy, self.table)
        copy.setContext(Qt.ShortcutContext.WidgetShortcut)
        copy.activated.connect(self.copy_selected)
        self._follow = True  # keep the newest row in view while the user has not scrolled up
        self._update_count()

    # -- what it shows ---------------------------------------------------------------------------------------------
    def append(self, entries: Sequence[Any]) -> None:
        """New entries (newer than every entry shown)."""
        bar = self.table.verticalScrollBar()
        at_bottom = bar.value() >= bar.maximum() - 2
        self.model.append(entries)
        self._update_count()
        if at_bottom and self._follow:
            self.table.scrollToBottom()

    def reset(self, entries: Iterable[Any]) -> None:
        """Show exactly ``entries`` (oldest first), e.g. after the oldest were dropped or a recording re-read."""
        shown = self.selected_entry()
        self.model.reset(entries)
        self._update_count()
        if shown is not None:
            self.select_number(shown.number, scroll=False)
        self.table.scrollToBottom()

    def set_kind_visible(self, kind: str, visible: bool) -> None:
        self.kind_buttons[kind].setChecked(visible)

    def set_search(self, text: str) -> None:
        self.search.setText(text)

    def _apply_filter(self) -> None:
        self.proxy.set_filter([k for k, b in self.kind_buttons.items() if b.isChecked()], self.search.text())
        self._update_count()

    def _update_count(self) -> None:
        total = self.model.rowCount()
        shown = self.proxy.rowCount()
        self.shown_label.setText(f"{shown} of {total}" if shown != total else f"{total} entries")

    # -- selection and the detail pane ------------------------------------------------------------------------------
    def visible_entries(self) -> list[Any]:
        """The entries the filter and search let through, oldest first."""
        return [self.model.entries[self.proxy.mapToSource(self.proxy.index(r, 0)).row()]
                for r in range(self.proxy.rowCount())]

    def selected_entries(self) -> list[Any]:
        rows = sorted({self.proxy.mapToSource(index).row() for index in self.table.selectionModel().selectedRows()})
        return [self.model.entries[r] for r in rows]

    def selected_entry(self) -> Any | None:
        current = self.table.selectionModel().currentIndex()
        if not current.isValid():
            return None
        return self.model.entries[self.proxy.mapToSource(current).row()]

    def select_number(self, number: int, scroll: bool = True) -> bool:
        """Select the entry numbered ``number`` (making its kind visible and clearing a search that hides it) and
        show its whole text below; False if it is not in the log."""
        row = next((k for k, e in enumerate(self.model.entries) if e.number == number), None)
        if row is None:
            return False
        entry = self.model.entries[row]
        if not self.kind_buttons.get(entry.kind, self.copy_button).isChecked() and entry.kind in self.kind_buttons:
            self.kind_buttons[entry.kind].setChecked(True)
        index = self.proxy.mapFromSource(self.model.index(row, 0))
        if not index.isValid():
            self.search.clear()
            index = self.proxy.mapFromSource(self.model.index(row, 0))
        self.table.selectionModel().setCurrentIndex(
            index, QItemSelectionModel.SelectionFlag.ClearAndSelect | QItemSelectionModel.SelectionFlag.Rows)
        if scroll:
            self.table.scrollTo(index, QAbstractItemView.ScrollHint.PositionAtCenter)
        self._show_detail(index)
        return True

    def _show_detail(self, index: ModelIndex) -> None:
        if not index.isValid():
            self.detail.setPlainText("")
            return
        entry = self.model.entries[self.proxy.mapToSource(index).row()]
        at = f" · t = {entry.recording_time_s:.3f} s in the recording" if entry.recording_time_s is not None else ""
        self.detail.setPlainText(f"{entry.time_text(with_date=True)} · {entry.kind} · {entry.source}{at}\n\n"
                                 f"{entry.text}")

    @property
    def detail_text(self) -> str:
        return self.detail.toPlainText()

    def copy_selected(self) -> str:
        """Put the selected entries on the clipboard, one line each; returns the text."""
        entries = self.selected_entries()
        if not entries:
            current = self.selected_entry()
            entries = [current] if current is not None else []
        text = "\n".join(entry.line() for entry in entries)
        if text:
            QGuiApplication.clipboard().setText(text)
        return text
