"""``sensnake calibrate --rig PORT --daq PORT --sensor NAME [--forces 1.75,3,4,5.25] [--trials 3] [--hold 370]
[--rest S] [--rate 6] [--baseline S] [--ramp S] [--area M2] [--condition N[@FORCE]] [--physics FILE]
[--time-scale X] [--config FILE] [--resume SESSION_DIR] [--save-anyway] --out CAL.json``: the calibration protocol
on the rig, unattended.

The protocol is checked before anything moves (:func:`app.core.rig_protocol.check_protocol`). Then the rig finds the
contact, runs the optional conditioning (``--condition N[@FORCE]``: N load/unload cycles at FORCE, default the top
force; not recorded as trials, logged in the session's ``conditioning.json``; a resumed session does not repeat a
conditioning that finished), and every trial (unloaded rest, unloaded baseline, loading ramp, hold) is written as a SPEC §3.1 CSV into a
session folder beside ``CAL.json`` as soon as it completes (:class:`app.core.rig_protocol.ProtocolRunner`, the same
runner as the Calibration tab). A progress line on stderr says where the run is and how long is left. At the end
the trials are fitted with the lab's readout circuit (:mod:`app.core.calibration_fit`) and the sensor is written into
``CAL.json``, unless the fit is degenerate or non-physical: then nothing is saved, the problems are named and the
command exits 1 (``--save-anyway`` saves it, still naming them).

Ctrl-C (or SIGTERM/SIGHUP) stops the run: the load comes off, finished trials stay in the session folder, exit 130.
``--resume SESSION_DIR`` continues a session cut short by Ctrl-C, a crash or ``kill -9``: its protocol comes from the
folder, finished trials are kept and the interrupted one is redone.

``--time-scale X`` only with simulated devices (``sim`` ports): the simulated lab's clock runs X times faster than the
wall clock and the protocol follows it, so a 370 s hold takes 370/X s.

``--sensors S02B,S03B,…`` (names or patterns of the board's channels: ``'S*B'`` is every bottom sensor) runs the
protocol on each sensor in turn, in one batch folder beside ``CAL.json`` (``batch.json``, then one session folder per
sensor); each sensor is fitted and saved into ``CAL.json`` as soon as its trials are done, so a long batch cut short
loses at most the sensor in progress. On the simulated lab the probe moves to each sensor by itself (as
``--sensor`` moves it to that one); on a real rig the command waits for Enter while you move the probe. A sensor whose
fit is refused is named and the batch goes on (exit 1 at the end). ``--resume BATCH_DIR`` continues a batch: the
saved and refused sensors are skipped, the interrupted one resumes its session, the rest run.

Threads: the rig runs on a worker thread (it owns the rig's port); a second drains the board into the runner's
feed; the main thread prints progress and handles Ctrl-C.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.cli.fit import _physics, print_report
from app.core import calfiles, calibration_fit
from app.core.rig_protocol import (
    ABORTED,
    COMPLETED,
    PAPER_FORCES_N,
    SESSION_FILE,
    ConductanceFeed,
    Outcome,
    Progress,
    ProtocolRunner,
    ProtocolSettings,
    RunOutcome,
    check_protocol,
    finished_trials,
    lab_times_from_seq,
    parse_forces,
    read_conditioning,
    read_session,
    session_folder,
)
from devices import factory
from devices.board import BoardReader
from devices.config import LabConfig, load_config
from devices.errors import DeviceError
from devices.rig import CalibrationRig
from devices.toml_files import read_state_file

if TYPE_CHECKING:  # pragma: no cover
    from devices.factory import SimPorts

EXIT_REFUSED = 1
EXIT_INTERRUPTED = 130
BATCH_FILE = "batch.json"  # a --sensors batch's folder: its sensors, protocol and each sensor's outcome
SAVED, REFUSED = "saved", "refused"
PROGRESS_INTERVAL_S = 0.5  # wall seconds between progress lines
# rest 300 s: the creep (τ ~ 10² s) of one trial must fade before the next starts (a fit assumes a rested sensor)
DEFAULTS = {"trials": 3, "hold": 370.0, "rest": 300.0, "rate": 6.0, "baseline": 3.0, "ramp": 2.0}
PROTOCOL_OPTIONS = ("forces", "trials", "hold", "rest", "rate", "baseline", "ramp", "sensor", "area", "condition")


STOP_SIGNALS = tuple(s for s in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None))
                     if s)


def run_until_done(work: Callable[[], Outcome], abort: Callable[[str], None], name: str) -> tuple[Outcome | None, str]:
    """Run ``work`` on a thread called ``name`` and wait for its outcome; Ctrl-C, SIGTERM and SIGHUP (unless ignored,
    e.g. under nohup) call ``abort("interrupted (WHY)")`` and the outcome is still waited for (the load comes off
    first). Returns (the outcome, or None if ``work`` raised; WHY: "Ctrl-C", "SIGTERM", "SIGHUP" or "" if none came).

    The signals set a flag instead of raising KeyboardInterrupt in the waiting thread: on Python 3.11 a
    KeyboardInterrupt that lands inside ``Thread.join(timeout)`` marks the still-running thread as ended
    (CPython's bpo-45274 handler releases the thread's own lock), so the next ``join()`` returned at once and a run
    stopped on a busy machine reported "the rig thread ended without an outcome" while the rig was still releasing."""
    result: list[Outcome] = []
    finished = threading.Event()
    why: list[str] = []

    def target() -> None:
        try:
            result.append(work())
        finally:
            finished.set()

    def on_signal(signum: int, _frame: object) -> None:
        why.append("Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name)
        abort(f"interrupted ({why[0]})")

    worker = threading.Thread(target=target, name=name, daemon=True)
    previous = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        worker.start()
        while not finished.wait(0.2):
            pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return (result[0] if result else None), (why[0] if why else "")


def _config(args: argparse.Namespace) -> LabConfig:
    config = load_config(args.config) if args.config else load_config(None)
    return config.with_ports(board=args.daq, rig=args.rig)


def _settings(args: argparse.Namespace, config: LabConfig) -> ProtocolSettings:
    if args.resume:
        given = [f"--{name}" for name in PROTOCOL_OPTIONS if getattr(args, name) is not None]
        if given:
            raise ValueError(f"--resume continues the session's own protocol: drop {', '.join(given)}")
        return read_session(args.resume)
    forces = parse_forces(args.forces) if args.forces is not None else PAPER_FORCES_N
    value = {key: getattr(args, key) if getattr(args, key) is not None else default
             for key, default in DEFAULTS.items()}
    cycles, condition_force = parse_condition(args.condition) if args.condition is not None else (0, 0.0)
    return ProtocolSettings(forces_n=forces, trials_per_force=int(value["trials"]), hold_s=value["hold"],
                            sample_rate_hz=value["rate"], rest_s=value["rest"], baseline_s=value["baseline"],
                            ramp_s=value["ramp"], sensor=(args.sensor or config.rig.sensor).strip(),
                            area_m2=args.area if args.area is not None else config.rig.area_m2,
                            condition_cycles=cycles, condition_force_n=condition_force)


def parse_condition(text: str) -> tuple[int, float]:
    """``--condition N[@FORCE]`` → (cycles, force N; 0.0: the protocol's top force); ValueError naming the problem."""
    count, _, force = text.strip().partition("@")
    try:
        cycles = int(count)
    except ValueError:
        raise ValueError(f"--condition {text!r}: the number of cycles must be a whole number (e.g. 5 or 5@6)") from None
    if cycles < 0:
        raise ValueError(f"--condition {text!r}: the number of cycles must be 0 (off) or more")
    if not force.strip():
        return cycles, 0.0
    try:
        value = float(force.strip().removesuffix("N").strip())
    except ValueError:
        raise ValueError(f"--condition {text!r}: {force!r} is not a force in N (e.g. 5@6)") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"--condition {text!r}: the conditioning force must be positive")
    return cycles, value


