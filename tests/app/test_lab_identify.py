"""`sensnake lab identify`: the physics lab's shell stiffness and the scene's frictions recovered from a recording
made with other values than the defaults, reading only what a real recording holds (the test removes /sim)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

pytest.importorskip("mujoco")

from app.cli.main import main  # noqa: E402
from app.core.experiment import run_experiment  # noqa: E402
from app.core.identify import candidate, read_measurement, replay  # noqa: E402
from devices.config import load_config  # noqa: E402

TRUTH = {"shell_stiffness_n_per_m": 2800.0, "ground_friction": 0.38, "obstacle_friction": 0.14}  # defaults 2000, 0.3, 0.1
SCENE = f"""[ground]
friction = {TRUTH["ground_friction"]}

[[obstacle]]
shape = "half_cylinder"
x_m = 0.0
radius_m = 0.2688
friction = {TRUTH["obstacle_friction"]}

[robot]
head_x_m = 0.44
start = "settle"
"""
PLAY_S = 6.0


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The paper's obstacle with its frictions and the shell's stiffness changed, the settled drape played
    follow-the-leader at 0.3 rad/s for 6 s (sliding over the PTFE and the floor); and a copy of the recording without
    /sim, what a real robot's recording would be."""
    folder = tmp_path_factory.mktemp("identify")
    scene = folder / "scene.toml"
    scene.write_text(SCENE, encoding="utf-8")
    lab = folder / "lab.toml"
    lab.write_text(f"[lab.physics]\nshell_stiffness_n_per_m = {TRUTH['shell_stiffness_n_per_m']}\n", encoding="utf-8")
    rec = folder / "rec.h5"
    result = run_experiment(rec, load_config(lab), scene=str(scene), speed_rad_s=0.3, seconds=PLAY_S, rest_cap_s=0.0)
    assert result.valid
    real = folder / "real.h5"
    real.write_bytes(rec.read_bytes())
    with h5py.File(real, "a") as f:
        del f["sim"]  # the simulation's truth: a real recording has none
    return folder, scene, lab, rec, real


def test_a_replay_with_the_values_the_recording_was_made_with_gives_its_angles_and_currents_back(made):
    folder, scene, lab, rec, real = made
    measurement = read_measurement(real, 2.0, scene.read_text(encoding="utf-8"))
    config, terrain = candidate(load_config(lab), measurement.scene_text, {k: v for k, v in TRUTH.items()})
    replayed = replay(measurement, config, terrain)
    assert not replayed.invalid
    np.testing.assert_array_equal(replayed.present_rad, measurement.present_rad)
    np.testing.assert_array_equal(replayed.current_ma, measurement.current_ma)
    with h5py.File(rec) as f:  # the body too (the replay's segment centres, at the ticks, against /sim's)
        points = f["sim/points_m"][: len(measurement.tick_s)]
    np.testing.assert_allclose(replayed.centers_m, 0.5 * (points[:, :-1] + points[:, 1:]), atol=1e-12)
    usable = np.isfinite(measurement.force_n)
    assert np.sqrt(np.mean((replayed.force_n[usable] - measurement.force_n[usable]) ** 2)) < 0.02  # estimates' error


@pytest.mark.slow
@pytest.mark.timeout(1200)  # about 40 replays of 12 simulated s: 40 s of CPU, 7-8 min on the shared cores at load 15
def test_identify_recovers_the_shell_stiffness_and_both_frictions_within_10_percent(made, capsys):
    folder, scene, lab, rec, real = made
    out = folder / "fitted.toml"
    code = main(["lab", "identify", str(real), "--scene", str(scene), "--window", str(PLAY_S), "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    fitted = load_config(out)  # a lab-config fragment: loads as one
    got = {"shell_stiffness_n_per_m": fitted.lab.physical.shell_stiffness_n_per_m,
           "ground_friction": fitted.lab.ground_friction, "obstacle_friction": fitted.lab.obstacle_friction}
    for key, value in TRUTH.items():
        assert got[key] == pytest.approx(value, rel=0.10), (key, printed.out)
    assert "NOT FIXED" not in out.read_text(encoding="utf-8")
    assert "residual RMS" in printed.out and "a 10 % rise moves each signal" in printed.out


def test_identify_refuses_to_replace_a_file_and_unknown_keys_before_any_replay(made, capsys):
    folder, scene, lab, rec, real = made
    existing = folder / "kept.toml"
    existing.write_text("# mine\n", encoding="utf-8")
    assert main(["lab", "identify", str(rec), "--out", str(existing)]) == 1
    assert "never replaces" in capsys.readouterr().err and existing.read_text(encoding="utf-8") == "# mine\n"
    assert main(["lab", "identify", str(rec), "--fit", "timestep_s", "--out", str(folder / "x.toml")]) == 1
    assert "not a property of the robot" in capsys.readouterr().err
    assert main(["lab", "identify", str(real), "--out", str(folder / "y.toml")]) == 1  # no /sim: no scene in it
    assert "--scene" in capsys.readouterr().err
    assert not (folder / "x.toml").exists() and not (folder / "y.toml").exists()
