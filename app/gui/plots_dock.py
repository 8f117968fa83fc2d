"""The Plots dock (View ▸ Plots): any live or recorded series on stacked plots with linked time axes, or as X–Y.

The data model is Qt-free (:mod:`app.core.series`): :class:`LiveSeries` rings for the live lab,
:class:`RecordingSeries` for an opened recording, :class:`PlotLayout` for what is plotted. This module wires them to
the view (:class:`widgets.plots_view.PlotsView`) and to the lab:

- live, while the dock is shown (and only then: hidden, it is subscribed to nothing and its timer is stopped), it
  takes the robot's states (``lab.robot.state_block``: goals, present angles, velocities, currents and a feedback
  controller's corrections), the servos' polled health (``lab.robot.health``), the board's blocks (``lab.board.block``:
  conductance; the board's last minute is taken on show) and the Forces tab's estimated forces, status codes and
  sensor health flags (its :class:`app.core.live_session.LiveSession`; a force series plotted while that tab was never
  opened builds it, in the background, since it is what estimates forces). One timer redraws at most
  :data:`REDRAW_HZ` and only when something new arrived; the rings have a fixed size;
- a recording (Open recording…) shows in the same plots on its own clock, with a time cursor; a layout saved beside it
  (``RUN.plots.json``) opens with it when the plots are empty or show none of its series. **3-D replay** opens it in
  the 3-D lab's replay: from then on that timeline and this cursor follow each other (the dock reads the replay's
  time while it shows the same file, and moves it when the cursor is moved here). The Forces tab's cursor too, while
  that tab shows the same recording: its dashed line and body map go where this cursor is put, and the mouse over
  its plots moves this cursor (and the replay); and its trial overlay's, while this recording is one of the trials
  overlaid: a line at the cursor's time from that trial's zero, which the user drags to move this cursor;
- layouts are saved beside the recording shown, or in the data folder's ``plots/`` (live), never over an existing
  file without asking (replace, keep both, or cancel); the last layout is kept in the window's settings.

GUI thread only.
"""

from __future__ import annotations

import json
import math
import os
import stat
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from PySide6.QtCore import QSettings, Qt, QTimer
from PySide6.QtWidgets import QDockWidget, QFileDialog, QMessageBox, QWidget

from app.core import series as sr
from app.core import user_folders
from app.core.errors import PlotLayoutError
from widgets import theme
from widgets.plots_view import CURRENT_PLOT, NEW_PLOT, NEW_XY_PLOT, CurveSpec, PlotsView, PlotViewSpec

REDRAW_HZ = 30.0
READOUT_EVERY_S = 0.25  # the live readout's numbers change 4 times a second (readable, and cheap)
XY_MAX_POINTS = 4000
SETTINGS_KEY = "plots/layout"
FORCE_SOURCES = (sr.FORCES, sr.HEALTH)  # live series the Forces tab estimates
SOURCE = "Plots"


class TabHost(Protocol):
    """What the dock asks of the main window: a built tab (or None), a tab built without showing it, a tab shown."""

    def tab_widget(self, name: str) -> QWidget | None: ...

    def build_tab(self, name: str) -> QWidget: ...

    def show_tab(self, name: str) -> QWidget: ...


def _format(value: float) -> str:
    return "—" if not math.isfinite(value) else f"{value:.4g}"


