"""Synthetic trial recordings (SPEC §3.5 with /robot, /forces, /sim and run documents), written with h5py.

One underlying run: the goals rest until ``ONSET_S`` and then ramp; each bottom sensor k feels a bump of
``PEAK_N`` centred ``k`` s after the onset; the body's segments move forward at 2 cm/s from the onset. A trial is
that run sampled on its own clock, shifted by ``shift_s`` (the event happens ``shift_s`` later on that clock) and
with noise added: nothing is merely relabelled, every sample is taken again.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.run_documents import condition, run_start_document, run_stop_document
from devices.config import default_sensor_names

CHANNELS = default_sensor_names()
ONSET_S = 2.0
PEAK_N = 5.0
BUMP_SD_S = 0.5
SPEED_M_S = 0.02


def underlying_forces(t: np.ndarray) -> np.ndarray:
    """(N, 36) forces of the underlying run at its own times ``t`` (onset at ONSET_S)."""
    forces = np.zeros((len(t), len(CHANNELS)))
    for k in range(12):
        centre = ONSET_S + 1.0 + 0.5 * k
        forces[:, 3 * k + 2] = PEAK_N * np.exp(-0.5 * ((t - centre) / BUMP_SD_S) ** 2)
    return forces


def write_trial(path: Path, shift_s: float = 0.0, noise_n: float = 0.05, seed: int = 0, duration_s: float = 12.0,
                scene: str = "paper_obstacle", speed_rad_s: float = 0.034, with_documents: bool = True,
                outcome: str = "traversed", trial: int | None = None, series_uid: str | None = None,
                extra_attrs: dict[str, Any] | None = None) -> Path:
    rng = np.random.default_rng(seed)
    daq_t = np.arange(0.0, duration_s, 1 / 30.0) + rng.uniform(0, 1 / 30.0)  # the board's own phase
    robot_t = np.arange(0.0, duration_s, 1 / 50.0) + rng.uniform(0, 1 / 50.0)
    sim_t = np.arange(0.0, duration_s, 1 / 50.0)
    forces = underlying_forces(daq_t - shift_s) + rng.normal(0, noise_n, (len(daq_t), len(CHANNELS)))
    ramp = np.clip(robot_t - shift_s - ONSET_S, 0, None) * speed_rad_s
    goal = np.zeros((len(robot_t), 12))
    goal[:, 0] = ramp
    goal[:, 2] = -0.5 * ramp
    moved = np.clip(sim_t - shift_s - ONSET_S, 0, None) * SPEED_M_S
    points = np.zeros((len(sim_t), 13, 3))
    points[:, :, 0] = -0.3 - 0.08 * np.arange(13)[None, :] + moved[:, None] + rng.normal(0, 0.001, (len(sim_t), 13))
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["version"] = 1
        f.attrs["started"] = "2026-12-01T10:00:00.000+00:00"
        f.attrs["config"] = "[board]\n"
        f.attrs["duration_s"] = duration_s
        if with_documents:
            start = run_start_document("experiment run", condition(
                scene=scene, scene_text=f"# {scene}", shape="settled", mode="follow", speed_rad_s=speed_rad_s,
                controller="feedforward", tail_load_n=0.0, config_text="[board]\n"), seed=seed, trial=trial,
                series_uid=series_uid)
            f.attrs["run_start"] = json.dumps(start)
            f.attrs["run_stop"] = json.dumps(run_stop_document(start, "success", "", outcome))
        daq = f.create_group("daq")
        daq.attrs["channels"] = np.array(CHANNELS, dtype=h5py.string_dtype())
        for key in ("crc_errors", "dropped_frames", "resyncs"):
            daq.attrs[key] = 0
        daq["time_s"] = daq_t
        daq["seq"] = np.arange(len(daq_t), dtype=np.uint32)
        daq["counts"] = np.zeros((len(daq_t), len(CHANNELS)), np.uint16)
        daq["conductance_S"] = np.zeros((len(daq_t), len(CHANNELS)))
        f.create_group("forces")["force_N"] = forces
        f["forces"].attrs["calibration"] = "{}"
        robot = f.create_group("robot")
        robot["time_s"] = robot_t
        robot["goal_rad"] = goal
        robot["present_rad"] = goal
        robot["current_mA"] = np.zeros_like(goal)
        sim = f.create_group("sim")
        sim["time_s"] = sim_t
        sim["points_m"] = points
        sim.attrs["valid"] = 1
        sim.attrs["scene_name"] = scene
        sim.attrs["outcome"] = outcome
        for key, value in (extra_attrs or {}).items():
            f.attrs[key] = value
    return path
