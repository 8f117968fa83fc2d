"""The Calibration tab: load trial CSVs, fit on a worker thread, plot measured vs fitted, save the calibration."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from PySide6.QtCore import Qt

from app.core import calfiles
from app.core.rig_protocol import ABORTED
from app.gui.lab import LabContext
from app.gui.tabs.calibration import PROTOCOL, REVIEW, RIG_CHECK, SAVE, SETUP, CalibrationTab
from devices.config import BoardConfig, LabConfig, RigConfig, RobotConfig, SimLabConfig, default_sensor_names
from models.physics import PhysicsConstants
from models.synthetic import TYPICAL_TRUTH, paper_protocol

NO_PORT_CONFIG = LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port"))
# The rig's sensor on a spare board channel, away from the lying robot's weight (see tests/app/test_rig_session.py).
# The board at 12 Hz (the protocol samples at 6 Hz): at 30 Hz the 50x simulated board makes 1500 frames per wall
# second (~18 % of a core, each frame runs the lying robot's contact model), and on a busy machine (load 8-10) its
# thread fell behind the lab clock by more than the runner's 5 s board-stale limit: "no conductance from the board".
BENCH_CONFIG = LabConfig(board=BoardConfig(rate_hz=12.0, channel_names=(*default_sensor_names(), "BENCH")),
                         rig=RigConfig(sensor="BENCH"), lab=SimLabConfig(physics="scripted"))


@pytest.fixture
def trial_files(tmp_path):
    trials = paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=3, forces_n=(1.75, 5.25), repeats=1,
                            noise_rel=0.002)
    paths = []
    for trial in trials:
        path = tmp_path / f"{trial.name}.csv"
        calfiles.write_trial_csv(path, trial.time_s, trial.force_n, trial.conductance_s)
        paths.append(path)
    return paths


@pytest.fixture
def tab(qtbot):
    lab = LabContext(NO_PORT_CONFIG)
    page = CalibrationTab(lab)
    qtbot.addWidget(page)
    yield page
    lab.close()


@pytest.mark.slow  # the fit runs in a spawned process: interpreter start + fitting stack import, ~3-7 s
def test_fit_plots_measured_and_fitted_and_saves(tab, qtbot, trial_files, tmp_path):
    assert tab.add_trial_files(trial_files) == 2
    assert len(tab.curves()) == 2  # measured only, before the fit
    assert not tab.save_button.isEnabled()
    with qtbot.waitSignal(tab.fit_finished, timeout=60_000) as blocker:
        tab.fit_button.click()
    result = blocker.args[0]
    assert len(tab.curves()) == 4  # measured + SLS prediction per trial
    for trial, fitted in zip(result.trials, result.fitted_s):
        hold = trial.force_n >= 0.99 * trial.force_n.max()
        relative = np.abs(fitted[hold] - trial.conductance_s[hold]) / trial.conductance_s[hold]
        assert np.median(relative) < 0.02  # the model follows the measurement on the hold
    assert abs(float(result.calibration.sls.E1_Pa) / TYPICAL_TRUTH.E1_Pa[0] - 1) < 0.2
    assert tab.trial_table.rowCount() == 2
    # One unit on screen: the fit axis stays µS (no automatic mS/µS prefix), RMSE in µS like the plot.
    left = tab.plot.getPlotItem().getAxis("left")
    assert left.labelText == "conductance (µS)" and not left.autoSIPrefix
    assert tab.trial_table.horizontalHeaderItem(6).text() == "RMSE (µS)"
    rmse_us = float(tab.trial_table.item(0, 6).text())
    assert rmse_us == pytest.approx(result.calibration.trials[0].rmse_s * 1e6, rel=1e-3)
    assert "S06B" in tab.summary_label.text() and "τ" in tab.summary_label.text()
    headers = [tab.trial_table.horizontalHeaderItem(c).text() for c in range(tab.trial_table.columnCount())]
    assert headers[:4] == ["Trial", "Force (N)", "E0 (Pa)", "E1 (Pa)"]
    for row, report in enumerate(result.calibration.trials):
        e1_cell = tab.trial_table.item(row, headers.index("E1 (Pa)"))
        assert float(e1_cell.text()) == pytest.approx(float(report.params.E1_Pa), rel=1e-3)
        assert e1_cell.toolTip().startswith("95 % interval")
    lo, hi = result.calibration.sls_ci95["E1_Pa"]
    assert f"95 %: {lo:.4g} … {hi:.4g}" in tab.summary_label.text()
    out = tmp_path / "cal.json"
    assert tab.save(out)
    document = calfiles.read_calibration(out)
    assert "S06B" in document["sensors"]
    assert document["sensors"]["S06B"]["area_m2"] == pytest.approx(1.4e-3)


def test_bad_trial_file_is_reported_with_its_line(tab, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,force_N,conductance_S\n0,1,0.001\n1,oops,0.001\n", encoding="utf-8")
    assert tab.add_trial_files([bad]) == 0
    assert "bad.csv:3" in tab.status_label.text()
    assert not tab.fit_button.isEnabled()


def test_flat_sensor_fit_is_refused_with_a_reason(tab, qtbot, tmp_path):
    time_s = np.arange(0, 370, 1 / 6)
    force = np.clip((time_s - 5) / 2, 0, 1) * 3.0
    path = tmp_path / "flat.csv"
    calfiles.write_trial_csv(path, time_s, force, np.full(time_s.shape, 2e-4))
    tab.add_trial_files([path])
    with qtbot.waitSignal(tab.fit_failed, timeout=60_000) as blocker:
        tab.start_fit()
    assert "flat.csv" in blocker.args[0]
    assert tab.fit_button.isEnabled() and not tab.save_button.isEnabled()


# -- running the protocol on the (simulated) rig -------------------------------------------------------------------
@pytest.fixture
def fast_sim_lab(install_fast_sim_lab):
    return install_fast_sim_lab(BENCH_CONFIG, seed=5, speed=50.0)


@pytest.fixture
def rig_tab(qtbot, fast_sim_lab, tmp_path):
    lab = LabContext(BENCH_CONFIG)  # every port on the simulated lab; the robot is never connected
    page = CalibrationTab(lab)
    qtbot.addWidget(page)
    form = page.protocol_form
    form.forces_edit.setText("1.75, 5.25")
    form.trials_spin.setValue(1)
    form.hold_spin.setValue(200.0)  # lab seconds: the protocol runs on the 50× lab's clock
    form.baseline_spin.setValue(50.0)
    form.ramp_spin.setValue(50.0)
    form.rest_spin.setValue(15.0)
    form.folder_edit.setText(str(tmp_path))
    yield page
    page.shutdown()
    lab.close()


@pytest.mark.slow  # a 2-trial run on the 50× sim (~12 s) and the fit in a spawned process
def test_protocol_run_records_trials_then_fits_them(rig_tab, qtbot):
    tab = rig_tab
    with qtbot.waitSignal(tab.rig_session.running_changed, timeout=15_000):
        assert tab.start_run()
    assert not tab.fit_button.isEnabled() and not tab.protocol_form.run_button.isEnabled()
    assert tab.protocol_form.abort_button.isEnabled()
    assert tab.view_tabs.currentWidget() is tab.live_plot
    qtbot.waitUntil(lambda: tab.live_plot.n_samples > 10, timeout=30_000)  # the live trial is drawn
    t, force, conductance = tab.live_plot.data()
    assert np.all(np.diff(t) > 0) and np.all(np.isfinite(force)) and np.all(np.isfinite(conductance))
    # The run ends, its trials join the list and the fit starts by itself with the window scaled to the 4 s hold.
    qtbot.waitUntil(lambda: not tab.rig_session.is_running and not tab.is_fitting
                    and ("fitted" in tab.status_label.text() or "refused" in tab.status_label.text()),
                    timeout=120_000)
    assert tab.last_fit_window_s == pytest.approx((50.0 + 225 * 200 / 370, 50.0 + 300 * 200 / 370))
    assert len(tab.trials) == 2 and tab.trial_list.count() == 2
    assert "2/2 trials" in tab.protocol_form.progress_bar.format()
    assert tab.protocol_form.run_button.isEnabled() and not tab.protocol_form.abort_button.isEnabled()
    # On the 50× simulated lab the wall-clock protocol squeezes the sensor's creep (τ ≈ 100 s simulated) into ~2 s
    # and a busy CPU shifts force against conductance by a sample: the fit of such short trials is sometimes refused
    # (models issue reported to the lead). Either way the outcome is shown; the result display itself is checked
    # deterministically by test_fit_plots_measured_and_fitted_and_saves.
    if tab.result is None:
        assert tab.status_label.text().startswith("fit refused: ")
        return
    assert [t.name for t in tab.result.trials] == [t.name for t in tab.trials]
    forces = [float(tab.trial_table.item(row, 1).text()) for row in range(2)]
    assert forces == pytest.approx([1.75, 5.25], abs=0.25)
    assert tab.view_tabs.currentIndex() == 0 and tab.save_button.isEnabled()


def test_abort_from_the_tab_keeps_the_finished_trial_in_the_list(rig_tab, qtbot, fast_sim_lab):
    tab = rig_tab
    tab.protocol_form.hold_spin.setValue(100.0)
    tab.protocol_form.ramp_spin.setValue(15.0)
    tab.protocol_form.baseline_spin.setValue(25.0)
    tab.start_run()
    qtbot.waitUntil(lambda: len(tab.trials) == 1, timeout=30_000)  # then abort while trial 2 rests or runs
    with qtbot.waitSignal(tab.rig_session.finished, timeout=20_000):
        tab.protocol_form.abort_button.click()
    assert tab.trial_list.count() == 1 and tab.fit_button.isEnabled()
    assert "aborted by the user" in tab.protocol_form.message_label.text()
    assert "kept" in tab.status_label.text()
    assert fast_sim_lab.rig.applied_force_n() == 0.0
    assert not tab.is_fitting  # an aborted run is not fitted without asking
    # Nothing of this run stays on screen as if it were the next one's: a refused start clears the progress…
    assert "trials" in tab.protocol_form.progress_bar.format() and tab.live_plot.n_samples > 0
    tab.protocol_form.forces_edit.setText("1.75, three")
    assert not tab.start_run()
    assert tab.protocol_form.progress_bar.value() == 0 and tab.protocol_form.progress_label.text() == ""
    assert "trials" not in tab.protocol_form.progress_bar.format()
    # …and a start clears the live trace until the new run's first sample.
    tab.protocol_form.forces_edit.setText("1.75")
    assert tab.start_run()
    assert tab.live_plot.n_samples == 0 and "waiting" in tab.live_plot.title.text()
    with qtbot.waitSignal(tab.rig_session.finished, timeout=20_000):
        tab.protocol_form.abort_button.click()


def test_a_rig_that_does_not_answer_is_reported_on_the_form(rig_tab, qtbot, fast_sim_lab):
    tab = rig_tab
    fast_sim_lab.rig.chain.set_no_reply(tab.lab.config.rig.servo_id)
    with qtbot.waitSignal(tab.rig_session.finished, timeout=30_000):
        tab.start_run()
    message = tab.protocol_form.message_label.text()
    assert "no reply from servo 1" in message and "check its cable" in message
    assert tab.trial_list.count() == 0 and tab.protocol_form.run_button.isEnabled()


def test_bad_protocol_fields_are_refused_before_anything_moves(rig_tab):
    tab = rig_tab
    tab.protocol_form.forces_edit.setText("1.75, three")
    assert not tab.start_run()
    assert "'three' is not a number" in tab.protocol_form.message_label.text()
    assert not tab.rig_session.is_running


def test_escape_in_the_main_window_stops_the_run_and_releases_the_force(qtbot, install_fast_sim_lab, tmp_path):
    from PySide6.QtCore import QSettings, Qt

    from app.gui.main_window import MainWindow

    # 20x, not 50x: the whole window's GUI thread moves the board's blocks to the run, and at 50x (600 frames per wall
    # second) a busy machine (load 8-12) starved it past the run's 5 s board-stale limit ("no conductance ... for 5 s").
    fast_sim_lab = install_fast_sim_lab(BENCH_CONFIG, seed=5, speed=20.0)
    window = MainWindow(LabContext(BENCH_CONFIG), settings=QSettings(str(tmp_path / "s.ini"),
                                                                    QSettings.Format.IniFormat))
    qtbot.addWidget(window)
    tab = window.show_tab("calibration")
    tab.protocol_form.forces_edit.setText("3")
    tab.protocol_form.trials_spin.setValue(1)
    tab.protocol_form.hold_spin.setValue(3000.0)
    tab.protocol_form.rest_spin.setValue(10.0)
    tab.protocol_form.baseline_spin.setValue(15.0)
    tab.protocol_form.ramp_spin.setValue(15.0)
    tab.protocol_form.folder_edit.setText(str(tmp_path))
    window.show()
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow)
    tab.start_run()
    # Wait for the load (or the run's end, to name why it ended instead of timing out).
    qtbot.waitUntil(lambda: (tab.live_plot.n_samples > 0 and fast_sim_lab.rig.applied_force_n() > 2.5)
                    or not tab.rig_session.is_running, timeout=60_000)
    assert tab.rig_session.is_running, f"the run ended before the load: {tab.rig_session.outcome}"
    with qtbot.waitSignal(tab.rig_session.finished, timeout=20_000):
        qtbot.keyClick(tab.live_plot, Qt.Key.Key_Escape)
    assert fast_sim_lab.rig.applied_force_n() == 0.0
    assert tab.protocol_form.message_label.text().startswith("STOP pressed")
    window.close()


@pytest.mark.slow  # three 50× trials, an abort, a restart and a resume, then the fit in a spawned process
def test_wizard_end_to_end_abort_in_trial_3_restart_resume_and_save(qtbot, fast_sim_lab, tmp_path, monkeypatch):
    from app.core import user_folders
    from app.core.rig_protocol import finished_trials, read_session

    monkeypatch.setattr(user_folders, "calibrations_dir", lambda: tmp_path)
    lab = LabContext(BENCH_CONFIG)
    saved_paths = []
    lab.calibration_saved.connect(saved_paths.append)  # what the Forces tab listens to
    tab = CalibrationTab(lab)
    qtbot.addWidget(tab)
    form = tab.protocol_form
    form.forces_edit.setText("1.75, 3, 5.25")
    form.trials_spin.setValue(1)
    form.hold_spin.setValue(200.0)
    form.baseline_spin.setValue(20.0)
    form.ramp_spin.setValue(20.0)
    form.rest_spin.setValue(15.0)
    form.folder_edit.setText(str(tmp_path))
    assert tab.start_run()
    assert tab.steps.currentIndex() == PROTOCOL and tab.view_tabs.currentWidget() is tab.live_plot
    folder = tab.session_folder
    qtbot.waitUntil(lambda: len(tab.trials) == 2, timeout=90_000)
    with qtbot.waitSignal(tab.rig_session.progress, timeout=60_000,
                          check_params_cb=lambda p: p.trial == 2 and p.phase in ("loading", "hold")):
        pass
    with qtbot.waitSignal(tab.rig_session.finished, timeout=30_000) as blocker:
        form.abort_button.click()  # in trial 3
    assert blocker.args[0].status == ABORTED and fast_sim_lab.rig.applied_force_n() == 0.0
    kept = {i: p.read_bytes() for i, p in finished_trials(folder, read_session(folder)).items()}
    assert sorted(kept) == [0, 1]

    # The app restarts: a new tab on the same lab names the unfinished session and resumes it.
    tab.shutdown()
    tab.close()
    tab = CalibrationTab(lab)
    qtbot.addWidget(tab)
    tab.protocol_form.folder_edit.setText(str(tmp_path))
    tab.show_unfinished_sessions()
    assert folder.name in tab.unfinished_label.text() and "2/3 trials" in tab.unfinished_label.text()
    assert tab.resume_run(folder)
    assert tab.trial_list.count() == 2  # the kept trials are listed at once
    assert tab.protocol_form.hold_spin.value() == 200.0  # the session's own protocol
    qtbot.waitUntil(lambda: not tab.rig_session.is_running and not tab.is_fitting
                    and ("fitted" in tab.status_label.text() or "refused" in tab.status_label.text()),
                    timeout=180_000)
    done = finished_trials(folder, read_session(folder))
    assert sorted(done) == [0, 1, 2] and all(done[i].read_bytes() == kept[i] for i in (0, 1))
    assert tab.result is not None, tab.status_label.text()
    assert len(tab.result.trials) == 3
    # Review: Fig. 9ii (means vs force) and Fig. 9iii (parameters vs force) are drawn; Next goes to Save.
    assert tab.steps.currentIndex() == REVIEW and tab.next_button.isEnabled()
    assert len(tab.mean_plot.getPlotItem().listDataItems()) >= 1
    assert len(tab.param_plot.getPlotItem().listDataItems()) >= 3
    tab.next_button.click()
    assert tab.steps.currentIndex() == SAVE and tab.save_button.isEnabled()
    asked = []
    tab.confirm_save = lambda problems: asked.append(problems) or True
    out = tmp_path / "cal.json"
    assert tab.save(out)
    assert asked == ([] if not tab.result.problems else [tab.result.problems])
    entry = json.loads(out.read_text())["sensors"]["BENCH"]
    assert len(entry["trials"]) == 3 and all("mean_conductance_S" in t for t in entry["trials"])
    assert entry["unloaded_conductance_S"] is not None
    assert saved_paths == [str(out)]
    assert tab.history_table.rowCount() == 1
    tab.shutdown()
    lab.close()


def test_the_sensor_is_picked_on_the_body_drawing(qtbot):
    page = CalibrationTab(LabContext(BENCH_CONFIG))
    qtbot.addWidget(page)
    picker = page.sensor_picker
    assert picker.selected == "BENCH" and picker.buttons["BENCH"].isChecked()  # the rig's sensor from the config
    picker.buttons["S03L"].click()
    assert page.sensor_edit.text() == "S03L" and picker.buttons["S03L"].isChecked()
    assert not picker.buttons["BENCH"].isChecked()
    page.sensor_edit.setText("S12B")
    assert picker.selected == "S12B" and picker.buttons["S12B"].isChecked() and not picker.buttons["S03L"].isChecked()
    page.shutdown()


def test_the_redo_button_rejects_the_selected_trial_and_runs_it_again(rig_tab, qtbot):
    from PySide6.QtCore import Qt

    from app.core.rig_protocol import finished_trials, read_session

    tab = rig_tab
    tab.protocol_form.hold_spin.setValue(100.0)
    tab.protocol_form.ramp_spin.setValue(15.0)
    tab.protocol_form.baseline_spin.setValue(25.0)
    tab.show()
    qtbot.waitExposed(tab)
    assert tab.start_run()
    folder = tab.session_folder
    qtbot.waitUntil(lambda: len(tab.trials) == 1, timeout=60_000)
    with qtbot.waitSignal(tab.rig_session.finished, timeout=30_000):
        tab.protocol_form.abort_button.click()  # trial 1 kept, trial 2 not run
    settings = read_session(folder)
    first = finished_trials(folder, settings)[0]
    original = first.read_bytes()
    tab.go_to_step(REVIEW)  # the review page, where the button is
    qtbot.waitUntil(tab.redo_button.isVisible, timeout=10_000)
    assert not tab.redo_button.isEnabled() or tab.trial_list.selectedItems() == []
    tab.trial_list.item(0).setSelected(True)
    qtbot.waitUntil(tab.redo_button.isEnabled, timeout=10_000)
    qtbot.mouseClick(tab.redo_button, Qt.MouseButton.LeftButton)
    # The CSV is kept aside, never deleted, and the session runs the trial again.
    rejected = folder / "rejected" / first.name
    assert rejected.read_bytes() == original and not first.exists()
    assert "rejected" in tab.status_label.text()
    assert tab.rig_session.is_running and tab.trial_list.count() == 0
    qtbot.waitUntil(lambda: 0 in finished_trials(folder, settings), timeout=60_000)
    redone = finished_trials(folder, settings)[0]
    assert redone.name == first.name and redone.read_bytes() != original  # a new recording of the same trial
    qtbot.waitUntil(lambda: tab.trial_list.count() >= 1, timeout=30_000)
    assert tab.trials[0].path == redone
    with qtbot.waitSignal(tab.rig_session.finished, timeout=30_000):
        tab.protocol_form.abort_button.click()
    assert rejected.read_bytes() == original


def test_the_conditioning_fields_go_into_the_protocol_and_come_back_on_resume(rig_tab, tmp_path):
    from app.core.rig_protocol import read_session, write_session

    tab = rig_tab
    form = tab.protocol_form
    assert tab.protocol_settings().condition_cycles == 0  # off unless asked for
    assert not form.condition_cycles_spin.isEnabled()
    before = form.estimated_duration_s()
    form.condition_check.setChecked(True)
    form.condition_cycles_spin.setValue(3)
    form.condition_force_spin.setValue(4.0)
    assert form.condition_cycles_spin.isEnabled()
    settings = tab.protocol_settings()
    assert (settings.condition_cycles, settings.condition_force_n) == (3, 4.0)
    assert form.estimated_duration_s() == pytest.approx(before + 3 * (form.ramp_spin.value() + 20.0))
    # A session's own conditioning comes back into the form when it is resumed.
    folder = tmp_path / "BENCH_x"
    folder.mkdir()
    write_session(folder, settings)
    form.condition_check.setChecked(False)
    form.condition_force_spin.setValue(0.0)
    started = []
    tab.start_run = lambda resume=None: started.append(resume) or True
    assert tab.resume_run(folder)
    assert started == [folder] and form.condition_check.isChecked()
    assert form.condition_cycles_spin.value() == 3 and form.condition_force_spin.value() == 4.0
    assert tab.protocol_settings() == read_session(folder)


def test_the_wizard_steps_and_next_waits_for_a_passing_rig_check(rig_tab, qtbot, fast_sim_lab, tmp_path):
    tab = rig_tab
    tab.show()
    qtbot.waitExposed(tab)
    assert tab.steps.currentIndex() == SETUP and tab.step_label.text().startswith("Step 1 of 6")
    assert tab.rig_note.isVisible() and "R_C = 900 Ω" in tab.rig_note.text()  # the readout, on the setup page
    assert tab.next_button.isEnabled() and not tab.back_button.isEnabled()
    tab.sensor_edit.setText("S99Z")
    assert not tab.next_button.isEnabled() and "S99Z is not a channel of the board" in tab.step_hint.text()
    tab.sensor_picker.buttons["BENCH"].click()
    qtbot.mouseClick(tab.next_button, Qt.MouseButton.LeftButton)
    assert tab.steps.currentIndex() == RIG_CHECK and not tab.next_button.isEnabled()

    # A rig servo that does not answer: that line fails with the reason, the ones after it are not tried, no Next.
    servo = tab.lab.config.rig.servo_id
    fast_sim_lab.rig.chain.set_no_reply(servo)
    with qtbot.waitSignal(tab.rig_check_finished, timeout=30_000) as blocker:
        qtbot.mouseClick(tab.check_button, Qt.MouseButton.LeftButton)
    assert blocker.args == [False]
    lines = tab.check_lines()
    assert lines[0][0] == "✔ pass" and lines[1][0] == "✘ FAIL" and "no reply from servo 1" in lines[1][2]
    assert lines[2][2].startswith("not tried") and lines[-1][1] == "board streams BENCH"
    assert lines[-1][0] == "✔ pass"  # the board part is judged on its own
    assert not tab.next_button.isEnabled() and "FAILED" in tab.status_label.text()

    # A healthy rig: every line passes with what was seen, and Next goes on.
    fast_sim_lab.rig.chain.set_no_reply(servo, False)
    with qtbot.waitSignal(tab.rig_check_finished, timeout=30_000) as blocker:
        tab.start_rig_check()
    assert blocker.args == [True], tab.check_lines()
    lines = tab.check_lines()
    assert [mark for mark, _, _ in lines] == ["✔ pass"] * 5
    assert "XM430-W350" in lines[1][2] and "mA at rest" in lines[3][2] and "µS" in lines[4][2]
    assert tab.next_button.isEnabled()
    # The check holds for the sensor it was run for: another sensor needs its own.
    tab.go_to_step(SETUP)
    tab.sensor_picker.buttons["S03L"].click()
    tab.go_to_step(RIG_CHECK)
    assert not tab.next_button.isEnabled()
    tab.sensor_picker.buttons["BENCH"].click()
    assert tab.next_button.isEnabled()
    qtbot.mouseClick(tab.next_button, Qt.MouseButton.LeftButton)
    # Find contact (the rig finds it, releases; nothing is recorded) and the optional conditioning.
    assert tab.steps.currentIndex() == RIG_CHECK + 1 and tab.protocol_form.condition_check.isVisible()
    assert not tab.next_button.isEnabled() and "find the contact first" in tab.step_hint.text()
    with qtbot.waitSignal(tab.rig_session.finished, timeout=60_000):
        qtbot.mouseClick(tab.contact_button, Qt.MouseButton.LeftButton)
    found = tab.contact_label.text()
    assert found.startswith("contact found: θ_contact = ") and "refined with the sensor" in found, found
    assert "load released" in found and fast_sim_lab.rig.applied_force_n() == 0.0
    assert list(tmp_path.iterdir()) == [] and tab.trial_list.count() == 0  # no session, no trial
    assert tab.next_button.isEnabled()
    qtbot.mouseClick(tab.next_button, Qt.MouseButton.LeftButton)
    assert tab.steps.currentIndex() == PROTOCOL and tab.protocol_form.run_button.isVisible()
    assert tab.view_tabs.currentWidget() is tab.live_plot
    assert not tab.next_button.isEnabled() and "run the protocol" in tab.step_hint.text()

    # An overloaded servo: torque cannot be enabled.
    fast_sim_lab.rig.chain.inject_overload(servo)
    with qtbot.waitSignal(tab.rig_check_finished, timeout=30_000) as blocker:
        tab.start_rig_check()
    assert blocker.args == [False]
    lines = tab.check_lines()
    assert lines[1][0] == "✔ pass" and lines[2][0] == "✘ FAIL" and "overload" in lines[2][2].lower(), lines
    tab.go_to_step(RIG_CHECK)
    assert not tab.next_button.isEnabled()


@pytest.mark.slow  # a trial on the 50x sim, then a fit in a spawned process while the run waits
def test_the_fit_of_the_trials_so_far_updates_during_the_run(rig_tab, qtbot, monkeypatch):
    tab = rig_tab
    monkeypatch.setattr(CalibrationTab, "LIVE_FIT_MIN_WALL_S", 0.0)  # the 50x trials take seconds, not minutes
    assert tab.start_run()
    # Pause during trial 1: the run then waits, unloaded, before trial 2 — time for the fit of trial 1.
    qtbot.waitUntil(lambda: tab.live_plot.trial == 0 or not tab.rig_session.is_running, timeout=60_000)
    assert tab.rig_session.is_running, tab.protocol_form.message_label.text()
    tab.protocol_form.pause_button.click()
    qtbot.waitUntil(lambda: tab.live_fits_shown >= 1 or not tab.rig_session.is_running, timeout=120_000)
    assert tab.rig_session.is_running, tab.protocol_form.message_label.text()
    assert len(tab.trials) == 1
    assert tab.live_fit_label.text().startswith("fit so far"), tab.live_fit_label.text()
    assert "τ =" in tab.live_fit_label.text() and tab.trial_table.rowCount() == 1
    assert "so far" in tab.summary_label.text() and len(tab.curves()) == 2  # measured + its fit
    assert tab.result is None and not tab.save_button.isEnabled()  # nothing to save from a run in progress
    assert tab.steps.currentIndex() == PROTOCOL  # the run's page stays
    with qtbot.waitSignal(tab.rig_session.finished, timeout=30_000):
        tab.protocol_form.abort_button.click()


def test_the_protocol_check_predicts_the_reading_from_the_sensors_last_calibration(tab, tmp_path):
    """With a saved calibration of the sensor in its history, the check predicts from it (a stiff sensor reads far
    below the ceiling: no warning); without one, from a typical sensor (which says so)."""
    from app.core import user_folders
    from app.core.calibration_fit import HISTORY_FILE
    from app.core.rig_protocol import check_protocol

    sensor = "S07B"
    settings = replace(tab.protocol_settings(), sensor=sensor)
    assert tab.last_calibration(sensor, settings.area_m2) is None
    typical = check_protocol(settings, tab.lab.config.rig, tab.lab.config.board,
                             expected_sls=tab.last_calibration(sensor, settings.area_m2))
    assert any("a typical sensor" in w for w in typical.warnings)
    folder = user_folders.calibrations_dir()
    folder.mkdir(parents=True, exist_ok=True)
    with (folder / HISTORY_FILE).open("a", encoding="utf-8") as handle:
        handle.write(json.dumps({"sensor": sensor, "sls": {"E0_Pa": 2e6, "E1_Pa": 4e6, "mu1_Pa_s": 4e8}}) + "\n")
    expected = tab.last_calibration(sensor, settings.area_m2)
    assert expected is not None and float(expected[0].E0_Pa) == 2e6
    own = check_protocol(settings, tab.lab.config.rig, tab.lab.config.board, expected_sls=expected)
    assert not any("readout's ceiling" in w for w in own.warnings), own.warnings
