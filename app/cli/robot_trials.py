"""``sensnake trials SHAPE.json --robot PORT --daq PORT --trials N --out DIR [--mode …] [--speed …] [--start
START.json] [--scene NAME] [--tail-load N] [--cal CAL.json] [--post S] [--note TEXT] [--config LAB.toml]``: a trial
series on the robot (:mod:`app.core.robot_trials`, the steps the GUI's Trials panel runs too).

Before each trial the robot goes to the start pose and the command waits for the operator: "Place the robot, then
Start trial k of N" — Enter starts it (``q`` ends the series for now). The recording (the board's forces and the
robot's goals, positions and currents; ``run_start`` naming the series and the trial) starts before the motion and
stops ``--post`` seconds after it; then the operator types the outcome (``t``raversed, ``f``ailed, ``a``borted) and a
note. Ctrl-C is STOP: the robot halts at once, the trial in progress is kept, marked aborted, and the command ends
(exit 130). The same command again (SHAPE.json may be left out: the series' own options are used) resumes the series
at the next trial — after a crash or a kill too: a trial cut short while recording is set aside and run again.

At the end: the trials' table, ``DIR/trials.csv`` and, when two or more trials were not aborted and their recordings
hold forces (``--cal``), the repeatability report of those trials in DIR (:mod:`app.cli.report`). Main thread; the
robot's bus thread only appends states to a list this thread drains.
"""

from __future__ import annotations

import argparse
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import Any, TextIO

from app.cli._robot import lab_config, port_from, reworded, robot_config, start_controller
from app.cli.record import STOP_SIGNALS, StopSignal
from app.cli.report import align_options, make_report, print_summary
from app.core import live_session
from app.core.errors import BoardSilentError, RepeatabilityError, TrialsError
from app.core.forces_pipeline import ForcesPipeline
from app.core.live_session import LiveSession
from app.core.recording import open_recording
from app.core.robot_trials import (
    ASK_OUTCOME,
    KEPT_ABORTED,
    OUTCOMES,
    RobotSeries,
    RobotSeriesOptions,
    start_motion,
    trial_motion,
    trial_shape,
)
from app.core.trials import SERIES_FILE
from devices import factory
from devices.board import BoardReader
from devices.config import load_config
from devices.errors import DeviceError, ServoHardwareError
from models.health import HealthMonitor

PUMP_WAIT_S = 0.05
EXIT_INTERRUPTED = 130
OUTCOME_KEYS = {"t": "traversed", "f": "failed", "a": "aborted", **{o: o for o in OUTCOMES}}


class _EndOfInput(Exception):  # noqa: N818 - this module's own control flow, never raised to a caller
    """Standard input ended while the command waited for the operator."""


def _say(text: str) -> None:
    print(text, flush=True)


class OperatorLines:
    """Lines the operator types, read on a thread of their own (a blocked read never stops the main thread from
    keeping the board and the robot's states drained); the thread ends at the end of input (_EndOfInput)."""

    def __init__(self, stream: TextIO) -> None:
        self._lines: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._read, args=(stream,), name="operator-input", daemon=True)
        self._thread.start()

    def _read(self, stream: TextIO) -> None:
        while True:
            line = stream.readline()
            if not line:
                self._lines.put(None)
                return
            self._lines.put(line.rstrip("\r\n"))

    def ask(self, question: str, pump: Callable[[], None]) -> str:
        """Show ``question`` and wait for a line, pumping the devices meanwhile; EndOfInput at the end of input (_EndOfInput)."""
        print(question, end="", flush=True)
        while True:
            try:
                line = self._lines.get_nowait()
            except queue.Empty:
                pump()
                continue
            if line is None:
                self._lines.put(None)  # every later question ends the same way
                print(flush=True)
                raise _EndOfInput
            return line