def _install_lab(config: LabConfig, time_scale: float | None) -> tuple[Any, SimPorts | None]:
    """The simulated lab behind ``sim`` ports, from this config, at ``time_scale``. Returns (the lab installed or
    None with real ports, the lab it replaced, to put back)."""
    uses_sim = factory.is_sim(config.rig.port) or factory.is_sim(config.board.port)
    if time_scale is not None:
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ValueError(f"--time-scale must be a positive number, got {time_scale!r}")
        if not (factory.is_sim(config.rig.port) and factory.is_sim(config.board.port)):
            raise ValueError("--time-scale only runs the simulated lab faster: use it with --rig sim --daq sim")
    if not uses_sim:
        return None, None
    return factory.start_sim_lab(config, speed=time_scale or 1.0)


class _ProgressLine:
    """One line on stderr, rewritten in place (a terminal) or printed every few seconds (a log file)."""

    def __init__(self, n_trials: int, time_scale: float = 1.0, prefix: str = "") -> None:
        self.n_trials = n_trials
        self.prefix = prefix  # which sensor of a batch ("S03B (2/12): ")
        self.time_scale = time_scale  # the runner's times are the lab's; the user waits wall seconds
        self._last = 0.0
        self._tty = sys.stderr.isatty()
        self._lock = threading.Lock()
        self._width = 0
        self._phase: tuple[int, str] | None = None

    def __call__(self, progress: Progress) -> None:
        if progress.phase == "redo":  # why a trial is run again: a line of its own, kept on screen
            with self._lock:
                if self._tty and self._width:
                    sys.stderr.write("\n")
                    self._width = 0
                sys.stderr.write(f"{self.prefix}{progress.message}\n")
                sys.stderr.flush()
            return
        now = time.monotonic()
        interval = PROGRESS_INTERVAL_S if self._tty else 5.0
        phase = (progress.trial, progress.phase)
        if (progress.phase not in ("done", "contact", "conditioning") and now - self._last < interval
                and phase == self._phase):
            return
        self._last, self._phase = now, phase
        left = _duration(progress.time_left_s / self.time_scale)
        if progress.trial >= 0 and progress.phase not in ("done",):
            text = (f"trial {progress.trial + 1}/{self.n_trials} {progress.force_n:g} N r{progress.repeat}: "
                    f"{progress.phase} {progress.elapsed_s:5.0f} s — about {left} left")
        else:
            text = progress.message
        text = self.prefix + text
        with self._lock:
            if self._tty:
                pad = max(0, self._width - len(text))
                sys.stderr.write("\r" + text + " " * pad)
                self._width = len(text)
            else:
                sys.stderr.write(text + "\n")
            sys.stderr.flush()

    def end(self) -> None:
        if self._tty and self._width:
            sys.stderr.write("\n")
            self._width = 0


