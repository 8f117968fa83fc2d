"""The Trials panel's face of a trial series on the robot: :mod:`app.core.robot_trials`'s steps driven from the GUI, on
``lab.robot`` and the Forces tab's live session (the one data path: its calibration's forces, the robot's states).

:class:`TrialsSession` holds the :class:`widgets.trials_panel.TrialsPanel` and the series, and moves them through
the panel's phases:

    Start series / Resume ─▶ moving (to the start pose) ─▶ waiting ("Place the robot, then Start trial k of N")
      ─▶ recording (the recording starts, then the motion; it runs on post_s after the motion) ─▶ marking
      (Traversed / Failed / Aborted + note) ─▶ moving … ─▶ complete

STOP (Esc or the status bar's button: ``lab.stop_requested``) while a trial records ends it at once: the motion
halts, the recording closes with ``run_stop`` ``abort``, the trial is kept and marked aborted, and the panel asks for
"Go to start pose" before anything moves again (so does a fault, or a STOP on the way to the start pose). Every step
is saved in the series folder's state file (``series.json``), so a crash loses nothing finished: Resume series…
goes on from where the series was (a trial cut short while recording is set aside and run again).

The recording is :meth:`app.core.live_session.LiveSession.start_recording` on the live session the Forces tab feeds
(``live`` gives it, building that tab if needed); ``lab.recording`` shows it in the status bar.

:class:`TrialsDock` is the main window's Trials dock (View ▸ Trials): the panel and its session for the window's lab
(:meth:`TrialsDock.attach_lab` on every lab; :meth:`TrialsDock.detach_lab` before a lab closes, which closes a trial
being recorded as stopped). GUI thread only.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, Qt, QTimer, Signal
from PySide6.QtWidgets import QDockWidget, QFileDialog, QWidget

from app.core import user_folders
from app.core.errors import TrialsError
from app.core.robot_trials import (
    ASK_OUTCOME,
    KEPT_ABORTED,
    NOT_RECORDED,
    RobotSeries,
    RobotSeriesOptions,
    start_motion,
    trial_motion,
    trial_shape,
)
from app.core.shapes import Shape, ShapeLibrary
from app.gui.robot_bridge import describe_error
from app.gui.thread_bridge import ThreadBridge
from widgets import theme
from widgets.trials_panel import SeriesForm, TrialsPanel

STOP_REASON = "STOP (button or Esc)"


def default_series_folder(now: float | None = None) -> Path:
    """A new series' folder: ``series-<date>-<time>`` under the recordings folder (where Open recording… looks)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    return user_folders.recordings_dir() / f"series-{stamp}"


