"""Repeatability of trials (the paper's Fig. 7): recordings of one condition aligned on an event, then the mean and
spread of each bottom sensor's force and each segment's forward position over time.

The analysis reads only the recordings (any series can be re-analysed later):

1. **Load** each recording (:func:`load_trial`): the bottom sensors' forces estimated when it was recorded
   (``/forces/force_N``, the columns of the ``S<k>B`` channels), the robot's goals (``/robot/goal_rad``) and the
   segments' positions along the path — ``/mocap/segment_center_m`` when the lab's motion capture is in the file,
   else the physics lab's body (``/sim/points_m``: a segment's centre is the mean of its two ends); of a take
   longer than :data:`POSITION_FRAMES` frames every k-th (the fewest that keep within it, read so: never whole).
2. **Check** that they are trials of one condition (their ``run_start`` documents, :mod:`app.core.run_documents`):
   a difference is refused, naming it, unless mixed conditions are asked for. A simulated run marked invalid
   (``/sim`` ``valid`` = 0) is refused: an invalid run is never averaged in.
3. **Align** (:func:`event_time`): each recording's event time on its own clock, its *offset*: aligned time =
   ``time_s − offset``. ``onset`` (default) — the first change of any joint's goal (the motion starts; the time is
   extrapolated back along the first moving goals to where they left their start, so it is not quantised to the
   robot's sample period); ``contact`` — the first time a bottom sensor's force rises past ``contact_force_n``
   (linear between samples); ``mocap`` — the first time a segment's centre (the head's by default) passes
   ``position_x_m`` along the path, or, without one, moves ``position_move_m`` past where it started (from every
   frame: a long take's positions are read again in blocks of :data:`POSITION_BLOCK_FRAMES`).
4. **Resample** every trial on one grid of aligned time (the span all trials cover, at the forces' median sample
   period; linear interpolation) and take the mean and sample s.d. (n − 1) across trials at each instant.
5. **Summarise** per quantity: the peak of each trial (its value and aligned time; for a segment its farthest
   forward position), mean ± s.d. over trials; the trial-to-trial RMS difference (root mean square over every pair of
   trials and every instant); the intraclass correlation ICC(A,1) (two-way, absolute agreement, single trial; the
   instants as subjects, the trials as raters) where it means something — a quantity whose mean curve varies more
   than its noise floor (:data:`ICC_MIN_FORCE_SPREAD_N`, :data:`ICC_MIN_POSITION_SPREAD_M`); a flat one has nothing
   to agree on and gets no ICC. The instants are not independent samples: the ICC describes agreement, it is no test.

Qt-free; any thread (no state). The figure is SVG text (:func:`repeatability_svg`); the command line rasterises it.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import h5py
import numpy as np

from app.core.calfiles import write_atomically
from app.core.errors import RepeatabilityError
from app.core.mocap import frame_step
from app.core.recording import check_input
from app.core.run_documents import RUN_START, condition_differences, parse_document
from devices.scene import channel_map

ALIGN_EVENTS = ("onset", "contact", "mocap")
ALIGN_WORDS = {"onset": "motion onset (first goal change)", "contact": "first bottom contact",
               "mocap": "a segment's position"}
GOAL_CHANGE_RAD = 1e-4  # a goal this far from its start has moved (servo ticks are 1.5e-3 rad)
CONTACT_FORCE_N = 1.0
POSITION_MOVE_M = 0.01
ICC_MIN_FORCE_SPREAD_N = 0.2  # the mean curve's s.d. over time below which a sensor is flat (noise, no contact)
ICC_MIN_POSITION_SPREAD_M = 0.005
MIN_TRIALS = 2
POSITION_FRAMES = 20_000  # of a longer take the curves use every k-th frame (~2 MB); the alignment reads them all
POSITION_BLOCK_FRAMES = 16_384  # the alignment goes through a long take's positions in blocks this long (~0.3 MB)


@dataclass(frozen=True)
class Trial:
    """What the analysis needs from one recording; times on its own clock (s since its ``started``)."""

    path: Path
    run_start: dict[str, Any] | None
    force_time_s: np.ndarray  # (N,)
    bottom_names: tuple[str, ...]
    bottom_force_n: np.ndarray  # (N, B)
    goal_time_s: np.ndarray | None = None  # (M,)
    goal_rad: np.ndarray | None = None  # (M, J)
    position_source: str = ""  # "mocap", "sim" or "" (none)
    position_time_s: np.ndarray | None = None  # (T,)
    segment_x_m: np.ndarray | None = None  # (T, n): each segment's centre along the path (+x)
    position_step: int = 1  # the positions above are every k-th frame of the file's (1: all of them)
    valid: bool = True
    invalid_reason: str = ""


def _text(value: Any) -> str:
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def load_trial(path: str | Path) -> Trial:
    """Read what the analysis needs from a recording; :class:`RepeatabilityError` naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        check_input(path)  # a FIFO, a device, a link loop: named for what it is
        raise RepeatabilityError(f"{path}: no such recording")
    try:
        with h5py.File(path, "r", locking=False) as f:
            return _read_trial(f, path)
    except OSError as exc:
        raise RepeatabilityError(f"{path}: not a readable recording ({' '.join(str(exc).split())[:120]})") from exc
    except (KeyError, ValueError, IndexError, TypeError) as exc:
        if isinstance(exc, RepeatabilityError):
            raise
        raise RepeatabilityError(f"{path}: damaged recording ({type(exc).__name__}: {exc})") from exc


