"""A trial series on the robot: one condition run N times, each trial placed by hand and recorded on its own (the
robot's half of the paper's Fig. 7 experiments; the physics lab's is :mod:`app.core.trials`).

Every trial goes through the same steps, whichever face drives it (``sensnake trials``, app/cli/robot_trials.py;
the Trials panel, app/gui/trials_session.py):

1. the robot goes to the start pose (:func:`start_motion`: every joint straight, or a shape file's pose);
2. the operator places it and starts the trial (:meth:`RobotSeries.prompt`: "Place the robot, then Start trial k of
   N");
3. the recording starts before the motion (:meth:`RobotSeries.begin`: its ``run_start`` names the plan ``robot
   trials``, the series' uid and the trial's index) and stops ``post_s`` after it (:meth:`RobotSeries.ended`);
4. the operator marks the outcome — ``traversed``, ``failed`` or ``aborted``, with a note (:meth:`RobotSeries.mark`:
   written into the recording's ``run_stop``, which also gets the note).

STOP (Esc, the STOP button, Ctrl-C) or a fault ends a trial at once: it is kept and marked ``aborted`` with the
reason, and the series goes on at the next trial (the robot is not moved again until the operator asks).

The series' state is ``DIR/series.json``, rewritten atomically after every step, so a crash or a kill loses nothing
that was finished. :meth:`RobotSeries.open` resumes a folder: every marked trial is kept; a trial recorded but not yet
marked asks its outcome first; a trial cut short while recording (its file without ``run_stop``) is set aside —
renamed ``trial-<k>.cut-short.h5``, its ``run_stop`` saying so — and run again, as the physics lab's series runs a
trial cut short again. ``DIR/trials.csv`` (the physics lab's columns, then ``exit_status`` and ``note``) is rewritten
with every outcome. Qt-free; one thread at a time (the command line's main thread, or the GUI thread).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import uuid
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.calfiles import write_atomically
from app.core.catalog import index_quietly
from app.core.errors import TrialsError
from app.core.play import build_source
from app.core.run_documents import (
    EXIT_STATUSES,
    condition,
    read_documents,
    run_start_document,
    write_run_stop,
)
from app.core.shapes import Shape, read_shape
from app.core.trials import MAX_TRIALS, SERIES_FILE, TRIALS_COLUMNS
from devices.config import RobotConfig
from devices.toml_files import read_state_file
from models.trajectory import BlendTo, PlannedMotion

PLAN_NAME = "robot trials"
SERIES_FORMAT = "sensnake-trials"
OUTCOMES = ("traversed", "failed", "aborted")
ROBOT_TRIALS_COLUMNS = (*TRIALS_COLUMNS, "exit_status", "note")
MODES = ("follow", "keyframes")
START_SPEED_RAD_S = 0.2  # the move to the start pose (capped at the robot's max joint speed)
MAX_POST_S = 60.0
CUT_SHORT = "cut-short"

# A trial's state in the series file: its recording is being written, is closed with its outcome still to be
# marked, or is finished (marked).
RECORDING, RECORDED, DONE = "recording", "recorded", "done"
# What follows a trial's end (RobotSeries.ended).
ASK_OUTCOME, KEPT_ABORTED, NOT_RECORDED = "ask outcome", "kept aborted", "not recorded"


@dataclass(frozen=True)
class RobotSeriesOptions:
    """What every trial of a series shares, how many trials, and how long each recording runs on after the motion.
    ``shape``/``start``: shape files (absolute paths); ``start`` None is the straight pose."""

    shape: str
    trials: int
    mode: str = "follow"
    speed_rad_s: float = 0.034
    shifts: int | None = None
    repeat: int = 1
    time_scale: float = 1.0
    start: str | None = None
    scene: str = ""  # what the robot runs on, in the lab's words (paper_obstacle, flat, …): the condition's scene
    tail_load_n: float = 0.0
    post_s: float = 1.0
    note: str = ""

    def condition(self) -> dict[str, Any]:
        """The options a resumed series must share (the number of trials may grow; the note and the time recorded
        after the motion may change)."""
        return {k: v for k, v in asdict(self).items() if k not in ("trials", "note", "post_s")}

    def check(self) -> None:
        """TrialsError naming the option when one cannot be run."""
        if not 1 <= self.trials <= MAX_TRIALS:
            raise TrialsError(f"--trials must be 1 … {MAX_TRIALS}, got {self.trials}")
        if self.mode not in MODES:
            raise TrialsError(f"--mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if not (math.isfinite(self.post_s) and 0.0 <= self.post_s <= MAX_POST_S):
            raise TrialsError(f"--post must be 0 … {MAX_POST_S:g} s, got {self.post_s}")
        if not (math.isfinite(self.tail_load_n) and self.tail_load_n >= 0.0):
            raise TrialsError(f"--tail-load must be 0 N or more, got {self.tail_load_n}")
        if not (math.isfinite(self.speed_rad_s) and self.speed_rad_s > 0):
            raise TrialsError(f"--speed must be positive, got {self.speed_rad_s}")
        if self.repeat < 1:
            raise TrialsError(f"--repeat must be 1 or more, got {self.repeat}")


def start_pose(options: RobotSeriesOptions, robot: RobotConfig) -> np.ndarray:
    """The pose (rad, joint order) the robot goes to before each trial: the ``start`` shape's, else straight."""
    if options.start is None:
        return np.zeros(robot.n_joints)
    shape = read_shape(options.start)
    if shape.n_joints != robot.n_joints:
        raise TrialsError(f"the start pose {options.start} has {shape.n_joints} joints, the robot {robot.n_joints}")
    return np.asarray(shape.angles_rad, dtype=float)


