"""``sensnake experiment run --scene SCENE.toml [--shape SHAPE.json] [--mode follow|keyframes|serpenoid|sidewinding]
[--speed RAD_S] [--seconds S] [--settle S] [--seed K] [--config FILE] --out REC.h5`` (any scene, any motion) and
``sensnake experiment obstacle --out REC.h5 [--height-ratio R] …`` (the paper's Sec. III-C experiment): the physics lab
(MuJoCo) headless and faster than real time (:mod:`app.core.experiment`). Prints a progress line about once a second
and a summary at the end. Runs on the main thread.
"""

from __future__ import annotations

import argparse
import math
import sys

from app.core.experiment import read_gains, run_experiment, run_obstacle_experiment
from app.core.physics_check import check_recording
from app.core.shapes import read_shape
from app.core.sweep import compare, read_sweep, run_sweep, summary_table
from devices.config import LabConfig, load_config


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
    rows = run_sweep(plan, args.out, jobs=args.jobs, progress=_progress)
    if sys.stdout.isatty():
        print()
    failed = [r for r in rows if str(r["file"]).startswith("failed")]
    print(f"{'scene':<18} {'controller':<16} {'tail N':>6} {'runs':>4} {'traversed':>9} {'advance m':>9} "
          f"{'overloads':>9}")
    for entry in summary_table(rows):
        print(f"{entry['scene']:<18} {entry['controller']:<16} {entry['tail_load_N']:6g} {entry['runs']:4d} "
              f"{100 * entry['success']:8.0f}% {entry['median_advance_m']:9.3f} {entry['overloads']:9d}")
    indices = sorted({int(r["gains_index"]) for r in rows if r["controller"] == "feedback" and r["traversed"] != ""})
    if "feedforward" in plan.controllers:
        for index in indices:
            c = compare(rows, index)
            print(f"feedback g{index} against feedforward over {c.pairs} paired runs: where feedforward fails "
                  f"({c.ff_fail_cases} scene × load cases) it traverses {100 * c.fb_success_in_those:.0f}% against "
                  f"{100 * c.ff_success_in_those:.0f}% (crawling, not falling off a crest: "
                  f"{100 * c.fb_crawled_in_those:.0f}% against {100 * c.ff_crawled_in_those:.0f}%; median crawl before "
                  f"a fall or roll {c.fb_crawl_in_those:.2f} against {c.ff_crawl_in_those:.2f} m); median advance ratio "
                  f"{c.median_advance_ratio:.2f} (the tail point's {c.median_tail_advance_ratio:.2f}; the centroid's "
                  f"where both traverse {c.median_advance_ratio_both_traversed:.2f}); overloads "
                  f"{c.fb_overloads} against {c.ff_overloads}; where both traverse, {100 * c.slower_where_ff_succeeds:+.0f}% "
                  f"time to traverse")
    for row in failed:
        print(f"run {row['run']} ({row['scene']}, {row['controller']}, {row['tail_load_N']} N, seed {row['seed']}) "
              f"{row['file']}")
    print(f"wrote {len(rows)} runs, summary.csv and summary.svg in {args.out}")
    return 1 if failed else 0


def run(args: argparse.Namespace) -> int:
    if args.name not in ("run", "obstacle", "sweep"):  # argparse's choices refuse others; kept for a direct call
        raise ValueError(f"unknown experiment {args.name!r}; known: run, obstacle, sweep")
    try:
        import mujoco  # noqa: F401 - a clear message instead of an ImportError deep inside the lab
    except ImportError as exc:
        raise RuntimeError("the physics lab needs the 'mujoco' package: pip install mujoco") from exc
    if args.name == "sweep":
        return _sweep(args)
    if args.plan:
        raise ValueError(f"a sweep file ({args.plan}) is for 'sensnake experiment sweep'")
    config = load_config(args.config) if args.config else LabConfig()
    if args.name == "obstacle":
        for option in ("scene", "shape", "gains"):
            if getattr(args, option):
                raise ValueError(f"--{option} is for 'sensnake experiment run' (obstacle is the paper's scene)")
        result = run_obstacle_experiment(args.out, config, seconds=args.seconds, height_ratio=args.height_ratio,
                                         speed_rad_s=args.speed, settle_s=args.settle, seed=args.seed,
                                         progress=_progress)
    else:
        shape = read_shape(args.shape) if args.shape else None
        gains = read_gains(args.gains) if args.gains else None
        if gains is not None and args.controller != "feedback":
            raise ValueError("--gains is for --controller feedback")
        result = run_experiment(args.out, config, scene=args.scene, shape=shape, mode=args.mode,
                                seconds=args.seconds, speed_rad_s=args.speed, settle_s=args.settle, seed=args.seed,
                                controller=args.controller, gains=gains, tail_load_n=args.tail_load,
                                repeat=args.repeat, progress=_progress)
    if sys.stdout.isatty():
        print()
    print(f"scene {result.scene_name}: simulated {result.simulated_s:.1f} s in {result.wall_s:.1f} s "
          f"({result.real_time_factor:.1f}× real time; machine load changes this)")
    traversed = (f"yes, at {result.traverse_s:.1f} s" if result.traversed else "no")
    print(f"{result.controller}, tail load {result.tail_load_n:g} N: body advanced {result.advance_m * 100:+.1f} cm "
          f"(its tail {result.tail_advance_m * 100:+.1f} cm; it ends {result.end_extent_m:.2f} m long along the path); "
          f"traversed: {traversed}; {len(result.overloads)} overload(s); peak current {result.peak_current_ma:.0f} mA")
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
    return 0
