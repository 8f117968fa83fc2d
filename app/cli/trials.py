"""``sensnake experiment trials --scene S --trials N [--seed K] [experiment run's motion and controller options]
[--align …] --out DIR``: one condition run N times in the physics lab (:mod:`app.core.trials`), then the
repeatability report of its valid trials into DIR (:mod:`app.cli.report`). ``sensnake trials`` (the robot's series)
comes here too and is handed to :mod:`app.cli.robot_trials`. Resumable: the same command again keeps
the finished trials. Exit 0 with the report; 3 when a trial was invalid (the report averages the valid ones, if two or
more); 1 with one line when the series cannot run. Main thread.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

from app.cli.report import align_options, make_report, print_summary
from app.core.experiment import REST_CAP_S, read_gains, run_experiment
from app.core.repeatability import MIN_TRIALS
from app.core.shapes import read_shape
from app.core.trials import SeriesOptions, run_series, valid_recordings
from devices.config import LabConfig, load_config

EXIT_INVALID = 3


def _progress(line: str) -> None:
    print(line, flush=True)


def series_options(args: argparse.Namespace) -> SeriesOptions:
    if not args.scene:
        raise ValueError("experiment trials needs --scene (a scene file or a built-in scene: paper_obstacle, …)")
    if args.trials is None:
        raise ValueError("experiment trials needs --trials N")
    if args.plan:
        raise ValueError(f"a sweep file ({args.plan}) is for 'sensnake experiment sweep'")
    gains = read_gains(args.gains) if args.gains else None
    if gains is not None and args.controller == "feedforward":
        raise ValueError("--gains is for --controller feedback (or one of its variants)")
    rest_cap = getattr(args, "rest_cap", None)
    return SeriesOptions(scene=args.scene, trials=args.trials, seed=args.seed, mode=args.mode,
                         speed_rad_s=args.speed, seconds=args.seconds, settle_s=args.settle,
                         controller=args.controller, gains=asdict(gains) if gains is not None else None,
                         tail_load_n=args.tail_load, repeat=args.repeat,
                         rest_cap_s=REST_CAP_S if rest_cap is None else rest_cap,
                         shape=str(Path(args.shape).resolve()) if args.shape else None,
                         config=str(Path(args.config).resolve()) if args.config else None, note=args.note or "")


def run(args: argparse.Namespace) -> int:
    if getattr(args, "command", None) == "trials":  # sensnake trials --robot …: a series on the robot
        from app.cli import robot_trials

        return robot_trials.run(args)
    options = series_options(args)
    config = load_config(options.config) if options.config else LabConfig()
    shape = read_shape(options.shape) if options.shape else None
    gains = read_gains(args.gains) if args.gains else None
    report_options = align_options(args)  # refused before any trial runs if they are bad

    def run_one(path: Path, seed: int, md: Mapping[str, Any]) -> object:
        return run_experiment(path, config, scene=options.scene, shape=shape, mode=options.mode,
                              seconds=options.seconds, speed_rad_s=options.speed_rad_s, settle_s=options.settle_s,
                              seed=seed, controller=options.controller, gains=gains,
                              tail_load_n=options.tail_load_n, repeat=options.repeat, rest_cap_s=options.rest_cap_s,
                              md=md)

    rows, kept = run_series(options, args.out, run_one, progress=_progress)
    out = Path(args.out)
    print(f"{'trial':>5} {'seed':>5} {'outcome':<14} {'duration s':>10} {'advance m':>10}  file")
    for row in rows:
        print(f"{row['trial']:5d} {row['seed']:5d} {row['outcome']:<14} {row['duration_s']:10.1f} "
              f"{row['advance_m']:10.3f}  {row['file']}")
    print(f"{len(rows)} trials in {out / 'trials.csv'}" + (f" ({kept} kept from an earlier run)" if kept else ""))
    valid = valid_recordings(out, rows)
    invalid = len(rows) - len(valid)
    if len(valid) < MIN_TRIALS:
        print(f"sensnake experiment trials: {len(valid)} valid trial(s) of {len(rows)}: the repeatability report "
              f"needs at least {MIN_TRIALS}", file=sys.stderr)
        return EXIT_INVALID if invalid else 1
    result = make_report([str(p) for p in valid], out, report_options)
    print_summary(result, out)
    if invalid:
        print(f"sensnake experiment trials: {invalid} invalid trial(s) left out of the report (trials.csv)",
              file=sys.stderr)
        return EXIT_INVALID
    return 0