def _read_trial(f: h5py.File, path: Path) -> Trial:
    if _text(f.attrs.get("format", "")) != "sensnake-recording" or "daq" not in f:
        raise RepeatabilityError(f"{path}: not a SenSnake recording")
    channels = [_text(c) for c in f["daq"].attrs["channels"]]
    if "forces" not in f or "force_N" not in f["forces"]:
        raise RepeatabilityError(f"{path}: no forces in it (/forces/force_N): record with a calibration, or add "
                                 f"them with 'sensnake estimate {path.name} --cal CAL.json --out NEW.h5'")
    n_segments = int(f["robot/goal_rad"].shape[1]) if "robot" in f else 12
    rows, segments = channel_map(channels, max(n_segments, 1))
    bottom = [int(c) for c in np.flatnonzero(rows == 0)]
    bottom.sort(key=lambda c: int(segments[c]))
    if not bottom:
        raise RepeatabilityError(f"{path}: no bottom sensor among its channels (S01B … S12B)")
    force = f["forces/force_N"]
    daq_time = f["daq/time_s"]
    n = min(force.shape[0], daq_time.shape[0])
    force_n = np.asarray(force[:n], dtype=float)[:, bottom]
    time_s = np.asarray(daq_time[:n], dtype=float)
    goal_time = goal = None
    if "robot" in f and "goal_rad" in f["robot"]:
        m = min(f["robot/time_s"].shape[0], f["robot/goal_rad"].shape[0])
        goal_time, goal = np.asarray(f["robot/time_s"][:m], float), np.asarray(f["robot/goal_rad"][:m], float)
    source, position_time, segment_x, step = _position_source(f), None, None, 1
    if source:
        time_ds, data_ds = _position_datasets(f, source)
        m = min(time_ds.shape[0], data_ds.shape[0])
        step = frame_step(m, POSITION_FRAMES)  # a long take is read every k-th frame, never whole
        position_time = np.asarray(time_ds[:m:step], float)
        along = np.asarray(data_ds[:m:step, :, 0], float)
        segment_x = along if source == "mocap" else 0.5 * (along[:, :-1] + along[:, 1:])
    valid, reason = True, ""
    if "sim" in f:
        valid = bool(int(f["sim"].attrs.get("valid", 1)))
        reason = _text(f["sim"].attrs.get("invalid_reason", ""))
    return Trial(path, parse_document(f.attrs.get(RUN_START)), time_s, tuple(channels[c] for c in bottom),
                 force_n, goal_time, goal, source, position_time, segment_x, step, valid, reason)


def _position_source(f: h5py.File) -> str:
    """Where a recording's segment positions are: "mocap", "sim" or "" (none)."""
    if "mocap" in f and "segment_center_m" in f["mocap"]:
        return "mocap"
    if "sim" in f and "points_m" in f["sim"]:
        return "sim"
    return ""


def _position_datasets(f: h5py.File, source: str) -> tuple[h5py.Dataset, h5py.Dataset]:
    """(times, positions) of ``source``: /mocap's segment centres (M, n, 3) or /sim's points (T, n+1, 3), whose
    segment k's centre is the mean of points k and k+1."""
    group = f[source]
    return group["time_s"], group["segment_center_m" if source == "mocap" else "points_m"]