class PlotsDock(QDockWidget):
    """See the module docstring. ``attach_lab(lab)`` for every lab the window holds; ``shutdown()`` on close."""

    def __init__(self, host: TabHost, settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__("Plots", parent)
        self.setObjectName("plots_dock")
        self.setAllowedAreas(Qt.DockWidgetArea.AllDockWidgetAreas)
        self.host = host
        self.settings = settings
        self.view = PlotsView(sr.WINDOWS_S)
        self.setWidget(self.view)
        self.lab: Any = None
        self.live: sr.LiveSeries | None = None
        self.recording: sr.RecordingSeries | None = None
        self.layout_model = self._stored_layout()
        self._infos: dict[str, sr.SeriesInfo] = {}
        self._subscribed = False
        self._forces_tab: Any = None
        self._drawn_version = -1
        self._paused = False
        self._readout_s = 0.0
        self._replay_seen: float | None = None
        self._forces_seen: float | None = None
        self._overlay_seen: tuple[float | None, float] | None = None  # (its cursor, this recording's zero) as put
        self.redraws = 0
        # Questions (tests answer them instead of a person): a path to open or save, what to do about a file there.
        self.ask_open_path: Callable[[str, str, str], str] = self._dialog_open_path
        self.ask_save_path: Callable[[str, str], str] = self._dialog_save_path
        self.ask_existing: Callable[[Path], str] = self._dialog_existing
        self._timer = QTimer(self)
        self._timer.setInterval(int(1000 / REDRAW_HZ))
        self._timer.timeout.connect(self._tick)
        v = self.view
        v.series_added.connect(self.add_series)
        v.series_removed.connect(lambda plot, key: self.set_layout(self.layout_model.removing(plot, key)))
        v.plot_removed.connect(lambda plot: self.set_layout(self.layout_model.removing(plot)))
        v.xy_plot_requested.connect(lambda: self.set_layout(self.layout_model.adding_plot(sr.XY)))
        v.clear_requested.connect(lambda: self.set_layout(replace(self.layout_model, plots=())))
        v.cursor_moved.connect(self._cursor_moved)
        v.time_range_changed.connect(self.redraw)
        v.open_requested.connect(self._choose_recording)
        v.live_requested.connect(self.show_live)
        v.replay_requested.connect(self.open_replay)
        v.save_layout_requested.connect(self._choose_save_layout)
        v.open_layout_requested.connect(self._choose_open_layout)
        v.window_changed.connect(self.set_window)
        v.pause_toggled.connect(self._set_paused)
        v.set_window(self.layout_model.window_s)
        self.visibilityChanged.connect(self._visibility_changed)

    # -- the lab ---------------------------------------------------------------------------------------------------
    def attach_lab(self, lab: Any) -> None:
        """Plot ``lab``'s live series from now on (the window's lab changed: a new config)."""
        self._unsubscribe()
        self._forces_tab = None  # the old lab's tabs are gone
        self.lab = lab
        config = lab.config
        board = getattr(lab, "board", None)
        t0 = float(board.t0_monotonic_s) if board is not None else time.monotonic()
        self.live = sr.LiveSeries(config.board.channel_names, config.robot.joint_ids, t0,
                                  robot_rate_hz=config.robot.control_rate_hz, board_rate_hz=config.board.rate_hz,
                                  history_s=sr.LIVE_HISTORY_S)
        self._drawn_version = -1
        if self.recording is None:
            self._show_catalog()
        if self.isVisible():
            self._subscribe()

    def _source(self) -> sr.LiveSeries | sr.RecordingSeries | None:
        return self.recording if self.recording is not None else self.live

    @property
    def showing_live(self) -> bool:
        return self.recording is None

    def _show_catalog(self) -> None:
        source = self._source()
        if source is None:
            return
        infos = source.catalog()
        self._infos = {i.key: i for i in infos}
        if isinstance(source, sr.RecordingSeries):
            start, end = source.span()
            title = f"Recording: {source.name} ({end - start:.1f} s)"
        else:
            title = "Live"
        self.view.set_catalog(infos, title)
        self.view.set_live(self.recording is None)
        self._apply_layout()

    # -- live subscription (only while shown) ----------------------------------------------------------------------
    def _visibility_changed(self, visible: bool) -> None:
        if visible:
            self._subscribe()
            self._timer.start()
            self._drawn_version = -1
            self.redraw()
        else:
            self._timer.stop()
            self._unsubscribe()

    @property
    def subscribed(self) -> bool:
        """True while the dock takes live data (it is shown)."""
        return self._subscribed

    def _subscribe(self) -> None:
        lab, live = self.lab, self.live
        if self._subscribed or lab is None or live is None:
            return
        self._subscribed = True
        robot = lab.robot
        robot.state_block.connect(self._on_states)
        robot.health.connect(self._on_servo_health)
        board = getattr(lab, "board", None)
        if board is not None:
            key = sr.conductance_key(live.channel_names[0]) if live.channel_names else ""
            newest = live.newest_s([key]) if key else -math.inf
            for block in board.recent_blocks():  # the board's last minute, what the rings do not hold yet
                live.add_block(block, after_s=newest)
            board.block.connect(self._on_block)
        self._follow_forces_tab(build=self._wants_forces())

    def _unsubscribe(self) -> None:
        if not self._subscribed:
            return
        self._subscribed = False
        lab = self.lab
        for signal, slot in ((lab.robot.state_block, self._on_states), (lab.robot.health, self._on_servo_health)):
            signal.disconnect(slot)
        board = getattr(lab, "board_if_created", None)
        if board is not None:
            board.block.disconnect(self._on_block)
        forces = self._forces_tab
        if forces is not None:
            forces.live.unsubscribe(self._on_live_update)

    def _wants_forces(self) -> bool:
        live = self.live
        keys = self.layout_model.series_keys()
        return live is not None and any(live.source_of(k) in FORCE_SOURCES for k in keys)

    def _follow_forces_tab(self, build: bool = False) -> None:
        """Take the Forces tab's estimates once it exists (built here when ``build``: a force series is plotted)."""
        if not self._subscribed or self._forces_tab is not None:
            return
        tab = self.host.tab_widget("forces")
        if tab is None and build:
            tab = self.host.build_tab("forces")
            self.say("forces are estimated by the Forces tab: it was opened in the background for the plots")
        live_session = getattr(tab, "live", None)
        if live_session is None:
            return
        self._forces_tab = tab
        live_session.subscribe(self._on_live_update)

    def _on_states(self, states: Sequence[Any]) -> None:
        if self.live is not None:
            self.live.add_states(states)

    def _on_servo_health(self, healths: Sequence[Any]) -> None:
        if self.live is not None:
            self.live.add_servo_health(time.monotonic(), healths)

    def _on_block(self, block: Any) -> None:
        if self.live is not None:
            self.live.add_block(block)

    def _on_live_update(self, update: Any) -> None:
        live, forces = self.live, update.forces
        if live is None or forces is None or len(update.block) == 0:
            return
        host_time = np.asarray(update.block.host_time_s, dtype=float)
        live.add_forces(host_time, forces.force_n, forces.status)
        health = getattr(self._forces_tab, "health", None)
        if health is not None:
            live.add_health(float(host_time[-1]), health.flags)

    # -- drawing ---------------------------------------------------------------------------------------------------
    def _tick(self) -> None:
        if self.recording is not None:
            self._follow_replay()
            self._follow_forces_cursor()
            self._follow_overlay_cursor()
            return
        if self._forces_tab is None:
            self._follow_forces_tab()
        live = self.live
        if live is None or self._paused or live.version == self._drawn_version:
            return
        self.redraw()

    def redraw(self) -> None:
        """Draw every plot from the source shown (live: the last ``window_s``; a recording: the time range shown)."""
        if not self.isVisible():
            return
        self.redraws += 1
        if self.recording is not None:
            self._draw_recording(self.recording)
        elif self.live is not None:
            self._drawn_version = self.live.version
            self._draw_live(self.live)
        self.view.finish_frame()

    def _draw_live(self, live: sr.LiveSeries) -> None:
        keys = [k for k in self.layout_model.series_keys() if live.has(k)]
        newest = live.newest_s(keys)
        if not math.isfinite(newest):
            return
        t0, t1 = newest - self.layout_model.window_s, newest
        width = self.view.plot_width_px()
        for index, plot in enumerate(self.layout_model.plots):
            if plot.kind == sr.TIME:
                for curve, key in enumerate(plot.series):
                    x, y = live.window(key, t0, t1, width) if live.has(key) else (np.zeros(0), np.zeros(0))
                    self.view.set_curve(index, curve, x - newest, y)
            else:
                self._draw_xy(index, plot, live, t0, t1, None)
        now = time.monotonic()
        if now - self._readout_s >= READOUT_EVERY_S:
            self._readout_s = now
            self.view.set_readout(self._readout_text(live, newest, "newest"))

    def _draw_recording(self, recording: sr.RecordingSeries) -> None:
        t0, t1 = self.view.time_range()
        if not any(p.kind == sr.TIME for p in self.layout_model.plots):
            t0, t1 = recording.span()
        width = self.view.plot_width_px()
        for index, plot in enumerate(self.layout_model.plots):
            if plot.kind == sr.TIME:
                for curve, key in enumerate(plot.series):
                    x, y = (self._read_window(recording, key, t0, t1, width) if recording.has(key)
                            else (np.zeros(0), np.zeros(0)))
                    self.view.set_curve(index, curve, x, y)
            else:
                self._draw_xy(index, plot, recording, t0, t1, self.view.cursor_s)
        self._show_cursor_values()

    def _read_window(self, source: sr.RecordingSeries, key: str, t0: float, t1: float,
                     width: int) -> tuple[np.ndarray, np.ndarray]:
        try:
            return source.window(key, t0, t1, width)
        except (OSError, ValueError) as exc:
            self.say(str(exc), theme.ERROR)
            return np.zeros(0), np.zeros(0)

    def _draw_xy(self, index: int, plot: sr.PlotSpec, source: sr.LiveSeries | sr.RecordingSeries, t0: float,
                 t1: float, cursor_s: float | None) -> None:
        if not plot.series or not source.has(plot.series[0]):
            for curve in range(max(0, len(plot.series) - 1)):
                self.view.set_curve(index, curve, np.zeros(0), np.zeros(0))
            return
        tx, vx = self._span_of(source, plot.series[0], t0, t1)
        if tx.size > XY_MAX_POINTS:
            step = int(math.ceil(tx.size / XY_MAX_POINTS))
            tx, vx = tx[::step], vx[::step]
        marks_x, marks_y = [], []
        for curve, key in enumerate(plot.series[1:]):
            if not source.has(key):
                self.view.set_curve(index, curve, np.zeros(0), np.zeros(0))
                continue
            ty, vy = self._span_of(source, key, t0, t1)
            y = sr.resample(ty, vy, tx)
            self.view.set_curve(index, curve, vx, y)
            if cursor_s is not None and tx.size:
                marks_x.append(float(sr.resample(tx, vx, np.array([cursor_s]))[0]))
                marks_y.append(float(sr.resample(ty, vy, np.array([cursor_s]))[0]))
        self.view.set_marker(index, np.array(marks_x), np.array(marks_y))

    def _span_of(self, source: sr.LiveSeries | sr.RecordingSeries, key: str, t0: float,
                 t1: float) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(source, sr.LiveSeries):
            return source.read(key, t0, t1)
        t, v = source.read(key)
        i0, i1 = int(np.searchsorted(t, t0, "left")), int(np.searchsorted(t, t1, "right"))
        return t[i0:i1], v[i0:i1]

    def _readout_text(self, source: sr.LiveSeries | sr.RecordingSeries, t_s: float, what: str) -> str:
        parts = []
        for key in self.layout_model.series_keys():
            info = self._infos.get(key)
            if info is None or not source.has(key):
                continue
            try:
                value = source.value_at(key, t_s)
            except (OSError, ValueError):
                value = math.nan
            parts.append(f"{info.label} {_format(value)} {info.unit}")
        return f"{what} t = {t_s:.3f} s — " + " · ".join(parts) if parts else ""

    def _show_cursor_values(self) -> None:
        recording, cursor = self.recording, self.view.cursor_s
        if recording is None or cursor is None:
            return
        self.view.set_readout(self._readout_text(recording, cursor, "cursor"))

    # -- the layout ------------------------------------------------------------------------------------------------
    def add_series(self, keys: Sequence[str], plot: int = NEW_PLOT) -> None:
        """Put ``keys`` on plot ``plot`` (an index, ``NEW_PLOT``, ``CURRENT_PLOT`` or ``NEW_XY_PLOT``; several keys
        on a new plot go on one plot; on a new X–Y plot the first is x)."""
        keys = list(keys)
        if not keys:
            return
        layout = self.layout_model
        if plot == CURRENT_PLOT:
            current = self.view.current_plot
            plot = current if 0 <= current < len(layout.plots) else NEW_PLOT
        if plot in (NEW_XY_PLOT, NEW_PLOT):
            kind = sr.XY if plot == NEW_XY_PLOT else sr.TIME
            layout = layout.adding_plot(kind)
            plot = len(layout.plots) - 1
        for key in keys:
            layout = layout.adding(key, plot)
        self.view.current_plot = plot
        self.set_layout(layout)
        self._explain_missing_forces(keys)

    def _explain_missing_forces(self, keys: Sequence[str]) -> None:
        """Say why a force series plotted live draws nothing: its sensor has no calibration."""
        live, tab = self.live, self._forces_tab
        if self.recording is not None or live is None or tab is None:
            return
        estimated = getattr(getattr(tab, "pipeline", None), "estimated", None)
        if estimated is None:
            return
        names = [k.split("/")[1] for k in keys if k.startswith("forces/") and k.endswith("/force_N")]
        missing = [n for n in names if n in live.channel_names and not estimated[live.channel_names.index(n)]]
        if missing:
            self.say(f"{', '.join(missing)}: no calibration, so no force (load one in the Forces tab, or plot the "
                     "conductance)", theme.WARN)

    def set_layout(self, layout: sr.PlotLayout) -> None:
        """Show ``layout`` (kept in the window's settings)."""
        self.layout_model = layout
        self._apply_layout()
        if self.settings is not None:
            self.settings.setValue(SETTINGS_KEY, layout.to_json())

    def _apply_layout(self) -> None:
        layout, source = self.layout_model, self._source()
        specs = []
        for plot in layout.plots:
            curves = []
            for key in plot.series:
                info = self._infos.get(key)
                text = info.text if info is not None else key
                curves.append(CurveSpec(key, text, source is not None and source.has(key),
                                        bool(info is not None and info.steps)))
            specs.append(PlotViewSpec(plot.kind, tuple(curves)))
        had_time_axis = any(p.kind == sr.TIME for p in self.view.plots)
        self.view.set_plots(specs)
        if self.recording is not None:
            self.recording.keep_only(layout.series_keys())
            if not had_time_axis:  # the first time plot on a recording shows all of it
                start, end = self.recording.span()
                self.view.set_time_range(start, end if end > start else start + 1.0)
        else:
            self.view.set_time_range(-layout.window_s, 0.0)
        if self._subscribed and self.recording is None and self._wants_forces():
            self._follow_forces_tab(build=True)
        self._drawn_version = -1
        self.redraw()

    def _stored_layout(self) -> sr.PlotLayout:
        text = self.settings.value(SETTINGS_KEY, "") if self.settings is not None else ""
        if isinstance(text, str) and text:
            try:
                return sr.parse_layout(text, "the window's settings")
            except PlotLayoutError:
                pass  # an older or damaged entry: start empty
        return sr.PlotLayout()

    def set_window(self, seconds: float) -> None:
        """The live time window (s)."""
        self.view.set_window(seconds)
        self.set_layout(replace(self.layout_model, window_s=float(seconds)))

    def _set_paused(self, paused: bool) -> None:
        self._paused = paused
        if not paused:
            self._drawn_version = -1

    # -- recordings ------------------------------------------------------------------------------------------------
    def open_recording(self, path: str | Path) -> bool:
        """Plot ``path``'s series (the plots kept; a layout beside it opens when they show none of its series)."""
        try:
            recording = sr.RecordingSeries(path)
        except (OSError, ValueError) as exc:
            self.say(f"cannot plot {path}: {exc}", theme.ERROR)
            return False
        self.recording = recording
        self._replay_seen = self._forces_seen = None
        if self._overlay_seen is not None:
            self._overlay_seen = (None, math.nan)  # put for another recording: put again, or taken away
        self._log("action", f"plot recording {recording.path}")
        beside = sr.layout_beside(recording.path)
        keys = self.layout_model.series_keys()
        note = ""
        if beside.is_file() and not any(recording.has(k) for k in keys):
            try:
                self.layout_model = replace(sr.read_layout(beside), window_s=self.layout_model.window_s)
                note = f"; its layout {beside.name} opened"
            except (OSError, ValueError) as exc:
                note = f"; its layout {beside.name} not opened: {exc}"
        start, end = recording.span()
        self.view.set_cursor(start)
        self._show_catalog()
        self.view.set_time_range(start, end if end > start else start + 1.0)
        self.redraw()
        missing = [k for k in self.layout_model.series_keys() if not recording.has(k)]
        level = theme.WARN if missing or "not opened" in note else theme.OK
        tail = f"; not in it: {', '.join(missing)}" if missing else ""
        self.say(f"showing {recording.name}{note}{tail}", level)
        return True

    def show_live(self) -> None:
        """The live lab again, in the same plots."""
        self.recording = None
        self.view.set_cursor(None)
        self._drop_overlay_cursor()
        self._show_catalog()
        self.say("showing the live lab", theme.OK)

    def _choose_recording(self) -> None:
        folder = user_folders.dialog_folder(user_folders.recordings_dir())
        path = self.ask_open_path("Plot a recording", folder, "Recordings (*.h5 *.hdf5);;All files (*)")
        if path:
            self.open_recording(path)

    # -- the time cursor and the 3-D replay ------------------------------------------------------------------------
    def _scene_on_this_recording(self) -> Any:
        """The 3-D lab tab when its replay shows the recording plotted here, else None."""
        recording = self.recording
        scene = self.host.tab_widget("scene")
        replay = getattr(scene, "replay", None)
        if recording is None or replay is None:
            return None
        try:
            same = Path(replay.path).resolve() == recording.path.resolve()
        except OSError:
            return None
        return scene if same else None

    def _forces_on_this_recording(self) -> Any:
        """The Forces tab when it shows the recording plotted here, else None."""
        recording = self.recording
        forces = self.host.tab_widget("forces")
        viewed = getattr(forces, "viewed", None)
        if recording is None or viewed is None or not hasattr(forces, "put_cursor"):
            return None
        try:
            same = Path(viewed.path).resolve() == recording.path.resolve()
        except OSError:
            return None
        return forces if same else None

    def _overlay_of_this_recording(self) -> tuple[Any, float] | None:
        """(the Forces tab's trial overlay, this recording's time zero there) when it is one of the trials
        overlaid, else None."""
        recording = self.recording
        forces: Any = self.host.tab_widget("forces")
        zeros = getattr(forces, "overlay_zero_s", None)
        if recording is None or not zeros:
            return None
        try:
            zero = zeros.get(recording.path.resolve())
        except OSError:
            return None
        return None if zero is None else (forces.overlay, float(zero))

    def _put_overlay_cursor(self, overlay: Any, zero_s: float, t_s: float) -> None:
        overlay.set_cursor(t_s - zero_s)
        self._overlay_seen = (overlay.cursor_s, zero_s)

    def _drop_overlay_cursor(self) -> None:
        """The trial overlay's line put from here goes: the overlay no longer shows this recording."""
        if self._overlay_seen is None:
            return
        self._overlay_seen = None
        overlay = getattr(self.host.tab_widget("forces"), "overlay", None)
        if overlay is not None and hasattr(overlay, "set_cursor"):
            overlay.set_cursor(None)

    def _follow_overlay_cursor(self) -> None:
        """The user dragged the trial overlay's cursor: the cursor goes to that time on this recording's clock. An
        overlay that has just taken this recording (or changed its time zero) takes the cursor from here; one that
        no longer shows it loses the line put there."""
        overlaid = self._overlay_of_this_recording()
        if overlaid is None:
            self._drop_overlay_cursor()
            return
        overlay, zero_s = overlaid
        cursor = self.view.cursor_s
        seen = self._overlay_seen
        if seen is None or seen[1] != zero_s or overlay.cursor_s is None:
            if cursor is not None:
                self._put_overlay_cursor(overlay, zero_s, cursor)
            return
        if overlay.cursor_s == seen[0]:
            return
        self._overlay_seen = (overlay.cursor_s, zero_s)
        self._sync_cursor(float(overlay.cursor_s) + zero_s, "overlay")

    def _cursor_moved(self, t_s: float) -> None:
        """The user put the cursor at ``t_s``: the readout, the X–Y markers, the 3-D replay and the Forces tab
        follow."""
        self._sync_cursor(t_s, "plots")

    def _sync_cursor(self, t_s: float, moved_in: str) -> None:
        """The time cursor is at ``t_s``, moved ``moved_in`` the ``plots`` here, the 3-D ``replay``, the ``forces``
        tab or its trial ``overlay``: every other view showing this recording goes there."""
        t0, t1 = self.view.time_range()
        if moved_in != "plots":
            self.view.set_cursor(t_s)
        if moved_in != "plots" and not t0 <= t_s <= t1:  # keep the cursor in view: the axes move by their width
            self.view.set_time_range(t_s - 0.5 * (t1 - t0), t_s + 0.5 * (t1 - t0))
            self.redraw()
        else:
            self._refresh_cursor()
        scene = self._scene_on_this_recording() if moved_in != "replay" else None
        if scene is not None:
            scene.seek(t_s)
            self._replay_seen = float(scene.replay_time_s)
        forces = self._forces_on_this_recording() if moved_in != "forces" else None
        if forces is not None:
            forces.put_cursor(t_s)
            self._forces_seen = forces.plots.cursor_s
        overlaid = self._overlay_of_this_recording() if moved_in != "overlay" else None
        if overlaid is not None:
            self._put_overlay_cursor(*overlaid, t_s)

    def _refresh_cursor(self) -> None:
        recording = self.recording
        if recording is None:
            return
        if any(p.kind == sr.XY for p in self.layout_model.plots):
            self.redraw()
        else:
            self._show_cursor_values()

    def _follow_replay(self) -> None:
        """The 3-D replay moved (scrubbed, played, stepped): the cursor goes there, the time axes with it."""
        scene = self._scene_on_this_recording()
        if scene is None:
            return
        t_s = float(scene.replay_time_s)
        if t_s == self._replay_seen:
            return
        self._replay_seen = t_s
        if self.view.cursor_s is not None and abs(self.view.cursor_s - t_s) < 1e-9:
            return
        self._sync_cursor(t_s, "replay")

    def _follow_forces_cursor(self) -> None:
        """The mouse moved the Forces tab's cursor on this recording: the cursor goes there (the replay with it). A
        Forces tab that has just opened this recording takes the cursor from here."""
        forces = self._forces_on_this_recording()
        if forces is None:
            self._forces_seen = None
            return
        t_s = forces.plots.cursor_s
        if t_s is None:
            if self.view.cursor_s is not None:
                forces.put_cursor(self.view.cursor_s)
                self._forces_seen = forces.plots.cursor_s
            return
        if t_s == self._forces_seen:
            return
        self._forces_seen = t_s
        if self.view.cursor_s is not None and abs(self.view.cursor_s - t_s) < 1e-9:
            return
        self._sync_cursor(float(t_s), "forces")

    def open_replay(self) -> bool:
        """Open the recording shown here in the 3-D lab's replay, at the cursor; its timeline and this cursor follow
        each other from then on."""
        recording = self.recording
        if recording is None:
            return False
        scene: Any = self.host.show_tab("scene")
        opener = getattr(scene, "open_replay", None)
        if opener is None or not opener(recording.path):
            self.say(f"{recording.name} cannot be replayed in 3-D (see the 3-D lab tab for why)", theme.WARN)
            return False
        if self.view.cursor_s is not None:
            scene.seek(self.view.cursor_s)
        self._replay_seen = float(scene.replay_time_s)
        return True

    # -- saving and opening layouts --------------------------------------------------------------------------------
    def suggested_layout_path(self) -> Path:
        if self.recording is not None:
            return sr.layout_beside(self.recording.path)
        return user_folders.plot_layouts_dir() / f"layout-{time.strftime('%Y%m%d-%H%M%S')}{sr.LAYOUT_SUFFIX}"

    def save_layout(self, path: str | Path, replace_existing: bool | None = None) -> Path | None:
        """Save the layout at ``path``. A file there is replaced only when ``replace_existing`` is True, or when the
        user, asked (``replace_existing`` None), chooses to; "keep both" saves it as ``NAME-2.plots.json``."""
        path = Path(path)
        try:
            user_folders.ensure_folder(path.parent)
            try:
                written = sr.write_layout(self.layout_model, path, replace_existing=bool(replace_existing))
            except FileExistsError:
                if replace_existing is not None or not _is_regular_file(path):
                    raise  # a folder, link, device or FIFO there is never offered for replacing: said as it is
                choice = self.ask_existing(path)
                if choice == "replace":
                    written = sr.write_layout(self.layout_model, path, replace_existing=True)
                elif choice == "keep":
                    written = sr.write_layout(self.layout_model, sr.free_path(path))
                else:
                    self.say(f"layout not saved: {path.name} kept as it was", theme.IDLE)
                    return None
        except (OSError, ValueError) as exc:
            self.say(f"layout not saved: {exc}", theme.ERROR)
            return None
        self.say(f"layout saved: {written}", theme.OK)
        self._log("action", f"save plot layout {written}")
        return written

    def open_layout(self, path: str | Path) -> bool:
        """Show the layout saved at ``path``; series the source shown does not hold are named."""
        try:
            layout = sr.read_layout(path)
        except (OSError, ValueError) as exc:
            self.say(f"layout not opened: {exc}", theme.ERROR)
            return False
        self.view.set_window(layout.window_s)
        self.set_layout(layout)
        source = self._source()
        missing = [k for k in layout.series_keys() if source is None or not source.has(k)]
        tail = f"; not in what is shown: {', '.join(missing)}" if missing else ""
        self.say(f"layout {Path(path).name} opened{tail}", theme.WARN if missing else theme.OK)
        self._log("action", f"open plot layout {path}")
        return True

    def _choose_save_layout(self) -> None:
        suggested = self.suggested_layout_path()
        user_folders.dialog_folder(suggested.parent)
        path = self.ask_save_path("Save the plot layout", str(suggested))
        if path:
            self.save_layout(path)

    def _choose_open_layout(self) -> None:
        folder = (str(self.recording.path.parent) if self.recording is not None
                  else user_folders.dialog_folder(user_folders.plot_layouts_dir()))
        path = self.ask_open_path("Open a plot layout", folder, "Plot layouts (*.plots.json *.json);;All files (*)")
        if path:
            self.open_layout(path)

    def _dialog_open_path(self, title: str, folder: str, filters: str) -> str:
        path, _filter = QFileDialog.getOpenFileName(self, title, folder, filters)
        return path

    def _dialog_save_path(self, title: str, suggested: str) -> str:
        path, _filter = QFileDialog.getSaveFileName(self, title, suggested,
                                                    "Plot layouts (*.plots.json);;All files (*)",
                                                    options=QFileDialog.Option.DontConfirmOverwrite)
        return path

    def _dialog_existing(self, path: Path) -> str:
        box = QMessageBox(QMessageBox.Icon.Question, "A layout is there already",
                          f"{path.name} exists in {path.parent}.", parent=self)
        box.setInformativeText("Replace it with this layout, or keep it and save this one beside it as "
                               f"{sr.free_path(path).name}?")
        replace_button = box.addButton("Replace", QMessageBox.ButtonRole.DestructiveRole)
        keep_button = box.addButton("Keep both", QMessageBox.ButtonRole.AcceptRole)
        box.addButton(QMessageBox.StandardButton.Cancel)
        box.setDefaultButton(keep_button)
        box.exec()
        clicked = box.clickedButton()
        return "replace" if clicked is replace_button else "keep" if clicked is keep_button else "cancel"

    # -- messages and life cycle -----------------------------------------------------------------------------------
    def say(self, text: str, level: str = theme.IDLE) -> None:
        """On the dock's message line, and in the event log (a fault when ``level`` is error, a warning when warn)."""
        self.view.set_message(text, level)
        self._log({theme.ERROR: "fault", theme.WARN: "warning"}.get(level, "info"), text)

    def _log(self, kind: str, text: str) -> None:
        log = getattr(self.lab, "event_log", None)
        if log is not None and text:
            log.add(kind, text, SOURCE)

    def layout_json(self) -> str:
        """The layout shown, as its file would hold it."""
        return json.dumps(self.layout_model.to_document())

    def shutdown(self) -> None:
        """Stop the timer and take no more live data (the window closes)."""
        self._timer.stop()
        self._unsubscribe()


def _is_regular_file(path: Path) -> bool:
    """A regular file itself at ``path`` (not a link to one, a folder, a device or a FIFO)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False
