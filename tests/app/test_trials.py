"""Physics-lab trial series: one recording per trial, trials.csv, resumable, the repeatability report; and the one
short physics run that shows an experiment's recording carries its run documents and is catalogued."""

from __future__ import annotations

import csv
import json

import h5py
import pytest

from app.cli.main import main
from app.core.catalog import Catalog
from app.core.run_documents import read_documents
from tests.app.synthetic_trials import write_trial

SHIFTS_S = (0.0, 0.21, 0.43)


@pytest.fixture
def fake_lab(monkeypatch):
    """``experiment trials`` with the physics replaced by synthetic recordings (seed → clock shift); records each
    call, and can leave one trial cut short (its run_stop missing), as a crash would."""
    calls = []
    cut_short = set()

    def run_experiment(path, config, *, seed, md, **options):
        calls.append((path.name, seed, dict(md)))
        write_trial(path, shift_s=SHIFTS_S[seed % 3], seed=seed, trial=md["trial"], series_uid=md["series_uid"],
                    duration_s=8.0, speed_rad_s=options["speed_rad_s"])
        if path.name in cut_short:
            with h5py.File(path, "a") as f:
                del f.attrs["run_stop"]

    monkeypatch.setattr("app.cli.trials.run_experiment", run_experiment)
    return calls, cut_short


def _rows(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_a_series_writes_one_recording_per_trial_trials_csv_and_the_report_and_resumes(tmp_path, fake_lab, capsys):
    calls, cut_short = fake_lab
    out = tmp_path / "series"
    argv = ["experiment", "trials", "--scene", "paper_obstacle", "--trials", "3", "--seed", "10", "--out", str(out)]
    cut_short.add("trial-001.h5")
    assert main(argv) == 0
    assert [(name, seed) for name, seed, _ in calls] == [("trial-000.h5", 10), ("trial-001.h5", 11),
                                                          ("trial-002.h5", 12)]
    series_uid = calls[0][2]["series_uid"]
    assert {md["series_uid"] for _, _, md in calls} == {series_uid}
    assert [md["trial"] for _, _, md in calls] == [0, 1, 2]
    rows = _rows(out / "trials.csv")
    assert list(rows[0]) == ["file", "trial", "seed", "outcome", "duration_s", "advance_m"]
    assert [(r["file"], r["seed"]) for r in rows] == [("trial-000.h5", "10"), ("trial-001.h5", "11"),
                                                      ("trial-002.h5", "12")]
    assert float(rows[0]["advance_m"]) > 0.05 and float(rows[0]["duration_s"]) == pytest.approx(8.0, abs=0.05)
    offsets = [float(r["offset_s"]) for r in _rows(out / "alignment.csv")]
    assert [round(o - offsets[0], 2) for o in offsets] == [0.0, 0.22, -0.21]  # seeds 10, 11, 12: shifts .21, .43, 0
    assert (out / "repeatability.png").is_file() and (out / "repeatability.csv").is_file()
    # resumed: the finished trials are kept, the one cut short (no run_stop) runs again
    calls.clear()
    cut_short.clear()
    assert main(argv) == 0
    assert [name for name, _, _ in calls] == ["trial-001.h5"]
    assert "2 kept from an earlier run" in capsys.readouterr().out
    # more trials of the same series: only the new one runs
    calls.clear()
    assert main([*argv[:5], "4", *argv[6:]]) == 0
    assert [name for name, _, _ in calls] == ["trial-003.h5"]
    # other options into the same folder: refused by name, nothing run, nothing clobbered
    calls.clear()
    before = (out / "trials.csv").read_text()
    assert main([*argv, "--speed", "0.05"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "speed_rad_s 0.034 ≠ 0.05" in err and str(out) in err
    assert calls == [] and (out / "trials.csv").read_text() == before


def test_a_short_physics_run_carries_its_run_documents_and_is_catalogued(tmp_path):
    out = tmp_path / "run.h5"
    code = main(["experiment", "run", "--scene", "paper_obstacle", "--seconds", "0.5", "--settle", "0.3",
                 "--rest-cap", "0", "--seed", "4", "--note", "first try", "--out", str(out)])
    assert code == 0
    start, stop = read_documents(out)
    assert start["plan_name"] == "experiment run" and start["note"] == "first try" and start["seed"] == 4
    condition = start["condition"]
    assert condition["scene"] == "paper_obstacle" and condition["mode"] == "follow"  # the scene before the seed's jitter
    assert condition["calibration_hash"] and condition["speed_rad_s"] == 0.034
    assert stop["run_start"] == start["uid"] and stop["exit_status"] == "success"
    assert stop["outcome"] == "undecided"  # no time to come to rest (--rest-cap 0)
    with Catalog() as catalog:
        entry = catalog.get(out)
    assert entry is not None and entry["uid"] == start["uid"] and entry["scene"] == "paper_obstacle"
    assert json.loads(json.dumps(entry))["seed"] == 4
