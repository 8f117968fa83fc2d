"""The Trials dock (View ▸ Trials) on the simulated lab, offscreen: a 3-trial series with the operator's prompts, Esc
in trial 2 (kept, marked aborted), the app gone mid-trial 3 and the series resumed to its end; and the run catalog's
browser (File ▸ Open recording…) filtering the catalog and opening a trial in the 3-D replay, with the control loop's
missed 50 Hz ticks counted while it indexes."""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path

import pytest
from PySide6.QtCore import Qt

from app.core.run_documents import read_documents
from devices.config import SIM_PORT, load_config
from tests.app.test_robot_trials import shape_file
from tests.app.windows import open_connected_window

CONNECT_TIMEOUT_MS = 10_000
TRIAL_TIMEOUT_MS = 30_000


@pytest.fixture
def window(qtbot, sim_lab_fast, tmp_path, monkeypatch):
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    win = open_connected_window(qtbot, config, tmp_path, CONNECT_TIMEOUT_MS)
    with qtbot.waitSignal(win.lab.board.connected, timeout=CONNECT_TIMEOUT_MS):
        win.lab.board.start()
    yield win
    win.close()


def click(qtbot, button) -> None:
    assert button.isEnabled(), f"{button.text()!r} is disabled"
    qtbot.mouseClick(button, Qt.MouseButton.LeftButton)


def recording_data(window) -> bool:
    """The trial's recording has the board's frames and the robot's states (its file is this process's: not read)."""
    recorder = window.lab.recording
    return recorder is not None and recorder.n_daq_samples > 0 and recorder.n_robot_samples > 0 and \
        recorder.elapsed_s > 1.0  # past the writer's first flush (every 0.5 s)


def crash_copy(path: Path) -> bytes:
    """The recording's bytes as a crash would leave them: flushed up to now, no run_stop (read back to be sure)."""
    scratch = path.with_name("crash-copy.h5.tmp")
    for _attempt in range(100):
        shutil.copyfile(path, scratch)
        try:
            start, stop = read_documents(scratch)
        except OSError:  # copied in the middle of a flush: copy again
            continue
        if start is not None and stop is None:
            data = scratch.read_bytes()
            scratch.unlink()
            return data
    raise AssertionError(f"no readable copy of {path} mid-recording")


def run_trial(qtbot, panel, session, k: int, n: int) -> None:
    qtbot.waitUntil(lambda: session.phase == "waiting", timeout=TRIAL_TIMEOUT_MS)
    assert panel.prompt_label.text() == f"Place the robot, then Start trial {k} of {n}"
    assert panel.start_trial_button.text() == f"Start trial {k} of {n}"
    assert not any(b.isEnabled() for b in panel.outcome_buttons.values())
    click(qtbot, panel.start_trial_button)
    assert session.phase == "recording" and panel.prompt_label.text().startswith(f"Recording trial {k} of {n}")
    assert not panel.start_trial_button.isEnabled() and not panel.end_button.isEnabled()


