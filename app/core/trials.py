"""A trial series in the physics lab: one condition run N times, each trial its own recording (the paper's three runs
over its obstacle, Fig. 7).

A series is a plan repeated: trial ``k`` is :func:`app.core.experiment.run_experiment` with seed ``seed + k`` (the
seed varies the simulated sensors, the start position and the frictions, as placing a real robot again does), its
recording ``DIR/trial-<k>.h5`` carrying ``run_start`` with ``plan_name = "experiment trials"``, ``trial`` = k and
the series' ``series_uid`` (:mod:`app.core.run_documents`). ``DIR/series.json`` holds the series' uid and options;
``DIR/trials.csv`` one row per trial (``file``, ``trial``, ``seed``, ``outcome``, ``duration_s``: the recording's
length, ``advance_m``: the body centroid's advance while the motion played), rewritten after each trial.

Resumable: a re-run of the same command keeps every trial whose recording is finished (its ``run_stop`` written, of
this series) and runs the others — one cut short by a crash or Ctrl-C is run again from its start. A folder that
holds a series of other options is refused, naming the difference: a series never mixes conditions.

Every row is read back from its recording (:func:`trial_row`), so a kept trial and a fresh one are described alike.
Qt-free; called from one thread (the command line's main thread).
"""

from __future__ import annotations

import csv
import io
import json
import math
import uuid
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.calfiles import write_atomically
from app.core.errors import TrialsError
from app.core.experiment import InvalidRunError
from app.core.run_documents import parse_document
from devices.toml_files import read_state_file

SERIES_FILE = "series.json"
TRIALS_CSV = "trials.csv"
TRIALS_COLUMNS = ("file", "trial", "seed", "outcome", "duration_s", "advance_m")
MAX_TRIALS = 1000
PLAN_NAME = "experiment trials"


@dataclass(frozen=True)
class SeriesOptions:
    """What every trial of a series shares (run_experiment's options) and how many trials from which seed."""

    scene: str
    trials: int
    seed: int = 0
    mode: str = "follow"
    speed_rad_s: float = 0.034
    seconds: float | None = None
    settle_s: float = 6.0
    controller: str = "feedforward"
    gains: dict[str, Any] | None = None  # FeedbackGains as a dict (None: the defaults, or feedforward)
    tail_load_n: float = 0.0
    repeat: int = 1
    rest_cap_s: float = 30.0
    shape: str | None = None  # the shape file's path (None: the settled pose)
    config: str | None = None  # the lab config file's path
    note: str = ""

    def condition(self) -> dict[str, Any]:
        """The options a resumed series must share (how many trials may grow; the note may change)."""
        return {k: v for k, v in asdict(self).items() if k not in ("trials", "note")}


def _trial_file(k: int) -> str:
    return f"trial-{k:03d}.h5"


def trial_row(path: Path, trial: int, seed: int) -> dict[str, Any]:
    """The ``trials.csv`` row of a finished trial, from its recording alone."""
    row: dict[str, Any] = {"file": path.name, "trial": trial, "seed": seed, "outcome": "", "duration_s": math.nan,
                           "advance_m": math.nan}
    with h5py.File(path, "r", locking=False) as f:
        stop = parse_document(f.attrs.get("run_stop")) or {}
        row["duration_s"] = float(f.attrs.get("duration_s", math.nan))
        sim = f.get("sim")
        outcome = stop.get("outcome") or (str(sim.attrs.get("outcome", "")) if sim is not None else "")
        row["outcome"] = outcome or "undecided"
        if sim is not None and "points_m" in sim and sim["points_m"].shape[0]:
            times = sim["time_s"][:]
            if len(times):
                row["duration_s"] = max(float(times[-1]), row["duration_s"] if math.isfinite(row["duration_s"])
                                        else -math.inf)
            if row["outcome"] != "invalid":
                end = float(sim.attrs.get("motion_end_s", math.nan))
                k = len(times) - 1 if math.isnan(end) else int(np.clip(np.searchsorted(times, end - 1e-9), 0,
                                                                           len(times) - 1))
                first = sim["points_m"][0, :, 0]
                at_end = sim["points_m"][k, :, 0]
                row["advance_m"] = float(np.mean(at_end) - np.mean(first))
    return row


