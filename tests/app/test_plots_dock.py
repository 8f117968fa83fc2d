"""The Plots dock in the window (offscreen): a user puts joint 5's current and S06B's force on linked time axes live,
records, reopens the recording in the same plots, saves the layout beside it and gets it back; a file there is
never replaced without asking; hidden, the dock takes no data; its time cursor and the 3-D replay follow each
other; X–Y plots; a layout naming series the source lacks says which."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from PySide6.QtCore import QPointF, QSettings, Qt
from PySide6.QtGui import QDropEvent

from app.core import series as sr
from devices.config import SIM_PORT, LabConfig, RobotConfig
from tests.app.test_series import write_recording
from tests.app.windows import open_connected_window
from tests.calibration_files import write_typical_calibration
from tests.conftest import scripted_config
from tests.motion_sources import JointRamp
from widgets.plots_view import NEW_PLOT

J5_CURRENT, S06B_FORCE = "robot/J5/current_mA", "forces/S06B/force_N"


@pytest.fixture
def window(qtbot, install_fast_sim_lab, tmp_path, monkeypatch):
    install_fast_sim_lab(speed=2.0)  # the plots follow the host's clock: no need to hurry the lab (a busy machine)
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    from devices.config import load_config

    config = scripted_config(load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT))
    win = open_connected_window(qtbot, config, tmp_path, 15_000)
    win.resize(1600, 1000)
    with qtbot.waitSignal(win.lab.board.connected, timeout=15_000):
        win.lab.board.start()
    yield win
    win.close()


@pytest.fixture
def idle_window(qtbot, tmp_path):
    """The window with no robot and no board running (recordings only)."""
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow

    lab = LabContext(LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port")))
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.resize(1400, 900)
    win.show()
    yield win
    win.close()


def drawn(plot, curve=0):
    item = plot.curves[curve]
    return (np.zeros(0), np.zeros(0)) if item.xData is None else (item.xData, item.yData)


def drop(view, keys_leaves, at: str = "new"):
    """Drag the tree's ``keys_leaves`` onto the plots: ``new`` (the strip below them) or a plot index."""
    mime = view.picker.tree.mimeData(keys_leaves)
    target = view._strip if at == "new" else view.plots[int(at)].item
    point = view.graphics.mapFromScene(target.sceneBoundingRect().center())
    event = QDropEvent(QPointF(point), Qt.DropAction.CopyAction, mime, Qt.MouseButton.LeftButton,
                       Qt.KeyboardModifier.NoModifier)
    view.graphics.dropEvent(event)


def wait_calibrated(qtbot, forces) -> None:
    qtbot.waitUntil(lambda: not getattr(forces, "is_loading_calibration", False), timeout=30_000)