def _segment_x_blocks(trial: Trial, segment: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Segment ``segment`` (0-based)'s x at every frame of ``trial``'s positions, block after block: the
    positions the trial holds when it holds every frame, else read from its file (a long take, never whole)."""
    if trial.position_step == 1 and trial.segment_x_m is not None and trial.position_time_s is not None:
        yield trial.position_time_s, trial.segment_x_m[:, segment]
        return
    try:
        with h5py.File(trial.path, "r", locking=False) as f:
            time_ds, data_ds = _position_datasets(f, trial.position_source)
            m = min(time_ds.shape[0], data_ds.shape[0])
            for start in range(0, m, POSITION_BLOCK_FRAMES):
                block = slice(start, min(start + POSITION_BLOCK_FRAMES, m))
                t = np.asarray(time_ds[block], float)
                if trial.position_source == "mocap":
                    yield t, np.asarray(data_ds[block, segment, 0], float)
                else:
                    yield t, np.asarray(data_ds[block, segment:segment + 2, 0], float).mean(axis=1)
    except (OSError, KeyError) as exc:
        raise RepeatabilityError(f"{trial.path}: its segment positions cannot be read ({exc})") from exc


# -- alignment -----------------------------------------------------------------------------------------------------
def _rising_crossing(time_s: np.ndarray, values: np.ndarray, level: float) -> float:
    """The first time ``values`` rise from below ``level`` to at or above it (linear between samples); NaN: never.
    A series that starts above the level crosses only after it has been below it."""
    finite = np.isfinite(values)
    t, v = time_s[finite], values[finite]
    below = v < level
    rises = np.flatnonzero(below[:-1] & ~below[1:])
    if not rises.size:
        return math.nan
    i = int(rises[0])
    return float(t[i] + (level - v[i]) * (t[i + 1] - t[i]) / (v[i + 1] - v[i]))


def first_rise(blocks: Iterable[tuple[np.ndarray, np.ndarray]], level: float | None,
               move: float) -> tuple[float, float]:
    """:func:`_rising_crossing` over a series given block after block ((times, values) pairs, in order), in one
    pass: the first rise past ``level`` or, when it is None, past the first finite value + ``move``. Returns the
    time (NaN: never) and the level."""
    carry_t, carry_v = np.empty(0), np.empty(0)  # the last finite sample before the block: a rise can straddle two
    for time_s, values in blocks:
        finite = np.isfinite(values)
        t, v = time_s[finite], values[finite]
        if level is None and v.size:
            level = float(v[0]) + move
        t, v = np.concatenate([carry_t, t]), np.concatenate([carry_v, v])
        if level is not None:
            when = _rising_crossing(t, v, level)
            if not math.isnan(when):
                return when, level
        if v.size:
            carry_t, carry_v = t[-1:], v[-1:]
    return math.nan, math.nan if level is None else level


def onset_time(goal_time_s: np.ndarray, goal_rad: np.ndarray, threshold_rad: float = GOAL_CHANGE_RAD) -> float:
    """When the goals first leave their start: the first sample whose largest joint change exceeds
    ``threshold_rad``, moved back along the change's own slope (over the next samples) to where it began — exact for
    a motion that starts as a ramp, and never before the last still sample. NaN: the goals never change."""
    change = np.max(np.abs(goal_rad - goal_rad[0]), axis=1)
    moved = np.flatnonzero(change > threshold_rad)
    if not moved.size:
        return math.nan
    k = int(moved[0])
    if k == 0:
        return float(goal_time_s[0])
    t_still, t_first = float(goal_time_s[k - 1]), float(goal_time_s[k])
    ahead = min(k + 3, len(change) - 1)
    if ahead > k and goal_time_s[ahead] > t_first:
        slope = (change[ahead] - change[k]) / (goal_time_s[ahead] - t_first)
        if slope > 0:
            return float(np.clip(t_first - change[k] / slope, t_still, t_first))
    return 0.5 * (t_still + t_first)


@dataclass(frozen=True)
class AlignOptions:
    event: str = "onset"
    contact_force_n: float = CONTACT_FORCE_N
    contact_sensor: str | None = None  # a bottom sensor's name; default: any of them
    position_segment: int = 1  # 1 = the head segment
    position_x_m: float | None = None  # absolute x to pass; None: position_move_m past the start
    position_move_m: float = POSITION_MOVE_M

    def describe(self) -> str:
        if self.event == "onset":
            return ALIGN_WORDS["onset"]
        if self.event == "contact":
            where = self.contact_sensor or "any bottom sensor"
            return f"first bottom contact ({where} past {self.contact_force_n:g} N)"
        target = (f"x = {self.position_x_m:g} m" if self.position_x_m is not None
                  else f"{self.position_move_m * 100:g} cm past its start")
        return f"segment {self.position_segment}'s position ({target})"


def event_time(trial: Trial, options: AlignOptions) -> float:
    """The alignment event's time on ``trial``'s own clock; :class:`RepeatabilityError` naming the file when the
    recording has no such event."""
    path = trial.path
    if options.event == "onset":
        if trial.goal_rad is None or trial.goal_time_s is None or not len(trial.goal_time_s):
            raise RepeatabilityError(f"{path}: no robot goals (/robot/goal_rad) to find the motion onset in; "
                                     f"align on --align contact or --align mocap")
        when = onset_time(trial.goal_time_s, trial.goal_rad)
        if math.isnan(when):
            raise RepeatabilityError(f"{path}: the robot's goals never change: no motion onset to align on")
        return when
    if options.event == "contact":
        columns = range(len(trial.bottom_names))
        if options.contact_sensor is not None:
            if options.contact_sensor not in trial.bottom_names:
                raise RepeatabilityError(f"{path}: no bottom sensor {options.contact_sensor} (it has "
                                         f"{', '.join(trial.bottom_names)})")
            columns = range(trial.bottom_names.index(options.contact_sensor),
                            trial.bottom_names.index(options.contact_sensor) + 1)
        times = [_rising_crossing(trial.force_time_s, trial.bottom_force_n[:, c], options.contact_force_n)
                 for c in columns]
        finite = [t for t in times if not math.isnan(t)]
        if not finite:
            raise RepeatabilityError(f"{path}: no bottom sensor's force rises past {options.contact_force_n:g} N: no "
                                     f"contact to align on (try --contact-force)")
        return min(finite)
    if options.event == "mocap":
        if trial.segment_x_m is None or trial.position_time_s is None or not len(trial.position_time_s):
            raise RepeatabilityError(f"{path}: no segment positions (/mocap or /sim) to align on")
        k = options.position_segment
        if not 1 <= k <= trial.segment_x_m.shape[1]:
            raise RepeatabilityError(f"{path}: no segment {k} (it has 1 … {trial.segment_x_m.shape[1]})")
        when, level = first_rise(_segment_x_blocks(trial, k - 1), options.position_x_m, options.position_move_m)
        if math.isnan(when):
            raise RepeatabilityError(f"{path}: segment {k} never passes x = {level:.3f} m: nothing to align on")
        return when
    raise RepeatabilityError(f"unknown alignment {options.event!r}; one of {', '.join(ALIGN_EVENTS)}")


# -- the analysis --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Quantity:
    """One quantity over the trials on the common grid: ``trials`` (k × T), their mean and s.d. (T)."""

    name: str  # "S05B" or "seg3_x"
    unit: str  # "N" or "m"
    trials: np.ndarray
    mean: np.ndarray
    sd: np.ndarray


@dataclass(frozen=True)
class Repeatability:
    paths: tuple[Path, ...]
    offsets_s: tuple[float, ...]
    align: str  # what was aligned on, in words
    time_s: np.ndarray  # the common grid of aligned time
    forces: tuple[Quantity, ...]
    positions: tuple[Quantity, ...]
    position_source: str
    differences: tuple[str, ...] = ()  # the condition differences accepted (mixed)
    notes: tuple[str, ...] = field(default=())

    @property
    def n_trials(self) -> int:
        return len(self.paths)


def check_conditions(trials: Sequence[Trial], mixed: bool) -> list[str]:
    """The condition differences between the trials (each naming the file); :class:`RepeatabilityError` unless
    ``mixed``."""
    known = [t for t in trials if t.run_start]
    differences: list[str] = []
    for trial in known[1:]:
        first = known[0]
        assert first.run_start is not None and trial.run_start is not None
        for difference in condition_differences(first.run_start.get("condition"), trial.run_start.get("condition")):
            differences.append(f"{trial.path.name} differs from {first.path.name}: {difference}")
    if differences and not mixed:
        raise RepeatabilityError(f"{differences[0]} — not trials of one condition (--mixed compares them anyway)")
    return differences


def _resample(time_s: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``values`` (N,) or (N, C) at ``grid`` (linear; NaN outside the samples or where a column has none)."""
    values2 = values.reshape(len(time_s), -1)
    out = np.full((len(grid), values2.shape[1]), np.nan)
    order = np.argsort(time_s, kind="stable")
    t_sorted = time_s[order]
    for c in range(values2.shape[1]):
        column = values2[order, c]
        finite = np.isfinite(column) & np.isfinite(t_sorted)
        if finite.sum() < 2:
            continue
        t, v = t_sorted[finite], column[finite]
        inside = (grid >= t[0]) & (grid <= t[-1])
        out[inside, c] = np.interp(grid[inside], t, v)
    return out


def _stack(name: str, unit: str, columns: list[np.ndarray]) -> Quantity:
    trials = np.vstack(columns)
    with warnings.catch_warnings():  # an instant no trial covers: the NaN numpy returns says it already
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(trials, axis=0)
        sd = np.nanstd(trials, axis=0, ddof=1)
    return Quantity(name, unit, trials, mean, sd)


def _positions(trial: Trial) -> tuple[np.ndarray, np.ndarray]:
    """(time, segment x) of a trial known to have positions."""
    if trial.position_time_s is None or trial.segment_x_m is None:
        raise RepeatabilityError(f"{trial.path}: no segment positions")
    return trial.position_time_s, trial.segment_x_m


def analyse(paths: Sequence[str | Path], options: AlignOptions | None = None, mixed: bool = False,
            step_s: float | None = None) -> tuple[Repeatability, tuple[Trial, ...]]:
    """Load, check, align and resample the recordings (see the module docstring)."""
    options = options or AlignOptions()
    if options.event not in ALIGN_EVENTS:
        raise RepeatabilityError(f"--align must be one of {', '.join(ALIGN_EVENTS)}, got {options.event!r}")
    seen: set[Path] = set()
    for path in paths:
        if Path(path).resolve() in seen:
            raise RepeatabilityError(f"{path}: given twice (a trial counts once)")
        seen.add(Path(path).resolve())
    if len(seen) < MIN_TRIALS:
        raise RepeatabilityError(f"repeatability needs at least {MIN_TRIALS} recordings (trials), got {len(seen)}")
    trials = tuple(load_trial(p) for p in paths)
    for trial in trials:
        if not trial.valid:
            raise RepeatabilityError(f"{trial.path}: an invalid run ({trial.invalid_reason or '/sim valid = 0'}); "
                                     f"an invalid run is never averaged in: leave it out")
    names = trials[0].bottom_names
    for trial in trials[1:]:
        if trial.bottom_names != names:
            raise RepeatabilityError(f"{trial.path}: its bottom sensors ({', '.join(trial.bottom_names)}) are not "
                                     f"{trials[0].path.name}'s ({', '.join(names)})")
    differences = check_conditions(trials, mixed)
    unknown = [t.path.name for t in trials if not t.run_start]
    notes: list[str] = []
    if unknown:
        notes.append(f"condition not checked for {', '.join(unknown)}: no run_start (recorded before run documents)")
    for trial in trials:
        if trial.position_step > 1 and trial.position_time_s is not None:
            notes.append(f"{trial.path.name}: a long take, its segment positions' curves from one frame in "
                         f"{trial.position_step} ({len(trial.position_time_s):,} of them); an alignment on a "
                         "position reads every frame")
    offsets = [event_time(t, options) for t in trials]
    starts = [float(np.nanmin(t.force_time_s)) - o for t, o in zip(trials, offsets)]
    ends = [float(np.nanmax(t.force_time_s)) - o for t, o in zip(trials, offsets)]
    lo, hi = max(starts), min(ends)
    if not hi > lo:
        raise RepeatabilityError("the recordings share no stretch of time once aligned on the "
                                 f"{options.describe()}: nothing to compare")
    if step_s is None:
        periods = [float(np.median(np.diff(t.force_time_s))) for t in trials if len(t.force_time_s) > 1]
        step_s = min(periods) if periods else 1.0 / 30.0
    if not (math.isfinite(step_s) and step_s > 0):
        raise RepeatabilityError(f"the grid step must be positive, got {step_s}")
    grid = lo + step_s * np.arange(int(math.floor((hi - lo) / step_s + 1e-9)) + 1)
    resampled = [_resample(t.force_time_s - o, t.bottom_force_n, grid) for t, o in zip(trials, offsets)]
    forces = tuple(_stack(name, "N", [r[:, c] for r in resampled]) for c, name in enumerate(names))
    positions: tuple[Quantity, ...] = ()
    with_positions = [t for t in trials if t.segment_x_m is not None and t.position_time_s is not None]
    sources = {t.position_source for t in with_positions}
    if len(with_positions) == len(trials) and len(sources) == 1:
        n_seg = min(_positions(t)[1].shape[1] for t in trials)
        moved = [_resample(_positions(t)[0] - o, _positions(t)[1][:, :n_seg], grid) for t, o in zip(trials, offsets)]
        positions = tuple(_stack(f"seg{k + 1}_x", "m", [m[:, k] for m in moved]) for k in range(n_seg))
    elif with_positions:
        notes.append("segment positions left out: not every recording has them from the same source "
                     f"({', '.join(sorted(sources)) or 'none'})")
    result = Repeatability(tuple(t.path for t in trials), tuple(offsets), options.describe(), grid, forces,
                           positions, sources.pop() if positions and sources else "", tuple(differences),
                           tuple(notes))
    return result, trials


# -- figures of merit ----------------------------------------------------------------------------------------------
def rms_difference(trials: np.ndarray) -> float:
    """Root mean square of the difference between every pair of trials (k × T), over every instant both have."""
    squares = [np.nanmean((a - b) ** 2) for a, b in itertools.combinations(trials, 2)
               if np.isfinite(a - b).any()]
    return float(math.sqrt(np.mean(squares))) if squares else math.nan


def icc_a1(trials: np.ndarray) -> float:
    """ICC(A,1), McGraw & Wong's two-way absolute agreement of single measures: the instants (columns of the k × T
    ``trials``) are the subjects, the trials the raters; instants any trial misses are left out. NaN when it cannot
    be computed (fewer than 2 trials or instants, no variance at all)."""
    data = trials[:, np.all(np.isfinite(trials), axis=0)].T  # n subjects × k raters
    n, k = data.shape if data.ndim == 2 else (0, 0)
    if n < 2 or k < 2:
        return math.nan
    grand = data.mean()
    ms_rows = k * np.sum((data.mean(axis=1) - grand) ** 2) / (n - 1)
    ms_cols = n * np.sum((data.mean(axis=0) - grand) ** 2) / (k - 1)
    residual = data - data.mean(axis=1, keepdims=True) - data.mean(axis=0, keepdims=True) + grand
    ms_error = np.sum(residual ** 2) / ((n - 1) * (k - 1))
    denominator = ms_rows + (k - 1) * ms_error + k * (ms_cols - ms_error) / n
    return float((ms_rows - ms_error) / denominator) if denominator > 0 else math.nan


SUMMARY_COLUMNS = ("quantity", "unit", "trials", "peak_mean", "peak_sd", "peak_time_mean_s", "peak_time_sd_s",
                   "rms_difference", "icc", "note")


def summary_rows(result: Repeatability) -> list[dict[str, Any]]:
    """One row per quantity (see the module docstring, step 5)."""
    rows = []
    for quantity in (*result.forces, *result.positions):
        peaks, peak_times = [], []
        for trial in quantity.trials:
            if np.isfinite(trial).any():
                i = int(np.nanargmax(trial))
                peaks.append(float(trial[i]))
                peak_times.append(float(result.time_s[i]))
        floor = ICC_MIN_FORCE_SPREAD_N if quantity.unit == "N" else ICC_MIN_POSITION_SPREAD_M
        spread = float(np.nanstd(quantity.mean)) if np.isfinite(quantity.mean).any() else 0.0
        if spread >= floor:
            icc, note = icc_a1(quantity.trials), ""
        else:
            icc = math.nan
            note = (f"flat (its mean varies by {spread:.3g} {quantity.unit} s.d. over time, under "
                    f"{floor:g}): no ICC")
        rows.append({"quantity": quantity.name, "unit": quantity.unit, "trials": len(quantity.trials),
                     "peak_mean": _mean(peaks), "peak_sd": _sd(peaks), "peak_time_mean_s": _mean(peak_times),
                     "peak_time_sd_s": _sd(peak_times), "rms_difference": rms_difference(quantity.trials),
                     "icc": icc, "note": note})
    return rows


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def _sd(values: list[float]) -> float:
    return float(np.std(values, ddof=1)) if len(values) > 1 else math.nan


# -- files ---------------------------------------------------------------------------------------------------------
def _number(value: float) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.6g}"


