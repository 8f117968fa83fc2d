"""``sensnake experiment obstacle --out REC.h5 [--seconds S] [--height-ratio R] [--speed RAD_S] [--settle S]
[--config FILE] [--seed N]``: the paper's Sec. III-C obstacle experiment in the physics lab (MuJoCo), headless and
faster than real time (:mod:`app.core.obstacle_experiment`). Prints a progress line about once a second and a
summary at the end. Runs on the main thread.
"""

from __future__ import annotations

import argparse
import sys

from app.core.obstacle_experiment import run_obstacle_experiment
from devices.config import LabConfig, load_config


def _progress(line: str) -> None:
    # One line rewritten in place on a terminal; one line per report when piped to a file.
    end = "\r" if sys.stdout.isatty() else "\n"
    print(line, end=end, flush=True)


def run(args: argparse.Namespace) -> int:
    if args.name != "obstacle":  # argparse's choices already refuse others; kept for a direct call
        raise ValueError(f"unknown experiment {args.name!r}; known: obstacle")
    try:
        import mujoco  # noqa: F401 - a clear message instead of an ImportError deep inside the lab
    except ImportError as exc:
        raise RuntimeError("the physics lab needs the 'mujoco' package: pip install mujoco") from exc
    config = load_config(args.config) if args.config else LabConfig()
    result = run_obstacle_experiment(args.out, config, seconds=args.seconds, height_ratio=args.height_ratio,
                                     speed_rad_s=args.speed, settle_s=args.settle, seed=args.seed,
                                     progress=_progress)
    if sys.stdout.isatty():
        print()
    print(f"simulated {result.simulated_s:.1f} s in {result.wall_s:.1f} s ({result.real_time_factor:.1f}× real "
          f"time; machine load changes this)")
    print(f"body advanced {result.advance_m * 100:+.1f} cm; median total bottom force {result.median_bottom_force_n:.1f}"
          f" N (robot weight {result.weight_n:.1f} N)")
    for line in result.overloads:
        print(line)
    print(f"wrote {result.path}")
    return 0
