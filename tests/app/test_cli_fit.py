"""``sensnake fit / estimate / forward / bench`` in-process: round trip on synthetic files, one-line errors."""

from __future__ import annotations

import json
import os
import shutil
import sys

import numpy as np
import pytest

import benchmarks
from app.cli import main
from app.core import calfiles
from models.physics import PhysicsConstants
from models.synthetic import TYPICAL_TRUTH, Readout, paper_protocol

AREA = "1.4e-3"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Four synthetic trials (one per paper force, 0.1 % noise, 12-bit readout) fitted once into cal.json."""
    folder = tmp_path_factory.mktemp("cal")
    trials = paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=5, repeats=1, noise_rel=0.001,
                            readout=Readout())
    paths = []
    for t in trials:
        path = folder / f"{t.name}.csv"
        calfiles.write_trial_csv(path, t.time_s, t.force_n, t.conductance_s)
        paths.append(str(path))
    physics = folder / "physics.json"
    physics.write_text(json.dumps(PhysicsConstants().to_dict()))
    code = main(["fit", *paths, "--sensor", "S06B", "--area", AREA, "--physics", str(physics),
                 "--out", str(folder / "cal.json")])
    assert code == 0
    return folder, paths


def _run(argv, capsys):
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_fit_writes_spec_calibration_and_prints_table(lab, capsys):
    folder, paths = lab
    document = json.loads((folder / "cal.json").read_text())
    assert document["format"] == "sensnake-calibration" and document["version"] == 1
    entry = document["sensors"]["S06B"]
    assert entry["area_m2"] == pytest.approx(1.4e-3)
    assert entry["sls"]["E0_Pa"] == pytest.approx(6e5, rel=0.01)
    assert entry["sls"]["mu1_Pa_s"] == pytest.approx(9e7, rel=0.01)
    assert [t["file"] for t in entry["trials"]] == [p.rsplit("/", 1)[1] for p in paths]
    assert [t["force_N"] for t in entry["trials"]] == pytest.approx([1.75, 3.0, 4.0, 5.25])
    # Fitting into another file (physics taken from the first one) prints the table: one row per trial.
    code, out, err = _run(["fit", paths[0], paths[3], "--sensor", "S01L", "--area", AREA, "--physics",
                           str(folder / "cal.json"), "--out", str(folder / "other.json")], capsys)
    assert code == 0, err
    assert "file" in out.splitlines()[0] and "mu1_Pa_s" in out.splitlines()[0]
    assert sum(line.startswith("F1.75_r1.csv") for line in out.splitlines()) == 1


def test_fit_writes_every_spec_key(lab):
    """SPEC §3.3: the keys other tools may read are all there (extra keys are allowed)."""
    folder, _ = lab
    document = json.loads((folder / "cal.json").read_text())
    assert set(document["physics"]) == set(PhysicsConstants().to_dict())
    entry = document["sensors"]["S06B"]
    assert {"area_m2", "linear", "sls", "sls_trend", "trials"} <= set(entry)
    assert set(entry["linear"]) == {"m_S_per_N", "d_S"}
    assert set(entry["sls"]) == {"E0_Pa", "E1_Pa", "mu1_Pa_s"}
    assert {key: len(pair) for key, pair in entry["sls_trend"].items()} == {"E0_Pa": 2, "E1_Pa": 2, "mu1_Pa_s": 2}
    spec_trial_keys = {"file", "force_N", "c1", "c2", "c3", "E0_Pa", "E1_Pa", "mu1_Pa_s", "a_s", "b_Pa", "c_Pa_s",
                       "rmse_S", "warnings"}
    for trial in entry["trials"]:
        assert spec_trial_keys <= set(trial)
        assert isinstance(trial["warnings"], list)


def test_fit_takes_the_saturation_level_from_the_configured_readout(lab, tmp_path, capsys):
    """SPEC §4: R_C is configurable, and samples at the readout's ceiling 1/R_C are flagged, not fitted."""
    folder, paths = lab
    trial = calfiles.read_trial_csv(paths[1])
    conductance = trial.conductance_s.copy()
    hold = np.flatnonzero(trial.force_n > 0)
    conductance[hold[100:103]] = 1.0 / 900.0  # three samples at the default circuit's ceiling
    calfiles.write_trial_csv(tmp_path / "t.csv", trial.time_s, trial.force_n, conductance)
    physics = ["--physics", str(folder / "cal.json")]
    config = tmp_path / "lab.toml"
    config.write_text("[board]\nr_c_ohm = 450.0\n")
    saturated = {}
    for name, extra in (("default", []), ("configured", ["--config", str(config)])):
        out = tmp_path / f"{name}.json"
        code, _, err = _run(["fit", str(tmp_path / "t.csv"), "--sensor", "S06B", "--area", AREA, *physics,
                             "--out", str(out), *extra], capsys)
        assert code == 0, err
        saturated[name] = json.loads(out.read_text())["sensors"]["S06B"]["trials"][0]["saturated_samples"]
    assert saturated == {"default": 3, "configured": 0}