def alignment_csv(result: Repeatability) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["recording", "offset_s"])
    for path, offset in zip(result.paths, result.offsets_s):
        writer.writerow([str(path), f"{offset:.6f}"])
    return out.getvalue()


def repeatability_csv(result: Repeatability) -> str:
    """``time_s`` (aligned), per bottom sensor ``<name>_mean_N``, ``<name>_sd_N``, per segment
    ``seg<k>_x_mean_m``, ``seg<k>_x_sd_m`` (when the recordings have positions)."""
    header = ["time_s"]
    columns = [result.time_s]
    for quantity in (*result.forces, *result.positions):
        header += [f"{quantity.name}_mean_{quantity.unit}", f"{quantity.name}_sd_{quantity.unit}"]
        columns += [quantity.mean, quantity.sd]
    table = np.column_stack(columns)
    out = io.StringIO()
    out.write(",".join(header) + "\n")
    for row in table:
        out.write(",".join(_number(float(v)) for v in row) + "\n")
    return out.getvalue()


def summary_csv(result: Repeatability) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in summary_rows(result):
        writer.writerow({k: _number(v) if isinstance(v, float) else v for k, v in row.items()})
    return out.getvalue()


REPORT_FILES = ("alignment.csv", "repeatability.csv", "repeatability_summary.csv", "repeatability.svg")


