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
A column without a calibration is passed through as ``<name>_uS`` (conductance in µS) with a note; a file with no
calibrated column is refused. ``sensnake estimate REC.h5 --cal CAL.json --out NEW.h5`` re-estimates a recording: NEW.h5
is a copy of it (daq, robot, control, events kept; REC.h5 untouched) whose ``/forces`` holds ``force_N`` (NaN for the
channels without a calibration), ``status`` (the flag codes) and the calibration as the attribute ``calibration``.
A calibration that ``sensnake fit`` marked ``"degenerate": true`` is refused unless ``--allow-degenerate``.
Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import json
import os
import stat
import sys
from dataclasses import replace
from pathlib import Path

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
    """Force (N) and status codes of ``estimator`` over a whole record: ``engine`` "compiled" (the C kernel, else
    numba's) or "reference" (the numpy paths, same numbers); ``float32`` rounds the readings and the forces to float32."""
    values = conductance_s.astype(np.float32).astype(np.float64) if float32 else conductance_s
    with sls.engine("numpy" if engine == "reference" else "auto"):
        force = estimator.update(time_s, values)
    if float32:
        force = force.astype(np.float32).astype(np.float64)
    return force, estimator.last_status


def _readout(args: argparse.Namespace, document: dict, names: list[str]) -> BoardConfig:
    """The readout circuit: ``--config``'s, else the one stored with the calibration, else the default (said)."""
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
    return board


