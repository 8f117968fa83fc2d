"""``sensnake forward IN.csv --cal CAL.json --out OUT.csv``: force → conductance, the SLS model run forwards.

Same column layout as IN.csv (SPEC §3.2); a single ``force_N`` column maps to the calibration's only sensor and is
written back as ``conductance_S``. Physics constants come from the calibration file. Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse

import numpy as np

from app.cli.estimate import output_names, resolve_columns
from app.core import calfiles
from models.sls import SLSParams, conductance_from_force


def run(args: argparse.Namespace) -> int:
    document = calfiles.read_calibration(args.cal)
    table = calfiles.read_series_csv(args.input, calfiles.FORCE_COLUMN)
    names = resolve_columns(table, document, calfiles.FORCE_COLUMN, args.cal)
    entries = [calfiles.sensor_entry(document, name, "sls", args.cal) for name in names]
    phys = calfiles.physics_from_calibration(document, args.cal)
    params = SLSParams.stack([SLSParams.from_dict(entry["sls"]) for entry in entries])
    areas = np.array([float(entry["area_m2"]) for entry in entries])
    conductance = conductance_from_force(table.time_s, table.values, params, areas, phys)
    calfiles.write_series_csv(args.out, table.time_s, output_names(table, calfiles.FORCE_COLUMN,
                                                                   calfiles.CONDUCTANCE_COLUMN), conductance)
    print(f"wrote {conductance.shape[0]} samples × {conductance.shape[1]} sensor(s) of conductance to {args.out}")
    return 0