def write_report(result: Repeatability, out_dir: str | Path,
                 rasterise: Callable[[str, Path], object] | None = None) -> list[Path]:
    """Write the report's files into ``out_dir`` (created if needed), each whole or not at all; ``rasterise(svg,
    png_path)`` writes ``repeatability.png`` (the command line passes Qt's SVG renderer). Returns the files."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise RepeatabilityError(f"{out} is not a folder: --out names the report's folder")
    out.mkdir(parents=True, exist_ok=True)
    texts = {"alignment.csv": alignment_csv(result), "repeatability.csv": repeatability_csv(result),
             "repeatability_summary.csv": summary_csv(result), "repeatability.svg": repeatability_svg(result)}
    written = []
    for name, text in texts.items():
        write_atomically(out / name, _writer(text))
        written.append(out / name)
    if rasterise is not None:
        rasterise(texts["repeatability.svg"], out / "repeatability.png")
        written.append(out / "repeatability.png")
    return written


def _writer(text: str) -> Callable[[TextIO], object]:
    return lambda handle: handle.write(text)


# -- the figure ----------------------------------------------------------------------------------------------------
COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf", "#393b79", "#637939"]


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / count
    magnitude = 10 ** math.floor(math.log10(raw))
    step = min((m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw), default=raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]


class _Panel:
    """A plot area in SVG pixels with data limits."""

    def __init__(self, x: float, y: float, w: float, h: float, t_lim: tuple[float, float],
                 v_lim: tuple[float, float]) -> None:
        self.x, self.y, self.w, self.h = x, y, w, h
        self.t0, self.t1 = t_lim
        self.v0, self.v1 = v_lim if v_lim[1] > v_lim[0] else (v_lim[0] - 1, v_lim[0] + 1)

    def px(self, t: np.ndarray) -> np.ndarray:
        return self.x + (t - self.t0) / (self.t1 - self.t0) * self.w

    def py(self, v: np.ndarray) -> np.ndarray:
        return self.y + self.h - (v - self.v0) / (self.v1 - self.v0) * self.h

    def polyline(self, t: np.ndarray, v: np.ndarray, style: str) -> str:
        parts = []
        ok = np.isfinite(v)
        for run in np.split(np.arange(len(v)), np.flatnonzero(np.diff(ok.astype(int))) + 1):
            if run.size > 1 and ok[run[0]]:
                points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(self.px(t[run]), self.py(v[run])))
                parts.append(f'<polyline fill="none" {style} points="{points}"/>')
        return "".join(parts)

    def band(self, t: np.ndarray, lo: np.ndarray, hi: np.ndarray, colour: str) -> str:
        ok = np.isfinite(lo) & np.isfinite(hi)
        parts = []
        for run in np.split(np.arange(len(t)), np.flatnonzero(np.diff(ok.astype(int))) + 1):
            if run.size > 1 and ok[run[0]]:
                xs = np.concatenate([self.px(t[run]), self.px(t[run])[::-1]])
                ys = np.concatenate([self.py(hi[run]), self.py(lo[run])[::-1]])
                points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(xs, ys))
                parts.append(f'<polygon fill="{colour}" fill-opacity="0.25" stroke="none" points="{points}"/>')
        return "".join(parts)

    def axes(self, t_label: str, v_label: str, title: str, font: int = 11) -> str:
        parts = [f'<rect x="{self.x}" y="{self.y}" width="{self.w}" height="{self.h}" fill="none" '
                 f'stroke="#444444"/>']
        for tick in _ticks(self.t0, self.t1, max(3, int(self.w // 80))):
            x = float(self.px(np.array(tick)))
            parts.append(f'<line x1="{x:.1f}" y1="{self.y + self.h}" x2="{x:.1f}" y2="{self.y + self.h + 3}" '
                         f'stroke="#444444"/>')
            parts.append(f'<text x="{x:.1f}" y="{self.y + self.h + 4 + font}" text-anchor="middle" '
                         f'font-size="{font - 1}">{tick:g}</text>')
        for tick in _ticks(self.v0, self.v1, max(3, int(self.h // 60))):
            y = float(self.py(np.array(tick)))
            parts.append(f'<line x1="{self.x}" y1="{y:.1f}" x2="{self.x + self.w}" y2="{y:.1f}" stroke="#e4e4e4"/>')
            parts.append(f'<text x="{self.x - 4}" y="{y + 4:.1f}" text-anchor="end" font-size="{font - 1}">'
                         f'{tick:g}</text>')
        if t_label:
            parts.append(f'<text x="{self.x + self.w / 2}" y="{self.y + self.h + 2 * font + 6}" '
                         f'text-anchor="middle" font-size="{font}">{_escape(t_label)}</text>')
        if v_label:
            parts.append(f'<text transform="translate({self.x - 38},{self.y + self.h / 2}) rotate(-90)" '
                         f'text-anchor="middle" font-size="{font}">{_escape(v_label)}</text>')
        if title:
            parts.append(f'<text x="{self.x + 4}" y="{self.y + font + 2}" font-size="{font}" '
                         f'font-weight="bold">{_escape(title)}</text>')
        return "".join(parts)


def _limits(quantities: Sequence[Quantity]) -> tuple[float, float]:
    values = [q.trials[np.isfinite(q.trials)] for q in quantities]
    values += [(q.mean + q.sd)[np.isfinite(q.mean + q.sd)] for q in quantities]
    values += [(q.mean - q.sd)[np.isfinite(q.mean - q.sd)] for q in quantities]
    flat = np.concatenate(values) if values else np.zeros(0)
    if not flat.size:
        return 0.0, 1.0
    lo, hi = float(flat.min()), float(flat.max())
    pad = 0.05 * (hi - lo) if hi > lo else 0.5
    return lo - pad, hi + pad


def _quantity_lines(panel: _Panel, time_s: np.ndarray, quantity: Quantity, colour: str) -> str:
    parts = [panel.band(time_s, quantity.mean - quantity.sd, quantity.mean + quantity.sd, colour)]
    for trial in quantity.trials:
        parts.append(panel.polyline(time_s, trial, f'stroke="{colour}" stroke-width="0.6" stroke-opacity="0.6"'))
    parts.append(panel.polyline(time_s, quantity.mean, f'stroke="{colour}" stroke-width="1.8"'))
    return "".join(parts)


def repeatability_svg(result: Repeatability) -> str:
    """The paper's Fig. 7 layout: (A) each segment's forward position against aligned time; (B) each bottom sensor's
    force against aligned time, one small panel per sensor with a common force axis. Mean line, ±1 s.d. band, each
    trial a thin line; the title says what was aligned on and how many trials."""
    width, height = 1280, 780
    t = result.time_s
    t_lim = (float(t[0]), float(t[-1])) if len(t) > 1 else (0.0, 1.0)
    title = (f"Repeatability: {result.n_trials} trials aligned on {result.align}; mean line, ±1 s.d. band, "
             f"each trial thin")
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
             f'font-size="12"><rect width="100%" height="100%" fill="white"/>',
             f'<text x="{width / 2}" y="22" text-anchor="middle" font-size="15">{_escape(title)}</text>']
    subtitle = "time 0 = the event on each recording's own clock (alignment.csv)"
    if result.differences:
        subtitle += f"; MIXED conditions: {result.differences[0]}" + (
            f" (+{len(result.differences) - 1} more)" if len(result.differences) > 1 else "")
    parts.append(f'<text x="{width / 2}" y="40" text-anchor="middle" font-size="11" fill="#555555">'
                 f'{_escape(subtitle)}</text>')
    a_panel = _Panel(80, 70, 420, 620, t_lim, _limits(result.positions) if result.positions else (0.0, 1.0))
    source = {"mocap": "motion capture", "sim": "simulated body"}.get(result.position_source, "")
    parts.append(a_panel.axes("aligned time (s)", "segment forward position x (m)",
                              f"A  segment position{f' ({source})' if source else ''}"))
    if result.positions:
        for k, quantity in enumerate(result.positions):
            parts.append(_quantity_lines(a_panel, t, quantity, COLOURS[k % len(COLOURS)]))
            last = np.flatnonzero(np.isfinite(quantity.mean))
            if last.size:
                y = float(a_panel.py(np.array(quantity.mean[last[-1]])))
                parts.append(f'<text x="{a_panel.x + a_panel.w + 3}" y="{y + 3:.1f}" font-size="9" '
                             f'fill="{COLOURS[k % len(COLOURS)]}">{k + 1}</text>')
    else:
        parts.append(f'<text x="{a_panel.x + a_panel.w / 2}" y="{a_panel.y + a_panel.h / 2}" text-anchor="middle" '
                     f'fill="#777777">no segment positions (/mocap or /sim) in these recordings</text>')
    n = len(result.forces)
    columns = 3
    rows = max(1, math.ceil(n / columns))
    bx, by, bw, bh = 590.0, 70.0, 670.0, 640.0
    cell_w, cell_h = bw / columns, bh / rows
    v_lim = _limits(result.forces)
    parts.append(f'<text x="{bx}" y="{by - 8}" font-size="12" font-weight="bold">B  bottom sensor force (N)</text>')
    for i, quantity in enumerate(result.forces):
        r, c = divmod(i, columns)
        panel = _Panel(bx + c * cell_w + 36, by + r * cell_h + 6, cell_w - 50, cell_h - 30, t_lim, v_lim)
        last_row = r == rows - 1 or i + columns >= n
        parts.append(panel.axes("aligned time (s)" if last_row else "", "", quantity.name, font=10))
        parts.append(_quantity_lines(panel, t, quantity, "#1f4e9c"))
    parts.append("</svg>")
    return "".join(parts)