def _duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds >= 3600:
        return f"{seconds / 3600:.1f} h"
    if seconds >= 120:
        return f"{seconds / 60:.0f} min"
    return f"{seconds:.0f} s"


def _drain(reader: BoardReader, feed: ConductanceFeed, channel: int, stop: threading.Event,
           lab_rate_hz: float | None) -> None:
    """Board → feed. On a simulated lab (``lab_rate_hz``, the board's frame rate) the samples go on the lab's clock."""
    while not stop.is_set():
        if not reader.wait_for_frames(1, 0.1):
            continue
        block = reader.read_block()
        if block is None or not len(block):
            continue
        if lab_rate_hz is not None:
            times = lab_times_from_seq(block.seq, lab_rate_hz)
            feed.push(times, block.conductance_s[:, channel], times)
        else:
            feed.push(block.host_time_s, block.conductance_s[:, channel], block.board_time_s)


def _run_protocol(config: LabConfig, settings: ProtocolSettings, folder: Path, time_scale: float,
                  done: dict[int, Path], prefix: str = "") -> Outcome:
    """Run the protocol on the rig (worker thread) while the board is drained (second thread); Ctrl-C aborts.
    ``prefix`` starts each progress line (a batch names the sensor)."""
    channel = config.board.channel_names.index(settings.sensor)
    sim = factory.is_sim(config.rig.port) and factory.is_sim(config.board.port)
    lab_clock = factory.sim_lab().clock.now if sim else None
    reader = BoardReader(config.board)
    feed = ConductanceFeed(time_scale=1.0 if sim else time_scale, source_alive_s=reader.newest_frame_host_s)
    line = _ProgressLine(settings.n_trials, time_scale, prefix)
    runner = ProtocolRunner(settings, feed, folder, on_progress=line, time_scale=time_scale, done=done,
                            clock=lab_clock, simulated_board=factory.is_sim(config.board.port))
    reader.start()  # PortOpenError (an OSError) names the port
    stop_drain = threading.Event()
    drain = threading.Thread(target=_drain, args=(reader, feed, channel, stop_drain,
                                                          config.board.rate_hz if sim else None), name="calibrate-board",
                             daemon=True)
    drain.start()

    def work() -> Outcome:
        rig = CalibrationRig(config.rig, interrupt=runner.stop_requested)
        try:
            rig.open()
        except (DeviceError, OSError, ValueError) as exc:
            return Outcome(RunOutcome.FAILED, f"cannot open the calibration rig on {config.rig.port}: {exc}", folder)
        try:
            return runner.run(rig)
        finally:
            with contextlib.suppress(DeviceError, OSError):
                rig.close()

    try:
        result, interrupted = run_until_done(work, runner.abort, "calibrate-rig")
    finally:
        stop_drain.set()
        drain.join()
        reader.close()
        line.end()
    outcome = result or Outcome(RunOutcome.FAILED, "the rig thread ended without an outcome", folder)
    if interrupted and outcome.status == ABORTED:
        outcome = replace(outcome, status=RunOutcome.INTERRUPTED)
    return outcome


