"""The paper's Sec. III-C obstacle experiment in the physics lab, headless and faster than real time.

1. **Settle**: torque off; the limp robot, started straight with segment 6 over the obstacle's top (the paper's
   start), drapes over the half cylinder under gravity.
2. **Capture**: the present joint angles become the shape (as Teach captures a pose pushed by hand in the paper).
3. **Play**: torque on where it is, then follow-the-leader (SPEC §5, :class:`models.trajectory.FollowTheLeader`, the
   motion source ``sensnake play`` uses) at ``speed_rad_s``, goals written at the robot's control rate.
4. **Record** (SPEC §3.5) from the moment of capture: the board's frames (``/daq``), forces estimated live by the
   app's :class:`app.core.forces_pipeline.ForcesPipeline` with the simulated board's own calibration
   (``/forces``), the robot's goals, present angles and currents (``/robot``), and, as an extra group readers may
   ignore, the simulated body (``/sim``: ``time_s``, ``points_m`` N×(n+1)×3 head tip then each segment's back end,
   ``bottom_true_N`` N×n the true bottom-sheet forces) with the scene as attributes.

The robot and the board are reached through their wire protocol on a manual clock (``devices.factory.
headless_physics_lab``), so the run takes as long as the machine needs, not as long as the motion. Servo errors
(overload from physics) are logged as recording events and the run goes on with that servo limp, as on the robot.

Called from one thread (the CLI's main thread).
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from app.core.forces_pipeline import ForcesPipeline
from app.core.recording import RecordingWriter
from devices import factory
from devices.board import FrameParser, conductance_from_counts
from devices.config import LabConfig, SimLabConfig
from models.trajectory import FollowTheLeader

SETTLE_S = 6.0
PAPER_HEIGHT_RATIO = 0.28


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


@dataclass(frozen=True)
class ObstacleResult:
    path: Path
    shape_rad: np.ndarray
    simulated_s: float
    wall_s: float
    advance_m: float  # how far the body's centroid moved forward (+x) while playing
    median_bottom_force_n: float  # median over board samples of the estimated bottom-sheet forces' sum
    weight_n: float
    overloads: tuple[str, ...]

    @property
    def real_time_factor(self) -> float:
        return self.simulated_s / self.wall_s if self.wall_s > 0 else math.inf


def experiment_config(config: LabConfig, height_ratio: float) -> LabConfig:
    """``config`` with its simulated lab set to the physics lab and the obstacle at ``height_ratio`` × body length."""
    if not (math.isfinite(height_ratio) and 0.0 <= height_ratio <= 1.0):
        raise ValueError(f"--height-ratio must be in [0, 1] (× body length; the paper's is 0.28), got {height_ratio}")
    return replace(config, lab=replace(config.lab, physics="mujoco", obstacle_height_ratio=float(height_ratio)))


def run_obstacle_experiment(out: str | Path, config: LabConfig | None = None, *, seconds: float | None = None,
                            height_ratio: float = PAPER_HEIGHT_RATIO, speed_rad_s: float = 0.034,
                            settle_s: float = SETTLE_S, seed: int = 0,
                            progress: Callable[[str], None] | None = None) -> ObstacleResult:
    """Run the experiment and write the recording to ``out``; ``seconds`` caps the played part (default: the whole
    follow-the-leader plan). ``progress`` gets a one-line status about once a wall second."""
    config = experiment_config(config or LabConfig(), height_ratio)
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"--seconds must be positive, got {seconds}")
    if not (math.isfinite(speed_rad_s) and 0 < speed_rad_s <= config.robot.max_joint_speed_rad_s):
        raise ValueError(f"--speed must be in (0, {config.robot.max_joint_speed_rad_s}] rad/s, got {speed_rad_s}")
    robot = config.robot
    lab = factory.headless_physics_lab(config, seed=seed)
    names = config.board.channel_names
    bottom = np.array([i for i, name in enumerate(names) if name.endswith("B")])
    stream = BoardStream(lab, config)
    pipeline = ForcesPipeline(names)
    pipeline.set_readout(config.board.r_c_ohm)
    calibration = json.dumps(lab.ground_truth_calibration())
    with tempfile.TemporaryDirectory() as scratch:
        cal_path = Path(scratch) / "board_truth.json"
        cal_path.write_text(calibration, encoding="utf-8")
        pipeline.load_calibration(cal_path)
    period_s = 1.0 / robot.control_rate_hz
    wall0 = time.perf_counter()

    # 1. Settle limp; the pipeline follows the sensors from the start so its creep state is right at capture.
    lab.set_torque(False)
    tick = 0
    while tick * period_s < settle_s:
        tick += 1
        lab.advance_to(tick * period_s)
        _, conductance, board_time, seq = stream.read()
        if seq.size:
            pipeline.process(board_time, conductance)
    # 2. Capture.
    shape = lab.read_robot().position_rad
    if not np.all(np.isfinite(shape)):
        raise RuntimeError("the simulated robot did not answer the capture read")
    # 3. Play, and 4. record from here on.
    source = FollowTheLeader(shape, robot.axes, speed_rad_s, rate_hz=robot.control_rate_hz)
    lab.write_goals(shape)
    lab.set_torque(True)
    t_capture = lab.time_s
    host0 = time.monotonic()  # recording time = simulated time since capture; host stamps are host0 + that
    writer = RecordingWriter(out, _config_text(config), names, calibration_json=calibration, with_robot=True,
                             n_joints=robot.n_joints, t0_monotonic_s=host0, flush_interval_s=math.inf)
    sim_times: list[float] = []
    sim_points: list[np.ndarray] = []
    sim_bottom: list[np.ndarray] = []
    bottom_totals: list[np.ndarray] = []
    overloads: list[str] = []
    limp: set[int] = set()
    start_centroid = float(lab.body_state().points_m[:, 0].mean())
    goal = shape.copy()
    last_report = -math.inf
    try:
        writer.log_event(f"captured the settled shape after {settle_s:g} s limp; playing follow-the-leader at "
                         f"{speed_rad_s:g} rad/s", host0)
        k = 0
        while True:
            t = k * period_s
            reading = lab.read_robot()
            next_goal = source.goal_at(t, reading.position_rad)
            if next_goal is None or (seconds is not None and t > seconds):
                break
            goal = next_goal
            lab.write_goals(goal)
            for servo_id in reading.alert_ids:
                if servo_id not in limp:
                    limp.add(servo_id)
                    text = f"servo {servo_id} overload (hardware error): torque off, it goes limp"
                    overloads.append(f"t={t:.2f} s: {text}")
                    writer.log_event(text, host0 + t, kind="servo")
            writer.append_robot(host0 + t, goal, reading.position_rad, reading.current_ma)
            body = lab.body_state()
            sim_times.append(t)
            sim_points.append(body.points_m)
            sim_bottom.append(lab.segment_loads_n()[0])
            k += 1
            lab.advance_to(t_capture + k * period_s)
            counts, conductance, board_time, seq = stream.read()
            if seq.size:
                forces = pipeline.process(board_time, conductance).force_n
                writer.append_daq(DaqRows(counts, conductance, host0 + (board_time - t_capture), board_time, seq))
                writer.append_forces(forces)
                bottom_totals.append(np.nansum(forces[:, bottom], axis=1))
            now = time.perf_counter()
            if progress is not None and now - last_report >= 1.0:
                last_report = now
                total = source.progress.total_s if seconds is None else min(seconds, source.progress.total_s)
                progress(f"t = {t:6.1f} / {total:.1f} s simulated  ({(settle_s + t) / (now - wall0):4.1f}× real "
                         f"time)  {source.progress.describe()}")
        writer.flush()
    finally:
        writer.close()
    end_centroid = float(lab.body_state().points_m[:, 0].mean())
    _append_body(out, np.array(sim_times), np.array(sim_points), np.array(sim_bottom), config, lab)
    totals = np.concatenate(bottom_totals) if bottom_totals else np.array([np.nan])
    wall_s = time.perf_counter() - wall0
    simulated_s = settle_s + (sim_times[-1] if sim_times else 0.0)
    weight_n = lab.physics.world.weight_n
    return ObstacleResult(Path(out), shape, simulated_s, wall_s, end_centroid - start_centroid,
                          float(np.nanmedian(totals)), weight_n, tuple(overloads))


def _config_text(config: LabConfig) -> str:
    lab: SimLabConfig = config.lab
    header = (f"# sensnake experiment obstacle: [lab] physics = \"mujoco\", obstacle_height_ratio = "
              f"{lab.obstacle_height_ratio}, obstacle_friction = {lab.obstacle_friction}, ground_friction = "
              f"{lab.ground_friction}\n")
    return header + (config.source_text or "")


def _append_body(out: str | Path, times: np.ndarray, points: np.ndarray, bottom_n: np.ndarray, config: LabConfig,
                 lab: object) -> None:
    """The simulated body as the extra ``/sim`` group (after the recording is closed: readers ignore it)."""
    scene = lab.physics.world.scene  # type: ignore[attr-defined]
    with h5py.File(out, "a") as f:
        group = f.create_group("sim")
        group.create_dataset("time_s", data=times)
        group.create_dataset("points_m", data=points)
        group.create_dataset("bottom_true_N", data=bottom_n)
        group.attrs["obstacle_height_m"] = scene.obstacle_height_m
        group.attrs["obstacle_friction"] = scene.obstacle_friction
        group.attrs["ground_friction"] = scene.ground_friction
        group.attrs["segment_length_m"] = scene.segment_length_m
        group.attrs["weight_N"] = lab.physics.world.weight_n  # type: ignore[attr-defined]
        group.attrs["note"] = ("simulated body (MuJoCo): points_m[:, 0] is the head tip, points_m[:, i] the back "
                               "end of segment i; the obstacle's axis lies along y at x = 0 on the ground")
