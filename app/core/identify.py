"""The physics lab's physical parameters identified from recordings (``sensnake lab identify``).

**What it reads** — only what a recording of the real robot holds: the goals the robot was sent and the angles and
currents it answered (``/robot``), the forces estimated from the board (``/forces``, on ``/daq``'s clock; samples the
pipeline rejected or saw saturated are left out), the segments' positions from motion capture (``/mocap``) when the
recording has them, the run's plan (the root ``run_start``: the tail load it dragged) and the scene it was made on (a
description of the terrain, as the lab's scene file is: ``--scene``, else the recording's copy of it, ``/sim``'s
attribute ``scene``). Never ``/sim``'s data (the simulation's truth) nor the lab config stored in the recording (its
``[lab.physics]`` is the answer); the values fitted start from the ``--config`` given (else the defaults), the scene's
frictions from its ``[lab] ground_friction`` and ``obstacle_friction``.

**How** — each candidate set of values is *replayed*: the physics lab is built with them on the recording's scene,
the robot started as the scene says (dropped limp and settled for ``settle_s``, or lying straight), and the
recording's goals written at its control ticks, open loop, for the first ``window_s`` after the capture (a feedback
run's goals already hold its corrections). What the replay's robot answers (present angles, currents), its sheets'
loads at the board's instants and its segments' centres are compared with what was recorded, each signal in units of
its resolution (:data:`SIGNALS`), and :func:`scipy.optimize.least_squares` moves the values (in log, so each stays
positive and steps are relative) to the least sum of squares. The Jacobian is by forward differences of
:data:`DIFF_STEP` (5 %): MuJoCo's contacts make the signals rough on a finer scale (stick and slip come a step earlier
or later), so a finer difference would follow that roughness, not the trend.

**How sure** — each value's 95 % interval is from the Jacobian at the fit with a cluster-robust covariance: the
residuals of one recording's one signal within one second are one cluster (the model's errors are smooth in time, so
samples are not independent, and treating them so would make the intervals far too narrow). That interval is local:
it says how well the misfit's minimum is located, not how rough the misfit is around it, so three checks follow, and
a value failing any is named as one the recordings cannot fix (it is still written, marked): no signal feels it (a
10 % change moves none by a tenth of its resolution); its interval is wider than ±:data:`FIXED_WITHIN` (10 %); the
replays with it 10 % higher and lower raise the misfit by less than a 95 % test needs to tell them from the fit, or
lower it (:func:`_probe`); or the robot started :data:`START_M` (1 mm) elsewhere along the path moves its best
value by more than 10 % (:func:`_start_shifts`: where the robot was placed is known to about that, and a value that
moves more is told by the recordings less well than the start is). The summary's sensitivity table says, per key
and signal, how far a 10 % rise moves the signal (RMS, in its unit); ``--screen`` adds every key not fitted.

Pure computation on files: any thread (one at a time per call). Needs the ``mujoco`` package.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from devices import factory
from devices.config import LAB_PHYSICS_RANGES, LabConfig, LabPhysicsConfig
from devices.control_table import CURRENT_MA_PER_LSB, RAD_PER_TICK
from devices.scene import Scene, parse_scene

FRICTION_KEYS = ("ground_friction", "obstacle_friction")  # the scene's surfaces' (SPEC §6), [lab]'s legacy keys
FRICTION_RANGE = (0.005, 5.0)  # a scene file's friction range (devices.scene), above 0 for the log
NUMERICAL_KEYS = ("timestep_s",)  # how the lab integrates, not the robot: never fitted
DEFAULT_FIT = ("shell_stiffness_n_per_m", "ground_friction", "obstacle_friction")
DIFF_STEP = 0.05  # the forward difference, in log (5 % of the value)
FIXED_WITHIN = 0.10  # a value is fixed by the recordings when its 95 % interval is within ±10 %
FELT = 0.1  # a 10 % change moves some signal by at least this × its resolution (RMS) or the value is not felt
CLUSTER_S = 1.0  # residuals within one second of one signal of one recording are one cluster (the intervals)
WINDOW_S = 20.0
SETTLE_S = 6.0  # as `sensnake experiment` settles (app.core.experiment.SETTLE_S)
START_M = 0.001  # how well a robot's start is known: placed to within a millimetre (the start-placement check)
MAX_STEPS = 8  # least_squares' steps (each one replay per recording; each Jacobian len(keys) more)
UNUSABLE_FORCE = (5, 6, 10)  # ForceStatus SATURATED, NOT_CONVERGED, READOUT_SATURATED: no force to compare


@dataclass(frozen=True)
class Signal:
    """A measured signal compared with the replay: its label, unit and resolution (the residual's unit)."""

    label: str
    unit: str
    resolution: float


SIGNALS: dict[str, Signal] = {
    "present_rad": Signal("present angles", "rad", RAD_PER_TICK),  # one encoder tick
    "current_mA": Signal("currents", "mA", CURRENT_MA_PER_LSB),  # one step of Present Current
    "force_N": Signal("estimated forces", "N", 0.02),  # the sheets' resolution: 0.5 ADC counts near 2 N
    "mocap_m": Signal("segment positions", "m", 0.0005),  # a segment's centre fitted to its markers
}


def fittable_keys() -> tuple[str, ...]:
    """Every key ``--fit`` takes: the ``[lab.physics]`` keys but the time step, and the scene's frictions."""
    return tuple(f.name for f in fields(LabPhysicsConfig) if f.name not in NUMERICAL_KEYS) + FRICTION_KEYS


def parse_keys(text: str) -> tuple[str, ...]:
    """``--fit KEY,KEY…`` checked: known keys, each once, at least one."""
    keys = tuple(k.strip() for k in text.split(",") if k.strip())
    known = fittable_keys()
    for key in keys:
        if key not in known:
            why = " (how the lab integrates, not a property of the robot)" if key in NUMERICAL_KEYS else ""
            raise ValueError(f"--fit: unknown key {key!r}{why}; known: {', '.join(known)}")
    if not keys:
        raise ValueError("--fit: name at least one key")
    if len(set(keys)) != len(keys):
        raise ValueError(f"--fit: a key named twice in {text!r}")
    return keys


# ----------------------------------------------------------------------------------------------------------------
# What a recording holds
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Measurement:
    """One recording's measured signals over its window (recording clock, s from the capture): the robot's ticks
    ``tick_s`` (K,) with the goals sent, the angles and currents read (K, n; NaN: no answer); the usable estimated
    forces ``force_n`` (F, C; NaN: rejected or saturated) at ``force_s`` (F,); the segments' centres from motion
    capture at the ticks ``mocap_m`` (K, n, 3; NaN: unseen), or None; the scene; the tail load dragged."""

    path: Path
    tick_s: np.ndarray
    goal_rad: np.ndarray
    present_rad: np.ndarray
    current_ma: np.ndarray
    force_s: np.ndarray
    force_n: np.ndarray
    mocap_m: np.ndarray | None
    scene_text: str
    tail_load_n: float
    window_s: float


def read_measurement(path: str | Path, window_s: float = WINDOW_S, scene_text: str | None = None,
                     control_rate_hz: float = 50.0) -> Measurement:
    """The measured signals of ``path`` over its first ``window_s`` (see the module docstring for what is read and
    what never is). ``scene_text``: the scene to replay on (default: the recording's copy of its scene)."""
    path = Path(path)
    with h5py.File(path, "r") as f:
        if "robot" not in f:
            raise ValueError(f"{path}: no /robot group: identify replays the goals the robot was sent")
        robot = f["robot"]
        tick_s = robot["time_s"][:]
        period = 1.0 / control_rate_hz
        if tick_s.size < 2 or abs(float(np.median(np.diff(tick_s))) - period) > 1e-3:
            raise ValueError(f"{path}: /robot was not recorded at the config's control rate ({control_rate_hz:g} Hz, "
                             "the rate the replay writes the goals at): give the recording's lab config (--config)")
        keep = (tick_s - tick_s[0]) <= window_s + 1e-9
        goal, present, current = (robot[name][:][keep] for name in ("goal_rad", "present_rad", "current_mA"))
        ticks = tick_s[keep] - tick_s[0]
        if "forces" not in f or "daq" not in f:
            raise ValueError(f"{path}: no /forces (estimated forces on /daq's clock): nothing to compare the replay's "
                             "sheets with")
        force_s = f["daq/time_s"][:] - tick_s[0]
        force = f["forces/force_N"][:]
        status = f["forces/status"][:] if "status" in f["forces"] else np.zeros(force.shape, np.int8)
        mocap = _mocap_at(f, ticks + tick_s[0]) if "mocap" in f else None
        if scene_text is None:
            if "sim" not in f or "scene" not in f["sim"].attrs:
                raise ValueError(f"{path}: the recording holds no scene: give the one it was made on (--scene)")
            scene_text = str(f["sim"].attrs["scene"])  # the scene's description, as a scene file holds it
            if not int(f["sim"].attrs.get("valid", 1)):  # a run whose physics broke is no measurement
                raise ValueError(f"{path} is marked invalid ({f['sim'].attrs.get('invalid_reason', '')}): not data")
        plan = json.loads(f.attrs["run_start"]) if "run_start" in f.attrs else {}
    tail = float((plan.get("condition") or {}).get("tail_load_n") or 0.0)
    in_window = (force_s >= 0.0) & (force_s <= ticks[-1] + 1e-9)
    usable = np.isfinite(force) & ~np.isin(status, UNUSABLE_FORCE)
    force = np.where(usable, force, np.nan)[in_window]
    return Measurement(path, ticks, goal, present, current, force_s[in_window], force, mocap, scene_text, tail,
                       float(ticks[-1]))


def _mocap_at(f: h5py.File, times_s: np.ndarray) -> np.ndarray:
    """``/mocap``'s segment centres at ``times_s`` (recording clock): the nearest frame within 10 ms, else NaN."""
    group = f["mocap"]
    frame_s, centers = group["time_s"][:], group["segment_center_m"][:]
    out = np.full((times_s.size, *centers.shape[1:]), np.nan)
    if frame_s.size == 0:
        return out
    nearest = np.clip(np.searchsorted(frame_s, times_s), 1, frame_s.size - 1)
    nearest = np.where(np.abs(frame_s[nearest - 1] - times_s) < np.abs(frame_s[nearest] - times_s), nearest - 1,
                       nearest)
    close = np.abs(frame_s[nearest] - times_s) <= 0.010
    out[close] = centers[nearest[close]]
    return out


# ----------------------------------------------------------------------------------------------------------------
# The replay
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Replayed:
    """What the replay's robot gave at the measurement's ticks and force times (the same shapes), and whether its
    physics stayed physics (``invalid``: what and when, "" if it did)."""

    present_rad: np.ndarray
    current_ma: np.ndarray
    force_n: np.ndarray
    centers_m: np.ndarray
    invalid: str


def candidate(config: LabConfig, scene_text: str, values: dict[str, float],
              start_offset_m: float = 0.0) -> tuple[LabConfig, Scene]:
    """The lab config and the terrain of one candidate: ``values`` (key → value, :func:`fittable_keys`) over the
    config's ``[lab.physics]`` and the scene's frictions (``obstacle_friction``: every obstacle's);
    ``start_offset_m``: the robot started that much further along +x than the scene says."""
    physical = replace(config.lab.physical, **{k: float(v) for k, v in values.items() if k not in FRICTION_KEYS})
    terrain = parse_scene(scene_text, "the recording's scene", default_roll_m=physical.roll_resistance_m)
    if start_offset_m:
        robot = config.robot
        head = terrain.head_x_m if terrain.head_x_m is not None else (
            5.5 * robot.segment_length_m if terrain.obstacles else 0.5 * robot.n_joints * robot.segment_length_m)
        terrain = replace(terrain, head_x_m=head + start_offset_m)  # PhysicsWorld.place's default start, moved
    if "ground_friction" in values:
        terrain = replace(terrain, ground_friction=float(values["ground_friction"]))
    if "obstacle_friction" in values:
        terrain = replace(terrain, obstacles=tuple(replace(o, friction=float(values["obstacle_friction"]))
                                                   for o in terrain.obstacles))
    return replace(config, lab=replace(config.lab, physics="mujoco", scene="", physical=physical)), terrain


def replay(measurement: Measurement, config: LabConfig, terrain: Scene, settle_s: float = SETTLE_S) -> Replayed:
    """Replay ``measurement``'s goals in the physics lab of ``config`` on ``terrain`` (module docstring): the same
    calls, in the same order and at the same instants, as ``sensnake experiment`` made (so a recording of the lab
    replayed with the values it was made with gives back its angles and currents to the bit)."""
    robot = config.robot
    lab = factory.headless_physics_lab(config, terrain=terrain)
    world = lab.physics.world
    period = 1.0 / robot.control_rate_hz
    if terrain.start == "flat":
        lab.write_goals(np.zeros(robot.n_joints))
        lab.set_torque(True)
    else:
        lab.set_torque(False)
    tick = 0
    while tick * period < settle_s:
        tick += 1
        lab.advance_to(tick * period)
    lab.read_robot()  # the capture's read (its reply wait is part of the timing)
    goals = measurement.goal_rad
    lab.write_goals(goals[0])
    lab.set_torque(True)
    lab.set_tail_load(measurement.tail_load_n)
    t_capture = lab.time_s
    n = len(goals)
    present = np.full((n, robot.n_joints), np.nan)
    current = np.full((n, robot.n_joints), np.nan)
    centers = np.full((n, robot.n_joints, 3), np.nan)
    board_period = 1.0 / config.board.rate_hz
    next_instant = math.ceil(t_capture / board_period - 1e-9)
    instants: list[float] = []
    loads: list[np.ndarray] = []
    for k in range(n):
        points = lab.body_state().points_m
        centers[k] = 0.5 * (points[:-1] + points[1:])
        lab.segment_loads_n()  # the run read the sheets at every tick (their contact memory follows the reads)
        reading = lab.read_robot()
        lab.write_goals(goals[k])
        present[k], current[k] = reading.position_rad, reading.current_ma
        lab.advance_to(t_capture + (k + 1) * period)
        while next_instant * board_period <= lab.time_s + 1e-12:
            instants.append(next_instant * board_period - t_capture)
            loads.append(lab.physics.forces_n(next_instant * board_period))
            next_instant += 1
    force = _at_times(np.array(instants), np.array(loads), measurement.force_s)
    invalid = world.invalid.describe(t_capture) if world.invalid is not None else ""
    return Replayed(present, current, force, centers, invalid)


def _at_times(times: np.ndarray, values: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """``values`` (T, C) at ``times`` linearly interpolated to ``wanted`` (the same instants give the same values)."""
    if times.size == 0:
        return np.full((wanted.size, values.shape[1] if values.ndim == 2 else 0), np.nan)
    return np.column_stack([np.interp(wanted, times, values[:, c]) for c in range(values.shape[1])])


# ----------------------------------------------------------------------------------------------------------------
# Residuals
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Layout:
    """Where each signal of each recording sits in the residual vector, and each entry's cluster (recording,
    signal, second)."""

    slices: tuple[tuple[int, str, slice], ...]
    clusters: np.ndarray


def _pairs(measurement: Measurement, replayed: Replayed | None) -> list[tuple[str, np.ndarray, np.ndarray,
                                                                              np.ndarray]]:
    """(signal, measured, replayed, time of each entry) of one recording, usable entries only (``replayed`` None:
    the measured values twice, for the layout)."""
    out = []
    ticks = measurement.tick_s
    sources = [("present_rad", measurement.present_rad, ticks), ("current_mA", measurement.current_ma, ticks),
               ("force_N", measurement.force_n, measurement.force_s)]
    if measurement.mocap_m is not None:
        sources.append(("mocap_m", measurement.mocap_m, ticks))
    simulated = {} if replayed is None else {"present_rad": replayed.present_rad, "current_mA": replayed.current_ma,
                                             "force_N": replayed.force_n, "mocap_m": replayed.centers_m}
    for name, measured, times in sources:
        usable = np.isfinite(measured)
        when = np.broadcast_to(times.reshape((-1,) + (1,) * (measured.ndim - 1)), measured.shape)[usable]
        model = simulated[name][usable] if replayed is not None else measured[usable]
        out.append((name, measured[usable], model, when))
    return out


def layout(measurements: Sequence[Measurement]) -> Layout:
    slices = []
    clusters = []
    start = 0
    for i, measurement in enumerate(measurements):
        for name, measured, _, when in _pairs(measurement, None):
            slices.append((i, name, slice(start, start + measured.size)))
            bins = np.floor(when / CLUSTER_S).astype(np.int64)
            clusters.append(((i * len(SIGNALS) + list(SIGNALS).index(name)) << 32) + bins)
            start += measured.size
    return Layout(tuple(slices), np.concatenate(clusters) if clusters else np.zeros(0, np.int64))


def residuals(measurements: Sequence[Measurement], replays: Sequence[Replayed]) -> np.ndarray:
    """(replayed − measured) / resolution, every usable entry of every signal of every recording (:func:`layout`'s
    order). A replayed value that is not finite counts as 1000 resolutions off."""
    parts = []
    for measurement, replayed in zip(measurements, replays):
        for name, measured, model, _ in _pairs(measurement, replayed):
            r = (model - measured) / SIGNALS[name].resolution
            parts.append(np.where(np.isfinite(r), r, 1e3))
    return np.concatenate(parts) if parts else np.zeros(0)


def rms_by_signal(r: np.ndarray, plan: Layout) -> dict[str, float]:
    """The residual's RMS per signal over every recording, in the signal's unit."""
    out: dict[str, float] = {}
    for name, signal in SIGNALS.items():
        parts = [r[s] for _, n, s in plan.slices if n == name]
        values = np.concatenate(parts) if parts else np.zeros(0)
        if values.size:
            out[name] = float(np.sqrt(np.mean(values**2))) * signal.resolution
    return out


# ----------------------------------------------------------------------------------------------------------------
# The fit
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Identified:
    """A fit's result. Values by key; ``interval`` the 95 % interval of each; ``relative_se`` its standard error
    relative to the value; ``sensitivity[key][signal]``: the RMS change of the signal (its unit) for a 10 % rise of
    the key; ``residual_start``/``residual_fit``: each signal's residual RMS (its unit) at the start and the fit;
    ``not_fixed``: the keys the recordings cannot fix, each with why."""

    keys: tuple[str, ...]
    start: dict[str, float]
    value: dict[str, float]
    interval: dict[str, tuple[float, float]]
    relative_se: dict[str, float]
    correlation: np.ndarray
    sensitivity: dict[str, dict[str, float]]
    residual_start: dict[str, float]
    residual_fit: dict[str, float]
    not_fixed: dict[str, str]
    evaluations: int
    cpu_s: float
    recordings: tuple[Path, ...]
    window_s: float
    settle_s: float
    invalid_replays: tuple[str, ...] = ()
    screened: dict[str, dict[str, float]] = field(default_factory=dict)  # keys not fitted: their sensitivity
    probe: dict[str, tuple[float, float]] = field(default_factory=dict)  # key: (misfit rise 10 % away, rise needed)
    start_shift: dict[str, float] = field(default_factory=dict)  # key: its best value's move, the start ±START_M


def start_values(keys: Sequence[str], config: LabConfig) -> dict[str, float]:
    """Where each key's fit starts: the config's ``[lab.physics]`` value, its ``[lab]`` frictions for the scene's."""
    lab = config.lab
    return {key: float(getattr(lab, key) if key in FRICTION_KEYS else getattr(lab.physical, key)) for key in keys}


def _bounds(key: str) -> tuple[float, float]:
    if key in FRICTION_KEYS:
        return FRICTION_RANGE
    low, high, _ = LAB_PHYSICS_RANGES[key]
    return max(low, 1e-9), high  # above 0: the fit moves the log


class _Problem:
    """The replays behind the least-squares problem, cached by the point (least_squares asks for some twice)."""

    def __init__(self, measurements: Sequence[Measurement], config: LabConfig, keys: Sequence[str],
                 start: dict[str, float], settle_s: float, progress: Callable[[str], None] | None) -> None:
        self.measurements, self.config, self.keys = list(measurements), config, tuple(keys)
        self.start, self.settle_s, self.progress = start, settle_s, progress
        self.plan = layout(measurements)
        self.evaluations = 0
        self.invalid: list[str] = []
        self._cache: dict[bytes, np.ndarray] = {}
        self._jacobians: dict[bytes, np.ndarray] = {}

    def values(self, x: np.ndarray, keys: Sequence[str] | None = None) -> dict[str, float]:
        keys = self.keys if keys is None else keys
        return {key: self.start[key] * math.exp(float(v)) for key, v in zip(keys, x)}

    def evaluate(self, values: dict[str, float], start_offset_m: float = 0.0) -> np.ndarray:
        replays = []
        for measurement in self.measurements:
            config, terrain = candidate(self.config, measurement.scene_text, values, start_offset_m)
            replayed = replay(measurement, config, terrain, self.settle_s)
            if replayed.invalid:
                self.invalid.append(f"{measurement.path.name} with {_describe(values)}: {replayed.invalid}")
            replays.append(replayed)
        self.evaluations += 1
        r = residuals(self.measurements, replays)
        if self.progress is not None:
            moved = f", started {1000 * start_offset_m:+g} mm along" if start_offset_m else ""
            self.progress(f"replay {self.evaluations}: {_describe(values)}{moved}: cost {0.5 * float(r @ r):.4g}")
        return r

    def fun(self, x: np.ndarray) -> np.ndarray:
        key = np.asarray(x, dtype=float).tobytes()
        if key not in self._cache:
            self._cache[key] = self.evaluate(self.values(x))
        return self._cache[key]

    def jac(self, x: np.ndarray, *_: Any) -> np.ndarray:
        """Forward differences of :data:`DIFF_STEP` in each log value (toward the inside of the bounds)."""
        key = np.asarray(x, dtype=float).tobytes()
        if key not in self._jacobians:
            r0 = self.fun(x)
            columns = []
            for j, name in enumerate(self.keys):
                step = DIFF_STEP if self.start[name] * math.exp(x[j] + DIFF_STEP) <= _bounds(name)[1] else -DIFF_STEP
                moved = np.array(x, dtype=float)
                moved[j] += step
                columns.append((self.fun(moved) - r0) / step)
            self._jacobians[key] = np.column_stack(columns)
        return self._jacobians[key]


def _describe(values: dict[str, float]) -> str:
    return ", ".join(f"{key} {value:.4g}" for key, value in values.items())


def identify(paths: Sequence[str | Path], keys: Sequence[str] = DEFAULT_FIT, config: LabConfig | None = None, *,
             window_s: float = WINDOW_S, settle_s: float = SETTLE_S, scene_text: str | None = None,
             max_steps: int = MAX_STEPS, screen: bool = False,
             progress: Callable[[str], None] | None = None) -> Identified:
    """Fit ``keys`` so that the physics lab replaying each recording reproduces its measured signals (module
    docstring). ``config``: the lab config the recordings were made with, its ``[lab.physics]`` and frictions the
    starting values (default: the built-in lab); ``scene_text``: the scene every recording was made on (default:
    each recording's own); ``screen``: also the sensitivity of every fittable key not fitted."""
    from scipy.optimize import least_squares

    config = config or LabConfig()
    if not paths:
        raise ValueError("identify needs at least one recording")
    if not (math.isfinite(window_s) and window_s > 0):
        raise ValueError(f"--window must be above 0 s, got {window_s}")
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise ValueError(f"--settle must be 0 s or more, got {settle_s}")
    cpu0 = time.process_time()
    measurements = [read_measurement(p, window_s, scene_text, config.robot.control_rate_hz) for p in paths]
    keys = tuple(keys)
    _refuse_what_cannot_act(keys, measurements)
    start = start_values(fittable_keys(), config)
    problem = _Problem(measurements, config, keys, start, settle_s, progress)
    lows = np.array([math.log(_bounds(k)[0] / start[k]) for k in keys])
    highs = np.array([math.log(_bounds(k)[1] / start[k]) for k in keys])
    x0 = np.zeros(len(keys))
    r0 = problem.fun(x0)
    result = least_squares(problem.fun, x0, jac=problem.jac, bounds=(lows, highs), method="trf", x_scale=1.0,
                           max_nfev=max_steps, xtol=2e-3, ftol=1e-3)
    x = np.asarray(result.x, dtype=float)
    r = problem.fun(x)
    if 0.5 * float(r @ r) > 0.5 * float(r0 @ r0):  # never worse than the start
        x, r = x0, r0
    jacobian = problem.jac(x)
    cov = _cluster_covariance(jacobian, r, problem.plan.clusters)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    values = problem.values(x)
    interval = {k: (values[k] * math.exp(-1.96 * s), values[k] * math.exp(1.96 * s)) for k, s in zip(keys, se)}
    sensitivity = {k: _signal_change(jacobian[:, j], problem.plan) for j, k in enumerate(keys)}
    probes = _probe(problem, values, r, jacobian)
    placed = _start_shifts(problem, values, r, jacobian)
    not_fixed = {}
    for j, key in enumerate(keys):
        felt = max((change / SIGNALS[s].resolution for s, change in sensitivity[key].items()), default=0.0)
        rise, needed = probes[key]
        if felt < FELT:
            not_fixed[key] = (f"no signal feels it: a 10 % change moves none by {FELT:g} of its resolution "
                              f"(at most {felt:.2g})")
        elif not math.isfinite(se[j]) or math.exp(1.96 * se[j]) - 1.0 > FIXED_WITHIN:
            not_fixed[key] = f"its 95 % interval is ±{100 * (math.exp(1.96 * se[j]) - 1.0):.0f} % (over ±" \
                             f"{100 * FIXED_WITHIN:.0f} %)"
        elif rise < 0.0:
            not_fixed[key] = ("10 % away it fits better (the misfit is rough on that scale: stick and slip differ "
                              "from one value to the next), so the fit is not its minimum")
        elif rise < needed:
            not_fixed[key] = (f"10 % away the misfit rises by {rise:.3g}, less than the {needed:.3g} a 95 % "
                              "interval within ±10 % needs")
        elif abs(placed[key]) > FIXED_WITHIN:
            not_fixed[key] = (f"the robot placed {1000 * START_M:g} mm elsewhere moves its best value by "
                              f"{100 * placed[key]:+.0f} %: the recordings tell it less well than where the robot "
                              "started")
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = cov / np.outer(se, se)
    screened = {}
    if screen:
        for other in fittable_keys():
            if other in keys:
                continue
            moved = dict(values)
            moved[other] = start[other] * math.exp(DIFF_STEP)
            column = (problem.evaluate(moved) - r) / DIFF_STEP
            screened[other] = _signal_change(column, problem.plan)
    return Identified(keys, {k: start[k] for k in keys}, values, interval,
                      {k: float(s) for k, s in zip(keys, se)}, correlation, sensitivity,
                      rms_by_signal(r0, problem.plan), rms_by_signal(r, problem.plan), not_fixed,
                      problem.evaluations, time.process_time() - cpu0, tuple(Path(p) for p in paths), window_s,
                      settle_s, tuple(problem.invalid), screened, probes, placed)


def _probe(problem: _Problem, values: dict[str, float], r: np.ndarray,
           jacobian: np.ndarray) -> dict[str, tuple[float, float]]:
    """Per fitted key: (the least rise of the cost ½|r|² when the key alone is 10 % higher or lower, the rise a value
    known to ±10 % at 95 % needs): the replays themselves, not the Jacobian's straight line, so a rough misfit (a
    lower cost 10 % away) or a flat one shows. The rise needed is 1.92 B/A (A = JⱼᵀJⱼ, B = Σ_c (Jⱼ,cᵀ r_c)²: the
    misfit's scale in the key's direction, cluster-robust), where a likelihood-ratio test at 95 % would tell the
    change from the fit; on a quadratic misfit it says the same as the key's own interval."""
    cost = 0.5 * float(r @ r)
    clusters = problem.plan.clusters
    out = {}
    for j, key in enumerate(problem.keys):
        column = jacobian[:, j]
        a = float(column @ column)
        variance = float(_cluster_covariance(column[:, None], r, clusters)[0, 0])  # B / A²
        needed = 1.92 * variance * a if a > 0 and math.isfinite(variance) else math.inf
        rises = []
        low, high = _bounds(key)
        for factor in (1.0 + FIXED_WITHIN, 1.0 / (1.0 + FIXED_WITHIN)):
            moved = dict(values)
            moved[key] = min(max(values[key] * factor, low), high)
            rm = problem.evaluate(moved)
            rises.append(0.5 * float(rm @ rm) - cost)
        out[key] = (min(rises), needed)
    return out


def _start_shifts(problem: _Problem, values: dict[str, float], r: np.ndarray,
                  jacobian: np.ndarray) -> dict[str, float]:
    """Per fitted key, the largest relative change of its best value when the robot's start is :data:`START_M`
    further or nearer along the path than the scene says (a Gauss-Newton step from the fit with the replays so
    started): what placing a robot to within a millimetre leaves open. A slow play keeps the contacts where the
    settle left them, and a value whose signals are mostly that (the frictions, with the body sticking) moves with
    the start; a play whose contacts slide forgets it."""
    here = np.linalg.lstsq(jacobian, r, rcond=None)[0]
    worst = np.zeros(len(problem.keys))
    for offset in (START_M, -START_M):
        moved = np.linalg.lstsq(jacobian, problem.evaluate(values, offset), rcond=None)[0]
        worst = np.maximum(worst, np.abs(np.exp(here - moved) - 1.0))
    return {key: float(w) for key, w in zip(problem.keys, worst)}


def _refuse_what_cannot_act(keys: Sequence[str], measurements: Sequence[Measurement]) -> None:
    """A key no replay could move: obstacle friction on scenes without obstacles, the roll resistance default on
    scenes that name every surface's own."""
    scenes = [parse_scene(m.scene_text, str(m.path)) for m in measurements]
    if "obstacle_friction" in keys and not any(s.obstacles for s in scenes):
        raise ValueError("--fit obstacle_friction: the recordings' scenes have no obstacle")
    if "obstacle_friction" in keys:
        for m, s in zip(measurements, scenes):
            if len({o.friction for o in s.obstacles}) > 1:
                raise ValueError(f"--fit obstacle_friction: {m.path.name}'s scene has obstacles of different frictions "
                                 f"({', '.join(f'{o.friction:g}' for o in s.obstacles)}); obstacle_friction would "
                                 "give them one (fit a scene whose obstacles share one cover)")
    if "roll_resistance_m" in keys and all("roll_resistance_m" in m.scene_text for m in measurements):
        raise ValueError("--fit roll_resistance_m: the recordings' scenes name their surfaces' roll resistance, so "
                         "[lab.physics] roll_resistance_m (the default of a surface naming none) acts on nothing")


def _signal_change(column: np.ndarray, plan: Layout) -> dict[str, float]:
    """The RMS change of each signal (its unit) for a 10 % rise of a value, from its Jacobian column (per unit of
    log value, in resolutions)."""
    step = math.log(1.1)
    return {name: rms * step for name, rms in rms_by_signal(column, plan).items()}


def _cluster_covariance(jacobian: np.ndarray, r: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """The cluster-robust (sandwich) covariance of the log values: (JᵀJ)⁻¹ (Σ_c J_cᵀ r_c r_cᵀ J_c) (JᵀJ)⁻¹, with the
    small-sample factor G/(G − 1)."""
    p = jacobian.shape[1]
    a = jacobian.T @ jacobian
    try:
        a_inv = np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return np.full((p, p), np.inf)
    order = np.argsort(clusters, kind="stable")
    scores = jacobian[order] * r[order, None]
    boundaries = np.flatnonzero(np.diff(clusters[order])) + 1
    sums = np.add.reduceat(scores, np.concatenate([[0], boundaries]), axis=0) if scores.size else np.zeros((0, p))
    groups = sums.shape[0]
    meat = sums.T @ sums * (groups / max(groups - 1, 1))
    return a_inv @ meat @ a_inv


# ----------------------------------------------------------------------------------------------------------------
# The fitted file
# ----------------------------------------------------------------------------------------------------------------
def fitted_toml(result: Identified) -> str:
    """The fitted values as a lab-config fragment: ``[lab.physics]`` keys, and the scene's frictions as ``[lab]``'s
    (the legacy half cylinder's, ``sensnake experiment obstacle``'s scene; a scene file takes them in its own
    ``[ground]`` and ``[[obstacle]]`` friction), each with its interval and where it started; the residuals and
    what the recordings cannot fix in comments."""
    names = ", ".join(p.name for p in result.recordings)
    lines = [f"# sensnake lab identify: fitted to {len(result.recordings)} recording(s) ({names}), replaying the "
             f"goals of the first {result.window_s:g} s after each capture ({result.settle_s:g} s settle first);",
             f"# {result.evaluations} replays, {result.cpu_s:.0f} s of CPU. Each value: its 95 % interval "
             "(cluster-robust, 1 s clusters) and its starting value.",
             "# Residual RMS per signal, at the fit (at the start): " + "; ".join(
                 f"{SIGNALS[s].label} {_unit(result.residual_fit[s], s)} ({_unit(result.residual_start[s], s)})"
                 for s in result.residual_fit)]
    if result.not_fixed:
        lines.append("# NOT FIXED by these recordings (kept here, but do not trust them): " + "; ".join(
            f"{k}: {why}" for k, why in result.not_fixed.items()))
    else:
        lines.append(f"# Every value is fixed by these recordings (95 % interval within ±{100 * FIXED_WITHIN:.0f} %).")
    for title, chosen in (("lab", [k for k in result.keys if k in FRICTION_KEYS]),
                          ("lab.physics", [k for k in result.keys if k not in FRICTION_KEYS])):
        if not chosen:
            continue
        lines.append("")
        if title == "lab":
            lines.append("# the scene's frictions ([lab] keys of the legacy half cylinder, 'experiment obstacle'); "
                         "a scene file takes them as its [ground] / [[obstacle]] friction")
        lines.append(f"[{title}]")
        for key in chosen:
            low, high = result.interval[key]
            lines.append(f"{key} = {result.value[key]:.6g}  # 95 %: {low:.4g} to {high:.4g}; started from "
                         f"{result.start[key]:.6g}" + ("; NOT FIXED" if key in result.not_fixed else ""))
    return "\n".join(lines) + "\n"


def _unit(value: float, signal: str) -> str:
    unit = SIGNALS[signal].unit
    if unit == "rad":
        return f"{value * 1000:.3g} mrad"
    if unit == "m":
        return f"{value * 1000:.3g} mm"
    return f"{value:.3g} {unit}"


def write_fitted(result: Identified, out: str | Path) -> Path:
    """Write :func:`fitted_toml` to ``out``, a new file (an existing one is never replaced)."""
    out = Path(out)
    with open(out, "x", encoding="utf-8") as handle:
        handle.write(fitted_toml(result))
    return out


def summary_lines(result: Identified) -> list[str]:
    """The fit as a table a person reads: each value with its interval, start and verdict; each signal's residual;
    the sensitivity table (how far a 10 % rise moves each signal, RMS, against its resolution)."""
    lines = [f"{'key':<34} {'fitted':>10} {'95 % interval':>21} {'start':>10} {'±10 %: misfit rise (needed)':>28} "
             f"{'start ±1 mm':>11}  verdict"]
    for key in result.keys:
        low, high = result.interval[key]
        verdict = "NOT FIXED: " + result.not_fixed[key] if key in result.not_fixed else "fixed"
        rise, needed = result.probe.get(key, (math.nan, math.nan))
        shift = result.start_shift.get(key, math.nan)
        lines.append(f"{key:<34} {result.value[key]:10.5g} {low:10.4g}–{high:<10.4g} {result.start[key]:10.5g} "
                     f"{f'{rise:.3g} ({needed:.3g})':>28} {f'{100 * shift:.1f} %':>11}  {verdict}")
    lines.append("residual RMS, at the fit (at the start): " + "; ".join(
        f"{SIGNALS[s].label} {_unit(result.residual_fit[s], s)} ({_unit(result.residual_start[s], s)})"
        for s in result.residual_fit))
    table = {**result.sensitivity, **result.screened}
    signals = [s for s in SIGNALS if any(s in row for row in table.values())]
    lines.append("a 10 % rise moves each signal by (RMS; resolution in brackets):")
    lines.append(f"{'key':<34} " + " ".join(f"{SIGNALS[s].label + ' (' + _unit(SIGNALS[s].resolution, s) + ')':>28}"
                                             for s in signals))
    for key, row in table.items():
        lines.append(f"{key + (' (not fitted)' if key in result.screened else ''):<34} " + " ".join(
            f"{_unit(row.get(s, math.nan), s):>28}" for s in signals))
    if len(result.keys) > 1:
        pairs = [(result.keys[i], result.keys[j], result.correlation[i, j]) for i in range(len(result.keys))
                 for j in range(i + 1, len(result.keys)) if abs(result.correlation[i, j]) > 0.9]
        for a, b, c in pairs:
            lines.append(f"{a} and {b} are correlated ({c:+.2f}): the recordings tell their combination better than "
                         "each")
    if result.invalid_replays:
        lines.append(f"{len(result.invalid_replays)} replay(s) stopped being physics (their residuals count as "
                     f"large): {result.invalid_replays[0]}")
    return lines