def start_motion(options: RobotSeriesOptions, robot: RobotConfig) -> tuple[PlannedMotion, str]:
    """The move to the start pose, from wherever the robot is, at :data:`START_SPEED_RAD_S`."""
    speed = min(START_SPEED_RAD_S, robot.max_joint_speed_rad_s)
    return BlendTo(start_pose(options, robot), speed, rate_hz=robot.control_rate_hz), "start pose"


def trial_shape(options: RobotSeriesOptions) -> Shape:
    return read_shape(options.shape)


def trial_motion(options: RobotSeriesOptions, robot: RobotConfig, shape: Shape | None = None
                 ) -> tuple[PlannedMotion, str]:
    """The trial's motion (:func:`app.core.play.build_source`, what ``sensnake play`` and the Gait tab run) and its
    name; ValueError with a readable message before anything moves."""
    shape = shape if shape is not None else trial_shape(options)
    source = build_source(shape, robot, options.mode, options.speed_rad_s, options.time_scale, options.shifts,
                          options.repeat)
    return source, f"{options.mode} {shape.name or Path(options.shape).stem}"


def trial_file(k: int) -> str:
    return f"trial-{k:03d}.h5"


def _plain_options(stored: Mapping[str, Any], trials: int, note: str, post_s: float) -> RobotSeriesOptions:
    known = {f.name for f in fields(RobotSeriesOptions)}
    values = {k: v for k, v in stored.items() if k in known}
    return RobotSeriesOptions(**{**values, "trials": trials, "note": note, "post_s": post_s})