def test_fit_without_physics_uses_the_papers_constants_and_says_so(lab, tmp_path, capsys):
    _, paths = lab
    out = tmp_path / "new.json"
    code, _, err = _run(["fit", paths[0], "--sensor", "S01L", "--area", AREA, "--out", str(out)], capsys)
    assert code == 0
    assert "no --physics given" in err and "K_contact_ohm_sqrtN" in err
    stored = json.loads(out.read_text())["physics"]
    assert stored == PhysicsConstants().to_dict()


def test_an_out_in_a_missing_folder_is_refused_before_the_fit(lab, tmp_path, capsys, monkeypatch):
    from app.cli import fit as fit_command

    _, paths = lab
    monkeypatch.setattr(fit_command.calfiles, "read_trial_csv", lambda path: pytest.fail("the fit ran first"))
    code, _, err = _run(["fit", paths[0], "--sensor", "S01L", "--area", AREA, "--out",
                         str(tmp_path / "nodir" / "x.json")], capsys)
    assert code == 1 and "the folder" in err and "nodir does not exist" in err, err


def test_a_trial_of_a_few_rows_is_refused_as_too_few_not_as_a_flat_sensor(tmp_path, capsys):
    """Three rows whose conductance rises 1000-fold were called "flat (0 S span …, noise nan S)"."""
    trial = tmp_path / "three.csv"
    trial.write_text("time_s,force_N,conductance_S\n0,0,1.3e-8\n1,1,1.2e-5\n2,1,2.4e-5\n", encoding="utf-8")
    code, _, err = _run(["fit", str(trial), "--sensor", "S06B", "--area", AREA, "--out", str(tmp_path / "o.json")],
                        capsys)
    assert code == 1 and "3 conductance sample(s): too few to fit" in err and "flat" not in err, err


def test_fit_updates_and_keeps_other_sensors(lab, tmp_path, capsys, monkeypatch):
    folder, paths = lab
    cal = tmp_path / "cal.json"
    shutil.copy(folder / "cal.json", cal)
    monkeypatch.setenv("SENSNAKE_FIT_SOLVER", "gauss-newton")  # the CasADi path through the CLI
    code, _, _ = _run(["fit", *paths[:2], "--sensor", "S01L", "--area", "1e-3", "--out", str(cal)], capsys)
    assert code == 0
    document = json.loads(cal.read_text())
    assert set(document["sensors"]) == {"S06B", "S01L"}
    assert document["sensors"]["S01L"]["area_m2"] == 1e-3
    assert document["sensors"]["S01L"]["solver"] == "casadi gauss-newton"
    monkeypatch.setenv("SENSNAKE_FIT_SOLVER", "newton-raphson")
    code, _, err = _run(["fit", paths[0], "--sensor", "S01L", "--area", "1e-3", "--out", str(cal)], capsys)
    assert code == 1 and "SENSNAKE_FIT_SOLVER='newton-raphson' is not one of" in err