def _estimate(args: argparse.Namespace, document: dict, names: list[str], time_s: np.ndarray,
              conductance_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Force (N, S) and status codes of sensors ``names`` (each calibrated) over a whole record."""
    entries = [calfiles.sensor_entry(document, name, args.model, args.cal) for name in names]
    refuse_degenerate(document, names, args.model, args.cal, getattr(args, "allow_degenerate", False))
    board = _readout(args, document, names)
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
    force, status = run_estimator(estimator, conductance_s, time_s, getattr(args, "engine", "compiled"),
                                  getattr(args, "float32", False))
    for line in summarise(names, force, status, ranges):
        print(f"sensnake estimate: warning: {line}", file=sys.stderr)
    return force, status


def split_calibrated(columns: tuple[str, ...] | list[str], document: dict, source: str,
                     cal_path: str) -> tuple[list[int], list[int]]:
    """Indices of the columns with a calibration and of those without; none calibrated is refused."""
    sensors = document.get("sensors", {})
    calibrated = [k for k, name in enumerate(columns) if name in sensors]
    if not calibrated:
        raise calfiles.CalFileError(
            f"{source}: none of its columns ({', '.join(columns[:4])}{' …' if len(columns) > 4 else ''}) has a "
            f"calibration in {cal_path} (calibrated: {', '.join(sorted(sensors)) or 'none'}): run 'sensnake fit'")
    return calibrated, [k for k in range(len(columns)) if k not in calibrated]


def _passed_through_note(names: list[str], how: str) -> None:
    if names:
        shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
        print(f"sensnake estimate: note: {len(names)} channel(s) without a calibration {how}: {shown}",
              file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    document = calfiles.read_calibration(args.cal)
    if is_recording(args.input):
        return _run_recording(args, document)
    table = calfiles.read_series_csv(args.input, calfiles.CONDUCTANCE_COLUMN, allow_gaps=True)
    if table.columns == (calfiles.CONDUCTANCE_COLUMN,):
        names = resolve_columns(table, document, calfiles.CONDUCTANCE_COLUMN, args.cal)
        calibrated, passed = [0], list[int]()
    else:
        names = list(table.columns)
        calibrated, passed = split_calibrated(table.columns, document, f"{table.file}:1", args.cal)
    for name, (count, line_no, text) in table.bad_cells.items():
        print(f"sensnake estimate: warning: {name}: {count} non-numeric cell(s) read as gaps (first at line {line_no}: "
              f"'{text}')", file=sys.stderr)
    estimated = [names[k] for k in calibrated]
    force, status = _estimate(args, document, estimated, table.time_s, table.values[:, calibrated])
    out_names = list(output_names(table, calfiles.CONDUCTANCE_COLUMN, calfiles.FORCE_COLUMN))
    values = np.empty(table.values.shape)
    codes = np.zeros(table.values.shape)
    values[:, calibrated], codes[:, calibrated] = force, status
    values[:, passed] = table.values[:, passed] * 1e6  # µS: the column name says so
    for k in passed:
        out_names[k] = f"{names[k]}_uS"
    _passed_through_note([names[k] for k in passed], "passed through as conductance in µS (columns <name>_uS)")
    flag_names = list(out_names)
    if getattr(args, "units", "bare") == "suffixed":
        out_names, values = calfiles.with_unit_suffixes(out_names, values, calfiles.FORCE_COLUMN)
    calfiles.write_series_csv(args.out, table.time_s, out_names, values, 9 if getattr(args, "float32", False) else 17)
    if getattr(args, "flags", None):
        calfiles.write_series_csv(args.flags, table.time_s, flag_names, codes)  # codes: no unit
    elif status.any():
        print("sensnake estimate: note: per-sample flags: add --flags FLAGS.csv", file=sys.stderr)
    print(f"wrote {force.shape[0]} samples × {force.shape[1]} sensor(s) of force ({args.model}) to {args.out}")
    return 0


def is_recording(path: str) -> bool:
    """An HDF5 file (by its signature, whatever its name). Only a regular file is opened: a FIFO's open would wait
    for a writer (the CSV reader then names what it is)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        with open(path, "rb") as handle:
            return handle.read(8) == b"\x89HDF\r\n\x1a\n"
    except OSError:
        return False


def _run_recording(args: argparse.Namespace, document: dict) -> int:
    """``sensnake estimate REC.h5 --cal CAL.json --out NEW.h5``: a copy of the recording with /forces re-estimated."""
    from app.core.recording import open_recording, write_reestimated

    if getattr(args, "flags", None):
        raise ValueError("--flags is for a CSV input: with a recording the per-sample flags go into NEW.h5 as "
                         "/forces/status")
    if Path(args.out).suffix.lower() in (".csv", ".txt"):
        raise ValueError(f"--out {args.out}: a recording is re-estimated into a new recording (NEW.h5); for a "
                         "CSV, 'sensnake export' it first")
    recording = open_recording(args.input)
    bad_times = np.flatnonzero(~np.isfinite(recording.time_s))
    if bad_times.size:
        raise ValueError(f"{args.input}: /daq/time_s row {int(bad_times[0])} is {float(recording.time_s[bad_times[0]])} "
                         f"({bad_times.size} row(s) not finite): a damaged recording; expected a time in seconds")
    names = list(recording.channels)
    calibrated, passed = split_calibrated(names, document, str(args.input), args.cal)
    estimated = [names[k] for k in calibrated]
    force, status = _estimate(args, document, estimated, recording.time_s,
                                       recording.conductance_s[:, calibrated])
    force_all = np.full(recording.conductance_s.shape, np.nan)
    status_all = np.zeros(recording.conductance_s.shape, dtype=np.int8)
    force_all[:, calibrated], status_all[:, calibrated] = force, status
    _passed_through_note([names[k] for k in passed], "kept as conductance only (/daq/conductance_S; force NaN)")
    note = (f"{args.model} model, {len(calibrated)} of {len(names)} channel(s), from {Path(args.cal).name} by "
            f"'sensnake estimate'" + (f"; without a calibration: {', '.join(names[k] for k in passed)}" if passed
                                      else ""))
    write_reestimated(args.input, args.out, force_all, status_all, json.dumps(document), note)
    print(f"wrote {args.out}: {recording.n_samples} samples, /forces re-estimated for {len(calibrated)} of "
          f"{len(names)} channel(s) ({args.model})")
    return 0
