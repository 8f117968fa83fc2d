"""The physics lab's motion capture: a PhaseSpace-like Lab Streaming Layer stream of the simulated body's markers.

``[lab] mocap = true`` makes the physics lab publish it (:meth:`devices.sim.lab.SimLab.start_mocap_stream`; in the
app the lab's own process does): the stream named :data:`devices.config.SIM_MOCAP_STREAM`, type ``MoCap``, 960 Hz,
one channel per marker coordinate in millimetres with the LSL MoCap convention's metadata (``label``
``SEG01_1_X``…, ``marker`` ``SEG01_1``, ``type`` PositionX/Y/Z, ``unit`` mm). ``sensnake record --mocap`` and the
app follow it exactly as they follow a real system's stream: nothing on the receiving side knows it is simulated.

What it sends (docs/MOCAP.md, "The physics lab's motion capture"): every ``[mocap] marker_layout_m`` marker on
every segment, where the world puts it, at frames k / 960 s of the lab's clock. The world is looked at every
:data:`CHUNK_S` (its pose then, read under its lock); the frames between two looks lie on the straight line between
the markers' two positions (a 0.3 rad/s joint turns 3 mrad in 10 ms: the line is off the arc by well under a
micrometre). Each sample is stamped with its frame's instant on the LSL clock — the capture time — not the time it
is sent. Seen markers carry Gaussian noise (:data:`NOISE_M` a coordinate); each marker drops out now and then for
a burst (about :data:`DROPOUT_FRACTION` of its frames, :data:`DROPOUT_BURST_S` long on average), and it is unseen
while fewer than two of the eight cameras (:data:`CAMERAS_M`) see it: a camera sees a marker when the marker's LED,
pointing along its segment's z, faces it within :data:`LED_HALF_ANGLE_DEG` and the line between them clears the
terrain (the scene's obstacles span the whole width). An unseen marker is NaN.

Threads: one sender thread (:meth:`SimulatedMocapStream.start`, ended by :meth:`close`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from devices.config import SIM_MOCAP_STREAM, MocapConfig
from models.mocap import check_layout, markers_from_poses

log = logging.getLogger(__name__)

RATE_HZ = 960.0
CHUNK_S = 0.01  # the world is looked at, and a chunk of frames sent, this often
NOISE_M = 0.0003
DROPOUT_FRACTION = 0.01
DROPOUT_BURST_S = 0.02
LED_HALF_ANGLE_DEG = 75.0
MIN_CAMERAS = 2  # a marker is triangulated from two cameras or more
# Eight cameras on the lab's walls, four at each end of the track, 2 m up, looking at the obstacle (x = 0): the
# terrain can hide a marker from one end, and a marker whose LED faces away from the other end is then lost.
CAMERAS_M = np.array([[x, y, 2.0] for x in (-2.5, 2.5) for y in (-1.2, -0.4, 0.4, 1.2)])
RAY_SAMPLES = 24
VISIBILITY_EVERY_S = 0.05  # which cameras see which marker is worked out this often (half a chunk's cost)
TERRAIN_STEP_M = 0.005


def channel_labels(mocap: MocapConfig, n_segments: int) -> list[tuple[str, str]]:
    """(marker label, axis) of every channel: segment 1's markers 1…K, X, Y, Z each, then segment 2's, …"""
    return [(mocap.label(s + 1, k + 1), axis) for s in range(n_segments)
            for k in range(len(mocap.marker_layout_m)) for axis in "XYZ"]


class TerrainProfile:
    """The terrain's height along x on a fine grid (the scene's obstacles span the whole width), for line-of-sight
    tests in bulk."""

    def __init__(self, height_at: Callable[[float], float], x_from_m: float = -4.0, x_to_m: float = 4.0) -> None:
        self.x_m = np.arange(x_from_m, x_to_m + TERRAIN_STEP_M, TERRAIN_STEP_M)
        self.height_m = np.array([height_at(float(x)) for x in self.x_m])

    def heights(self, x_m: np.ndarray) -> np.ndarray:
        return np.interp(x_m, self.x_m, self.height_m, left=0.0, right=0.0)


def cameras_seeing(markers_m: np.ndarray, led_axis: np.ndarray, terrain: TerrainProfile,
                   cameras_m: np.ndarray = CAMERAS_M, half_angle_deg: float = LED_HALF_ANGLE_DEG) -> np.ndarray:
    """How many cameras see each marker: ``markers_m`` (..., 3), each marker's LED direction ``led_axis`` (..., 3)
    (unit); a camera sees a marker when the LED faces it within ``half_angle_deg`` and the straight line between
    them stays above the terrain."""
    to_camera = cameras_m - markers_m[..., None, :]  # (..., C, 3)
    distance = np.linalg.norm(to_camera, axis=-1)
    facing = np.einsum("...ci,...i->...c", to_camera, led_axis) > math.cos(math.radians(half_angle_deg)) * distance
    fractions = np.arange(1, RAY_SAMPLES + 1) / (RAY_SAMPLES + 1)  # along the line of sight, the marker left out
    x = markers_m[..., None, :1] + to_camera[..., :1] * fractions  # (..., C, R)
    z = markers_m[..., None, 2:3] + to_camera[..., 2:3] * fractions
    clear = np.all(z > terrain.heights(x), axis=-1)
    return np.count_nonzero(facing & clear, axis=-1)


class SimulatedMocapStream:
    """The stream; see the module docstring. ``body_state()`` gives the world's pose (an object with ``time_s``,
    the world's clock, ``points_m`` (n+1, 3) and ``frames`` (n, 3, 3)); ``wall_of_world(t)`` turns the world's time
    into ``time.monotonic()``."""

    def __init__(self, body_state: Callable[[], Any], wall_of_world: Callable[[float], float], mocap: MocapConfig,
                 n_segments: int, height_at: Callable[[float], float], *, name: str = SIM_MOCAP_STREAM,
                 rate_hz: float = RATE_HZ, seed: int = 0, realtime: bool = False) -> None:
        self.body_state = body_state
        self.wall_of_world = wall_of_world
        self.layout = check_layout(mocap.marker_layout_m, n_segments)
        self.n_segments = n_segments
        self.terrain = TerrainProfile(height_at)
        self.name = name
        self.rate_hz = float(rate_hz)
        self.labels = channel_labels(mocap, n_segments)
        self.frames_sent = 0
        # In the lab's own process the sender asks for the servos' real-time priority, as that process's other
        # threads that share the interpreter lock with its pty thread do: one preempted while it holds the lock
        # would make the servos answer late (the control loop then misses ticks).
        self.realtime = realtime
        self._rng = np.random.default_rng(seed)
        self._dropout_left = np.zeros(self.layout.shape[:2], dtype=int)  # frames each marker stays dropped
        self._hidden = np.zeros(self.layout.shape[:2], dtype=bool)  # seen by fewer than MIN_CAMERAS cameras
        self._hidden_at = -np.inf  # the world's time it was worked out
        self._outlet: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _make_outlet(self) -> Any:
        import pylsl

        info = pylsl.StreamInfo(self.name, "MoCap", len(self.labels), self.rate_hz, "float32",
                                f"sensnake-sim-mocap-{self.name}")
        desc = info.desc()
        desc.append_child("acquisition").append_child_value("manufacturer", "SenSnake Studio (simulated, "
                                                                            "PhaseSpace-like)")
        channels = desc.append_child("channels")
        for marker, axis in self.labels:
            channel = channels.append_child("channel")
            channel.append_child_value("label", f"{marker}_{axis}")
            channel.append_child_value("marker", marker)
            channel.append_child_value("type", f"Position{axis}")
            channel.append_child_value("unit", "mm")
        return pylsl.StreamOutlet(info, chunk_size=0, max_buffered=60)

    def start(self) -> None:
        """Open the outlet and start sending (idempotent)."""
        if self._thread is not None:
            return
        self._outlet = self._make_outlet()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim-mocap-stream", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop sending and withdraw the stream (joins the thread)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._outlet = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    def _run(self) -> None:
        import pylsl

        if self.realtime:
            from devices.realtime import _raise_thread_priority

            log.debug("simulated motion capture: %s", _raise_thread_priority())
        lsl_minus_mono = pylsl.local_clock() - time.monotonic()
        previous: tuple[float, np.ndarray] | None = None
        while not self._stop.wait(CHUNK_S):
            try:
                state = self.body_state()
            except (RuntimeError, ValueError) as exc:  # the world is being rebuilt: nothing to film this time
                log.debug("simulated motion capture: no pose (%s)", exc)
                continue
            now = (float(state.time_s), self._markers(state))
            if previous is None or now[0] <= previous[0]:  # the first look, or the world's clock went back
                previous = now
                continue
            values, last_frame_s = self.chunk(previous, now, np.asarray(state.frames)[:, :, 2])
            previous = now
            if len(values):
                self._outlet.push_chunk(values, timestamp=self.wall_of_world(last_frame_s) + lsl_minus_mono)
                self.frames_sent += len(values)

    def _markers(self, state: Any) -> np.ndarray:
        points = np.asarray(state.points_m, dtype=float)
        centres = 0.5 * (points[:-1] + points[1:])
        return markers_from_poses(centres[None], np.asarray(state.frames, dtype=float)[None], self.layout)[0]

    def chunk(self, previous: tuple[float, np.ndarray], now: tuple[float, np.ndarray],
              led_axis: np.ndarray) -> tuple[np.ndarray, float]:
        """The frames whose instants lie in (previous time, now time] (world clock), as channel values (F, 3·S·K)
        float32 in mm, NaN where unseen, and the instant of the last frame (the world's clock)."""
        (t0, m0), (t1, m1) = previous, now
        first = math.floor(t0 * self.rate_hz) + 1
        last = math.floor(t1 * self.rate_hz)
        if last < first:
            return np.zeros((0, len(self.labels)), np.float32), t1
        frame_t = np.arange(first, last + 1) / self.rate_hz
        share = ((frame_t - t0) / (t1 - t0))[:, None, None, None]
        markers = m0[None] + share * (m1 - m0)[None]  # (F, S, K, 3)
        markers = markers + self._rng.normal(0.0, NOISE_M, markers.shape)
        if not abs(t1 - self._hidden_at) < VISIBILITY_EVERY_S:
            axis = np.broadcast_to(led_axis[:, None, :], m1.shape)
            self._hidden = cameras_seeing(m1, axis, self.terrain) < MIN_CAMERAS
            self._hidden_at = t1
        hidden = self._hidden
        burst = max(1, int(round(DROPOUT_BURST_S * self.rate_hz)))
        unseen = np.empty(markers.shape[:3], dtype=bool)
        for f in range(len(frame_t)):
            starts = (self._dropout_left == 0) & (self._rng.random(hidden.shape) < DROPOUT_FRACTION / burst)
            self._dropout_left[starts] = self._rng.integers(1, 2 * burst, int(starts.sum()))
            unseen[f] = hidden | (self._dropout_left > 0)
            self._dropout_left = np.maximum(self._dropout_left - 1, 0)
        markers[unseen] = np.nan
        return (markers.reshape(len(frame_t), -1) * 1000.0).astype(np.float32), float(frame_t[-1])
