"""The Calibration tab: load trial CSVs, fit on a worker thread, plot measured vs fitted, save the calibration."""

from __future__ import annotations

import numpy as np
import pytest

from app import calfiles
from app.lab import LabContext
from app.tabs.calibration import CalibrationTab
from devices.config import LabConfig, RobotConfig
from models.physics import PhysicsConstants
from models.synthetic import TYPICAL_TRUTH, paper_protocol

NO_PORT_CONFIG = LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port"))


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
    assert "S06B" in tab.summary_label.text() and "τ" in tab.summary_label.text()
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