def _what_the_sensor_read(args: argparse.Namespace, settings: Any) -> tuple[Any, Any]:
    """What predicts this sensor's reading at the top force (for check_protocol): its calibration in ``--out`` if it
    has one, else the highest reading of a trial of the session being resumed, else nothing (a typical sensor)."""
    from models.sls_model import SLSParams

    if Path(args.out).exists():
        document = calfiles.read_calibration(args.out)
        entry: dict | None = None
        try:
            entry = calfiles.sensor_entry(document, settings.sensor, "sls", str(args.out))
            physics = calfiles.physics_from_calibration(document, str(args.out))
        except ValueError:
            entry = None  # no usable earlier calibration of this sensor: try the session's trials
        else:
            if entry.get("degenerate") or entry.get("refusal_reasons"):
                entry = None  # a fit that was not fit to use predicts nothing
        if entry is not None:
            return (SLSParams.from_dict(entry["sls"]), float(entry["area_m2"]), physics), None
    if args.resume:
        best: tuple[float, float] | None = None
        for path in finished_trials(Path(args.resume), settings).values():
            try:
                trial = calfiles.read_trial_csv(path)
            except (ValueError, OSError):
                continue
            force = float(np.nanmax(trial.force_n))
            if best is None or force > best[0]:
                best = (force, float(np.nanmax(trial.conductance_s)))
        return None, best
    return None, None


def _write_simulated_truth(args: argparse.Namespace, config: LabConfig) -> int:
    """``--simulated-truth``: the simulated lab's sensors' true calibration into a new file (never over one)."""
    import json

    out = Path(args.out)
    if out.exists() or out.is_symlink():
        raise ValueError(f"--out {args.out} already exists: --simulated-truth writes a new file only")
    document = factory.simulated_sensors_calibration(config)
    calfiles.write_atomically(out, lambda handle: json.dump(document, handle, indent=1))
    print(f"wrote {len(document['sensors'])} simulated sensors to {args.out}: {factory.SIMULATED_TRUTH_NOTE}")
    return 0


def run(args: argparse.Namespace) -> int:
    config = _config(args)
    if getattr(args, "simulated_truth", False):
        return _write_simulated_truth(args, config)
    if getattr(args, "sensors", None) is not None or (args.resume and (Path(args.resume) / BATCH_FILE).is_file()):
        return _run_batch(args, config)
    settings = _settings(args, config)
    if Path(args.out).exists():
        calfiles.read_calibration(args.out)  # refuse an unknown format/version before the rig moves
    if not Path(args.out).resolve().parent.is_dir():
        raise ValueError(f"--out {args.out}: folder {Path(args.out).resolve().parent} does not exist")
    check = check_protocol(settings, config.rig, config.board, *_what_the_sensor_read(args, settings))
    if not check.ok:
        raise ValueError("protocol refused: " + "; ".join(check.errors))
    for text in check.warnings:
        print(f"sensnake calibrate: warning: {text}", file=sys.stderr)
    physics = _physics(argparse.Namespace(physics=args.physics, out=args.out))
    if args.resume:
        folder = Path(args.resume)
        done = finished_trials(folder, settings)
        print(f"sensnake calibrate: resuming {folder}: {len(done)} of {settings.n_trials} trial(s) kept",
              file=sys.stderr)
    else:
        folder = session_folder(Path(args.out).resolve().parent, settings.sensor)
        done = {}
    time_scale = args.time_scale or 1.0
    installed, previous_lab = _install_lab(config, args.time_scale)
    try:
        if installed is not None:
            _move_simulated_probe(installed, settings.sensor)
        if len(done) < settings.n_trials:
            conditioning = (settings.condition_cycles and not done
                            and not (read_conditioning(folder) or {}).get("finished"))
            total = ((settings.n_trials - len(done)) * (settings.trial_duration_s() + settings.rest_s)
                     + (settings.conditioning_duration_s() if conditioning else 0.0)) / time_scale
            first = (f"{settings.condition_cycles} conditioning cycle(s) at {settings.conditioning_force_n:g} N, then "
                     if conditioning else "")
            print(f"sensnake calibrate: session {folder}: {first}{settings.n_trials - len(done)} trial(s) of "
                  f"{settings.sensor} at {', '.join(f'{f:g}' for f in settings.forces_n)} N, about "
                  f"{_duration(total)}", file=sys.stderr)
            outcome = _run_protocol(config, settings, folder, time_scale, done)
            if outcome.status != COMPLETED:
                print(f"sensnake calibrate: {outcome.message}", file=sys.stderr)
                print(f"sensnake calibrate: continue with: {_resume_command(args, folder)}", file=sys.stderr)
                return EXIT_INTERRUPTED if outcome.status == "interrupted" else EXIT_REFUSED
    finally:
        if installed is not None:
            factory.install_sim_lab(previous_lab)
            installed.close()
    return 0 if _fit_and_save(args, config, settings, folder, physics) else EXIT_REFUSED


