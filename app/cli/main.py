"""The ``sensnake`` command line (SPEC §1).

The parser is the contract; each command's work lives in ``app/cli/<name>.py`` as ``run(args) -> int`` and is
imported only when that command runs, so ``sensnake fit`` never loads Qt and ``sensnake gui`` never loads casadi.
Expected failures (bad file, no reply from a servo, CRC storm, …) end with one line on stderr and a non-zero exit;
set ``SENSNAKE_DEBUG=1`` to see the traceback instead.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import select
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from typing import NoReturn

from app.core.outputs import check_output, refuse_replacing_a_recording

# Errors a user can cause and fix. Every project error subclasses one of these builtins
# (ConfigError(ValueError), NoReplyError(TimeoutError), CsvFormatError(ValueError), …).
EXPECTED_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, LookupError, RuntimeError)

# What main() turns into one line: those, a MemoryError, and a library that could not be loaded into memory.
HANDLED_ERRORS: tuple[type[BaseException], ...] = (MemoryError, ImportError, *EXPECTED_ERRORS)

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

# Column names of the CSVs estimate, forward and export write (app.core.calfiles.with_unit_suffixes).
UNIT_STYLES = ("bare", "suffixed")
UNITS_HELP = ("bare (default, SPEC §3.2): sensor names as in the calibration, forces in N, conductance in S; "
              "suffixed: each column names its unit (<name>_N; <name>_uS, in µS), as the GUI's exports do")


# Per command: the arguments that name files it reads, and those that name files it writes. A write onto a file the
# command is reading destroys the input before it has been read: refused before anything runs.
INPUTS_AND_OUTPUTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "estimate": (("input", "cal", "config"), ("out", "flags")),
    "forward": (("input", "cal"), ("out",)),
    "fit": (("trials",), ("out",)),  # --physics may be the calibration it updates (--out): reading it first is fine
    "export": (("recording",), ("csv",)),
    "repair": (("recording",), ("out",)),
    "experiment": (("scene", "shape", "gains", "config", "plan"), ("out",)),
    "calibrate": (("config",), ("out",)),
    "record": (("config",), ("out",)),
    "teach": (("config",), ("out",)),
    "play": (("shape", "config"), ("log",)),
    "servo": (("config", "settings"), ("out",)),
    "mocap": (("take", "xdf", "rec", "config", "recording"), ("out",)),
    "lab": (("recordings", "config", "scene"), ("out",)),
    "trials": (("shape", "start", "cal", "config"), ("out",)),
}


def refuse_outputs_onto_inputs(command: str, args: argparse.Namespace) -> None:
    """Raise ValueError naming the file when an output of ``command`` is (or resolves to) one of its inputs, and
    :class:`app.core.errors.OutputPathError` when it is no regular file to replace (:mod:`app.core.outputs`)."""
    inputs_, outputs = INPUTS_AND_OUTPUTS.get(command, ((), ()))
    read: dict[str, str] = {}
    for name in inputs_:
        values = getattr(args, name, None)
        for value in values if isinstance(values, list) else [values]:
            if value:
                positional = name in ("input", "trials", "recording", "recordings", "plan") or \
                    (command, name) in (("play", "shape"), ("trials", "shape"))
                read[os.path.realpath(value)] = str(value) if positional else f"--{name} {value}"
    for name in outputs:
        value = getattr(args, name, None)
        if value and os.path.realpath(value) in read:
            raise ValueError(f"--{name} {value} is also an input ({read[os.path.realpath(value)]}): choose another "
                             f"file to write, the input would be destroyed before it is read")
        folder_wanted = command == "experiment" and getattr(args, "name", None) in ("sweep", "trials", "evaluate",
                                                                                    "tune")
        folder_wanted = folder_wanted or command == "trials"  # sensnake trials --out DIR: the series' folder
        if value and not folder_wanted and not os.path.isdir(value):  # a folder: refused by the writer, in its words
            check_output(value)  # a device, FIFO, socket or link loop: refused before anything runs
            # nor a recording (another run's raw data); an estimate or repair may replace its own input's copy
            refuse_replacing_a_recording(value, tuple(read) if command in ("estimate", "repair") else ())


class _OneLineErrorParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (SPEC §1) that points to ``--help`` instead of printing
    the whole usage block first. Subparsers inherit the class. Exit code stays argparse's 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {' '.join(message.split())} (see '{self.prog} --help')\n")


ROBOT_HELP = "the servo bus: a serial device or 'sim' (default: the --config file's [robot] port)"


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineErrorParser(
        prog="sensnake",
        description="SenSnake Studio: run the snake robot, its force sensors and the calibration rig. "
        "With no command, opens the desktop app.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    gui = sub.add_parser("gui", help="open the desktop app (default)")
    _add_gui_options(gui)

    fit = sub.add_parser("fit", help="fit the sensor models to calibration trials")
    fit.add_argument("trials", nargs="+", metavar="TRIAL.csv", help="calibration trial CSVs (time_s,force_N,conductance_S)")
    fit.add_argument("--sensor", required=True, metavar="NAME", help="sensor name, e.g. S06B")
    fit.add_argument("--area", required=True, type=float, metavar="M2", help="sensor active area in m²")
    fit.add_argument("--physics", metavar="FILE.json", help="resistance–strain constants (a calibration file works)")
    fit.add_argument("--window", nargs=2, type=float, default=(225.0, 300.0), metavar=("START", "END"),
                     help="time window in s for the linear model's mean conductance (default 225 300)")
    fit.add_argument("--out", required=True, metavar="CAL.json", help="calibration file to create or update")
    fit.add_argument("--solver", choices=("gauss-newton", "scipy", "ipopt", "sqpmethod"), default=None,
                     help="joint-fit solver (default scipy; CasADi gauss-newton/ipopt/sqpmethod reach the same "
                          "parameters, slower: `sensnake bench`)")
    fit.add_argument("--fit-rate", type=float, default=None, metavar="HZ",
                     help="block-average faster trials to this rate before fitting (default 5 Hz: a 1 kHz "
                          "calibration in seconds, ~0.1 %% parameter error measured; 0 fits every sample)")
    fit.add_argument("--config", metavar="FILE",
                     help="lab config: its board's channel names (--sensor must be one) and readout circuit "
                          "(board.r_c_ohm, the saturation level not to fit)")
    fit.add_argument("--drift", choices=("fit", "off"), default="fit",
                     help="fit: look for a baseline drift common to the trials and separate it from the creep "
                          "(default; its rate is stored as drift_S_per_s and said); off: the plain fit, faster")

    calibrate = sub.add_parser("calibrate", help="run the calibration protocol on the rig, fit and save (unattended)")
    calibrate.add_argument("--rig", metavar="PORT", help="the rig servo's serial port, or sim (default: the config's)")
    calibrate.add_argument("--daq", metavar="PORT", help="the force-sensor board's port, or sim (default: the config's)")
    calibrate.add_argument("--sensor", metavar="NAME", help="the sensor under the probe (default: the config's rig.sensor)")
    calibrate.add_argument("--sensors", metavar="NAME,…",
                           help="several sensors, one after another, each saved into --out as its fit is done: names "
                                "or patterns of board channels ('S*B': every bottom sensor); the simulated lab moves "
                                "its probe to each, on a real rig the command waits while you move it")
    calibrate.add_argument("--forces", metavar="F1,F2,…", help="forces in N (default 1.75,3,4,5.25, the paper's)")
    calibrate.add_argument("--trials", type=int, metavar="N", help="trials per force (default 3)")
    calibrate.add_argument("--hold", type=float, metavar="S", help="hold per trial in s (default 370)")
    calibrate.add_argument("--rest", type=float, metavar="S", help="unloaded rest before each trial in s (default 300)")
    calibrate.add_argument("--rate", type=float, metavar="HZ", help="sampling rate in Hz (default 6)")
    calibrate.add_argument("--baseline", type=float, metavar="S", help="unloaded record before the ramp in s (default 3)")
    calibrate.add_argument("--ramp", type=float, metavar="S", help="loading ramp in s (default 2)")
    calibrate.add_argument("--area", type=float, metavar="M2", help="sensor area under the probe (default: rig.area_m2)")
    calibrate.add_argument("--condition", metavar="N[@FORCE]",
                           help="condition the sensor first: N load/unload cycles at FORCE N (default: the top force), "
                                "not recorded as trials, logged in the session (default: off)")
    calibrate.add_argument("--physics", metavar="FILE.json", help="resistance–strain constants (a calibration file works)")
    calibrate.add_argument("--time-scale", type=float, default=None, metavar="X",
                           help="run the simulated lab X times faster than real time (only with sim ports)")
    calibrate.add_argument("--resume", metavar="SESSION_DIR",
                           help="continue a session cut short: finished trials kept, the interrupted one redone")
    calibrate.add_argument("--save-anyway", action="store_true",
                           help="save a fit that is degenerate or non-physical (still named on stderr)")
    calibrate.add_argument("--config", metavar="FILE", help="lab config (rig, board channel map, readout circuit)")
    calibrate.add_argument("--simulated-truth", action="store_true",
                           help="write the simulated lab's every sensor's true calibration (the simulation's truth, "
                                "not a measurement) to a new --out and exit; nothing moves")
    calibrate.add_argument("--out", required=True, metavar="CAL.json", help="calibration file to create or update")

    estimate = sub.add_parser("estimate", help="conductance → force for every sensor column, or a recording's "
                              "forces re-estimated with another calibration")
    estimate.add_argument("input", metavar="IN.csv|REC.h5",
                          help="a conductance CSV, or a recording (its /forces are re-estimated into --out NEW.h5)")
    estimate.add_argument("--cal", required=True, metavar="CAL.json")
    estimate.add_argument("--model", choices=("linear", "sls"), default="sls")
    estimate.add_argument("--out", required=True, metavar="OUT.csv|NEW.h5",
                          help="forces CSV (a column without a calibration passes through as <name>_uS), or for a "
                          "recording a copy of it with /forces replaced")
    estimate.add_argument("--flags", metavar="FLAGS.csv",
                          help="also write per-sample flag codes (same columns; 0 = ok, legend in docs/NUMERICS.md)")
    estimate.add_argument("--config", metavar="FILE",
                          help="lab config whose readout circuit (board.r_c_ohm) sets the ceiling 1/R_C")
    estimate.add_argument("--allow-degenerate", action="store_true",
                          help="use a calibration that 'sensnake fit' marked degenerate (at a bound/unidentifiable)")
    # Run time against error: `sensnake bench` (bench_pareto) measures every mode; the defaults are the fastest
    # within 1 % of the best error.
    estimate.add_argument("--engine", choices=("compiled", "reference"), default="compiled",
                          help="sls: compiled recursion (C, else numba; default) or the numpy reference (same numbers, slower)")
    estimate.add_argument("--interp", choices=("hold", "linear"), default="hold",
                          help="sls: force held (default, the paper's Eq. 12) or linear between samples")
    estimate.add_argument("--no-contact", action="store_true",
                          help="sls: leave out the contact term K/√F (faster; biased on a sensor that has one)")
    estimate.add_argument("--float32", action="store_true",
                          help="round readings and forces to float32 and write 9 significant digits (smaller file)")
    estimate.add_argument("--units", choices=UNIT_STYLES, default="bare", help=UNITS_HELP)

    forward = sub.add_parser("forward", help="force → conductance (the model run forwards)")
    forward.add_argument("input", metavar="IN.csv")
    forward.add_argument("--cal", required=True, metavar="CAL.json")
    forward.add_argument("--out", required=True, metavar="OUT.csv")
    forward.add_argument("--clip-negative", action="store_true",
                         help="read negative forces (load-cell noise) as 0 N, with a warning; without it they are "
                              "refused: a contact sensor is pressed, never pulled")
    forward.add_argument("--units", choices=UNIT_STYLES, default="bare", help=UNITS_HELP)

    scan = sub.add_parser("scan", help="list the servos on a bus")
    scan.add_argument("--robot", metavar="PORT", help=ROBOT_HELP)
    scan.add_argument("--config", metavar="FILE", help="lab config (its [robot] port, baud and joint IDs)")
    bauds = scan.add_mutually_exclusive_group()
    bauds.add_argument("--baud", type=int, default=None, metavar="B")
    bauds.add_argument("--all-bauds", action="store_true", help="try every Dynamixel baud rate")

    teach = sub.add_parser("teach", help="pose the robot by hand and capture the shape")
    teach.add_argument("--robot", metavar="PORT", help=ROBOT_HELP)
    teach.add_argument("--baud", type=int, default=None, metavar="B")
    teach.add_argument("--after", type=float, default=None, metavar="SECONDS",
                       help="capture after this many seconds instead of waiting for Enter")
    teach.add_argument("--out", required=True, metavar="SHAPE.json")
    teach.add_argument("--config", metavar="FILE", help="lab config (joint IDs, signs, offsets)")

    play = sub.add_parser("play", help="play a taught shape on the robot")
    play.add_argument("shape", metavar="SHAPE.json")
    play.add_argument("--robot", metavar="PORT", help=ROBOT_HELP)
    play.add_argument("--baud", type=int, default=None, metavar="B")
    play.add_argument("--mode", choices=("follow", "keyframes"), default="follow")
    play.add_argument("--speed", type=float, default=0.034, metavar="RAD_S")
    play.add_argument("--time-scale", type=float, default=1.0, metavar="X")
    play.add_argument("--rate", type=float, default=50.0, metavar="HZ")
    play.add_argument("--shifts", type=int, default=None, metavar="K")
    play.add_argument("--log", metavar="LOG.csv")
    play.add_argument("--strict", action="store_true",
                      help="exit 1 when more than 1 %% of the control ticks were missed (the cause and its fix are "
                           "said either way)")
    play.add_argument("--config", metavar="FILE", help="lab config (joint IDs, signs, offsets, limits)")

    record = sub.add_parser("record", help="record the force-sensor board to HDF5")
    record.add_argument("--daq", metavar="PORT",
                        help="the force-sensor board's serial device or 'sim' (default: the --config file's [board] "
                             "port)")
    record.add_argument("--baud", type=int, default=None, metavar="B")
    record.add_argument("--seconds", required=True, type=float, metavar="S")
    record.add_argument("--out", required=True, metavar="REC.h5")
    record.add_argument("--config", metavar="FILE", help="lab config (channel map, readout circuit)")
    record.add_argument("--note", default="", metavar="TEXT", help="the operator's note, kept in the run_start")
    record.add_argument("--mocap", metavar="lsl:NAME", help="also record a motion-capture stream (Lab Streaming "
                        "Layer: the stream named NAME, else the first of type MoCap), stamped at capture, as /mocap "
                        "(default: the config's [lab] mocap)")
    record.add_argument("--lsl-out", action="store_true", help="publish SenSnake-forces and SenSnake-events on the "
                        "Lab Streaming Layer while recording")

    _add_robot_trials(sub)

    export = sub.add_parser("export", help="recording → CSV")
    export.add_argument("recording", metavar="REC.h5")
    export.add_argument("--csv", required=True, metavar="OUT.csv")
    export.add_argument("--units", choices=UNIT_STYLES, default="bare", help=UNITS_HELP)

    servo = sub.add_parser("servo", help="read, write, back up and restore the servos' control tables",
                           description="The servos' control tables without Dynamixel Wizard: every item of a servo "
                           "(get), one item checked and confirmed (set; EEPROM items with torque off), all of them "
                           "to a file (dump) and back (restore: only the differences are written).")
    servo_sub = servo.add_subparsers(dest="servo_command", metavar="ACTION", required=True)
    servo_get = servo_sub.add_parser("get", help="every item of one servo, or one item")
    servo_get.add_argument("item", nargs="?", metavar="ITEM", help='e.g. "Position P Gain" (default: all)')
    servo_set = servo_sub.add_parser("set", help="write one item (range-checked, read back)")
    servo_set.add_argument("item", metavar="ITEM")
    servo_set.add_argument("value", type=int, metavar="VALUE", help="raw control-table units (see 'get')")
    servo_dump = servo_sub.add_parser("dump", help="every item of every servo to a settings file")
    servo_dump.add_argument("--out", required=True, metavar="SERVOS.json")
    servo_restore = servo_sub.add_parser("restore", help="write a settings file's items back where they differ")
    servo_restore.add_argument("settings", metavar="SERVOS.json")
    servo_reset = servo_sub.add_parser("reset", help="factory reset of one servo's settings, keeping its ID and "
                                       "baud rate (dump them first)")
    servo_reset.add_argument("--yes", action="store_true", help="do it: the servo's settings are erased")
    servo_zero = servo_sub.add_parser("zero", help="lay the robot straight: its present pose becomes every joint's 0 "
                                      "(zero offsets written into --config, the old file kept as a backup)")
    servo_zero.add_argument("--dry-run", action="store_true", help="show the angles before and after; write nothing")
    servo_reboot = servo_sub.add_parser("reboot", help="reboot servos (clears a latched hardware error such as an "
                                        "overload; each comes back with torque off) and read their error status")
    servo_torque = servo_sub.add_parser("torque", help="torque on (each joint held where it is) or off")
    servo_led = servo_sub.add_parser("led", help="LED on or off")
    for switch in (servo_torque, servo_led):
        switch.add_argument("state", choices=("on", "off"))
    for action in (servo_get, servo_set, servo_dump, servo_restore, servo_zero, servo_reset, servo_reboot,
                   servo_torque, servo_led):
        action.add_argument("--robot", metavar="PORT", help=ROBOT_HELP)
        action.add_argument("--baud", type=int, default=None, metavar="B")
        action.add_argument("--config", metavar="FILE", help="lab config (its [robot] port and joint IDs)")
        ids = action.add_mutually_exclusive_group() if action in (servo_reboot, servo_torque, servo_led) else action
        ids.add_argument("--id", type=int, action="append", dest="ids", metavar="N",
                         help="a servo ID (repeatable; default: every configured joint; get and set need one)")
        if action in (servo_reboot, servo_torque, servo_led):
            ids.add_argument("--all", action="store_true", help="every configured joint (reboot needs --id or this)")

    repair = sub.add_parser("repair", help="salvage a truncated recording into a clean file")
    repair.add_argument("recording", metavar="REC.h5")
    repair.add_argument("--out", metavar="FIXED.h5", help="where to write it (default: REC-repaired.h5)")

    experiment = sub.add_parser("experiment", help="run a simulated experiment in the physics lab (MuJoCo)")
    experiment.add_argument("name", choices=("run", "obstacle", "sweep", "trials", "evaluate", "tune"),
                            help="run: any scene and motion; obstacle: the paper's Sec. III-C experiment; sweep: "
                                 "scenes × controllers × gains × tail loads × seeds from a sweep file; trials: one "
                                 "condition --trials times (seeds --seed …), each its own recording, and the "
                                 "repeatability report; evaluate: a pre-registered evaluation file (conditions drawn "
                                 "from scene families, controllers paired with feedforward); tune: the law's gains "
                                 "searched by Optuna on training scenes, scored once on test scenes")
    experiment.add_argument("plan", nargs="?", metavar="SWEEP.toml|EVAL.toml|TUNE.toml",
                            help="sweep, evaluate, tune: the plan file")
    experiment.add_argument("--engine", choices=("local", "dask"), default="local",
                            help="sweep, evaluate, tune: local processes (default) or Dask (an embedded cluster on "
                                 "127.0.0.1, or --scheduler's)")
    experiment.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                            help="with --engine dask: an existing Dask scheduler (default: start one here)")
    experiment.add_argument("--out", required=True, metavar="REC.h5|DIR",
                            help="the recording (run, obstacle) or the folder (sweep, evaluate, tune: a new one, or "
                                 "one the same command left unfinished, which it resumes)")
    experiment.add_argument("--jobs", type=int, default=None, metavar="N",
                            help="sweep, evaluate, tune: runs at a time (default and at most: the machine's cores, "
                                 "and no more than the runs)")
    experiment.add_argument("--scene", metavar="SCENE.toml",
                            help="run: a scene file or a built-in scene (paper_obstacle, flat, step, wedge, "
                                 "two_obstacles); default: the config's [lab] scene, else the paper's obstacle")
    experiment.add_argument("--shape", metavar="SHAPE.json",
                            help="run: the shape to play (default: the settled pose, captured as the paper does)")
    experiment.add_argument("--mode", choices=("follow", "keyframes", "serpenoid", "sidewinding"), default="follow",
                            help="run: how to play it (default follow-the-leader)")
    experiment.add_argument("--controller", choices=("feedforward", "feedback", "conform_only", "push_only"),
                            default="feedforward",
                            help="run: feedforward (the motion as planned), feedback (force-feedback body bending), "
                                 "or the law's conform_only or push_only variant (models/controllers.py)")
    experiment.add_argument("--gains", metavar="FILE.toml", help="run: the feedback controller's gains")
    experiment.add_argument("--repeat", type=int, default=1, metavar="K",
                            help="run: play a follow-the-leader shape K times (each re-forms it at the head)")
    experiment.add_argument("--tail-load", type=float, default=0.0, metavar="N",
                            help="run: a constant backward force on the tail (N), from the capture on")
    experiment.add_argument("--seconds", type=float, default=None, metavar="S",
                            help="stop playing after S simulated seconds (default: the whole motion)")
    experiment.add_argument("--rest-cap", type=float, default=None, metavar="S",
                            help="run, obstacle: after the motion, wait up to S simulated seconds for the body to "
                                 "come to rest, where the outcome is judged (default 30; 0: no wait, undecided)")
    experiment.add_argument("--height-ratio", type=float, default=0.28, metavar="R",
                            help="obstacle: its height × body length (default 0.28, the paper's)")
    experiment.add_argument("--speed", type=float, default=0.034, metavar="RAD_S",
                            help="follow-the-leader speed (default 0.034 rad/s, the paper's)")
    experiment.add_argument("--settle", type=float, default=6.0, metavar="S",
                            help="seconds the robot settles on the scene before the capture")
    experiment.add_argument("--seed", type=int, default=0, help="seed of the simulated sensors' spread and noise")
    experiment.add_argument("--config", metavar="FILE", help="lab config (robot, board, [lab] scene and frictions)")
    experiment.add_argument("--trials", type=int, default=None, metavar="N",
                            help="trials: how many (trial k runs with seed --seed + k); tune: how many Optuna trials "
                                 "the study in --out holds when done (it resumes)")
    experiment.add_argument("--note", default="", metavar="TEXT", help="the operator's note, kept in each run_start")
    experiment.add_argument("--ideal-sensing", action="store_true",
                            help="run, obstacle, sweep: the controller's forces through the sensors' true calibration "
                                 "(default: as a robot senses them, through a rig calibration's errors, the "
                                 "board's noise and the creep; [lab] sensing)")
    add_align_options(experiment)

    mocap = sub.add_parser("mocap", help="motion capture: a take (C3D or XDF) added to a recording on its clock",
                           description="Motion-capture takes beside recordings (docs/MOCAP.md): each segment's pose "
                           "fitted to its markers, the take placed on the recording's clock, written to a copy of the "
                           "recording as /mocap.")
    mocap_sub = mocap.add_subparsers(dest="mocap_command", metavar="ACTION", required=True)
    mocap_import = mocap_sub.add_parser("import", help="a take added to a copy of a recording as /mocap")
    mocap_import.add_argument("take", nargs="?", metavar="TAKE.c3d", help="a C3D take (or give --xdf)")
    mocap_import.add_argument("--xdf", metavar="FILE.xdf", help="instead of a C3D: the first stream of type MoCap in "
                              "a LabRecorder file")
    mocap_import.add_argument("--rec", required=True, metavar="REC.h5", help="the recording (only read)")
    mocap_import.add_argument("--config", metavar="LAB.toml", help="lab config: [mocap] labels and marker_layout_m, "
                              "the joint axes (default: the one stored in the recording)")
    mocap_import.add_argument("--offset", type=float, metavar="S", help="the recording time (s) of the take's first "
                              "frame (default: found from the motion, against /robot/present_rad)")
    mocap_import.add_argument("--out", required=True, metavar="NEW.h5", help="the copy with /mocap (a new file)")
    mocap_simulate = mocap_sub.add_parser("simulate", help="a C3D take of a physics-lab recording's simulated body")
    mocap_simulate.add_argument("recording", metavar="REC.h5", help="a recording of 'sensnake experiment run'")
    mocap_simulate.add_argument("--out", required=True, metavar="TAKE.c3d", help="the take (a new file)")
    mocap_simulate.add_argument("--lead", type=float, default=1.5, metavar="S",
                                help="the take starts this long before the recording (default 1.5 s)")
    mocap_simulate.add_argument("--seed", type=int, default=0, help="seed of the noise and dropouts")
    mocap_simulate.add_argument("--config", metavar="LAB.toml", help="lab config ([mocap] labels, layout)")

    _add_lab(sub)

    bench = sub.add_parser("bench", help="print the benchmark tables")
    bench.add_argument("--quick", action="store_true", help="smaller scenarios, for a first look")
    _add_report_and_runs(sub)
    return parser


def _add_lab(sub: argparse._SubParsersAction) -> None:
    """``sensnake lab identify REC.h5… [--fit KEY,…] --out FITTED.toml`` (app/cli/lab.py, app/core/identify.py) and
    ``sensnake lab shell --rig PORT … --out SHELL.toml`` (app/core/shell_bench.py)."""
    lab = sub.add_parser("lab", help="the physics lab's parameters, identified from recordings or measured on the rig",
                         description="The physics lab's [lab.physics] values and the scene's frictions fitted to "
                         "recordings (docs/PHYSICS_LAB.md, 'Parameters identified from measurements'), or the "
                         "shell's measured on the calibration rig ('The shell on the rig').")
    lab_sub = lab.add_subparsers(dest="lab_command", metavar="ACTION", required=True)
    identify = lab_sub.add_parser(
        "identify", help="fit [lab.physics] values and the scene's frictions so that the physics lab, replaying each "
        "recording's goals, reproduces what it measured",
        description="Replays each recording's goals open-loop in the physics lab with candidate values and fits "
        "them (least squares) to what the recording measured: present angles and currents (/robot), estimated "
        "forces (/forces), segment positions (/mocap, when present). Never reads the simulation's truth (/sim's "
        "data). Writes the values as a lab-config fragment, with their intervals, and says which the recordings "
        "cannot fix.")
    identify.add_argument("recordings", nargs="+", metavar="REC.h5", help="recordings of one robot (their goals are "
                          "replayed from each capture)")
    identify.add_argument("--fit", default="shell_stiffness_n_per_m,ground_friction,obstacle_friction",
                          metavar="KEY,KEY…", help="the values to fit: [lab.physics] keys, ground_friction, "
                          "obstacle_friction (default: shell_stiffness_n_per_m,ground_friction,obstacle_friction)")
    identify.add_argument("--config", metavar="LAB.toml", help="the lab config the recordings were made with: its "
                          "robot and board, the values not fitted and where the fitted ones start ([lab.physics]; "
                          "[lab] ground_friction, obstacle_friction); default: the built-in lab")
    identify.add_argument("--scene", metavar="SCENE.toml", help="the scene the recordings were made on (default: "
                          "each recording's copy of its scene; its frictions are not read for the fitted ones)")
    identify.add_argument("--window", type=float, default=20.0, metavar="S",
                          help="seconds of each recording replayed, from its capture (default 20)")
    identify.add_argument("--settle", type=float, default=6.0, metavar="S",
                          help="seconds the robot settled on the scene before the capture (default 6, as "
                               "'experiment run')")
    identify.add_argument("--max-steps", type=int, default=8, metavar="N",
                          help="least-squares steps at most (each one replay per recording, and each Jacobian one "
                               "per key; default 8)")
    identify.add_argument("--screen", action="store_true",
                          help="also say how much every [lab.physics] key not fitted moves the signals (one replay "
                               "each)")
    identify.add_argument("--out", required=True, metavar="FITTED.toml", help="the fitted values (a new file; an "
                          "existing one is never replaced)")
    shell = lab_sub.add_parser(
        "shell", help="the shell's bench test: force against deflection of a segment's shell on the calibration rig, "
        "fitted to [lab.physics] shell_stiffness_n_per_m (and shell_travel_m when the shell bottoms out)",
        description="With the segment on the rig's beam, its sensor under the probe and a dial gauge on the probe: "
        "finds the contact, steps the rig through a force ramp reading the servo's angle and the gauge at each step "
        "(typed in on a real rig; the simulated rig's gauge on 'sim', its shell the --config's [lab.physics]), fits "
        "the shell's stiffness (and travel) with 95 % intervals and writes them as a lab-config fragment. The "
        "damping is not measurable this way and is never written (docs/PHYSICS_LAB.md, 'The shell on the rig').")
    shell.add_argument("--rig", metavar="PORT", help="the rig servo's serial port, or sim (default: the --config "
                       "file's [rig] port)")
    shell.add_argument("--config", metavar="LAB.toml", help="lab config: the rig (spring, wheel, servo, max force) "
                       "and, on sim, the simulated shell's [lab.physics] values (default: the built-in lab)")
    shell.add_argument("--max-force", type=float, default=8.0, metavar="N",
                       help="the last step's nominal force k·r·(θ − θ_c) in N (default 8; capped by rig.max_force_n; "
                            "the shell makes the real force smaller)")
    shell.add_argument("--steps", type=int, default=16, metavar="N", help="loaded steps (default 16)")
    shell.add_argument("--gauge-resolution", type=float, default=0.01, metavar="MM",
                       help="the dial gauge's digit in mm (default 0.01)")
    shell.add_argument("--gauge-force", type=float, default=0.0, metavar="N",
                       help="the gauge plunger's measuring force at the slack reading, in N, from its datasheet or "
                            "weighed (default 0: a gauge whose spring is negligible)")
    shell.add_argument("--gauge-rate", type=float, default=0.0, metavar="N_PER_M",
                       help="how much the plunger's force falls per metre the probe goes in, in N/m ((largest − "
                            "smallest measuring force) / stroke; default 0)")
    shell.add_argument("--hold", type=float, default=0.0, metavar="S",
                       help="hold the ramp's middle step S seconds and read the gauge again: a shell that creeps is "
                            "named (default 0: no hold)")
    shell.add_argument("--time-scale", type=float, default=None, metavar="X",
                       help="run the simulated rig X times faster than real time (only with --rig sim)")
    shell.add_argument("--seed", type=int, default=0, help="the simulated rig's and gauge's seed (sim only)")
    shell.add_argument("--out", required=True, metavar="SHELL.toml", help="the fitted values (a new file; an "
                       "existing one is never replaced)")


def _add_report_and_runs(sub: argparse._SubParsersAction) -> None:
    """``sensnake report repeatability …`` (app/cli/report.py) and ``sensnake runs list|show|reindex``
    (app/cli/runs.py); ``experiment trials`` takes the report's alignment options too."""
    report = sub.add_parser("report", help="reports over recordings: repeatability of trials (the paper's Fig. 7)")
    report.add_argument("kind", choices=("repeatability",), help="repeatability: trials aligned on an event, the "
                        "mean and s.d. of each bottom force and segment position over time")
    report.add_argument("recordings", nargs="+", metavar="REC.h5", help="two or more recordings of one condition")
    report.add_argument("--out", required=True, metavar="DIR", help="the report's folder (created if needed)")
    report.add_argument("--mixed", action="store_true",
                        help="compare recordings of different conditions anyway (the differences are named)")
    report.add_argument("--step", type=float, default=None, metavar="S",
                        help="the common grid's step in s (default: the forces' sample period)")
    add_align_options(report)

    runs = sub.add_parser("runs", help="the run catalog: every recording's run metadata, searchable")
    runs_sub = runs.add_subparsers(dest="runs_command", metavar="ACTION", required=True)
    runs_list = runs_sub.add_parser("list", help="recordings matching --where/--since (the files are read again "
                                    "where they changed)")
    runs_list.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                           help="keep runs whose KEY is VALUE (repeatable; e.g. scene=paper_obstacle, outcome=traversed)")
    runs_list.add_argument("--since", metavar="DATE", help="runs started on or after DATE (YYYY-MM-DD or ISO 8601)")
    runs_list.add_argument("--format", choices=("table", "csv", "json"), default="table")
    runs_show = runs_sub.add_parser("show", help="one recording's run documents and what the catalog holds of it")
    runs_show.add_argument("file", metavar="FILE")
    runs_reindex = runs_sub.add_parser("reindex", help="read every recording under the folder again")
    for action in (runs_list, runs_reindex):
        action.add_argument("--dir", metavar="DIR", help="the folder of recordings (default: the data folder's "
                            "recordings)")


