"""The Teach tab: pose the robot by hand with torque off, capture keyframes, hold, edit, save to the shape library.

Wires :class:`widgets.teach_panel.TeachPanel` to ``lab.robot`` through :class:`app.core.teach.TeachSession` (the same
logic as ``sensnake teach``). The keyframe list is a plain Python list edited through a ``QUndoStack`` (each edit is a
before/after snapshot: the list is a few dozen poses, so snapshots are cheap and can't get out of step).
In the simulated lab, dragging the drawing or a slider bends a limp joint of the simulated chain
(:class:`app.core.teach.SimHand`); with a real robot a person bends it and the drawing follows.
Live angles are refreshed from ``lab.robot.latest_state`` by a 20 Hz timer while the tab is visible.
GUI thread only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from PySide6.QtCore import QTimer
from PySide6.QtGui import QHideEvent, QShowEvent, QUndoCommand, QUndoStack
from PySide6.QtWidgets import QVBoxLayout, QWidget

from app.core.shapes import Keyframe, Shape, ShapeLibrary, mirror, scale, shift
from app.core.teach import SimHand, TeachSession, sim_hand_for
from app.gui.lab import LabContext
from app.gui.robot_bridge import describe_error
from widgets import theme
from widgets.teach_panel import TeachPanel, joints_text

REFRESH_INTERVAL_MS = 50  # 20 Hz: smooth enough to watch a joint being bent
DEFAULT_KEYFRAME_SPACING_S = 2.0


class _ListEdit(QUndoCommand):
    """One undoable edit of the keyframe list: swap between two snapshots."""

    def __init__(self, tab: TeachTab, before: list[Keyframe], after: list[Keyframe], text: str,
                 select_after: int) -> None:
        super().__init__(text)
        self._tab, self._before, self._after = tab, before, after
        self._select_before = tab.current_index
        self._select_after = select_after

    def redo(self) -> None:
        self._tab.apply_frames(self._after, self._select_after)

    def undo(self) -> None:
        self._tab.apply_frames(self._before, self._select_before)


class TeachTab(QWidget):
    def __init__(self, lab: LabContext, library: ShapeLibrary | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        self.robot = lab.robot
        self.config = lab.config.robot
        self.session = TeachSession(self.robot.run_on_bus, self.config, self._set_torque)
        self.library = library or ShapeLibrary()
        self.keyframes: list[Keyframe] = []
        self.current_index = -1
        self.undo_stack = QUndoStack(self)
        self._hand: SimHand | None = None
        n = self.config.n_joints
        self.limp = [False] * n

        self.panel = TeachPanel(self.config.joint_ids, self.config.axes, self.config.joint_min_rad,
                                self.config.joint_max_rad, self.config.segment_length_m)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.panel)

        p = self.panel
        p.torque_off_requested.connect(self.torque_off)
        p.hold_requested.connect(self.hold)
        p.capture_requested.connect(self.capture)
        p.pose_angle_requested.connect(self.pose_joint)
        p.keyframe_selected.connect(self._select)
        p.move_requested.connect(self.move_keyframe)
        p.delete_requested.connect(self.delete_keyframe)
        p.rename_requested.connect(self.rename_keyframe)
        p.time_edited.connect(self.set_keyframe_time)
        p.angle_edited.connect(self.set_keyframe_angle)
        p.undo_requested.connect(self.undo)
        p.redo_requested.connect(self.redo)
        p.clear_requested.connect(self.clear_keyframes)
        p.save_requested.connect(self.save_shape)
        p.load_requested.connect(self.load_shape)
        p.mirror_requested.connect(lambda: self._transform(mirror, "mirror"))
        p.scale_requested.connect(lambda f: self._transform(lambda s: scale(s, f), f"scale × {f:g}"))
        p.shift_requested.connect(lambda k: self._transform(lambda s: shift(s, k), f"shift {k:+d}"))
        self.undo_stack.indexChanged.connect(self._undo_changed)
        self.robot.connected.connect(self._connected_changed)
        self.robot.health.connect(self._health)

        self._timer = QTimer(self)
        self._timer.setInterval(REFRESH_INTERVAL_MS)
        self._timer.timeout.connect(self.refresh)
        self._connected_changed(self.robot.is_connected)
        self._undo_changed()
        self.refresh_library()
        p.set_keyframes([])

    def _set_torque(self, enabled: bool, ids: list[int] | None) -> Any:
        """Through the controller, so it also forgets its last goal (the next motion starts from the pose)."""
        controller = self.robot.controller
        if controller is None:
            raise ConnectionError("the robot is not connected: connect it first (Hardware tab → Connect)")
        return controller.set_torque(enabled, ids)

    # -- live view ---------------------------------------------------------------------------------------------------
    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt override
        super().showEvent(event)
        self._timer.start()
        self.refresh()

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt override
        self._timer.stop()
        super().hideEvent(event)

    def refresh(self) -> None:
        state = self.robot.latest_state
        if state is None:
            return
        goal = self.keyframes[self.current_index].angles_rad if 0 <= self.current_index < len(self.keyframes) \
            else None
        self.panel.set_live_angles(np.asarray(state.position_rad), None if goal is None else np.asarray(goal))

    def _connected_changed(self, connected: bool) -> None:
        self.panel.set_connected(connected)
        if connected:
            self.panel.set_limp(self.limp, self._posable())

    def _health(self, health: list) -> None:
        index = {sid: j for j, sid in enumerate(self.config.joint_ids)}
        changed = False
        for item in health:
            j = index.get(item.servo_id)
            if j is not None and self.limp[j] == item.torque_on:
                self.limp[j] = not item.torque_on
                changed = True
        if changed:
            self.panel.set_limp(self.limp, self._posable())

    def _posable(self) -> bool:
        return self.robot.is_sim and self.robot.is_connected

    # -- posing --------------------------------------------------------------------------------------------------------
    def torque_off(self, ids: list[int] | None) -> None:
        try:
            future = self.session.torque_off(ids)
        except (ValueError, OSError) as exc:
            self._error(str(exc))
            return
        chosen = set(self.config.joint_ids if ids is None else ids)
        if self._hand is not None:  # "torque off" again is also how the simulated hand lets go: gravity takes over
            self._hand.let_go()

        def done(_result: Any) -> None:
            self.limp = [sid in chosen or limp for sid, limp in zip(self.config.joint_ids, self.limp)]
            self.panel.set_limp(self.limp, self._posable())
            how = "drag the drawing or the sliders" if self._posable() else "bend the robot by hand"
            which = "every joint" if len(chosen) == self.config.n_joints else joints_text(sorted(chosen))
            self.panel.set_status(f"torque off for {which}: {how}, then Capture", theme.OK)

        self.robot.when_done(future, done, self._failed("torque off"))

    def hold(self, ids: list[int] | None = None) -> None:
        def done(goals: np.ndarray) -> None:
            self.limp = [False] * self.config.n_joints
            self.panel.set_limp(self.limp, self._posable())
            self.panel.set_status("torque on: holding the present pose", theme.OK)

        try:
            future = self.session.hold(ids)
        except (ValueError, OSError) as exc:
            self._error(str(exc))
            return
        self.robot.when_done(future, done, self._failed("torque on"))

    def capture(self) -> None:
        def done(pose: Any) -> None:
            t_s = self.keyframes[-1].t_s + DEFAULT_KEYFRAME_SPACING_S if self.keyframes else 0.0
            name = self._unique_name(f"pose {len(self.keyframes) + 1}")
            frame = Keyframe(t_s, tuple(float(a) for a in pose.angles_rad), name)
            after = [*self.keyframes, frame]
            self.undo_stack.push(_ListEdit(self, list(self.keyframes), after, f"capture {name}", len(after) - 1))
            self.panel.set_status(f"captured {name!r} at t = {t_s:.1f} s", theme.OK)

        self.robot.when_done(self.session.capture(), done, self._failed("capture"))

    def pose_joint(self, joint_index: int, angle_rad: float) -> None:
        """Bend a limp joint (simulated lab only; a real robot is bent by hand)."""
        if not self._posable():
            self.panel.set_status("bend the real robot by hand; the drawing follows it", theme.WARN)
            return
        if not self.limp[joint_index]:
            self.panel.set_status(f"joint {self.config.joint_ids[joint_index]} holds torque: turn torque off to "
                                  "pose it", theme.WARN)
            return
        if self._hand is None:
            self._hand = sim_hand_for(self.config)
        if self._hand is None:
            return
        lo, hi = self.config.joint_min_rad[joint_index], self.config.joint_max_rad[joint_index]
        try:
            self._hand.set_angle(joint_index, min(max(angle_rad, lo), hi))
        except ValueError as exc:  # the servo turned torque back on meanwhile
            self._error(str(exc))

    # -- keyframe list (undoable) --------------------------------------------------------------------------------------
    def apply_frames(self, frames: list[Keyframe], select: int) -> None:
        self.keyframes = list(frames)
        self.current_index = select if 0 <= select < len(frames) else (len(frames) - 1 if frames else -1)
        self.panel.set_keyframes([(k.name, k.t_s) for k in self.keyframes], self.current_index)
        self._show_current()

    def _edit(self, after: list[Keyframe], text: str, select: int | None = None) -> None:
        self.undo_stack.push(_ListEdit(self, list(self.keyframes), after, text,
                                       self.current_index if select is None else select))

    def _select(self, row: int) -> None:
        self.current_index = row
        self._show_current()

    def _show_current(self) -> None:
        if 0 <= self.current_index < len(self.keyframes):
            self.panel.set_keyframe_angles(self.keyframes[self.current_index].angles_rad)
        else:
            self.panel.set_keyframe_angles(None)
        self.refresh()

    def move_keyframe(self, row: int, delta: int) -> None:
        target = row + delta
        if not (0 <= row < len(self.keyframes) and 0 <= target < len(self.keyframes)):
            return
        frames = list(self.keyframes)
        frames[row], frames[target] = frames[target], frames[row]
        # the times stay in their slots: reordering changes which pose comes when, not the timeline
        frames[row] = Keyframe(self.keyframes[row].t_s, frames[row].angles_rad, frames[row].name)
        frames[target] = Keyframe(self.keyframes[target].t_s, frames[target].angles_rad, frames[target].name)
        self._edit(frames, f"move {self.keyframes[row].name}", target)

    def delete_keyframe(self, row: int) -> None:
        if 0 <= row < len(self.keyframes):
            frames = [k for i, k in enumerate(self.keyframes) if i != row]
            self._edit(frames, f"delete {self.keyframes[row].name}", min(row, len(frames) - 1))

    def clear_keyframes(self) -> None:
        if self.keyframes:
            self._edit([], "clear keyframes", -1)

    def rename_keyframe(self, row: int, name: str) -> None:
        if not (0 <= row < len(self.keyframes)) or name == self.keyframes[row].name:
            return
        if not name:
            self._error("a keyframe needs a name")
            self.apply_frames(self.keyframes, row)
            return
        frames = list(self.keyframes)
        frames[row] = Keyframe(frames[row].t_s, frames[row].angles_rad, name)
        self._edit(frames, f"rename {self.keyframes[row].name} → {name}", row)

    def set_keyframe_time(self, row: int, t_s: float) -> None:
        if not (0 <= row < len(self.keyframes)):
            return
        if not (math.isfinite(t_s) and t_s >= 0):
            self._error(f"keyframe {row + 1}: time must be 0 s or more")
            self.apply_frames(self.keyframes, row)
            return
        frames = list(self.keyframes)
        frames[row] = Keyframe(float(t_s), frames[row].angles_rad, frames[row].name)
        self._edit(frames, f"time of {frames[row].name}", row)

    def set_keyframe_angle(self, row: int, joint_index: int, angle_rad: float) -> None:
        if not (0 <= row < len(self.keyframes)):
            return
        lo, hi = self.config.joint_min_rad[joint_index], self.config.joint_max_rad[joint_index]
        if not (math.isfinite(angle_rad) and lo <= angle_rad <= hi):
            self._error(f"J{self.config.joint_ids[joint_index]}: angle must be within [{lo:.3f}, {hi:.3f}] rad "
                        "(the joint limits in the lab config); the keyframe is unchanged")
            self.apply_frames(self.keyframes, row)
            return
        frames = list(self.keyframes)
        angles = list(frames[row].angles_rad)
        angles[joint_index] = float(angle_rad)
        frames[row] = Keyframe(frames[row].t_s, tuple(angles), frames[row].name)
        self._edit(frames, f"J{self.config.joint_ids[joint_index]} of {frames[row].name}", row)

    def undo(self) -> None:
        """Undo the last keyframe edit; the status line says what was undone (not what the edit had said)."""
        text = self.undo_stack.undoText()
        if not self.undo_stack.canUndo():
            return
        self.undo_stack.undo()
        self.panel.set_status(f"undone: {text}", theme.IDLE)

    def redo(self) -> None:
        text = self.undo_stack.redoText()
        if not self.undo_stack.canRedo():
            return
        self.undo_stack.redo()
        self.panel.set_status(f"redone: {text}", theme.IDLE)

    def _undo_changed(self, *_args: Any) -> None:
        s = self.undo_stack
        self.panel.set_undo_state(s.canUndo(), s.canRedo(), s.undoText(), s.redoText())

    def _unique_name(self, name: str) -> str:
        names = {k.name for k in self.keyframes}
        candidate, n = name, 2
        while candidate in names:
            candidate, n = f"{name} ({n})", n + 1
        return candidate

    # -- shapes ---------------------------------------------------------------------------------------------------------
    def current_shape(self, name: str = "") -> Shape:
        """The list as a shape: ``angles_rad`` is the selected keyframe (the first if none is selected); the
        keyframes are all of them when there are two or more."""
        if not self.keyframes:
            raise ValueError("capture at least one pose first")
        index = self.current_index if 0 <= self.current_index < len(self.keyframes) else 0
        frames = tuple(self.keyframes) if len(self.keyframes) > 1 else ()
        return Shape(name or "untitled", tuple(self.config.axes), self.keyframes[index].angles_rad, frames)

    def save_shape(self, name: str) -> None:
        if not name:
            self._error("type a name for the shape first")
            return
        try:
            path = self.library.save(self.current_shape(name))
        except (OSError, ValueError) as exc:
            self._error(f"could not save shape {name!r}: {exc}")
            return
        self.refresh_library()
        self.panel.set_status(f"saved {name!r} to {path}", theme.OK)

    def load_shape(self, name: str) -> None:
        if not name:
            self._error("the shape library is empty: save a shape first")
            return
        try:
            shape = self.library.load(name)
        except (OSError, ValueError) as exc:
            self._error(str(exc))
            return
        if len(shape.axes) != self.config.n_joints:
            self._error(f"shape {name!r} has {len(shape.axes)} joints; this robot has {self.config.n_joints}")
            return
        frames = list(shape.keyframes) or [Keyframe(0.0, shape.angles_rad, shape.name or name)]
        frames = [k if k.name else Keyframe(k.t_s, k.angles_rad, f"pose {i + 1}") for i, k in enumerate(frames)]
        self._edit(frames, f"load {name}", 0)
        self.panel.name_edit.setText(shape.name or name)
        self.panel.set_status(f"loaded {name!r}: {len(frames)} keyframe(s)", theme.OK)

    def _transform(self, fn, text: str) -> None:
        if not self.keyframes:
            self._error("nothing to transform: capture or load a shape first")
            return
        shape = Shape("draft", tuple(self.config.axes), self.keyframes[0].angles_rad, tuple(self.keyframes))
        try:
            changed = fn(shape)
        except ValueError as exc:
            self._error(str(exc))
            return
        lo, hi = np.asarray(self.config.joint_min_rad), np.asarray(self.config.joint_max_rad)
        for k in changed.keyframes:
            a = np.asarray(k.angles_rad)
            if np.any(a < lo) or np.any(a > hi):
                self._error(f"{text} would put {k.name!r} outside the joint limits; not applied")
                return
        self._edit(list(changed.keyframes), text, self.current_index)
        self.panel.set_status(f"{text}: applied to {len(changed.keyframes)} keyframe(s)", theme.OK)

    def refresh_library(self) -> None:
        self.panel.set_library(self.library.names(), str(self.library.root))

    # -- errors ---------------------------------------------------------------------------------------------------------
    def _failed(self, what: str):
        def report(exc: BaseException) -> None:
            self._error(f"{what} failed: {describe_error(exc)}")

        return report

    def _error(self, text: str) -> None:
        self.panel.set_status(text, theme.ERROR)


def create_tab(lab: LabContext) -> QWidget:
    return TeachTab(lab)
