"""``sensnake experiment run --scene SCENE.toml [--shape SHAPE.json] [--mode follow|keyframes|serpenoid|sidewinding]
[--speed RAD_S] [--seconds S] [--settle S] [--seed K] [--config FILE] --out REC.h5`` (any scene, any motion) and
``sensnake experiment obstacle --out REC.h5 [--height-ratio R] …`` (the paper's Sec. III-C experiment): the physics lab
(MuJoCo) headless and faster than real time (:mod:`app.core.experiment`). Prints a progress line about once a second
and a summary at the end; the outcome (traversed or not) is judged once the body is at rest after the motion
(``--rest-cap S``: how long to wait for it, default 30 s). A run whose physics stopped being physics exits
``EXIT_INVALID`` (3) with one line on standard error naming what and when; its recording is kept, marked invalid.
Runs on the main thread.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

from app.cli.run_progress import interrupted
from app.core.errors import InvalidRunError, RunsInterrupted
from app.core.experiment import (
    REST_CAP_S,
    REST_HOLD_S,
    REST_SPEED_M_S,
    ExperimentResult,
    read_gains,
    run_experiment,
    run_obstacle_experiment,
)
from app.core.physics_check import check_recording
from app.core.shapes import read_shape
from app.core.sweep import compare, is_invalid, read_sweep, run_sweep, summary_table
from devices.config import LabConfig, load_config

EXIT_INVALID = 3  # SPEC §7: a physics run that is invalid (experiment run, obstacle; a sweep with an invalid run)


def _progress(line: str) -> None:
    # One line rewritten in place on a terminal; one line per report when piped to a file.
    end = "\r" if sys.stdout.isatty() else "\n"
    print(line, end=end, flush=True)


def _sweep(args: argparse.Namespace) -> int:
    if not args.plan:
        raise ValueError("usage: sensnake experiment sweep SWEEP.toml --out DIR")
    if args.jobs is not None and args.jobs < 1:
        raise ValueError(f"--jobs must be 1 or more, got {args.jobs}")
    plan = read_sweep(args.plan)
    if getattr(args, "ideal_sensing", False):  # the sweep file's ideal_sensing, from the command line
        plan = replace(plan, ideal_sensing=True)
    try:
        rows = run_sweep(plan, args.out, jobs=args.jobs, engine=args.engine, scheduler=args.scheduler,
                         progress=_progress, say=print)
    except RunsInterrupted as stop:
        return interrupted(stop, args.out)
    if sys.stdout.isatty():
        print()
    failed = [r for r in rows if str(r["file"]).startswith("failed")]
    invalid = [r for r in rows if is_invalid(r)]
    # runs: the valid ones, the figures' data; invalid runs are counted apart (never data), and so are the runs
    # still moving when the wait for rest ended (undecided: the at-rest traversal rate is over the decided ones)
    print(f"{'scene':<18} {'controller':<16} {'tail N':>6} {'runs':>4} {'traversed':>9} {'at rest':>7} "
          f"{'undecided':>9} {'advance m':>9} {'overloads':>9} {'invalid':>7}")
    for entry in summary_table(rows):
        print(f"{entry['scene']:<18} {entry['controller']:<16} {entry['tail_load_N']:6g} {entry['runs']:4d} "
              f"{_percent(entry['success']):>9} {_percent(entry['at_rest_success']):>7} {entry['undecided']:9d} "
              f"{entry['median_advance_m']:9.3f} {entry['overloads']:9d} {entry['invalid']:7d}")
    candidates = sorted({(str(r["controller"]), int(r["gains_index"])) for r in rows
                         if r["controller"] != "feedforward" and r["traversed"] != ""})
    if "feedforward" in plan.controllers:
        for controller, index in candidates:
            c = compare(rows, index, controller)
            fails = c.ff_fail_cases
            print(f"{controller} g{index} against feedforward over {c.pairs} paired runs:")
            if fails:
                print(f"  where feedforward fails ({fails} scene × load case{'s' if fails != 1 else ''}): it traverses "
                      f"{100 * c.fb_success_in_those:.0f}% against {100 * c.ff_success_in_those:.0f}%; crawling, not "
                      f"falling off a crest, {100 * c.fb_crawled_in_those:.0f}% against "
                      f"{100 * c.ff_crawled_in_those:.0f}%; median crawl before a fall or roll "
                      f"{_number(c.fb_crawl_in_those, '.2f', ' m')} against {_number(c.ff_crawl_in_those, '.2f', ' m')}")
            else:
                print("  feedforward traversed in every scene × load case: nothing to compare where it fails")
            positive = "none (no pair advanced forward under both)"
            print(f"  median advance ratio {_number(c.median_advance_ratio, '.2f', '×', positive)} (the tail point's "
                  f"{_number(c.median_tail_advance_ratio, '.2f', '×', 'none')}; the centroid's where both traverse "
                  f"{_number(c.median_advance_ratio_both_traversed, '.2f', '×', 'none')}); overloads {c.fb_overloads} "
                  f"against {c.ff_overloads}; where both traverse, time to traverse "
                  f"{_number(100 * c.slower_where_ff_succeeds, '+.0f', '%', 'none (no pair where both traverse)')}"
                  + (f"; {c.invalid_runs} invalid run(s) and their pairs left out" if c.invalid_runs else ""))
    for row in failed:
        print(f"run {row['run']} ({row['scene']}, {row['controller']}, {row['tail_load_N']} N, seed {row['seed']}) "
              f"{row['file']}")
    for row in invalid:
        print(f"run {row['run']} ({row['scene']}, {row['controller']}, {row['tail_load_N']} N, seed {row['seed']}) "
              f"{row['invalid_reason']}: left out of every figure", file=sys.stderr)
    print(f"wrote {len(rows)} runs, summary.csv and summary.svg in {args.out}")
    return 1 if failed else EXIT_INVALID if invalid else 0


def _number(value: float, spec: str, unit: str, missing: str = "none") -> str:
    """``value`` formatted, or ``missing`` where no pair gave it (never a bare "nan")."""
    return f"{value:{spec}}{unit}" if math.isfinite(value) else missing


def _percent(fraction: float) -> str:
    return "—" if math.isnan(fraction) else f"{100 * fraction:.0f}%"


def run(args: argparse.Namespace) -> int:
    if args.name not in ("run", "obstacle", "sweep", "trials", "evaluate", "tune"):  # argparse refuses others
        raise ValueError(f"unknown experiment {args.name!r}; known: run, obstacle, sweep, trials, evaluate, tune")
    try:
        import mujoco  # noqa: F401 - a clear message instead of an ImportError deep inside the lab
    except ImportError as exc:
        raise RuntimeError("the physics lab needs the 'mujoco' package: pip install mujoco") from exc
    if getattr(args, "ideal_sensing", False) and args.name not in ("run", "obstacle", "sweep"):
        raise ValueError(f"--ideal-sensing is for 'experiment run', 'obstacle' and 'sweep', not {args.name!r} (its "
                         "runs sense as a robot does: a rig calibration's errors, the board's noise, the creep)")
    if args.name == "sweep":
        return _sweep(args)
    if args.name in ("evaluate", "tune"):  # app/cli/evaluate.py, app/cli/tune.py
        from app.cli import evaluate, tune

        return evaluate.run(args) if args.name == "evaluate" else tune.run(args)
    if args.name == "trials":  # a series of one condition and its repeatability report (app/cli/trials.py)
        from app.cli.trials import run as run_trials

        return run_trials(args)
    if args.plan:
        raise ValueError(f"a sweep file ({args.plan}) is for 'sensnake experiment sweep'")
    config = load_config(args.config) if args.config else LabConfig()
    if getattr(args, "ideal_sensing", False):  # the controller reads the sensors' true calibration
        config = replace(config, lab=replace(config.lab, sensing="ideal"))
    rest_cap_s = getattr(args, "rest_cap", None)
    rest_cap_s = REST_CAP_S if rest_cap_s is None else rest_cap_s
    try:
        if args.name == "obstacle":
            for option in ("scene", "shape", "gains"):
                if getattr(args, option):
                    raise ValueError(f"--{option} is for 'sensnake experiment run' (obstacle is the paper's scene)")
            result = run_obstacle_experiment(args.out, config, seconds=args.seconds, height_ratio=args.height_ratio,
                                             speed_rad_s=args.speed, settle_s=args.settle, seed=args.seed,
                                             rest_cap_s=rest_cap_s, progress=_progress)
        else:
            shape = read_shape(args.shape) if args.shape else None
            gains = read_gains(args.gains) if args.gains else None
            if gains is not None and args.controller == "feedforward":
                raise ValueError("--gains is for --controller feedback (or one of its variants)")
            result = run_experiment(args.out, config, scene=args.scene, shape=shape, mode=args.mode,
                                    seconds=args.seconds, speed_rad_s=args.speed, settle_s=args.settle,
                                    seed=args.seed, controller=args.controller, gains=gains,
                                    tail_load_n=args.tail_load, repeat=args.repeat, rest_cap_s=rest_cap_s,
                                    progress=_progress, md={"note": getattr(args, "note", "") or ""})
    except InvalidRunError as exc:
        if sys.stdout.isatty():
            print()
        print(f"sensnake experiment: {exc}", file=sys.stderr)
        return EXIT_INVALID
    if sys.stdout.isatty():
        print()
    if not result.valid:  # no figure of a run that stopped being physics: one line, and the file marked
        print(f"sensnake experiment: {result.invalid_reason}; {result.path} is kept, marked invalid "
              f"(/sim valid = 0)", file=sys.stderr)
        return EXIT_INVALID
    _print_summary(result)
    return 0


def _print_summary(result: ExperimentResult) -> None:
    print(f"scene {result.scene_name}: simulated {result.simulated_s:.1f} s in {result.wall_s:.1f} s "
          f"({result.real_time_factor:.1f}× real time; machine load changes this)")
    passed = (f"its tail passed the far edge at {result.traverse_s:.1f} s" if result.traversed
              else "its tail did not pass the far edge")
    print(f"{result.controller}, tail load {result.tail_load_n:g} N, while playing (until {result.motion_end_s:.1f} "
          f"s): body advanced {result.advance_m * 100:+.1f} cm (its tail {result.tail_advance_m * 100:+.1f} cm; it "
          f"ends {result.end_extent_m:.2f} m long along the path); {passed}; {len(result.overloads)} overload(s); "
          f"peak current {result.peak_current_ma:.0f} mA")
    print(_at_rest_line(result))
    print(f"median total bottom force {result.median_bottom_force_n:.1f} N (normal forces: more than the weight "
          f"where the body lies on a curve); their vertical part {result.median_vertical_support_n:.1f} N "
          f"(robot weight {result.weight_n:.1f} N)")
    if math.isfinite(result.median_support_n):
        print(f"true contact forces, normal and friction, upward part: on the bottom sheets "
              f"{result.median_bottom_support_n:.1f} N, on the whole robot {result.median_support_n:.1f} N "
              f"(the weight when nothing accelerates)")
        check = check_recording(result.path)
        print(f"true sheet forces frame to frame: {100 * check.true_jump_frames:.1f} % of 30 Hz frames with a sheet "
              f"changing by > 1 N; {100 * (check.true_jump_frames - check.true_jump_frames_slow):.1f} % while the body "
              f"fell, tipped or landed, {100 * check.true_reversal_frames_slow:.1f} % reversing while it crept "
              f"(chatter)")
    for line in result.overloads:
        print(line)
    print(f"wrote {result.path}")


def _at_rest_line(result: ExperimentResult) -> str:
    """The outcome judged at rest, with the margin by which the whole body is past (or short of) the far edge."""
    if result.outcome == "undecided":
        return (f"at rest: undecided — the body was still moving {result.rest_cap_s:g} s after the motion was over "
                f"(--rest-cap), its centroid at {result.final_speed_m_s * 1000:.2f} mm/s over the last "
                f"{REST_HOLD_S:g} s (at rest: under {REST_SPEED_M_S * 1000:g} mm/s); no traversal, advance or "
                f"slide-back judged")
    if math.isnan(result.rest_margin_m):
        judged = "no obstacle to traverse"
    elif result.outcome == "traversed":
        judged = (f"traversed: yes, the whole body past the far edge, its rearmost point by "
                  f"{result.rest_margin_m * 100:.1f} cm")
    else:
        judged = (f"traversed: no, the rearmost body point {-result.rest_margin_m * 100:.1f} cm short of the far "
                  f"edge")
    return (f"at rest from {result.at_rest_s:.1f} s: {judged}; body advanced {result.advance_at_rest_m * 100:+.1f} "
            f"cm, {result.slide_back_m * 100:.1f} cm behind the farthest it had been")