def test_round_trip_forward_then_estimate(lab, tmp_path, capsys):
    folder, _ = lab
    cal = str(folder / "cal.json")
    t = np.arange(0, 200, 1 / 6)
    force = np.where(t > 5, 2.0, 0.0) + np.where(t > 80, 2.5, 0.0) - np.where(t > 150, 3.0, 0.0)
    calfiles.write_series_csv(tmp_path / "force.csv", t, ("S06B",), force[:, None])
    assert _run(["forward", str(tmp_path / "force.csv"), "--cal", cal, "--out", str(tmp_path / "c.csv")],
                capsys)[0] == 0
    conductance = calfiles.read_series_csv(tmp_path / "c.csv", "conductance_S")
    assert conductance.columns == ("S06B",)
    assert _run(["estimate", str(tmp_path / "c.csv"), "--cal", cal, "--out", str(tmp_path / "f.csv")],
                capsys)[0] == 0
    back = calfiles.read_series_csv(tmp_path / "f.csv", "force_N")
    np.testing.assert_allclose(back.values[:, 0], force, atol=1e-9)
    # The linear model ignores creep: same file, visibly different forces during the holds.
    assert _run(["estimate", str(tmp_path / "c.csv"), "--cal", cal, "--model", "linear", "--out",
                 str(tmp_path / "lin.csv")], capsys)[0] == 0
    linear = calfiles.read_series_csv(tmp_path / "lin.csv", "force_N").values[:, 0]
    assert 0.01 < np.max(np.abs(linear - force)[t > 6]) < 1.0


def test_linear_estimate_clips_below_baseline_like_sls_and_says_so(lab, tmp_path, capsys):
    folder, _ = lab
    cal = str(folder / "cal.json")
    t = np.arange(0.0, 10.0, 1 / 6)
    # Below the linear model's offset d (0 S, then a small reading above an open line's 1e-9 S but under d): the line
    # would give negative forces.
    d = json.loads((folder / "cal.json").read_text())["sensors"]["S06B"]["linear"]["d_S"]
    assert d > 1e-8
    conductance = np.where(t < 5, 0.0, d / 2)
    calfiles.write_series_csv(tmp_path / "low.csv", t, ("S06B",), conductance[:, None])
    code, _, err = _run(["estimate", str(tmp_path / "low.csv"), "--cal", cal, "--model", "linear",
                         "--out", str(tmp_path / "f.csv")], capsys)
    assert code == 0, err
    force = calfiles.read_series_csv(tmp_path / "f.csv", "force_N").values[:, 0]
    assert np.all(force == 0.0)
    assert "BELOW_BASELINE" in err and "OPEN_CIRCUIT" in err


def test_estimate_warns_when_extrapolating(lab, tmp_path, capsys):
    folder, _ = lab
    cal = str(folder / "cal.json")
    t = np.arange(0, 60, 1 / 6)
    calfiles.write_series_csv(tmp_path / "big.csv", t, ("S06B",), np.where(t > 5, 9.0, 0.0)[:, None])
    assert _run(["forward", str(tmp_path / "big.csv"), "--cal", cal, "--out", str(tmp_path / "c.csv")],
                capsys)[0] == 0
    # 9 N reads above the default readout's ceiling 1/900 S: impossible there, so rejected and said so.
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", cal, "--out", str(tmp_path / "f.csv")],
                        capsys)
    assert code == 0
    assert "S06B: 329 sample(s) rejected, force NaN (ABOVE_CEILING 329)" in err
    assert np.all(np.isnan(calfiles.read_series_csv(tmp_path / "f.csv", "force_N", allow_gaps=True).values[t > 5]))
    # With a readout that can report it (R_C = 100 Ω), 9 N is estimated and flagged as extrapolated.
    config = tmp_path / "lab.toml"
    config.write_text("[board]\nr_c_ohm = 100.0\n")
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", cal, "--out", str(tmp_path / "f.csv"),
                         "--config", str(config)], capsys)
    assert code == 0
    assert "329 extrapolated (forces 9–9 N outside the calibrated range 1.75–5.25 N)" in err


