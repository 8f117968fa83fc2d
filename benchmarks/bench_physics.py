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
Target (issue 13): the simulation at least at real time on 2 cores while the GUI plots.

Wall-clock figures depend on the machine's load (the lab's 2 cores are shared): compare rows of one run.
``run(quick)``; ``python -m benchmarks.bench_physics [--quick]``.
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
            stepping0 = world.stepping_s
            redraws0 = tab.plots.redraw_count if tab is not None else 0
            QTimer.singleShot(int(run_s * 1000), loop.quit)
            loop.exec()
            wall = time.monotonic() - wall0
            simulated = (world.steps - steps0) * world.scene.timestep_s
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


def run(quick: bool) -> None:
    print("(a) world alone: real-time factor (simulated s / wall s) against error with known ground truth")
    print(f"{'dt ms':>6} {'RTF flat':>9} {'RTF drape':>10} {'RTF play':>9} {'|Σbottom−mg|/mg':>16} "
          f"{'drape − wrap (rad)':>19}")
    for row in _world_rows(quick):
        print(f"{row['dt_ms']:6.1f} {row['rtf_flat']:9.1f} {row['rtf_drape']:10.1f} {row['rtf_play']:9.1f} "
              f"{row['weight_err_pct']:15.3f}% {row['drape_err_rad']:19.3f}")
    print("\n(b) headless lab (world + virtual chain + virtual board through their wire protocols), 2 ms step: "
          f"{_headless_rtf(quick):.1f}× real time")
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    run(parser.parse_args().quick)


if __name__ == "__main__":
    main()
