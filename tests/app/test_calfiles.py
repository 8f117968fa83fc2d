"""Calibration file formats (SPEC §3.1–3.3): good files read back exactly, bad files fail with file:line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.core import calfiles
from app.core.errors import CalFileError
from models.physics import PhysicsConstants


def _write(path, text):
    path.write_text(text, encoding="utf-8")
    return path


def test_trial_csv_reads_columns_and_ignores_extras(tmp_path):
    path = _write(tmp_path / "t.csv", "note,time_s,conductance_S,force_N\nx,0,0,0\ny,0.5,1e-4,1.5\nz,1.0,2e-4,3\n")
    trial = calfiles.read_trial_csv(path)
    np.testing.assert_array_equal(trial.time_s, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(trial.force_n, [0.0, 1.5, 3.0])
    np.testing.assert_array_equal(trial.conductance_s, [0.0, 1e-4, 2e-4])


def test_trial_csv_round_trip_keeps_full_precision(tmp_path):
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.1, 0.2, 50))
    f, c = rng.uniform(0, 5, 50), rng.uniform(0, 1e-3, 50)
    calfiles.write_trial_csv(tmp_path / "t.csv", t, f, c)
    trial = calfiles.read_trial_csv(tmp_path / "t.csv")
    np.testing.assert_array_equal(trial.time_s, t)
    np.testing.assert_array_equal(trial.conductance_s, c)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("time_s,conductance_S\n0,1\n", "t.csv:1: missing column 'force_N'"),
        ("time_s,force_kN,conductance_S\n0,1,1\n", "t.csv:1: column 'force_kN' is in kN, expected 'force_N'"),
        ("time_ms,force_N,conductance_S\n0,1,1\n", "t.csv:1: column 'time_ms' is in ms"),
        ("time_s,force_N,conductance_S\n0,1,1e-4\n1,1,nan\n2,1,1e-4\n", "t.csv:3: column 'conductance_S' is nan"),
        ("time_s,force_N,conductance_S\n0,1,1e-4\n1,abc,1e-4\n", "t.csv:3: column 'force_N' holds 'abc'"),
        ("time_s,force_N,conductance_S\n0,1,1e-4\n2,1,1e-4\n1,1,1e-4\n", "t.csv:4: time_s goes backwards"),
        ("time_s,force_N,conductance_S\n0,1,1e-4\n0,1,1e-4\n", "t.csv:3: time_s repeats"),
        ("time_s,force_N,conductance_S\n", "no data rows"),
        ("", "empty file"),
        ("time_s,force_N,conductance_S\n0,1,1e-4\n1,1\n", "t.csv:3: row has 2 cells"),
    ],
)
def test_bad_trial_csv_names_file_and_line(tmp_path, text, expected):
    path = _write(tmp_path / "t.csv", text)
    with pytest.raises(CalFileError) as info:
        calfiles.read_trial_csv(path)
    assert expected in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_trial_file(tmp_path):
    with pytest.raises(CalFileError, match="no such file"):
        calfiles.read_trial_csv(tmp_path / "nope.csv")


def test_series_csv_round_trip(tmp_path):
    t = np.linspace(0, 10, 21)
    values = np.random.default_rng(1).uniform(0, 5, (21, 3))
    calfiles.write_series_csv(tmp_path / "f.csv", t, ("S01L", "S01R", "S06B"), values)
    table = calfiles.read_series_csv(tmp_path / "f.csv", "force_N")
    assert table.columns == ("S01L", "S01R", "S06B")
    np.testing.assert_array_equal(table.values, values)
    np.testing.assert_array_equal(table.time_s, t)
    assert (tmp_path / "f.csv").read_text().splitlines()[0] == "time_s,S01L,S01R,S06B"


def test_series_csv_without_data_column(tmp_path):
    with pytest.raises(CalFileError, match="no data column"):
        calfiles.read_series_csv(_write(tmp_path / "x.csv", "time_s\n0\n"), "conductance_S")


def _physics():
    return PhysicsConstants()


def test_calibration_update_keeps_other_sensors(tmp_path):
    path = tmp_path / "cal.json"
    calfiles.update_calibration(path, "S01L", {"area_m2": 1e-3, "sls": {"E0_Pa": 1.0}}, _physics())
    calfiles.update_calibration(path, "S06B", {"area_m2": 2e-3, "extra": np.float64(2.5)}, _physics())
    document = calfiles.read_calibration(path)
    assert document["format"] == "sensnake-calibration" and document["version"] == 1
    assert set(document["sensors"]) == {"S01L", "S06B"}
    assert document["sensors"]["S06B"]["extra"] == 2.5
    assert PhysicsConstants.from_dict(document) == _physics()


def test_calibration_keeps_unknown_top_level_keys(tmp_path):
    path = _write(tmp_path / "cal.json", json.dumps({"format": "sensnake-calibration", "version": 1,
                                                      "lab_note": "rig B", "sensors": {}}))
    calfiles.update_calibration(path, "S01L", {"area_m2": 1e-3}, _physics())
    assert calfiles.read_calibration(path)["lab_note"] == "rig B"


@pytest.mark.parametrize(
    ("document", "expected"),
    [
        ({"format": "other", "version": 1}, "unknown format 'other'"),
        ({"format": "sensnake-calibration", "version": 2}, "unsupported calibration version 2"),
        ([1, 2], "expected a JSON object"),
    ],
)
def test_calibration_rejects_unknown_format_and_version(tmp_path, document, expected):
    path = _write(tmp_path / "cal.json", json.dumps(document))
    with pytest.raises(CalFileError, match=expected):
        calfiles.read_calibration(path)
    before = path.read_text()
    with pytest.raises(CalFileError):
        calfiles.update_calibration(path, "S01L", {}, _physics())
    assert path.read_text() == before, "a file of another format must never be overwritten"


def test_calibration_invalid_json_names_line(tmp_path):
    path = _write(tmp_path / "cal.json", '{"format": "sensnake-calibration",\n "version": 1,,\n}')
    with pytest.raises(CalFileError, match=r"cal.json:2: not valid JSON"):
        calfiles.read_calibration(path)


def test_update_refuses_changing_physics_under_other_sensors(tmp_path):
    path = tmp_path / "cal.json"
    calfiles.update_calibration(path, "S01L", {"area_m2": 1e-3}, _physics())
    other = PhysicsConstants(K_contact_ohm_sqrtN=1000.0)
    with pytest.raises(CalFileError, match="physics constants differ"):
        calfiles.update_calibration(path, "S06B", {"area_m2": 1e-3}, other)
    # Re-fitting the only sensor with new physics is allowed.
    calfiles.update_calibration(path, "S01L", {"area_m2": 1e-3}, other)
    assert calfiles.read_calibration(path)["physics"]["K_contact_ohm_sqrtN"] == 1000.0


def test_read_physics_top_level_or_nested(tmp_path):
    constants = PhysicsConstants(K_contact_ohm_sqrtN=900.0)
    top = _write(tmp_path / "p.json", json.dumps(constants.to_dict()))
    nested = _write(tmp_path / "c.json", json.dumps({"format": "sensnake-calibration", "version": 1,
                                                     "physics": constants.to_dict()}))
    assert calfiles.read_physics(top) == constants
    assert calfiles.read_physics(nested) == constants
    broken = _write(tmp_path / "b.json", json.dumps({"R0_ohm": 1.0}))
    with pytest.raises(CalFileError, match="b.json: physics is missing key"):
        calfiles.read_physics(broken)


@pytest.mark.parametrize(
    ("header", "expected"),
    [
        ({"format": "sensnake-calibration", "version": 2}, "unsupported calibration version 2"),
        ({"format": "sensnake-shape", "version": 1}, "unknown format 'sensnake-shape'"),
        ({"version": 1}, "unknown format None"),
    ],
)
def test_read_physics_refuses_a_file_of_unknown_format_or_version(tmp_path, header, expected):
    # SPEC §3.3: --physics takes a calibration file too, and readers reject a format/version they do not know.
    path = _write(tmp_path / "p.json", json.dumps({**header, "physics": PhysicsConstants().to_dict()}))
    with pytest.raises(CalFileError, match=f"p.json: {expected}"):
        calfiles.read_physics(path)


def test_sensor_entry_checks_model_section(tmp_path):
    document = {"sensors": {"S01L": {"area_m2": 1e-3, "linear": {"m_S_per_N": 1e-4, "d_S": None}}}}
    with pytest.raises(CalFileError, match="no calibration for sensor 'S02L'"):
        calfiles.sensor_entry(document, "S02L", "linear", "cal.json")
    with pytest.raises(CalFileError, match=r"linear.d_S is None"):
        calfiles.sensor_entry(document, "S01L", "linear", "cal.json")
    with pytest.raises(CalFileError, match="has no 'sls' model"):
        calfiles.sensor_entry(document, "S01L", "sls", "cal.json")


def test_the_fast_csv_path_reads_and_writes_what_the_numpy_path_does(tmp_path):
    """Arrow's reader/writer (the fast path) against numpy's loadtxt on the same files: same numbers, empty cells as
    NaN, a text cell handed to the numpy path (which counts it), full float64 / float32 round trips."""
    rng = np.random.default_rng(5)
    t = np.arange(200) / 100.0
    values = rng.uniform(1e-5, 1e-3, (200, 3))
    path = tmp_path / "in.csv"
    calfiles.write_series_csv(path, t, ["S01L", "S01R", "S01B"], values)
    header = calfiles._read_header(path)
    fast = calfiles._read_numbers_fast(path, header, [0, 1, 2, 3])
    slow = calfiles._read_columns_numpy(path, header, [0, 1, 2, 3], 1, {})
    assert fast is not None and np.array_equal(fast, slow)
    assert np.array_equal(fast[:, 1:], values) and np.array_equal(fast[:, 0], t)  # float64 round trip
    calfiles.write_series_csv(path, t, ["S01L", "S01R", "S01B"], values, digits=9)
    read32 = calfiles.read_series_csv(path, "conductance_S").values.astype(np.float32)
    assert np.array_equal(read32, values.astype(np.float32))  # reads back to the same float32
    lines = path.read_text().splitlines()
    assert lines[0] == "time_s,S01L,S01R,S01B"  # the header as the SPEC writes it, unquoted
    lines[5] = lines[5].split(",", 1)[0] + ",,nan,inf"
    lines[9] = lines[9].split(",", 1)[0] + ",ERR,1e-4,2e-4"
    path.write_text("\n".join(lines) + "\n")
    assert calfiles._read_numbers_fast(path, header, [0, 1, 2, 3]) is None  # text: the numpy path decides
    table = calfiles.read_series_csv(path, "conductance_S", allow_gaps=True)
    assert np.isnan(table.values[4, 0]) and np.isnan(table.values[4, 1]) and np.isinf(table.values[4, 2])
    assert np.isnan(table.values[8, 0]) and table.bad_cells["S01L"][0] == 1
    del lines[9]
    path.write_text("\n".join(lines) + "\n")
    fast = calfiles._read_numbers_fast(path, header, [0, 1, 2, 3])
    slow = calfiles._read_columns_numpy(path, header, [0, 1, 2, 3], 1, {})
    assert fast is not None and np.array_equal(fast, slow, equal_nan=True)
