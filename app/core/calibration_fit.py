"""Fit a calibration session's trials and decide whether the result may be saved — one path for the CLI
(``sensnake calibrate``, ``sensnake fit``'s checks) and the Calibration tab, so both give the same result on the same
files.

:func:`fit_trials` runs :func:`models.calibration.calibrate_with_drift` (the numerics' fitter: multi-start, degenerate
marking, warnings) with the readout circuit of the lab config (its ceiling ``1/R_C`` censors saturated samples, SPEC
§4) and the paper's averaging window scaled to the hold. It adds what the calibration file should say about what the
rig saw: per trial the window mean the linear model uses (``mean_conductance_S``) and the unloaded level before the
ramp (``unloaded_conductance_S``), per sensor the median unloaded level.

:func:`refusal_reasons` names what makes a fit unfit to use: a degenerate SLS fit (at a bound, singular, τ not
resolved), non-physical parameters, a mean conductance that does not rise with force, an unloaded level that is not
small against the loaded ones (something else loads the sensor). The CLI then exits non-zero naming them; the tab
asks for an explicit confirmation before saving.

Pure: no Qt, any thread (the tab calls it from a worker).
"""

from __future__ import annotations

import errno
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.core import calfiles
from app.core.errors import OutputPathError
from app.core.outputs import NOFOLLOW, describe_kind
from devices.config import BoardConfig
from models.calibration import DEFAULT_SOLVER, SensorCalibration, TrialInput, calibrate_with_drift
from models.linear import DEFAULT_WINDOW_S, trial_baseline, trial_mean
from models.physics import PhysicsConstants

# The unloaded level may be at most this fraction of the smallest loaded window mean.
UNLOADED_FRACTION_LIMIT = 0.5
# Window means of successive force levels must rise by more than this fraction of their spread to count as rising.
RISE_TOLERANCE = 0.0


@dataclass(frozen=True)
class SessionFit:
    """A fitted sensor plus what the trials showed; :meth:`entry` is what goes into the calibration file."""

    sensor: str
    calibration: SensorCalibration
    trial_files: tuple[str, ...]
    forces_n: tuple[float, ...]  # each trial's hold force (N)
    mean_conductance_s: tuple[float, ...]  # each trial's window mean (S), what the linear model uses
    trial_unloaded_s: tuple[float | None, ...]  # each trial's level before the ramp (S); None: starts loaded
    unloaded_conductance_s: float | None  # median over the trials (S)
    window_s: tuple[float, float]
    readout_ceiling_s: float
    problems: tuple[str, ...]  # refusal reasons (empty: fit to use)

    @property
    def ok(self) -> bool:
        return not self.problems

    def entry(self) -> dict:
        """The sensor's SPEC §3.3 entry with the extras (``mean_conductance_S`` per trial, ``unloaded_conductance_S``,
        ``refusal_reasons``, ``readout_ceiling_S``, ``window_s``); ``estimate`` ignores the extras."""
        entry = self.calibration.to_dict()
        for row, mean, unloaded in zip(entry["trials"], self.mean_conductance_s, self.trial_unloaded_s):
            row["mean_conductance_S"] = _finite_or_none(mean)
            row["unloaded_conductance_S"] = _finite_or_none(unloaded)
        entry["unloaded_conductance_S"] = _finite_or_none(self.unloaded_conductance_s)
        entry["readout_ceiling_S"] = self.readout_ceiling_s
        entry["window_s"] = list(self.window_s)
        entry["refusal_reasons"] = list(self.problems)
        return entry