def test_single_generic_column_maps_to_the_only_sensor(lab, tmp_path, capsys):
    folder, paths = lab
    code, _, _ = _run(["estimate", paths[1], "--cal", str(folder / "cal.json"), "--out", str(tmp_path / "f.csv")],
                      capsys)
    # A trial file has force_N and conductance_S: force_N is not a calibrated sensor.
    assert code == 1
    trial = calfiles.read_trial_csv(paths[1])
    calfiles.write_series_csv(tmp_path / "c.csv", trial.time_s, ("conductance_S",), trial.conductance_s[:, None])
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", str(folder / "cal.json"),
                         "--out", str(tmp_path / "f.csv")], capsys)
    assert code == 0, err
    estimate = calfiles.read_series_csv(tmp_path / "f.csv", "force_N")
    assert estimate.columns == ("force_N",)
    hold = trial.time_s > 10
    assert np.median(estimate.values[hold, 0]) == pytest.approx(3.0, rel=0.01)


def _bad_cases(folder, paths, tmp_path):
    good_cal = str(folder / "cal.json")
    text = (tmp_path / "x").parent
    cases = {
        "missing column": ("t.csv", "time_s,conductance_S\n0,1e-4\n", ["fit", "@", "--sensor", "S", "--area", AREA,
                                                                        "--out", str(text / "o.json")],
                           "t.csv:1: missing column 'force_N'"),
        "kN units": ("t.csv", "time_s,force_kN,conductance_S\n0,1,1e-4\n",
                     ["fit", "@", "--sensor", "S", "--area", AREA, "--out", str(text / "o.json")],
                     "t.csv:1: column 'force_kN' is in kN"),
        "NaN": ("t.csv", "time_s,force_N,conductance_S\n0,1,1e-4\n1,1,NaN\n",
                ["fit", "@", "--sensor", "S", "--area", AREA, "--out", str(text / "o.json")],
                "t.csv:3: column 'conductance_S' is NaN"),
        "unsorted": ("t.csv", "time_s,force_N,conductance_S\n0,1,1e-4\n2,1,1e-4\n1,1,1e-4\n",
                     ["fit", "@", "--sensor", "S", "--area", AREA, "--out", str(text / "o.json")],
                     "t.csv:4: time_s goes backwards"),
        "unknown format": ("cal.json", '{"format": "other", "version": 1}',
                           ["estimate", paths[0], "--cal", "@", "--out", str(text / "o.csv")],
                           "unknown format 'other'"),
        "unknown version": ("cal.json", '{"format": "sensnake-calibration", "version": 9}',
                            ["fit", paths[0], "--sensor", "S", "--area", AREA, "--out", "@"],
                            "unsupported calibration version 9"),
        # A column without a calibration is passed through in µS (test_cli_estimate_reanalysis); none at all is refused.
        "uncalibrated column": ("in.csv", "time_s,S07L,S08L\n0,1e-4,1e-4\n",
                                ["estimate", "@", "--cal", good_cal, "--out", str(text / "o.csv")],
                                "in.csv:1: none of its columns (S07L, S08L) has a calibration"),
        "forward kN": ("in.csv", "time_s,force_kN\n0,1\n",
                       ["forward", "@", "--cal", good_cal, "--out", str(text / "o.csv")],
                       "in.csv:1: column 'force_kN' is in kN"),
        "missing file": (None, None, ["forward", str(text / "nope.csv"), "--cal", good_cal, "--out",
                                      str(text / "o.csv")], "nope.csv: no such file"),
        "no physics in cal": ("cal.json", '{"format": "sensnake-calibration", "version": 1, "sensors": {"S06B": '
                              '{"area_m2": 1e-3, "sls": {"E0_Pa": 1, "E1_Pa": 1, "mu1_Pa_s": 1}}}}',
                              ["forward", str(folder / "force_only.csv"), "--cal", "@", "--out", str(text / "o.csv")],
                              "no 'physics' section"),
    }
    return cases