class RobotSeries:
    """A series' folder and its state; see the module docstring. Make one with :meth:`start` or :meth:`open`."""

    def __init__(self, folder: Path, options: RobotSeriesOptions, series_uid: str, trials: list[dict[str, Any]],
                 set_aside: list[str]) -> None:
        self.folder = folder
        self.options = options
        self.series_uid = series_uid
        self._trials = {int(t["trial"]): dict(t) for t in trials}
        self.set_aside = list(set_aside)
        self.recovered: list[str] = []  # what opening the folder found and did, in words

    # -- making and opening --------------------------------------------------------------------------------------
    @classmethod
    def start(cls, folder: str | Path, options: RobotSeriesOptions) -> RobotSeries:
        """A new series in ``folder`` (created if needed), or the one already there when its options are these
        (``trials`` may grow): resumed as :meth:`open` does. A folder of other options is refused, naming the
        difference: one folder, one condition."""
        options.check()
        folder = Path(folder)
        if folder.exists() and not folder.is_dir():
            raise TrialsError(f"{folder} is not a folder: --out names the series' folder")
        if (folder / SERIES_FILE).exists():
            series = cls.open(folder)
            stored = json.loads(json.dumps(series.options.condition()))
            current = json.loads(json.dumps(options.condition()))
            differences = [f"{key} {stored.get(key)!r} ≠ {current.get(key)!r}"
                           for key in dict.fromkeys([*stored, *current]) if stored.get(key) != current.get(key)]
            if differences:
                raise TrialsError(f"{folder} holds a series of other options ({'; '.join(differences)}): a series "
                                  "never mixes conditions; choose another folder")
            if options.trials < series.options.trials:
                raise TrialsError(f"{folder} holds a series of {series.options.trials} trials: --trials may grow, "
                                  f"not shrink (got {options.trials})")
            series.update(trials=options.trials, note=options.note or series.options.note, post_s=options.post_s)
            return series
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise TrialsError(f"cannot create the series folder {folder}: {exc.strerror or exc}") from None
        series = cls(folder, options, str(uuid.uuid4()), [], [])
        series._save()
        return series

    @classmethod
    def open(cls, folder: str | Path, recover: bool = True) -> RobotSeries:
        """The series in ``folder``, resumed: trials cut short set aside (to be run again), one recorded but not
        marked left for its outcome (:attr:`recovered` says what was found). ``recover`` False: its state only, as
        stored (to read its options)."""
        folder = Path(folder)
        path = folder / SERIES_FILE
        try:
            stored = json.loads(read_state_file(path, "series file"))
            if stored.get("plan_name") != PLAN_NAME:
                what = stored.get("plan_name") or "another kind of"
                raise TrialsError(f"{path}: a series of {what!r}, not of the robot's trials; choose another folder")
            options = _plain_options(stored["options"], int(stored["trials_planned"]), str(stored.get("note", "")),
                                     float(stored.get("post_s", 1.0)))
            series = cls(folder, options, str(stored["series_uid"]), list(stored.get("trials", [])),
                         list(stored.get("set_aside", [])))
        except FileNotFoundError:
            raise TrialsError(f"{folder} holds no series ({SERIES_FILE} missing): start one there") from None
        except OSError as exc:
            raise TrialsError(f"cannot read {path}: {exc.strerror or exc}") from None
        except (ValueError, KeyError, TypeError) as exc:
            if isinstance(exc, TrialsError):
                raise
            raise TrialsError(f"{path}: not a series file this version reads ({exc}); choose another folder") from None
        if recover:
            series._recover()
        return series

    def _recover(self) -> None:
        changed = False
        for k, trial in sorted(self._trials.items()):
            if trial["state"] != RECORDING:
                continue
            path = self.trial_path(k)
            start, stop = _documents(path)
            if start is None or start.get("series_uid") != self.series_uid:
                del self._trials[k]  # nothing of this run was written: the trial is simply run again
                self.recovered.append(f"trial {k + 1} had not started recording: it runs again")
            elif stop is not None and stop.get("run_start") == start.get("uid"):
                step = self._closed(k, str(stop.get("exit_status") or "success"), str(stop.get("reason") or ""))
                self.recovered.append(f"trial {k + 1} was recorded to the end: " + (
                    "its outcome is still to be marked" if step == ASK_OUTCOME else "kept, marked aborted"))
            else:
                aside = self._set_aside(k, start)
                self.recovered.append(f"trial {k + 1} was cut short while recording (a crash or a kill): its file "
                                      f"is kept as {aside.name}, and the trial runs again")
            changed = True
        if changed:
            self._save()

    def _set_aside(self, k: int, start: Mapping[str, Any]) -> Path:
        """Close a cut-short trial's recording as such (``run_stop`` ``fail``, outcome ``aborted``) and rename it out
        of the trial's way."""
        path = self.trial_path(k)
        with contextlib.suppress(OSError):  # a file h5py cannot open keeps what it has (no run_stop: cut short)
            write_run_stop(path, start, "fail", "cut short: the app or the command ended during the trial "
                           "(found when the series was resumed)", "aborted")
        n = 1
        while True:
            aside = path.with_name(f"{path.stem}.{CUT_SHORT}{'' if n == 1 else f'-{n}'}.h5")
            if not aside.exists():
                break
            n += 1
        os.replace(path, aside)
        index_quietly(aside)
        self.set_aside.append(aside.name)
        del self._trials[k]
        return aside

    # -- where the series is -------------------------------------------------------------------------------------
    @property
    def n_trials(self) -> int:
        return self.options.trials

    def trial_path(self, k: int) -> Path:
        return self.folder / trial_file(k)

    def trial(self, k: int) -> dict[str, Any] | None:
        trial = self._trials.get(k)
        return None if trial is None else dict(trial)

    def pending_outcome(self) -> int | None:
        """The trial recorded to the end whose outcome the operator has not marked yet (None: none)."""
        waiting = [k for k, t in self._trials.items() if t["state"] == RECORDED]
        return min(waiting) if waiting else None

    def next_trial(self) -> int | None:
        """The next trial to run (0-based), or None when every trial is finished (or one waits for its outcome)."""
        if self.pending_outcome() is not None:
            return None
        for k in range(self.options.trials):
            if k not in self._trials:
                return k
        return None

    @property
    def complete(self) -> bool:
        return all(self._trials.get(k, {}).get("state") == DONE for k in range(self.options.trials))

    def prompt(self, k: int) -> str:
        """What the operator is asked before trial ``k`` (0-based)."""
        return f"Place the robot, then Start trial {k + 1} of {self.options.trials}"

    def outcomes(self) -> dict[str, int]:
        counts = dict.fromkeys(OUTCOMES, 0)
        for trial in self._trials.values():
            if trial["state"] == DONE:
                counts[trial["outcome"]] = counts.get(trial["outcome"], 0) + 1
        return counts

    def summary(self) -> str:
        counts = ", ".join(f"{n} {name}" for name, n in self.outcomes().items() if n)
        done = sum(t["state"] == DONE for t in self._trials.values())
        return f"{done} of {self.options.trials} trials finished" + (f" ({counts})" if counts else "")

    # -- the steps of a trial ------------------------------------------------------------------------------------
    def run_start(self, k: int, *, config_text: str, calibration_json: str | None,
                  shape: Shape | None = None) -> dict[str, Any]:
        """Trial ``k``'s RunStart document: the condition (scene, shape, mode, speed, feedforward, tail load, the
        calibration and lab config by hash), ``trial`` = k, this series' uid and the operator's note."""
        options = self.options
        shape = shape if shape is not None else trial_shape(options)
        run_condition = condition(scene=options.scene or None, shape=shape.name or Path(options.shape).stem,
                                  mode=options.mode, speed_rad_s=options.speed_rad_s, controller="feedforward",
                                  tail_load_n=options.tail_load_n, calibration_json=calibration_json,
                                  config_text=config_text)
        return run_start_document(PLAN_NAME, run_condition, trial=k, series_uid=self.series_uid,
                                  note=options.note)

    def begin(self, k: int) -> Path:
        """Trial ``k``'s recording is about to start: its state is saved first (a crash from here on is found by
        :meth:`open`). Returns the recording's path."""
        if k != self.next_trial():
            raise TrialsError(f"trial {k + 1} is not the next one of the series in {self.folder}")
        path = self.trial_path(k)
        if path.exists():  # a file of no finished trial (left by another tool): out of the way, never overwritten
            start, _stop = _documents(path)
            self._set_aside(k, start or {})
        self._trials[k] = {"trial": k, "file": path.name, "state": RECORDING}
        self._save()
        return path

    def ended(self, k: int, exit_status: str, reason: str = "") -> str:
        """Trial ``k``'s recording is closed (its ``run_stop`` written by the recorder). Returns what comes next:

        - :data:`ASK_OUTCOME` — ``exit_status`` ``success``: the motion ran to its end, the outcome is the
          operator's to mark;
        - :data:`KEPT_ABORTED` — ``abort`` (STOP) or ``fail`` (a fault): the trial is kept, marked ``aborted`` with
          the reason;
        - :data:`NOT_RECORDED` — no file was kept (stopped before the board's first frame reached it): there is
          nothing to keep, the trial runs again."""
        if exit_status not in EXIT_STATUSES:
            raise ValueError(f"exit_status must be one of {', '.join(EXIT_STATUSES)}, got {exit_status!r}")
        trial = self._trials.get(k)
        if trial is None or trial["state"] != RECORDING:
            raise TrialsError(f"trial {k + 1} is not being recorded")
        if not self.trial_path(k).exists():
            del self._trials[k]
            self._save()
            return NOT_RECORDED
        next_step = self._closed(k, exit_status, reason)
        self._save()
        return next_step

    def _closed(self, k: int, exit_status: str, reason: str) -> str:
        trial = self._trials[k]
        trial.update(state=RECORDED, exit_status=exit_status, reason=reason)
        if exit_status == "success":
            return ASK_OUTCOME
        self._write_outcome(k, "aborted", "")
        return KEPT_ABORTED

    def mark(self, k: int, outcome: str, note: str = "") -> None:
        """The operator's outcome of trial ``k`` (``traversed``, ``failed``, ``aborted``) and note: into the
        recording's ``run_stop`` and the catalog, then the series' state and ``trials.csv``."""
        if outcome not in OUTCOMES:
            raise TrialsError(f"the outcome must be one of {', '.join(OUTCOMES)}, got {outcome!r}")
        trial = self._trials.get(k)
        if trial is None or trial["state"] == RECORDING:
            raise TrialsError(f"trial {k + 1} has no closed recording to mark")
        self._write_outcome(k, outcome, note.strip())
        self._save()

    def _write_outcome(self, k: int, outcome: str, note: str) -> None:
        trial = self._trials[k]
        path = self.trial_path(k)
        start, _stop = _documents(path)
        with contextlib.suppress(OSError):  # a file that cannot be written keeps its run_stop; the state says it
            if not path.is_file():  # never a new file holding only the outcome
                raise FileNotFoundError(path)
            write_run_stop(path, start, str(trial.get("exit_status", "success")), str(trial.get("reason", "")),
                           outcome, note=note or None)
        index_quietly(path)
        trial.update(state=DONE, outcome=outcome, note=note, duration_s=_duration_s(path))
        write_robot_trials_csv(self.folder, self.rows())

    def update(self, *, trials: int, note: str, post_s: float) -> None:
        """What may change between the sittings of a series: how many trials, the note, the run-on after a motion."""
        self.options = replace(self.options, trials=trials, note=note, post_s=post_s)
        self._save()

    def add_trials(self, n: int = 1) -> None:
        """``n`` more trials (one aborted may be made up for)."""
        total = self.options.trials + n
        if not 1 <= total <= MAX_TRIALS:
            raise TrialsError(f"a series holds 1 … {MAX_TRIALS} trials")
        self.options = replace(self.options, trials=total)
        self._save()

    # -- what is written ------------------------------------------------------------------------------------------
    def rows(self) -> list[dict[str, Any]]:
        """One row per trial of the series (``trials.csv``'s columns, plus ``state``): finished, recorded or still
        to run."""
        rows = []
        for k in range(max([self.options.trials, *(t + 1 for t in self._trials)])):
            trial = self._trials.get(k, {})
            rows.append({"file": trial_file(k), "trial": k, "seed": "", "outcome": trial.get("outcome", ""),
                         "duration_s": trial.get("duration_s", math.nan), "advance_m": math.nan,
                         "exit_status": trial.get("exit_status", ""), "note": trial.get("note", ""),
                         "state": trial.get("state", "to run"), "reason": trial.get("reason", "")})
        return rows

    def done_paths(self, usable_only: bool = True) -> list[Path]:
        """The finished trials' recordings (without the aborted ones when ``usable_only``), for a report."""
        return [self.trial_path(k) for k, t in sorted(self._trials.items())
                if t["state"] == DONE and not (usable_only and t.get("outcome") == "aborted")]

    def _save(self) -> None:
        document = {"format": SERIES_FORMAT, "version": 1, "series_uid": self.series_uid, "plan_name": PLAN_NAME,
                    "options": self.options.condition(), "trials_planned": self.options.trials,
                    "note": self.options.note, "post_s": self.options.post_s,
                    "trials": [self._trials[k] for k in sorted(self._trials)], "set_aside": self.set_aside}
        text = json.dumps(document, indent=1, allow_nan=False) + "\n"
        try:
            write_atomically(self.folder / SERIES_FILE, lambda handle: handle.write(text))
        except OSError as exc:
            raise TrialsError(f"cannot save the series' state in {self.folder}: {exc.strerror or exc}") from None


def _documents(path: Path) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    try:
        return read_documents(path)
    except OSError:
        return None, None


def _duration_s(path: Path) -> float | None:
    try:
        with h5py.File(path, "r", locking=False) as f:
            duration = float(f.attrs.get("duration_s", math.nan))
    except OSError:
        return None
    return duration if math.isfinite(duration) else None


def write_robot_trials_csv(folder: Path, rows: list[dict[str, Any]]) -> Path:
    """``folder/trials.csv``: a row per finished trial (:data:`ROBOT_TRIALS_COLUMNS`), written atomically."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=ROBOT_TRIALS_COLUMNS, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        if not row.get("outcome"):
            continue
        writer.writerow({k: ("" if v is None or (isinstance(v, float) and not math.isfinite(v)) else
                             f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    path = folder / "trials.csv"
    write_atomically(path, lambda handle: handle.write(text.getvalue()))
    return path