def _add_robot_trials(sub: argparse._SubParsersAction) -> None:
    """``sensnake trials SHAPE.json --robot PORT --daq PORT --trials N --out DIR …`` (app/cli/robot_trials.py)."""
    trials = sub.add_parser("trials", help="a trial series on the robot: N trials of one condition, each placed by "
                            "the operator and recorded; resumable",
                            description="Before each trial the robot goes to the start pose and the command waits "
                            "for the operator (Enter starts the trial); the recording starts before the motion and "
                            "stops --post seconds after it; the operator types the outcome and a note. Ctrl-C is STOP: "
                            "the trial in progress is kept, marked aborted. The same command resumes the series.")
    trials.add_argument("shape", nargs="?", metavar="SHAPE.json",
                        help="the shape to play (left out: resume the series in --out with its own options)")
    trials.add_argument("--robot", metavar="PORT", help=ROBOT_HELP)
    trials.add_argument("--baud", type=int, default=None, metavar="B", help="the servo bus's baud rate")
    trials.add_argument("--daq", metavar="PORT", help="the force-sensor board's serial device or 'sim' (default: the "
                        "--config file's [board] port)")
    trials.add_argument("--trials", type=int, default=None, metavar="N",
                        help="how many trials (a resumed series may grow)")
    trials.add_argument("--out", required=True, metavar="DIR", help="the series' folder: a recording per trial, "
                        "series.json (its state), trials.csv, the repeatability report")
    trials.add_argument("--mode", choices=("follow", "keyframes"), default=None, help="default follow")
    trials.add_argument("--speed", type=float, default=None, metavar="RAD_S", help="default 0.034 rad/s")
    trials.add_argument("--shifts", type=int, default=None, metavar="K")
    trials.add_argument("--repeat", type=int, default=None, metavar="K", help="play a follow-the-leader shape K times")
    trials.add_argument("--time-scale", type=float, default=None, metavar="X", help="keyframes: time scale")
    trials.add_argument("--start", metavar="START.json",
                        help="the start pose the robot goes to before each trial (a shape file; default: straight)")
    trials.add_argument("--scene", metavar="NAME", help="what the robot runs on, in your words (paper_obstacle, "
                        "flat, …): the condition's scene, searchable with 'runs list --where scene=NAME'")
    trials.add_argument("--tail-load", type=float, default=None, metavar="N", help="a load on the tail (N), noted")
    trials.add_argument("--post", type=float, default=None, metavar="S",
                        help="the recording runs on S seconds after the motion (default 1)")
    trials.add_argument("--cal", metavar="CAL.json", help="estimate forces live with this calibration (the "
                        "repeatability report needs forces)")
    trials.add_argument("--note", default=None, metavar="TEXT", help="the operator's note, kept in each run_start")
    trials.add_argument("--config", metavar="FILE", help="lab config (ports, joint IDs, channel map)")
    add_align_options(trials)


