"""devices/sim/mocap_stream.py: the physics lab's simulated motion capture — frames on the 960 Hz grid of the lab's
clock, markers where the body puts them, lost where fewer than two cameras see them, published on LSL with the MoCap
convention's metadata and stamped at capture. LSL stays on this machine (tests/conftest.py)."""

from __future__ import annotations

import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from devices.config import SIM_MOCAP_STREAM, LabConfig, MocapConfig, mocap_stream_spec, parse_config
from devices.errors import ConfigError
from devices.scene import Obstacle, Scene
from devices.sim import mocap_stream
from devices.sim.mocap_stream import SimulatedMocapStream, TerrainProfile, cameras_seeing
from models.kinematics import forward_kinematics
from models.mocap import check_layout, markers_from_poses
from tests.waiting import wait_until

SPEED_M_S = 0.25


def sliding_body(t_s: float) -> SimpleNamespace:
    """The straight body lying on flat ground, sliding along x: what ``PhysicsBackend.body_state`` gives."""
    pose = forward_kinematics(np.zeros(12), ("pitch", "yaw") * 6)
    points = pose.points_m + np.array([SPEED_M_S * t_s, 0.0, 0.036])
    return SimpleNamespace(time_s=t_s, points_m=points, frames=pose.frames)


LAYOUT = check_layout(MocapConfig().marker_layout_m, 12)


def true_markers(t_s: float) -> np.ndarray:
    body = sliding_body(t_s)
    centres = 0.5 * (body.points_m[:-1] + body.points_m[1:])
    return markers_from_poses(centres[None], body.frames[None], LAYOUT)[0]


def test_config_mocap_true_is_the_simulated_labs_stream():
    assert parse_config("[lab]\nmocap = true\n").lab.mocap == "sim"
    assert parse_config("[lab]\nmocap = false\n").lab.mocap == ""
    assert mocap_stream_spec("sim") == f"lsl:{SIM_MOCAP_STREAM}"
    assert mocap_stream_spec("lsl:PhaseSpace") == "lsl:PhaseSpace"
    with pytest.raises(ConfigError, match="lab.mocap"):
        parse_config('[lab]\nmocap = "PhaseSpace"\n')


def test_frames_lie_on_the_960_hz_grid_where_the_body_is(monkeypatch):
    monkeypatch.setattr(mocap_stream, "NOISE_M", 0.0)
    monkeypatch.setattr(mocap_stream, "DROPOUT_FRACTION", 0.0)
    stream = SimulatedMocapStream(lambda: sliding_body(0.0), lambda t: t, MocapConfig(), 12, Scene().height_at)
    t0, t1 = 1.0003, 1.0121
    values, last = stream.chunk((t0, true_markers(t0)), (t1, true_markers(t1)), sliding_body(t1).frames[:, :, 2])
    frames = np.arange(np.floor(t0 * 960) + 1, np.floor(t1 * 960) + 1) / 960
    assert len(values) == len(frames) and last == pytest.approx(frames[-1])
    assert values.dtype == np.float32 and values.shape[1] == 144
    for row, t in zip(values, frames):
        np.testing.assert_allclose(row, true_markers(t).reshape(-1) * 1000.0, atol=0.01)  # mm


def test_noise_and_dropouts_are_what_the_module_says():
    stream = SimulatedMocapStream(lambda: sliding_body(0.0), lambda t: t, MocapConfig(), 12, Scene().height_at,
                                  seed=3)
    axis = sliding_body(0.0).frames[:, :, 2]
    rows, truths = [], []
    t = 0.0
    for _ in range(300):  # 3 s in 10 ms looks
        values, _ = stream.chunk((t, true_markers(t)), (t + 0.01, true_markers(t + 0.01)), axis)
        frames = np.arange(np.floor(t * 960) + 1, np.floor((t + 0.01) * 960) + 1) / 960
        rows.append(values)
        truths += [true_markers(f).reshape(-1) * 1000.0 for f in frames]
        t += 0.01
    values, truth = np.concatenate(rows), np.asarray(truths)
    unseen = np.isnan(values)
    assert 0.3 * mocap_stream.DROPOUT_FRACTION < unseen.mean() < 3 * mocap_stream.DROPOUT_FRACTION
    error_mm = (values - truth)[~unseen]
    assert np.std(error_mm) == pytest.approx(1000 * mocap_stream.NOISE_M, rel=0.1)