@pytest.mark.parametrize("case", ["missing column", "kN units", "NaN", "unsorted", "unknown format",
                                  "unknown version", "uncalibrated column", "forward kN", "missing file",
                                  "no physics in cal"])
def test_bad_files_give_one_line_and_exit_1(lab, tmp_path, capsys, case):
    folder, paths = lab
    calfiles.write_series_csv(folder / "force_only.csv", np.array([0.0, 1.0]), ("S06B",), np.ones((2, 1)))
    name, content, argv, expected = _bad_cases(folder, paths, tmp_path)[case]
    if name is not None:
        path = tmp_path / name
        path.write_text(content)
        argv = [str(path) if a == "@" else a for a in argv]
    code, _, err = _run(argv, capsys)
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert expected in lines[0]
    assert "Traceback" not in err


def test_flat_sensor_fit_is_refused(tmp_path, capsys):
    t = np.arange(0, 370, 1 / 6)
    force = np.where(t > 5, 3.0, 0.0)
    calfiles.write_trial_csv(tmp_path / "flat.csv", t, force, np.full(t.size, 4e-4))
    physics = tmp_path / "physics.json"
    physics.write_text(json.dumps(PhysicsConstants().to_dict()))
    code, _, err = _run(["fit", str(tmp_path / "flat.csv"), "--sensor", "S01L", "--area", AREA, "--physics",
                         str(physics), "--out", str(tmp_path / "cal.json")], capsys)
    assert code == 1
    assert "flat.csv: conductance is flat" in err and "refused" in err
    assert not (tmp_path / "cal.json").exists()


@pytest.fixture
def fake_benchmarks(tmp_path, monkeypatch):
    (tmp_path / "bench_aaa.py").write_text("def run(quick):\n    print('aaa ran', quick)\n")
    (tmp_path / "bench_bbb.py").write_text("def run(quick):\n    raise RuntimeError('boom\\nsecond line')\n")
    (tmp_path / "bench_ccc.py").write_text("def run(quick):\n    print('ccc ran', quick)\n")
    (tmp_path / "helper.py").write_text("raise AssertionError('not a benchmark')\n")
    monkeypatch.setattr(benchmarks, "__path__", [str(tmp_path)])
    yield
    for name in ("bench_aaa", "bench_bbb", "bench_ccc"):
        sys.modules.pop(f"benchmarks.{name}", None)


def test_bench_runs_every_module_and_survives_a_failure(fake_benchmarks, capsys):
    code, out, err = _run(["bench", "--quick"], capsys)
    assert code == 1
    assert "=== bench_aaa (quick) ===" in out and "aaa ran True" in out and "ccc ran True" in out
    failure = [line for line in err.splitlines() if "bench_bbb failed" in line]
    assert failure == ["sensnake bench: bench_bbb failed: RuntimeError: boom second line"]


def test_several_sensor_columns_round_trip(lab, tmp_path, capsys):
    folder, _ = lab
    document = calfiles.read_calibration(folder / "cal.json")
    second = dict(document["sensors"]["S06B"], area_m2=2.0e-3)
    cal = tmp_path / "cal.json"
    shutil.copy(folder / "cal.json", cal)
    calfiles.update_calibration(cal, "S01L", second, PhysicsConstants())
    t = np.arange(0, 100, 1 / 6)
    forces = np.column_stack([np.where(t > 5, 4.0, 0.0), np.where(t > 5, 4.0, 0.0) - np.where(t > 60, 1.0, 0.0)])
    calfiles.write_series_csv(tmp_path / "f.csv", t, ("S01L", "S06B"), forces)
    assert _run(["forward", str(tmp_path / "f.csv"), "--cal", str(cal), "--out", str(tmp_path / "c.csv")],
                capsys)[0] == 0
    conductance = calfiles.read_series_csv(tmp_path / "c.csv", "conductance_S")
    assert conductance.columns == ("S01L", "S06B")
    # The larger area sees less stress: lower conductance at the same force.
    late = (t > 6) & (t < 60)
    assert np.all(conductance.values[late, 0] < conductance.values[late, 1])
    assert _run(["estimate", str(tmp_path / "c.csv"), "--cal", str(cal), "--out", str(tmp_path / "e.csv")],
                capsys)[0] == 0
    np.testing.assert_allclose(calfiles.read_series_csv(tmp_path / "e.csv", "force_N").values, forces, atol=1e-9)


