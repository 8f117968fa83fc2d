"""``sensnake forward IN.csv --cal CAL.json --out OUT.csv``: force → conductance, the SLS model run forwards.

Same column layout as IN.csv (SPEC §3.2); a single ``force_N`` column maps to the calibration's only sensor and is
written back as ``conductance_S``. Physics constants come from the calibration file. A negative force is refused
(the model would map it to an open sensor, 0 S, without a word) unless ``--clip-negative`` reads it as 0 N, which
is then said on stderr. Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from app.cli.estimate import output_names, resolve_columns
from app.core import calfiles
from models.sls import SLSParams, conductance_from_force


def run(args: argparse.Namespace) -> int:
    document = calfiles.read_calibration(args.cal)
    table = calfiles.read_series_csv(args.input, calfiles.FORCE_COLUMN)
    names = resolve_columns(table, document, calfiles.FORCE_COLUMN, args.cal)
    forces = _non_negative_forces(table, names, args.input, bool(getattr(args, "clip_negative", False)))
    entries = [calfiles.sensor_entry(document, name, "sls", args.cal) for name in names]
    phys = calfiles.physics_from_calibration(document, args.cal)
    params = SLSParams.stack([SLSParams.from_dict(entry["sls"]) for entry in entries])
    areas = np.array([float(entry["area_m2"]) for entry in entries])
    conductance = conductance_from_force(table.time_s, forces, params, areas, phys)
    names_out = list(output_names(table, calfiles.FORCE_COLUMN, calfiles.CONDUCTANCE_COLUMN))
    if getattr(args, "units", "bare") == "suffixed":
        names_out, conductance = calfiles.with_unit_suffixes(names_out, conductance, calfiles.CONDUCTANCE_COLUMN)
    calfiles.write_series_csv(args.out, table.time_s, names_out, conductance)
    print(f"wrote {conductance.shape[0]} samples × {conductance.shape[1]} sensor(s) of conductance to {args.out}")
    return 0


def _non_negative_forces(table: calfiles.SeriesTable, names: list[str], source: str, clip: bool) -> np.ndarray:
    """The table's forces (N); negative ones refused with the first one named, or read as 0 N when ``clip``."""
    negative = table.values < 0
    if not negative.any():
        return table.values
    row, column = (int(i) for i in np.argwhere(negative)[0])
    count = int(negative.sum())
    first = (f"{names[column]} = {table.values[row, column]:g} N at time_s = {table.time_s[row]:g} "
             f"(sample {row + 1})")
    if not clip:
        raise ValueError(f"{source}: {count} negative force(s), the first {first}: a contact sensor is pressed, "
                         "never pulled. Fix the data, or pass --clip-negative to read them as 0 N")
    print(f"sensnake forward: warning: {count} negative force(s) read as 0 N (--clip-negative), the first {first}",
          file=sys.stderr)
    return np.maximum(table.values, 0.0)
