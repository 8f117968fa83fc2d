"""Joint-space trajectories for the snake: follow-the-leader (SPEC §5), keyframes, serpenoid gaits, blends.

Two layers:

* pure planning functions (:func:`follow_the_leader_targets`, :func:`plan_follow_the_leader`,
  :func:`plan_keyframes`) return a :class:`Plan` — the full target list, the duration of every move and the
  piecewise-linear goal as a function of time — so tests check SPEC §5 without a robot;
* :class:`MotionSource`-compatible classes (``goal_at(t_s, present_rad)``, see ``devices/controller.py``) that build
  their plan from the present pose on the first call and are driven by the controller thread.

Angles are in radians in the joint order of ``RobotConfig.joint_ids`` (head first, SPEC §2); times in seconds since
the motion started. Pure numpy: no Qt, no I/O.

Threads: a motion source is called by the one controller thread; its :attr:`progress` is an immutable snapshot
replaced atomically, so any thread (the GUI, a CLI printer) may read it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from models.errors import TrajectoryError

AXES = ("pitch", "yaw")
DEFAULT_SPEED_RAD_S = 0.034  # the paper's follow-the-leader propagation speed


# ----------------------------------------------------------------------------------------------------------------
# Plans: a start pose and a list of targets reached by straight lines in joint space
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Progress:
    """Where a motion is: ``index`` of the target being approached (shift k, keyframe j, or cycle), of ``count``.

    ``move_fraction`` is the fraction of the current move done, ``fraction`` of the whole motion (by time).
    """

    kind: str  # "shift", "keyframe" or "cycle"
    index: int
    count: int
    move_fraction: float
    fraction: float
    elapsed_s: float
    total_s: float
    done: bool = False

    def describe(self) -> str:
        state = "done" if self.done else f"{self.move_fraction * 100:3.0f}% of move"
        return (f"{self.kind} {self.index}/{self.count - 1}  {state}  "
                f"total {self.fraction * 100:5.1f}%  t={self.elapsed_s:7.2f}/{self.total_s:.2f} s")


@dataclass(frozen=True)
class Plan:
    """A piecewise-linear joint trajectory.

    ``start_rad`` (n,) is where the robot is; ``targets_rad`` (M, n) the poses reached one after the other;
    ``durations_s`` (M,) how long the move *into* each target takes (0 = skipped, SPEC §5); ``labels`` (M,) the
    progress index of each target (shift k or keyframe j); ``kind`` names what the index counts.

    Sampling at ``rate_hz`` (one synchronised write per tick): move m takes ``ceil(T_m · rate)`` ticks; on each
    full tick the goal advances by ``Δ/(T_m · rate)`` (the fastest joint at exactly its speed) and the move's last
    tick lands exactly on its target (a partial step, never faster). So every target is sent as such, no joint
    ever moves faster than planned, and a move is at most one tick longer than T. Moves with T = 0 take no tick.
    """

    start_rad: np.ndarray
    targets_rad: np.ndarray
    durations_s: np.ndarray
    labels: np.ndarray
    kind: str = "shift"
    # derived in __post_init__ (a frozen dataclass sets them with object.__setattr__)
    _ends_s: np.ndarray = field(init=False, repr=False, compare=False)
    _starts_s: np.ndarray = field(init=False, repr=False, compare=False)
    _tick_cache: dict[float, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        starts = np.concatenate([[0.0], np.cumsum(self.durations_s)])
        object.__setattr__(self, "_ends_s", starts[1:])
        object.__setattr__(self, "_starts_s", starts[:-1])
        object.__setattr__(self, "_tick_cache", {})

    @property
    def total_s(self) -> float:
        """Sum of the move durations T (s), before rounding to ticks."""
        return float(self._ends_s[-1]) if len(self._ends_s) else 0.0

    @property
    def move_end_times_s(self) -> np.ndarray:
        """When each target is reached in continuous time (s since start)."""
        return self._ends_s.copy()

    @property
    def count(self) -> int:
        return int(self.labels.max()) + 1 if len(self.labels) else 0

    # -- sampled at a control rate ------------------------------------------------------------------------------
    def tick_counts(self, rate_hz: float) -> np.ndarray:
        """Ticks each move takes at ``rate_hz``: ceil(T · rate), at least 1 for T > 0 (0 for T = 0)."""
        if not rate_hz > 0:
            raise TrajectoryError(f"rate must be positive, got {rate_hz} Hz")
        # the small tolerance keeps T·rate = 10.000000000002 (float noise) at 10 ticks
        ticks = np.ceil(self.durations_s * rate_hz - 1e-9).astype(np.int64).clip(min=0)
        ticks[(self.durations_s > 0) & (ticks == 0)] = 1  # a tiny move still gets its one tick
        return ticks

    def _tick_ends(self, rate_hz: float) -> np.ndarray:
        cache = self._tick_cache
        if rate_hz not in cache:
            cache[rate_hz] = np.cumsum(self.tick_counts(rate_hz))
        return cache[rate_hz]

    def total_ticks(self, rate_hz: float) -> int:
        ends = self._tick_ends(rate_hz)
        return int(ends[-1]) if len(ends) else 0

    def _tick_move(self, tick: int, rate_hz: float) -> tuple[int, float]:
        """(move index, fraction of that move done) at ``tick`` (≥ 1, ≤ total)."""
        ends = self._tick_ends(rate_hz)
        m = int(np.searchsorted(ends, tick, side="left"))  # first move whose end tick ≥ tick
        if tick >= ends[m]:
            # The move's last tick is its target exactly: with T·rate a hair above a whole number (the 1e-9 slack
            # in tick_counts) the ratio below would stop 1e-16 short and the target would never be sent as such.
            return m, 1.0
        before = int(ends[m - 1]) if m > 0 else 0
        return m, min((tick - before) / (self.durations_s[m] * rate_hz), 1.0)

    def goal_at_tick(self, tick: int, rate_hz: float) -> np.ndarray:
        """The goal sent on tick ``tick`` (0 = the start pose) at ``rate_hz``; the last target after the end."""
        total = self.total_ticks(rate_hz)
        if len(self.targets_rad) == 0:
            return self.start_rad.copy()
        if tick <= 0:
            return self.start_rad.copy()
        if tick >= total:
            return self.targets_rad[-1].copy()
        m, fraction = self._tick_move(tick, rate_hz)
        a = self.start_rad if m == 0 else self.targets_rad[m - 1]
        b = self.targets_rad[m]
        return b.copy() if fraction >= 1.0 else a + (b - a) * fraction

    def progress_at_tick(self, tick: int, rate_hz: float) -> Progress:
        total = self.total_ticks(rate_hz)
        elapsed = max(tick, 0) / rate_hz
        if len(self.targets_rad) == 0 or tick >= total:
            last = int(self.labels[-1]) if len(self.labels) else 0
            return Progress(self.kind, last, max(self.count, 1), 1.0, 1.0, total / rate_hz, total / rate_hz,
                            done=True)
        m, fraction = self._tick_move(max(tick, 1), rate_hz) if tick > 0 else (self._first_move(rate_hz), 0.0)
        return Progress(self.kind, int(self.labels[m]), self.count, fraction if tick > 0 else 0.0,
                        max(tick, 0) / total, elapsed, total / rate_hz)

    def _first_move(self, rate_hz: float) -> int:
        counts = self.tick_counts(rate_hz)
        nonzero = np.flatnonzero(counts)
        return int(nonzero[0]) if nonzero.size else len(counts) - 1

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """Every goal one sync write per tick would send: ``(t_s (N,), goals_rad (N, n))``, tick 0 … end."""
        ticks = np.arange(self.total_ticks(rate_hz) + 1)
        return ticks / rate_hz, np.array([self.goal_at_tick(int(j), rate_hz) for j in ticks])

    # -- continuous time ------------------------------------------------------------------------------------------
    def _segment(self, t_s: float) -> int:
        """Index of the move in progress at ``t_s`` (moves of zero duration are never in progress)."""
        i = int(np.searchsorted(self._ends_s, t_s, side="right"))
        return min(i, len(self._ends_s) - 1)

    def goal_at(self, t_s: float) -> np.ndarray:
        """Goal pose (rad) at ``t_s`` in continuous time: linear within each move; the last target after the end."""
        if len(self.targets_rad) == 0:
            return self.start_rad.copy()
        if t_s >= self.total_s:
            return self.targets_rad[-1].copy()
        i = self._segment(max(t_s, 0.0))
        a = self.start_rad if i == 0 else self.targets_rad[i - 1]
        b = self.targets_rad[i]
        d = self.durations_s[i]
        s = 1.0 if d <= 0 else min(max((t_s - self._starts_s[i]) / d, 0.0), 1.0)
        return a + (b - a) * s


def _move_durations(start: np.ndarray, targets: np.ndarray, speed_rad_s: float) -> np.ndarray:
    """T = max_j |Δθ_j| / speed for each consecutive move (SPEC §5)."""
    previous = np.vstack([start[None, :], targets[:-1]])
    return np.max(np.abs(targets - previous), axis=1) / speed_rad_s


def _check_speed(speed_rad_s: float, what: str = "speed") -> None:
    if not (isinstance(speed_rad_s, (int, float)) and math.isfinite(speed_rad_s) and speed_rad_s > 0):
        raise TrajectoryError(f"{what} must be a positive number of rad/s, got {speed_rad_s!r}")


def _as_pose(angles: Sequence[float] | np.ndarray, n: int, what: str) -> np.ndarray:
    pose = np.asarray(angles, dtype=float)
    if pose.shape != (n,):
        raise TrajectoryError(f"{what} has {pose.size} angles, expected {n} (one per joint)")
    if not np.all(np.isfinite(pose)):
        raise TrajectoryError(f"{what} contains a non-finite angle")
    return pose


def axis_groups(axes: Sequence[str]) -> dict[str, np.ndarray]:
    """Joint indices of each axis, head to tail (SPEC §5: 'group the joints by axis')."""
    for i, axis in enumerate(axes):
        if axis not in AXES:
            raise TrajectoryError(f"joint {i + 1} has axis {axis!r}; expected 'pitch' or 'yaw'")
    return {axis: np.array([i for i, a in enumerate(axes) if a == axis], dtype=int) for axis in AXES}


def default_shifts(axes: Sequence[str]) -> int:
    """K = m, the number of joints of an axis (the largest axis group if they differ)."""
    return max(len(g) for g in axis_groups(axes).values())


# ----------------------------------------------------------------------------------------------------------------
# Follow-the-leader (SPEC §5)
# ----------------------------------------------------------------------------------------------------------------
def follow_the_leader_targets(shape_rad: Sequence[float] | np.ndarray, axes: Sequence[str],
                              shifts: int | None = None) -> np.ndarray:
    """Targets of shifts k = 0 … K, shape (K+1, n).

    For each axis with taught angles g_1 … g_m (its joints head to tail), the i-th joint's target at shift k is
    g_{i−k} if i−k ≥ 1, else 0 (straight). ``shifts`` = K defaults to m.
    """
    n = len(axes)
    shape = _as_pose(shape_rad, n, "the shape")
    groups = axis_groups(axes)
    k_max = default_shifts(axes) if shifts is None else int(shifts)
    if k_max < 0:
        raise TrajectoryError(f"shifts must be 0 or more, got {shifts}")
    targets = np.zeros((k_max + 1, n))
    for joints in groups.values():
        g = shape[joints]  # g[0] is g_1
        m = len(joints)
        for k in range(k_max + 1):
            if k < m:
                # joint i (1-based) takes g_{i-k} for i > k
                targets[k, joints[k:]] = g[: m - k]
    return targets


def plan_follow_the_leader(present_rad: Sequence[float] | np.ndarray, shape_rad: Sequence[float] | np.ndarray,
                           axes: Sequence[str], speed_rad_s: float = DEFAULT_SPEED_RAD_S,
                           shifts: int | None = None, repeat: int = 1) -> Plan:
    """Present → shift 0 → shift 1 → … → shift K (``repeat`` times), each a straight line at ``speed_rad_s``."""
    _check_speed(speed_rad_s)
    if repeat < 1:
        raise TrajectoryError(f"repeat must be 1 or more, got {repeat}")
    n = len(axes)
    start = _as_pose(present_rad, n, "the present pose")
    one = follow_the_leader_targets(shape_rad, axes, shifts)
    targets = np.vstack([one] * repeat)
    labels = np.tile(np.arange(len(one)), repeat)
    return Plan(start, targets, _move_durations(start, targets, speed_rad_s), labels, "shift")


# ----------------------------------------------------------------------------------------------------------------
# Keyframes (SPEC §5, --mode keyframes)
# ----------------------------------------------------------------------------------------------------------------
def check_keyframes(times_s: Sequence[float] | np.ndarray, poses_rad: np.ndarray, time_scale: float,
                    velocity_limit_rad_s: float, joint_ids: Sequence[int] | None = None,
                    names: Sequence[str] | None = None) -> None:
    """Refuse keyframes out of time order, or a step that needs a joint faster than ``velocity_limit_rad_s``.

    The error names the keyframe (its name if given, else its number from 1), the joint ID, and the speed needed.
    """
    times = np.asarray(times_s, dtype=float)
    n_joints = poses_rad.shape[1]
    ids = list(joint_ids) if joint_ids is not None else list(range(1, n_joints + 1))
    for j in range(1, len(times)):
        label = f"keyframe {j + 1}" + (f" ({names[j]!r})" if names is not None else "")
        dt = (times[j] - times[j - 1]) * time_scale
        step = np.abs(poses_rad[j] - poses_rad[j - 1])
        if dt < 0:
            raise TrajectoryError(f"{label} at t={times[j]} s comes before keyframe {j} at t={times[j - 1]} s; "
                                  "keyframe times must not decrease")
        worst = int(np.argmax(step))
        if step[worst] == 0:
            continue
        needed = math.inf if dt == 0 else step[worst] / dt
        if needed > velocity_limit_rad_s:
            raise TrajectoryError(
                f"{label} needs joint {ids[worst]} to move {step[worst]:.3f} rad in {dt:.3f} s "
                f"({needed:.3f} rad/s), faster than the velocity limit {velocity_limit_rad_s:.3f} rad/s; "
                "spread the keyframes out or raise --time-scale")


def plan_keyframes(present_rad: Sequence[float] | np.ndarray, times_s: Sequence[float] | np.ndarray,
                   poses_rad: Sequence[Sequence[float]] | np.ndarray, *, time_scale: float = 1.0,
                   approach_speed_rad_s: float = DEFAULT_SPEED_RAD_S, velocity_limit_rad_s: float = math.inf,
                   joint_ids: Sequence[int] | None = None, names: Sequence[str] | None = None,
                   repeat: int = 1) -> Plan:
    """Present → keyframe 0 at ``approach_speed_rad_s``, then keyframes linearly in time at ``t_s × time_scale``.

    Repeats go back to keyframe 0 at the approach speed. Raises :class:`TrajectoryError` before anything moves if a
    step would need a joint faster than ``velocity_limit_rad_s``.
    """
    _check_speed(approach_speed_rad_s, "approach speed")
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise TrajectoryError(f"time scale must be positive, got {time_scale}")
    if repeat < 1:
        raise TrajectoryError(f"repeat must be 1 or more, got {repeat}")
    poses = np.asarray(poses_rad, dtype=float)
    times = np.asarray(times_s, dtype=float)
    if poses.ndim != 2 or len(poses) == 0:
        raise TrajectoryError("keyframe mode needs at least one keyframe")
    n = poses.shape[1]
    start = _as_pose(present_rad, n, "the present pose")
    if times.shape != (len(poses),):
        raise TrajectoryError(f"{len(times)} keyframe times for {len(poses)} keyframes")
    if not np.all(np.isfinite(poses)) or not np.all(np.isfinite(times)):
        raise TrajectoryError("a keyframe contains a non-finite time or angle")
    check_keyframes(times, poses, time_scale, velocity_limit_rad_s, joint_ids, names)
    step_s = np.diff(times) * time_scale
    targets, durations, labels = [], [], []
    previous = start
    for _ in range(repeat):
        durations.append(float(np.max(np.abs(poses[0] - previous))) / approach_speed_rad_s)
        targets.append(poses[0])
        labels.append(0)
        for j in range(1, len(poses)):
            targets.append(poses[j])
            durations.append(float(step_s[j - 1]))
            labels.append(j)
        previous = poses[-1]
    return Plan(start, np.array(targets), np.array(durations), np.array(labels), "keyframe")


# ----------------------------------------------------------------------------------------------------------------
# Motion sources (called by the controller thread)
# ----------------------------------------------------------------------------------------------------------------
class PlannedMotion:
    """A MotionSource that plans from the present pose on its first call and then follows the plan.

    ``planner(present_rad) -> Plan``. The plan is sampled at ``rate_hz`` (see :class:`Plan`): the controller's
    time ``t_s`` becomes the tick number ``round(t_s · rate_hz)``, so timing jitter never changes a step, but never
    more than one tick past the previous call: when the loop misses a deadline the motion waits one tick rather
    than take a double step (which would exceed the speed, and could skip a shift target). Every target is sent
    exactly. ``goal_at`` returns the final target once the last tick is due, then ``None`` (done). Call from the
    controller thread only; read :attr:`progress` from anywhere.
    """

    def __init__(self, planner: Callable[[np.ndarray], Plan], kind: str, rate_hz: float) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise TrajectoryError(f"rate must be a positive number of Hz, got {rate_hz!r}")
        self._planner = planner
        self.rate_hz = float(rate_hz)
        self._plan: Plan | None = None
        self._finished = False
        self._last_tick = -1
        self.progress = Progress(kind, 0, 1, 0.0, 0.0, 0.0, 0.0)

    @property
    def plan(self) -> Plan | None:
        """The plan, once the first ``goal_at`` has fixed the start pose."""
        return self._plan

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        if self._plan is None:
            self._plan = self._planner(np.asarray(present_rad, dtype=float))
        if self._finished:
            return None
        plan = self._plan
        tick = min(int(round(t_s * self.rate_hz)), self._last_tick + 1)
        tick = max(tick, self._last_tick, 0)
        self._last_tick = tick
        if tick >= plan.total_ticks(self.rate_hz):
            self._finished = True
        self.progress = plan.progress_at_tick(tick, self.rate_hz)
        return plan.goal_at_tick(tick, self.rate_hz)


class FollowTheLeader(PlannedMotion):
    """SPEC §5 follow-the-leader as a MotionSource; see :func:`plan_follow_the_leader`."""

    def __init__(self, shape_rad: Sequence[float] | np.ndarray, axes: Sequence[str],
                 speed_rad_s: float = DEFAULT_SPEED_RAD_S, shifts: int | None = None, repeat: int = 1,
                 rate_hz: float = 50.0) -> None:
        # Validate now, in the caller's thread, so a bad request fails before the robot moves.
        follow_the_leader_targets(shape_rad, axes, shifts)
        _check_speed(speed_rad_s)
        shape = np.array(shape_rad, dtype=float)
        axes = tuple(axes)
        # A partial, not a lambda: a motion source crosses to the control loop's process by pickling.
        super().__init__(functools.partial(plan_follow_the_leader, shape_rad=shape, axes=axes, speed_rad_s=speed_rad_s,
                                           shifts=shifts, repeat=repeat), "shift", rate_hz)


class Keyframes(PlannedMotion):
    """SPEC §5 keyframe replay as a MotionSource; refuses too-fast steps at construction."""

    def __init__(self, times_s: Sequence[float], poses_rad: Sequence[Sequence[float]] | np.ndarray, *,
                 time_scale: float = 1.0, approach_speed_rad_s: float = DEFAULT_SPEED_RAD_S,
                 velocity_limit_rad_s: float = math.inf, joint_ids: Sequence[int] | None = None,
                 names: Sequence[str] | None = None, repeat: int = 1, rate_hz: float = 50.0) -> None:
        poses = np.array(poses_rad, dtype=float)
        times = np.array(times_s, dtype=float)
        kwargs: dict[str, Any] = dict(time_scale=time_scale, approach_speed_rad_s=approach_speed_rad_s,
                                      velocity_limit_rad_s=velocity_limit_rad_s, joint_ids=joint_ids, names=names,
                                      repeat=repeat)
        if poses.ndim == 2:
            plan_keyframes(poses[0], times, poses, **kwargs)  # validation only: refuse before anything moves
        else:
            raise TrajectoryError("keyframe mode needs at least one keyframe")
        super().__init__(functools.partial(plan_keyframes, times_s=times, poses_rad=poses, **kwargs), "keyframe", rate_hz)


# ----------------------------------------------------------------------------------------------------------------
# Parametric gaits
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SerpenoidParams:
    """θ_i(t) = envelope(t) · α · sin(2π f t − i β) + γ on the joints of one axis (i counts that axis's joints).

    ``amplitude_rad`` α, ``spatial_rad`` β (phase lag per joint of the axis), ``frequency_hz`` f, ``offset_rad`` γ
    (turning), ``cycles`` how many periods to run, ``ramp_s`` the amplitude ramp at start and end.
    """

    amplitude_rad: float = 0.5
    spatial_rad: float = math.pi / 3
    frequency_hz: float = 0.2
    offset_rad: float = 0.0
    cycles: float = 3.0
    ramp_s: float = 2.0


@dataclass(frozen=True)
class SidewindingParams:
    """Yaw wave as :class:`SerpenoidParams`, plus a pitch wave of ``pitch_amplitude_rad`` lagging by ``phase_rad``."""

    yaw: SerpenoidParams = SerpenoidParams()
    pitch_amplitude_rad: float = 0.3
    pitch_spatial_rad: float = math.pi / 3
    phase_rad: float = math.pi / 2


def _envelope(t_s: float, duration_s: float, ramp_s: float) -> float:
    """Smooth 0→1→0 amplitude envelope (raised cosine ramps) so a gait starts and ends straight."""
    if ramp_s <= 0:
        return 1.0 if 0 <= t_s <= duration_s else 0.0
    ramp = min(ramp_s, duration_s / 2) if duration_s > 0 else 0.0
    if ramp <= 0:
        return 0.0
    x = min(t_s / ramp, (duration_s - t_s) / ramp, 1.0)
    x = max(x, 0.0)
    return 0.5 - 0.5 * math.cos(math.pi * x)


def _check_wave(p: SerpenoidParams) -> None:
    for name in ("amplitude_rad", "spatial_rad", "frequency_hz", "offset_rad", "cycles", "ramp_s"):
        if not math.isfinite(getattr(p, name)):
            raise TrajectoryError(f"{name} must be finite")
    if p.frequency_hz <= 0:
        raise TrajectoryError(f"frequency must be positive, got {p.frequency_hz} Hz")
    if p.cycles <= 0:
        raise TrajectoryError(f"cycles must be positive, got {p.cycles}")
    if p.ramp_s < 0:
        raise TrajectoryError(f"ramp must be 0 s or more, got {p.ramp_s} s")


def serpenoid_pose(t_s: float, axes: Sequence[str], yaw: SerpenoidParams | None,
                   pitch: SerpenoidParams | None = None, pitch_phase_rad: float = 0.0) -> np.ndarray:
    """The parametric pose at ``t_s`` (no blending): yaw and/or pitch waves; an axis with ``None`` stays at 0."""
    groups = axis_groups(axes)
    pose = np.zeros(len(axes))
    for axis, params, phase in (("yaw", yaw, 0.0), ("pitch", pitch, pitch_phase_rad)):
        if params is None:
            continue
        duration = params.cycles / params.frequency_hz
        env = _envelope(t_s, duration, params.ramp_s)
        i = np.arange(len(groups[axis]))
        wave = params.amplitude_rad * np.sin(2 * math.pi * params.frequency_hz * t_s - i * params.spatial_rad + phase)
        pose[groups[axis]] = env * wave + env * params.offset_rad
    return pose


class ParametricGait:
    """A parametric gait blended in from the present pose.

    Over the first ``blend_s`` the goal moves from the present pose to the gait with a smooth (raised-cosine)
    weight; the gait's own amplitude ramps from 0, so nothing jumps. Done after the gait's duration.
    """

    def __init__(self, axes: Sequence[str], yaw: SerpenoidParams | None, pitch: SerpenoidParams | None = None,
                 pitch_phase_rad: float = 0.0, blend_s: float | None = None, kind: str = "cycle") -> None:
        for p in (yaw, pitch):
            if p is not None:
                _check_wave(p)
        axis_groups(axes)
        self._axes = tuple(axes)
        self._yaw, self._pitch, self._phase = yaw, pitch, pitch_phase_rad
        waves = [p for p in (yaw, pitch) if p is not None]
        if not waves:
            raise TrajectoryError("a parametric gait needs a yaw or a pitch wave")
        self.duration_s = max(p.cycles / p.frequency_hz for p in waves)
        self._period_s = 1.0 / waves[0].frequency_hz
        self._n_cycles = max(1, math.ceil(waves[0].cycles))
        self.blend_s = max(p.ramp_s for p in waves) if blend_s is None else float(blend_s)
        self._start: np.ndarray | None = None
        self._finished = False
        self.progress = Progress(kind, 0, self._n_cycles, 0.0, 0.0, 0.0, self.duration_s)

    def pose_at(self, t_s: float) -> np.ndarray:
        """The gait without the blend (rad)."""
        return serpenoid_pose(t_s, self._axes, self._yaw, self._pitch, self._phase)

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        if self._start is None:
            self._start = np.asarray(present_rad, dtype=float).copy()
        if self._finished:
            return None
        if t_s >= self.duration_s:
            self._finished = True
            t_s = self.duration_s
        gait = self.pose_at(t_s)
        w = 1.0 if self.blend_s <= 0 else _envelope(min(t_s, self.blend_s), 2 * self.blend_s, self.blend_s)
        cycle = min(int(t_s / self._period_s), self._n_cycles - 1)
        move = (t_s % self._period_s) / self._period_s if not self._finished else 1.0
        self.progress = Progress(self.progress.kind, cycle, self._n_cycles, move,
                                 min(t_s / self.duration_s, 1.0), t_s, self.duration_s, done=self._finished)
        return (1.0 - w) * self._start + w * gait


def serpenoid(axes: Sequence[str], params: SerpenoidParams = SerpenoidParams(),
              blend_s: float | None = None) -> ParametricGait:
    """Lateral undulation: a travelling wave on the yaw joints, pitch joints straight."""
    return ParametricGait(axes, yaw=params, pitch=None, blend_s=blend_s)


def sidewinding(axes: Sequence[str], params: SidewindingParams = SidewindingParams(),
                blend_s: float | None = None) -> ParametricGait:
    """Sidewinding: yaw and pitch waves of the same frequency, the pitch wave ``phase_rad`` out of phase."""
    pitch = SerpenoidParams(amplitude_rad=params.pitch_amplitude_rad, spatial_rad=params.pitch_spatial_rad,
                            frequency_hz=params.yaw.frequency_hz, offset_rad=0.0, cycles=params.yaw.cycles,
                            ramp_s=params.yaw.ramp_s)
    return ParametricGait(axes, yaw=params.yaw, pitch=pitch, pitch_phase_rad=params.phase_rad, blend_s=blend_s)


def plan_blend_to(present_rad: Sequence[float] | np.ndarray, target_rad: np.ndarray, speed_rad_s: float) -> Plan:
    """One straight move from ``present_rad`` to ``target_rad`` at ``speed_rad_s`` (the slowest joint sets its time)."""
    start = _as_pose(present_rad, len(target_rad), "the present pose")
    targets = np.asarray(target_rad, dtype=float)[None, :]
    return Plan(start, targets, _move_durations(start, targets, speed_rad_s), np.zeros(1, int), "shift")


class BlendTo(PlannedMotion):
    """Move from the present pose to ``target_rad`` in a straight line at ``speed_rad_s`` (e.g. 'go straight')."""

    def __init__(self, target_rad: Sequence[float] | np.ndarray, speed_rad_s: float, rate_hz: float = 50.0) -> None:
        _check_speed(speed_rad_s)
        target = np.array(target_rad, dtype=float)
        # A partial, not a closure: a motion source crosses to the control loop's process by pickling.
        super().__init__(functools.partial(plan_blend_to, target_rad=target, speed_rad_s=speed_rad_s), "shift",
                         rate_hz)