def test_a_three_trial_series_with_prompts_a_stop_in_trial_2_and_a_crash_then_resume(window, qtbot, tmp_path):
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow)  # Esc is the window's shortcut: it fires in the active window
    window.trials_action.trigger()
    dock = window.trials_dock
    assert dock.isVisible()
    panel, session = dock.panel, dock.session
    folder = tmp_path / "recordings" / "obstacle-x3"
    session.add_shape_file(shape_file(tmp_path))
    panel.speed_spin.setValue(0.5)
    panel.trials_spin.setValue(3)
    panel.scene_edit.setText("flat")
    panel.note_edit.setText("bench, three trials")
    panel.folder_edit.setText(str(folder))
    click(qtbot, panel.start_series_button)
    assert session.phase == "moving" and not panel.form_box.isEnabled()

    run_trial(qtbot, panel, session, 1, 3)
    assert window.status.recording_label.text().startswith("● REC trial-000.h5")
    qtbot.waitUntil(lambda: session.phase == "marking", timeout=TRIAL_TIMEOUT_MS)
    assert panel.prompt_label.text() == "Trial 1 of 3 recorded: mark its outcome"
    panel.outcome_note.setText("clean pass")
    click(qtbot, panel.outcome_buttons["traversed"])
    assert panel.table.item(0, 1).text() == "traversed" and panel.table.item(0, 5).text() == "clean pass"

    run_trial(qtbot, panel, session, 2, 3)  # after the outcome the robot went to the start pose by itself
    qtbot.waitUntil(lambda: recording_data(window), timeout=20_000)
    qtbot.keyClick(window.focusWidget() or window, Qt.Key.Key_Escape)  # STOP
    qtbot.waitUntil(lambda: session.phase == "ready")
    assert panel.prompt_label.text() == "Go to the start pose for trial 3 of 3"
    assert "trial 2 stopped (STOP (button or Esc)): kept, marked aborted" in panel.detail_label.text()
    assert panel.table.item(1, 1).text() == "aborted" and panel.table.item(1, 2).text() == "abort"
    assert not panel.start_trial_button.isEnabled()  # nothing moves until the operator asks
    _start, stop = read_documents(folder / "trial-001.h5")
    assert (stop["exit_status"], stop["outcome"]) == ("abort", "aborted")
    click(qtbot, panel.go_start_button)

    run_trial(qtbot, panel, session, 3, 3)
    qtbot.waitUntil(lambda: recording_data(window), timeout=20_000)
    # The app dies here: what it leaves on disk is the state saved when trial 3 began and a recording without
    # run_stop. (The window closing mid-trial instead keeps it as stopped; then the crash's leftovers are put back.)
    state = (folder / "series.json").read_text()
    leftover = crash_copy(folder / "trial-002.h5")
    dock.detach_lab()
    (folder / "series.json").write_text(state)
    (folder / "trial-002.h5").write_bytes(leftover)

    dock.attach_lab(window.lab)
    panel, session = dock.panel, dock.session
    assert session.resume(folder)
    assert session.phase == "ready" and panel.prompt_label.text() == "Go to the start pose for trial 3 of 3"
    assert "trial 3 was cut short while recording" in panel.detail_label.text()
    assert [panel.table.item(r, 1).text() for r in range(3)] == ["traversed", "aborted", ""]
    click(qtbot, panel.go_start_button)
    run_trial(qtbot, panel, session, 3, 3)
    qtbot.waitUntil(lambda: session.phase == "marking", timeout=TRIAL_TIMEOUT_MS)
    click(qtbot, panel.outcome_buttons["failed"])
    assert session.phase == "complete"
    assert panel.prompt_label.text() == "Series complete: 3 of 3 trials finished (1 traversed, 1 failed, 1 aborted)"
    assert panel.add_trial_button.isEnabled() and not panel.start_trial_button.isEnabled()

    uids = set()
    for k, outcome in enumerate(("traversed", "aborted", "failed")):
        start, stop = read_documents(folder / f"trial-{k:03d}.h5")
        assert start["plan_name"] == "robot trials" and start["trial"] == k and stop["outcome"] == outcome
        assert start["note"] == "bench, three trials" and start["condition"]["scene"] == "flat"
        uids.add(start["series_uid"])
    assert len(uids) == 1
    assert (folder / "trial-002.cut-short.h5").exists()
    state = json.loads((folder / "series.json").read_text())
    assert [t["outcome"] for t in state["trials"]] == ["traversed", "aborted", "failed"]
    assert state["set_aside"] == ["trial-002.cut-short.h5"]