def test_a_marker_in_the_lee_of_a_wall_facing_away_is_lost_and_one_facing_down_too():
    """The cameras stand at both ends of the track: a marker low behind a tall box is hidden from one end; when its
    LED also faces away from the other end, fewer than two cameras see it."""
    wall = Scene(obstacles=(Obstacle("box", x_m=0.0, friction=0.3, length_m=0.1, height_m=0.6),))
    terrain = TerrainProfile(wall.height_at)
    behind = np.array([[0.08, 0.0, 0.05]])
    up = np.array([[0.0, 0.0, 1.0]])
    away = np.array([[np.sin(np.radians(80)), 0.0, np.cos(np.radians(80))]])  # tilted toward +x, away from −x
    down = np.array([[0.0, 0.0, -1.0]])
    open_ground = TerrainProfile(Scene().height_at)
    assert cameras_seeing(behind, up, open_ground)[0] == 8
    assert cameras_seeing(behind, up, terrain)[0] == 4  # the far end's cameras only
    assert cameras_seeing(behind, away, open_ground)[0] == 4
    assert cameras_seeing(behind, -away, terrain)[0] < mocap_stream.MIN_CAMERAS
    assert cameras_seeing(behind, down, open_ground)[0] == 0


@pytest.mark.slow
def test_the_physics_labs_stream_is_found_by_name_and_stamped_at_the_worlds_time():
    """``[lab] mocap = true`` on the physics lab: the stream is published under its name, with the MoCap metadata
    the app reads, 960 samples a second stamped at the world's time, the segments where the world has them."""
    pytest.importorskip("mujoco")
    import pylsl

    from app.core.lsl_link import MocapInlet
    from devices.sim.lab import SimLab

    config = LabConfig()
    config = replace(config, lab=replace(config.lab, physics="mujoco", mocap="sim", scene="flat"))
    lab = SimLab(config, seed=2)
    lab.start_background()
    try:
        assert lab.mocap_stream is not None and lab.mocap_stream.running
        inlet = MocapInlet(f"lsl:{SIM_MOCAP_STREAM}", mocap=config.mocap, live_rate_hz=20.0)
        inlet.start()
        try:
            assert inlet.rate_hz == 960.0 and inlet.unit == "mm" and len(inlet.channels) == 144
            assert wait_until(lambda: inlet.received >= 1500, 60.0), f"{inlet.received} samples arrived"
            # The body, placed just above the ground, settles first: compared once it rests, from poses fitted
            # after that (a pose fitted while it still moved, beside the state read a moment later, differed by
            # 2.7 mm on a loaded machine).
            assert wait_until(lambda: lab.physics.world.resting, 30.0), "the limp body never came to rest"
            settled = inlet.received
            assert wait_until(lambda: inlet.received >= settled + 480, 30.0), "no samples after the body rested"
            host, values = inlet.samples()
            snapshot = inlet.live.snapshot() if inlet.live is not None else None
            truth = lab.physics.body_state()
        finally:
            inlet.close()
    finally:
        lab.close()
    assert len(host) >= 1500
    steps = np.diff(host)
    assert np.median(steps) == pytest.approx(1 / 960, rel=0.01) and steps.max() < 2.5 / 960
    lsl_lag = pylsl.local_clock() - (host[-1] + (pylsl.local_clock() - time.monotonic()))
    assert lsl_lag < 1.0
    assert snapshot is not None
    centres = 0.5 * (truth.points_m[:-1] + truth.points_m[1:])  # the robot lies still on flat ground
    # One frame's pose carries the markers' noise, and a segment fitted from three markers (the fourth dropped out)
    # can be off by a few millimetres across the body (markers 1–3 span 12 mm sideways: 0.3 mm noise tilts it by
    # ~0.03 rad, 60 mm below them): the median of the last half second's live poses, all taken at rest, is compared.
    rested = snapshot.center_m[-10:]
    assert np.isfinite(rested).all(axis=-1).sum(axis=0).min() >= 5, "a segment had no pose in most recent frames"
    np.testing.assert_allclose(np.nanmedian(rested, axis=0), centres, atol=0.002)
    assert np.isfinite(snapshot.newest_center_m).any()
