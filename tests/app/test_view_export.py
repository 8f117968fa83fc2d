"""The Forces tab's CSV export: units in every header, robot joints and currents beside the forces (newest robot
sample at or before each row), only the asked time range, missing values empty (never another unit's number)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from app.core.recording import Recording, RobotRecord
from app.core.view_export import export_view_csv


def make_recording(with_forces: bool = True, with_robot: bool = True) -> Recording:
    n = 10
    time_s = np.arange(n) * 0.1  # 0.0 … 0.9 s
    conductance = np.column_stack([np.full(n, 10e-6), np.full(n, 20e-6), np.full(n, 30e-6)])
    forces = None
    if with_forces:
        forces = np.column_stack([np.linspace(0.0, 0.9, n), np.full(n, np.nan), np.full(n, 2.5)])
        forces[4, 2] = np.nan  # one missing estimate of a calibrated sensor
    robot = None
    if with_robot:
        robot = RobotRecord(time_s=np.array([0.15, 0.55]), goal_rad=np.array([[0.1, -0.1], [0.2, -0.2]]),
                            present_rad=np.array([[0.11, -0.11], [0.21, -0.21]]),
                            current_ma=np.array([[5.0, 6.0], [7.0, 8.0]]))
    return Recording(path=Path("x.h5"), version=1, started="2026-01-01T00:00:00Z", config_text="",
                     channels=("S01L", "S01R", "S01B"), time_s=time_s, seq=np.arange(n, dtype=np.uint32),
                     counts=np.zeros((n, 3), dtype=np.uint16), conductance_s=conductance, board_time_s=None,
                     crc_errors=0, dropped_frames=0, resyncs=0, robot=robot, forces_n=forces,
                     calibration_json=None, events=())


def read(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open(newline="", encoding="utf-8") as handle:
        rows = list(csv.reader(handle))
    return rows[0], rows[1:]


def test_header_names_every_unit_and_puts_the_robot_beside_the_forces(tmp_path):
    out, n = export_view_csv(make_recording(), tmp_path / "view.csv", joint_ids=[3, 4])
    header, rows = read(out)
    assert n == 10 and len(rows) == 10
    assert header == ["time_s", "S01L_N", "S01R_uS", "S01B_N",
                      "J3_present_rad", "J3_goal_rad", "J3_current_mA",
                      "J4_present_rad", "J4_goal_rad", "J4_current_mA"]
    # S01R has no force anywhere: its conductance in µS, never a force.
    assert {row[2] for row in rows} == {"20"}
    # A calibrated sensor's missing estimate stays empty (not its conductance).
    assert rows[4][3] == "" and rows[3][3] == "2.5"
    # Robot: rows before its first sample (t < 0.15 s) are empty; then the newest sample at or before the row.
    assert rows[0][4:] == [""] * 6 and rows[1][4:] == [""] * 6
    assert rows[2][4:] == ["0.11", "0.1", "5", "-0.11", "-0.1", "6"]  # t = 0.2 s
    assert rows[5][4:7] == ["0.11", "0.1", "5"]  # t = 0.5 s: the 0.55 s sample is not yet there
    assert rows[6][4:7] == ["0.21", "0.2", "7"]  # t = 0.6 s


def test_only_the_visible_range(tmp_path):
    out, n = export_view_csv(make_recording(), tmp_path / "view.csv", t0_s=0.25, t1_s=0.65)
    _header, rows = read(out)
    assert n == 4 and [row[0] for row in rows] == ["0.3", "0.4", "0.5", "0.6"]
    with pytest.raises(ValueError, match="no samples between"):
        export_view_csv(make_recording(), tmp_path / "empty.csv", t0_s=5.0, t1_s=6.0)


def test_no_forces_no_robot_is_conductance_in_microsiemens(tmp_path):
    out, _n = export_view_csv(make_recording(with_forces=False, with_robot=False), tmp_path / "view.csv")
    header, rows = read(out)
    assert header == ["time_s", "S01L_uS", "S01R_uS", "S01B_uS"]
    assert rows[0] == ["0", "10", "20", "30"]


def test_an_unwritable_path_names_it(tmp_path):
    target = tmp_path / "missing" / "view.csv"
    with pytest.raises(OSError, match="cannot write .*view.csv"):
        export_view_csv(make_recording(), target)


def test_default_joint_names_and_float_values_round_trip(tmp_path):
    out, _n = export_view_csv(make_recording(), tmp_path / "view.csv")
    header, rows = read(out)
    assert header[4] == "J1_present_rad" and header[7] == "J2_present_rad"
    assert np.allclose([float(row[1]) for row in rows], np.linspace(0.0, 0.9, 10))