def test_joint_5_current_and_s06b_force_on_linked_axes_live_then_on_the_reopened_recording(window, qtbot, tmp_path):
    lab = window.lab
    dock, view = window.plots_dock, window.plots_dock.view
    forces = window.build_tab("forces")  # a calibration, so S06B has a force
    assert forces.load_calibration(write_typical_calibration(tmp_path / "typical.json",
                                                             lab.config.board.channel_names))
    wait_calibrated(qtbot, forces)
    window.plots_action.trigger()  # View ▸ Plots
    qtbot.waitUntil(lambda: dock.isVisible() and dock.subscribed)
    lab.robot.set_torque(True).result(timeout=30)
    lab.robot.run_motion(JointRamp(index=4, speed_rad_s=0.3), "ramp")  # joint 5 moves: its current changes

    # joint 5's current: found by searching, added by a double click (the first plot)
    view.picker.search.setText("J5 current")
    assert view.picker.visible_keys() == [J5_CURRENT]
    view.picker.tree.itemDoubleClicked.emit(view.picker.leaf(J5_CURRENT), 0)
    # S06B's force: dragged from the tree onto the strip below the plots (a second plot, its time axis linked)
    view.picker.search.setText("s06b force")
    assert "forces/S06B/force_N" in view.picker.visible_keys()
    drop(view, [view.picker.leaf(S06B_FORCE)], "new")
    assert [p.keys for p in view.plots] == [[J5_CURRENT], [S06B_FORCE]]
    assert view.plots[1].vb.linkedView(0) is view.plots[0].vb  # linked time axes
    assert "J5 current (mA)" in view.header_text(0) and "S06B force (N)" in view.header_text(1)

    def has_live_data() -> bool:
        (x0, y0), (x1, y1) = drawn(view.plots[0]), drawn(view.plots[1])
        return x0.size > 10 and x1.size > 10 and np.isfinite(y1).sum() > 10 and np.isfinite(y0).sum() > 10

    qtbot.waitUntil(has_live_data, timeout=30_000)
    x, y = drawn(view.plots[1])
    t_live, v_live = dock.live.read(S06B_FORCE)
    # x: time before the newest sample of the plotted series (a source drained late ends short of 0)
    assert x.max() <= 0.0 and x.min() >= -dock.layout_model.window_s - 1.0
    assert set(np.round(y[np.isfinite(y)], 6)) <= set(np.round(v_live[np.isfinite(v_live)], 6))
    assert "J5 current" in view.readout.text() and "S06B force" in view.readout.text()

    # record a few seconds, reopen the recording in the same plots
    forces.controls.record.click()
    session = forces.session
    qtbot.waitUntil(lambda: session.n_daq_samples > 60 and session.n_robot_samples > 20, timeout=20_000)
    forces.controls.record.click()
    path = Path(session.path)
    dock.ask_open_path = lambda _title, _folder, _filter: str(path)
    view.open_button.click()
    assert dock.recording is not None and not view.live and view.source_label.text().startswith("Recording")
    assert [p.keys for p in view.plots] == [[J5_CURRENT], [S06B_FORCE]]
    with h5py.File(path) as f:
        t_rob, current = f["robot/time_s"][:], f["robot/current_mA"][:, 4]
        t_daq, force = f["daq/time_s"][:], f["forces/force_N"][:, 17]
    x, y = drawn(view.plots[0])
    assert x[0] <= t_rob[0] and x[-1] >= t_rob[-1] - 1e-9 and y.min() == current.min() and y.max() == current.max()
    x, y = drawn(view.plots[1])
    finite = force[np.isfinite(force)]
    assert np.nanmin(y) == finite.min() and np.nanmax(y) == finite.max()
    # the linked axes pan together; the cursor reads both series at its time
    view.plots[1].vb.setXRange(t_daq[5], t_daq[40], padding=0)
    assert view.time_range() == pytest.approx((t_daq[5], t_daq[40]))
    view.put_cursor(float(t_daq[20]))
    assert f"S06B force {force[20]:.4g} N" in view.readout.text()
    assert f"J5 current {current[np.flatnonzero(t_rob <= t_daq[20])[-1]]:.4g} mA" in view.readout.text()

    # the layout saved beside the recording, the plots emptied, the recording opened again: the layout is back
    dock.ask_save_path = lambda _title, suggested: suggested
    view.save_action.trigger()
    beside = path.with_name(path.stem + ".plots.json")
    saved = json.loads(beside.read_text())
    assert [p["series"] for p in saved["plots"]] == [[J5_CURRENT], [S06B_FORCE]]
    view.clear_action.trigger()
    assert view.plots == []
    view.live_button.click()
    assert dock.showing_live and view.live
    view.open_button.click()
    assert [p.keys for p in view.plots] == [[J5_CURRENT], [S06B_FORCE]]
    assert "plots.json opened" in view.message.text()

    # a layout is never written over a file unasked: cancel keeps it, keep both saves beside it, replace replaces
    dock.add_series(["robot/J5/goal_rad"], 0)
    asked: list[Path] = []
    for answer in ("cancel", "keep", "replace"):
        dock.ask_existing = lambda p, a=answer: asked.append(p) or a
        view.save_action.trigger()
    assert asked == [beside] * 3
    two = beside.with_name(path.stem + "-2.plots.json")
    assert json.loads(two.read_text())["plots"][0]["series"] == [J5_CURRENT, "robot/J5/goal_rad"]
    assert json.loads(beside.read_text())["plots"][0]["series"] == [J5_CURRENT, "robot/J5/goal_rad"]
    lab.robot.stop_motion()