class TrialsSession(QObject):
    """See the module docstring. ``live()``: the live session a recording is started on (None: no board)."""

    changed = Signal(str)  # the panel's phase, after every step

    def __init__(self, lab: Any, panel: TrialsPanel, live: Callable[[], Any], library: ShapeLibrary | None = None,
                 parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        self.robot = lab.robot
        self.panel = panel
        self._live_of = live
        self.library = library or ShapeLibrary()
        self._files: dict[str, Path] = {}  # shapes opened from files, by display name
        self._bridge = ThreadBridge(self)
        self.series: RobotSeries | None = None
        self.phase = "idle"
        self.trial = -1  # the trial recording or to be marked (0-based)
        self._shape: Shape | None = None
        self._live: Any = None
        self._recorder: Any = None
        self._stop_pressed = False
        self._token = 0  # a motion's outcome counts only while its token is the current one
        self._post_timer = QTimer(self)
        self._post_timer.setSingleShot(True)
        self._post_timer.timeout.connect(lambda: self._close_trial("success", ""))
        p = panel
        p.start_series_requested.connect(self.start_series)
        p.resume_requested.connect(self._choose_resume)
        p.browse_folder_requested.connect(self._choose_folder)
        p.open_shape_requested.connect(self._open_shape_file)
        p.go_to_start_requested.connect(self.go_to_start)
        p.start_trial_requested.connect(self.start_trial)
        p.outcome_marked.connect(self.mark)
        p.add_trial_requested.connect(self.add_trial)
        p.end_series_requested.connect(self.end_series)
        lab.stop_requested.connect(self._on_stop)
        panel.set_folder(str(default_series_folder()))
        self.refresh_shapes()

    # -- shapes ------------------------------------------------------------------------------------------------------
    def refresh_shapes(self) -> None:
        self.panel.set_shapes(self.library.names() + sorted(self._files))

    def add_shape_file(self, path: str | Path) -> str:
        """Offer a shape file outside the library; returns its display name."""
        path = Path(path)
        name = f"{path.stem} (file)"
        self._files[name] = path
        self.panel.set_shapes(self.library.names() + sorted(self._files), current=name)
        return name

    def _shape_path(self, name: str) -> Path:
        if not name:
            raise ValueError("no shape chosen: save one in the Teach tab or open a shape file (…)")
        return self._files[name] if name in self._files else self.library.path(name)

    def _open_shape_file(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self.panel, "Shape for the trials",
                                              user_folders.dialog_folder(self.library.root), "Shapes (*.json)")
        if path:
            self.add_shape_file(path)

    def _choose_folder(self) -> None:
        folder = QFileDialog.getExistingDirectory(self.panel, "Folder for the series",
                                                  user_folders.dialog_folder(user_folders.recordings_dir()))
        if folder:
            self.panel.set_folder(str(Path(folder) / default_series_folder().name))

    def _choose_resume(self) -> None:
        folder = QFileDialog.getExistingDirectory(self.panel, "Resume the series in",
                                                  user_folders.dialog_folder(user_folders.recordings_dir()))
        if folder:
            self.resume(folder)

    # -- a series ----------------------------------------------------------------------------------------------------
    def start_series(self, form: SeriesForm) -> bool:
        """A new series (or the one in the form's folder, of the same options): the robot goes to the start pose."""
        try:
            options = RobotSeriesOptions(
                shape=str(self._shape_path(form.shape).resolve()), trials=form.trials, mode=form.mode,
                speed_rad_s=form.speed_rad_s, start=str(self._shape_path(form.start).resolve()) if form.start else None,
                scene=form.scene, tail_load_n=form.tail_load_n, note=form.note)
            shape = trial_shape(options)
            trial_motion(options, self.robot.config, shape)  # a shape the robot cannot play: refused now
            start_motion(options, self.robot.config)
            series = RobotSeries.start(form.folder or default_series_folder(), options)
        except (OSError, ValueError) as exc:  # TrialsError, ShapeFormatError, JointLimitError are ValueErrors
            self.panel.set_status(f"series not started: {exc}", theme.ERROR)
            return False
        self._adopt(series, shape)
        self._log(f"start trial series in {series.folder} ({options.trials} trials of {Path(options.shape).stem})")
        self._next(move=True)
        return True

    def resume(self, folder: str | Path) -> bool:
        """Go on with the series in ``folder``: finished trials kept, a trial cut short set aside and run again, one
        recorded but not marked asked first. The robot moves only when asked (Go to start pose)."""
        try:
            series = RobotSeries.open(folder)
            shape = trial_shape(series.options)
            trial_motion(series.options, self.robot.config, shape)
        except (OSError, ValueError) as exc:
            self.panel.set_status(f"series not resumed: {exc}", theme.ERROR)
            return False
        self._adopt(series, shape)
        self._log(f"resume trial series in {series.folder}: {series.summary()}")
        self.panel.set_folder(str(series.folder))
        self._next(move=False, why="; ".join(series.recovered))
        return True

    def _adopt(self, series: RobotSeries, shape: Shape) -> None:
        self.series, self._shape = series, shape
        self.panel.set_status("", theme.IDLE)
        options = series.options
        self.panel.set_form(SeriesForm(
            shape=self._display_name(options.shape), start=self._display_name(options.start) if options.start else "",
            mode=options.mode, speed_rad_s=options.speed_rad_s, trials=options.trials, scene=options.scene,
            tail_load_n=options.tail_load_n, note=options.note, folder=str(series.folder)))
        self._show_rows()

    def _display_name(self, path: str) -> str:
        """A shape file's name in the form: its library name, else the file's own entry."""
        file = Path(path)
        if file.parent.resolve() == self.library.root.resolve() and file.stem in self.library.names():
            return file.stem
        return self.add_shape_file(file)

    def add_trial(self) -> None:
        series = self.series
        if series is None or self.phase in ("moving", "recording", "marking"):
            return
        try:
            series.add_trials(1)
        except TrialsError as exc:
            self.panel.set_status(str(exc), theme.ERROR)
            return
        self._show_rows()
        self._next(move=False, why=f"trial {series.n_trials} added")

    def end_series(self) -> None:
        """Close the series here (its folder keeps everything; Resume series… goes on with it)."""
        if self.phase in ("moving", "recording"):
            return
        series = self.series
        self.series, self._shape = None, None
        self.trial = -1
        if series is not None:
            self._log(f"end trial series in {series.folder}: {series.summary()}")
            self.panel.set_status(f"series closed: {series.summary()} in {series.folder}", theme.IDLE)
        self.panel.set_folder(str(default_series_folder()))
        self._set_phase("idle", "Start a series, or resume one")

    def _next(self, move: bool, why: str = "") -> None:
        """The series' next step: an outcome to mark, the move to the start pose (``move``) or the button for it,
        or the end."""
        series = self.series
        if series is None:
            return
        pending = series.pending_outcome()
        if pending is not None:
            self.trial = pending
            self._set_phase("marking", f"Trial {pending + 1} of {series.n_trials} recorded: mark its outcome", why)
            return
        k = series.next_trial()
        if k is None:
            self._set_phase("complete", f"Series complete: {series.summary()}",
                            f"{series.folder}: the recordings, series.json and trials.csv" + (f". {why}" if why else ""))
            return
        if move:
            self.go_to_start()
        else:
            self._set_phase("ready", f"Go to the start pose for trial {k + 1} of {series.n_trials}", why)

    # -- the steps of a trial ----------------------------------------------------------------------------------------
    def go_to_start(self) -> None:
        series = self.series
        if series is None or self.phase in ("moving", "recording"):
            return
        k = series.next_trial()  # None while an outcome is to be marked, or when every trial is finished
        if k is None:
            return
        if not self.robot.is_connected:
            self._set_phase("ready", f"Go to the start pose for trial {k + 1} of {series.n_trials}",
                            "the robot is not connected: connect it (Hardware tab → Connect), then Go to start pose")
            return
        source, name = start_motion(series.options, self.robot.config)
        self._stop_pressed = False
        self.panel.set_status("", theme.IDLE)
        self._set_phase("moving", f"Trial {k + 1} of {series.n_trials}: the robot goes to the start pose…",
                        "Esc or STOP halts it")
        token = self._new_token()
        future = self.robot.play(source, name)
        self.robot.when_done(future, lambda outcome: self._at_start(token, k, outcome),
                             lambda exc: self._start_failed(token, k, exc))

    def _at_start(self, token: int, k: int, outcome: object) -> None:
        if token != self._token or self.series is None:
            return
        if outcome == "finished":
            self._waiting(k)
            return
        why = STOP_REASON if self._stop_pressed else f"the move was {outcome}"
        self._waiting(k, f"the start pose was not reached ({why}): Go to start pose again, or place the robot in "
                         "it by hand")

    def _start_failed(self, token: int, k: int, exc: BaseException) -> None:
        if token != self._token or self.series is None:
            return
        self._set_phase("ready", f"Go to the start pose for trial {k + 1} of {self.series.n_trials}",
                        f"the start pose was not reached: {describe_error(exc)}")

    def _waiting(self, k: int, detail: str = "") -> None:
        series = self.series
        assert series is not None
        self._set_phase("waiting", series.prompt(k), detail or "the robot holds the start pose",
                        trial_label=f"Start trial {k + 1} of {series.n_trials}")

    def start_trial(self) -> bool:
        """Trial k: the recording starts, then the motion; False (and why in the panel) when it cannot."""
        series, shape = self.series, self._shape
        if series is None or shape is None or self.phase != "waiting":
            return False
        k = series.next_trial()
        if k is None:
            return False
        board: Any = getattr(self.lab, "board", None)
        live = self._live_of() if board is not None else None
        if live is None or not board.is_connected:
            self.panel.set_status(f"the force-sensor board is not connected ({self.lab.config.board.port}): a trial "
                                  "records its forces; connect it, then Start trial", theme.ERROR)
            return False
        if not self.robot.is_connected:
            self.panel.set_status("the robot is not connected: connect it first (Hardware tab → Connect)", theme.ERROR)
            return False
        busy = live.recorder
        if busy is not None and busy.running:
            self.panel.set_status(f"already recording to {busy.path} (Forces tab): stop that recording first",
                                  theme.ERROR)
            return False
        config = self.lab.config
        try:
            source, name = trial_motion(series.options, self.robot.config, shape)
            run_start = series.run_start(k, config_text=config.source_text,
                                         calibration_json=live.recording_calibration_json(), shape=shape)
            path = series.begin(k)
        except (OSError, ValueError) as exc:
            self.panel.set_status(f"trial {k + 1} not started: {exc}", theme.ERROR)
            return False
        try:
            recorder = live.start_recording(path, config.source_text, with_robot=True,
                                            n_joints=config.robot.n_joints, run_start=run_start,
                                            on_failed=lambda message: self._bridge.post(self._record_failed, message))
        except (OSError, ValueError, RuntimeError) as exc:
            series.ended(k, "fail", str(exc))  # no file was made: the trial is still to run
            self.panel.set_status(f"trial {k + 1} not started: {exc}", theme.ERROR)
            return False
        self._live, self._recorder, self.trial = live, recorder, k
        self.lab.recording = recorder
        self.panel.set_status("", theme.IDLE)
        self._stop_pressed = False
        self._set_phase("recording", f"Recording trial {k + 1} of {series.n_trials}: {name}",
                        f"{path} — Esc or STOP halts the robot; the trial is kept, marked aborted")
        self._log(f"trial {k + 1} of {series.n_trials}: recording {path.name}, playing {name}")
        token = self._new_token()
        future: Future = self.robot.play(source, name)
        self.robot.when_done(future, lambda outcome: self._motion_ended(token, outcome),
                             lambda exc: self._motion_failed(token, exc))
        return True

    def _motion_ended(self, token: int, outcome: object) -> None:
        if token != self._token or self.phase != "recording":
            return
        if outcome == "finished":
            post_s = self.series.options.post_s if self.series is not None else 0.0
            self._post_timer.start(int(round(max(post_s, 0.0) * 1000)))  # the recording runs on after the motion
            return
        self._close_trial("abort", STOP_REASON if self._stop_pressed else f"the motion was {outcome}")

    def _motion_failed(self, token: int, exc: BaseException) -> None:
        if token != self._token or self.phase != "recording":
            return
        self._close_trial("fail", describe_error(exc))

    def _on_stop(self) -> None:
        """STOP (any tab): the robot halts on its own (``lab.emergency_stop``); a trial in its recording's run-on
        after the motion ends here, aborted."""
        self._stop_pressed = True
        if self.phase == "recording" and self._post_timer.isActive():
            self._post_timer.stop()
            self._close_trial("abort", STOP_REASON)

    def _record_failed(self, message: str) -> None:
        if self.phase == "recording":
            self.panel.set_status(f"the recording failed: {message}; the robot was stopped", theme.ERROR)
            self.robot.stop_motion()
            self._close_trial("fail", f"recording failed: {message}")

    def _close_trial(self, exit_status: str, reason: str) -> None:
        series, k = self.series, self.trial
        if self.phase != "recording" or series is None:
            return
        self._post_timer.stop()
        self._new_token()
        live, self._live, self._recorder = self._live, None, None
        if live is not None:
            live.stop_recording(exit_status, reason)  # the file complete and its run_stop written
        if self.lab.recording is not None:
            self.lab.recording = None
        try:
            step = series.ended(k, exit_status, reason)
        except (OSError, ValueError) as exc:
            self.panel.set_status(f"trial {k + 1}: {exc}", theme.ERROR)
            step = KEPT_ABORTED
        self._show_rows()
        if step == NOT_RECORDED:
            self._log(f"trial {k + 1} ended ({reason}) before anything was recorded: it runs again")
            self._next(move=False, why=f"trial {k + 1} ended ({reason}) before anything was recorded: it runs again")
            return
        if step == ASK_OUTCOME:
            self._log(f"trial {k + 1} recorded: {series.trial_path(k).name}")
            self._set_phase("marking", f"Trial {k + 1} of {series.n_trials} recorded: mark its outcome",
                            "Traversed, Failed or Aborted; then the robot goes to the start pose for the next trial")
            return
        self._log(f"trial {k + 1} stopped ({reason}): kept, marked aborted")
        self._next(move=False, why=f"trial {k + 1} stopped ({reason}): kept, marked aborted")

    def mark(self, outcome: str, note: str = "") -> bool:
        """The operator's outcome of the trial just recorded; then the robot goes to the start pose of the next."""
        series, k = self.series, self.trial
        if series is None or self.phase != "marking":
            return False
        try:
            series.mark(k, outcome, note)
        except (OSError, ValueError) as exc:
            self.panel.set_status(f"outcome not saved: {exc}", theme.ERROR)
            return False
        self._log(f"trial {k + 1} marked {outcome}" + (f" ({note})" if note else ""))
        self.panel.set_status(f"trial {k + 1}: {outcome}", theme.OK)
        self._show_rows()
        self._next(move=True)
        return True

    # -- showing it --------------------------------------------------------------------------------------------------
    def _set_phase(self, phase: str, prompt: str, detail: str = "", trial_label: str = "Start trial") -> None:
        self.phase = phase
        self.panel.set_phase(phase, prompt, detail, trial_label)
        self.changed.emit(phase)

    def _show_rows(self) -> None:
        series = self.series
        if series is None:
            return
        rows = []
        for row in series.rows():
            duration = row["duration_s"]
            shown = f"{duration:.1f}" if isinstance(duration, float) and math.isfinite(duration) else ""
            rows.append((str(row["trial"] + 1), row["outcome"], row["exit_status"] or row["state"], shown,
                         row["file"], row["note"] or row["reason"]))
        self.panel.set_rows(rows)

    def _log(self, text: str) -> None:
        log = getattr(self.lab, "event_log", None)
        if log is not None:
            log.add("action", text, "Trials")

    def _new_token(self) -> int:
        self._token += 1
        return self._token

    def shutdown(self) -> None:
        """The window closes (or the lab changes) during a trial: the recording is closed as stopped, the trial kept,
        marked aborted (Resume series… goes on at the next one)."""
        self._post_timer.stop()
        if self.phase == "recording":
            self.robot.stop_motion()
            self._close_trial("abort", "the app was closed during the trial")
        self._bridge.close()


class TrialsDock(QDockWidget):
    """View ▸ Trials: the Trials panel and its :class:`TrialsSession` for the window's lab. ``host``: the main window
    (``build_tab(name)`` gives a tab's page, built without showing it: the Forces tab's live session records)."""

    def __init__(self, host: Any, parent: QWidget | None = None) -> None:
        super().__init__("Trials", parent)
        self.setObjectName("trials_dock")
        self.setAllowedAreas(Qt.DockWidgetArea.RightDockWidgetArea | Qt.DockWidgetArea.BottomDockWidgetArea
                             | Qt.DockWidgetArea.LeftDockWidgetArea)
        self.host = host
        self.panel: TrialsPanel | None = None
        self.session: TrialsSession | None = None

    def attach_lab(self, lab: Any) -> None:
        """A panel and a session on ``lab`` (the window's lab changed: a new config)."""
        self.detach_lab()
        panel = TrialsPanel(lab.config.robot.max_joint_speed_rad_s)
        self.panel = panel
        self.session = TrialsSession(lab, panel, self._live, parent=panel)
        self.setWidget(panel)

    def _live(self) -> Any:
        """The Forces tab's live session (the tab built if it was not), or None without a board."""
        page = self.host.build_tab("forces")
        return getattr(page, "live", None) if getattr(page, "board", None) is not None else None

    def detach_lab(self) -> None:
        """Before the lab closes: a trial being recorded is closed as stopped (kept, marked aborted)."""
        session, panel = self.session, self.panel
        self.session, self.panel = None, None
        if session is not None:
            session.shutdown()
        if panel is not None:
            panel.setParent(None)
            panel.deleteLater()

    def shutdown(self) -> None:
        self.detach_lab()
