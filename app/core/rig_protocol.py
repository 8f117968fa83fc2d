"""The calibration protocol on the rig (paper Sec. IV-C), without Qt: forces × trials, each trial held and sampled.

For each force in ``forces_n`` and each of ``trials_per_force`` repeats (force-major order, the paper's 4 × 3):
the sensor rests unloaded (probe lifted) for ``rest_s`` — also before the first trial, since the contact search
loads the sensor to about 2 N — then sampling starts with ``baseline_s`` still unloaded (so the record holds the
unloaded level and the loading ramp, which identify E0; the probe is lifted rather than just touching, so the force
column reads exactly 0 N there instead of a tick's worth of spring stretch); the rig ramps the force up linearly over
``ramp_s`` (paced by the servo's own Profile Velocity, :meth:`devices.rig.CalibrationRig.start_ramp`: a servo left to
itself at full speed loads in a fraction of a second, too fast for a 6 Hz record to see the ramp and for the fit to
identify E0; one goal per sample would stall wherever a busy computer's thread does) and the trial samples
``time_s``, the rig's applied force (``F = k·r·(θ − θ_contact)`` from the servo's present position, SPEC §2) and the
sensor's conductance at ``sample_rate_hz`` for ``hold_s`` from the command; then the load comes off and the trial is
written as a SPEC §3.1 CSV into the session folder. The contact is found once, at the start.

Conditioning (optional, ``condition_cycles`` > 0): after the contact search and before the first trial's rest, the
rig loads the sensor to ``conditioning_force_n`` over the protocol's ramp, holds it ``condition_load_s``, unloads it
for ``condition_unload_s``, N times (piezo-resistive sheets are conditioned before calibration). Nothing of it is a
trial; each cycle is logged in the session's ``conditioning.json``. A resumed session skips a conditioning the log
says finished, and one begun after trials were recorded; an interrupted conditioning starts over.

Conductance comes from the board stream (:class:`ConductanceFeed`: the board's samples of the sensor's channel,
pushed by whoever drains the board, with their host ``time.monotonic()`` and board-clock times). Each trial row takes
the mean of the board samples in the sampling interval centred on its time (a boxcar decimation from the board's
rate to ``sample_rate_hz``; centred, so that it lines up with the force read at that time), computed when the trial ends, so a late delivery of board data (a busy GUI) does not
misalign force and conductance. The samples are placed on the host clock through the board's own clock
(:func:`board_times_on_host_clock`): a frame's host time is when the reader got to it, late by however long the
reader thread waited for the CPU, while the board clock ticks evenly.

Control (any thread): :meth:`ProtocolRunner.abort` ends the run at once — the load comes off, the trial in progress is
discarded, the finished trials stay on disk. :meth:`ProtocolRunner.pause` takes effect after the trial in progress
(a creep hold cannot be paused without spoiling it): the rig stays unloaded until :meth:`ProtocolRunner.resume`.
A rig error (pulled cable, no reply, overload) or a board stream that stops ends the run with a message that says
what happened and what to do; finished trials stay on disk.

Clock: the protocol's times (hold, rest, baseline, ramp, sampling) are the lab's seconds. ``time_scale`` > 1 runs the
protocol that much faster than the wall clock, for a simulated lab whose clock runs accelerated (``SimLab(speed=X)``):
give the runner the lab's clock (``clock=lab.clock.now``) and push the board's samples on it
(:func:`lab_times_from_seq`), since host arrival times are too coarse once a wall millisecond is X lab ones.

Resume: ``done`` (plan index → CSV) lists trials a previous run of the same session folder finished; they are kept
and skipped, so a run cut short (Ctrl-C, a crash, ``kill -9``) continues with the interrupted trial, which is redone.
A trial's CSV is written atomically when it completes, so a file in the folder is a finished trial.

Safety: the rig refuses a force above its maximum (``rig.max_force_n``) or past the spring's travel; every sample
reads the rig servo, so a servo error (overload, …) ends the run; a reading that collapses during a hold (cable snap,
probe slip: the sensor's conductance falls back most of the way to its unloaded level) aborts the trial with the reason.

Threads: :meth:`ProtocolRunner.run` blocks and owns the rig; call it from one worker thread (``app.gui.rig_session``
does). The callbacks are called from that thread.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from app.core import calfiles
from app.core.errors import (
    BoardGapError,
    BoardStreamError,
    ForceCollapsedError,
    RigReadGapError,
    TrialGapError,
)
from devices.config import BoardConfig, RigConfig
from devices.errors import DeviceError, RigInterrupted
from devices.rig import ANGLE_LIMIT_RAD
from devices.toml_files import read_state_file
from models.physics import PhysicsConstants, conductance_from_strain
from models.sls import TYPICAL_SLS, SLSParams

PAPER_FORCES_N = (1.75, 3.0, 4.0, 5.25)
PAPER_HOLD_S = 370.0
BOARD_STALE_S = 5.0  # no board sample of the sensor for this long (seconds of the lab clock) ends the run
PROGRESS_INTERVAL_S = 0.5  # progress callbacks during rests and pauses
FEED_CAPACITY = 1 << 16  # board samples kept by the feed (≈ 36 min at the board's default 30 Hz)
# A trial whose board samples leave a stretch uncovered that interpolation cannot bridge is not kept (frames lost: a
# pulled cable, a host too busy to read the board): over the loading edge more than EDGE_GAP_PERIODS sample periods
# (the step itself would be made up), elsewhere more than GAP_CREEP_FRACTION of the creep time (a straight line over
# 10 s of a creep with τ ≥ 100 s is off by ~0.1 % of its rise) or MAX_GAP_PERIODS periods, whichever is longer. It
# runs again once, after its rest; a second such gap ends the run.
EDGE_GAP_PERIODS = 3
MAX_GAP_PERIODS = 5
GAP_CREEP_FRACTION = 0.1
GAP_RETRIES = 1
# A force read on the loading ramp that took longer than this many sample periods (the thread held up between asking
# the servo and hearing it: a busy machine) has no time to pair it with the sensor's reading within an eighth period:
# the row is left out, as one whose moment went by is (a time off by 3 s on the ramp made a whole trial a "poor fit").
# Elsewhere the force stands still (the probe lifted, or held), so when it was read does not matter.
MAX_READ_SPAN_PERIODS = 0.25
# The servo paces the loading ramp (a straight line in time, between the knee where the probe touches and the corner
# where it reaches the goal), so the rig's force record may skip part of it: a gap up to this fraction of the ramp
# (or EDGE_GAP_PERIODS sample periods) cuts a corner by at most rate × gap² / 8 of force × time — 0.3 % of the creep
# of a τ = 20 s sensor at a 2 s ramp. A longer gap over the loading edge leaves the ramp unrecorded (E0 then rests on
# nothing): the trial is not kept and runs again, as one with a board gap does.
RAMP_GAP_FRACTION = 0.5
# ... and runs again up to this many times (a busy spell of the computer often outlasts one trial; at 60× real time,
# beside 6 busy processes on 2 cores, 1 run in 6 once met two such trials in a row).
READ_GAP_RETRIES = 3
LATE_DATA_WAIT_S = 1.0  # at a trial's end, how long to wait for board samples that cover its last interval

MIN_HOLD_SAMPLES = 10  # samples at full force the fit needs (models.calibration refuses fewer)
MIN_WINDOW_SAMPLES = 3  # samples in the linear model's averaging window
# A hold whose reading falls below baseline + this fraction of its rise, for COLLAPSE_ROWS rows in a row, collapsed.
COLLAPSE_FRACTION = 0.3
COLLAPSE_ROWS = 3
COLLAPSE_MIN_RISE = 0.05  # ... judged only when the hold rose by this fraction of its level (a dead sensor is the fit's)
# The servo's range past the centre (rad): the most winding past a contact near the centre the spring can get.
MAX_WINDING_RAD = ANGLE_LIMIT_RAD
REFINE_SPAN_RAD = 0.05  # the contact refinement searches this far either side of the current's estimate
REFINE_STEP_RAD = 2 * math.pi / 4096  # one encoder tick: k·r × 1.5 mrad ≈ 0.008 N on the paper's rig
REFINE_RISE_S = 5e-6  # a reading this far above the unloaded level is the probe touching (S)
REFINE_SAMPLES = 2
MAX_CLOCK_RATE_ERROR = 1e-3  # board clock vs host clock rate (crystals: ~1e-4)
READOUT_MARGIN = 0.9
CREEP_TIME_S = 100.0  # the paper's creep time (~10² s, Fig. 8B)
REST_CREEP_TIMES = 3.0  # rests shorter than this many creep times are warned about  # a predicted reading above this fraction of the readout's ceiling is reported

class RunOutcome(StrEnum):
    """How a rig run ended (equal to its plain string)."""

    COMPLETED = "completed"
    ABORTED = "aborted"
    FAILED = "failed"
    INTERRUPTED = "interrupted"  # aborted by a signal to `sensnake calibrate` (Ctrl-C, SIGTERM)


COMPLETED, ABORTED, FAILED = RunOutcome.COMPLETED, RunOutcome.ABORTED, RunOutcome.FAILED
SESSION_FILE = "protocol.json"
CONDITIONING_FILE = "conditioning.json"  # the conditioning cycles' log (ProtocolRunner._condition)


class RigDevice(Protocol):
    """What the runner needs from :class:`devices.rig.CalibrationRig` (one thread calls it)."""

    def find_contact(self) -> float: ...
    def command_force(self, force_n: float) -> float: ...
    def start_ramp(self, force_n: float, duration_s: float) -> float: ...
    def applied_force_n(self) -> float: ...
    def release(self) -> None: ...


@runtime_checkable
class RefinableRig(RigDevice, Protocol):
    """A rig that can also be wound to an angle and holds its contact angle (the real and simulated rigs; not the
    tests' simple doubles): the runner then refines the contact with the sensor's own reading."""

    contact_rad: float | None

    def move_to(self, angle_rad: float) -> float: ...


@dataclass(frozen=True)
class ProtocolSettings:
    """The protocol's parameters: forces (N), repeats, hold, rest and baseline (s, wall clock), sampling rate
    (Hz), the sensor (board channel name), its area (m²) and the folder the session folder is made in."""

    forces_n: tuple[float, ...] = PAPER_FORCES_N
    trials_per_force: int = 3
    hold_s: float = PAPER_HOLD_S
    sample_rate_hz: float = 6.0
    rest_s: float = 60.0
    baseline_s: float = 3.0
    ramp_s: float = 2.0
    sensor: str = "S06B"
    area_m2: float = 1.4e-3
    # Conditioning before the protocol (off with 0 cycles): load/unload cycles at condition_force_n (0: the top
    # force of the protocol), each loaded for condition_load_s and unloaded for condition_unload_s (lab s); not
    # recorded as trials, logged in the session's conditioning.json.
    condition_cycles: int = 0
    condition_force_n: float = 0.0
    condition_load_s: float = 10.0
    condition_unload_s: float = 10.0

    def __post_init__(self) -> None:
        forces = tuple(float(f) for f in self.forces_n)
        object.__setattr__(self, "forces_n", forces)
        if not forces:
            raise ValueError("forces: give at least one force (N)")
        bad = [f for f in forces if not (math.isfinite(f) and f > 0)]
        if bad:
            raise ValueError(f"forces: {bad[0]:g} N is not a positive force")
        if not (isinstance(self.trials_per_force, int) and self.trials_per_force >= 1):
            raise ValueError(f"trials per force must be 1 or more, got {self.trials_per_force!r}")
        checks = (("hold", self.hold_s, 0.0), ("rest", self.rest_s, -1e-12), ("baseline", self.baseline_s, -1e-12),
                  ("ramp", self.ramp_s, -1e-12),
                  ("sample rate", self.sample_rate_hz, 0.0), ("area", self.area_m2, 0.0))
        for name, value, above in checks:
            if not (math.isfinite(value) and value > above):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not self.sensor.strip():
            raise ValueError("name the sensor (e.g. S06B)")
        if not (isinstance(self.condition_cycles, int) and self.condition_cycles >= 0):
            raise ValueError(f"conditioning cycles must be 0 (off) or more, got {self.condition_cycles!r}")
        if not (math.isfinite(self.condition_force_n) and self.condition_force_n >= 0):
            raise ValueError(f"conditioning force must be a positive force (N) or 0 for the top force, got "
                             f"{self.condition_force_n!r}")
        for name, value in (("conditioning load time", self.condition_load_s),
                            ("conditioning unload time", self.condition_unload_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
        if self.ramp_s >= self.hold_s:
            raise ValueError(f"the loading ramp ({self.ramp_s:g} s) must be shorter than the hold ({self.hold_s:g} s)")
        held = (self.hold_s - self.ramp_s) * self.sample_rate_hz
        if held < MIN_HOLD_SAMPLES:
            raise ValueError(
                f"a {self.hold_s:g} s hold with a {self.ramp_s:g} s ramp at {self.sample_rate_hz:g} Hz leaves "
                f"{max(0, int(held))} samples at full force; the fit needs at least {MIN_HOLD_SAMPLES}: lengthen the "
                "hold, shorten the ramp or sample faster")
        lo, hi = self.fit_window_s()
        if (hi - lo) * self.sample_rate_hz < MIN_WINDOW_SAMPLES:
            raise ValueError(f"the linear model's averaging window ({lo:g}–{hi:g} s) holds fewer than "
                             f"{MIN_WINDOW_SAMPLES} samples at {self.sample_rate_hz:g} Hz: lengthen the hold or "
                             "sample faster")
        if self.baseline_s * self.sample_rate_hz < 2:
            raise ValueError(f"a {self.baseline_s:g} s baseline at {self.sample_rate_hz:g} Hz gives fewer than 2 "
                             "unloaded samples: the fit needs the unloaded level before the ramp")

    @property
    def plan(self) -> tuple[tuple[float, int], ...]:
        """(force N, repeat number from 1) of every trial, in the order they run."""
        return tuple((force, repeat) for force in self.forces_n for repeat in range(1, self.trials_per_force + 1))

    @property
    def n_trials(self) -> int:
        return len(self.forces_n) * self.trials_per_force

    def trial_duration_s(self) -> float:
        """Recorded length of one trial (s): baseline + hold."""
        return self.baseline_s + self.hold_s

    @property
    def conditioning_force_n(self) -> float:
        """The conditioning cycles' force (N): ``condition_force_n``, or the protocol's top force when 0."""
        return self.condition_force_n or max(self.forces_n)

    def conditioning_duration_s(self) -> float:
        """Expected length of the conditioning (s): every cycle's ramp, load and unload; 0 when off."""
        return self.condition_cycles * (self.ramp_s + self.condition_load_s + self.condition_unload_s)

    def total_duration_s(self) -> float:
        """Expected run time (s) without contact search and settling: the conditioning, every trial and the rest
        before each."""
        return self.conditioning_duration_s() + self.n_trials * (self.trial_duration_s() + self.rest_s)

    def fit_window_s(self) -> tuple[float, float]:
        """The linear model's averaging window (s of trial time): the paper's 225–300 s of a 370 s hold, scaled to
        this hold and shifted by the baseline."""
        scale = self.hold_s / PAPER_HOLD_S
        return (self.baseline_s + 225.0 * scale, self.baseline_s + 300.0 * scale)


@dataclass(frozen=True)
class TrialRecord:
    """A finished trial: its CSV, force commanded (N), repeat, and the arrays written (s, N, S)."""

    index: int  # 0-based position in the plan
    path: Path
    force_n: float
    repeat: int
    time_s: np.ndarray
    applied_force_n: np.ndarray
    conductance_s: np.ndarray


@dataclass(frozen=True)
class Progress:
    """Where the run is: ``phase`` one of contact / conditioning / baseline / loading / hold / release / rest / paused
    / redo (a trial not kept, to run again: ``message`` says why) / done;
    ``trial`` 0-based (−1 before the first), ``elapsed_s`` in the phase's trial (s), ``time_left_s`` for the whole
    run (estimate, s)."""

    phase: str
    trial: int
    n_trials: int
    force_n: float
    repeat: int
    elapsed_s: float
    time_left_s: float
    message: str


@dataclass(frozen=True)
class Sample:
    """One live sample of the trial in progress: trial time (s), applied force (N), latest conductance (S)."""

    trial: int
    time_s: float
    force_n: float
    conductance_s: float


@dataclass(frozen=True)
class Outcome:
    """How a run ended: ``status`` completed / aborted / failed, a message for the user, the session folder and
    the trials written."""

    status: RunOutcome
    message: str
    folder: Path
    trials: tuple[TrialRecord, ...] = field(default_factory=tuple)


class ConductanceFeed:
    """Thread-safe store of the sensor's board samples: ``push`` from the thread that drains the board, ``window``
    and ``latest`` from the runner. A fixed ring (no per-sample append); times are host ``time.monotonic()`` (s)."""

    def __init__(self, capacity: int = FEED_CAPACITY, time_scale: float = 1.0,
                 source_alive_s: Callable[[], float] | None = None) -> None:
        self.time_scale = float(time_scale)  # host times are stored × this (the runner's clock; see the module doc)
        # ``time.monotonic()`` of the newest frame the board's reader thread has received, drained or not: frames
        # waiting for a busy thread to push them here are late, not missing (see :meth:`last_alive_wall_s`).
        self._source_alive_s = source_alive_s
        self._t = np.full(capacity, -np.inf)
        self._b = np.full(capacity, np.nan)
        self._c = np.full(capacity, np.nan)
        self._n = 0  # samples ever pushed
        self.last_push_wall_s = -math.inf  # time.monotonic() of the last push (s): is the board still streaming?
        self._lock = threading.Lock()

    def push(self, host_time_s: np.ndarray, conductance_s: np.ndarray, board_time_s: np.ndarray | None = None) -> None:
        """Add samples: host times (non-decreasing, s), conductance (S), board-clock times (s; NaN if unknown).
        Any thread."""
        t = np.asarray(host_time_s, dtype=np.float64).ravel() * self.time_scale
        c = np.asarray(conductance_s, dtype=np.float64).ravel()
        b = (np.full(t.shape, np.nan) if board_time_s is None
             else np.asarray(board_time_s, dtype=np.float64).ravel())
        cap = self._t.size
        if t.size > cap:
            t, c, b = t[-cap:], c[-cap:], b[-cap:]
        with self._lock:
            self.last_push_wall_s = time.monotonic()
            idx = (self._n + np.arange(t.size)) % cap
            self._t[idx] = t
            self._b[idx] = b
            self._c[idx] = c
            self._n += t.size

    def last_alive_wall_s(self) -> float:
        """``time.monotonic()`` of the newest sign that the board streams: a push here, or a frame its reader has
        received that the thread draining it has not pushed yet (a GUI thread starved by a busy machine)."""
        alive = self._source_alive_s() if self._source_alive_s is not None else -math.inf
        return max(self.last_push_wall_s, alive)

    def latest(self) -> tuple[float, float]:
        """(time s, conductance S) of the newest sample, or (−inf, nan) if none arrived yet."""
        with self._lock:
            if self._n == 0:
                return -math.inf, math.nan
            k = (self._n - 1) % self._t.size
            return float(self._t[k]), float(self._c[k])

    def snapshot(self, since_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the samples with host time after ``since_s`` (s), oldest first: host times (s), conductance
        (S), board times (s)."""
        with self._lock:
            n = min(self._n, self._t.size)
            order = (self._n - n + np.arange(n)) % self._t.size
            t, c, b = self._t[order], self._c[order], self._b[order]
        keep = t > since_s
        return t[keep].copy(), c[keep].copy(), b[keep].copy()


def board_times_on_host_clock(host_time_s: np.ndarray, board_time_s: np.ndarray) -> np.ndarray:
    """Each sample's time on the host clock (s), from the board clock: ``host ≈ a + b·board``, both from the lower
    envelope of ``host − board`` (a frame can reach the host late, never early): ``a`` from the least-delayed
    sample, the rate ``b`` from the least-delayed samples of the first and last quarters, held within
    :data:`MAX_CLOCK_RATE_ERROR` of 1 (a board's crystal is far better; a least-squares line would lean on a burst
    of late deliveries at one end). The host times themselves when the board clock cannot be used (unknown, not
    increasing — a board reset after a pulled cable —, or too few samples)."""
    if (host_time_s.size < 10 or not np.all(np.isfinite(board_time_s))
            or not np.all(np.diff(board_time_s) > 0)):
        return host_time_s
    lag = host_time_s - board_time_s
    quarter = max(1, lag.size // 4)
    first, last = int(np.argmin(lag[:quarter])), lag.size - quarter + int(np.argmin(lag[-quarter:]))
    span = board_time_s[last] - board_time_s[first]
    drift = (lag[last] - lag[first]) / span if span > 0 else 0.0
    rate = 1.0 + float(np.clip(drift, -MAX_CLOCK_RATE_ERROR, MAX_CLOCK_RATE_ERROR))
    offset = float(np.min(host_time_s - rate * board_time_s))
    return offset + rate * board_time_s


def lab_times_from_seq(seq: np.ndarray, rate_hz: float) -> np.ndarray:
    """Sample times (s) on the simulated lab's clock of the simulated board's frames: frame ``k`` is sampled at
    ``k / rate_hz`` of the lab clock and carries ``seq = k`` (``devices.sim.board``). Exact, however late the frames
    reach the host — unlike host arrival times, too coarse once a wall millisecond is many lab ones."""
    return np.asarray(seq, dtype=np.float64) / float(rate_hz)


def longest_gap_s(board_t_s: np.ndarray, t0_s: float, t1_s: float) -> float:
    """The longest stretch of ``[t0, t1]`` (s) with no board sample in it (``t1 − t0`` when there is none)."""
    inside = board_t_s[(board_t_s >= t0_s) & (board_t_s <= t1_s)]
    edges = np.concatenate([[t0_s], inside, [t1_s]])
    return float(np.max(np.diff(edges)))


def decimate_to(row_times_s: np.ndarray, period_s: float, board_t_s: np.ndarray,
                board_c_s: np.ndarray) -> np.ndarray:
    """Conductance (S) at each row time: the mean of the board samples in ``(t − period, t]``; a row with none
    (a dropped frame) takes the board signal interpolated at ``t``. Times in the same clock (s)."""
    if board_t_s.size == 0:
        return np.full(row_times_s.shape, np.nan)
    lo = np.searchsorted(board_t_s, row_times_s - period_s, side="right")
    hi = np.searchsorted(board_t_s, row_times_s, side="right")
    sums = np.concatenate([[0.0], np.cumsum(board_c_s)])
    counts = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        means = (sums[hi] - sums[lo]) / counts
    empty = counts == 0
    if empty.any():
        means[empty] = np.interp(row_times_s[empty], board_t_s, board_c_s)
    return means


class ProtocolRunner:
    """Runs :class:`ProtocolSettings` on a rig; see the module docstring."""

    def __init__(self, settings: ProtocolSettings, feed: ConductanceFeed, folder: Path, *,
                 on_progress: Callable[[Progress], None] | None = None,
                 on_sample: Callable[[Sample], None] | None = None,
                 on_trial: Callable[[TrialRecord], None] | None = None,
                 clock: Callable[[], float] | None = None, board_stale_s: float = BOARD_STALE_S,
                 time_scale: float = 1.0, done: dict[int, Path] | None = None, contact_only: bool = False,
                 simulated_board: bool = False) -> None:
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ValueError(f"time scale must be positive, got {time_scale!r}")
        self.settings = settings
        self.time_scale = float(time_scale)
        self.done = dict(done or {})  # plan index → CSV of trials finished by an earlier run of this session
        # Only find the contact and release (the wizard's "Find contact" step): no session folder, no trial.
        self.contact_only = contact_only
        self.contact_note = ""  # what the contact search found (set by run)
        self.rig: RigDevice | None = None  # set by run(), on the thread that owns the rig
        self.feed = feed
        self.folder = Path(folder)
        self._conditioned = False  # this run has done (or skipped) its conditioning
        self._on_progress = on_progress or (lambda _p: None)
        self._on_sample = on_sample or (lambda _s: None)
        self._on_trial = on_trial or (lambda _t: None)
        self._clock = clock or (lambda: time.monotonic() * self.time_scale)
        self.board_stale_s = board_stale_s  # no board sample for this long (s) ends the run
        # The board is the simulated lab's: messages name it, and its advice is the lab's, not a cable's.
        self.simulated_board = simulated_board
        self._board_words = "the simulated lab's board" if simulated_board else "the board"
        self._stop = threading.Event()
        self._resume = threading.Event()
        self._resume.set()
        self._stop_reason = ""
        self.trials: list[TrialRecord] = []

    # -- control (any thread) --------------------------------------------------------------------------------------
    def abort(self, reason: str = "aborted") -> None:
        """End the run as soon as possible; the load comes off. ``reason`` starts the outcome's message."""
        if not self._stop.is_set():
            self._stop_reason = reason
        self._stop.set()
        self._resume.set()

    def pause(self) -> None:
        """Hold the run after the trial in progress (rig unloaded) until :meth:`resume`."""
        self._resume.clear()

    def resume(self) -> None:
        self._resume.set()

    @property
    def paused(self) -> bool:
        return not self._resume.is_set()

    def stop_requested(self) -> bool:
        """True once :meth:`abort` was called; the rig's ``interrupt``."""
        return self._stop.is_set()

    # -- the run (worker thread) -----------------------------------------------------------------------------------
    def run(self, rig: RigDevice) -> Outcome:
        """Run the whole protocol on ``rig`` (open, owned by the calling thread) and return how it ended. Never
        raises for rig, board or file problems."""
        s = self.settings
        self.rig = rig
        self._started_s = self._clock()
        self._conditioned = False
        try:
            # The conditioning is over (the time left no longer counts it): read once here, not at every report.
            log = read_conditioning(self.folder) if s.condition_cycles and self.folder.exists() else None
            self._conditioned = bool(log is not None and log.get("finished"))
            if not self.contact_only:
                self.folder.mkdir(parents=True, exist_ok=True)
                write_session(self.folder, s)
            self._progress("contact", -1, 0.0, 0, 0.0, "finding where the probe touches the sensor…")
            rig.find_contact()
            self._refine_contact()
            reachable = getattr(rig, "reachable_force_n", None)
            top = max(max(s.forces_n), s.conditioning_force_n if s.condition_cycles else 0.0)
            if reachable is not None and top > reachable():
                raise DeviceError(f"{top:g} N is out of reach from the contact found (at most "
                                  f"{reachable():.2f} N before the servo's range ends): re-spool the cable")
            rig.release()
            if self.contact_only:
                contact = getattr(rig, "contact_rad", None)
                where = f"θ_contact = {contact:.4f} rad" if isinstance(contact, float) else "the contact"
                room = f"; up to {reachable():.2f} N reachable from it" if reachable is not None else ""
                self.contact_note = f"contact found: {where}{room}{self.contact_note}; load released"
                self._progress("done", -1, 0.0, 0, 0.0, self.contact_note)
                return Outcome(COMPLETED, self.contact_note, self.folder, ())
            self._condition()
            for index, (force, repeat) in enumerate(s.plan):
                if index in self.done:
                    continue
                attempt = 0
                while True:
                    self._rest(index)
                    self._check_stop()
                    try:
                        record = self._trial(index, force, repeat)
                    except TrialGapError as exc:
                        if attempt >= (READ_GAP_RETRIES if isinstance(exc, RigReadGapError) else GAP_RETRIES):
                            raise
                        attempt += 1
                        self._progress("redo", index, force, repeat, 0.0, f"{exc}; it runs again after its rest")
                        continue
                    break
                self.trials.append(record)
                self._on_trial(record)
        except RigInterrupted:
            return self._end(ABORTED, self._stop_reason or "aborted", None)
        except _Stopped:
            return self._end(ABORTED, self._stop_reason or "aborted", None)
        except DeviceError as exc:
            return self._end(FAILED, f"rig error: {exc}", exc)
        except (BoardStreamError, ForceCollapsedError, TrialGapError) as exc:
            return self._end(FAILED, str(exc), exc)
        except OSError as exc:
            return self._end(FAILED, f"cannot write the trial files in {self.folder}: {exc}", exc)
        self._release_safely()
        n = len(self.trials)
        kept = f" ({len(self.done)} kept from before)" if self.done else ""
        self._progress("done", n - 1, 0.0, 0, 0.0, f"{n} trial(s) recorded{kept}")
        return Outcome(COMPLETED, f"all {s.n_trials} trials recorded in {self.folder}{kept}", self.folder,
                       tuple(self.trials))

    def _condition(self) -> None:
        """The conditioning cycles (``settings.condition_cycles``, 0: none): each ramps the load up to the
        conditioning force over the protocol's ramp, holds it ``condition_load_s`` (reading the servo every sample
        period, so a servo error ends the run), takes it off and waits ``condition_unload_s``. Nothing is recorded
        as a trial; each cycle is logged in the session's ``conditioning.json`` (force and the sensor's reading at
        the end of its load). Skipped when the log says the conditioning finished (a resumed session) or when
        trials were already recorded (conditioning again would change the sensor between trials)."""
        s = self.settings
        if not s.condition_cycles:
            return
        log = read_conditioning(self.folder)
        if log is not None and log.get("finished"):
            self._progress("conditioning", -1, s.conditioning_force_n, 0, 0.0,
                           f"conditioning finished earlier ({log.get('cycles_done')} cycle(s) at "
                           f"{log.get('force_N'):g} N): not repeated")
            return
        if self.done:
            self._progress("conditioning", -1, s.conditioning_force_n, 0, 0.0,
                           "trials already recorded in this session: conditioning skipped")
            return
        rig = self.rig
        assert rig is not None
        force = s.conditioning_force_n
        period = 1.0 / s.sample_rate_hz
        document: dict = {"format": "sensnake-conditioning", "version": 1, "cycles": s.condition_cycles,
                          "force_N": force, "load_s": s.condition_load_s, "unload_s": s.condition_unload_s,
                          "cycles_done": 0, "finished": False, "cycle_log": []}
        if log is not None:
            document["restarted_after"] = int(log.get("cycles_done", 0))  # an interrupted conditioning starts over
        write_conditioning(self.folder, document)
        for cycle in range(s.condition_cycles):
            label = f"conditioning cycle {cycle + 1}/{s.condition_cycles} at {force:g} N"
            left_cycles = s.condition_cycles - cycle
            total_left = (left_cycles * (s.ramp_s + s.condition_load_s + s.condition_unload_s)
                          + (s.n_trials - len(self.done)) * (s.trial_duration_s() + s.rest_s))
            self._progress("conditioning", -1, force, 0, 0.0, f"{label}: loading", total_left)
            t0 = self._clock()
            rig.start_ramp(force, s.ramp_s)  # the protocol's ramp, paced by the servo
            self._wait_until(t0 + s.ramp_s)
            end = t0 + s.ramp_s + s.condition_load_s
            while self._clock() < end:
                applied = rig.applied_force_n()  # reads the servo: an overload or a lost servo ends the run
                self._wait_until(min(end, self._clock() + period))
            applied = rig.applied_force_n()
            reading = self.feed.latest()[1]
            self._progress("conditioning", -1, force, 0, 0.0, f"{label}: unloading", total_left - s.ramp_s
                           - s.condition_load_s)
            rig.release()
            self._wait_until(self._clock() + s.condition_unload_s)
            document["cycle_log"].append({"cycle": cycle + 1, "force_N": applied,
                                          "conductance_S": reading if math.isfinite(reading) else None})
            document["cycles_done"] = cycle + 1
            document["finished"] = cycle + 1 == s.condition_cycles
            write_conditioning(self.folder, document)
        self._conditioned = True

    def _refine_contact(self) -> None:
        """Refine the contact the rig found from its servo's current with the sensor itself: from a little before
        it, wind one encoder tick at a time until the sensor's reading leaves its unloaded level (the contact term
        makes even a tick's worth of force, ~0.01 N, read tens of µS). The current alone leaves an error of a few
        hundredths of a newton, which biases every force of the calibration. Skipped for a rig without
        ``move_to``/``contact_rad`` (test doubles)."""
        rig = self.rig
        if not isinstance(rig, RefinableRig) or rig.contact_rad is None:
            return
        base = rig.contact_rad
        self._progress("contact", -1, 0.0, 0, 0.0, "refining the contact with the sensor's reading…")
        start = base - REFINE_SPAN_RAD
        rig.move_to(start)
        unloaded = self._fresh_reading()
        angle, below = start, start
        while angle < base + REFINE_SPAN_RAD:
            angle += REFINE_STEP_RAD
            reached = rig.move_to(angle)
            touched = self._fresh_reading()
            if touched > unloaded + REFINE_RISE_S:
                rig.contact_rad = 0.5 * (below + reached)  # between the last untouched and the first touching step
                self.contact_note = (f" (refined with the sensor: it read {unloaded * 1e6:.2f} µS lifted, "
                                     f"{touched * 1e6:.1f} µS one encoder tick into contact)")
                return
            below = reached
        # No rise within the span: keep the current's estimate (the fit will show a sensor that does not respond).
        self.contact_note = (" (from the servo's current only: the sensor's reading did not rise within "
                             f"±{REFINE_SPAN_RAD:g} rad of it — is the probe over the sensor?)")

    def _late_data_given_up(self, deadline: float, waited_from: float) -> bool:
        """Whether to stop waiting for the board samples that cover a trial's end: past ``deadline`` (the runner's
        clock) once the board shows no sign of streaming for ``board_stale_s`` wall seconds, or after 12× that in
        all. A board that streams behind the runner's clock — the simulated lab's at X× on a busy machine, its
        frames late, not missing — is waited for while it catches up."""
        if self._clock() < deadline:
            return False
        now = time.monotonic()
        patience_s = max(self.board_stale_s, BOARD_STALE_S)
        return now - self.feed.last_alive_wall_s() > patience_s or now - waited_from > 12 * patience_s

    def _fresh_reading(self) -> float:
        """Median of the sensor's next few board samples taken after now (S)."""
        since = self._clock()
        # Wall seconds without any sign of the board streaming (at least BOARD_STALE_S: a board that was just
        # started may still be opening); samples that keep arriving late (a lab behind its clock) wait a while longer.
        patience_s = max(self.board_stale_s, BOARD_STALE_S)
        started = time.monotonic()
        while True:
            _, values, _ = self.feed.snapshot(since)
            if values.size >= REFINE_SAMPLES:
                return float(np.median(values[:REFINE_SAMPLES]))
            now = time.monotonic()
            if now - max(started, self.feed.last_alive_wall_s()) > patience_s or now - started > 12 * patience_s:
                raise BoardStreamError(f"no conductance from {self._board_words} for sensor {self.settings.sensor} "
                                       "while finding the contact")
            if self._stop.wait(0.01):
                raise _Stopped

    def _end(self, status: RunOutcome, what: str, exc: BaseException | None) -> Outcome:
        released = self._release_safely()
        n = len(self.trials)
        kept = (f"the {n} finished trial(s) are kept in {self.folder}" if n else
                f"no trial was finished (folder {self.folder})")
        if isinstance(exc, DeviceError):
            todo = ("fix the cause (cable, power, then reboot the rig servo if it reports an error), then run again; "
                    "you can fit the kept trials now")
        elif isinstance(exc, BoardStreamError) and self.simulated_board:
            todo = ("check that the simulated board streams (Forces tab): a simulated unplug, or a machine too busy "
                    f"for the lab at {self.time_scale:g}× real time (run again at a lower speed), then run again")
        elif isinstance(exc, BoardStreamError):
            todo = "check the board's cable and that it streams (Forces tab), then run again"
        elif isinstance(exc, RigReadGapError):
            todo = ("close what keeps the computer busy"
                    + (" or run the simulated lab at a lower speed" if self.time_scale != 1.0 else "")
                    + ", then resume the session")
        elif isinstance(exc, ForceCollapsedError):
            todo = ("the trial in progress was discarded; check the cable, the spring and that the probe sits on the "
                    "sensor, then resume the session")
        elif exc is not None:
            todo = "choose a folder you can write to (Save under), then run again"
        else:
            todo = "the trial in progress was discarded"
        load = "load released" if released else "the rig could NOT take the load off: unwind it by hand"
        message = f"{what}; {load}; {kept}; {todo}"
        self._progress("done", n - 1, 0.0, 0, 0.0, message)
        return Outcome(status, message, self.folder, tuple(self.trials))

    def _release_safely(self) -> bool:
        if self.rig is None:
            return True
        try:
            self.rig.release()
        except DeviceError:
            return False
        return True

    def _check_stop(self) -> None:
        if self._stop.is_set():
            raise _Stopped

    def _wait_until(self, deadline_s: float) -> None:
        """Wait (interruptibly) until the clock reaches ``deadline_s``."""
        while True:
            left = deadline_s - self._clock()
            if left <= 0:
                return
            if self._stop.wait(left / self.time_scale):
                raise _Stopped

    def _time_left(self, index: int, elapsed_in_trial_s: float, rest_left_s: float = 0.0) -> float:
        """Estimated run time left (s) from inside trial ``index`` (or its rest, with ``rest_left_s`` to go)."""
        s = self.settings
        remaining_trials = sum(1 for k in range(index + 1, s.n_trials) if k not in self.done)
        return (rest_left_s + max(0.0, s.trial_duration_s() - elapsed_in_trial_s)
                + remaining_trials * (s.trial_duration_s() + s.rest_s))

    def _before_trials_left_s(self) -> float:
        """Run time left (s) before the first trial of this run starts: the conditioning still to do (not for a
        resumed session whose conditioning finished, nor once trials exist) and every trial still to record with
        the rest before it."""
        s = self.settings
        conditioning = 0.0
        if s.condition_cycles and not self.done and not self._conditioned:
            conditioning = s.conditioning_duration_s()
        return conditioning + (s.n_trials - len(self.done)) * (s.trial_duration_s() + s.rest_s)

    def _progress(self, phase: str, index: int, force: float, repeat: int, elapsed_s: float, message: str,
                  time_left_s: float | None = None) -> None:
        if time_left_s is None:
            time_left_s = 0.0 if phase == "done" else self._before_trials_left_s()
        left = time_left_s
        self._on_progress(Progress(phase, index, self.settings.n_trials, force, repeat, elapsed_s, left, message))

    def _rest(self, index: int) -> None:
        s = self.settings
        end = self._clock() + s.rest_s
        force, repeat = s.plan[index]
        while True:
            left = end - self._clock()
            if left <= 0:
                break
            self._progress("rest", index, force, repeat, 0.0, f"resting unloaded, {left:.0f} s before trial "
                           f"{index + 1}/{s.n_trials}", self._time_left(index, 0.0, left))
            if self._stop.wait(min(left / self.time_scale, PROGRESS_INTERVAL_S)):
                raise _Stopped
        while not self._resume.is_set():
            self._progress("paused", index, force, repeat, 0.0, f"paused before trial {index + 1}/{s.n_trials} "
                           "(rig unloaded); Resume to go on", self._time_left(index, 0.0))
            self._resume.wait(PROGRESS_INTERVAL_S)
        self._check_stop()

    def _trial(self, index: int, force: float, repeat: int) -> TrialRecord:
        s = self.settings
        rig = self.rig
        assert rig is not None  # run() set it
        label = f"trial {index + 1}/{s.n_trials}: {force:g} N, repeat {repeat}"
        period = 1.0 / s.sample_rate_hz
        n_rows = int(math.floor(s.trial_duration_s() * s.sample_rate_hz)) + 1
        times = np.empty(n_rows)
        forces = np.empty(n_rows)
        t0 = self._clock()
        loaded = False
        unloaded: list[float] = []  # the sensor's readings before loading (S)
        peak = -math.inf
        collapsed = 0
        ramp_from: float | None = None  # when the ramp was commanded (runner clock, s)
        load_from: float | None = None  # when the ramp started, the hold was reached (runner clock, s)
        hold_from: float | None = None
        last_judged = -math.inf
        row = -1
        for slot in range(n_rows):
            self._wait_until(t0 + slot * period)
            now = self._clock()
            if now > t0 + (slot + 1) * period and slot < n_rows - 1:
                continue  # this slot's moment went by (the thread was held up): no bunched catch-up rows
            if not loaded and now - t0 >= s.baseline_s:
                loaded = True
                ramp_from = self._clock()
                rig.start_ramp(force, s.ramp_s)  # the servo paces the ramp: a held-up thread cannot stall it
            read_from = self._clock()
            applied = rig.applied_force_n()
            read_to = self._clock()
            if loaded and hold_from is None and read_to - read_from > MAX_READ_SPAN_PERIODS * period:
                continue  # on the ramp, when the force was read is not known well enough (held up mid-read)
            row += 1
            forces[row] = applied
            times[row] = now = 0.5 * (read_from + read_to)  # the read takes a while; the force is its midpoint's
            board_t, board_c = self.feed.latest()
            if time.monotonic() - self.feed.last_alive_wall_s() > self.board_stale_s:
                raise BoardStreamError(
                    f"no conductance from {self._board_words} for sensor {s.sensor} for {self.board_stale_s:g} s "
                    f"during {label}" if math.isfinite(board_t)
                    else f"no conductance from {self._board_words} for sensor {s.sensor}")
            elapsed = now - t0
            phase = "baseline" if not loaded else ("loading" if forces[row] < 0.95 * force else "hold")
            # The collapse check judges each board sample by its own time (board data may arrive late).
            if loaded and load_from is None:
                load_from = now
            if phase == "hold" and hold_from is None:
                hold_from = now
            if math.isfinite(board_c) and board_t > last_judged:
                last_judged = board_t
                if board_t >= t0 and (load_from is None or board_t < load_from):
                    unloaded.append(board_c)
                elif hold_from is not None and board_t >= hold_from + period and unloaded:
                    low = float(np.median(unloaded))
                    peak = max(peak, board_c)
                    collapsed = collapsed + 1 if board_c < low + COLLAPSE_FRACTION * (peak - low) else 0
                    if collapsed >= COLLAPSE_ROWS and peak - low > COLLAPSE_MIN_RISE * abs(peak):
                        raise ForceCollapsedError(
                            f"{label}: the reading collapsed during the hold ({peak * 1e6:.1f} → {board_c * 1e6:.1f} µS, "
                            f"unloaded {low * 1e6:.1f} µS) while the rig held {forces[row]:.2f} N: the cable may have "
                            "snapped or the probe slipped off the sensor")
            self._on_sample(Sample(index, elapsed, float(forces[row]), board_c))
            if row % max(1, int(round(s.sample_rate_hz * PROGRESS_INTERVAL_S))) == 0:
                self._progress(phase, index, force, repeat, elapsed, label, self._time_left(index, elapsed))
        times, forces = times[: row + 1], forces[: row + 1]  # the slots the thread kept
        # Each row's conductance is the board's mean over the sampling interval centred on the row's time (where
        # its force was read). Board samples can arrive after the rig's (the GUI drains the board): wait for them.
        end = times[-1] + 0.5 * period
        deadline = self._clock() + max(LATE_DATA_WAIT_S, self.board_stale_s) * self.time_scale
        waited_from = time.monotonic()
        while self.feed.latest()[0] < end and not self._late_data_given_up(deadline, waited_from):
            if self._stop.wait(0.05):
                raise _Stopped
        if self.feed.latest()[0] < times[-1] - period:
            raise BoardStreamError(f"the board's samples of sensor {s.sensor} stopped arriving before the end of "
                                   f"{label}")
        self._progress("release", index, force, repeat, s.trial_duration_s(), f"{label}: releasing the load",
                       self._time_left(index, s.trial_duration_s()))
        rig.release()
        snap_host_t, snap_conductance, snap_board_t = self.feed.snapshot(times[0] - 2 * period)
        sample_t = board_times_on_host_clock(snap_host_t, snap_board_t)
        edge_from = (load_from if load_from is not None else times[0]) - period
        edge_to = (hold_from if hold_from is not None else times[-1]) + 2 * period
        gap_s = longest_gap_s(sample_t, times[0] - 0.5 * period, times[-1] + 0.5 * period)
        edge_gap_s = longest_gap_s(sample_t, edge_from, edge_to)
        uncovered, where = 0.0, ""
        if edge_gap_s > EDGE_GAP_PERIODS * period:
            uncovered, where = edge_gap_s, " over the loading edge"
        elif gap_s > max(MAX_GAP_PERIODS * period, GAP_CREEP_FRACTION * CREEP_TIME_S):
            uncovered = gap_s
        force_edge_gap_s = longest_gap_s(times, (ramp_from if ramp_from is not None else times[0]) - period,
                                         edge_to)
        if not uncovered and force_edge_gap_s > max(EDGE_GAP_PERIODS * period, RAMP_GAP_FRACTION * s.ramp_s):
            raise RigReadGapError(
                f"{label}: the rig's force was not read for {force_edge_gap_s:.1f} s over the loading edge (the "
                f"computer was too busy{f' at {self.time_scale:g}× real time' if self.time_scale != 1.0 else ''}): the record cannot say how the force rose there; the "
                "trial is not kept")
        if uncovered:
            cause = (f"the simulated lab's board frames were lost: the computer did not read them in time at "
                     f"{self.time_scale:g}× real time" if self.simulated_board
                     else "frames lost: a loose cable, or a computer too busy to read the board")
            raise BoardGapError(f"{label}: the board's samples of sensor {s.sensor} leave {uncovered:.1f} s "
                                f"uncovered{where} ({cause}); the trial is not kept")
        conductance = decimate_to(times + 0.5 * period, period, sample_t, snap_conductance)
        time_s = times - times[0]  # measured sample times (s), the first at 0
        path = self.folder / trial_file_name(s.sensor, index, force, repeat)
        calfiles.write_trial_csv(path, time_s, forces, conductance)
        return TrialRecord(index, path, force, repeat, time_s, forces, conductance)


@dataclass(frozen=True)
class ProtocolCheck:
    """What :func:`check_protocol` found: ``errors`` (the run must not start) and ``warnings`` (shown; it may)."""

    errors: tuple[str, ...]
    warnings: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.errors


def readout_ceiling_s(board: BoardConfig) -> float:
    """The largest conductance the readout can report (S): ``1/R_C`` at 0 counts (SPEC §4)."""
    return 1.0 / board.r_c_ohm


def check_protocol(settings: ProtocolSettings, rig: RigConfig, board: BoardConfig,
                   expected_sls: tuple[SLSParams, float, PhysicsConstants] | None = None,
                   seen: tuple[float, float] | None = None) -> ProtocolCheck:
    """Everything the run and the fit need, checked before the rig moves (the settings' own checks ran when they
    were made). The readout's range at the top force is predicted from, in order: ``expected_sls`` (SLS parameters,
    area m², physics) of this sensor's earlier calibration; ``seen`` (force N, highest conductance S) of a trial of
    this session already recorded, scaled in proportion to the top force (an over-estimate: the contact term makes
    the reading rise more slowly than the force); else the models' typical sensor, which only warns."""
    errors: list[str] = []
    warnings: list[str] = []
    names = board.channel_names
    if settings.sensor not in names:
        errors.append(f"sensor {settings.sensor} is not a channel of the board ({names[0]} … {names[-1]}): check "
                      "the name or the board's channel map")
    top = max(settings.forces_n)
    if settings.condition_cycles:
        condition = settings.conditioning_force_n
        if condition > rig.max_force_n:
            errors.append(f"conditioning at {condition:g} N is above the rig's maximum force {rig.max_force_n:g} N "
                          "(rig.max_force_n): condition at a lower force")
        top = max(top, condition)
    if max(settings.forces_n) > rig.max_force_n:
        errors.append(f"{max(settings.forces_n):g} N is above the rig's maximum force {rig.max_force_n:g} N "
                      "(rig.max_force_n): "
                      "lower the forces, or raise the maximum only if the sensor and spring allow it")
    k_r = rig.spring_k_n_per_m * rig.wheel_radius_m
    winding = top / k_r
    if winding > MAX_WINDING_RAD:
        errors.append(f"{top:g} N needs {winding:.2f} rad of winding past the contact; the spring's travel on the "
                      f"servo's range is {MAX_WINDING_RAD:.2f} rad (at most {MAX_WINDING_RAD * k_r:.2f} N with "
                      f"k = {rig.spring_k_n_per_m:g} N/m, r = {rig.wheel_radius_m * 1e3:g} mm)")
    if settings.rest_s < REST_CREEP_TIMES * CREEP_TIME_S and settings.n_trials > 1:
        warnings.append(f"a {settings.rest_s:g} s rest is short against the sensor's creep (τ ~ {CREEP_TIME_S:g} s): "
                        "the creep of one trial still fades in the next, which the fit does not model; rest "
                        f"≥ {REST_CREEP_TIMES * CREEP_TIME_S:g} s")
    ceiling = readout_ceiling_s(board)
    top = max(settings.forces_n)  # the readout matters for the recorded trials only, not for the conditioning
    if expected_sls is None and seen is not None and seen[0] > 0 and np.isfinite(seen[1]):
        predicted = seen[1] * top / seen[0]
        source = f"scaling this session's trial at {seen[0]:g} N ({seen[1] * 1e6:.0f} µS)"
    else:
        params, area, physics = expected_sls if expected_sls is not None else (TYPICAL_SLS, settings.area_m2,
                                                                               PhysicsConstants())
        strain = np.array([top / area / float(params.b)])
        predicted = float(conductance_from_strain(strain, np.array([top]), physics)[0])
        source = "this sensor's last calibration" if expected_sls is not None else (
            "a typical sensor (no calibration or trial of this sensor to go by)")
    if predicted >= READOUT_MARGIN * ceiling:
        text = (f"at {top:g} N the sensor would read {predicted * 1e6:.0f} µS by {source}, at or near the readout's "
                f"ceiling "
                f"{ceiling * 1e6:.0f} µS (1/R_C, R_C = {board.r_c_ohm:g} Ω): saturated samples only say 'at least'; "
                "lower the top force or R_C if the first trial saturates")
        warnings.append(text)  # a prediction: it warns, it never refuses a run (the run itself will show it)
    return ProtocolCheck(tuple(errors), tuple(warnings))


def write_session(folder: Path, settings: ProtocolSettings) -> None:
    """Write (or keep) the session's protocol file; a folder made for another protocol is refused (ValueError)."""
    path = Path(folder) / SESSION_FILE
    document = {"format": "sensnake-calibration-protocol", "version": 1, **asdict(settings)}
    if path.exists():
        previous = read_session(folder)
        if previous != settings:
            raise ValueError(f"{folder} holds a session of another protocol ({path.name} differs); "
                             "resume it with its own settings or start a new session")
        return
    calfiles.write_atomically(path, lambda handle: handle.write(json.dumps(document, indent=2) + "\n"))


def read_session(folder: str | Path) -> ProtocolSettings:
    """The protocol a session folder was started with (its ``protocol.json``); ValueError naming the problem."""
    path = Path(folder) / SESSION_FILE
    try:
        document = json.loads(read_state_file(path, "session protocol"))
    except FileNotFoundError:
        raise ValueError(f"{folder} is not a calibration session folder (no {SESSION_FILE})") from None
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read the session's protocol: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != "sensnake-calibration-protocol":
        raise ValueError(f"{path}: not a calibration protocol file")
    if document.get("version") != 1:
        raise ValueError(f"{path}: protocol version {document.get('version')!r} is not known (expected 1)")
    known = {f for f in ProtocolSettings.__dataclass_fields__}
    kwargs = {k: v for k, v in document.items() if k in known}
    if "forces_n" in kwargs:
        kwargs["forces_n"] = tuple(kwargs["forces_n"])
    try:
        return ProtocolSettings(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None


def read_conditioning(folder: str | Path) -> dict | None:
    """The session's conditioning log (``conditioning.json``), or None when there is none (or it is unreadable: the
    conditioning then runs again)."""
    try:
        document = json.loads(read_state_file(Path(folder) / CONDITIONING_FILE, "conditioning log"))
    except (OSError, ValueError):
        return None
    return document if isinstance(document, dict) and document.get("format") == "sensnake-conditioning" else None


def write_conditioning(folder: str | Path, document: dict) -> None:
    """Write the session's conditioning log atomically (a crash leaves the previous version)."""
    calfiles.write_atomically(Path(folder) / CONDITIONING_FILE,
                              lambda handle: handle.write(json.dumps(document, indent=2) + "\n"))


def finished_trials(folder: str | Path, settings: ProtocolSettings) -> dict[int, Path]:
    """Plan index → CSV of the trials of ``settings`` already in the session folder (complete files only: they are
    written atomically when a trial ends)."""
    found = {}
    for index, (force, repeat) in enumerate(settings.plan):
        path = Path(folder) / trial_file_name(settings.sensor, index, force, repeat)
        if path.is_file():
            found[index] = path
    return found


def unfinished_sessions(base: str | Path) -> list[tuple[Path, ProtocolSettings, int]]:
    """Session folders under ``base`` whose protocol is not complete: (folder, settings, trials done), newest
    first — what the app offers to resume after a restart."""
    found: list[tuple[Path, ProtocolSettings, int]] = []
    try:
        folders = sorted((p for p in Path(base).iterdir() if (p / SESSION_FILE).is_file()),
                         key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return found
    for folder in folders:
        try:
            settings = read_session(folder)
        except ValueError:
            continue
        done = len(finished_trials(folder, settings))
        if done < settings.n_trials:
            found.append((folder, settings, done))
    return found


def reject_trial(path: str | Path) -> Path:
    """Move a finished trial's CSV into its session's ``rejected/`` folder (kept, never deleted), so that resuming
    the session runs that trial again. Returns the new path."""
    source = Path(path)
    target_dir = source.parent / "rejected"
    target_dir.mkdir(exist_ok=True)
    target = target_dir / source.name
    k = 1
    while target.exists():
        target = target_dir / f"{source.stem}.{k}{source.suffix}"
        k += 1
    source.replace(target)
    return target


def trial_file_name(sensor: str, index: int, force_n: float, repeat: int) -> str:
    """``S06B_t03_4.00N_r1.csv``: sortable by run order, readable."""
    return f"{sensor}_t{index + 1:02d}_{force_n:.2f}N_r{repeat}.csv"


def session_folder(base: Path, sensor: str, now: time.struct_time | None = None) -> Path:
    """A new folder name under ``base`` for one run: ``<sensor>_<YYYYmmdd-HHMMSS>``."""
    stamp = time.strftime("%Y%m%d-%H%M%S", now or time.localtime())
    return Path(base) / f"{sensor}_{stamp}"


def parse_forces(text: str) -> tuple[float, ...]:
    """``"1.75, 3, 4, 5.25"`` → forces (N); ValueError naming the bad entry."""
    forces = []
    for part in text.replace(";", ",").split(","):
        part = part.strip()
        if not part:
            continue
        try:
            forces.append(float(part))
        except ValueError:
            raise ValueError(f"forces: {part!r} is not a number (write e.g. 1.75, 3, 4, 5.25)") from None
    return tuple(forces)


def format_forces(forces: Sequence[float]) -> str:
    return ", ".join(f"{f:g}" for f in forces)


class _Stopped(Exception):
    """Internal: the run was aborted during a wait."""
