"""The "3-D lab" tab: the physics lab's scene rendered offscreen (MuJoCo, EGL on Linux), or the 2-D body drawing.

The picture is rendered in a worker thread of this tab (an OpenGL context belongs to the thread that made it), at
most ``FRAME_RATE_HZ`` and only while the tab is visible; frames reach the GUI thread through the app's one
:class:`app.gui.thread_bridge.ThreadBridge`. Without a physics lab (a real robot, ``[lab] physics = "scripted"``) or
without OpenGL it shows the 2-D body drawing of the robot's present joint angles and says why. A line above the
picture names the scene (``[lab] scene``) and its obstacles.

**Live motion capture** (a source picked beside the Forces tab's Record, or ``[lab] mocap``): the motion-captured
markers and segment centres are drawn into the 3-D picture over the simulated body, and a panel beside it
(:class:`widgets.kinematics_view.KinematicsView`) shows the motion-captured body from the side and each segment's
position against time (the paper's Fig. 6D) over the last ``KINEMATICS_WINDOW_S``, on the Forces tab's clock. Both
read the poses the stream's reader fits (:meth:`app.gui.mocap_link.MocapLink.live_snapshot`); the panel redraws
at ``KINEMATICS_RATE_HZ`` while the tab is visible.

**Replay** (Open recording…): a recording on a timeline (:class:`widgets.replay_view.ReplayView`) — the simulated body
from ``/sim``, the motion-captured one from ``/mocap`` when present, else the commanded pose from ``/robot`` — with
the contact forces drawn on the body; scrub, play, pause, speed 0.1–10×, step frame by frame. The data are read by
:mod:`app.core.replay`; one timer, running only while the replay plays and the tab is visible, advances the time and
draws the frame there. The live picture pauses meanwhile; **Live** goes back to it.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QTimer
from PySide6.QtGui import QHideEvent, QShowEvent
from PySide6.QtWidgets import (
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSplitter,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from app.core import replay as replays
from app.core import user_folders
from app.gui.thread_bridge import ThreadBridge
from devices.errors import SceneError
from devices.scene import half_cylinder_scene, load_scene
from widgets import theme
from widgets.kinematics_view import MOCAP_COLOR, KinematicsView
from widgets.replay_view import ReplayView
from widgets.scene_view import SceneView

FRAME_RATE_HZ = 10.0
FRAME_SIZE = (640, 480)
BODY_RATE_MS = 100
REPLAY_FRAME_MS = 33  # the replay draws at ~30 frames/s while it plays
KINEMATICS_RATE_HZ = 15.0
KINEMATICS_WINDOW_S = 30.0
MARKER_RADIUS_M = 0.006  # the motion-captured markers and segment centres as drawn into the 3-D picture
CENTRE_RADIUS_M = 0.011


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
        self._physics, note = _physics_of(lab)
        self.view = SceneView(robot.axes, robot.segment_length_m,
                              waiting_text="Starting the 3-D picture…" if self._physics is not None else "")
        layout = QVBoxLayout(self)
        bar = QHBoxLayout()
        self.scene_label = QLabel(scene_description(lab.config))
        self.scene_label.setWordWrap(True)
        bar.addWidget(self.scene_label, 1)
        self.open_button = QPushButton("Open recording…")
        self.open_button.setToolTip("Replay a recording in 3-D: the simulated body (/sim), the motion-captured one "
                                    "(/mocap) or the commanded pose (/robot), with its contact forces")
        self.open_button.clicked.connect(self._choose_replay)
        bar.addWidget(self.open_button)
        self.live_button = QPushButton("Live")
        self.live_button.setToolTip("Back to the live lab")
        self.live_button.clicked.connect(self.show_live)
        self.live_button.setVisible(False)
        bar.addWidget(self.live_button)
        layout.addLayout(bar)
        self.pages = QStackedWidget()
        self.live_page = QSplitter()
        self.live_page.addWidget(self.view)
        self.pages.addWidget(self.live_page)
        layout.addWidget(self.pages, 1)
        # The kinematics panel and the replay's timeline are built when first needed (a motion capture source is
        # picked, a recording is opened; reading ``kinematics`` or ``replay_view`` builds it): hidden until then,
        # they cost the tab's first opening 30-100 ms of blocked window and nothing else.
        self._kinematics: KinematicsView | None = None
        self._replay_view: ReplayView | None = None
        self.replay: replays.Replay | None = None
        self.replay_time_s = 0.0
        self.replay_frame: replays.ReplayFrame | None = None
        self._replay_speed = 1.0
        self._replay_clock: tuple[float, float] | None = None  # (monotonic, replay time) when play last started
        self._replay_timer = QTimer(self)
        self._replay_timer.setInterval(REPLAY_FRAME_MS)
        self._replay_timer.timeout.connect(self._replay_tick)
        self._bridge = ThreadBridge(self)
        self._visible = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.render_error = ""
        self._body_timer = QTimer(self)
        self._body_timer.setInterval(BODY_RATE_MS)
        self._body_timer.timeout.connect(self._draw_body)
        self.mocap = getattr(lab, "mocap", None)
        self._kinematics_timer = QTimer(self)
        self._kinematics_timer.setInterval(int(1000 / KINEMATICS_RATE_HZ))
        self._kinematics_timer.timeout.connect(self.draw_kinematics)
        if self._physics is None:
            why = (f"No physics lab: {note}." if note else "No physics lab: this is a real robot or the scripted "
                   "simulated lab ([lab] physics = \"scripted\").")
            self.view.show_fallback(f"{why} The 2-D drawing shows the present joint angles.")
        if self.mocap is not None:
            self.mocap.source_changed.connect(self._on_mocap_source)
            self.mocap.status_changed.connect(self._on_mocap_status)
            if self.mocap.source:
                self._on_mocap_source(self.mocap.source)

    # -- the views built when first needed ---------------------------------------------------------------------------
    @property
    def kinematics(self) -> KinematicsView:
        """The live motion capture's panel beside the picture (built now if it was not)."""
        if self._kinematics is None:
            self._build_kinematics()
        assert self._kinematics is not None
        return self._kinematics

    @property
    def replay_view(self) -> ReplayView:
        """The replay's timeline and picture (built now if it was not)."""
        if self._replay_view is None:
            self._build_replay_view()
        assert self._replay_view is not None
        return self._replay_view

    def _build_kinematics(self) -> None:
        view = KinematicsView(self.lab.config.robot.n_joints)
        view.setVisible(False)
        self._kinematics = view
        self.live_page.addWidget(view)
        self.live_page.setStretchFactor(0, 3)
        self.live_page.setStretchFactor(1, 2)
        if self.mocap is not None:
            view.set_status(self.mocap.status, self.mocap.level)

    def _build_replay_view(self) -> None:
        rv = ReplayView()
        self._replay_view = rv
        self.pages.addWidget(rv)
        rv.time_requested.connect(self.seek)
        rv.play_toggled.connect(lambda on: self.play() if on else self.pause())
        rv.step_requested.connect(self.step)
        rv.speed_changed.connect(self.set_speed)

    @property
    def rendering(self) -> bool:
        """True while the render thread is allowed to draw (the tab is visible and has a physics lab)."""
        return self._thread is not None and self._visible.is_set() and not self._stop.is_set()

    # -- visibility drives the work ----------------------------------------------------------------------------------
    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt's name
        super().showEvent(event)
        if self.replay is not None:
            if self._replay_clock is not None:
                self._replay_clock = (time.monotonic(), self.replay_time_s)
                self._replay_timer.start()
            return
        if self._physics is not None and not self.render_error:
            self._visible.set()
            if self._thread is None:
                self._stop.clear()
                self._thread = threading.Thread(target=self._render_loop, name="scene-render", daemon=True)
                self._thread.start()
        else:
            self._body_timer.start()
        if self._kinematics is not None and self._kinematics.isVisibleTo(self):
            self._kinematics_timer.start()

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt's name
        super().hideEvent(event)
        self._visible.clear()
        self._body_timer.stop()
        self._kinematics_timer.stop()
        self._replay_timer.stop()  # a playing replay resumes where it was when the tab comes back

    def shutdown(self) -> None:
        self._stop.set()
        self._visible.set()  # wake the loop so it sees the stop
        if self._thread is not None:
            self._thread.join(timeout=3.0)
            self._thread = None
        self._body_timer.stop()
        self._kinematics_timer.stop()
        self._replay_timer.stop()
        self._bridge.close()

    # -- render thread -------------------------------------------------------------------------------------------------
    def _render_loop(self) -> None:
        period = 1.0 / FRAME_RATE_HZ
        try:
            while not self._stop.is_set():
                self._visible.wait()
                if self._stop.is_set():
                    break
                frame = self._physics.render_rgb(*FRAME_SIZE, self.mocap_marks())
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

    def mocap_marks(self) -> list[tuple[np.ndarray, float, tuple[float, float, float, float]]]:
        """The newest motion-captured markers and segment centres, as spheres for the 3-D picture (render thread)."""
        snapshot = self.mocap.live_snapshot() if self.mocap is not None and self.mocap.source else None
        if snapshot is None:
            return []
        colour = theme.qcolor(MOCAP_COLOR)
        rgba = (colour.redF(), colour.greenF(), colour.blueF(), 1.0)
        return [(snapshot.markers_m.reshape(-1, 3), MARKER_RADIUS_M, rgba),
                (snapshot.newest_center_m, CENTRE_RADIUS_M, (rgba[0], rgba[1], rgba[2], 0.55))]

    # -- live motion capture -------------------------------------------------------------------------------------------
    def _on_mocap_source(self, source: str) -> None:
        if source:
            first = self._kinematics is None
            self.kinematics.setVisible(True)
            if first:  # added beside a picture already laid out: given the 3:2 split a panel built with the page gets
                width = max(5, self.live_page.width())
                self.live_page.setSizes([width * 3 // 5, width - width * 3 // 5])
            if self.isVisible():
                self._kinematics_timer.start()
        else:
            if self._kinematics is not None:
                self._kinematics.setVisible(False)
            self._kinematics_timer.stop()

    def _on_mocap_status(self, text: str, level: str) -> None:
        if self._kinematics is not None:
            self._kinematics.set_status(text, level)

    def draw_kinematics(self) -> None:
        """The kinematics panel from the newest poses (timer, while the tab is visible)."""
        snapshot = self.mocap.live_snapshot() if self.mocap is not None else None
        if snapshot is None:
            self.kinematics.show_body(None, None)
            return
        board = getattr(self.lab, "board_if_created", None)
        t0 = getattr(board, "t0_monotonic_s", None)
        t0 = float(snapshot.time_s[0]) if t0 is None else float(t0)
        recent = snapshot.time_s >= snapshot.newest_time_s - KINEMATICS_WINDOW_S
        self.kinematics.show_body(snapshot.newest_center_m, snapshot.markers_m)
        self.kinematics.show_positions(snapshot.time_s[recent] - t0, snapshot.center_m[recent])

    # -- 2-D fallback --------------------------------------------------------------------------------------------------
    def _draw_body(self) -> None:
        state = self.lab.robot.latest_state
        if state is not None:
            self.view.body.set_angles(np.asarray(state.position_rad))


    # -- replay ------------------------------------------------------------------------------------------------------
    def _choose_replay(self) -> None:
        folder = user_folders.dialog_folder(user_folders.recordings_dir())
        path, _filter = QFileDialog.getOpenFileName(self, "Replay a recording in 3-D", folder,
                                                    "Recordings (*.h5 *.hdf5);;All files (*)")
        if path:
            self.open_replay(path)

    def open_replay(self, path: str | Path) -> bool:
        """Open ``path`` on the timeline at its start, paused; False (and the reason above the picture) when it has
        nothing to replay."""
        robot = self.lab.config.robot
        try:
            replay = replays.open_replay(path, tuple(robot.axes), robot.segment_length_m)
        except (OSError, ValueError) as exc:
            self.scene_label.setText(f"cannot replay: {exc}")
            self.scene_label.setStyleSheet(theme.status_style(theme.ERROR))
            return False
        self.pause()
        self.replay = replay
        self._visible.clear()  # the live picture rests while a recording is shown
        self._body_timer.stop()
        sources = " and ".join(replays.SOURCE_TITLES[t.source] for t in replay.tracks)
        forces = f"; contact forces {replay.forces_source}" if replay.forces_source else "; no contact forces"
        self.scene_label.setText(f"Replay of {replay.path.name} ({replay.duration_s:.1f} s)")
        self.scene_label.setStyleSheet("")
        self.replay_view.set_timeline(replay.start_s, replay.end_s, f"{sources}{forces}")
        self.pages.setCurrentWidget(self.replay_view)
        self.live_button.setVisible(True)
        log = getattr(self.lab, "event_log", None)
        if log is not None:
            log.add("action", f"replay {replay.path} in 3-D", "3-D lab")
        self.seek(replay.start_s, refit=True)
        return True

    def show_live(self) -> None:
        """Leave the replay: the live lab again."""
        self.pause()
        self.replay = None
        self.replay_frame = None
        self.pages.setCurrentWidget(self.live_page)
        self.live_button.setVisible(False)
        self.scene_label.setText(scene_description(self.lab.config))
        if self.isVisible():
            if self._physics is not None and not self.render_error:
                self._visible.set()
            else:
                self._body_timer.start()

    def seek(self, t_s: float, refit: bool = False) -> None:
        """Show the recording's frame at ``t_s`` (the last recorded at or before it)."""
        replay = self.replay
        if replay is None:
            return
        t_s = min(max(float(t_s), replay.start_s), replay.end_s)
        self.replay_time_s = t_s
        if self._replay_clock is not None:
            self._replay_clock = (time.monotonic(), t_s)
        frame = replay.frame_at(t_s)
        self.replay_frame = frame
        body = frame.bodies[0]
        forces = frame.forces_n if frame.forces_n is not None and len(frame.forces_n) == len(body.sensors_m) else None
        self.replay_view.show_frame([(b.source, b.points_m) for b in frame.bodies], body.sensors_m, forces,
                                    refit=refit)
        self.replay_view.set_time(t_s)

    def step(self, frames: int) -> None:
        """One frame (or ``frames``) forward or back; pauses a playing replay."""
        if self.replay is None:
            return
        self.pause()
        self.seek(self.replay.step(self.replay_time_s, frames))

    def set_speed(self, speed: float) -> None:
        """Playback speed (0.1–10× real time)."""
        self._replay_speed = float(speed)
        if self._replay_clock is not None:
            self._replay_clock = (time.monotonic(), self.replay_time_s)
        if self.replay_view.speed != speed:
            self.replay_view.set_speed(speed)

    def play(self) -> None:
        replay = self.replay
        if replay is None:
            self.replay_view.set_playing(False)
            return
        if self.replay_time_s >= replay.end_s:
            self.seek(replay.start_s)
        self._replay_clock = (time.monotonic(), self.replay_time_s)
        self.replay_view.set_playing(True)
        if self.isVisible():
            self._replay_timer.start()

    def pause(self) -> None:
        self._replay_clock = None
        self._replay_timer.stop()
        self.replay_view.set_playing(False)

    @property
    def playing(self) -> bool:
        return self._replay_clock is not None

    def _replay_tick(self) -> None:
        replay, clock = self.replay, self._replay_clock
        if replay is None or clock is None:
            self._replay_timer.stop()
            return
        started_s, from_s = clock
        t_s = from_s + (time.monotonic() - started_s) * self._replay_speed
        if t_s >= replay.end_s:
            self.seek(replay.end_s)
            self.pause()
            return
        self.seek(t_s)


def create_tab(lab: Any) -> QWidget:
    """The main window's entry point (``app/gui/tabs/<name>.py`` contract)."""
    return SceneTab(lab)

