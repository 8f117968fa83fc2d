"""``sensnake estimate IN.csv --cal CAL.json [--model linear|sls] --out OUT.csv [--flags FLAGS.csv] [--config FILE]
[--allow-degenerate] [--engine compiled|reference] [--interp hold|linear] [--no-contact] [--float32]``: conductance →
force.

Every sensor column of IN.csv is converted with its calibration (SPEC §3.2); a single ``conductance_S`` column maps
to the calibration's only sensor. Physics constants come from the calibration file. Every sample first passes the
sample-validation rule of :mod:`models.validation` with the readout ceiling ``1/R_C`` (``board.r_c_ohm`` of
``--config``, else the default circuit): an empty/NaN cell, a negative, above-ceiling or flat-lined reading is a gap
(force NaN in OUT.csv; time passes for the creep state), never a refusal of the file. OUT.csv keeps exactly the SPEC
§3.2 columns; ``--flags`` writes a sidecar CSV with the same header holding each sample's integer
:class:`models.sls.ForceStatus` code (0 = ok; legend in docs/NUMERICS.md); stderr gets one line per affected sensor.
A calibration that ``sensnake fit`` marked ``"degenerate": true`` is refused unless ``--allow-degenerate``.
Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from app.core import calfiles
from devices.config import BoardConfig, load_config
from models import sls
from models.estimators import LinearEstimator, SLSEstimator
from models.linear import LinearModel
from models.sls import SLSParams
from models.validation import ValidationRule, summarise


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


def _force_ranges(document: dict, names: list[str]) -> list[tuple[float, float] | None]:
    ranges: list[tuple[float, float] | None] = []
    for name in names:
        span = document["sensors"][name].get("force_range_N")
        ok = isinstance(span, list) and len(span) == 2 and all(isinstance(v, (int, float)) for v in span)
        ranges.append((float(span[0]), float(span[1])) if ok else None)
    return ranges


def _range_arrays(ranges: list[tuple[float, float] | None]) -> tuple[np.ndarray, np.ndarray]:
    """Per-sensor (low, high) for the EXTRAPOLATED flag; an unknown range never flags (−∞, ∞)."""
    low = np.array([r[0] if r else -np.inf for r in ranges])
    high = np.array([r[1] if r else np.inf for r in ranges])
    return low, high


def refuse_degenerate(document: dict, names: list[str], model: str, cal_path: str, allow: bool) -> None:
    """A sensor whose fit was marked degenerate is refused (CalFileError naming why) unless ``allow``."""
    for name in names:
        entry = document["sensors"][name]
        if model == "sls" and entry.get("degenerate") is True:
            why = "; ".join(entry.get("degenerate_reasons", [])) or "marked degenerate by 'sensnake fit'"
            if not allow:
                raise calfiles.CalFileError(
                    f"{cal_path}: sensor '{name}' has a degenerate SLS fit ({why}): its forces would not be "
                    "trustworthy; recalibrate, or pass --allow-degenerate to use it anyway")
            print(f"sensnake estimate: warning: {name}: using a degenerate SLS fit ({why})", file=sys.stderr)


def run_estimator(estimator: LinearEstimator | SLSEstimator, conductance_s: np.ndarray, time_s: np.ndarray,
                  engine: str = "compiled", float32: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Force (N) and status codes of ``estimator`` over a whole record: ``engine`` "compiled" (numba kernels) or
    "reference" (the numpy paths, same numbers); ``float32`` rounds the readings and the forces to float32."""
    values = conductance_s.astype(np.float32).astype(np.float64) if float32 else conductance_s
    with sls.engine("numpy" if engine == "reference" else "auto"):
        force = estimator.update(time_s, values)
    if float32:
        force = force.astype(np.float32).astype(np.float64)
    return force, estimator.last_status


def run(args: argparse.Namespace) -> int:
    document = calfiles.read_calibration(args.cal)
    table = calfiles.read_series_csv(args.input, calfiles.CONDUCTANCE_COLUMN, allow_gaps=True)
    names = resolve_columns(table, document, calfiles.CONDUCTANCE_COLUMN, args.cal)
    entries = [calfiles.sensor_entry(document, name, args.model, args.cal) for name in names]
    refuse_degenerate(document, names, args.model, args.cal, getattr(args, "allow_degenerate", False))
    stored = calfiles.sensor_readout(document, names, args.cal)
    if getattr(args, "config", None):
        board = load_config(args.config).board
        source = f"from {args.config}"
    elif stored is not None:
        board = replace(BoardConfig(), r_c_ohm=float(stored["r_c_ohm"]), v_ref_v=float(stored["v_ref_v"]),
                        v_supply_v=float(stored["v_supply_v"]))
        source = "as stored with the calibration"
    else:
        board = BoardConfig()
        source = "the default: the calibration does not say which readout it was fitted on (give --config)"
    print(f"sensnake estimate: note: readout R_C {board.r_c_ohm:g} Ω, V_ref {board.v_ref_v:g} V ({source})",
          file=sys.stderr)
    rule = ValidationRule.for_readout(board.r_c_ohm)
    ranges = _force_ranges(document, names)
    bounds = _range_arrays(ranges)
    estimator: LinearEstimator | SLSEstimator
    if args.model == "linear":
        # The live Forces tab's estimator, so both treat a reading below the baseline alike (0 N, flagged).
        models = [LinearModel.from_dict(entry["linear"]) for entry in entries]
        for name, model in zip(names, models, strict=True):
            if not model.m_S_per_N > 0.0:
                raise calfiles.CalFileError(f"{args.cal}: sensor '{name}' linear.m_S_per_N = {model.m_S_per_N!r} "
                                            "must be > 0 to invert: re-run 'sensnake fit'")
        estimator = LinearEstimator(models, force_range_n=bounds, validation=rule)
    else:
        phys = calfiles.physics_from_calibration(document, args.cal)
        params = SLSParams.stack([SLSParams.from_dict(entry["sls"]) for entry in entries])
        areas = np.array([float(entry["area_m2"]) for entry in entries])
        estimator = SLSEstimator(params, areas, phys, interp=getattr(args, "interp", "hold"),
                                 with_contact=not getattr(args, "no_contact", False), n_sensors=len(names),
                                 force_range_n=bounds, validation=rule)
    force, status = run_estimator(estimator, table.values, table.time_s, getattr(args, "engine", "compiled"),
                                  getattr(args, "float32", False))
    out_names = output_names(table, calfiles.CONDUCTANCE_COLUMN, calfiles.FORCE_COLUMN)
    for name, (count, line_no, text) in table.bad_cells.items():
        print(f"sensnake estimate: warning: {name}: {count} non-numeric cell(s) read as gaps (first at line {line_no}: "
              f"'{text}')", file=sys.stderr)
    for line in summarise(names, force, status, ranges):
        print(f"sensnake estimate: warning: {line}", file=sys.stderr)
    calfiles.write_series_csv(args.out, table.time_s, out_names, force, 9 if getattr(args, "float32", False) else 17)
    if getattr(args, "flags", None):
        calfiles.write_series_csv(args.flags, table.time_s, out_names, status.astype(np.float64))
    elif status.any():
        print("sensnake estimate: note: per-sample flags: add --flags FLAGS.csv", file=sys.stderr)
    print(f"wrote {force.shape[0]} samples × {force.shape[1]} sensor(s) of force ({args.model}) to {args.out}")
    return 0
