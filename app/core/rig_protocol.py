"""The calibration protocol on the rig (paper Sec. IV-C), without Qt: forces × trials, each trial held and sampled.

For each force in ``forces_n`` and each of ``trials_per_force`` repeats (force-major order, the paper's 4 × 3):
the sensor rests unloaded (probe lifted) for ``rest_s`` — also before the first trial, since the contact search
loads the sensor to about 2 N — then sampling starts with ``baseline_s`` still unloaded (so the record holds the
unloaded level and the loading ramp, which identify E0; the probe is lifted rather than just touching, so the force
column reads exactly 0 N there instead of a tick's worth of spring stretch); the rig ramps the force up linearly over
``ramp_s`` (one goal per sample: a servo left to itself loads in a fraction of a second, too fast for a 6 Hz record to
see the ramp, and too fast for the fit to identify E0) and the trial samples
``time_s``, the rig's applied force (``F = k·r·(θ − θ_contact)`` from the servo's present position, SPEC §2) and the
sensor's conductance at ``sample_rate_hz`` for ``hold_s`` from the command; then the load comes off and the trial is
written as a SPEC §3.1 CSV into the session folder. The contact is found once, at the start.

Conductance comes from the board stream (:class:`ConductanceFeed`: the board's samples of the sensor's channel,
pushed by whoever drains the board, with their host ``time.monotonic()`` and board-clock times). Each trial row takes
the mean of the board samples in the sampling interval that ends at its time (a boxcar decimation from the board's
rate to ``sample_rate_hz``), computed when the trial ends, so a late delivery of board data (a busy GUI) does not
misalign force and conductance. The samples are placed on the host clock through the board's own clock
(:func:`board_times_on_host_clock`): a frame's host time is when the reader got to it, late by however long the
reader thread waited for the CPU, while the board clock ticks evenly.

Control (any thread): :meth:`ProtocolRunner.abort` ends the run at once — the load comes off, the trial in progress is
discarded, the finished trials stay on disk. :meth:`ProtocolRunner.pause` takes effect after the trial in progress
(a creep hold cannot be paused without spoiling it): the rig stays unloaded until :meth:`ProtocolRunner.resume`.
A rig error (pulled cable, no reply, overload) or a board stream that stops ends the run with a message that says
what happened and what to do; finished trials stay on disk.

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
from pathlib import Path
from typing import Protocol

import numpy as np

from app.core import calfiles
from devices.errors import DeviceError
from devices.rig import RigInterrupted

PAPER_FORCES_N = (1.75, 3.0, 4.0, 5.25)
PAPER_HOLD_S = 370.0
BOARD_STALE_S = 5.0  # no board sample of the sensor for this long (wall seconds) ends the run
PROGRESS_INTERVAL_S = 0.5  # progress callbacks during rests and pauses
FEED_CAPACITY = 1 << 16  # board samples kept by the feed (≈ 36 min at the board's default 30 Hz)
LATE_DATA_WAIT_S = 1.0  # at a trial's end, how long to wait for board samples that cover its last interval

COMPLETED, ABORTED, FAILED = "completed", "aborted", "failed"


class RigDevice(Protocol):
    """What the runner needs from :class:`devices.rig.CalibrationRig` (one thread calls it)."""

    def find_contact(self) -> float: ...
    def command_force(self, force_n: float) -> float: ...
    def start_force(self, force_n: float) -> float: ...
    def applied_force_n(self) -> float: ...
    def release(self) -> None: ...


class BoardStreamError(RuntimeError):
    """The sensor's conductance stopped arriving from the board."""


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
        if self.ramp_s >= self.hold_s:
            raise ValueError(f"the loading ramp ({self.ramp_s:g} s) must be shorter than the hold ({self.hold_s:g} s)")
        if self.hold_s * self.sample_rate_hz < 10:
            raise ValueError(f"a {self.hold_s:g} s hold at {self.sample_rate_hz:g} Hz gives fewer than 10 samples; "
                             "the fit needs at least 10 in the hold")

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

    def total_duration_s(self) -> float:
        """Expected run time (s) without contact search and settling: every trial and the rest before each."""
        return self.n_trials * (self.trial_duration_s() + self.rest_s)

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
    """Where the run is: ``phase`` one of contact / baseline / loading / hold / release / rest / paused / done;
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

    status: str
    message: str
    folder: Path
    trials: tuple[TrialRecord, ...] = field(default_factory=tuple)


class ConductanceFeed:
    """Thread-safe store of the sensor's board samples: ``push`` from the thread that drains the board, ``window``
    and ``latest`` from the runner. A fixed ring (no per-sample append); times are host ``time.monotonic()`` (s)."""

    def __init__(self, capacity: int = FEED_CAPACITY) -> None:
        self._t = np.full(capacity, -np.inf)
        self._b = np.full(capacity, np.nan)
        self._c = np.full(capacity, np.nan)
        self._n = 0  # samples ever pushed
        self._lock = threading.Lock()

    def push(self, host_time_s: np.ndarray, conductance_s: np.ndarray, board_time_s: np.ndarray | None = None) -> None:
        """Add samples: host times (non-decreasing, s), conductance (S), board-clock times (s; NaN if unknown).
        Any thread."""
        t = np.asarray(host_time_s, dtype=np.float64).ravel()
        c = np.asarray(conductance_s, dtype=np.float64).ravel()
        b = (np.full(t.shape, np.nan) if board_time_s is None
             else np.asarray(board_time_s, dtype=np.float64).ravel())
        cap = self._t.size
        if t.size > cap:
            t, c, b = t[-cap:], c[-cap:], b[-cap:]
        with self._lock:
            idx = (self._n + np.arange(t.size)) % cap
            self._t[idx] = t
            self._b[idx] = b
            self._c[idx] = c
            self._n += t.size

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
    """Each sample's time on the host clock (s), from the board clock: ``host ≈ a + b·board`` with the rate ``b``
    fitted over the samples and the offset ``a`` from the least-delayed sample (the lower envelope: a frame can reach
    the host late, never early). The host times themselves when the board clock cannot be used (unknown, not
    increasing — a board reset after a pulled cable —, or too few samples)."""
    if (host_time_s.size < 10 or not np.all(np.isfinite(board_time_s))
            or not np.all(np.diff(board_time_s) > 0)):
        return host_time_s
    rate = float(np.polyfit(board_time_s - board_time_s[0], host_time_s - host_time_s[0], 1)[0])
    if not rate > 0:
        return host_time_s
    offset = float(np.min(host_time_s - rate * board_time_s))
    return offset + rate * board_time_s


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
                 clock: Callable[[], float] = time.monotonic, board_stale_s: float = BOARD_STALE_S) -> None:
        self.settings = settings
        self.rig: RigDevice | None = None  # set by run(), on the thread that owns the rig
        self.feed = feed
        self.folder = Path(folder)
        self._on_progress = on_progress or (lambda _p: None)
        self._on_sample = on_sample or (lambda _s: None)
        self._on_trial = on_trial or (lambda _t: None)
        self._clock = clock
        self.board_stale_s = board_stale_s  # no board sample for this long (s) ends the run
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
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            (self.folder / "protocol.json").write_text(json.dumps(
                {"format": "sensnake-calibration-protocol", "version": 1, **asdict(s)}, indent=2), encoding="utf-8")
            self._progress("contact", -1, 0.0, 0, 0.0, "finding where the probe touches the sensor…")
            rig.find_contact()
            rig.release()
            for index, (force, repeat) in enumerate(s.plan):
                self._rest(index)
                self._check_stop()
                self.trials.append(self._trial(index, force, repeat))
                self._on_trial(self.trials[-1])
        except RigInterrupted:
            return self._end(ABORTED, self._stop_reason or "aborted", None)
        except _Stopped:
            return self._end(ABORTED, self._stop_reason or "aborted", None)
        except DeviceError as exc:
            return self._end(FAILED, f"rig error: {exc}", exc)
        except BoardStreamError as exc:
            return self._end(FAILED, str(exc), exc)
        except OSError as exc:
            return self._end(FAILED, f"cannot write the trial files in {self.folder}: {exc}", exc)
        self._release_safely()
        n = len(self.trials)
        self._progress("done", n - 1, 0.0, 0, 0.0, f"{n} trial(s) recorded")
        return Outcome(COMPLETED, f"all {n} trials recorded in {self.folder}", self.folder, tuple(self.trials))

    def _end(self, status: str, what: str, exc: BaseException | None) -> Outcome:
        released = self._release_safely()
        n = len(self.trials)
        kept = (f"the {n} finished trial(s) are kept in {self.folder}" if n else
                f"no trial was finished (folder {self.folder})")
        if isinstance(exc, DeviceError):
            todo = ("fix the cause (cable, power, then reboot the rig servo if it reports an error), then run again; "
                    "you can fit the kept trials now")
        elif isinstance(exc, BoardStreamError):
            todo = "check the board's cable and that it streams (Forces tab), then run again"
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
            if self._stop.wait(left):
                raise _Stopped

    def _time_left(self, index: int, elapsed_in_trial_s: float, rest_left_s: float = 0.0) -> float:
        """Estimated run time left (s) from inside trial ``index`` (or its rest, with ``rest_left_s`` to go)."""
        s = self.settings
        remaining_trials = s.n_trials - index - 1
        return (rest_left_s + max(0.0, s.trial_duration_s() - elapsed_in_trial_s)
                + remaining_trials * (s.trial_duration_s() + s.rest_s))

    def _progress(self, phase: str, index: int, force: float, repeat: int, elapsed_s: float, message: str,
                  time_left_s: float | None = None) -> None:
        left = self.settings.total_duration_s() if time_left_s is None else time_left_s
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
            if self._stop.wait(min(left, PROGRESS_INTERVAL_S)):
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
        ramped = False
        for row in range(n_rows):
            self._wait_until(t0 + row * period)
            now = self._clock()
            if not ramped and now - t0 >= s.baseline_s:
                loaded = True
                share = (now - t0 - s.baseline_s + period) / s.ramp_s if s.ramp_s > 0 else 1.0
                ramped = share >= 1.0
                rig.start_force(force * min(share, 1.0))
            times[row] = now
            forces[row] = rig.applied_force_n()
            board_t, board_c = self.feed.latest()
            if now - board_t > self.board_stale_s:
                raise BoardStreamError(
                    f"no conductance from the board for sensor {s.sensor} for {self.board_stale_s:g} s during {label}"
                    if math.isfinite(board_t) else f"no conductance from the board for sensor {s.sensor}")
            elapsed = now - t0
            phase = "baseline" if not loaded else ("loading" if forces[row] < 0.95 * force else "hold")
            self._on_sample(Sample(index, elapsed, float(forces[row]), board_c))
            if row % max(1, int(round(s.sample_rate_hz * PROGRESS_INTERVAL_S))) == 0:
                self._progress(phase, index, force, repeat, elapsed, label, self._time_left(index, elapsed))
        # Board samples can arrive after the rig's (the GUI drains the board): wait briefly for the last interval.
        deadline = self._clock() + LATE_DATA_WAIT_S
        while self.feed.latest()[0] < times[-1] and self._clock() < deadline:
            if self._stop.wait(0.05):
                raise _Stopped
        self._progress("release", index, force, repeat, s.trial_duration_s(), f"{label}: releasing the load")
        rig.release()
        snap_host_t, snap_conductance, snap_board_t = self.feed.snapshot(times[0] - 2 * period)
        conductance = decimate_to(times, period, board_times_on_host_clock(snap_host_t, snap_board_t),
                                  snap_conductance)
        time_s = times - times[0]  # measured sample times (s), the first at 0
        path = self.folder / trial_file_name(s.sensor, index, force, repeat)
        calfiles.write_trial_csv(path, time_s, forces, conductance)
        return TrialRecord(index, path, force, repeat, time_s, forces, conductance)


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
