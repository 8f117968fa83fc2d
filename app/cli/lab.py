"""``sensnake lab shell --rig PORT [--config LAB.toml] [--max-force N] [--steps N] [--gauge-resolution MM]
[--gauge-force N] [--gauge-rate N_PER_M] [--hold S] [--time-scale X] [--seed K] --out SHELL.toml``: the shell's
bench test on the calibration rig (:mod:`app.core.shell_bench`): force against deflection, the stiffness (and
travel) with intervals, a creep check with ``--hold``, written as a ``[lab.physics]`` fragment (a new file). Runs on
the CLI's main thread, which owns the rig.

``sensnake lab identify REC.h5 [REC2.h5 …] [--fit KEY,KEY…] [--config LAB.toml] [--scene SCENE.toml] [--window S]
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
from dataclasses import replace
from pathlib import Path

from devices.config import LabConfig, load_config
from devices.toml_files import read_text_file


def _progress(line: str) -> None:
    end = "\r" if sys.stdout.isatty() else "\n"
    print(f"{line:<110}", end=end, flush=True)


def _check_out(out: Path, command: str) -> None:
    if out.exists() or out.is_symlink():
        raise FileExistsError(f"{out} exists: {command} never replaces a file; choose another --out")
    if not os.access(out.parent if str(out.parent) else Path("."), os.W_OK):
        raise PermissionError(f"cannot write {out}: its folder is not writable")


def run_shell(args: argparse.Namespace) -> int:
    """``sensnake lab shell``: see the module docstring."""
    from app.cli._robot import lab_config
    from app.core.shell_bench import ShellBenchSettings, fit_bench, run_bench, summary_lines, write_shell_toml
    from devices import factory
    from devices.config import sets_port
    from devices.errors import DeviceError
    from devices.rig import CalibrationRig

    out = Path(args.out)
    _check_out(out, "lab shell")
    given = lab_config(args)
    if args.rig is not None:
        port = str(args.rig).strip()
    elif given is not None and sets_port(given, "rig"):
        port = given.rig.port
    else:
        raise ValueError("no rig port: give --rig PORT (a serial device, or sim) or --config LAB.toml whose [rig] "
                         "names its port")
    config = (given or LabConfig()).with_ports(rig=port)
    settings = ShellBenchSettings(max_force_n=args.max_force, steps=args.steps,
                                  gauge_resolution_m=args.gauge_resolution / 1000.0, gauge_force_n=args.gauge_force,
                                  gauge_rate_n_per_m=args.gauge_rate, hold_s=args.hold)
    sim = factory.is_sim(config.rig.port)
    if sim:
        settings = replace(settings, clock_scale=args.time_scale or 1.0)
    if args.time_scale is not None:
        if not sim:
            raise ValueError("--time-scale only runs the simulated rig faster: use it with --rig sim")
        if not (args.time_scale > 0 and args.time_scale <= 1000):
            raise ValueError(f"--time-scale must be above 0 and at most 1000, got {args.time_scale}")
    previous = None
    if sim:
        _, previous = factory.start_sim_rig_bench(config, speed=args.time_scale or 1.0, seed=args.seed,
                                                  gauge_force_n=settings.gauge_force_n,
                                                  gauge_rate_n_per_m=settings.gauge_rate_n_per_m)
        print(f"simulated rig: a segment's shell under the probe ({config.lab.physical.shell_stiffness_n_per_m:g} "
              f"N/m, {config.lab.physical.shell_damping_n_s_per_m:g} N·s/m, "
              f"{config.lab.physical.shell_travel_m * 1e3:g} mm travel, from [lab.physics]) and a dial gauge on it")
    try:
        rig = CalibrationRig(config.rig)
        for check in rig.check():
            if not check.ok:
                raise DeviceError(f"rig check failed: {check.name}: {check.detail}")
        gauge = factory.travel_gauge(config.rig.port, settings.gauge_resolution_m, seed=args.seed)
        with rig:
            data = run_bench(rig, gauge, settings, progress=print)
    finally:
        if sim:
            factory.install_sim_lab(previous)
    result = fit_bench(data, config, settings)
    for line in summary_lines(result):
        print(line)
    if "shell_stiffness_n_per_m" in result.fit.not_fixed:
        raise ValueError(f"the steps do not fix the shell's stiffness "
                         f"({result.fit.not_fixed['shell_stiffness_n_per_m']}); nothing written to {out}")
    write_shell_toml(result, out)
    print(f"wrote {out}: " + ", ".join(f"{k} = {v:.6g}" for k, v in result.fixed_values().items()))
    left = [k for k in result.fit.not_fixed if k != "shell_stiffness_n_per_m"]
    print(f"sensnake lab shell: not fixed by the bench test, not written: {', '.join(left)} (see above)",
          file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> int:
    if args.lab_command == "shell":
        return run_shell(args)
    if args.lab_command != "identify":  # argparse refuses others
        raise ValueError(f"unknown lab action {args.lab_command!r}; known: identify, shell")
    try:
        import mujoco  # noqa: F401 - a clear message instead of an ImportError deep inside the lab
    except ImportError as exc:
        raise RuntimeError("the physics lab needs the 'mujoco' package: pip install mujoco") from exc
    from app.core.identify import identify, parse_keys, summary_lines, write_fitted
    from app.core.recording import check_input
    from devices.errors import SceneError
    from devices.scene import resolve_scene_path

    out = Path(args.out)
    _check_out(out, "identify")
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