def add_align_options(parser: argparse.ArgumentParser) -> None:
    """The repeatability report's alignment options (``report repeatability``, ``experiment trials``)."""
    parser.add_argument("--align", choices=("onset", "contact", "mocap"), default="onset",
                        help="the event trials are aligned on: onset (first goal change, default), contact (first "
                             "bottom force past --contact-force), mocap (a segment's position from /mocap or /sim)")
    parser.add_argument("--contact-force", type=float, default=1.0, metavar="N",
                        help="contact: the force a bottom sensor rises past (default 1 N)")
    parser.add_argument("--contact-sensor", metavar="NAME", help="contact: only this bottom sensor (e.g. S01B)")
    parser.add_argument("--segment", type=int, default=1, metavar="K", help="mocap: the segment (1 = head)")
    parser.add_argument("--position-x", type=float, default=None, metavar="X_M",
                        help="mocap: the x (m) the segment passes (default: --position-move past its start)")
    parser.add_argument("--position-move", type=float, default=0.01, metavar="M",
                        help="mocap: how far past its start (default 0.01 m)")


def _add_gui_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="lab config TOML (default: the built-in simulated lab)")
    parser.add_argument("--sim", action="store_true", help="use the simulated lab for every device")


def _write_errors_not_signals() -> None:
    """A write past the process's file-size limit (``ulimit -f``) fails with EFBIG, which the writers handle (one
    line, the file kept as last flushed), instead of SIGXFSZ killing the process mid-write with a core dump."""
    xfsz = getattr(signal, "SIGXFSZ", None)
    if xfsz is not None and threading.current_thread() is threading.main_thread():
        signal.signal(xfsz, signal.SIG_IGN)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if not argv or (argv[0].startswith("--") and argv[0] not in ("-h", "--help")):
        argv = ["gui", *argv]
    args = parser.parse_args(argv)
    command = args.command or "gui"
    _write_errors_not_signals()
    bound_numeric_threads()
    try:
        refuse_outputs_onto_inputs(command, args)
        if command == "experiment" and args.name in ("sweep", "evaluate", "tune") and args.engine == "dask" \
                and not args.scheduler:
            from app.core.engines import start_worker_server

            start_worker_server()  # an embedded Dask cluster's workers: their imports overlap this command's
        with _import_watchdog(command, float(os.environ.get(IMPORT_WATCHDOG_ENV, "") or IMPORT_WATCHDOG_S)):
            module = importlib.import_module(f"app.cli.{command}")
        return int(module.run(args) or EXIT_OK)
    except KeyboardInterrupt:
        print(f"sensnake {command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except HANDLED_ERRORS as exc:
        if os.environ.get("SENSNAKE_DEBUG") or (isinstance(exc, ImportError) and not _memory_failure(exc)):
            raise  # SENSNAKE_DEBUG=1 keeps the traceback; a missing module is a broken install, shown as it is
        text = _memory_words() if _memory_failure(exc) else _one_line(exc)
        print(f"sensnake {command}: error: {text}", file=sys.stderr)
        return EXIT_FAILURE


# -- memory and threads ----------------------------------------------------------------------------------------------
# One BLAS/OpenMP thread per process. Under an address-space limit (`ulimit -v` 300 MB or 2 GB) a pool of OpenBLAS
# threads could not allocate its buffers and OpenBLAS retried for minutes with nothing printed, where the same fit
# takes 3 s in one thread; the numerical work here is on small matrices, where threads gain little, and a sweep
# already runs its runs in processes. Set before numpy is first imported (each command's module imports it): a value
# the user set wins, and a caller that already imported numpy (a test calling main()) keeps its pools.
NUMERIC_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
# OpenBLAS can also spin in its allocator while a library is being loaded under a tight limit (measured at 150 and
# 250 MB: nothing printed for minutes). A loading that takes this long is that, not a slow disk.
IMPORT_WATCHDOG_S = 60.0
IMPORT_WATCHDOG_ENV = "SENSNAKE_IMPORT_WATCHDOG_S"  # another time in seconds (the fault matrix waits 5 s)


def bound_numeric_threads() -> None:
    """Bound the numerical libraries' thread pools to one thread (see :data:`NUMERIC_THREAD_VARIABLES`)."""
    for name in NUMERIC_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


def address_space_limit() -> int | None:
    """The process's address-space limit in bytes (``ulimit -v``), or None when there is none (or no such limit on
    this platform)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return None
    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else int(soft)


def _memory_failure(exc: BaseException) -> bool:
    """A MemoryError, or a library that could not be mapped into memory under an address-space limit (the loader
    says "failed to map segment", llvmlite "could not find/load shared object")."""
    if isinstance(exc, MemoryError):
        return True
    text = str(exc).lower()
    return isinstance(exc, ImportError | OSError) and address_space_limit() is not None and (
        "failed to map segment" in text or "cannot allocate memory" in text or "shared object" in text)


def _memory_words() -> str:
    limit = address_space_limit()
    if limit is None:
        return ("out of memory: the machine's memory is used up; close other programs or give the command a smaller "
                "input")
    return (f"out of memory: this process may use only {limit / 2**20:.0f} MB of address space (ulimit -v "
            f"{limit // 1024}), less than the numerical libraries need to load and run (about 2 GB for fit): raise "
            "the limit (ulimit -v unlimited)")


@contextlib.contextmanager
def _import_watchdog(command: str, timeout_s: float = IMPORT_WATCHDOG_S) -> Iterator[None]:
    """Under an address-space limit, end the process with one line if loading ``command``'s libraries does not
    finish within ``timeout_s`` (OpenBLAS spinning in its allocator holds the interpreter's lock, so no thread of
    this process could say it: a forked watcher does, then kills this process). Without a limit, nothing."""
    if address_space_limit() is None or not hasattr(os, "fork") or threading.active_count() > 1:
        yield  # a process with threads is not forked (a test calling main() in-process)
        return
    done_read, done_write = os.pipe()
    parent = os.getpid()
    watcher = os.fork()
    if watcher == 0:  # pragma: no cover - the watcher process: covered by the fault matrix's ulimit -v case
        os.close(done_write)
        ready, _, _ = select.select([done_read], [], [], timeout_s)
        if not ready and os.getppid() == parent:  # never another process, should this one be gone
            limit = address_space_limit() or 0
            os.write(2, (f"sensnake {command}: error: the numerical libraries did not load in {timeout_s:.0f} s "
                         f"within this process's {limit / 2**20:.0f} MB of address space (ulimit -v {limit // 1024}): "
                         "OpenBLAS keeps retrying an allocation the limit refuses; raise the limit (ulimit -v "
                         "unlimited)\n").encode())
            os.kill(os.getppid(), signal.SIGKILL)
        os._exit(0)
    os.close(done_read)
    try:
        yield
    finally:
        os.close(done_write)  # the watcher sees the end of the pipe and exits
        os.waitpid(watcher, 0)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    if isinstance(exc, OSError) and exc.strerror and text.startswith("[Errno"):
        # "[Errno 21] cannot write out.csv: Is a directory" reads as Python, not as the cause: keep the words.
        text = str(exc.strerror)
        if exc.filename is not None and str(exc.filename) not in text:
            text += f": {exc.filename}"
    return " ".join(text.split())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