def test_estimate_treats_an_empty_cell_as_a_gap_and_writes_flags(lab, tmp_path, capsys):
    """One empty/NaN sample in a 6000-row file is a gap (NaN out, flagged), not a refusal of the file."""
    folder, _ = lab
    cal = str(folder / "cal.json")
    t = np.arange(6000) / 6.0
    force = np.where(t > 5, 3.0, 0.0)
    calfiles.write_series_csv(tmp_path / "force.csv", t, ("S06B",), force[:, None])
    assert _run(["forward", str(tmp_path / "force.csv"), "--cal", cal, "--out", str(tmp_path / "c.csv")],
                capsys)[0] == 0
    lines = (tmp_path / "c.csv").read_text().splitlines()
    lines[3001] = lines[3001].split(",")[0] + ","  # row 3000: empty conductance cell
    lines[4001] = lines[4001].split(",")[0] + ",nan"
    (tmp_path / "c.csv").write_text("\n".join(lines) + "\n")
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", cal, "--out", str(tmp_path / "f.csv"),
                         "--flags", str(tmp_path / "flags.csv")], capsys)
    assert code == 0, err
    assert "S06B: 2 sample(s) rejected, force NaN (NAN_INPUT 2)" in err
    out = calfiles.read_series_csv(tmp_path / "f.csv", "force_N", allow_gaps=True)
    assert out.columns == ("S06B",)  # SPEC §3.2 columns only
    gaps = np.isnan(out.values[:, 0])
    assert np.flatnonzero(gaps).tolist() == [3000, 4000]
    np.testing.assert_allclose(out.values[~gaps & (t > 6), 0], 3.0, atol=1e-6)
    flags = calfiles.read_series_csv(tmp_path / "flags.csv", "force_N").values[:, 0]
    assert flags[3000] == 1 and flags[4000] == 1


def test_estimate_refuses_a_degenerate_calibration_unless_allowed(lab, tmp_path, capsys):
    folder, paths = lab
    document = json.loads((folder / "cal.json").read_text())
    document["sensors"]["S06B"]["degenerate"] = True
    document["sensors"]["S06B"]["degenerate_reasons"] = ["E1_Pa at its upper bound"]
    cal = tmp_path / "deg.json"
    cal.write_text(json.dumps(document))
    trial = calfiles.read_trial_csv(paths[1])
    calfiles.write_series_csv(tmp_path / "c.csv", trial.time_s, ("S06B",), trial.conductance_s[:, None])
    argv = ["estimate", str(tmp_path / "c.csv"), "--cal", str(cal), "--out", str(tmp_path / "f.csv")]
    code, _, err = _run(argv, capsys)
    assert code == 1 and "degenerate SLS fit (E1_Pa at its upper bound)" in err and "--allow-degenerate" in err
    code, _, err = _run([*argv, "--allow-degenerate"], capsys)
    assert code == 0 and "using a degenerate SLS fit" in err