def test_hidden_the_dock_takes_no_data_and_draws_nothing(window, qtbot):
    dock = window.plots_dock
    dock.add_series([J5_CURRENT, "daq/S06B/conductance_uS"])
    assert not dock.isVisible() and not dock.subscribed and dock.live.nbytes == 0
    window.plots_action.trigger()
    qtbot.waitUntil(lambda: dock.subscribed and dock.live.version > 5)
    qtbot.waitUntil(lambda: dock.redraws > 3)
    window.plots_action.trigger()
    assert not dock.isVisible() and not dock.subscribed and not dock._timer.isActive()
    version, redraws = dock.live.version, dock.redraws
    with qtbot.waitSignals([window.lab.robot.state_block] * 5, timeout=10_000):
        pass
    with qtbot.waitSignal(window.lab.board.block, timeout=10_000):
        pass
    assert dock.live.version == version and dock.redraws == redraws
    # shown again: the board's recent past fills what was missed, nothing twice
    window.plots_action.trigger()
    qtbot.waitUntil(lambda: dock.live.version > version)
    t, _v = dock.live.read("daq/S06B/conductance_uS")
    assert np.all(np.diff(t) >= 0)


def test_the_cursor_and_the_3d_replay_follow_each_other_and_xy_plots(idle_window, qtbot, tmp_path):
    path = write_recording(tmp_path / "run.h5")
    dock, view = idle_window.plots_dock, idle_window.plots_dock.view
    idle_window.plots_action.trigger()
    qtbot.waitUntil(dock.isVisible)
    assert dock.open_recording(path)
    dock.add_series([J5_CURRENT])
    assert view.time_range() == pytest.approx(sr.RecordingSeries(path).span())  # the first plot: all of it
    assert dock.open_replay()
    scene = idle_window.tab_widget("scene")
    assert idle_window.tabs.currentWidget().objectName() == "tab_scene"
    assert Path(scene.replay.path) == path
    scene.seek(2.5)  # the user scrubs the 3-D replay
    qtbot.waitUntil(lambda: view.cursor_s == pytest.approx(2.5))
    assert "cursor t = 2.500 s" in view.readout.text()
    view.put_cursor(1.2)  # the user moves the plots' cursor
    assert scene.replay_time_s == pytest.approx(1.2)
    scene.seek(5.9)  # beyond what the plots show: the axes follow the cursor
    view.set_time_range(0.0, 2.0)
    qtbot.waitUntil(lambda: view.cursor_s == pytest.approx(5.9))
    t0, t1 = view.time_range()
    assert t0 <= 5.9 <= t1 and t1 - t0 == pytest.approx(2.0)

    # an X–Y plot: a segment's motion-captured y against its x over the time the linked axes show, the cursor's
    # point on it
    dock.add_series(["mocap/seg03/x_m", "mocap/seg03/y_m"], plot=-3)
    xy = view.plots[-1]
    assert xy.kind == "xy" and "X–Y" in view.header_text(len(view.plots) - 1)
    x, y = drawn(xy)
    with h5py.File(path) as f:
        centers, t_m = f["mocap/segment_center_m"][:, 2], f["mocap/time_s"][:]
    shown = (t_m >= t0) & (t_m <= t1)
    assert np.allclose(x, centers[shown, 0]) and np.allclose(y, centers[shown, 1])
    marker_x, marker_y = xy.marker.getData()
    k = np.flatnonzero(t_m <= 5.9)[-1]
    assert marker_x[0] == pytest.approx(centers[k, 0], abs=2e-3) and marker_y[0] == pytest.approx(centers[k, 1],
                                                                                                   abs=2e-3)
    dock.set_layout(dock.layout_model.removing(0))  # with no time plot, the X–Y plot shows the whole recording
    x, _y = drawn(view.plots[0])
    assert np.allclose(x, centers[:, 0])


