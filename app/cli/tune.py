"""``sensnake experiment tune TUNE.toml --trials N --out DIR [--jobs J] [--engine local|dask] [--scheduler ADDR]``:
the law's gains searched with Optuna on the training conditions (:mod:`app.core.tune`), the study kept in
``DIR/study.journal`` (the same command with a larger ``--trials`` adds to it), then the best gains and the base gains
scored against feedforward on the training and the test conditions: ``trials.csv``, ``best_gains.toml``,
``report.csv``, ``tune.svg`` and ``.png`` in DIR. Exit 130 when interrupted (the same command resumes).
"""

from __future__ import annotations

import argparse
import math

from app.cli.run_progress import finished, interrupted, progress_line
from app.core.errors import RunsInterrupted
from app.core.tune import read_tune, run_tune


def run(args: argparse.Namespace) -> int:
    if not args.plan:
        raise ValueError("usage: sensnake experiment tune TUNE.toml --trials N --out DIR")
    if args.trials is None:
        raise ValueError("sensnake experiment tune needs --trials N (how many trials the study holds when done)")
    plan = read_tune(args.plan)
    try:
        report = run_tune(plan, args.out, args.trials, jobs=args.jobs, engine=args.engine, scheduler=args.scheduler,
                          progress=progress_line, say=print)
    except RunsInterrupted as stop:
        return interrupted(stop, args.out)
    out = finished(args.out, "tune")
    print(f"{'gains':<6} {'trial':>5} {'split':<6} {'decided':>9} {'objective m':>11} {'advance Δ m':>11} "
          f"{'traversal ff → ctl':>19} {'overloads ff → ctl':>19}")
    for r in report:
        print(f"{r['gains']:<6} {str(r['trial']):>5} {r['split']:<6} {r['decided']:>4}/{r['conditions']:<4} "
              f"{_f(r['objective']):>11} {_f(r['median_advance_delta_m']):>11} "
              f"{_f(r['feedforward_traversal']):>8} → {_f(r['candidate_traversal']):<8} "
              f"{_f(r['feedforward_overloads']):>8} → {_f(r['candidate_overloads']):<8}")
    print(f"wrote trials.csv, best_gains.toml, report.csv, tune.svg and .png in {out} (the study: "
          f"optuna-dashboard {out / 'study.journal'})")
    return 0


def _f(value: float) -> str:
    return "—" if not math.isfinite(value) else f"{value:+.3f}"