class SeriesDevices:
    """The robot's control loop and the board's reader around one live session, pumped by the main thread."""

    def __init__(self, args: argparse.Namespace) -> None:
        named = lab_config(args)
        self.robot = robot_config(args)  # --robot, else the config's [robot] port (exit 2 without either)
        daq = port_from(args, "daq", "board", named)
        self.config = named if named is not None else load_config()
        self.board = replace(self.config.board, port=daq)
        if factory.is_sim(self.board.port):
            factory.sim_lab(replace(self.config, board=self.board))  # the simulated board follows the channel list
        pipeline = None
        if args.cal:
            pipeline = ForcesPipeline(self.board.channel_names)
            pipeline.load_calibration(args.cal)
        self.live = LiveSession(self.board, pipeline=pipeline,
                                health=HealthMonitor(self.board.n_channels, self.board.rate_hz))
        self._states: list[Any] = []
        self._lock = threading.Lock()
        self.reader = BoardReader(self.board, on_status=self.live.post_status)
        self.controller: Any = None

    def _on_state(self, state: Any) -> None:  # the robot's bus thread: keep it short
        with self._lock:
            self._states.append(state)

    def open(self) -> None:
        """Start the board's reader (waiting for its first frame) and the robot's control loop."""
        self.reader.start()
        if not self.reader.wait_for_frames(1, live_session.NO_FRAMES_TIMEOUT_S):
            raise BoardSilentError(f"no frames from the board on {self.board.port} in "
                                   f"{live_session.NO_FRAMES_TIMEOUT_S:g} s: check that it is powered and streaming")
        self.controller = start_controller(self.robot, on_state=self._on_state)

    def close(self) -> None:
        if self.controller is not None:
            self.controller.close()
        self.reader.close()

    def pump(self) -> None:
        """One turn: the board's new frames through the live session (recorded while a recording runs), the robot's
        states into it, the link's statuses and counters."""
        for status in self.live.pending_statuses():
            if status.state in live_session.TOLD_STATES:
                _say(f"board: {status.message}")
        self.reader.wait_for_frames(1, PUMP_WAIT_S)
        block = self.reader.read_block()
        if block is not None:
            self.live.process_block(block)
        with self._lock:
            states, self._states = self._states, []
        self.live.add_robot_states(states)
        warning = self.live.handle_stats(self.reader.stats)
        if warning:
            _say(f"board: {warning}")

    def move(self, source: Any, name: str) -> tuple[str, str]:
        """Play ``source`` to its end (pumping meanwhile): (exit status, reason) — ``success``; ``abort`` when it
        was stopped; ``fail`` with the fault. Ctrl-C stops the robot at once (STOP) and passes on."""
        future = self.controller.play(source, name)
        try:
            while not future.done():
                self.pump()
        except KeyboardInterrupt:
            self.controller.emergency_stop()
            raise
        try:
            outcome = future.result()
        except ServoHardwareError as exc:
            return "fail", str(reworded(exc, "motion stopped"))
        except (DeviceError, ValueError, OSError) as exc:
            return "fail", " ".join(str(exc).split())
        return ("success", "") if outcome == "finished" else ("abort", f"{name} {outcome}")

    def wait(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pump()


def series_options(args: argparse.Namespace) -> RobotSeriesOptions:
    """The options of the command line, over the stored series' (a resume) where an option is not given."""
    stored = None
    if (Path(args.out) / SERIES_FILE).exists():
        stored = RobotSeries.open(args.out, recover=False).options
    if args.shape is None and stored is None:
        raise ValueError(f"sensnake trials needs SHAPE.json (or --out a folder holding a series to resume; {args.out} "
                         "holds none)")
    if args.trials is None and stored is None:
        raise ValueError("sensnake trials needs --trials N")
    given = {"shape": str(Path(args.shape).resolve()) if args.shape else None, "trials": args.trials,
             "mode": args.mode, "speed_rad_s": args.speed, "shifts": args.shifts, "repeat": args.repeat,
             "time_scale": args.time_scale, "start": str(Path(args.start).resolve()) if args.start else None,
             "scene": args.scene, "tail_load_n": args.tail_load, "post_s": args.post, "note": args.note}
    base = stored if stored is not None else RobotSeriesOptions(shape="", trials=1)
    values = {f.name: given[f.name] if given.get(f.name) is not None else getattr(base, f.name)
              for f in fields(RobotSeriesOptions)}
    return RobotSeriesOptions(**values)


def run(args: argparse.Namespace) -> int:
    options = series_options(args)
    options.check()
    report_options = align_options(args)  # refused before anything moves when they are bad
    shape = trial_shape(options)
    devices = SeriesDevices(args)
    trial_motion(options, devices.robot, shape)  # a shape the robot cannot play is refused before anything moves
    start_motion(options, devices.robot)
    series = RobotSeries.start(args.out, options)
    for line in series.recovered:
        _say(f"resumed: {line}")
    lines = OperatorLines(sys.stdin)
    interrupt = signal.getsignal(signal.SIGINT)
    previous = {s: signal.signal(s, _raise_stop) for s in STOP_SIGNALS}
    try:
        devices.open()
        _say(f"series {series.series_uid} in {series.folder}: {series.summary()}. Ctrl-C stops the robot at once "
             "(STOP): the trial in progress is kept, marked aborted")
        code = _run_series(series, devices, lines, shape)
    finally:
        devices.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
        signal.signal(signal.SIGINT, interrupt)  # ignored while a stopped trial's file was closed
    _print_table(series)
    if code == 0 and series.complete:
        _report(series, report_options)
    return code


def _raise_stop(signum: int, _frame: object) -> None:
    raise StopSignal(signum)


def _run_series(series: RobotSeries, devices: SeriesDevices, lines: OperatorLines, shape: Any) -> int:
    options = series.options
    try:
        pending = series.pending_outcome()
        if pending is not None:
            _ask_outcome(series, pending, lines, devices)
        while (k := series.next_trial()) is not None:
            _say(f"trial {k + 1} of {options.trials}: the robot goes to the start pose")
            status, reason = devices.move(*start_motion(options, devices.robot))
            if status != "success":
                _say(f"the start pose was not reached ({reason}); place the robot in it by hand")
            answer = lines.ask(f"{series.prompt(k)}: press Enter (q ends the series for now) ", devices.pump)
            if answer.strip().lower() in ("q", "quit"):
                _say(f"series paused before trial {k + 1}: the same command goes on from there")
                return 0
            if not _run_trial(series, k, devices, shape):
                _say(f"sensnake trials: stopped; {series.summary()}; the same command resumes the series")
                return EXIT_INTERRUPTED
            if series.pending_outcome() == k:
                _ask_outcome(series, k, lines, devices)
    except _EndOfInput:
        _say("standard input ended: the series stops here; the same command goes on from where it is")
        return 0
    except KeyboardInterrupt as stop:
        devices.controller.emergency_stop()
        _say(f"sensnake trials: {'interrupted' if not isinstance(stop, StopSignal) else f'terminated by {stop}'}; "
             f"the robot was stopped. {series.summary()}; the same command resumes the series")
        return EXIT_INTERRUPTED
    _say(f"series complete: {series.summary()}")
    return 0


def _run_trial(series: RobotSeries, k: int, devices: SeriesDevices, shape: Any) -> bool:
    """Record trial ``k``: False when Ctrl-C stopped it (kept, marked aborted)."""
    options = series.options
    live = devices.live
    run_start = series.run_start(k, config_text=devices.config.source_text,
                                 calibration_json=live.recording_calibration_json(), shape=shape)
    path = series.begin(k)
    live.start_recording(path, devices.config.source_text, with_robot=True, n_joints=devices.robot.n_joints,
                         run_start=run_start)
    source, name = trial_motion(options, devices.robot, shape)
    _say(f"trial {k + 1} of {options.trials}: recording {path.name}, playing {name}")
    try:
        status, reason = devices.move(source, name)
        if status == "success":
            devices.wait(options.post_s)  # the recording runs on after the motion
    except KeyboardInterrupt:
        for s in (signal.SIGINT, *STOP_SIGNALS):  # a second signal must not cut the file's close short
            signal.signal(s, signal.SIG_IGN)
        live.stop_recording("abort", "STOP (Ctrl-C)")
        if series.ended(k, "abort", "STOP (Ctrl-C)") == KEPT_ABORTED:
            _say(f"trial {k + 1} stopped: kept in {path.name}, marked aborted")
        else:
            _say(f"trial {k + 1} stopped before anything was recorded: it runs again")
        return False
    recorder = live.stop_recording(status, reason)
    if recorder is not None and recorder.error:
        _say(f"sensnake trials: warning: {recorder.error}")
    step = series.ended(k, status, reason)
    if step == ASK_OUTCOME:
        _say(f"trial {k + 1} recorded: {path.name}")
    elif step == KEPT_ABORTED:
        _say(f"trial {k + 1} ended early ({reason}): kept, marked aborted")
    else:
        _say(f"trial {k + 1} ended ({reason or 'no data'}) before anything was recorded: it runs again")
    return True


def _ask_outcome(series: RobotSeries, k: int, lines: OperatorLines, devices: SeriesDevices) -> None:
    while True:
        answer = lines.ask(f"outcome of trial {k + 1}: [t]raversed, [f]ailed, [a]borted? ", devices.pump)
        outcome = OUTCOME_KEYS.get(answer.strip().lower())
        if outcome is not None:
            break
        _say(f"{answer.strip()!r} is not an outcome: t, f or a")
    note = lines.ask("note (Enter for none): ", devices.pump)
    series.mark(k, outcome, note)
    _say(f"trial {k + 1}: {outcome}" + (f" ({note.strip()})" if note.strip() else ""))


def _print_table(series: RobotSeries) -> None:
    print(f"{'trial':>5} {'outcome':<10} {'status':<8} {'duration s':>10}  file  note")
    for row in series.rows():
        duration = row["duration_s"]
        shown = f"{duration:10.1f}" if isinstance(duration, float) and duration == duration else f"{'':>10}"
        print(f"{row['trial'] + 1:5d} {row['outcome'] or '—':<10} {row['exit_status'] or row['state']:<8} {shown}  "
              f"{row['file']}  {row['note']}")
    print(f"{series.summary()}; trials.csv in {series.folder}")


def _report(series: RobotSeries, options: Any) -> None:
    """The repeatability report of the trials that were not aborted, when their recordings hold forces."""
    paths = series.done_paths()
    if len(paths) < 2:
        _say(f"no repeatability report: {len(paths)} trial(s) not aborted, it needs 2 or more")
        return
    try:
        without = [p.name for p in paths if open_recording(p).forces_n is None]
    except (OSError, ValueError) as exc:
        _say(f"no repeatability report: {exc}")
        return
    if without:
        _say(f"no repeatability report: {', '.join(without)} hold no forces (give --cal CAL.json; 'sensnake estimate "
             "REC.h5 --cal CAL.json --out NEW.h5' adds them to a recording)")
        return
    try:
        result = make_report([str(p) for p in paths], series.folder, options)
    except (RepeatabilityError, TrialsError) as exc:
        _say(f"no repeatability report: {exc}")
        return
    print_summary(result, series.folder)