def _finite_or_none(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


FIT_NICENESS = 10  # how much lower than the app a background fit runs (POSIX nice; 0 … 19)


def yield_cpu() -> None:
    """In a fitting worker process: run below the app's priority, so a long fit takes only the CPU that the robot's
    control loop, the board and the simulated lab leave (no effect where the platform has no ``nice``)."""
    import contextlib
    import os

    with contextlib.suppress(AttributeError, OSError):
        os.nice(FIT_NICENESS)


def read_trials(paths: Sequence[str | Path]) -> list[TrialInput]:
    """SPEC §3.1 trial CSVs → fitter inputs (name = file name); CalFileError naming the file and line."""
    out = []
    for path in paths:
        trial = calfiles.read_trial_csv(path)
        out.append(TrialInput(Path(path).name, trial.time_s, trial.force_n, trial.conductance_s))
    return out


def fit_trials(trials: Sequence[TrialInput], sensor: str, area_m2: float, physics: PhysicsConstants,
               board: BoardConfig, window_s: tuple[float, float] = DEFAULT_WINDOW_S, *,
               solver: str = DEFAULT_SOLVER) -> SessionFit:
    """Fit ``trials`` of ``sensor`` with the readout circuit of ``board``; see the module docstring. Raises
    ValueError (FlatSensorError, unusable trials) naming the trial."""
    ceiling = 1.0 / board.r_c_ohm
    # A drifting baseline is looked for and separated from the creep (models.calibration.calibrate_with_drift).
    cal = calibrate_with_drift(trials, area_m2, physics, window_s=window_s, saturation_s=ceiling, solver=solver)
    means, unloaded = [], []
    for trial in trials:
        means.append(trial_mean(trial.time_s, trial.conductance_s, window_s))
        unloaded.append(trial_baseline(trial.time_s, trial.force_n, trial.conductance_s))
    forces = tuple(float(t.force_n) for t in cal.trials)
    known = [u for u in unloaded if u is not None and math.isfinite(u)]
    level = float(np.median(known)) if known else None
    problems = refusal_reasons(cal, forces, means, level)
    return SessionFit(sensor, cal, tuple(t.name for t in trials), forces, tuple(means), tuple(unloaded), level,
                      window_s, ceiling, tuple(problems))


def refusal_reasons(cal: SensorCalibration, forces_n: Sequence[float], means_s: Sequence[float],
                    unloaded_s: float | None) -> list[str]:
    """Why this calibration must not be used as it is (empty: it may). See the module docstring."""
    problems: list[str] = []
    if cal.degenerate:
        problems.append("degenerate SLS fit: " + "; ".join(cal.degenerate_reasons))
    sls = cal.sls
    bad = [name for name in ("E0_Pa", "E1_Pa", "mu1_Pa_s")
           if not (math.isfinite(float(getattr(sls, name))) and float(getattr(sls, name)) > 0)]
    if bad:
        problems.append(f"non-physical SLS parameters ({', '.join(bad)} not a positive finite number)")
    forces = np.asarray(forces_n, dtype=np.float64)
    means = np.asarray(means_s, dtype=np.float64)
    levels = np.unique(np.round(forces, 3))
    if levels.size >= 2:
        per_level = np.array([np.nanmean(means[np.isclose(np.round(forces, 3), f)]) for f in levels])
        steps = np.diff(per_level)
        if np.any(~np.isfinite(steps)) or np.any(steps <= RISE_TOLERANCE * np.ptp(per_level)):
            listing = ", ".join(f"{f:g} N: {m * 1e6:.1f} µS" for f, m in zip(levels, per_level))
            problems.append(f"the mean conductance does not rise with force ({listing}): the rig does not load "
                            "this sensor alone (check the sensor name, the probe and that nothing else presses it)")
    finite = means[np.isfinite(means)]
    if unloaded_s is not None and finite.size and unloaded_s > UNLOADED_FRACTION_LIMIT * float(np.min(finite)):
        problems.append(f"the unloaded level {unloaded_s * 1e6:.1f} µS is {100 * unloaded_s / float(np.min(finite)):.0f} % "
                        f"of the smallest loaded mean ({float(np.min(finite)) * 1e6:.1f} µS): something other than "
                        "the probe loads the sensor")
    return problems


def save(path: str | Path, fit: SessionFit, physics: PhysicsConstants, board: Any = None) -> dict:
    """Write ``fit`` into the calibration file ``path`` (other sensors kept, SPEC §3.3), with the readout circuit of
    ``board`` (a BoardConfig) it was fitted on."""
    readout = calfiles.readout_of(board) if board is not None else None
    return calfiles.update_calibration(path, fit.sensor, fit.entry(), physics, readout)


HISTORY_FILE = "calibration_history.jsonl"


def append_history(folder: str | Path, fit: SessionFit, saved_to: str | Path) -> Path:
    """Append one line (JSON) describing this calibration of the sensor to ``folder/calibration_history.jsonl``:
    when, where it was saved, its SLS parameters, linear model, unloaded level and refusal reasons. The history of a
    sensor's calibrations shows its drift (:func:`read_history`)."""
    import datetime
    import json

    cal = fit.calibration
    record = {"sensor": fit.sensor, "saved": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "file": str(saved_to), "trials": list(fit.trial_files),
              "sls": cal.sls.to_dict(), "tau_s": float(cal.sls.tau_s),
              "linear": cal.linear.model.to_dict() if cal.linear is not None else None,
              "unloaded_conductance_S": _finite_or_none(fit.unloaded_conductance_s),
              "force_range_N": list(cal.force_range_n), "refusal_reasons": list(fit.problems)}
    path = Path(folder) / HISTORY_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    # Appended to a regular file only, never through a symbolic link planted there (O_NOFOLLOW) nor into a FIFO
    # (O_NONBLOCK: opening one with no reader fails at once instead of hanging the window).
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | NOFOLLOW | getattr(os, "O_NONBLOCK", 0), 0o666)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENXIO):  # a symbolic link; a FIFO nobody reads
            what = "a symbolic link" if exc.errno == errno.ELOOP else "a FIFO (named pipe)"
            raise OutputPathError(f"{path} is {what}: the calibration history is appended to a regular file "
                                  "only") from None
        raise
    try:
        kind = describe_kind(os.fstat(fd).st_mode)
        if kind is not None:
            raise OutputPathError(f"{path} is {kind}: the calibration history is appended to a regular file only")
        os.write(fd, (json.dumps(record) + "\n").encode("utf-8"))
    finally:
        os.close(fd)
    return path


def read_history(folder: str | Path, sensor: str) -> list[dict]:
    """The saved calibrations of ``sensor``, oldest first (unreadable lines are skipped)."""
    import json

    path = Path(folder) / HISTORY_FILE
    out: list[dict] = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            record = json.loads(line)
        except ValueError:
            continue
        if isinstance(record, dict) and record.get("sensor") == sensor:
            out.append(record)
    return out


def fit_trials_with_curves(trials: Sequence[TrialInput], sensor: str, area_m2: float, physics: PhysicsConstants,
                           board: BoardConfig, window_s: tuple[float, float] = DEFAULT_WINDOW_S
                           ) -> tuple[SessionFit, tuple[np.ndarray, ...]]:
    """:func:`fit_trials` plus each trial's conductance predicted by the fitted SLS model from its force (S) — for
    a child process that does all of the fitting's work (the GUI's)."""
    from models.sls import conductance_from_force

    fit = fit_trials(trials, sensor, area_m2, physics, board, window_s)
    curves = tuple(np.asarray(conductance_from_force(t.time_s, t.force_n, fit.calibration.sls, area_m2, physics),
                              dtype=np.float64) for t in trials)
    return fit, curves