def test_estimate_modes_from_the_pareto_table(lab, tmp_path, capsys):
    """--engine reference gives the compiled numbers; --float32 writes float32-rounded forces; --no-contact runs
    the model without K/√F (visibly different on this sensor); --interp linear is accepted."""
    folder, _ = lab
    cal = str(folder / "cal.json")
    t = np.arange(0, 120, 1 / 6)
    force = np.where(t > 5, 2.0, 0.0) + np.where(t > 60, 2.0, 0.0)
    calfiles.write_series_csv(tmp_path / "force.csv", t, ("S06B",), force[:, None])
    assert _run(["forward", str(tmp_path / "force.csv"), "--cal", cal, "--out", str(tmp_path / "c.csv")],
                capsys)[0] == 0
    results = {}
    for name, extra in (("default", []), ("reference", ["--engine", "reference"]), ("f32", ["--float32"]),
                        ("nocontact", ["--no-contact"]), ("linear", ["--interp", "linear"])):
        out = tmp_path / f"{name}.csv"
        assert _run(["estimate", str(tmp_path / "c.csv"), "--cal", cal, "--out", str(out), *extra], capsys)[0] == 0
        results[name] = calfiles.read_series_csv(out, "force_N").values[:, 0]
        if name == "f32":
            assert max(len(line.split(",")[1]) for line in out.read_text().splitlines()[1:]) <= 16
    np.testing.assert_allclose(results["reference"], results["default"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(results["default"], force, atol=1e-9)
    np.testing.assert_allclose(results["f32"], force, rtol=1e-6, atol=1e-6)
    assert not np.allclose(results["f32"], results["default"], rtol=0, atol=0)
    assert np.max(np.abs(results["nocontact"] - force)[t > 6]) > 0.05
    np.testing.assert_allclose(results["linear"][t > 6], force[t > 6], rtol=0.05)


def test_slow_creep_sensor_fits_and_estimates_right_end_to_end(tmp_path, capsys):
    """A slow-creep sensor on the CLI: τ = 1600 s under 370 s holds, 0.2 % noise. The fit once collapsed to
    τ ≈ 1e-17 s and estimate then erred 0.11 N RMS with exit 0; now: not degenerate, τ's interval holds the truth,
    and a held-out record comes back within a few mN."""
    from models.sls import conductance_from_force
    from models.synthetic import SensorTruth

    truth = SensorTruth.constant(6.0e5, 9.0e5, 9.0e5 * 1600.0)
    paths = []
    for t in paper_protocol(truth, PhysicsConstants(), seed=0, noise_rel=0.002):
        paths.append(str(tmp_path / f"{t.name}.csv"))
        calfiles.write_trial_csv(paths[-1], t.time_s, t.force_n, t.conductance_s)
    physics = tmp_path / "physics.json"
    physics.write_text(json.dumps(PhysicsConstants().to_dict()))
    cal = tmp_path / "cal.json"
    code, out, _ = _run(["fit", *paths, "--sensor", "S06B", "--area", AREA, "--physics", str(physics), "--out",
                         str(cal)], capsys)
    assert code == 0 and "degenerate" not in out
    entry = json.loads(cal.read_text())["sensors"]["S06B"]
    assert entry["degenerate"] is False
    lo, hi = entry["tau_s_ci95"]
    assert lo <= 1600.0 <= (hi if hi is not None else np.inf)
    t = np.arange(0.0, 600.0, 1 / 6)
    force = np.where(t >= 300.0, 4.5, np.where(t >= 10.0, 2.0, 0.0))
    c = np.asarray(conductance_from_force(t, force, truth.params_at(3.0), truth.area_m2, PhysicsConstants()))
    calfiles.write_series_csv(tmp_path / "c.csv", t, ("S06B",), c[:, None])
    assert _run(["estimate", str(tmp_path / "c.csv"), "--cal", str(cal), "--out", str(tmp_path / "f.csv")],
                capsys)[0] == 0
    back = calfiles.read_series_csv(tmp_path / "f.csv", "force_N").values[:, 0]
    loaded = force > 0
    assert float(np.sqrt(np.mean((back[loaded] - force[loaded]) ** 2))) < 0.005


def test_the_readout_travels_with_the_calibration_and_estimate_says_which_it_used(lab, tmp_path, capsys):
    """`estimate` without --config once used the default 900 Ω ceiling and rejected most samples of a sensor
    calibrated on a 500 Ω readout. Now `fit --config` stores the readout with the sensor, and `estimate` uses it
    unless --config overrides, saying which."""
    folder, paths = lab
    config = tmp_path / "lab.toml"
    config.write_text("[board]\nr_c_ohm = 500.0\n")
    cal = tmp_path / "cal500.json"
    code, _, err = _run(["fit", *paths, "--sensor", "S06B", "--area", AREA, "--physics", str(folder / "cal.json"),
                         "--config", str(config), "--out", str(cal)], capsys)
    assert code == 0, err
    assert json.loads(cal.read_text())["sensors"]["S06B"]["readout"]["r_c_ohm"] == 500.0
    t = np.arange(0, 60, 1 / 6)
    reading = 1.3e-3 + 2e-5 * np.sin(t)  # above the 900 Ω ceiling (1.11 mS), below the 500 Ω one (2 mS)
    calfiles.write_series_csv(tmp_path / "c.csv", t, ("S06B",), reading[:, None])
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", str(cal), "--out", str(tmp_path / "f.csv")],
                        capsys)
    assert code == 0 and "R_C 500 Ω" in err and "as stored with the calibration" in err, err
    forces = calfiles.read_series_csv(tmp_path / "f.csv", "force_N", allow_gaps=True).values[:, 0]
    assert np.isfinite(forces).all()  # not one sample taken for the 900 Ω ceiling
    override = tmp_path / "lab900.toml"
    override.write_text("[board]\nr_c_ohm = 900.0\n")
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", str(cal), "--config", str(override),
                         "--out", str(tmp_path / "f2.csv")], capsys)
    assert code == 0 and "R_C 900 Ω" in err and f"from {override}" in err
    at_900 = calfiles.read_series_csv(tmp_path / "f2.csv", "force_N", allow_gaps=True).values[:, 0]
    assert not np.isfinite(at_900).any()  # the trap the stored readout avoids: every sample at the wrong ceiling
    document = json.loads(cal.read_text())
    del document["sensors"]["S06B"]["readout"]  # a calibration written before the readout was stored
    old = tmp_path / "old.json"
    old.write_text(json.dumps(document))
    code, _, err = _run(["estimate", str(tmp_path / "c.csv"), "--cal", str(old), "--out", str(tmp_path / "f3.csv")],
                        capsys)
    assert "the default" in err and "does not say which readout" in err