def test_record_in_the_forces_tab_during_a_trial_shows_the_trial_s_recording(window, qtbot, tmp_path):
    """A trial records the Forces tab's data: its Record button is off and disabled, naming the trial, and a start
    asked for anyway (a script, a shortcut) is refused in one line: no exception, no second file, the trial's
    recording untouched. Free again once the trial ends."""
    from widgets.forces_panel import RECORD_TIP

    window.trials_action.trigger()
    panel, session = window.trials_dock.panel, window.trials_dock.session
    folder = tmp_path / "recordings" / "bench-x2"
    session.add_shape_file(shape_file(tmp_path))
    panel.speed_spin.setValue(0.5)
    panel.trials_spin.setValue(2)
    panel.folder_edit.setText(str(folder))
    click(qtbot, panel.start_series_button)
    run_trial(qtbot, panel, session, 1, 2)
    trial_recorder = window.lab.recording
    forces = window.show_tab("forces")
    record = forces.controls.record
    assert not record.isEnabled() and not record.isChecked()
    assert forces.controls.record_info.text() == "● trial 1 recording (Trials)"
    assert record.toolTip().startswith("Trial 1 of the series in bench-x2 is recording the board and the robot to "
                                       "trial-000.h5 (Trials dock)")
    qtbot.mouseClick(record, Qt.MouseButton.LeftButton)  # a disabled button: nothing happens
    assert forces.start_recording() is None  # asked for anyway
    assert forces.controls.message.text().startswith("not recorded: Trial 1 of the series in bench-x2 is recording")
    assert forces.session is None and forces.live.recorder is trial_recorder and window.lab.recording is trial_recorder
    assert not record.isChecked() and forces.controls.record_info.text() == "● trial 1 recording (Trials)"

    qtbot.waitUntil(lambda: session.phase == "marking", timeout=TRIAL_TIMEOUT_MS)
    assert record.isEnabled() and record.toolTip() == RECORD_TIP
    assert forces.controls.record_info.text() == "not recording"
    _start, stop = read_documents(folder / "trial-000.h5")
    assert stop["exit_status"] == "success"
    assert sorted(p.name for p in (tmp_path / "recordings").rglob("*.h5")) == ["trial-000.h5"]  # no second file


def test_the_catalog_browser_filters_and_opens_a_trial_in_the_3d_replay(window, qtbot, tmp_path, monkeypatch):
    from benchmarks.bench_catalog import write_small_recording
    from tests.app.synthetic_trials import write_trial

    monkeypatch.setenv("SENSNAKE_DATA_DIR", str(tmp_path / "data"))  # a catalog of this test's recordings only

    recordings = tmp_path / "recordings"
    recordings.mkdir(exist_ok=True)
    for index in range(40):
        write_small_recording(recordings / f"run-{index:03d}.h5", index)
    trial = write_trial(recordings / "bench-trial.h5", scene="bench", duration_s=3.0, trial=0, series_uid="s-1")
    from app.gui import catalog_browser
    from widgets.catalog_view import CatalogView

    monkeypatch.setattr(catalog_browser, "PROGRESS_EVERY_S", 0.0)  # every file's progress reaches the status line
    said: list[str] = []
    set_status = CatalogView.set_status
    monkeypatch.setattr(CatalogView, "set_status", lambda view, text, *a: (said.append(text), set_status(view, text, *a)))
    browser = window.open_catalog()
    view = browser.view
    qtbot.waitUntil(lambda: browser.last is not None, timeout=20_000)
    assert browser.last is not None and browser.last.read == 41
    # while it reads, the status line says how far it got; then what it did
    counts = [int(text.rsplit(": ", 1)[1].split(" of ")[0]) for text in said if text.endswith(" of 41…")]
    assert counts == sorted(counts) and counts[-1] == 41 and len(counts) > 10, said
    assert said[-1].endswith("… · 41 recording(s) read again, 0 gone forgotten"), said[-1]
    assert view.table.rowCount() == 41
    scenes = [view.filter_combos["scene"].itemText(i) for i in range(view.filter_combos["scene"].count())]
    assert scenes == ["any", "bench", "flat", "paper_obstacle", "step", "wedge"]
    with qtbot.waitSignal(browser.listed, timeout=20_000):
        view.filter_combos["scene"].setCurrentText("step")
    assert view.table.rowCount() == 10
    assert {view.table.item(r, 3).text() for r in range(10)} == {"step"}
    with qtbot.waitSignal(browser.listed, timeout=20_000):
        view.filter_combos["scene"].setCurrentText("bench")
    assert view.table.rowCount() == 1 and view.table.item(0, 1).text() == "bench-trial.h5"
    view.table.selectRow(0)
    assert view.open_button.isEnabled() and view.selected_paths() == [str(trial.resolve())]
    click(qtbot, view.open_button)
    scene = window.tab_widget("scene")
    assert window.tabs.currentWidget().objectName() == "tab_scene"
    assert scene is not None and scene.replay is not None and scene.replay.path == trial.resolve()
    again = window.open_catalog()
    assert again is not browser  # the first closed once its recording was open
    qtbot.waitUntil(lambda: again.last is not None, timeout=20_000)
    assert again.last is not None and again.last.read == 0  # nothing changed: nothing read again
    again.view.close()


