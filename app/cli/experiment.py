"""``sensnake experiment run --scene SCENE.toml [--shape SHAPE.json] [--mode follow|keyframes|serpenoid|sidewinding]
[--speed RAD_S] [--seconds S] [--settle S] [--seed K] [--config FILE] --out REC.h5`` (any scene, any motion) and
``sensnake experiment obstacle --out REC.h5 [--height-ratio R] …`` (the paper's Sec. III-C experiment): the physics lab
(MuJoCo) headless and faster than real time (:mod:`app.core.experiment`). Prints a progress line about once a second
and a summary at the end. Runs on the main thread.
"""

from __future__ import annotations

import argparse
import sys

from app.core.experiment import run_experiment, run_obstacle_experiment
from app.core.shapes import read_shape
from devices.config import LabConfig, load_config


def _progress(line: str) -> None:
    # One line rewritten in place on a terminal; one line per report when piped to a file.
    end = "\r" if sys.stdout.isatty() else "\n"
    print(line, end=end, flush=True)


def run(args: argparse.Namespace) -> int:
    if args.name not in ("run", "obstacle"):  # argparse's choices already refuse others; kept for a direct call
        raise ValueError(f"unknown experiment {args.name!r}; known: run, obstacle")
    try:
        import mujoco  # noqa: F401 - a clear message instead of an ImportError deep inside the lab
    except ImportError as exc:
        raise RuntimeError("the physics lab needs the 'mujoco' package: pip install mujoco") from exc
    config = load_config(args.config) if args.config else LabConfig()
    if args.name == "obstacle":
        for option in ("scene", "shape"):
            if getattr(args, option):
                raise ValueError(f"--{option} is for 'sensnake experiment run' (obstacle is the paper's scene)")
        result = run_obstacle_experiment(args.out, config, seconds=args.seconds, height_ratio=args.height_ratio,
                                         speed_rad_s=args.speed, settle_s=args.settle, seed=args.seed,
                                         progress=_progress)
    else:
        shape = read_shape(args.shape) if args.shape else None
        result = run_experiment(args.out, config, scene=args.scene, shape=shape, mode=args.mode,
                                seconds=args.seconds, speed_rad_s=args.speed, settle_s=args.settle, seed=args.seed,
                                progress=_progress)
    if sys.stdout.isatty():
        print()
    print(f"scene {result.scene_name}: simulated {result.simulated_s:.1f} s in {result.wall_s:.1f} s "
          f"({result.real_time_factor:.1f}× real time; machine load changes this)")
    print(f"body advanced {result.advance_m * 100:+.1f} cm"
          + (f"; traversed: {'yes' if result.traversed else 'no'}" if result.scene_name else ""))
    print(f"median total bottom force {result.median_bottom_force_n:.1f} N (normal forces: more than the weight "
          f"where the body lies on a curve); their vertical part {result.median_vertical_support_n:.1f} N "
          f"(robot weight {result.weight_n:.1f} N)")
    for line in result.overloads:
        print(line)
    print(f"wrote {result.path}")
    return 0
