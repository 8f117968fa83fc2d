"""``sensnake experiment evaluate EVAL.toml --out DIR [--jobs N] [--engine local|dask] [--scheduler ADDR]``: a
pre-registered evaluation (:mod:`app.core.evaluate`): conditions drawn from the file's scene families with its seed,
every controller paired with feedforward on the same draws, the report in DIR (``evaluation.csv`` with the file's
SHA-256, ``conditions.csv``, ``runs.csv``, ``evaluation.svg`` and ``.png``). Exit 3 when a run was invalid (counted
apart, never data), 1 when one failed, 130 when interrupted (the same command resumes).
"""

from __future__ import annotations

import argparse
import math
import sys

from app.cli.run_progress import EXIT_INVALID, finished, interrupted, progress_line
from app.core.errors import RunsInterrupted
from app.core.evaluate import read_evaluation, run_evaluation
from app.core.sweep import is_invalid, read_summary


def run(args: argparse.Namespace) -> int:
    if not args.plan:
        raise ValueError("usage: sensnake experiment evaluate EVAL.toml --out DIR")
    plan = read_evaluation(args.plan)
    try:
        table = run_evaluation(plan, args.out, jobs=args.jobs, engine=args.engine, scheduler=args.scheduler,
                               progress=progress_line, say=print)
    except RunsInterrupted as stop:
        return interrupted(stop, args.out)
    out = finished(args.out, "evaluation")
    print(f"{'family':<16} {'controller':<14} {'metric':<16} {'pairs':>5} {'feedforward':>11} {'controller':>10} "
          f"{'difference':>10}  {100 * plan.confidence:g} % interval  invalid undecided")
    for e in table:
        print(f"{e['family']:<16} {e['controller']:<14} {e['metric']:<16} {e['pairs']:5d} {_f(e['feedforward']):>11} "
              f"{_f(e['candidate']):>10} {_f(e['difference']):>10}  [{_f(e['ci_low'])}, {_f(e['ci_high'])}]"
              f"  {e['invalid_pairs']:7d} {e['undecided_pairs']:9d}")
    rows = read_summary(out / "runs.csv")
    invalid = [r for r in rows if is_invalid(r)]
    failed = [r for r in rows if str(r.get("file", "")).startswith("failed")]
    for r in invalid:
        print(f"run {r['run']} ({r['family']} condition {r['condition']}, {r['controller']}, seed {r['seed']}) "
              f"{r['invalid_reason']}: left out (its pair with it)", file=sys.stderr)
    print(f"wrote evaluation.csv (sha256 {plan.sha256[:16]}…), conditions.csv, runs.csv, evaluation.svg and .png in "
          f"{out}" + (f"; {len(failed)} run(s) failed: failures.csv" if failed else ""))
    return 1 if failed else EXIT_INVALID if invalid else 0


def _f(value: float) -> str:
    return "—" if not math.isfinite(value) else f"{value:+.3f}" if abs(value) < 100 else f"{value:.3g}"