def _resume_command(args: argparse.Namespace, folder: Path) -> str:
    return (f"sensnake calibrate --resume {folder} --out {args.out}"
            + (f" --config {args.config}" if args.config else "")
            + (f" --rig {args.rig}" if args.rig else "") + (f" --daq {args.daq}" if args.daq else "")
            + (f" --time-scale {args.time_scale:g}" if args.time_scale else ""))


def _move_simulated_probe(lab: Any, sensor: str) -> None:
    """The simulated lab's probe onto ``sensor`` (what a person does on the real rig before starting)."""
    move = getattr(lab, "move_rig_to", None)
    if callable(move) and getattr(lab, "rig_sensor", sensor) != sensor:
        move(sensor)
        print(f"sensnake calibrate: simulated lab: the probe moves onto {sensor}", file=sys.stderr)


def _fit_and_save(args: argparse.Namespace, config: LabConfig, settings: ProtocolSettings, folder: Path,
                  physics: Any) -> bool:
    """Fit the session's trials and save the sensor into ``--out``; False (nothing saved, the problems named) when
    the fit is not fit to use and ``--save-anyway`` was not given."""
    paths = [p for _, p in sorted(finished_trials(folder, settings).items())]
    trials = calibration_fit.read_trials(paths)
    fit = calibration_fit.fit_trials(trials, settings.sensor, settings.area_m2, physics, config.board,
                                     settings.fit_window_s())
    _print(fit, folder)
    if fit.problems and not args.save_anyway:
        for text in fit.problems:
            print(f"sensnake calibrate: refused: {text}", file=sys.stderr)
        print(f"sensnake calibrate: error: the fit of {settings.sensor} is not fit to use and was NOT saved to "
              f"{args.out}; the trials are in {folder} (sensnake fit them again, or --save-anyway)", file=sys.stderr)
        return False
    calibration_fit.save(args.out, fit, physics, config.board)
    for text in fit.problems:
        print(f"sensnake calibrate: warning: saved although {text}", file=sys.stderr)
    print(f"wrote {settings.sensor} to {args.out} (trials in {folder})")
    return True


# -- several sensors: --sensors --------------------------------------------------------------------------------------
def expand_sensors(text: str, channels: tuple[str, ...]) -> tuple[str, ...]:
    """``--sensors`` (comma-separated names or fnmatch patterns of board channels) → the sensors, in the order
    given (a pattern's matches in the board's order), each once; ValueError naming what matches nothing."""
    import fnmatch

    names: list[str] = []
    for part in (p.strip() for p in text.replace(";", ",").split(",")):
        if not part:
            continue
        found = [c for c in channels if fnmatch.fnmatchcase(c, part)]
        if not found:
            raise ValueError(f"--sensors: {part!r} is not a channel of the board ({channels[0]} … {channels[-1]})")
        names.extend(c for c in found if c not in names)
    if not names:
        raise ValueError("--sensors: name at least one sensor (e.g. S02B,S03B, or 'S*B' for every bottom sensor)")
    return tuple(names)