def finished_trial(path: Path, series_uid: str, trial: int) -> bool:
    """``path`` is a complete recording of trial ``trial`` of this series (its run_stop written)."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            start = parse_document(f.attrs.get("run_start"))
            stop = parse_document(f.attrs.get("run_stop"))
    except OSError:
        return False
    return bool(start and stop and start.get("series_uid") == series_uid and start.get("trial") == trial
                and stop.get("run_start") == start.get("uid"))


def _series(out: Path, options: SeriesOptions) -> str:
    """The series' uid: a new one, or that of the series already in ``out`` when its options are these."""
    path = out / SERIES_FILE
    if path.exists():
        try:
            stored = json.loads(read_state_file(path, "series file"))
            stored_condition, uid = stored["condition"], str(stored["series_uid"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise TrialsError(f"{path}: not a series file this version reads ({exc}); choose another --out") from exc
        current = json.loads(json.dumps(options.condition()))
        differences = [f"{key} {stored_condition.get(key)!r} ≠ {current.get(key)!r}"
                       for key in dict.fromkeys([*stored_condition, *current])
                       if stored_condition.get(key) != current.get(key)]
        if differences:
            raise TrialsError(f"{out} holds a series of other options ({'; '.join(differences)}): a series never "
                              f"mixes conditions; choose another --out")
        return uid
    uid = str(uuid.uuid4())
    document = {"format": "sensnake-trials", "version": 1, "series_uid": uid, "plan_name": PLAN_NAME,
                "condition": options.condition(), "note": options.note}
    write_atomically(path, lambda handle: handle.write(json.dumps(document, indent=1) + "\n"))
    return uid


def write_trials_csv(out: Path, rows: list[dict[str, Any]]) -> Path:
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=TRIALS_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) and math.isfinite(v) else
                             "" if isinstance(v, float) else v) for k, v in row.items() if k in TRIALS_COLUMNS})
    path = out / TRIALS_CSV
    write_atomically(path, lambda handle: handle.write(text.getvalue()))
    return path


RunOne = Callable[[Path, int, Mapping[str, Any]], object]  # (recording, seed, md) → run it


def run_series(options: SeriesOptions, out: str | Path, run_one: RunOne,
               progress: Callable[[str], None] | None = None) -> tuple[list[dict[str, Any]], int]:
    """Run (or resume) the series into ``out``: returns (the trials.csv rows, how many trials were kept from an
    earlier run). ``run_one(path, seed, md)`` runs one trial (the command line passes run_experiment with the
    series' options); an error it raises for one trial (an invalid settle) is that trial's outcome, the series goes
    on."""
    if not 1 <= options.trials <= MAX_TRIALS:
        raise TrialsError(f"--trials must be 1 … {MAX_TRIALS}, got {options.trials}")
    if options.seed < 0:
        raise TrialsError(f"--seed must be 0 or more, got {options.seed}")
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise TrialsError(f"{folder} is not a folder: --out names the series' folder")
    folder.mkdir(parents=True, exist_ok=True)
    series_uid = _series(folder, options)
    rows: list[dict[str, Any]] = []
    kept = 0
    for k in range(options.trials):
        path, seed = folder / _trial_file(k), options.seed + k
        if finished_trial(path, series_uid, k):
            kept += 1
            if progress:
                progress(f"trial {k + 1}/{options.trials} (seed {seed}): kept from an earlier run")
        else:
            if progress:
                progress(f"trial {k + 1}/{options.trials} (seed {seed}): running")
            md = {"plan_name": PLAN_NAME, "trial": k, "series_uid": series_uid, "note": options.note}
            try:
                run_one(path, seed, md)
            except InvalidRunError as exc:  # the physics was invalid before the capture: nothing recorded
                rows.append({"file": path.name, "trial": k, "seed": seed, "outcome": "invalid",
                             "duration_s": math.nan, "advance_m": math.nan, "reason": str(exc)})
                write_trials_csv(folder, rows)
                continue
        rows.append(trial_row(path, k, seed))
        write_trials_csv(folder, rows)
    return rows, kept


def valid_recordings(folder: Path, rows: list[dict[str, Any]]) -> list[Path]:
    """The trials a repeatability report may average: recorded and valid (an invalid run is never averaged in)."""
    return [folder / r["file"] for r in rows if r["outcome"] != "invalid" and (folder / r["file"]).is_file()]