def test_the_cursor_and_the_forces_tab_follow_each_other_on_the_same_recording(idle_window, qtbot, tmp_path):
    """The Forces tab showing the recording plotted here: this cursor puts its dashed line and body map at t, the
    mouse over its plots moves this cursor (and the 3-D replay); on another recording nothing is shared."""
    from tests.app.synthetic_trials import write_trial

    path = write_trial(tmp_path / "run.h5", duration_s=6.0, seed=1)  # a whole recording: the Forces tab opens it
    dock, view = idle_window.plots_dock, idle_window.plots_dock.view
    idle_window.plots_action.trigger()
    qtbot.waitUntil(dock.isVisible)
    assert dock.open_recording(path)
    dock.add_series([S06B_FORCE])
    forces = idle_window.show_tab("forces")
    assert forces.open_recording_file(path) is not None
    qtbot.waitUntil(lambda: forces.plots.cursor_s == pytest.approx(view.cursor_s))  # it takes the cursor from here

    def lines_at(t_s):
        offset = forces.plots.visible_range()[0] - forces.plots.plots[0].viewbox.viewRange()[0][0]
        shown = [p for p in forces.plots.plots if not p.collapsed]
        return shown and all(p.cursor_line.isVisible() and p.cursor_line.value() + offset == pytest.approx(t_s)
                             for p in shown)

    view.put_cursor(4.5)  # the user moves the plots' cursor: the Forces tab's line and body map go there
    assert forces.plots.cursor_s == pytest.approx(4.5) and lines_at(4.5)
    assert forces.replay_time_s() == pytest.approx(4.5)
    with h5py.File(path) as f:
        t_rob, present = f["robot/time_s"][:], f["robot/present_rad"][:]
    angles, _forces = forces.recorded_body(forces.replay_time_s())
    assert angles[0] > 0.05 and np.allclose(angles, present[np.flatnonzero(t_rob <= 4.5)[-1]])

    forces.plots.hover_at(0, 4.0)  # the mouse over the Forces tab's plots: this cursor follows (a 30 Hz sample)
    qtbot.waitUntil(lambda: view.cursor_s is not None and abs(view.cursor_s - 4.0) <= 1 / 30 + 1e-9)
    assert view.cursor_s == pytest.approx(forces.plots.cursor_s)
    assert f"cursor t = {view.cursor_s:.3f} s" in view.readout.text()
    view.set_time_range(0.0, 1.0)
    forces.plots.hover_at(0, 5.5)  # beyond what the plots show: the axes follow
    qtbot.waitUntil(lambda: view.cursor_s is not None and view.cursor_s > 5.0)
    t0, t1 = view.time_range()
    assert t0 <= view.cursor_s <= t1 and t1 - t0 == pytest.approx(1.0)

    assert dock.open_replay()  # the 3-D replay joins: the Forces tab's cursor moves it too
    scene = idle_window.tab_widget("scene")
    forces.plots.hover_at(0, 3.0)
    qtbot.waitUntil(lambda: abs(scene.replay_time_s - 3.0) <= 0.05)
    scene.seek(1.5)  # scrubbed in 3-D: the plots' cursor and the Forces tab's follow
    qtbot.waitUntil(lambda: forces.plots.cursor_s == pytest.approx(scene.replay_time_s))
    assert view.cursor_s == pytest.approx(scene.replay_time_s)

    other = write_trial(tmp_path / "other.h5", duration_s=3.0, seed=2)
    assert forces.open_recording_file(other) is not None  # another recording in the Forces tab: nothing shared
    assert forces.plots.cursor_s is None
    view.put_cursor(0.5)
    qtbot.wait(100)  # Deliberate: three of the dock's redraw ticks, which would share the cursor
    assert forces.plots.cursor_s is None and forces.replay_time_s() != pytest.approx(0.5)


def test_the_cursor_and_the_forces_tab_s_trial_overlay_follow_each_other(idle_window, qtbot, tmp_path):
    """The recording plotted here is one of the trials overlaid in the Forces tab: the overlay's cursor line is at
    this cursor's time from that trial's zero (the alignment's, whichever is chosen), and dragging it moves this
    cursor; cleared, the line goes."""
    from tests.app.synthetic_trials import ONSET_S, write_trial

    path = write_trial(tmp_path / "run.h5", duration_s=8.0, shift_s=1.0, seed=1)  # its onset at 3 s
    other = write_trial(tmp_path / "other.h5", duration_s=8.0, seed=2)
    dock, view = idle_window.plots_dock, idle_window.plots_dock.view
    idle_window.plots_action.trigger()
    qtbot.waitUntil(dock.isVisible)
    assert dock.open_recording(path)
    dock.add_series([S06B_FORCE])
    forces = idle_window.show_tab("forces")
    assert forces.add_overlay_files([other, path]) == 2
    overlay = forces.overlay
    view.put_cursor(4.5)
    qtbot.waitUntil(lambda: overlay.cursor_s is not None)
    onset = forces.overlay_zero_s[path.resolve()]  # aligned on the load's onset (the tab's default)
    assert onset > ONSET_S + 1.0  # the sensor overlaid is loaded after the motion's onset (at 3 s on its clock)
    assert overlay.cursor_s == pytest.approx(4.5 - onset) and overlay._cursor.value() == pytest.approx(4.5 - onset)

    forces.overlay_align.setCurrentIndex(forces.overlay_align.findData("start"))  # aligned on the recording's start
    start = forces.overlay_zero_s[path.resolve()]
    assert start < 1 / 30
    qtbot.waitUntil(lambda: overlay.cursor_s == pytest.approx(4.5 - start))

    overlay._cursor.setValue(2.0)  # the user drags the overlay's line to 2 s from the start
    qtbot.waitUntil(lambda: view.cursor_s == pytest.approx(start + 2.0))
    assert forces.plots.cursor_s is None  # the Forces tab's plots show the live board, not this recording

    forces.clear_overlay()
    qtbot.waitUntil(lambda: overlay.cursor_s is None)
    assert not overlay._cursor.isVisible()