@pytest.mark.skipif(not hasattr(os, "nice"), reason="no POSIX nice on this platform")
def test_a_background_fit_runs_below_the_apps_priority():
    """The Calibration tab fits in a worker process started with calibration_fit.yield_cpu: it must not compete with
    the robot's loop for the cores (a fit with its drift search takes seconds of CPU)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from app.core import calibration_fit

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                             initializer=calibration_fit.yield_cpu) as pool:
        child = pool.submit(os.nice, 0).result(timeout=60)
    assert child >= min(os.nice(0) + calibration_fit.FIT_NICENESS, 19)


def test_fit_names_a_second_creep_arm_and_stores_it(tmp_path, capsys):
    """Trials from a sensor with a second, slower creep arm (a model the app does not fit): `sensnake fit` says so on
    its summary, warns with the cost, removes no drift and stores `creep_second_arm` in the calibration."""
    from models.sls import SLSParams
    from tests.models.test_creep_arms import _two_arm_trials

    paths = []
    for trial in _two_arm_trials(SLSParams(6.0e5, 1.2e6, 1.2e6 * 80.0), 0.3, 450.0, 370.0, seed=57):
        path = tmp_path / f"{trial.name}.csv"
        calfiles.write_trial_csv(path, trial.time_s, trial.force_n, trial.conductance_s)
        paths.append(str(path))
    out = tmp_path / "cal.json"
    assert main(["fit", *paths, "--sensor", "S06B", "--area", "1.4e-3", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "second creep arm: tau2" in printed and "baseline drift +0 µS/s" in printed
    assert "a second creep arm, not a baseline drift" in printed
    entry = json.loads(out.read_text())["sensors"]["S06B"]
    assert entry["creep_second_arm"]["resolved"] is True and entry["drift_S_per_s"] == 0.0
    assert 450 / 2 < entry["creep_second_arm"]["tau2_s"] < 450 * 2
