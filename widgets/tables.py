"""Small helpers for QTableWidget cells that the panels fill once and update in place. GUI thread only."""

from __future__ import annotations

from PySide6.QtWidgets import QTableWidget, QTableWidgetItem


def cell_item(table: QTableWidget, row: int, column: int) -> QTableWidgetItem:
    """The item at (row, column). The panels create every cell's item when they build a row, so a missing one is a
    programming error: LookupError naming the cell (rather than an AttributeError on None later)."""
    item = table.item(row, column)
    if item is None:
        raise LookupError(f"{table.objectName() or 'table'} has no item at row {row}, column {column}")
    return item
