"""Physics lab (MuJoCo) benchmark: real-time factor against error, alone, through the wire, and under the app's plots.

(a) The world alone at three time steps: real-time factor (simulated s per wall s) of three scenes — held straight on
    flat ground, limp over the paper's obstacle (draping), follow-the-leader over it — against two errors with known
    ground truth: the bottom sheets' total force at rest on flat ground against m·g, and the settled limp drape's
    pitch angles against the wrap angle of a chain on a circle, −2·L/(h + r).
(b) The headless lab of ``sensnake experiment``: world + virtual chain + virtual board, driven through their wire
    protocols on a manual clock (what an experiment costs per simulated second).
(c) The app's lab: the physics lab stepping in its own thread at real time (speed 1), first alone, then with the
    Forces tab's plots running offscreen on the same process; reported as the world's real-time factor (1.0 = it kept
    up; below 1 the world skipped time, see ``PhysicsWorld.lagged_s``) and the plots' redraw rate.
(d) How true the forces are (app.core.physics_check on recordings of ``sensnake experiment run``): on flat ground (a
    bent shape, not one anything was tuned on) and on the paper's obstacle (the settled drape), played
    follow-the-leader at 0.034 and 0.3 rad/s: the bottom sheets' sum against the weight (and its vertical part), the
    share of 30 Hz frames with a > 1 N change on some sheet (true and estimated; "reversals" are the chattering
    ones), and the estimated forces' error against the true ones (RMS and 99th percentile per loaded sheet).
(e) The paper's experiment (``sensnake experiment obstacle``) at 20, 30 and 76 s: the median total bottom force and
    its vertical part against the weight.
(f) The other built-in scenes (step, wedge, two obstacles), the bent shape and the settled drape at 0.034 and
    0.3 rad/s: the same checks as (d), with every sheet summed as well as the bottom ones' vertical part, and the
    jumps split by what the body was doing: falling, tipping or landing (a point faster than 0.2 m/s) or creeping.
(g) Scenes no built-in has and nothing was tuned on (``benchmarks/scenes/terrain/``: a 12 cm step, a step down, a
    27° ramp, three bumps, a ramp then a cylinder), the settled drape at 0.034 and 0.3 rad/s: the checks of (f).
Targets: the simulation at least at real time on 2 cores while the GUI plots; forces summing to the
weight within ±10 % in ≥ 95 % of frames, < 1 % of frames with a > 1 N jump, median per-sheet RMS ≤ 0.3 N.

Wall-clock figures depend on the machine's load (the lab's 2 cores are shared): compare rows of one run.
``run(quick, sections)``; ``python -m benchmarks.bench_physics [--quick] [--sections abcdefg]``.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")


def _world_rows(quick: bool) -> list[dict]:
    from devices.sim.physics.model import SceneParams
    from devices.sim.physics.world import PhysicsWorld
    from models.trajectory import plan_follow_the_leader

    rows = []
    for dt in (0.001, 0.002, 0.004):
        flat = SceneParams(obstacle_height_m=0.0, timestep_s=dt)
        world = PhysicsWorld(flat)
        world.command(np.ones(12, bool), np.zeros(12))
        seconds = 1.0 if quick else 3.0
        t0 = time.perf_counter()
        world.step(int(seconds / dt))
        rtf_flat = seconds / (time.perf_counter() - t0)
        weight_error = abs(world.segment_loads_n()[0].sum() - world.weight_n) / world.weight_n

        scene = SceneParams(timestep_s=dt)
        world = PhysicsWorld(scene)
        seconds = 6.0
        t0 = time.perf_counter()
        world.step(int(seconds / dt))
        rtf_drape = seconds / (time.perf_counter() - t0)
        wrap = -2 * scene.segment_length_m / (scene.obstacle_height_m + scene.segment_radius_m)
        shape = world.joint_state().position_rad
        drape_error = float(np.max(np.abs(shape[[2, 4, 6, 8]] - wrap)))

        world.command(np.ones(12, bool), shape)
        plan = plan_follow_the_leader(shape, shape, scene.axes, 0.1)
        seconds = 5.0 if quick else 15.0
        ticks = int(seconds * 50)
        per_tick = max(1, int(round(0.02 / dt)))
        t0 = time.perf_counter()
        for k in range(ticks):
            world.command(np.ones(12, bool), plan.goal_at(k * 0.02))
            world.step(per_tick)
        rtf_play = seconds / (time.perf_counter() - t0)
        rows.append({"dt_ms": dt * 1e3, "rtf_flat": rtf_flat, "rtf_drape": rtf_drape, "rtf_play": rtf_play,
                     "weight_err_pct": 100 * weight_error, "drape_err_rad": drape_error})
    return rows


def _headless_rtf(quick: bool) -> float:
    from devices import factory
    from devices.config import LabConfig, SimLabConfig

    lab = factory.headless_physics_lab(replace(LabConfig(), lab=SimLabConfig(physics="mujoco")))
    seconds = 3.0 if quick else 10.0
    t0 = time.perf_counter()
    for k in range(int(seconds * 50)):
        lab.advance_to((k + 1) * 0.02)
        lab.read_robot()
        lab.read_board_bytes()
    return seconds / (time.perf_counter() - t0)


def _app_rows(quick: bool) -> list[dict]:
    from PySide6.QtCore import QEventLoop, QTimer
    from PySide6.QtWidgets import QApplication

    import widgets  # noqa: F401 - installs the PySide6 refcount guard before Qt is used
    from app.gui.lab import LabContext
    from app.gui.tabs.forces import ForcesTab
    from devices import factory
    from devices.config import LabConfig, SimLabConfig
    from devices.sim.lab import SimLab

    app = QApplication.instance() or QApplication([])
    run_s = 4.0 if quick else 15.0
    config = replace(LabConfig(), lab=SimLabConfig(physics="mujoco"))
    rows = []
    for with_plots in (False, True):
        sim = SimLab(config, seed=3, speed=1.0)
        assert sim.physics is not None
        previous = factory.install_sim_lab(sim)
        sim.start_background()
        lab = tab = None
        try:
            if with_plots:
                lab = LabContext(config)
                tab = ForcesTab(lab)
                tab.resize(1600, 1000)
                tab.show()
                lab.board.start()
            loop = QEventLoop()
            QTimer.singleShot(1000, loop.quit)  # warm-up
            loop.exec()
            world = sim.physics.world
            steps0, lag0, wall0, cpu0 = world.steps, world.lagged_s, time.monotonic(), time.process_time()
            rested0 = world.rested_s
            stepping0 = world.stepping_s
            redraws0 = tab.plots.redraw_count if tab is not None else 0
            QTimer.singleShot(int(run_s * 1000), loop.quit)
            loop.exec()
            wall = time.monotonic() - wall0
            # stepped, or resting (nothing moved: the clock moves on without stepping) — both keep up with time
            simulated = (world.steps - steps0) * world.scene.timestep_s + (world.rested_s - rested0)
            rows.append({"scenario": "physics thread + Forces tab plots" if with_plots else "physics thread alone",
                         "rtf": simulated / wall, "lagged_s": world.lagged_s - lag0,
                         "busy": (world.stepping_s - stepping0) / wall,
                         "cpu_pct": 100 * (time.process_time() - cpu0) / wall,
                         "fps": ((tab.plots.redraw_count - redraws0) / wall) if tab is not None else float("nan")})
        finally:
            if tab is not None:
                tab.shutdown()
                tab.deleteLater()
            if lab is not None:
                lab.close()
            sim.close()
            factory.install_sim_lab(previous)
            app.processEvents()
    return rows


def _truth_rows(quick: bool, scenes: tuple[str, ...] = ("flat", "paper_obstacle"), both_shapes: bool = False) -> list[dict]:
    import tempfile
    from pathlib import Path

    from app.core.experiment import run_experiment
    from app.core.physics_check import check_recording
    from app.core.shapes import Shape

    bent = np.zeros(12)
    bent[[1, 2, 3, 4, 5]] = [0.45, 0.2, -0.55, -0.2, 0.45]
    shape = Shape("bent", tuple("pitch" if i % 2 == 0 else "yaw" for i in range(12)), tuple(bent))
    # flat ground plays the bent shape, an obstacle its settled drape (or both, for the other scenes)
    plans = [(scene, taught) for scene in scenes
             for taught in ((shape, None) if both_shapes else ((shape,) if scene == "flat" else (None,)))]
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for scene, taught in plans:
            for speed in (0.034, 0.3):
                seconds = (20.0 if quick else 60.0) if speed < 0.1 else (10.0 if quick else 30.0)
                out = Path(scratch) / f"{Path(scene).stem}_{speed}_{'bent' if taught is not None else 'drape'}.h5"
                t0 = time.perf_counter()
                result = run_experiment(out, scene=scene, shape=taught, speed_rad_s=speed, seconds=seconds,
                                        settle_s=3.0 if scene == "flat" else 6.0)
                wall = time.perf_counter() - t0
                rows.append({"scene": scene, "speed": speed, "seconds": seconds, "wall": wall,
                             "shape": "bent" if taught is not None else "drape",
                             "check": check_recording(out), "rtf": result.real_time_factor})
    return rows


def _paper_rows(quick: bool) -> list[dict]:
    import tempfile
    from pathlib import Path

    from app.core.experiment import run_obstacle_experiment

    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for seconds in ((20.0,) if quick else (20.0, 30.0, 76.0)):
            result = run_obstacle_experiment(Path(scratch) / f"paper_{seconds}.h5", seconds=seconds)
            rows.append({"seconds": seconds, "bottom": result.median_bottom_force_n,
                         "vertical": result.median_vertical_support_n, "weight": result.weight_n,
                         "support": result.median_bottom_support_n})
    return rows


TERRAIN_DIR = os.path.join(os.path.dirname(__file__), "scenes", "terrain")


def _print_scene_rows(rows: list[dict]) -> None:
    print(f"{'scene':<20} {'shape':<6} {'rad/s':>6} {'sim s':>6} {'Σall±10%':>9} {'vertical±10%':>13} "
          f"{'robot↑±10%':>11} {'jumps true':>11} {'(chatter)':>9} {'falling':>8} {'jumps creeping':>15} "
          f"{'(chatter)':>9} {'jumps est':>10} {'(chatter)':>9} {'RMS med':>8} {'RMS max':>8}")
    for row in rows:
        c = row["check"]
        print(f"{row['scene']:<20} {row['shape']:<6} {row['speed']:6.3f} {row['seconds']:6.0f} "
              f"{100 * c.all_sheets_within_10pct:8.1f}% {100 * c.vertical_within_10pct:12.1f}% "
              f"{100 * c.support_within_10pct:10.1f}% {100 * c.true_jump_frames:10.2f}% "
              f"{100 * c.true_reversal_frames:8.2f}% {100 * c.fast_frames:7.1f}% {100 * c.true_jump_frames_slow:14.2f}% "
              f"{100 * c.true_reversal_frames_slow:8.2f}% {100 * c.estimated_jump_frames:9.2f}% "
              f"{100 * c.estimated_reversal_frames:8.2f}% {c.median_rms_n:8.3f} {c.worst_rms_n:8.3f}")
    print("    falling: frames in which some body point moves faster than 0.2 m/s (a fall off a crest, a tip onto the "
          "side, a landing); jumps creeping: > 1 N jumps in the other frames (a load moving fast, or chatter when "
          "they reverse)")


def run(quick: bool, sections: str = "abcdefg") -> None:
    if "a" in sections:
        print("(a) world alone: real-time factor (simulated s / wall s) against error with known ground truth")
        print(f"{'dt ms':>6} {'RTF flat':>9} {'RTF drape':>10} {'RTF play':>9} {'|Σbottom−mg|/mg':>16} "
              f"{'drape − wrap (rad)':>19}")
        for row in _world_rows(quick):
            print(f"{row['dt_ms']:6.1f} {row['rtf_flat']:9.1f} {row['rtf_drape']:10.1f} {row['rtf_play']:9.1f} "
                  f"{row['weight_err_pct']:15.3f}% {row['drape_err_rad']:19.3f}")
    if "b" in sections:
        print("\n(b) headless lab (world + virtual chain + virtual board through their wire protocols), 2 ms step: "
              f"{_headless_rtf(quick):.1f}× real time")
    if "c" in sections:
        print("\n(c) the app's physics lab at real time (speed 1), 2 ms step; target: RTF ≥ 1.0 with the plots running")
        print("    stepping = wall time inside PhysicsWorld.step per wall second; headroom = 1 / stepping (how much faster "
              "than real time the world could run here, at this load)")
        print(f"{'scenario':<36} {'world RTF':>9} {'skipped s':>10} {'stepping':>9} {'headroom':>9} {'process CPU':>12} "
              f"{'plot fps':>9}")
        for row in _app_rows(quick):
            headroom = 1.0 / row["busy"] if row["busy"] > 0 else float("inf")
            print(f"{row['scenario']:<36} {row['rtf']:9.2f} {row['lagged_s']:10.2f} {100 * row['busy']:8.1f}% "
                  f"{headroom:8.1f}× {row['cpu_pct']:11.0f}% {row['fps']:9.1f}")
        print("(machine load changes every wall-clock figure; the lab's 2 cores are shared)")
    if "d" in sections:
        print("\n(d) how true the forces are: recordings of `sensnake experiment run`, checked by app.core.physics_check")
        print("    targets: sum within ±10 % of the weight in ≥ 95 % of frames; < 1 % of 30 Hz frames with a > 1 N jump; "
              "median per-sheet RMS ≤ 0.3 N")
        print(f"{'scene':<15} {'rad/s':>6} {'sim s':>6} {'RTF':>5} {'Σbottom±10%':>12} {'vertical±10%':>13} "
              f"{'bottom↑±10%':>12} {'robot↑±10%':>11} {'jumps true':>11} {'(chatter)':>9} {'jumps est':>10} {'(chatter)':>9} {'RMS med':>8} {'RMS max':>8} "
              f"{'p99 med':>8} {'p99 max':>8}")
        for row in _truth_rows(quick):
            c = row["check"]
            print(f"{row['scene']:<15} {row['speed']:6.3f} {row['seconds']:6.0f} {row['rtf']:5.1f} "
                  f"{100 * c.bottom_within_10pct:11.1f}% {100 * c.vertical_within_10pct:12.1f}% "
                  f"{100 * c.bottom_support_within_10pct:11.1f}% {100 * c.support_within_10pct:10.1f}% "
                  f"{100 * c.true_jump_frames:10.2f}% {100 * c.true_reversal_frames:8.2f}% "
                  f"{100 * c.estimated_jump_frames:9.2f}% {100 * c.estimated_reversal_frames:8.2f}% "
                  f"{c.median_rms_n:8.3f} {c.worst_rms_n:8.3f} {c.median_p99_n:8.3f} {c.worst_p99_n:8.3f}")
        print("    Σbottom, vertical: the sheets' readings (pressure) summed, and their vertical part; bottom↑, robot↑: "
              "the upward part of the whole true contact forces (normal and friction) on the bottom sheets and on the "
              "whole robot (Newton: the weight when nothing accelerates). On a curve the normals sum to more than the "
              "weight; on a slope friction holds up what no sheet reads")
    if "e" in sections:
        print("\n(e) the paper's experiment (`sensnake experiment obstacle --seconds S`): estimated forces, median over the "
              "run")
        print(f"{'S':>4} {'Σ bottom N':>11} {'vertical N':>11} {'weight N':>9} {'vertical − weight':>18} "
              f"{'true bottom↑ N':>15} {'− weight':>9}")
        for row in _paper_rows(quick):
            print(f"{row['seconds']:4.0f} {row['bottom']:11.2f} {row['vertical']:11.2f} {row['weight']:9.2f} "
                  f"{100 * (row['vertical'] / row['weight'] - 1):17.1f}% {row['support']:15.2f} "
                  f"{100 * (row['support'] / row['weight'] - 1):8.1f}%")
        print("    (Σ bottom, vertical: the estimated forces, as the app shows them; true bottom↑: the upward part of the "
              "bottom sheets' whole true contact forces, normal and friction)")
    if "f" in sections:
        print("\n(f) the other built-in scenes (step, wedge, two obstacles), the bent shape and the settled drape: "
              "forces continuous and carrying the weight?")
        print("    Σ all sheets: every sheet summed (a body rolled onto its side carries its weight on its side sheets); "
              "what no sheet feels: a segment's rounded end on an edge, friction")
        _print_scene_rows(_truth_rows(quick, ("step", "wedge", "two_obstacles"), both_shapes=True))
    if "g" in sections:
        print("\n(g) scenes no built-in has (benchmarks/scenes/terrain/), the settled drape: continuous and carrying the "
              "weight?")
        scenes = tuple(sorted(os.path.join(TERRAIN_DIR, name) for name in os.listdir(TERRAIN_DIR)
                              if name.endswith(".toml")))
        rows = _truth_rows(quick, scenes)
        for row in rows:
            row["scene"] = os.path.basename(row["scene"]).removesuffix(".toml")
        _print_scene_rows(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--sections", default="abcdefg", help="which sections to run, e.g. 'df' (default: all)")
    args = parser.parse_args()
    run(args.quick, args.sections)


if __name__ == "__main__":
    main()
