"""Experiments in the physics lab, headless and faster than real time: any scene, any motion (``sensnake experiment``).

A run is a plan of four steps, executed by :func:`run_experiment`:

1. **Start**: the robot is placed on the scene (``[robot] head_x_m``) and, for ``start = "settle"``, dropped limp and
   left to settle under gravity (the paper's Sec. III-C drape over its obstacle); for ``start = "flat"`` it lies
   straight with the servos holding it straight.
2. **Shape**: the shape file given (``--shape``), else the settled pose captured (as Teach captures a pose pushed by
   hand in the paper).
3. **Play** it: ``follow`` (follow-the-leader, SPEC §5, :class:`models.trajectory.FollowTheLeader`, the motion source
   ``sensnake play`` uses), ``keyframes`` (the shape file's keyframes), ``serpenoid`` or ``sidewinding`` (the
   parametric gaits, default parameters), goals written at the robot's control rate.
4. **Record** (SPEC §3.5) from the moment of capture: the board's frames (``/daq``), forces estimated live by the
   app's :class:`app.core.forces_pipeline.ForcesPipeline` with the simulated board's own calibration
   (``/forces``), the robot's goals, present angles and currents (``/robot``), and the simulated body (``/sim``:
   ``time_s``, ``points_m`` T×(n+1)×3 head tip then each segment's back end, ``sheet_true_N`` T×C the true normal
   force on each sheet in the board's channel order, ``bottom_true_N`` T×n the bottom sheets' columns of it), with
   the scene file's text (attribute ``scene``) and the robot's weight (``weight_N``).

5. **Come to rest**: once the motion is over (played out, or ``seconds`` reached) the servos hold its last goals and
   the run goes on, recorded, until the body is at rest — its centroid slower than ``REST_SPEED_M_S`` for
   ``REST_HOLD_S`` — or ``rest_cap_s`` of simulated time has passed. The outcome is judged at rest
   (:func:`judge_at_rest`): *traversed* (the whole body past the last obstacle's far edge, and staying there, with
   the margin by which its rearmost point is past it), *not traversed*, or *undecided* (still moving at the cap).

A run checks itself: the world stops at the first sign that its state is not physics (MuJoCo's warnings, a
contact deeper than it resolves, a point faster or an energy higher than anything can make them:
``devices.sim.physics.validity``). The run then ends there, invalid: the recording so far is kept with ``/sim``
attributes ``valid`` = 0 and ``invalid_reason`` (what and when), and the result says so (``valid``,
``invalid_reason``), its measured numbers NaN — never data. A run that fails before the capture (in the settle)
raises :class:`InvalidRunError`. Inputs no physics can honour are refused before anything runs: a tail load beyond
what friction can hold on the scene (``Scene.refuse_unholdable_load``; scene features thinner than the contact
model resolves are refused when the scene is read). MuJoCo's log lines go to the recording's events (``physics``).

The robot and the board are reached through their wire protocol on a manual clock (``devices.factory.
headless_physics_lab``), so the run takes as long as the machine needs, not as long as the motion. Servo errors
(overload from physics) are logged as recording events and the run goes on with that servo limp, as on the robot.

The weight check: on flat ground the bottom sheets' normal forces add up to the weight; on a curved obstacle they
add up to more (a normal 60° from vertical carries half its force upward), and what equals the weight is their
*vertical* part — each sheet's force along the direction its segment's pose gives it (:func:`vertical_support_n`) —
less what friction holds up on a slope, which no sheet feels (a sheet reads pressure). Both are reported, from the
estimated forces as the app shows them; and, from the simulation's true contact forces, the upward part of the
*whole* contact forces (normal and friction) on the bottom sheets and on the whole robot (Newton's check: the weight
when nothing accelerates, on any terrain).

Called from one thread (the CLI's main thread).
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.catalog import finish_run
from app.core.errors import InvalidRunError
from app.core.force_control import ForceFeedbackMotion
from app.core.forces_pipeline import ForcesPipeline
from app.core.play import check_shape_fits
from app.core.recording import RecordingWriter
from app.core.run_documents import condition, run_start_document, with_calibration, with_metadata
from app.core.sensing import sensing_calibration
from devices import factory
from devices.board import FrameParser, conductance_from_counts
from devices.board_wire import saturated_from_counts
from devices.config import LabConfig
from devices.scene import Scene, channel_map, half_cylinder_scene, load_scene, scene_to_toml
from models.controllers import CONTROLLERS, law_gains, uses_law
from models.force_feedback import FeedbackGains
from models.health import HealthMonitor
from models.health import trusted as health_trusted
from models.trajectory import FollowTheLeader, Keyframes, serpenoid, sidewinding

SETTLE_S = 6.0
PAPER_HEIGHT_RATIO = 0.28
# At rest: the body's centroid slower than this for REST_HOLD_S. 1 mm/s is a tenth of the slowest gait's advance
# (follow-the-leader at the paper's 0.034 rad/s moves the body ~1 cm/s) and ten times the creep a body held by its
# servos shows lying still (MuJoCo's soft contacts); 2 s is two of the gaits' slowest wave periods at the paper's speed.
REST_SPEED_M_S = 0.001
REST_HOLD_S = 2.0
REST_CAP_S = 30.0  # how long (simulated s) a run goes on after the motion for the body to come to rest, by default
OUTCOMES = ("traversed", "not traversed", "undecided", "invalid")


@dataclass(frozen=True)
class DaqRows:
    """Board samples in the shape :meth:`RecordingWriter.append_daq` takes."""

    counts: np.ndarray
    conductance_s: np.ndarray
    host_time_s: np.ndarray
    board_time_s: np.ndarray
    seq: np.ndarray


class BoardStream:
    """The board's bytes → verified frames (the host's own parser) → samples with the board clock unwrapped."""

    def __init__(self, lab: object, config: LabConfig) -> None:
        self._lab = lab
        self._board = config.board
        self._parser = FrameParser()
        self._t_us_last: int | None = None
        self._wraps = 0

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(counts N×C, conductance N×C in S, board time N in s, seq N) of the frames that arrived."""
        frames = self._parser.feed(self._lab.read_board_bytes())  # type: ignore[attr-defined]
        n = self._board.n_channels
        if not frames:
            return np.zeros((0, n), np.uint16), np.zeros((0, n)), np.zeros(0), np.zeros(0, np.uint32)
        counts = np.vstack([f.counts for f in frames]).astype(np.uint16)
        board_time = np.empty(len(frames))
        for i, frame in enumerate(frames):
            if self._t_us_last is not None and frame.t_us < self._t_us_last:
                self._wraps += 1
            self._t_us_last = frame.t_us
            board_time[i] = (frame.t_us + self._wraps * 2**32) * 1e-6
        seq = np.array([f.seq for f in frames], dtype=np.uint32)
        return counts, conductance_from_counts(counts, self._board), board_time, seq


MODES = ("follow", "keyframes", "serpenoid", "sidewinding")
SEED_SPREAD = {"start_m": 0.01, "friction": 0.05}
MAX_TAIL_LOAD_N = 30.0


