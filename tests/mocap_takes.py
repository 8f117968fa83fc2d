"""A motion-capture take generated fast (not in real time) for tests and benchmarks that feed a
:class:`app.core.lsl_link.MocapInlet` directly, without Lab Streaming Layer: the body swaying as it slides along x,
markers in mm (float32) as an LSL MoCap stream's channels carry them, segment 5 half hidden (2 markers seen: no
pose) for a while, a gap of 0.1 s (a dropout) and noise, all from one seed."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from devices.config import MocapConfig
from devices.sim.mocap_stream import channel_labels

N_SEGMENTS = 12
SPACING_M = 0.085
SPEED_M_S = 0.2
MAX_BACKLOG = 40  # chunks queued for the recording's writer (~1 s at 960 Hz) before the feed waits for it


class _Node:
    """What :meth:`MocapInlet._describe` reads of a pylsl XML element."""

    def __init__(self, values: dict[str, str] | None = None, children: list[_Node] | None = None,
                 siblings: list[_Node] | None = None, index: int = 0) -> None:
        self.values, self.children = values or {}, children or []
        self.siblings, self.index = siblings, index

    def child(self, name: str) -> _Node:
        if name == "channels":
            return _Node(children=self.children)
        return self.children[0] if self.children else _Node(siblings=None, index=-1)

    def child_value(self, key: str) -> str:
        return self.values.get(key, "")

    def next_sibling(self) -> _Node:
        siblings = self.siblings or []
        return siblings[self.index + 1] if self.index + 1 < len(siblings) else _Node(index=-1)

    def empty(self) -> bool:
        return self.index < 0


class FakeInfo:
    """A MoCap stream's pylsl ``StreamInfo`` as the inlet reads it: ``SEG01_1_X`` … in mm."""

    def __init__(self, name: str = "GeneratedMocap", rate_hz: float = 960.0,
                 mocap: MocapConfig | None = None) -> None:
        self._name, self._rate = name, rate_hz
        labels = channel_labels(mocap or MocapConfig(), N_SEGMENTS)
        nodes: list[_Node] = []
        for marker, axis in labels:
            nodes.append(_Node({"label": f"{marker}_{axis}", "marker": marker, "type": f"Position{axis}",
                                "unit": "mm"}, siblings=nodes, index=len(nodes)))
        self._desc = _Node(children=nodes)
        self._count = len(labels)

    def name(self) -> str:
        return self._name

    def nominal_srate(self) -> float:
        return self._rate

    def channel_count(self) -> int:
        return self._count

    def desc(self) -> _Node:
        return self._desc


def generated_chunks(seconds: float, t0_s: float, rate_hz: float = 960.0, chunk: int = 24, seed: int = 0,
                     mocap: MocapConfig | None = None, gap_s: tuple[float, float] = (0.3, 0.4),
                     hidden_s: tuple[float, float] = (0.2, 0.5)) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(capture times (n,) on ``time.monotonic()`` from ``t0_s``, channel values (n, C) float32 in mm) chunk by
    chunk: ``seconds`` of a ``rate_hz`` take, as fast as numpy makes it."""
    layout = np.asarray((mocap or MocapConfig()).marker_layout_m, dtype=float)  # (K, 3)
    rng = np.random.default_rng(seed)
    total = int(round(seconds * rate_hz))
    segments = np.arange(N_SEGMENTS)
    for first in range(0, total, chunk):
        i = np.arange(first, min(total, first + chunk))
        t = i / rate_hz
        keep = ~((t >= gap_s[0]) & (t < gap_s[1]))
        i, t = i[keep], t[keep]
        if not len(t):
            continue
        yaw = 0.15 * np.sin(2 * np.pi * 0.5 * t[:, None] + segments[None, :])  # (n, S)
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.zeros((len(t), N_SEGMENTS, 3, 3))
        rot[..., 0, 0], rot[..., 0, 1], rot[..., 1, 0], rot[..., 1, 1], rot[..., 2, 2] = c, -s, s, c, 1.0
        center = np.stack([SPEED_M_S * t[:, None] - SPACING_M * segments[None, :],
                           0.01 * np.sin(2 * np.pi * 0.5 * t[:, None] + segments[None, :]),
                           np.full((len(t), N_SEGMENTS), 0.036)], axis=-1)  # (n, S, 3)
        markers = center[:, :, None, :] + np.einsum("nsij,kj->nski", rot, layout)
        markers += rng.normal(0.0, 0.0002, markers.shape)
        hidden = (t >= hidden_s[0]) & (t < hidden_s[1])
        markers[hidden, 4, :2] = 0.0  # two of segment 5's markers lost (sent as 0, 0, 0): fewer than 3 seen
        yield t0_s + t, (markers * 1000.0).reshape(len(t), -1).astype(np.float32)


def record_generated_take(path: str | Path, seconds: float, seed: int = 0, lead_s: float = 0.05,
                          before_stop: Callable[[], None] | None = None) -> str:
    """A recording at ``path`` whose motion capture is a generated ``seconds`` take fed straight into an inlet
    (no Lab Streaming Layer), as ``sensnake record --mocap`` records one: a few board frames, the take (starting
    ``lead_s`` before the recording: those samples are not its), ``/mocap`` written. The summary line.
    ``before_stop``: called once the take is fed, the recording still running."""
    from app.core.lsl_link import LslLinks, MocapInlet
    from app.core.recorder import Recorder
    from devices.board import SampleBlock
    from devices.config import LabConfig

    config = LabConfig()
    t0 = time.monotonic()
    recorder = Recorder(path, config.source_text, config.board.channel_names, t0_monotonic_s=t0)
    recorder.start()
    links = LslLinks(None, config.mocap, config.robot.axes)
    inlet = MocapInlet("lsl:GeneratedMocap", on_dropout=links._dropout, mocap=config.mocap,
                       n_segments=len(config.robot.axes), collect=False)
    inlet._describe(FakeInfo(mocap=config.mocap))
    links.adopt(inlet)
    links.start(recorder)
    n, c = 16, len(config.board.channel_names)
    recorder.add_block(SampleBlock(counts=np.zeros((n, c), np.uint16), conductance_s=np.full((n, c), 1e-6),
                                   board_time_s=np.arange(n) * 0.01, host_time_s=t0 + np.arange(n) * 0.01,
                                   seq=np.arange(n, dtype=np.uint32), saturated=np.zeros((n, c), bool)))
    for host, values in generated_chunks(seconds, t0 - lead_s, seed=seed, mocap=config.mocap):
        inlet.take_in(host, values)
        while recorder.backlog > MAX_BACKLOG and recorder.is_active:  # as fast as the writer keeps up
            # Deliberate: back-pressure on a generator, not a wait for an event (the writer offers no signal here).
            time.sleep(0.001)
    if before_stop is not None:
        before_stop()
    take = links.stop(recorder, close_inlet=True)
    recorder.stop()
    links.close()
    assert take is not None and recorder.kept
    result = take.write(path, t0, config.mocap, config.robot.axes)
    return take.summary(result, Path(path).name)
