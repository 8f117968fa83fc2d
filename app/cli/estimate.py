"""``sensnake estimate IN.csv --cal CAL.json [--model linear|sls] --out OUT.csv``: conductance → force.

Every sensor column of IN.csv is converted with its calibration (SPEC §3.2); a single ``conductance_S`` column maps
to the calibration's only sensor. Physics constants come from the calibration file. Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from app.core import calfiles
from models.estimators import LinearEstimator
from models.linear import LinearModel
from models.sls import SLSParams, explain_force_status, force_from_conductance

# Estimated forces beyond the calibrated range by more than this fraction are reported as extrapolated.
EXTRAPOLATION_MARGIN = 0.1


def resolve_columns(table: calfiles.SeriesTable, document: dict, generic: str, cal_path: str) -> list[str]:
    """Sensor names for the table's data columns; a lone ``generic`` column maps to the only calibrated sensor."""
    sensors = sorted(document.get("sensors", {}))
    if table.columns == (generic,):
        if len(sensors) != 1:
            raise calfiles.CalFileError(
                f"{table.file}: a single '{generic}' column needs a calibration with exactly one sensor, but "
                f"{cal_path} has {len(sensors)} ({', '.join(sensors) or 'none'}): name the column after its sensor")
        return sensors
    for name in table.columns:
        if name not in document.get("sensors", {}):
            raise calfiles.CalFileError(
                f"{table.file}:1: column '{name}' has no calibration in {cal_path} "
                f"(calibrated: {', '.join(sensors) or 'none'}): run 'sensnake fit' for it or drop the column")
    return list(table.columns)


def output_names(table: calfiles.SeriesTable, generic_in: str, generic_out: str) -> tuple[str, ...]:
    return (generic_out,) if table.columns == (generic_in,) else table.columns


def warn_extrapolation(document: dict, names: list[str], force_n: np.ndarray) -> None:
    for i, name in enumerate(names):
        span = document["sensors"][name].get("force_range_N")
        if not (isinstance(span, list) and len(span) == 2):
            continue
        column = force_n[:, i]
        finite = column[np.isfinite(column)]
        if finite.size and finite.max() > span[1] * (1 + EXTRAPOLATION_MARGIN):
            print(f"sensnake: warning: {name}: forces up to {finite.max():.3g} N are outside the calibrated range "
                  f"{span[0]:g}–{span[1]:g} N (extrapolated)", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    document = calfiles.read_calibration(args.cal)
    table = calfiles.read_series_csv(args.input, calfiles.CONDUCTANCE_COLUMN)
    names = resolve_columns(table, document, calfiles.CONDUCTANCE_COLUMN, args.cal)
    entries = [calfiles.sensor_entry(document, name, args.model, args.cal) for name in names]
    if args.model == "linear":
        # The live Forces tab's estimator, so both treat a reading below the baseline alike (0 N, flagged).
        models = [LinearModel.from_dict(entry["linear"]) for entry in entries]
        for name, model in zip(names, models, strict=True):
            if not model.m_S_per_N > 0.0:
                raise calfiles.CalFileError(f"{args.cal}: sensor '{name}' linear.m_S_per_N = {model.m_S_per_N!r} "
                                            "must be > 0 to invert: re-run 'sensnake fit'")
        estimator = LinearEstimator(models)
        force = estimator.update(table.time_s, table.values)
        status = estimator.last_status
    else:
        phys = calfiles.physics_from_calibration(document, args.cal)
        params = SLSParams.stack([SLSParams.from_dict(entry["sls"]) for entry in entries])
        areas = np.array([float(entry["area_m2"]) for entry in entries])
        result = force_from_conductance(table.time_s, table.values, params, areas, phys, with_status=True)
        force, status = result.force_n, result.status
    for line in explain_force_status(status):
        print(f"sensnake estimate: warning: {line}", file=sys.stderr)
    warn_extrapolation(document, names, force)
    calfiles.write_series_csv(args.out, table.time_s, output_names(table, calfiles.CONDUCTANCE_COLUMN,
                                                                   calfiles.FORCE_COLUMN), force)
    print(f"wrote {force.shape[0]} samples × {force.shape[1]} sensor(s) of force ({args.model}) to {args.out}")
    return 0