@dataclass(frozen=True)
class ExperimentResult:
    path: Path
    shape_rad: np.ndarray
    simulated_s: float
    wall_s: float
    advance_m: float  # how far the body's centroid moved forward (+x) while playing
    median_bottom_force_n: float  # median over board samples of the estimated bottom-sheet forces' sum
    median_vertical_support_n: float  # median over ticks of the estimated forces' vertical part (see the docstring)
    weight_n: float
    overloads: tuple[str, ...]
    scene_name: str = ""
    traversed: bool = False  # the tail point passed the far edge of the last obstacle (False on flat ground)
    controller: str = "feedforward"
    tail_load_n: float = 0.0
    traverse_s: float = math.nan  # when the tail passed the far edge (NaN: it did not)
    peak_current_ma: float = math.nan
    front_face_cv: float = math.nan
    lost_ground_s: float = math.nan  # first time the sheets together carried < a quarter of the weight (NaN: never)
    rolled_s: float = math.nan  # first time the side sheets carried most of the load (NaN: never)
    crawl_m: float = math.nan  # the centroid's advance when the first of those began (the whole advance if neither)
    median_bottom_support_n: float = math.nan  # median over ticks of the true bottom sheets' whole contact forces'
    # upward part (normal and friction; PhysicsWorld.contact_support_n): the weight, less what lands off the sheets
    median_support_n: float = math.nan  # … of every contact force on the robot: the weight when nothing accelerates
    tail_advance_m: float = math.nan  # how far the tail point moved forward (+x) while playing (see end_pose)
    end_extent_m: float = math.nan  # head tip x − tail end x at the end: ~0.96 m lying straight along the path
    valid: bool = True  # False: the physics stopped being physics (invalid_reason); every measured number is NaN
    invalid_reason: str = ""  # what and when, e.g. "MuJoCo: bad QACC … at DOF 29 (joint seg08_sz) at t=12.34 s"
    outcome: str = "undecided"  # judged at rest (OUTCOMES, judge_at_rest)
    motion_end_s: float = math.nan  # when the motion was over (played out or the seconds cap), recording clock
    at_rest_s: float = math.nan  # when the body was judged at rest (NaN: undecided or invalid)
    rest_margin_m: float = math.nan  # how far the rearmost body point was past the last far edge at rest (<0: short)
    advance_at_rest_m: float = math.nan  # the centroid's advance from the capture to rest
    slide_back_m: float = math.nan  # how far the centroid ended at rest behind the farthest it had been
    rest_cap_s: float = math.nan  # how long the run could go on after the motion for the body to come to rest
    final_speed_m_s: float = math.nan  # the centroid's mean speed over the run's last REST_HOLD_S (RestOutcome)

    @property
    def crawled_traverse(self) -> bool:
        """Traversed, having crawled at least :data:`CRAWLED_M` before the body first lost the ground or rolled onto
        its side (see :func:`body_upsets`): a crawl over the obstacle, not a fall off its crest."""
        return crawled(self.traversed, self.crawl_m)

    @property
    def real_time_factor(self) -> float:
        return self.simulated_s / self.wall_s if self.wall_s > 0 else math.inf


ObstacleResult = ExperimentResult  # the name of the paper's experiment's result, kept for callers


def experiment_config(config: LabConfig, height_ratio: float) -> LabConfig:
    """``config`` with its simulated lab set to the physics lab and the obstacle at ``height_ratio`` × body length."""
    if not (math.isfinite(height_ratio) and 0.0 <= height_ratio <= 1.0):
        raise ValueError(f"--height-ratio must be in [0, 1] (× body length; the paper's is 0.28), got {height_ratio}")
    return replace(config, lab=replace(config.lab, physics="mujoco", obstacle_height_ratio=float(height_ratio),
                                       scene=""))


def vertical_support_n(sheet_n: np.ndarray, frames: np.ndarray, rows: np.ndarray, segments: np.ndarray) -> float:
    """The upward part (N) of sheet normal forces ``sheet_n`` (C,) on a body posed as ``frames`` (n, 3, 3) (columns:
    each segment's forward, left, up axes in the world): a bottom sheet pushes the segment along its up axis, the
    left sheet along −left, the right along +left (contacts taken at the sheets' centres). ``rows`` (C,) is each
    channel's sheet (0 bottom, 1 left, 2 right, −1 none), ``segments`` (C,) its segment."""
    known = rows >= 0
    up_z = frames[segments[known], 2, 2]
    left_z = frames[segments[known], 2, 1]
    direction = np.where(rows[known] == 0, up_z, np.where(rows[known] == 1, -left_z, left_z))
    return float(np.nansum(sheet_n[known] * direction))


def run_obstacle_experiment(out: str | Path, config: LabConfig | None = None, *, seconds: float | None = None,
                            height_ratio: float = PAPER_HEIGHT_RATIO, speed_rad_s: float = 0.034,
                            settle_s: float = SETTLE_S, seed: int = 0, rest_cap_s: float = REST_CAP_S,
                            progress: Callable[[str], None] | None = None) -> ExperimentResult:
    """The paper's Sec. III-C experiment: :func:`run_experiment` on its half cylinder of ``height_ratio`` × body
    length (the lab config's legacy keys), the settled drape played follow-the-leader."""
    config = experiment_config(config or LabConfig(), height_ratio)
    return run_experiment(out, config, seconds=seconds, speed_rad_s=speed_rad_s, settle_s=settle_s, seed=seed,
                          rest_cap_s=rest_cap_s, progress=progress,
                          header=f"# sensnake experiment obstacle: height_ratio = {height_ratio}",
                          md={"plan_name": "experiment obstacle"})


def _motion(mode: str, shape: np.ndarray, keyframes: Any, config: LabConfig, speed_rad_s: float,
            repeat: int = 1) -> Any:
    robot = config.robot
    if mode == "follow":
        return FollowTheLeader(shape, robot.axes, speed_rad_s, repeat=repeat, rate_hz=robot.control_rate_hz)
    if mode == "keyframes":
        if keyframes is None or len(keyframes) == 0:
            raise ValueError("--mode keyframes needs a --shape file with keyframes")
        return Keyframes([k.t_s for k in keyframes], [k.angles_rad for k in keyframes],
                         approach_speed_rad_s=speed_rad_s, velocity_limit_rad_s=robot.max_joint_speed_rad_s,
                         rate_hz=robot.control_rate_hz)
    if mode == "serpenoid":
        return serpenoid(robot.axes)
    if mode == "sidewinding":
        return sidewinding(robot.axes)
    raise ValueError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")


class _LatestForces:
    """The force page of a headless run: what the last board frames estimated, read by the controller's next tick
    (the in-process stand-in for :class:`app.core.force_control.ForcePage`)."""

    def __init__(self, n_channels: int) -> None:
        self.arrival_s = -math.inf
        self.force_n = np.full(n_channels, np.nan)
        self.trusted = np.zeros(n_channels, bool)

    def publish(self, arrival_s: float, force_n: np.ndarray, trusted: np.ndarray) -> None:
        self.arrival_s, self.force_n, self.trusted = arrival_s, force_n.copy(), trusted.copy()

    def read(self) -> tuple[float, np.ndarray, np.ndarray]:
        return self.arrival_s, self.force_n, self.trusted


