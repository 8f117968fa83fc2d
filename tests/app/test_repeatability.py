"""The repeatability report (the paper's Fig. 7) on synthetic trials whose clocks are shifted by known amounts."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from app.cli.main import main
from app.core.repeatability import AlignOptions, RepeatabilityError, analyse, icc_a1
from tests.app.synthetic_trials import ONSET_S, write_trial

SHIFTS_S = (0.0, 0.337, 1.219, -0.45)


def _trials(tmp_path, **kwargs):
    return [write_trial(tmp_path / f"t{i}.h5", shift_s=shift, seed=i, **kwargs) for i, shift in enumerate(SHIFTS_S)]


def _read(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_shifted_noisy_copies_align_within_40_ms_and_agree_where_forces_are_large(tmp_path, capsys):
    paths = _trials(tmp_path)
    out = tmp_path / "report"
    assert main(["report", "repeatability", *map(str, paths), "--out", str(out)]) == 0
    assert "4 trials aligned on motion onset" in capsys.readouterr().out
    offsets = {row["recording"]: float(row["offset_s"]) for row in _read(out / "alignment.csv")}
    for path, shift in zip(paths, SHIFTS_S):
        assert abs(offsets[str(path.resolve())] - (ONSET_S + shift)) < 0.040, path
    rows = _read(out / "repeatability.csv")
    mean = np.array([float(r["S05B_mean_N"]) for r in rows])
    sd = np.array([float(r["S05B_sd_N"]) for r in rows])
    large = mean > 2.0
    assert large.sum() > 20
    assert np.max(sd[large]) < 0.25 and np.median(sd[large]) < 0.12  # noise 0.05 N: s.d. near zero
    time_s = np.array([float(r["time_s"]) for r in rows])
    assert abs(time_s[np.argmax(mean)] - 3.0) < 0.05  # S05B's bump: 1 + 0.5·4 s after the onset
    assert {"seg1_x_mean_m", "seg12_x_sd_m"} <= set(rows[0])
    summary = {r["quantity"]: r for r in _read(out / "repeatability_summary.csv")}
    assert abs(float(summary["S05B"]["peak_mean"]) - 5.0) < 0.2
    assert float(summary["S05B"]["icc"]) > 0.95
    assert summary["S05B"]["rms_difference"] and float(summary["S05B"]["rms_difference"]) < 0.15
    assert (out / "repeatability.png").stat().st_size > 10_000
    assert "4 trials aligned on motion onset" in (out / "repeatability.svg").read_text()


def test_contact_and_position_alignments_find_the_same_shifts(tmp_path):
    paths = _trials(tmp_path)
    for options in (AlignOptions("contact"), AlignOptions("mocap")):
        result, _ = analyse(paths, options)
        relative = np.array(result.offsets_s) - result.offsets_s[0]
        np.testing.assert_allclose(relative, np.array(SHIFTS_S) - SHIFTS_S[0], atol=0.040)


def test_one_trial_different_conditions_and_invalid_runs_are_refused_by_name(tmp_path, capsys):
    one = write_trial(tmp_path / "a.h5")
    other = write_trial(tmp_path / "b.h5", speed_rad_s=0.05, seed=1)
    out = tmp_path / "report"
    assert main(["report", "repeatability", str(one), "--out", str(out)]) != 0
    assert "at least 2" in capsys.readouterr().err
    assert main(["report", "repeatability", str(one), str(other), "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "b.h5" in err and "speed_rad_s 0.034 ≠ 0.05" in err and "--mixed" in err
    assert not out.exists()  # nothing written on a refusal
    result, _ = analyse([one, other], mixed=True)
    assert result.differences and "speed_rad_s" in result.differences[0]
    bad = write_trial(tmp_path / "bad.h5", seed=2)
    import h5py

    with h5py.File(bad, "a") as f:
        f["sim"].attrs["valid"] = 0
        f["sim"].attrs["invalid_reason"] = "invalid run: MuJoCo bad QACC at t=3 s"
    with pytest.raises(RepeatabilityError, match="bad.h5: an invalid run"):
        analyse([one, bad])
    (tmp_path / "junk.h5").write_text("not hdf5")
    assert main(["report", "repeatability", str(one), str(tmp_path / "junk.h5"), "--out", str(out)]) != 0
    assert "junk.h5" in capsys.readouterr().err


def test_icc_is_one_for_identical_trials_and_low_for_noise():
    t = np.linspace(0, 6, 200)
    signal = np.sin(t)
    assert icc_a1(np.vstack([signal, signal, signal])) == pytest.approx(1.0)
    noise = np.random.default_rng(0).normal(0, 1, (3, 200))
    assert icc_a1(noise) < 0.2
