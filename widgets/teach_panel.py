"""TeachPanel: the Teach tab's view — posing controls, keyframe list, joint editor, shape library, body drawing.

Passive: the owner (``app/gui/tabs/teach.py``) feeds it the live angles, the keyframe list and the library names, and
reacts to its signals. Nothing here talks to the robot or the disk. Angles in rad, times in s. GUI thread only.
Buttons that cannot work are disabled with a tooltip saying what they need (a name, a keyframe, a saved shape);
Ctrl+Enter captures (a person posing the robot has one hand free at best), while the panel is on screen.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QAbstractItemView,
    QComboBox,
    QDoubleSpinBox,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QPushButton,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from widgets import theme
from widgets.body_view import BodyView
from widgets.joint_sliders import JointSliders

CAPTURE_SHORTCUTS = ("Ctrl+Return", "Ctrl+Enter")  # main and keypad Enter
UNDO_SHORTCUTS = ("Ctrl+Z",)
REDO_SHORTCUTS = ("Ctrl+Shift+Z", "Ctrl+Y")


def joints_text(ids: Sequence[int]) -> str:
    """``joint 3`` or ``joints 3, 5``: servo IDs as a person reads them."""
    return f"joint {ids[0]}" if len(ids) == 1 else "joints " + ", ".join(str(i) for i in ids)


class TeachPanel(QWidget):
    # posing
    torque_off_requested = Signal(object)  # list of servo IDs, or None for all
    hold_requested = Signal(object)  # list of servo IDs, or None for all
    capture_requested = Signal()
    pose_angle_requested = Signal(int, float)  # joint index, rad (sliders or dragging the drawing)
    # keyframe list
    keyframe_selected = Signal(int)
    move_requested = Signal(int, int)  # row, +1 / −1
    delete_requested = Signal(int)
    rename_requested = Signal(int, str)
    time_edited = Signal(int, float)
    angle_edited = Signal(int, int, float)  # row, joint index, rad
    undo_requested = Signal()
    redo_requested = Signal()
    clear_requested = Signal()
    # shape library and transforms
    save_requested = Signal(str)
    load_requested = Signal(str)
    mirror_requested = Signal()
    scale_requested = Signal(float)
    shift_requested = Signal(int)

    def __init__(self, joint_ids: Sequence[int], axes: Sequence[str], min_rad: Sequence[float],
                 max_rad: Sequence[float], segment_length_m: float = 0.08, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._ids = tuple(joint_ids)
        self._axes = tuple(axes)
        self._filling = False

        # -- posing column ---------------------------------------------------------------------------------------
        pose_box = QGroupBox("Pose by hand")
        pose_layout = QVBoxLayout(pose_box)
        hint = QLabel("Turn torque off, bend the robot (in sim: drag the drawing or the sliders), then capture "
                      "(Ctrl+Enter).")
        hint.setWordWrap(True)
        hint.setStyleSheet("color: #555;")
        pose_layout.addWidget(hint)
        self.sliders = JointSliders(joint_ids, axes, min_rad, max_rad, selectable=True)
        pose_layout.addWidget(self.sliders)
        torque_row = QGridLayout()
        self.torque_off_selected_button = QPushButton("Torque off: selected")
        self.torque_off_all_button = QPushButton("Torque off: all")
        self.hold_button = QPushButton("Torque on (hold pose)")
        self.capture_button = QPushButton("Capture pose")
        self.capture_button.setStyleSheet("font-weight: bold;")
        self.torque_off_selected_button.setToolTip("Torque off for the joints ticked beside the sliders; the others "
                                                   "keep holding")
        self.torque_off_all_button.setToolTip("Torque off for every joint: the robot goes limp, support it first")
        self.hold_button.setToolTip("Torque back on for every joint, holding the present pose")
        self.capture_button.setToolTip("Add the present pose to the keyframe list (Ctrl+Enter)")
        torque_row.addWidget(self.torque_off_selected_button, 0, 0)
        torque_row.addWidget(self.torque_off_all_button, 0, 1)
        torque_row.addWidget(self.hold_button, 1, 0)
        torque_row.addWidget(self.capture_button, 1, 1)
        pose_layout.addLayout(torque_row)
        self.torque_label = QLabel("torque: unknown")
        self.torque_label.setWordWrap(True)  # the longest state must not be cut at the minimum window width
        pose_layout.addWidget(self.torque_label)
        pose_layout.addStretch(1)

        # -- keyframes column ------------------------------------------------------------------------------------
        frames_box = QGroupBox("Keyframes")
        frames_layout = QVBoxLayout(frames_box)
        self.keyframe_table = QTableWidget(0, 2)
        self.keyframe_table.setHorizontalHeaderLabels(["name", "t (s)"])
        self.keyframe_table.horizontalHeader().setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        self.keyframe_table.horizontalHeader().setSectionResizeMode(1, QHeaderView.ResizeMode.ResizeToContents)
        self.keyframe_table.verticalHeader().setVisible(True)
        self.keyframe_table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.keyframe_table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.keyframe_table.setMinimumHeight(130)
        self.keyframe_table.setToolTip("Double-click a name to rename it, or a time (s) to change when the pose "
                                       "is reached in keyframe playback")
        frames_layout.addWidget(self.keyframe_table, 2)
        list_buttons = QHBoxLayout()
        self.up_button = QPushButton("▲")
        self.down_button = QPushButton("▼")
        self.delete_button = QPushButton("Delete")
        self.undo_button = QPushButton("Undo")
        self.redo_button = QPushButton("Redo")
        self.clear_button = QPushButton("Clear")
        for b in (self.up_button, self.down_button):
            b.setFixedWidth(34)
        self.up_button.setToolTip("Move the selected keyframe one place earlier (the times stay in their slots)")
        self.down_button.setToolTip("Move the selected keyframe one place later (the times stay in their slots)")
        self.delete_button.setToolTip("Delete the selected keyframe (Undo brings it back)")
        self.clear_button.setToolTip("Delete every keyframe (Undo brings them back)")
        for b in (self.up_button, self.down_button, self.delete_button, self.clear_button, self.undo_button,
                  self.redo_button):
            list_buttons.addWidget(b)
        frames_layout.addLayout(list_buttons)
        frames_layout.addWidget(QLabel("Selected keyframe, joint angles (edit to correct):"))
        self.joint_table = QTableWidget(len(joint_ids), 3)
        self.joint_table.setHorizontalHeaderLabels(["axis", "rad", "deg"])
        self.joint_table.setVerticalHeaderLabels([f"J{i}" for i in joint_ids])
        self.joint_table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.joint_table.verticalHeader().setDefaultSectionSize(20)
        self.joint_table.setMinimumHeight(200)
        self.joint_table.setToolTip("Double-click a value in the rad column to correct that joint of the selected "
                                    "keyframe")
        frames_layout.addWidget(self.joint_table, 3)

        library_box = QGroupBox("Shape library")
        lib = QGridLayout(library_box)
        self.name_edit = QLineEdit()
        self.name_edit.setPlaceholderText("shape name, e.g. conform-obstacle")
        self.name_edit.setToolTip("Name of the shape in the library (also its file name)")
        self.save_button = QPushButton("Save")
        self.library_combo = QComboBox()
        self.library_combo.setMinimumContentsLength(14)
        self.library_combo.setToolTip("Shapes saved in the library")
        self.load_button = QPushButton("Load")
        self.mirror_button = QPushButton("Mirror L↔R")
        self.mirror_button.setToolTip("Swap left and right in every keyframe: yaw angles change sign, pitch angles "
                                      "stay")
        self.scale_spin = QDoubleSpinBox()
        self.scale_spin.setRange(-3.0, 3.0)
        self.scale_spin.setSingleStep(0.1)
        self.scale_spin.setValue(1.2)
        self.scale_spin.setPrefix("× ")
        self.scale_button = QPushButton("Scale")
        self.scale_button.setToolTip("Multiply every angle of every keyframe by the factor beside it (refused if a "
                                     "joint would leave its limits)")
        self.shift_spin = QSpinBox()
        self.shift_spin.setRange(-11, 11)
        self.shift_spin.setValue(1)
        self.shift_spin.setSuffix(" joint(s)")
        self.shift_button = QPushButton("Shift to tail")
        self.shift_button.setToolTip("Slide every keyframe along the body by this many joints of each axis "
                                     "(positive: toward the tail, negative: toward the head); uncovered joints "
                                     "become straight")
        lib.addWidget(self.name_edit, 0, 0, 1, 2)
        lib.addWidget(self.save_button, 0, 2)
        lib.addWidget(self.library_combo, 1, 0, 1, 2)
        lib.addWidget(self.load_button, 1, 2)
        lib.addWidget(self.mirror_button, 2, 0)
        lib.addWidget(self.scale_spin, 2, 1)
        lib.addWidget(self.scale_button, 2, 2)
        shift_label = QLabel("slide by")
        shift_label.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        lib.addWidget(shift_label, 3, 0)
        lib.addWidget(self.shift_spin, 3, 1)
        lib.addWidget(self.shift_button, 3, 2)
        self.library_path_label = QLabel("")
        self.library_path_label.setStyleSheet("color: #666; font-size: 8pt;")
        self.library_path_label.setWordWrap(True)
        lib.addWidget(self.library_path_label, 4, 0, 1, 3)

        middle = QWidget()
        middle_layout = QVBoxLayout(middle)
        middle_layout.setContentsMargins(0, 0, 0, 0)
        middle_layout.addWidget(frames_box, 1)
        middle_layout.addWidget(library_box)

        # -- drawing column --------------------------------------------------------------------------------------
        self.body_view = BodyView(axes, segment_length_m)
        self.body_view.setMinimumWidth(300)  # at the 960 px minimum window width it is not cut off
        self.status_label = QLabel("")
        self.status_label.setWordWrap(True)
        right = QWidget()
        right_layout = QVBoxLayout(right)
        right_layout.setContentsMargins(0, 0, 0, 0)
        right_layout.addWidget(self.body_view, 1)
        legend = QLabel(f"<span style='color:{theme.PRESENT_COLOR}'>━ present pose</span> &nbsp; "
                        f"<span style='color:{theme.GOAL_COLOR}'>╌ selected keyframe</span>")
        legend.setToolTip("Ringed joints have torque off; in the simulated lab, drag one in either view to bend it")
        right_layout.addWidget(legend)
        right_layout.addWidget(self.status_label)

        splitter = QSplitter(Qt.Orientation.Horizontal)
        splitter.addWidget(pose_box)
        splitter.addWidget(middle)
        splitter.addWidget(right)
        splitter.setStretchFactor(0, 0)
        splitter.setStretchFactor(1, 0)
        splitter.setStretchFactor(2, 1)
        splitter.setSizes([400, 330, 520])
        outer = QVBoxLayout(self)
        outer.setContentsMargins(6, 6, 6, 6)
        outer.addWidget(splitter)

        # -- wiring ----------------------------------------------------------------------------------------------
        self.torque_off_selected_button.clicked.connect(self._torque_off_selected)
        self.torque_off_all_button.clicked.connect(lambda: self.torque_off_requested.emit(None))
        self.hold_button.clicked.connect(lambda: self.hold_requested.emit(None))
        self.capture_button.clicked.connect(self.capture_requested)
        self.sliders.angle_changed.connect(self.pose_angle_requested)
        self.body_view.joint_dragged.connect(self.pose_angle_requested)
        self.keyframe_table.itemSelectionChanged.connect(self._row_selected)
        self.keyframe_table.itemChanged.connect(self._keyframe_item_changed)
        self.joint_table.itemChanged.connect(self._joint_item_changed)
        self.up_button.clicked.connect(lambda: self._move(-1))
        self.down_button.clicked.connect(lambda: self._move(+1))
        self.delete_button.clicked.connect(self._delete)
        self.undo_button.clicked.connect(self.undo_requested)
        self.redo_button.clicked.connect(self.redo_requested)
        self.clear_button.clicked.connect(self.clear_requested)
        self.save_button.clicked.connect(lambda: self.save_requested.emit(self.name_edit.text().strip()))
        self.load_button.clicked.connect(lambda: self.load_requested.emit(self.library_combo.currentText()))
        self.mirror_button.clicked.connect(self.mirror_requested)
        self.scale_button.clicked.connect(lambda: self.scale_requested.emit(self.scale_spin.value()))
        self.shift_button.clicked.connect(lambda: self.shift_requested.emit(self.shift_spin.value()))
        self.name_edit.textChanged.connect(lambda _text: self._update_library_buttons())
        self.capture_shortcuts = []
        for keys in CAPTURE_SHORTCUTS:
            # Application-wide so it works whatever has focus, but only while this panel is visible (Qt ignores
            # shortcuts of hidden widgets) and not while a modal dialog is up. click() does nothing when disabled.
            shortcut = QShortcut(QKeySequence(keys), self)
            shortcut.setContext(Qt.ShortcutContext.ApplicationShortcut)
            shortcut.activated.connect(self.capture_button.click)
            self.capture_shortcuts.append(shortcut)
        # Undo / redo of keyframe edits, the same way; a text field with the focus (name, spin box) keeps its own
        # Ctrl+Z (Qt offers the key to the focused editor first).
        self.undo_shortcuts = []
        for keys, button in [(k, self.undo_button) for k in UNDO_SHORTCUTS] + [(k, self.redo_button)
                                                                               for k in REDO_SHORTCUTS]:
            shortcut = QShortcut(QKeySequence(keys), self)
            shortcut.setContext(Qt.ShortcutContext.ApplicationShortcut)
            shortcut.activated.connect(button.click)
            self.undo_shortcuts.append(shortcut)
        self._has_keyframes = False
        self.set_keyframe_angles(None)
        self._update_library_buttons()

    # -- display API -------------------------------------------------------------------------------------------------
    def set_live_angles(self, present_rad: np.ndarray | None, goal_rad: np.ndarray | None = None) -> None:
        if present_rad is None:
            return
        self.sliders.set_angles(present_rad)
        self.body_view.set_angles(present_rad, goal_rad)

    def set_limp(self, limp: Sequence[bool], posable: bool) -> None:
        """Which joints have torque off; ``posable`` = the drawing and sliders may move them (simulated robot)."""
        limp = [bool(x) for x in limp]
        self.body_view.set_highlighted_joints([i for i, x in enumerate(limp) if x])
        self.body_view.set_drag_enabled(posable and any(limp))
        self.sliders.set_editable([posable and x for x in limp])
        n_limp = sum(limp)
        if n_limp == 0:
            self.torque_label.setText("torque: on for every joint (holding)")
        elif n_limp == len(limp):
            self.torque_label.setText("torque: OFF for every joint — pose the robot by hand")
        else:
            self.torque_label.setText(f"torque: OFF for {joints_text([sid for sid, x in zip(self._ids, limp) if x])}")

    def set_keyframes(self, rows: Sequence[tuple[str, float]], current: int = -1) -> None:
        """Show the keyframe list ``[(name, t_s), …]`` and select row ``current``."""
        self._filling = True
        try:
            self.keyframe_table.setRowCount(len(rows))
            for r, (name, t_s) in enumerate(rows):
                self.keyframe_table.setItem(r, 0, QTableWidgetItem(name))
                t_item = QTableWidgetItem(f"{t_s:.2f}")
                t_item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.keyframe_table.setItem(r, 1, t_item)
            if 0 <= current < len(rows):
                self.keyframe_table.selectRow(current)
            else:
                self.keyframe_table.clearSelection()
        finally:
            self._filling = False
        has = len(rows) > 0
        for b in (self.delete_button, self.up_button, self.down_button, self.clear_button):
            b.setEnabled(has)
        self._has_keyframes = has
        self._update_library_buttons()

    def current_row(self) -> int:
        rows = self.keyframe_table.selectionModel().selectedRows()
        return rows[0].row() if rows else -1

    def set_keyframe_angles(self, angles_rad: Sequence[float] | None) -> None:
        """Fill the joint editor with the selected keyframe's angles (None empties it)."""
        self._filling = True
        try:
            for j, axis in enumerate(self._axes):
                axis_item = QTableWidgetItem(axis)
                axis_item.setFlags(Qt.ItemFlag.ItemIsEnabled)
                axis_item.setForeground(theme.qcolor(theme.AXIS_COLORS[axis]))
                self.joint_table.setItem(j, 0, axis_item)
                if angles_rad is None:
                    rad_item, deg_item = QTableWidgetItem(""), QTableWidgetItem("")
                    rad_item.setFlags(Qt.ItemFlag.ItemIsEnabled)
                else:
                    rad_item = QTableWidgetItem(f"{angles_rad[j]:+.4f}")
                    deg_item = QTableWidgetItem(f"{math.degrees(angles_rad[j]):+.1f}")
                deg_item.setFlags(Qt.ItemFlag.ItemIsEnabled)
                for item in (rad_item, deg_item):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.joint_table.setItem(j, 1, rad_item)
                self.joint_table.setItem(j, 2, deg_item)
        finally:
            self._filling = False

    def set_library(self, names: Sequence[str], folder: str = "") -> None:
        current = self.library_combo.currentText()
        self.library_combo.clear()
        self.library_combo.addItems(list(names))
        if current in names:
            self.library_combo.setCurrentText(current)
        self.library_path_label.setText(f"library: {folder}" if folder else "")
        self._update_library_buttons()

    def set_undo_state(self, can_undo: bool, can_redo: bool, undo_text: str = "", redo_text: str = "") -> None:
        self.undo_button.setEnabled(can_undo)
        self.redo_button.setEnabled(can_redo)
        self.undo_button.setToolTip(f"Undo {undo_text} (Ctrl+Z)" if undo_text else "Undo (Ctrl+Z)")
        self.redo_button.setToolTip(f"Redo {redo_text} (Ctrl+Shift+Z)" if redo_text else "Redo (Ctrl+Shift+Z)")

    def set_connected(self, connected: bool) -> None:
        for b in (self.torque_off_selected_button, self.torque_off_all_button, self.hold_button,
                  self.capture_button):
            b.setEnabled(connected)
        if not connected:
            self.torque_label.setText("robot not connected (Hardware tab → Connect)")

    def set_status(self, text: str, level: str = theme.IDLE) -> None:
        self.status_label.setText(text)
        self.status_label.setStyleSheet(theme.status_style(level) if text else "")

    # -- internals ---------------------------------------------------------------------------------------------------
    def _update_library_buttons(self) -> None:
        """Enable what can work now; a disabled button's tooltip says what it needs."""
        has, named = self._has_keyframes, bool(self.name_edit.text().strip())
        self.save_button.setEnabled(has and named)
        self.save_button.setToolTip(
            "Save the keyframes as a shape in the library (the selected keyframe is the shape's pose)" if has and named
            else "Capture or load a pose first" if not has else "Type a name for the shape first")
        saved = self.library_combo.count() > 0
        self.load_button.setEnabled(saved)
        self.library_combo.setEnabled(saved)
        self.load_button.setToolTip("Replace the keyframe list with the chosen shape (Undo brings the list back)"
                                    if saved else "No shape saved yet: capture poses and Save one")
        for button in (self.mirror_button, self.scale_button, self.shift_button):
            button.setEnabled(has)

    def _torque_off_selected(self) -> None:
        ids = self.sliders.selected_ids()
        if not ids:
            self.set_status("select joints with the boxes beside the sliders first", theme.WARN)
            return
        self.torque_off_requested.emit(ids)

    def _row_selected(self) -> None:
        if not self._filling:
            self.keyframe_selected.emit(self.current_row())

    def _move(self, delta: int) -> None:
        row = self.current_row()
        if row >= 0:
            self.move_requested.emit(row, delta)

    def _delete(self) -> None:
        row = self.current_row()
        if row >= 0:
            self.delete_requested.emit(row)

    def _keyframe_item_changed(self, item: QTableWidgetItem) -> None:
        if self._filling:
            return
        if item.column() == 0:
            self.rename_requested.emit(item.row(), item.text().strip())
        else:
            try:
                value = float(item.text())
            except ValueError:
                self.set_status(f"keyframe {item.row() + 1}: {item.text()!r} is not a time in seconds",
                                theme.ERROR)
                value = math.nan
            self.time_edited.emit(item.row(), value)

    def _joint_item_changed(self, item: QTableWidgetItem) -> None:
        if self._filling or item.column() != 1:
            return
        row = self.current_row()
        try:
            value = float(item.text())
        except ValueError:
            self.set_status(f"J{self._ids[item.row()]}: {item.text()!r} is not an angle in radians", theme.ERROR)
            value = math.nan
        if row >= 0:
            self.angle_edited.emit(row, item.row(), value)
