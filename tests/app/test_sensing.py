"""What a physics-lab run's controller senses: a rig calibration's errors by default, the truth with ideal sensing;
the recording says which (``/sim`` attributes ``sensing`` and ``physics``)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from app.core.sensing import RIG_FIT_ERRORS, FitErrors, rig_calibration, sensing_calibration
from devices.config import LabConfig, parse_config
from devices.errors import ConfigError


def _truth() -> dict:
    from devices.config import BoardConfig
    from devices.sim.board import VirtualBoard
    from devices.sim.physics.headless import ManualClock

    return VirtualBoard(BoardConfig(), ManualClock(), seed=3).ground_truth_calibration()  # type: ignore[arg-type]


def test_ideal_sensing_is_the_true_calibration() -> None:
    truth = _truth()
    calibration, record = sensing_calibration(truth, "ideal", seed=4)
    assert calibration is truth and record["sensing"] == "ideal"


def test_a_robots_calibration_is_off_per_sensor_seeded_by_the_run() -> None:
    truth = _truth()
    errors = FitErrors(mean=(0.01, -0.02, 0.0), cov=((4e-4, 0, 0), (0, 9e-4, 0), (0, 0, 1e-3)), sensors=5,
                       source="test")
    first, ratios = rig_calibration(truth, seed=7, errors=errors)
    again, _ = rig_calibration(truth, seed=7, errors=errors)
    other, _ = rig_calibration(truth, seed=8, errors=errors)
    assert first == again and first != other
    assert ratios.shape == (36, 3) and len({tuple(r) for r in ratios.tolist()}) == 36  # each sensor its own
    name = "S06B"
    k = list(truth["sensors"]).index(name)
    for key, column in (("E0_Pa", 0), ("E1_Pa", 1), ("mu1_Pa_s", 2)):
        assert first["sensors"][name]["sls"][key] == pytest.approx(truth["sensors"][name]["sls"][key]
                                                                   * np.exp(ratios[k, column]), rel=1e-12)
    assert truth["sensors"][name]["sls"]["E0_Pa"] != first["sensors"][name]["sls"]["E0_Pa"]
    assert first["sensors"][name]["area_m2"] == truth["sensors"][name]["area_m2"]  # the rig's area, not fitted
    assert "source" in first and "source" not in truth  # the truth document is left as it was


def test_the_default_distribution_is_a_measured_one() -> None:
    assert RIG_FIT_ERRORS.sensors >= 3 and RIG_FIT_ERRORS.source.startswith("benchmarks/")
    cov = np.asarray(RIG_FIT_ERRORS.cov)
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) >= -1e-12)


def test_the_lab_config_names_a_bad_sensing() -> None:
    with pytest.raises(ConfigError, match=r"lab\.sensing"):
        parse_config('[lab]\nsensing = "perfect"\n', "lab.toml")


@pytest.mark.parametrize("sensing", ["robot", "ideal"])
def test_a_run_records_what_its_controller_sensed(tmp_path: Path, sensing: str) -> None:
    pytest.importorskip("mujoco")
    from app.core.experiment import run_experiment

    config = LabConfig()
    config = replace(config, lab=replace(config.lab, sensing=sensing))
    out = tmp_path / "run.h5"
    run_experiment(out, config, scene="flat", seconds=1.0, settle_s=0.5, rest_cap_s=0.0, controller="feedback")
    with h5py.File(out, "r") as f:
        record = json.loads(f["sim"].attrs["sensing"])
        physics = json.loads(f["sim"].attrs["physics"])
        used = json.loads(f["forces"].attrs["calibration"]) if "calibration" in f["forces"].attrs else None
    assert record["sensing"] == sensing
    assert physics["shell_stiffness_n_per_m"] == 2000.0
    assert used is not None and ("source" in used) == (sensing == "robot")


def test_a_sweep_file_may_ask_for_ideal_sensing(tmp_path: Path) -> None:
    from app.core.errors import SweepError
    from app.core.sweep import _lab_config, read_sweep, sweep_tasks

    path = tmp_path / "sweep.toml"
    path.write_text('scenes = ["flat"]\ncontrollers = ["feedback"]\nideal_sensing = true\n', encoding="utf-8")
    plan = read_sweep(path)
    assert plan.ideal_sensing
    task = sweep_tasks(plan, tmp_path)[0]
    assert task["ideal_sensing"] is True and _lab_config(task).lab.sensing == "ideal"
    path.write_text('scenes = ["flat"]\ncontrollers = ["feedback"]\n', encoding="utf-8")
    task = sweep_tasks(read_sweep(path), tmp_path)[0]
    assert "ideal_sensing" not in task and _lab_config(task).lab.sensing == "robot"  # a folder of before resumes
    path.write_text('scenes = ["flat"]\nideal_sensing = "yes"\n', encoding="utf-8")
    with pytest.raises(SweepError, match="ideal_sensing"):
        read_sweep(path)
