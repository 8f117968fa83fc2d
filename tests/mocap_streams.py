"""A Lab Streaming Layer motion-capture stream for tests: the straight body sliding along x, every sample stamped
when it was generated (its capture), sent in chunks as a mocap system's network sends them, with one gap. Traffic
stays on this machine (tests/conftest.py sets LSLAPICFG for the whole run)."""

from __future__ import annotations

import threading

import numpy as np

from devices.config import MocapConfig
from models.kinematics import forward_kinematics
from models.mocap import markers_from_poses

SPEED_M_S = 0.2  # the body slides forward: a sample stamped at its arrival would be off by up to 5 mm here
CHUNK_S = 0.025  # the stream's samples arrive in chunks this far apart
GAP = (0.6, 0.7)  # seconds into the stream without samples: a dropout
HEIGHT_M = 0.036


class MocapSender:
    """A ``rate_hz`` MoCap stream named ``name`` (markers ``SEG01_1_X``… in mm) of the straight body sliding along
    x at ``speed_m_s``; ``gap`` (s after its start) sends nothing. A context manager: the sender thread runs
    inside it."""

    def __init__(self, name: str, rate_hz: float = 960.0, speed_m_s: float = SPEED_M_S,
                 gap: tuple[float, float] | None = GAP) -> None:
        import pylsl

        mocap = MocapConfig()
        self.rate_hz = rate_hz
        self.speed_m_s = speed_m_s
        self.gap = gap
        info = pylsl.StreamInfo(name, "MoCap", 48 * 3, rate_hz, "float32", f"{name}-test")
        channels = info.desc().append_child("channels")
        for s in range(1, 13):
            for k in range(1, 5):
                for axis in "XYZ":
                    channel = channels.append_child("channel")
                    channel.append_child_value("label", f"{mocap.label(s, k)}_{axis}")
                    channel.append_child_value("unit", "mm")
        self.outlet = pylsl.StreamOutlet(info)
        pose = forward_kinematics(np.zeros(12), ("pitch", "yaw") * 6)
        self.centers = pose.segment_midpoints_m
        self.frames = pose.frames
        self.layout = np.array([mocap.marker_layout_m] * 12)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="test-mocap-sender")
        self.start_lsl = 0.0
        self.sent = 0

    def centers_at(self, lsl_time: float) -> np.ndarray:
        """The true segment centres (12, 3) at an LSL time."""
        return self.centers + np.array([self.speed_m_s * (lsl_time - self.start_lsl), 0.0, HEIGHT_M])

    def markers_mm(self, lsl_time: float) -> np.ndarray:
        centers = self.centers_at(lsl_time)[None]
        return markers_from_poses(centers, self.frames[None], self.layout)[0].reshape(-1) * 1000.0

    def _run(self) -> None:
        import pylsl

        self.start_lsl = pylsl.local_clock()
        sent = self.start_lsl
        while not self.stop.is_set():
            self.stop.wait(CHUNK_S)
            now = pylsl.local_clock()
            stamps = np.arange(sent, now, 1 / self.rate_hz)
            if len(stamps):
                sent = stamps[-1] + 1 / self.rate_hz
            keep = np.ones(len(stamps), dtype=bool)
            if self.gap is not None:
                keep = ~((stamps - self.start_lsl >= self.gap[0]) & (stamps - self.start_lsl < self.gap[1]))
            for stamp in stamps[keep]:
                self.outlet.push_sample(self.markers_mm(float(stamp)).tolist(), float(stamp))
                self.sent += 1

    def __enter__(self) -> MocapSender:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()
