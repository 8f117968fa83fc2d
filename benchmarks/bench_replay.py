"""3-D replay of a long recording: how long it takes to open, and how fast it scrubs.

Writes a one-hour physics-lab recording as the lab writes one (``/daq`` counts and conductances and ``/forces`` for 36
channels at 30 Hz, ``/robot`` at 50 Hz, ``/sim`` with points, segment rotations and sheet forces at 30 Hz: about
110 000 body frames), then measures on Qt's offscreen platform

- **open**: the 3-D tab's Open recording (``SceneTab.open_replay``: read what the replay needs, draw the first
  frame), target < 3 s;
- **scrub**: the slider dragged to random times, each move drawn and painted (``ReplayView`` repainted), as frames
  per second, target ≥ 20.

Run: ``python -m benchmarks.bench_replay [--quick]`` (``--quick``: a ten-minute recording).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from models.kinematics import forward_kinematics

N_SEG = 12
AXES = tuple("pitch" if k % 2 == 0 else "yaw" for k in range(N_SEG))
OPEN_TARGET_S = 3.0
SCRUB_TARGET_FPS = 20.0
SCRUB_MOVES = 120


def write_long_recording(path: Path, seconds: float, seed: int = 0) -> None:
    """A recording of ``seconds`` with /daq, /forces, /robot and /sim at the lab's rates (chunked as the writer
    chunks; the body poses are a few hundred distinct ones repeated, which costs the reader the same)."""
    rng = np.random.default_rng(seed)
    t_daq = np.arange(0.0, seconds, 1 / 30)
    t_robot = np.arange(0.0, seconds, 1 / 50)
    n, c = t_daq.size, 3 * N_SEG
    poses = [forward_kinematics(0.3 * np.sin(k / 20 + np.arange(N_SEG)), AXES) for k in range(400)]
    which = np.arange(n) % len(poses)
    points = np.stack([p.points_m for p in poses])[which]
    points[:, :, 0] += t_daq[:, None] * 0.002
    frames = np.stack([p.frames for p in poses])[which]
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["version"] = 1
        f.attrs["config"] = ""
        daq = f.create_group("daq")
        daq.attrs["channels"] = [f"S{s + 1:02d}{side}" for s in range(N_SEG) for side in "LRB"]
        daq.create_dataset("time_s", data=t_daq, chunks=(2048,))
        daq.create_dataset("seq", data=np.arange(n, dtype=np.uint32), chunks=(4096,))
        daq.create_dataset("counts", data=rng.integers(1, 4096, (n, c), dtype=np.uint16), chunks=(227, c))
        daq.create_dataset("conductance_S", data=rng.uniform(0, 1e-5, (n, c)), chunks=(56, c))
        f.create_group("forces").create_dataset("force_N", data=rng.uniform(0, 5, (n, c)), chunks=(56, c))
        robot = f.create_group("robot")
        robot.create_dataset("time_s", data=t_robot, chunks=(2048,))
        goal = 0.3 * np.sin(t_robot[:, None] + np.arange(N_SEG))
        for name in ("goal_rad", "present_rad", "current_mA"):
            robot.create_dataset(name, data=goal, chunks=(170, N_SEG))
        sim = f.create_group("sim")
        sim.create_dataset("time_s", data=t_daq)
        sim.create_dataset("points_m", data=points)
        sim.create_dataset("segment_rotation", data=frames)
        sim.create_dataset("sheet_true_N", data=rng.uniform(0, 5, (n, c)))
        sim.attrs["segment_length_m"] = 0.08


def run(quick: bool) -> None:
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    from app.gui.lab import LabContext
    from app.gui.tabs.scene import SceneTab
    from devices.config import LabConfig, RobotConfig

    app = QApplication.instance() or QApplication([])
    seconds = 600.0 if quick else 3600.0
    with tempfile.TemporaryDirectory(prefix="bench-replay-") as folder:
        path = Path(folder) / "long.h5"
        started = time.perf_counter()
        write_long_recording(path, seconds)
        written_s = time.perf_counter() - started
        size_mb = path.stat().st_size / 1e6
        lab = LabContext(LabConfig(robot=RobotConfig(port="/dev/sensnake-bench-no-port")))
        tab = SceneTab(lab)
        tab.resize(1280, 760)
        tab.show()
        app.processEvents()
        try:
            started = time.perf_counter()
            assert tab.open_replay(path), tab.scene_label.text()
            tab.replay_view.repaint()
            open_s = time.perf_counter() - started
            replay = tab.replay
            assert replay is not None
            rng = np.random.default_rng(1)
            moves = rng.uniform(replay.start_s, replay.end_s, SCRUB_MOVES)
            slider = tab.replay_view.slider
            started = time.perf_counter()
            for t_s in moves:
                slider.setValue(int(round((t_s - replay.start_s) * 1000)))  # as a drag delivers it
                tab.replay_view.repaint()
                app.processEvents()
            scrub_fps = SCRUB_MOVES / (time.perf_counter() - started)
        finally:
            tab.shutdown()
            tab.close()
            lab.close()
    frames = replay.primary.n_frames
    print(f"recording: {seconds / 60:.0f} min, {frames} body frames, {size_mb:.0f} MB (written in {written_s:.1f} s)")
    print(f"open for replay: {open_s:.2f} s (target < {OPEN_TARGET_S:g} s) "
          f"{'OK' if open_s < OPEN_TARGET_S else 'SLOW'}")
    print(f"scrub: {scrub_fps:.0f} frames/s over {SCRUB_MOVES} random moves (target >= {SCRUB_TARGET_FPS:g}) "
          f"{'OK' if scrub_fps >= SCRUB_TARGET_FPS else 'SLOW'}")


if __name__ == "__main__":
    run("--quick" in sys.argv[1:])
