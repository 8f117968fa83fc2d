"""Re-analysis: ``sensnake estimate REC.h5 --cal CAL.json --out NEW.h5`` re-estimates a recording's forces
with a new calibration (everything else kept, the input untouched), and a channel without a calibration is passed
through in µS with a note — in a recording and in a CSV — instead of refusing the file."""

from __future__ import annotations

import hashlib
import json
import time

import h5py
import numpy as np
import pytest

from app.cli.main import main
from app.core import calfiles
from app.core.recording import RecordingWriter, open_recording
from devices.board import SampleBlock
from devices.config import default_sensor_names
from models.physics import PhysicsConstants
from models.sls import SLSParams, conductance_from_force

CHANNELS = default_sensor_names()
SENSOR = "S06B"
PARAMS = {"E0_Pa": 2.1e6, "E1_Pa": 3.7e6, "mu1_Pa_s": 3.3e8}  # not the typical sensor: a new draw
AREA_M2 = 1.4e-3
RATE_HZ = 30.0


def _calibration(path) -> dict:
    document = {"format": calfiles.CAL_FORMAT, "version": calfiles.CAL_VERSION,
                "physics": PhysicsConstants().to_dict(),
                "sensors": {SENSOR: {"area_m2": AREA_M2, "sls": dict(PARAMS), "force_range_N": [1.0, 6.0],
                                     "linear": {"m_S_per_N": 1e-4, "d_S": 1e-6}}}}
    path.write_text(json.dumps(document))
    return document


def _force(t: np.ndarray) -> np.ndarray:
    """A press of 4 N from 10 s to 70 s with 1 s ramps, then released."""
    return 4.0 * np.clip(np.minimum(t - 10.0, 70.0 - t), 0.0, 1.0)


def _recording(path, seconds: float = 90.0):
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    rng = np.random.default_rng(29)
    conductance = rng.uniform(2e-6, 5e-4, (t.size, len(CHANNELS)))
    params = SLSParams.from_dict(PARAMS)
    channel = CHANNELS.index(SENSOR)
    conductance[:, channel] = conductance_from_force(t, _force(t)[:, None], params, np.array([AREA_M2]),
                                                     PhysicsConstants())[:, 0]
    counts = np.ones(conductance.shape, dtype=np.uint16)
    t0 = time.monotonic()
    seq = np.arange(t.size, dtype=np.uint32)
    block = SampleBlock(counts=counts, conductance_s=conductance, board_time_s=t, host_time_s=t0 + t, seq=seq,
                        saturated=np.zeros(conductance.shape, dtype=bool), gap_before=None)
    with RecordingWriter(path, "[board]\nrate_hz = 30.0\n", CHANNELS, calibration_json='{"old": true}',
                         t0_monotonic_s=t0) as writer:
        writer.append_daq(block)
        writer.append_forces(np.full(conductance.shape, 9.9))  # what an old calibration said
        writer.log_event("a note the re-analysis must keep", t0 + 5.0)
    return t, conductance