@pytest.fixture
def real_port_window(qtbot, sim_lab_fast, emulator, tmp_path, monkeypatch):
    """The robot on a real port (the independent XM430 emulator on a pty): the control loop in its own process, as
    on the lab's robot."""
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    config = load_config().with_ports(robot=emulator.path, board=SIM_PORT, rig=SIM_PORT)
    win = open_connected_window(qtbot, config, tmp_path, 30_000)
    yield win
    win.close()


@pytest.mark.serial
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the emulator needs a pty (Linux)")
def test_the_control_loop_misses_no_50_hz_tick_while_the_catalog_indexes(real_port_window, qtbot, tmp_path,
                                                                       monkeypatch, capsys):
    """1,000 new recordings indexed by the browser's worker while the robot plays at 50 Hz on the real-port path
    (the loop in its own process): the missed ticks over the whole indexing, beside those of as long a time just
    after it with the browser idle (printed; docs/TRIALS.md states the numbers)."""
    from benchmarks.bench_catalog import write_small_recording
    from devices.loop_process import ControllerProcess
    from models.trajectory import BlendTo

    window = real_port_window
    monkeypatch.setenv("SENSNAKE_DATA_DIR", str(tmp_path / "data"))
    recordings = tmp_path / "recordings"
    recordings.mkdir(exist_ok=True)
    for index in range(1000):
        write_small_recording(recordings / f"run-{index:04d}.h5", index)
    robot = window.lab.robot
    assert robot.config.control_rate_hz == 50.0 and isinstance(robot.controller, ControllerProcess)
    robot.set_torque(True).result(timeout=30)
    robot.play(BlendTo([0.3] + [0.0] * 11, 0.004), "slow bend")  # 75 s: longer than the indexing and the baseline
    qtbot.waitUntil(lambda: robot.motion_state == "running")
    quiet = robot.loop_stats()
    started = time.monotonic()
    browser = window.open_catalog()
    qtbot.waitUntil(lambda: browser.last is not None, timeout=60_000)
    indexing_s = time.monotonic() - started
    indexed = robot.loop_stats()
    qtbot.wait(int(indexing_s * 1000))  # Deliberate: as long again with the browser idle, the baseline
    after = robot.loop_stats()
    still_moving = robot.motion_state == "running"
    robot.stop_motion()
    browser.view.close()
    assert browser.last is not None and browser.last.read == 1000
    ticks, missed = indexed.ticks - quiet.ticks, indexed.missed_ticks - quiet.missed_ticks
    base_ticks, base_missed = after.ticks - indexed.ticks, after.missed_ticks - indexed.missed_ticks
    with capsys.disabled():
        print(f"\ncatalog indexed 1000 recordings in {indexing_s:.1f} s: {missed} of {ticks + missed} control ticks "
              f"missed at 50 Hz; as long after, browser idle: {base_missed} of {base_ticks + base_missed}")
    assert still_moving and ticks > 25
    # On a loaded machine the loop's process misses ticks whatever the GUI does (the baseline, 0 to 85 of ~500
    # measured beside other test runs, and the two halves of a run differ by as much): indexing may add no more than
    # 10 ticks or 10 % to that. Indexing on the GUI's own terms (before it gave way) cost 94-223 of ~500.
    assert missed <= base_missed + max(10.0, 0.10 * (ticks + missed)), \
        f"{missed} of {ticks + missed} control ticks missed while the catalog indexed ({base_missed} without)"