def test_a_layout_naming_series_the_source_lacks_says_which_and_a_bad_file_is_refused(idle_window, qtbot, tmp_path):
    dock = idle_window.plots_dock
    idle_window.plots_action.trigger()
    path = write_recording(tmp_path / "run.h5")
    assert dock.open_recording(path)
    layout = sr.PlotLayout().adding(J5_CURRENT).adding("robot/J99/current_mA", 0)
    sr.write_layout(layout, tmp_path / "mine.plots.json")
    assert dock.open_layout(tmp_path / "mine.plots.json")
    assert "robot/J99/current_mA" in dock.view.message.text()
    assert "not in what is shown" in dock.view.header_text(0)
    (tmp_path / "broken.plots.json").write_text("{")
    assert not dock.open_layout(tmp_path / "broken.plots.json")
    assert "broken.plots.json" in dock.view.message.text()
    assert dock.layout_model == layout  # kept
    fault = idle_window.event_log.latest("fault")
    assert fault is not None and "broken.plots.json" in fault.text and fault.source == "Plots"
    # the layout outlives the window: its settings hold it
    stored = idle_window.settings.value("plots/layout")
    assert sr.parse_layout(stored) == layout
    assert NEW_PLOT == -1


def test_a_layout_saved_onto_a_folder_or_a_link_is_refused_without_offering_to_replace_it(idle_window, tmp_path):
    dock = idle_window.plots_dock
    dock.add_series([J5_CURRENT])
    asked: list[Path] = []
    dock.ask_existing = lambda p: asked.append(p) or "replace"
    folder = tmp_path / "taken.plots.json"
    folder.mkdir()
    (tmp_path / "target.json").write_text("{}")
    link = tmp_path / "link.plots.json"
    link.symlink_to(tmp_path / "target.json")
    for path in (folder, link):
        assert dock.save_layout(path) is None
        assert path.name in dock.view.message.text() and "not saved" in dock.view.message.text()
    assert asked == []  # never asked "replace?" about something that is not a file it may replace
    assert folder.is_dir() and link.is_symlink() and (tmp_path / "target.json").read_text() == "{}"


def test_a_new_lab_is_plotted_and_the_old_one_let_go(idle_window, qtbot):
    from types import SimpleNamespace

    from app.gui.lab import LabContext

    dock = idle_window.plots_dock
    idle_window.plots_action.trigger()
    qtbot.waitUntil(lambda: dock.subscribed)
    old = idle_window.lab
    state = SimpleNamespace(host_time_s=1.0, position_rad=np.zeros(12), velocity_rad_s=np.zeros(12),
                            current_ma=np.full(12, 7.0), goal_rad=None, correction_rad=None)
    old.robot.state_block.emit([state])
    assert dock.live.value_at(J5_CURRENT, 1.0 - dock.live.t0_monotonic_s) == 7.0
    idle_window.replace_lab(LabContext(LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port"))))
    assert dock.lab is idle_window.lab is not old and dock.subscribed
    version = dock.live.version
    old.robot.state_block.emit([state])  # the old lab's robot is no longer heard
    assert dock.live.version == version
    idle_window.lab.robot.state_block.emit([state])
    assert dock.live.version == version + 1