def test_a_recording_is_re_estimated_into_a_copy_and_the_original_is_untouched(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    document = _calibration(cal)
    rec, new = tmp_path / "rec.h5", tmp_path / "new.h5"
    t, conductance = _recording(rec)
    before = hashlib.sha256(rec.read_bytes()).hexdigest()
    assert main(["estimate", str(rec), "--cal", str(cal), "--out", str(new)]) == 0
    captured = capsys.readouterr()
    assert hashlib.sha256(rec.read_bytes()).hexdigest() == before
    assert "re-estimated for 1 of 36 channel(s)" in captured.out
    assert "35 channel(s) without a calibration kept as conductance only" in captured.err

    recording = open_recording(new)
    channel = CHANNELS.index(SENSOR)
    forces = recording.forces_n
    assert forces is not None and forces.shape == conductance.shape
    held = (t > 15.0) & (t < 69.0)
    np.testing.assert_allclose(forces[held, channel], 4.0, atol=0.02)  # the press it was made from
    assert np.all(np.isnan(np.delete(forces, channel, axis=1)))  # uncalibrated: no force claimed
    np.testing.assert_array_equal(recording.conductance_s, conductance)  # the data itself is kept as it was
    assert any(e.text == "a note the re-analysis must keep" for e in recording.events)
    assert json.loads(recording.calibration_json or "") == document
    with h5py.File(new, "r") as f:
        assert "sls model, 1 of 36 channel(s)" in f["forces"].attrs["reestimated"]
        assert f["forces/status"].shape == conductance.shape and f["forces/status"].dtype == np.int8

    # The same numbers as the CSV path on the same data.
    csv_in, csv_out = tmp_path / "in.csv", tmp_path / "out.csv"
    calfiles.write_series_csv(csv_in, recording.time_s, (SENSOR,), conductance[:, [channel]])
    assert main(["estimate", str(csv_in), "--cal", str(cal), "--out", str(csv_out)]) == 0
    from_csv = np.loadtxt(csv_out, delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_allclose(forces[:, channel], from_csv, rtol=1e-12, atol=1e-12, equal_nan=True)


def test_a_csv_with_uncalibrated_columns_passes_them_through_in_microsiemens(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    _calibration(cal)
    t = np.arange(0.0, 40.0, 1.0 / RATE_HZ)
    sensor = conductance_from_force(t, _force(t)[:, None], SLSParams.from_dict(PARAMS), np.array([AREA_M2]),
                                    PhysicsConstants())[:, 0]
    other = np.linspace(1e-5, 2e-4, t.size)
    source, out, flags = tmp_path / "export.csv", tmp_path / "forces.csv", tmp_path / "flags.csv"
    calfiles.write_series_csv(source, t, ("S01L", SENSOR, "S12R"), np.column_stack([other, sensor, other * 2]))
    assert main(["estimate", str(source), "--cal", str(cal), "--out", str(out), "--flags", str(flags)]) == 0
    err = capsys.readouterr().err
    assert "2 channel(s) without a calibration passed through as conductance in µS" in err and "S01L, S12R" in err
    header = out.read_text().splitlines()[0].split(",")
    assert header == ["time_s", "S01L_uS", SENSOR, "S12R_uS"]
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 1], other * 1e6, rtol=1e-12)
    np.testing.assert_allclose(table[:, 3], other * 2e6, rtol=1e-12)
    assert table[(t > 15) & (t < 39), 2] == pytest.approx(4.0, abs=0.02)
    assert flags.read_text().splitlines()[0].split(",") == header


def test_a_recording_re_estimate_refuses_a_csv_out_and_flags_in_one_line(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    _calibration(cal)
    rec = tmp_path / "rec.h5"
    _recording(rec, seconds=5.0)
    assert main(["estimate", str(rec), "--cal", str(cal), "--out", str(tmp_path / "x.csv")]) == 1
    assert "'sensnake export' it first" in capsys.readouterr().err
    assert main(["estimate", str(rec), "--cal", str(cal), "--out", str(tmp_path / "x.h5"), "--flags",
                 str(tmp_path / "f.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/forces/status" in err[0]
    assert not (tmp_path / "x.h5").exists()
    assert main(["estimate", str(rec), "--cal", str(cal), "--out", str(rec)]) == 1  # never onto its input
    assert "Traceback" not in capsys.readouterr().err


def test_a_column_with_its_unit_reads_like_the_bare_spec_column(tmp_path, capsys):
    """The GUI's exports name their unit (S06B_uS); `estimate` reads them as the bare SPEC column in siemens, and a
    sensor given both ways is refused in one line."""
    cal = tmp_path / "cal.json"
    _calibration(cal)
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    sensor = conductance_from_force(t, _force(t)[:, None], SLSParams.from_dict(PARAMS), np.array([AREA_M2]),
                                    PhysicsConstants())[:, 0]
    bare, suffixed = tmp_path / "bare.csv", tmp_path / "suffixed.csv"
    calfiles.write_series_csv(bare, t, (SENSOR,), sensor[:, None])
    calfiles.write_series_csv(suffixed, t, (f"{SENSOR}_uS",), sensor[:, None] * 1e6)
    outs = []
    for source in (bare, suffixed):
        out = tmp_path / f"{source.stem}_forces.csv"
        assert main(["estimate", str(source), "--cal", str(cal), "--out", str(out)]) == 0
        outs.append(np.loadtxt(out, delimiter=",", skiprows=1))
        assert out.read_text().splitlines()[0] == f"time_s,{SENSOR}"
    np.testing.assert_allclose(outs[1], outs[0], rtol=1e-9, atol=1e-12)
    both = tmp_path / "both.csv"
    calfiles.write_series_csv(both, t, (SENSOR, f"{SENSOR}_uS"), np.column_stack([sensor, sensor * 1e6]))
    capsys.readouterr()
    assert main(["estimate", str(both), "--cal", str(cal), "--out", str(tmp_path / "o.csv")]) == 1
    assert "sensor 'S06B' has two columns" in capsys.readouterr().err


def test_units_suffixed_names_every_column_and_the_files_read_back(tmp_path):
    """``--units suffixed`` on export, forward and estimate: each column carries its unit (the GUI's style), the
    numbers are the bare files' in that unit, and each command reads the other's output back."""
    cal = tmp_path / "cal.json"
    _calibration(cal)
    rec = tmp_path / "rec.h5"
    _recording(rec, seconds=20.0)
    bare, suffixed = tmp_path / "bare.csv", tmp_path / "suffixed.csv"
    assert main(["export", str(rec), "--csv", str(bare)]) == 0
    assert main(["export", str(rec), "--csv", str(suffixed), "--units", "suffixed"]) == 0
    assert bare.read_text().splitlines()[0].split(",") == ["time_s", *CHANNELS]
    assert suffixed.read_text().splitlines()[0].split(",") == ["time_s", *(f"{c}_N" for c in CHANNELS)]
    np.testing.assert_array_equal(np.loadtxt(bare, delimiter=",", skiprows=1),
                                  np.loadtxt(suffixed, delimiter=",", skiprows=1))

    t = np.arange(0.0, 60.0, 1.0 / RATE_HZ)
    forces_in, conductance_out, forces_out = tmp_path / "f.csv", tmp_path / "c.csv", tmp_path / "f2.csv"
    calfiles.write_series_csv(forces_in, t, (SENSOR,), _force(t)[:, None])
    assert main(["forward", str(forces_in), "--cal", str(cal), "--out", str(conductance_out),
                 "--units", "suffixed"]) == 0
    assert conductance_out.read_text().splitlines()[0] == f"time_s,{SENSOR}_uS"
    expected = conductance_from_force(t, _force(t)[:, None], SLSParams.from_dict(PARAMS), np.array([AREA_M2]),
                                      PhysicsConstants())[:, 0]
    micro = np.loadtxt(conductance_out, delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_allclose(micro, expected * 1e6, rtol=1e-12)
    assert main(["estimate", str(conductance_out), "--cal", str(cal), "--out", str(forces_out),
                 "--units", "suffixed"]) == 0
    assert forces_out.read_text().splitlines()[0] == f"time_s,{SENSOR}_N"
    back = np.loadtxt(forces_out, delimiter=",", skiprows=1)[:, 1]
    hold = (t > 12) & (t < 55)
    assert back[hold] == pytest.approx(_force(t)[hold], abs=1e-6)