def write_batch(folder: Path, sensors: tuple[str, ...], template: ProtocolSettings,
                outcomes: dict[str, str]) -> None:
    """The batch's ``batch.json``: its sensors in order, the protocol every one runs (``sensor`` aside) and each
    finished sensor's outcome (``saved`` or ``refused``), rewritten atomically after every sensor."""
    import json
    from dataclasses import asdict

    document = {"format": "sensnake-calibration-batch", "version": 1, "sensors": list(sensors),
                "protocol": asdict(template), "outcomes": dict(outcomes)}
    calfiles.write_atomically(folder / BATCH_FILE, lambda handle: handle.write(json.dumps(document, indent=2) + "\n"))


def read_batch(folder: str | Path) -> tuple[tuple[str, ...], ProtocolSettings, dict[str, str]]:
    """(sensors, protocol, outcomes so far) of a batch folder; ValueError naming the problem."""
    import json

    path = Path(folder) / BATCH_FILE
    try:
        document = json.loads(read_state_file(path, "calibration batch"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read the batch: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != "sensnake-calibration-batch":
        raise ValueError(f"{path}: not a calibration batch file")
    if document.get("version") != 1:
        raise ValueError(f"{path}: batch version {document.get('version')!r} is not known (expected 1)")
    try:
        protocol = dict(document["protocol"])
        protocol["forces_n"] = tuple(protocol["forces_n"])
        known = set(ProtocolSettings.__dataclass_fields__)
        template = ProtocolSettings(**{k: v for k, v in protocol.items() if k in known})
        sensors = tuple(str(s) for s in document["sensors"])
        outcomes = {str(k): str(v) for k, v in dict(document.get("outcomes") or {}).items()}
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    return sensors, template, outcomes


def _wait_for_the_probe(sensor: str, config: LabConfig) -> None:
    """A real rig: the operator puts ``sensor``'s segment under the probe and presses Enter. ValueError when nobody
    can (standard input closed)."""
    print(f"sensnake calibrate: put {sensor}'s segment on the rig's beam under the probe (rig on {config.rig.port}), "
          "cable slack, then press Enter (Ctrl-C stops)", file=sys.stderr, flush=True)
    if not sys.stdin.readline():
        raise ValueError(f"nobody to move the probe onto {sensor} (standard input is closed): on a real rig run "
                         "--sensors where you can press Enter, or one sensor at a time with --sensor")


def _run_batch(args: argparse.Namespace, config: LabConfig) -> int:
    """``--sensors`` (or ``--resume`` of a batch folder): every sensor's protocol, fit and save in turn."""
    if args.sensor is not None:
        raise ValueError("--sensor names one sensor, --sensors several: give one of them")
    if args.resume:
        if args.sensors is not None:
            raise ValueError("--resume continues the batch's own sensors: drop --sensors")
        given = [f"--{name}" for name in PROTOCOL_OPTIONS if getattr(args, name) is not None]
        if given:
            raise ValueError(f"--resume continues the batch's own protocol: drop {', '.join(given)}")
        folder = Path(args.resume)
        sensors, template, outcomes = read_batch(folder)
    else:
        sensors = expand_sensors(args.sensors, config.board.channel_names)
        template = _settings(argparse.Namespace(**{**vars(args), "sensor": sensors[0]}), config)
        folder, outcomes = None, {}
    if Path(args.out).exists():
        calfiles.read_calibration(args.out)  # refuse an unknown format/version before the rig moves
    if not Path(args.out).resolve().parent.is_dir():
        raise ValueError(f"--out {args.out}: folder {Path(args.out).resolve().parent} does not exist")
    errors: dict[str, list[str]] = {}  # text → the sensors it is said of (said once, naming them)
    warnings: dict[str, list[str]] = {}
    for sensor in sensors:
        settings = replace(template, sensor=sensor)
        check = check_protocol(settings, config.rig, config.board, *_what_the_sensor_read(args, settings))
        for found, texts in ((errors, check.errors), (warnings, check.warnings)):
            for text in texts:
                found.setdefault(text, []).append(sensor)

    def said(text: str, of: list[str]) -> str:
        return text if len(of) == len(sensors) > 1 else f"{', '.join(of)}: {text}"

    for text, of in warnings.items():
        print(f"sensnake calibrate: warning: {said(text, of)}", file=sys.stderr)
    if errors:
        raise ValueError("protocol refused: " + "; ".join(said(text, of) for text, of in errors.items()))
    physics = _physics(argparse.Namespace(physics=args.physics, out=args.out))
    if folder is None:
        folder = Path(args.out).resolve().parent / f"sensors_{time.strftime('%Y%m%d-%H%M%S')}"
        folder.mkdir()
        write_batch(folder, sensors, template, outcomes)
    time_scale = args.time_scale or 1.0
    left = [s for s in sensors if s not in outcomes]
    per_sensor_s = template.n_trials * (template.trial_duration_s() + template.rest_s) + (
        template.conditioning_duration_s() if template.condition_cycles else 0.0)
    print(f"sensnake calibrate: batch {folder}: {len(left)} of {len(sensors)} sensor(s) to do ({', '.join(left)}), "
          f"{template.n_trials} trial(s) each at {', '.join(f'{f:g}' for f in template.forces_n)} N, about "
          f"{_duration(len(left) * per_sensor_s / time_scale)}", file=sys.stderr)
    installed, previous_lab = _install_lab(config, args.time_scale)
    try:
        for k, sensor in enumerate(sensors):
            if sensor in outcomes:
                continue
            settings = replace(template, sensor=sensor)
            session = folder / sensor
            done = finished_trials(session, settings) if (session / SESSION_FILE).is_file() else {}
            if len(done) < settings.n_trials:
                if installed is not None:
                    _move_simulated_probe(installed, sensor)
                else:
                    try:
                        _wait_for_the_probe(sensor, config)
                    except KeyboardInterrupt:
                        print(f"\nsensnake calibrate: stopped before {sensor}; continue with: "
                              f"{_resume_command(args, folder)}", file=sys.stderr)
                        return EXIT_INTERRUPTED
                print(f"sensnake calibrate: {sensor} ({k + 1}/{len(sensors)}): session {session}, "
                      f"{settings.n_trials - len(done)} trial(s)", file=sys.stderr)
                outcome = _run_protocol(config, settings, session, time_scale, done,
                                        prefix=f"{sensor} ({k + 1}/{len(sensors)}) ")
                if outcome.status != COMPLETED:
                    print(f"sensnake calibrate: {sensor}: {outcome.message}", file=sys.stderr)
                    print(f"sensnake calibrate: continue with: {_resume_command(args, folder)}", file=sys.stderr)
                    return EXIT_INTERRUPTED if outcome.status == "interrupted" else EXIT_REFUSED
            outcomes[sensor] = SAVED if _fit_and_save(args, config, settings, session, physics) else REFUSED
            write_batch(folder, sensors, template, outcomes)
    finally:
        if installed is not None:
            factory.install_sim_lab(previous_lab)
            installed.close()
    refused = [s for s in sensors if outcomes.get(s) == REFUSED]
    saved = [s for s in sensors if outcomes.get(s) == SAVED]
    print(f"wrote {len(saved)} of {len(sensors)} sensor(s) to {args.out} (batch in {folder})")
    if refused:
        print(f"sensnake calibrate: error: NOT saved, the fit not fit to use: {', '.join(refused)} (their trials are "
              f"in {folder}; sensnake fit them again, or run them again with --sensors)", file=sys.stderr)
        return EXIT_REFUSED
    return 0


def _print(fit: calibration_fit.SessionFit, folder: Path) -> None:
    """The fit's per-trial table (as ``sensnake fit``) without its closing line, plus the means and unloaded level."""
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        print_report(fit.sensor, fit.calibration, str(folder))
    lines = buffer.getvalue().rstrip("\n").splitlines()
    if lines and lines[-1].startswith("wrote "):
        lines = lines[:-1]
    print("\n".join(lines))
    means = ", ".join(f"{f:g} N {m * 1e6:.1f} µS" for f, m in zip(fit.forces_n, fit.mean_conductance_s))
    print(f"  window {fit.window_s[0]:g}–{fit.window_s[1]:g} s means: {means}")
    if fit.unloaded_conductance_s is not None:
        print(f"  unloaded level {fit.unloaded_conductance_s * 1e6:.2f} µS; readout ceiling "
              f"{fit.readout_ceiling_s * 1e6:.0f} µS")