def run_experiment(out: str | Path, config: LabConfig | None = None, *, scene: str | None = None,
                   shape: Any = None, mode: str = "follow", seconds: float | None = None,
                   speed_rad_s: float = 0.034, settle_s: float = SETTLE_S, seed: int = 0,
                   controller: str = "feedforward", gains: FeedbackGains | None = None, tail_load_n: float = 0.0,
                   repeat: int = 1, rest_cap_s: float = REST_CAP_S, progress: Callable[[str], None] | None = None,
                   header: str = "", md: Mapping[str, Any] | None = None, shape_scale: float = 1.0) -> ExperimentResult:
    """Run a plan (see the module docstring) and write its recording to ``out``. ``scene``: a scene file or a
    built-in scene's name (default: the config's ``[lab] scene``, else its legacy half cylinder); ``shape``: an
    :class:`app.core.shapes.Shape` (default: the settled pose); ``seconds`` caps the played part (default: the whole
    motion); ``controller``: ``feedforward`` (the motion as planned) or ``feedback``
    (:class:`app.core.force_control.ForceFeedbackMotion` with ``gains`` on the live estimated forces);
    ``tail_load_n``: a constant backward force on the tail from the capture on; ``repeat``: how many times a
    follow-the-leader play runs (each re-forms the shape at the head and propagates it again, as ``play --repeat``);
    ``rest_cap_s``: how long the run may go on after the motion for the body to come to rest (0: not at all, the
    outcome is then undecided); ``shape_scale``: the settled pose's angles times this before it is played (an
    evaluation's taught-shape scaling; 1 with a ``shape``); ``controller`` may also be a variant of the law
    (:mod:`models.controllers`). ``progress`` gets a one-line status about once a wall second. An invalid run returns
    a result with ``valid`` False (see the module docstring); one invalid before the capture raises
    :class:`InvalidRunError`."""
    config = config or LabConfig()
    config = replace(config, lab=replace(config.lab, physics="mujoco", scene=scene if scene else config.lab.scene))
    terrain = load_scene(config.lab.scene, default_roll_m=config.lab.physical.roll_resistance_m) \
        if config.lab.scene else None
    # The run's RunStart (app.core.run_documents): its condition is the scene before a seed's jitter; ``md`` adds
    # the caller's metadata (plan_name, trial, series_uid, note), as a bluesky plan's.
    base_scene = terrain or _legacy_terrain(config)
    run_start = with_metadata(run_start_document("experiment run", condition(
        scene=base_scene.name, scene_text=base_scene.text or scene_to_toml(base_scene),
        shape=("settled" if shape_scale == 1.0 else f"settled × {shape_scale:g}") if shape is None else shape.name,
        mode=mode, speed_rad_s=speed_rad_s, controller=controller,
        gains=(gains or FeedbackGains()) if uses_law(controller) else None, tail_load_n=tail_load_n,
        config_text=config.source_text or ""), seed=seed), md)
    scratch_scene: tempfile.TemporaryDirectory | None = None
    if seed > 0:  # a seed other than 0 also varies the start and the frictions (SEED_SPREAD), not only the sensors
        base = terrain or _legacy_terrain(config)
        terrain = jittered_scene(base, seed)
        scratch_scene = tempfile.TemporaryDirectory()
        path = Path(scratch_scene.name) / f"{base.name}-seed{seed}.toml"
        path.write_text(terrain.text, encoding="utf-8")
        config = replace(config, lab=replace(config.lab, scene=str(path)))
    try:
        return _run(out, config, terrain, shape=shape, mode=mode, seconds=seconds, speed_rad_s=speed_rad_s,
                    settle_s=settle_s, seed=seed, controller=controller, gains=gains, tail_load_n=tail_load_n,
                    repeat=repeat, rest_cap_s=rest_cap_s, progress=progress, header=header, run_start=run_start,
                    shape_scale=shape_scale)
    finally:
        if scratch_scene is not None:
            scratch_scene.cleanup()


def _legacy_terrain(config: LabConfig) -> Scene:
    lab = config.lab
    return half_cylinder_scene(lab.obstacle_height_ratio * config.robot.n_joints * config.robot.segment_length_m,
                               lab.obstacle_friction, lab.ground_friction, roll_m=lab.physical.roll_resistance_m)


def jittered_scene(scene: Scene, seed: int) -> Scene:
    """``scene`` with its start moved by N(0, 1 cm) along x (from its ``head_x_m``, or the default start) and every
    friction coefficient scaled by N(1, 5 %), clipped to ±2 s.d. (seeded): the run-to-run spread of placing a real
    robot and of a surface's friction, so that seeds differ in more than sensor noise."""
    rng = np.random.default_rng(seed)
    spread = SEED_SPREAD

    def vary(mu: float) -> float:
        return float(mu * np.clip(rng.normal(1.0, spread["friction"]), 1 - 2 * spread["friction"],
                                  1 + 2 * spread["friction"]))

    head = scene.head_x_m if scene.head_x_m is not None else (5.5 * 0.08 if scene.obstacles else 0.48)
    moved = replace(scene, ground_friction=vary(scene.ground_friction),
                    obstacles=tuple(replace(o, friction=vary(o.friction)) for o in scene.obstacles),
                    head_x_m=head + float(np.clip(rng.normal(0.0, spread["start_m"]), -0.02, 0.02)),
                    name=f"{scene.name} (seed {seed})")
    return replace(moved, text=scene_to_toml(moved))


