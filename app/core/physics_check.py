"""How true a physics-lab run's forces are, read from its recording alone (``/sim``, ``/daq``, ``/forces``).

:func:`check_recording` answers, for one recording of ``sensnake experiment run``:

- **weight**: the bottom sheets' true normal forces summed, against the robot's weight, frame by frame (on flat ground
  they must match; on a curve the normals add up to more, see :mod:`app.core.experiment`), and the same with each
  sheet's force taken along its segment's up axis (what must match the weight on any terrain, less what friction
  holds up, which no sheet feels), and every sheet's force summed (a body that rolled onto its side carries its
  weight on its side sheets); and, from ``/sim/support_N`` and ``/sim/sheet_support_N`` when the recording has them,
  the upward part of the *whole* contact forces (normal and friction) on the bottom sheets and on the whole robot:
  Newton's check, the weight on any terrain when nothing accelerates, which the sheets' readings (pressure only)
  cannot be on a curve or a slope held by friction;
- **jumps**: how often a sheet's force changes by more than ``jump_n`` between two board frames (30 Hz), in the
  true forces and in the app's estimated ones, and how many of those are *reversals* (a jump followed at once by
  one the other way: chatter, as opposed to a load moving fast); and how many of them come while the body moves
  slowly (no point of it faster than ``FAST_M_S`` around the frame): a jump while the body falls off a crest, tips
  over or lands is an event a real robot's sheets feel too, one while it creeps is a load moving fast or chatter;
- **accuracy** of the whole sensing chain on moving contact: the estimated forces (board → sensor model →
  estimator, what the Forces tab shows) against the true ones at the board's sample times, RMS and 99th
  percentile per sheet, over the sheets that were loaded at some time. A sample the recording flags
  ``READOUT_SATURATED`` (``/forces/status``: the readout at its ceiling, the force only a lower bound) is left out
  of the error and counted apart (``estimated_saturated_frames``).

The checks cover the play — the ticks before the motion was over (``/sim`` ``motion_end_s``), where the tables of
docs/PHYSICS_LAB.md come from — unless asked for the whole recording, the run's wait for the body to come to rest
included (``whole=True``).

A recording of a run whose physics stopped being physics (``/sim`` attribute ``valid`` = 0, ``invalid_reason``) is
refused (:class:`InvalidRecordingError`): its forces are not data. ``allow_invalid=True`` reads it anyway, and the
check then says so (``valid``, ``invalid_reason``).

Pure numpy and h5py; any thread.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.errors import InvalidRecordingError
from devices.scene import channel_map
from models.sls import ForceStatus

BOARD_PERIOD_S = 1.0 / 30.0
# A body point faster than this is falling, tipping over or sliding away: the gaits' fastest point moves at under
# 0.1 m/s on every built-in scene and five others while nothing falls (0.3 rad/s), a fall or a tip at 0.3–1.5 m/s.
FAST_M_S = 0.2


@dataclass(frozen=True)
class PhysicsCheck:
    frames: int
    weight_n: float
    bottom_within_10pct: float  # fraction of ticks with the bottom sheets' sum within ±10 % of the weight
    vertical_within_10pct: float  # … the same for their force along each segment's up axis
    median_bottom_n: float
    median_vertical_n: float
    all_sheets_within_10pct: float  # … the same for every sheet's force summed (a body rolled onto its side, too)
    true_jump_frames: float  # fraction of 30 Hz frames with a > jump_n change on some sheet (true forces)
    true_reversal_frames: float  # … of which followed at once by a jump the other way (chatter)
    estimated_jump_frames: float
    estimated_reversal_frames: float
    median_rms_n: float  # median over loaded sheets of the estimated force's RMS error
    worst_rms_n: float
    median_p99_n: float
    worst_p99_n: float
    estimated_saturated_frames: float = math.nan  # fraction of frames with a sheet at the readout's ceiling
    support_within_10pct: float = math.nan  # … every contact force's upward part on the robot (normal and friction)
    bottom_support_within_10pct: float = math.nan  # … the bottom sheets' whole contact forces' upward part
    median_bottom_support_n: float = math.nan
    fast_frames: float = math.nan  # fraction of 30 Hz frames in which some body point moves faster than FAST_M_S
    true_jump_frames_slow: float = math.nan  # fraction of frames with a > jump_n change while the body moves slowly
    true_reversal_frames_slow: float = math.nan  # … of which reversing (chatter while nothing falls)
    valid: bool = True  # False only with allow_invalid: the run's physics stopped being physics (invalid_reason)
    invalid_reason: str = ""


def _nan_or(reduce: Callable[[np.ndarray], Any], values: np.ndarray) -> float:
    """``reduce`` over the finite values; NaN when there are none (no estimate recorded, no sheet loaded)."""
    finite = values[np.isfinite(values)]
    return float(reduce(finite)) if finite.size else math.nan


def _jump_steps(series: np.ndarray, jump_n: float) -> tuple[np.ndarray, np.ndarray]:
    """Per step between rows: (a > jump_n change on some channel, one that reverses at the next step)."""
    if len(series) < 3:
        return np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
    steps = np.diff(series, axis=0)
    big = np.abs(steps) > jump_n
    reversal = np.zeros(len(steps), dtype=bool)
    reversal[:-1] = (big[:-1] & big[1:] & (np.sign(steps[:-1]) != np.sign(steps[1:]))).any(axis=1)
    return np.asarray(big.any(axis=1), dtype=bool), reversal


def _fractions(big: np.ndarray, reversal: np.ndarray) -> tuple[float, float]:
    """(fraction of steps with a jump, fraction that reverse at the next step) from :func:`_jump_steps`."""
    if not len(big):
        return 0.0, 0.0
    return float(np.mean(big)), float(np.mean(reversal[:-1]))


def _jumps(series: np.ndarray, jump_n: float) -> tuple[float, float]:
    """(fraction of steps with a > jump_n change on some channel, fraction that reverse at the next step)."""
    return _fractions(*_jump_steps(series, jump_n))


def _fast_steps(sim_t: np.ndarray, points: np.ndarray, frames_at: np.ndarray) -> np.ndarray:
    """Per step between board frames: did some body point move faster than ``FAST_M_S`` over a tick from one tick
    before the step to one tick after it."""
    steps = max(len(frames_at) - 1, 0)
    if len(sim_t) < 2 or not steps:
        return np.zeros(steps, dtype=bool)
    speed = np.linalg.norm(np.diff(points, axis=0), axis=2).max(axis=1) / np.maximum(np.diff(sim_t), 1e-9)
    tick = float(np.median(np.diff(sim_t)))
    ends = sim_t[1:]  # each speed is over the tick that ends here
    start = np.searchsorted(ends, frames_at[:-1] - tick, side="left")
    stop = np.searchsorted(ends, frames_at[1:] + tick, side="right")
    return np.array([b > a and speed[a:b].max() > FAST_M_S for a, b in zip(start, stop)], dtype=bool)


def check_recording(path: str | Path, jump_n: float = 1.0, allow_invalid: bool = False,
                    whole: bool = False) -> PhysicsCheck:
    """See the module docstring. Over the play (the ticks before ``/sim`` ``motion_end_s``, as before runs went on
    to rest after it), or with ``whole`` the whole recording, the wait for rest included. Raises ``KeyError`` naming
    what a recording without ``/sim`` lacks, and :class:`InvalidRecordingError` for an invalid run's recording
    unless ``allow_invalid``."""
    with h5py.File(path, "r") as f:
        if "sim" not in f or "sheet_true_N" not in f["sim"]:
            raise KeyError(f"{path}: no /sim/sheet_true_N (not a recording of sensnake experiment run)")
        valid = bool(int(f["sim"].attrs.get("valid", 1)))  # a recording from before the attribute: as it was read
        invalid_reason = str(f["sim"].attrs.get("invalid_reason", ""))
        if not valid and not allow_invalid:
            raise InvalidRecordingError(f"{path}: the run is marked invalid ({invalid_reason}); its forces are not "
                                        f"data")
        sim_t = f["sim/time_s"][:]
        motion_end_s = float(f["sim"].attrs.get("motion_end_s", math.nan))
        played = slice(None) if whole or math.isnan(motion_end_s) else \
            slice(0, max(int(np.searchsorted(sim_t, motion_end_s - 1e-9)), 2))
        sim_t = sim_t[played]
        true = f["sim/sheet_true_N"][played]
        points = f["sim/points_m"][played]
        weight = float(f["sim"].attrs["weight_N"])
        robot_t = f["robot/time_s"][:]
        channels = [c.decode() if isinstance(c, bytes) else str(c) for c in f["daq"].attrs["channels"]]
        daq_t = f["daq/time_s"][:]
        estimated = f["forces/force_N"][:] if "forces" in f else None
        status = f["forces/status"][:] if "forces" in f and "status" in f["forces"] else None
        support = f["sim/support_N"][played] if "support_N" in f["sim"] else None
        sheet_support = f["sim/sheet_support_N"][played] if "sheet_support_N" in f["sim"] else None
    rows, segments = channel_map(channels, points.shape[1] - 1)
    bottom = rows == 0
    bottom_sum = true[:, bottom].sum(axis=1)
    # each segment's up axis from the recorded points: perpendicular to its axis, in the vertical plane through it
    axis = points[:, 1:] - points[:, :-1]
    axis /= np.linalg.norm(axis, axis=2, keepdims=True)
    up_z = np.sqrt(np.clip(1.0 - axis[:, :, 2] ** 2, 0.0, 1.0))  # cos of the segment's pitch from horizontal
    vertical = (true[:, bottom] * up_z[:, segments[bottom]]).sum(axis=1)
    # the recording's clock: robot ticks are sim ticks (same count), board samples on the same clock
    offset = robot_t[0] - sim_t[0]
    frames_at = np.arange(sim_t[0], sim_t[-1], BOARD_PERIOD_S)
    true_frames = np.column_stack([np.interp(frames_at, sim_t, true[:, c]) for c in range(true.shape[1])])
    big, reversing = _jump_steps(true_frames, jump_n)
    true_jump, true_reversal = _fractions(big, reversing)
    fast = _fast_steps(sim_t, points, frames_at)[:len(big)]
    slow_jump, slow_reversal = _fractions(big & ~fast, reversing & ~fast)
    est_jump = est_reversal = float("nan")
    rms = p99 = np.array([np.nan])
    saturated_frames = math.nan
    if estimated is not None:
        t = daq_t - offset
        inside = (t >= sim_t[0]) & (t <= sim_t[-1])
        est = estimated[inside]
        est_jump, est_reversal = _jumps(np.nan_to_num(est), jump_n)
        truth = np.column_stack([np.interp(t[inside], sim_t, true[:, c]) for c in range(true.shape[1])])
        loaded = (truth > 0.05).any(axis=0) & (rows >= 0)
        error = est[:, loaded] - truth[:, loaded]
        if status is not None:  # a lower bound is not an estimate: left out of the error, counted apart
            censored = status[inside] == ForceStatus.READOUT_SATURATED
            error = np.where(censored[:, loaded], np.nan, error)
            saturated_frames = float(np.mean(censored.any(axis=1))) if len(censored) else 0.0
        judged = np.isfinite(error).any(axis=0)  # a sheet whose every sample is a lower bound is not judged
        rms = np.full(error.shape[1], np.nan)
        p99 = np.full(error.shape[1], np.nan)
        if judged.any():
            rms[judged] = np.sqrt(np.nanmean(error[:, judged] ** 2, axis=0))
            p99[judged] = np.nanpercentile(np.abs(error[:, judged]), 99, axis=0)
    def within(values: np.ndarray | None) -> float:
        return float(np.mean(np.abs(values - weight) <= 0.1 * weight)) if values is not None and len(values) \
            else math.nan

    bottom_support = sheet_support[:, bottom].sum(axis=1) if sheet_support is not None else None
    return PhysicsCheck(
        frames=len(true), weight_n=weight,
        bottom_within_10pct=float(np.mean(np.abs(bottom_sum - weight) <= 0.1 * weight)),
        vertical_within_10pct=float(np.mean(np.abs(vertical - weight) <= 0.1 * weight)),
        median_bottom_n=float(np.median(bottom_sum)), median_vertical_n=float(np.median(vertical)),
        all_sheets_within_10pct=float(np.mean(np.abs(true[:, rows >= 0].sum(axis=1) - weight) <= 0.1 * weight)),
        true_jump_frames=true_jump, true_reversal_frames=true_reversal,
        estimated_jump_frames=est_jump, estimated_reversal_frames=est_reversal,
        median_rms_n=_nan_or(np.nanmedian, rms), worst_rms_n=_nan_or(np.nanmax, rms),
        median_p99_n=_nan_or(np.nanmedian, p99), worst_p99_n=_nan_or(np.nanmax, p99),
        estimated_saturated_frames=saturated_frames,
        support_within_10pct=within(support), bottom_support_within_10pct=within(bottom_support),
        median_bottom_support_n=float(np.median(bottom_support)) if bottom_support is not None and
        len(bottom_support) else math.nan,
        fast_frames=float(np.mean(fast)) if len(fast) else 0.0,
        true_jump_frames_slow=slow_jump, true_reversal_frames_slow=slow_reversal,
        valid=valid, invalid_reason=invalid_reason,
    )
