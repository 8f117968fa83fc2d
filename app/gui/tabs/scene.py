"""The "3-D lab" tab: the physics lab's scene rendered offscreen (MuJoCo, EGL on Linux), or the 2-D body drawing.

The picture is rendered in a worker thread of this tab (an OpenGL context belongs to the thread that made it), at
most ``FRAME_RATE_HZ`` and only while the tab is visible; frames reach the GUI thread through the app's one
:class:`app.gui.thread_bridge.ThreadBridge`. Without a physics lab (a real robot, ``[lab] physics = "scripted"``) or
without OpenGL it shows the 2-D body drawing of the robot's present joint angles and says why. A line above the
picture names the scene (``[lab] scene``) and its obstacles.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
from PySide6.QtCore import QTimer
from PySide6.QtGui import QHideEvent, QShowEvent
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from app.gui.thread_bridge import ThreadBridge
from devices.errors import SceneError
from devices.scene import half_cylinder_scene, load_scene
from widgets.scene_view import SceneView

FRAME_RATE_HZ = 10.0
FRAME_SIZE = (640, 480)
BODY_RATE_MS = 100


def _physics_of(lab: Any) -> tuple[Any, str]:
    """The simulated lab's physics backend, or None (a real robot, or the scripted simulated lab), and why the
    simulated lab is scripted when physics was asked for ("" otherwise)."""
    if not lab.robot.is_sim:
        return None, ""
    from devices.factory import sim_lab

    sim = sim_lab()
    return getattr(sim, "physics", None), getattr(sim, "physics_note", "")


def scene_description(config: Any) -> str:
    """One line for the tab's header: the scene's name and its obstacles (or why it could not be read)."""
    lab = config.lab
    try:
        if lab.scene:
            scene = load_scene(lab.scene)
        else:
            height = lab.obstacle_height_ratio * config.robot.n_joints * config.robot.segment_length_m
            scene = half_cylinder_scene(height, lab.obstacle_friction, lab.ground_friction,
                                        name="the paper's obstacle ([lab] keys)" if height > 0 else "flat ground")
    except SceneError as exc:
        return f"Scene: {exc}"
    parts = []
    for o in scene.obstacles:
        size = (f"r {o.radius_m:.2f} m" if o.shape == "half_cylinder"
                else f"{o.length_m:.2f} m long, {o.height_m:.2f} m high")
        if o.roll_resistance_m != scene.ground_roll_m:  # said only where it differs from the ground's
            size += f", roll resistance {o.roll_resistance_m * 1000:g} mm" if o.roll_resistance_m else ", rolls freely"
        parts.append(f"{o.shape.replace('_', ' ')} at x {o.x_m:+.2f} m ({size}, μ {o.friction:g})")
    terrain = "; ".join(parts) if parts else "no obstacle"
    # the ground's roll resistance is every obstacle's too unless an obstacle says otherwise: said first, scene-wide
    roll = f"roll resistance {scene.ground_roll_m * 1000:g} mm; " if scene.ground_roll_m else "shells roll freely; "
    if scene.contact_onset_m is not None:  # said only when a scene asks for it (MuJoCo's impedance otherwise)
        roll += f"contact onset {scene.contact_onset_m * 1000:g} mm; "
    return f"Scene: {scene.name} — {roll}ground μ {scene.ground_friction:g}; {terrain}"


class SceneTab(QWidget):
    """See the module docstring. ``shutdown()`` stops the render thread (the main window calls it)."""

    def __init__(self, lab: Any, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        robot = lab.config.robot
        self.view = SceneView(robot.axes, robot.segment_length_m)
        layout = QVBoxLayout(self)
        self.scene_label = QLabel(scene_description(lab.config))
        self.scene_label.setWordWrap(True)
        layout.addWidget(self.scene_label)
        layout.addWidget(self.view)
        self._bridge = ThreadBridge(self)
        self._physics, note = _physics_of(lab)
        self._visible = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.render_error = ""
        self._body_timer = QTimer(self)
        self._body_timer.setInterval(BODY_RATE_MS)
        self._body_timer.timeout.connect(self._draw_body)
        if self._physics is None:
            why = (f"No physics lab: {note}." if note else "No physics lab: this is a real robot or the scripted "
                   "simulated lab ([lab] physics = \"scripted\").")
            self.view.show_fallback(f"{why} The 2-D drawing shows the present joint angles.")

    @property
    def rendering(self) -> bool:
        """True while the render thread is allowed to draw (the tab is visible and has a physics lab)."""
        return self._thread is not None and self._visible.is_set() and not self._stop.is_set()

    # -- visibility drives the work ----------------------------------------------------------------------------------
    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt's name
        super().showEvent(event)
        if self._physics is not None and not self.render_error:
            self._visible.set()
            if self._thread is None:
                self._stop.clear()
                self._thread = threading.Thread(target=self._render_loop, name="scene-render", daemon=True)
                self._thread.start()
        else:
            self._body_timer.start()

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt's name
        super().hideEvent(event)
        self._visible.clear()
        self._body_timer.stop()

    def shutdown(self) -> None:
        self._stop.set()
        self._visible.set()  # wake the loop so it sees the stop
        if self._thread is not None:
            self._thread.join(timeout=3.0)
            self._thread = None
        self._body_timer.stop()
        self._bridge.close()

    # -- render thread -------------------------------------------------------------------------------------------------
    def _render_loop(self) -> None:
        period = 1.0 / FRAME_RATE_HZ
        try:
            while not self._stop.is_set():
                self._visible.wait()
                if self._stop.is_set():
                    break
                frame = self._physics.render_rgb(*FRAME_SIZE)
                self._bridge.post(self.view.set_frame, frame)
                self._stop.wait(period)
        except RuntimeError as exc:  # RenderUnavailable (no EGL/OSMesa here), or the world went away
            self._bridge.post(self._on_render_error, str(exc))
        finally:
            self._physics.release_renderer()  # its OpenGL context is current here: only this thread can close it

    def _on_render_error(self, message: str) -> None:
        self.render_error = message
        self.view.show_fallback(f"{message}; showing the 2-D body drawing instead.")
        if self.isVisible():
            self._body_timer.start()

    # -- 2-D fallback --------------------------------------------------------------------------------------------------
    def _draw_body(self) -> None:
        state = self.lab.robot.latest_state
        if state is not None:
            self.view.body.set_angles(np.asarray(state.position_rad))


def create_tab(lab: Any) -> QWidget:
    """The main window's entry point (``app/gui/tabs/<name>.py`` contract)."""
    return SceneTab(lab)