def _run(out: str | Path, config: LabConfig, terrain: Scene | None, *, shape: Any, mode: str, seconds: float | None,
         speed_rad_s: float, settle_s: float, seed: int, controller: str, gains: FeedbackGains | None,
         tail_load_n: float, repeat: int, rest_cap_s: float, progress: Callable[[str], None] | None,
         header: str, run_start: dict[str, Any] | None = None, shape_scale: float = 1.0) -> ExperimentResult:
    if mode not in MODES:
        raise ValueError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")
    if controller not in CONTROLLERS:
        raise ValueError(f"--controller must be one of {', '.join(CONTROLLERS)}, got {controller!r}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"--seconds must be a finite number above 0, got {seconds}")
    if seed < 0:
        raise ValueError(f"--seed must be 0 or more, got {seed}")
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise ValueError(f"--settle must be 0 s or more, got {settle_s}")
    if not (math.isfinite(speed_rad_s) and 0 < speed_rad_s <= config.robot.max_joint_speed_rad_s):
        raise ValueError(f"--speed must be in (0, {config.robot.max_joint_speed_rad_s}] rad/s, got {speed_rad_s}")
    if not 1 <= repeat <= 100:
        raise ValueError(f"--repeat must be 1 … 100, got {repeat}")
    if not (math.isfinite(tail_load_n) and 0.0 <= tail_load_n <= MAX_TAIL_LOAD_N):
        raise ValueError(f"--tail-load must be in [0, {MAX_TAIL_LOAD_N:g}] N, got {tail_load_n}")
    if not (math.isfinite(rest_cap_s) and rest_cap_s >= 0):
        raise ValueError(f"--rest-cap must be 0 s or more, got {rest_cap_s}")
    if not (math.isfinite(shape_scale) and 0.0 < shape_scale <= 2.0) or (shape is not None and shape_scale != 1.0):
        raise ValueError(f"shape_scale must be in (0, 2] and scales only the settled pose, got {shape_scale}")
    robot = config.robot
    if shape is not None:  # as `sensnake play` refuses it: another joint count, other axes, beyond a joint limit
        check_shape_fits(shape, robot)
    lab = factory.headless_physics_lab(config, seed=seed)
    world = lab.physics.world
    scene_terrain = world.scene.terrain
    scene_terrain.refuse_unholdable_load(tail_load_n, "--tail-load", world.scene.robot_mass_kg)
    physics_log = _PhysicsLog()
    try:
        return _run_lab(out, config, lab, shape=shape, mode=mode, seconds=seconds, speed_rad_s=speed_rad_s,
                        settle_s=settle_s, controller=controller, gains=gains, tail_load_n=tail_load_n,
                        repeat=repeat, rest_cap_s=rest_cap_s, progress=progress, header=header,
                        physics_log=physics_log, terrain_text=terrain.text if terrain is not None else "",
                        run_start=run_start, shape_scale=shape_scale)
    finally:
        physics_log.close()


class _PhysicsLog(logging.Handler):
    """MuJoCo's log lines and the physics lab's (``devices.sim.physics``) while a run goes on, kept for the
    recording's events (and so not printed: the run reports an invalid state itself, in one line)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []
        self._logger = logging.getLogger("devices.sim.physics")
        self._logger.addHandler(self)

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())

    def take(self) -> list[str]:
        lines, self.lines = self.lines, []
        return lines

    def close(self) -> None:
        self._logger.removeHandler(self)
        super().close()


def _run_lab(out: str | Path, config: LabConfig, lab: Any, *, shape: Any, mode: str, seconds: float | None,
             speed_rad_s: float, settle_s: float, controller: str, gains: FeedbackGains | None, tail_load_n: float,
             repeat: int, rest_cap_s: float, progress: Callable[[str], None] | None, header: str,
             physics_log: _PhysicsLog, terrain_text: str, run_start: dict[str, Any] | None = None,
             shape_scale: float = 1.0) -> ExperimentResult:
    robot = config.robot
    world = lab.physics.world
    names = config.board.channel_names
    rows, segments = channel_map(names, robot.n_joints)
    bottom = np.flatnonzero(rows == 0)
    stream = BoardStream(lab, config)
    pipeline = ForcesPipeline(names)
    pipeline.set_readout(config.board.r_c_ohm)
    health = HealthMonitor(len(names), config.board.rate_hz)
    # what the controller senses (app.core.sensing): a rig calibration's errors by default, the truth if ideal
    calibration = json.dumps(sensing_calibration(lab.ground_truth_calibration(), config.lab.sensing, lab.seed)[0])
    with tempfile.TemporaryDirectory() as scratch:
        cal_path = Path(scratch) / "board_truth.json"
        cal_path.write_text(calibration, encoding="utf-8")
        pipeline.load_calibration(cal_path)
    period_s = 1.0 / robot.control_rate_hz
    wall0 = time.perf_counter()
    start = world.scene.terrain.start
    page = _LatestForces(len(names))

    def read_board() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                              np.ndarray | None]:
        """The frames that arrived, their forces estimated (with each force's status code) and published for the
        controller (as the app does)."""
        counts, conductance, board_time, seq = stream.read()
        if not seq.size:
            return counts, conductance, board_time, seq, None, None
        saturated = saturated_from_counts(counts)  # the readout at its ceiling, as the app's board reader marks it
        block = pipeline.process(board_time, conductance, saturated)
        forces = block.force_n
        health.update(board_time, conductance, saturated)
        page.publish(lab.time_s, forces[-1], np.isfinite(forces[-1]) & health_trusted(health.flags))
        return counts, conductance, board_time, seq, forces, block.status

    # 1. Start: settle limp (or lie straight, held); the pipeline follows the sensors from the start so its creep
    # state is right at capture.
    if start == "flat":
        lab.write_goals(np.zeros(robot.n_joints))
        lab.set_torque(True)
    else:
        lab.set_torque(False)
    tick = 0
    while tick * period_s < settle_s:
        tick += 1
        lab.advance_to(tick * period_s)
        if world.invalid is not None:
            raise InvalidRunError(f"invalid run: {world.invalid.describe()} in the {settle_s:g} s settle, before the "
                                  f"capture; nothing recorded")
        read_board()
    # 2. Shape.
    present = lab.read_robot().position_rad
    if not np.all(np.isfinite(present)):
        raise RuntimeError("the simulated robot did not answer the capture read")
    taught = present * shape_scale if shape is None else np.asarray(shape.angles_rad, dtype=float)
    source = _motion(mode, taught, None if shape is None else shape.keyframes, config, speed_rad_s, repeat)
    feedback: ForceFeedbackMotion | None = None
    if uses_law(controller):  # the law, or a variant of it with some of its gains zeroed (models.controllers)
        feedback = ForceFeedbackMotion(source, tuple(robot.axes), tuple(names),
                                       law_gains(controller, gains or FeedbackGains()),
                                       rate_hz=robot.control_rate_hz, page=page, clock=lambda: lab.time_s)
    # 3. Play, and 4. record from here on.
    lab.write_goals(present)
    lab.set_torque(True)
    lab.set_tail_load(tail_load_n)
    t_capture = lab.time_s
    host0 = time.monotonic()  # recording time = simulated time since capture; host stamps are host0 + that
    config_text = (header or f"# sensnake experiment run: scene {world.scene.terrain.name}, mode {mode}, "
                             f"controller {controller}, tail load {tail_load_n:g} N") + "\n"
    run_start = None if run_start is None else with_calibration(run_start, calibration)  # the calibration now known
    writer = RecordingWriter(out, config_text + (config.source_text or ""), names, calibration_json=calibration,
                             with_robot=True, n_joints=robot.n_joints, t0_monotonic_s=host0,
                             flush_interval_s=math.inf, run_start=run_start)
    sim_times: list[float] = []
    sim_points: list[np.ndarray] = []
    sim_rotations: list[np.ndarray] = []  # each segment's orientation: what a motion-capture take is made from
    sim_sheets: list[np.ndarray] = []
    sim_support: list[np.ndarray] = []
    sim_support_total: list[float] = []
    corrections: list[np.ndarray] = []
    currents: list[np.ndarray] = []
    bottom_totals: list[np.ndarray] = []
    vertical: list[float] = []
    overloads: list[str] = []
    limp: set[int] = set()
    start_centroid = float(lab.body_state().points_m[:, 0].mean())
    last_forces: np.ndarray | None = None
    last_report = -math.inf
    far_edge = world.scene.terrain.far_edge_m
    traverse_s = math.nan
    motion = feedback if feedback is not None else source
    held_goal = present  # once the motion is over, the servos hold its last goals
    motion_end_s = math.nan
    played = Played(0, 0, 0, start_centroid)  # the play part of the lists (before the motion was over)
    rest = RestWatch()
    invalid_reason = ""
    try:
        what = "the settled shape" if shape is None else f"shape {shape.name!r}"
        writer.log_event(f"scene {world.scene.terrain.name}: {what} after {settle_s:g} s ({start}); playing {mode} "
                         f"at {speed_rad_s:g} rad/s, {controller}, tail load {tail_load_n:g} N", host0)
        for line in physics_log.take():
            writer.log_event(line, host0, kind="physics")
        k = 0
        while True:
            t = k * period_s
            # The body and its true forces at the tick's instant t: read_robot then waits REPLY_WAIT_S for the
            # replies, and sampling after it recorded /sim 8.5 ms late under the tick's time stamp.
            body = lab.body_state()
            loads = lab.segment_loads_n()
            support, support_total = lab.contact_support_n()
            reading = lab.read_robot()
            if world.invalid is not None:  # the world stopped at its last good state: the run ends there
                break
            goal = None
            if math.isnan(motion_end_s):
                goal = motion.goal_at(t, reading.position_rad)
                if goal is None or (seconds is not None and t > seconds):
                    goal = None
                    motion_end_s = t
                    played = Played(len(sim_times), len(bottom_totals), len(vertical),
                                    float(lab.body_state().points_m[:, 0].mean()))
                    writer.log_event(f"the motion is over at t = {t:.2f} s: the servos hold its last goals until "
                                     f"the body is at rest (at most {rest_cap_s:g} s)", host0 + t)
                    if rest_cap_s <= 0:
                        break
            if goal is None:
                if t - motion_end_s > rest_cap_s + 1e-9:
                    break
                goal = held_goal
            held_goal = goal
            lab.write_goals(goal)
            for servo_id in reading.alert_ids:
                if servo_id not in limp:
                    limp.add(servo_id)
                    text = f"servo {servo_id} overload (hardware error): torque off, it goes limp"
                    overloads.append(f"t={t:.2f} s: {text}")
                    writer.log_event(text, host0 + t, kind="servo")
            writer.append_robot(host0 + t, goal, reading.position_rad, reading.current_ma)
            currents.append(reading.current_ma)
            corrections.append(feedback.correction_rad if feedback is not None else np.zeros(robot.n_joints))
            sim_times.append(t)
            sim_points.append(body.points_m)
            sim_rotations.append(body.frames)
            if math.isnan(traverse_s) and math.isnan(motion_end_s) and float(body.points_m[-1, 0]) > far_edge:
                traverse_s = t
            sheet = np.zeros(len(names))
            known = rows >= 0
            sheet[known] = loads[rows[known], segments[known]]
            sim_sheets.append(sheet)
            support_row = np.zeros(len(names))
            support_row[known] = support[rows[known], segments[known]]
            sim_support.append(support_row)
            sim_support_total.append(support_total)
            if not math.isnan(motion_end_s) and rest.add(t, body.points_m):
                break  # at rest: the outcome can be judged
            k += 1
            lab.advance_to(t_capture + k * period_s)
            for line in physics_log.take():
                writer.log_event(line, host0 + t, kind="physics")
            if world.invalid is not None:
                break
            counts, conductance, board_time, seq, forces, status = read_board()
            if forces is not None:
                writer.append_daq(DaqRows(counts, conductance, host0 + (board_time - t_capture), board_time, seq))
                writer.append_forces(forces, status)
                bottom_totals.append(np.nansum(forces[:, bottom], axis=1))
                last_forces = forces[-1]
            if last_forces is not None:
                vertical.append(vertical_support_n(last_forces, body.frames, rows, segments))
            now = time.perf_counter()
            if progress is not None and now - last_report >= 1.0:
                last_report = now
                total = source.progress.total_s if seconds is None else min(seconds, source.progress.total_s)
                rate = (settle_s + t) / (now - wall0)
                if math.isnan(motion_end_s):
                    left_s = max(total - t, 0.0) / rate if rate > 0 else math.inf
                    progress(f"t = {t:6.1f} / {total:.1f} s simulated  ({rate:4.1f}× real time, about {left_s:.0f} "
                             f"s left)  {source.progress.describe()}")
                else:
                    progress(f"t = {t:6.1f} s simulated  ({rate:4.1f}× real time): the motion is over, waiting "
                             f"for the body to come to rest (at most until t = {motion_end_s + rest_cap_s:.1f} s)")
        if world.invalid is not None:
            invalid_reason = f"invalid run: {world.invalid.describe(t_capture)}"
            writer.log_event(invalid_reason, host0 + world.invalid.time_s - t_capture, kind="physics")
        writer.flush()
    finally:
        writer.close()
    if math.isnan(motion_end_s):  # the run ended invalid while playing
        played = Played(len(sim_times), len(bottom_totals), len(vertical),
                        float(lab.body_state().points_m[:, 0].mean()))
    times, points, sheets = np.array(sim_times), np.array(sim_points), np.array(sim_sheets)
    judged = judge_at_rest(times, points, motion_end_s, far_edge) if not invalid_reason else \
        RestOutcome("invalid", math.nan, math.nan, math.nan, math.nan)
    _append_body(out, times, points, sheets, bottom, lab, terrain_text=terrain_text,
                 support=(np.array(sim_support).reshape(len(times), -1), np.array(sim_support_total)),
                 judged=judged, motion_end_s=motion_end_s, rest_cap_s=rest_cap_s, invalid_reason=invalid_reason,
                 rotations=np.array(sim_rotations))
    if controller != "feedforward":  # SPEC §3.5: /control when a controller other than feedforward ran
        _append_control(out, times, np.array(corrections), controller,
                        law_gains(controller, gains or FeedbackGains()), tail_load_n)
    finish_run(out, run_start, "fail" if invalid_reason else "success", invalid_reason, judged.outcome)
    wall_s = time.perf_counter() - wall0
    simulated_s = settle_s + (sim_times[-1] if sim_times else 0.0)
    scene_terrain = world.scene.terrain
    if invalid_reason:  # nothing measured on a run that stopped being physics is data
        return ExperimentResult(Path(out), taught, simulated_s, wall_s, math.nan, math.nan, math.nan,
                                world.weight_n, tuple(overloads), scene_terrain.name, False,
                                controller=controller, tail_load_n=tail_load_n, valid=False,
                                invalid_reason=invalid_reason, outcome="invalid", motion_end_s=motion_end_s,
                                rest_cap_s=rest_cap_s)
    # The play's figures (as before the run went on to rest): over the ticks before the motion was over.
    n = played.ticks
    play_times, play_points, play_sheets = times[:n], points[:n], sheets[:n]
    totals = np.concatenate(bottom_totals[:played.board_blocks]) if played.board_blocks else np.array([np.nan])
    play_vertical = vertical[:played.vertical]
    play_support = np.array(sim_support[:n])
    traversed = bool(scene_terrain.obstacles) and not math.isnan(traverse_s)
    peak_ma = float(np.nanmax(np.abs(np.array(currents[:n])))) if n else math.nan
    lost_ground_s, rolled_s = body_upsets(play_times, play_sheets, rows, world.weight_n)
    tail_advance_m, end_extent_m = end_pose(play_points)
    return ExperimentResult(Path(out), taught, simulated_s, wall_s, played.end_centroid_x - start_centroid,
                            float(np.nanmedian(totals)), float(np.median(play_vertical)) if play_vertical else math.nan,
                            world.weight_n, tuple(overloads), scene_terrain.name, traversed,
                            controller=controller, tail_load_n=tail_load_n, traverse_s=traverse_s,
                            peak_current_ma=peak_ma,
                            front_face_cv=front_face_cv(play_times, play_points,
                                                        play_sheets[:, bottom] if n else play_sheets, scene_terrain),
                            lost_ground_s=lost_ground_s, rolled_s=rolled_s,
                            crawl_m=crawl_m(play_times, play_points, (lost_ground_s, rolled_s)),
                            median_bottom_support_n=float(np.median(play_support[:, bottom].sum(axis=1)))
                            if n else math.nan,
                            median_support_n=float(np.median(sim_support_total[:n])) if n else math.nan,
                            tail_advance_m=tail_advance_m, end_extent_m=end_extent_m,
                            outcome=judged.outcome, motion_end_s=motion_end_s, at_rest_s=judged.at_rest_s,
                            rest_margin_m=judged.margin_m, advance_at_rest_m=judged.advance_m,
                            slide_back_m=judged.slide_back_m, rest_cap_s=rest_cap_s,
                            final_speed_m_s=judged.final_speed_m_s)


@dataclass(frozen=True)
class Played:
    """Where the play part of a run's lists ends (the motion over): ticks, board blocks, vertical-support values,
    and the centroid's x then."""

    ticks: int
    board_blocks: int
    vertical: int
    end_centroid_x: float


class RestWatch:
    """At rest, tick by tick: the body's centroid slower than ``speed_m_s`` over every tick for ``hold_s`` (the
    ticks fed from the moment the motion was over). :meth:`add` returns True once at rest (:attr:`at_rest_s`)."""

    def __init__(self, speed_m_s: float = REST_SPEED_M_S, hold_s: float = REST_HOLD_S) -> None:
        self.speed_m_s, self.hold_s = speed_m_s, hold_s
        self.at_rest_s = math.nan
        self._last: tuple[float, np.ndarray] | None = None
        self._still_since = math.nan

    def add(self, t_s: float, points_m: np.ndarray) -> bool:
        centroid = np.asarray(points_m, dtype=float).mean(axis=0)
        if self._last is None:
            self._still_since = t_s
        else:
            last_t, last_c = self._last
            if t_s > last_t and float(np.linalg.norm(centroid - last_c)) / (t_s - last_t) >= self.speed_m_s:
                self._still_since = t_s
        self._last = (t_s, centroid)
        if math.isnan(self.at_rest_s) and t_s - self._still_since >= self.hold_s - 1e-9:
            self.at_rest_s = t_s
        return not math.isnan(self.at_rest_s)


@dataclass(frozen=True)
class RestOutcome:
    """A run's outcome judged at rest (:func:`judge_at_rest`). Lengths in m along +x, times on the recording's clock."""

    outcome: str  # one of OUTCOMES
    at_rest_s: float  # NaN: never at rest (undecided)
    margin_m: float  # rearmost body point − the last obstacle's far edge, its least over the rest window
    advance_m: float  # the centroid's advance from the first tick to rest
    slide_back_m: float  # the farthest the centroid had been − where it rests
    final_speed_m_s: float = math.nan  # the centroid's mean speed over the last REST_HOLD_S recorded (the creep of
    # an undecided run; NaN for a recording shorter than that)


def judge_at_rest(times: np.ndarray, points: np.ndarray, motion_end_s: float, far_edge_m: float,
                  speed_m_s: float = REST_SPEED_M_S, hold_s: float = REST_HOLD_S) -> RestOutcome:
    """The outcome of a run from its body points (T × (n+1) × 3, head tip first, at ``times``): the first moment
    after ``motion_end_s`` at which the centroid has been slower than ``speed_m_s`` for ``hold_s``
    (:class:`RestWatch`); then *traversed* if every body point stayed past ``far_edge_m`` (the last obstacle's far
    edge) through that rest window, else *not traversed* (always on flat ground: ``far_edge_m`` −inf); *undecided*
    if the body never came to rest (or ``motion_end_s`` is NaN: the motion never ended)."""
    times = np.asarray(times, dtype=float)
    points = np.asarray(points, dtype=float)
    final_speed = math.nan
    if len(times) > 1 and times[-1] - times[0] >= hold_s - 1e-9:
        first = int(np.searchsorted(times, times[-1] - hold_s - 1e-9))
        final_speed = float(np.linalg.norm(points[-1].mean(axis=0) - points[first].mean(axis=0))
                            / (times[-1] - times[first]))
    undecided = RestOutcome("undecided", math.nan, math.nan, math.nan, math.nan, final_speed)
    if math.isnan(motion_end_s) or not len(times):
        return undecided
    watch = RestWatch(speed_m_s, hold_s)
    for tick in np.flatnonzero(times >= motion_end_s - 1e-9):
        if watch.add(float(times[tick]), points[tick]):
            break
    if math.isnan(watch.at_rest_s):
        return undecided
    k = int(np.searchsorted(times, watch.at_rest_s - 1e-9))
    window = (times >= watch.at_rest_s - hold_s - 1e-9) & (times <= watch.at_rest_s + 1e-9)
    rearmost = points[window, :, 0].min(axis=1)
    margin = float(rearmost.min() - far_edge_m) if math.isfinite(far_edge_m) else math.nan
    centroid_x = points[:, :, 0].mean(axis=1)
    return RestOutcome("traversed" if margin > 0 else "not traversed", watch.at_rest_s, margin,
                       float(centroid_x[k] - centroid_x[0]), float(centroid_x[:k + 1].max() - centroid_x[k]),
                       final_speed)


def outcome_from_recording(path: str | Path) -> tuple[bool, str, RestOutcome]:
    """(valid, invalid_reason, the outcome judged at rest again) of a recording of :func:`run_experiment`, from its
    ``/sim`` group alone; a recording from before these attributes reads as valid, its outcome undecided unless its
    motion's end is known."""
    with h5py.File(path, "r") as f:
        group = f["sim"]
        valid = bool(int(group.attrs.get("valid", 1)))
        reason = str(group.attrs.get("invalid_reason", ""))
        times, points = group["time_s"][:], group["points_m"][:]
        motion_end_s = float(group.attrs.get("motion_end_s", math.nan))
        far_edge = float(group.attrs.get("far_edge_m", -math.inf))
    if not valid:
        return False, reason, RestOutcome("invalid", math.nan, math.nan, math.nan, math.nan)
    return True, "", judge_at_rest(times, points, motion_end_s, far_edge)


def read_gains(path: str | Path) -> FeedbackGains:
    """A gains file: TOML with the keys of :class:`FeedbackGains` at the top level or in a ``[feedback]`` table (not
    both); unknown keys and values outside the safe ranges refused, naming the file and the key. Only a regular file
    of at most 1 MB is read (:func:`devices.toml_files.read_toml_file`)."""
    from devices.toml_files import read_toml_file
    from models.errors import GainsError

    _text, data = read_toml_file(path, "gains file", GainsError)
    table = data.get("feedback", data)
    if not isinstance(table, dict):
        raise GainsError(f"{path}: [feedback] must be a table")
    if "feedback" in data and len(data) > 1:
        top = ", ".join(sorted(key for key in data if key != "feedback"))
        raise GainsError(f"{path}: gains both at the top level ({top}) and in [feedback]; one of them would be "
                         "ignored: put them all in one place")
    return FeedbackGains.from_mapping(table, str(path))


LOST_GROUND_SHARE = 0.25  # the sheets together carry less than this share of the weight …
LOST_GROUND_S = 0.1  # … for this long: the body is in the air or lies on what no sheet covers (its top, its ends)
ROLLED_SHARE = 0.5  # the side sheets carry more than this share of what all the sheets carry …
ROLLED_S = 0.5  # … for this long: the body lies on its side
# A traversal is a crawl if the centroid had advanced this far before the first upset. Measured on 112 traversals of
# benchmarks/sweep_heldout4.toml and sweep_heldout5.toml: the advances fall apart, 0.03-0.09 m (the body balanced on the crest with both ends up, then
# falling off it) or 0.34-0.81 m (the body crawled on until its tail tipped over the crest or it rolled).
CRAWLED_M = 0.2


def crawled(traversed: bool, crawl_m: float) -> bool:
    """A traversal that crawled at least :data:`CRAWLED_M` before its first upset (False for NaN)."""
    return bool(traversed) and crawl_m >= CRAWLED_M


def _first_span(times: np.ndarray, condition: np.ndarray, min_s: float) -> float:
    """The start of the first run of ``condition`` that lasts at least ``min_s`` (NaN: none); a run lasts from its
    first sample to the sample after its last (one tick more for a run that ends the recording)."""
    held = np.asarray(condition, dtype=bool)
    if len(times) == 0 or not held.any():
        return math.nan
    tick = float(times[-1] - times[-2]) if len(times) > 1 else 0.0
    edges = np.diff(np.concatenate([[0], held.astype(np.int8), [0]]))
    for start, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        ends_s = times[end] if end < len(times) else times[-1] + tick
        if ends_s - times[start] >= min_s - 1e-9:
            return float(times[start])
    return math.nan


def body_upsets(times: np.ndarray, sheets_n: np.ndarray, rows: np.ndarray, weight_n: float) -> tuple[float, float]:
    """(when the body first lost the ground, when it first rolled onto its side), NaN for never, from the true
    sheet forces (T × channels, ``rows`` the channel map's side index: 0 bottom, 1 left, 2 right, −1 none).

    A robot that crawls over an obstacle stays on its bottom sheets. The physics lab's segments are round, and a
    body balanced on a crest can fall off it or roll onto its side; such a run may still end with its tail past the
    obstacle. These two times let a traversal be told from a fall: *lost the ground* — the sheets together carry
    less than a quarter of the weight for 0.1 s (in the air, or lying on its top or its segments' ends, which no
    sheet covers); *rolled* — the side sheets carry more than half of what the sheets carry for 0.5 s."""
    if len(times) == 0:
        return math.nan, math.nan
    sheets = np.asarray(sheets_n, dtype=float)
    sensed = sheets[:, rows >= 0].sum(axis=1)
    sides = sheets[:, rows >= 1].sum(axis=1)
    lost = _first_span(times, sensed < LOST_GROUND_SHARE * weight_n, LOST_GROUND_S)
    on_side = (sensed >= LOST_GROUND_SHARE * weight_n) & (sides > ROLLED_SHARE * np.maximum(sensed, 1e-9))
    return lost, _first_span(times, on_side, ROLLED_S)


def crawl_m(times: np.ndarray, points: np.ndarray, upsets_s: tuple[float, ...]) -> float:
    """How far the body's centroid had advanced (+x, m) when the first upset began: what it crawled before it fell
    or rolled (the whole advance if it did neither; NaN for an empty run)."""
    if len(times) == 0:
        return math.nan
    first = min((t for t in upsets_s if not math.isnan(t)), default=math.inf)
    k = len(times) - 1 if math.isinf(first) else int(np.searchsorted(times, first))
    k = min(max(k, 0), len(times) - 1)
    return float(points[k, :, 0].mean() - points[0, :, 0].mean())


def upsets_from_recording(path: str | Path) -> tuple[float, float, float]:
    """(lost the ground, rolled, crawled m) of a recording of :func:`run_experiment`: :func:`body_upsets` and
    :func:`crawl_m` from its ``/sim`` group and the board's channels."""
    with h5py.File(path, "r") as f:
        play = _played_ticks(f)
        times = f["sim/time_s"][play]
        sheets = f["sim/sheet_true_N"][play]
        points = f["sim/points_m"][play]
        weight = float(f["sim"].attrs["weight_N"])
        names = [c.decode() if isinstance(c, bytes) else str(c) for c in f["daq"].attrs["channels"]]
    rows, _ = channel_map(names, points.shape[1] - 1)
    lost, rolled = body_upsets(times, sheets, rows, weight)
    return lost, rolled, crawl_m(times, points, (lost, rolled))


def end_pose(points: np.ndarray) -> tuple[float, float]:
    """(the tail's advance, the body's extent along the path at the end), m, of a run's body points (T×13×3, head tip
    first). Where both controllers traverse, the tail ends in nearly the same place; the centroid's advance then
    says mostly how the body lay down after it came off the obstacle: straight along the path (extent ~0.96 m) or
    curled across it after rolling onto its side (0.25-0.75 m), the centroid up to 0.3 m farther back
    (docs/FORCE_FEEDBACK.md)."""
    if len(points) == 0:
        return math.nan, math.nan
    return float(points[-1, -1, 0] - points[0, -1, 0]), float(points[-1, 0, 0] - points[-1, -1, 0])


def pose_from_recording(path: str | Path) -> tuple[float, float]:
    """:func:`end_pose` of a recording of :func:`run_experiment` (its ``/sim/points_m``)."""
    with h5py.File(path, "r") as f:
        return end_pose(f["sim/points_m"][_played_ticks(f)])


def _played_ticks(f: h5py.File) -> slice:
    """The ``/sim`` rows of a recording's play, before the motion was over (``motion_end_s``; a recording from
    before the run went on to rest: all of them), which the play's figures are computed on."""
    end = float(f["sim"].attrs.get("motion_end_s", math.nan))
    if math.isnan(end):
        return slice(None)
    return slice(0, int(np.searchsorted(f["sim/time_s"][:], end - 1e-9)))


def front_face_cv(times: np.ndarray, points: np.ndarray, bottom_n: np.ndarray, terrain: Any) -> float:
    """Coefficient of variation (s.d. / mean over ticks) of the summed bottom forces of the segments on the first
    obstacle's face toward the robot's tail (x between its back edge and its top): how steadily the body pushes on
    the face that propels it forward. NaN without an obstacle or without contact there."""
    if not terrain.obstacles or len(times) == 0:
        return math.nan
    first = min(terrain.obstacles, key=lambda o: o.x_m)
    lo = first.x_range_m[0]
    top = first.x_m if first.shape == "half_cylinder" else first.x_range_m[0] + 0.02
    mid_x = 0.5 * (points[:, :-1, 0] + points[:, 1:, 0])
    on_face = (mid_x >= lo - 0.02) & (mid_x <= top)
    total = np.where(on_face, bottom_n, 0.0).sum(axis=1)
    pressing = total[total > 0.1]
    if pressing.size < 10:
        return math.nan
    return float(np.std(pressing) / np.mean(pressing))


def _append_control(out: str | Path, times: np.ndarray, corrections: np.ndarray, controller: str,
                    gains: FeedbackGains, tail_load_n: float) -> None:
    """``/control`` (SPEC §3.5): what the controller added to each goal, with its name and gains."""
    with h5py.File(out, "a") as f:
        group = f.create_group("control")
        group.create_dataset("time_s", data=times)
        group.create_dataset("correction_rad", data=corrections.reshape(len(times), -1))
        group.attrs["controller"] = controller
        group.attrs["gains"] = json.dumps(asdict(gains))
        group.attrs["tail_load_N"] = tail_load_n


def _append_body(out: str | Path, times: np.ndarray, points: np.ndarray, sheets_n: np.ndarray, bottom: np.ndarray,
                 lab: Any, terrain_text: str, support: tuple[np.ndarray, np.ndarray] | None = None,
                 judged: RestOutcome | None = None, motion_end_s: float = math.nan, rest_cap_s: float = math.nan,
                 invalid_reason: str = "", rotations: np.ndarray | None = None) -> None:
    """The simulated body as the extra ``/sim`` group (after the recording is closed: readers ignore it);
    ``rotations``: (T, n, 3, 3) each segment's orientation (``segment_rotation``);
    ``support``: (T×C, T) the upward part of each sheet's whole contact force and of every contact force on the
    robot (``PhysicsWorld.contact_support_n``); ``judged``: the outcome at rest; ``invalid_reason``: why the run is
    invalid ("" for a valid one)."""
    world = lab.physics.world
    scene = world.scene
    terrain = scene.terrain
    if not len(times):  # a run invalid at its first tick: empty datasets of the right shapes
        points = np.zeros((0, scene.n_segments + 1, 3))
        sheets_n = np.zeros((0, len(lab.config.board.channel_names)))
        support = (sheets_n.copy(), np.zeros(0))
    with h5py.File(out, "a") as f:
        group = f.create_group("sim")
        group.create_dataset("time_s", data=times)
        group.create_dataset("points_m", data=points)
        if rotations is not None:  # columns: the segment's x (to the head), y (left), z (up) in the world
            group.create_dataset("segment_rotation", data=rotations.reshape(len(times), scene.n_segments, 3, 3))
        group.create_dataset("sheet_true_N", data=sheets_n.reshape(len(times), -1))
        group.create_dataset("bottom_true_N", data=sheets_n.reshape(len(times), -1)[:, bottom])
        if support is not None:
            group.create_dataset("sheet_support_N", data=support[0])
            group.create_dataset("support_N", data=support[1])
        group.attrs["scene"] = terrain_text or scene_to_toml(terrain)
        group.attrs["scene_name"] = terrain.name
        group.attrs["obstacle_height_m"] = max((o.top_m for o in terrain.obstacles), default=0.0)
        group.attrs["obstacle_friction"] = terrain.obstacles[0].friction if terrain.obstacles else math.nan
        group.attrs["ground_friction"] = terrain.ground_friction
        group.attrs["segment_length_m"] = scene.segment_length_m
        group.attrs["weight_N"] = world.weight_n
        group.attrs["physics"] = json.dumps(lab.config.lab.physical.to_dict())  # [lab.physics] in force
        group.attrs["sensing"] = json.dumps(sensing_calibration(lab.ground_truth_calibration(), lab.config.lab.sensing,
                                                                lab.seed)[1])  # what the controller sensed
        group.attrs["note"] = ("simulated body (MuJoCo): points_m[:, 0] is the head tip, points_m[:, i] the back "
                               "end of segment i; sheet_true_N the normal force on each sheet (board channel "
                               "order); sheet_support_N the upward part of each sheet's whole contact force "
                               "(normal and friction), support_N that of every contact force on the robot (the "
                               "weight when nothing accelerates); the obstacles span y, the robot heads toward +x; "
                               "valid 0: the physics stopped being physics (invalid_reason), nothing here is data; "
                               "outcome judged at rest (at_rest_s; rest_margin_m: the rearmost point past "
                               "far_edge_m), after the motion was over at motion_end_s")
        # validity and the outcome at rest (SPEC §7: valid, invalid_reason)
        group.attrs["valid"] = 0 if invalid_reason else 1
        group.attrs["invalid_reason"] = invalid_reason
        group.attrs["motion_end_s"] = motion_end_s
        group.attrs["rest_cap_s"] = rest_cap_s
        group.attrs["far_edge_m"] = terrain.far_edge_m
        # how near the run came to each validity limit (devices.sim.physics.validity), whole run, settle included
        validity = world.validity
        group.attrs["peak_depth_m"] = validity.peak_depth_m
        group.attrs["peak_speed_m_s"] = validity.peak_speed_m_s
        group.attrs["peak_energy_gain_J"] = validity.peak_energy_gain_j
        group.attrs["limits"] = json.dumps({"depth_m": validity.penetration_m, "deepest_m": validity.deepest_m,
                                            "speed_m_s": validity.speed_limit_m_s,
                                            "energy_margin_J": validity.energy_margin_j})
        if judged is not None:
            group.attrs["outcome"] = judged.outcome
            group.attrs["at_rest_s"] = judged.at_rest_s
            group.attrs["rest_margin_m"] = judged.margin_m
            group.attrs["advance_at_rest_m"] = judged.advance_m
            group.attrs["slide_back_m"] = judged.slide_back_m
            group.attrs["final_speed_m_s"] = judged.final_speed_m_s
