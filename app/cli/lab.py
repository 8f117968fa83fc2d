"""``sensnake lab identify REC.h5 [REC2.h5 …] [--fit KEY,KEY…] [--config LAB.toml] [--scene SCENE.toml] [--window S]
[--settle S] [--max-steps N] [--screen] --out FITTED.toml``: the physics lab's ``[lab.physics]`` values and the
scene's frictions fitted so that the lab, replaying each recording's goals, reproduces what the recording measured
(:mod:`app.core.identify`). Prints a line per replay, then each value with its 95 % interval and whether the
recordings fix it, the residual per signal and how far a 10 % change of each value moves each signal; writes the
values as a lab-config fragment to ``--out`` (a new file: an existing one is refused before anything runs).
Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from devices.config import LabConfig, load_config
from devices.toml_files import read_text_file


def _progress(line: str) -> None:
    end = "\r" if sys.stdout.isatty() else "\n"
    print(f"{line:<110}", end=end, flush=True)


def run(args: argparse.Namespace) -> int:
    if args.lab_command != "identify":  # argparse refuses others
        raise ValueError(f"unknown lab action {args.lab_command!r}; known: identify")
    try:
        import mujoco  # noqa: F401 - a clear message instead of an ImportError deep inside the lab
    except ImportError as exc:
        raise RuntimeError("the physics lab needs the 'mujoco' package: pip install mujoco") from exc
    from app.core.identify import identify, parse_keys, summary_lines, write_fitted
    from app.core.recording import check_input
    from devices.errors import SceneError
    from devices.scene import resolve_scene_path

    out = Path(args.out)
    if out.exists() or out.is_symlink():
        raise FileExistsError(f"{out} exists: identify never replaces a file; choose another --out")
    if not os.access(out.parent if str(out.parent) else Path("."), os.W_OK):
        raise PermissionError(f"cannot write {out}: its folder is not writable")
    if args.max_steps < 1:
        raise ValueError(f"--max-steps must be 1 or more, got {args.max_steps}")
    keys = parse_keys(args.fit)
    config = load_config(args.config) if args.config else LabConfig()
    scene_text = read_text_file(resolve_scene_path(args.scene), "scene file", SceneError) if args.scene else None
    for path in args.recordings:
        if not Path(path).is_file():
            check_input(path)  # a FIFO, a device, a link loop: named for what it is
            raise FileNotFoundError(f"no such recording: {path}")
    result = identify(args.recordings, keys, config, window_s=args.window, settle_s=args.settle,
                      scene_text=scene_text, max_steps=args.max_steps, screen=args.screen, progress=_progress)
    if sys.stdout.isatty():
        print()
    for line in summary_lines(result):
        print(line)
    write_fitted(result, out)
    print(f"{result.evaluations} replays, {result.cpu_s:.0f} s of CPU; wrote {out}")
    if result.not_fixed:
        print(f"sensnake lab identify: the recordings do not fix {', '.join(result.not_fixed)} (see above; "
              f"written, marked NOT FIXED)", file=sys.stderr)
    return 0
