"""Lab Streaming Layer, in and out, for a live recording (docs/MOCAP.md, "Live").

In: :class:`MocapInlet` follows one motion-capture stream (``lsl:NAME``: the stream of that name, else the first of
type MoCap) on its own thread. Its channels are named by their metadata (``label`` ending in X/Y/Z, or ``marker`` +
``type`` PositionX/Y/Z) in their ``unit``; every sample is stamped at capture on this machine's LSL clock
(``time_correction()``, refreshed every :data:`CORRECTION_EVERY_S`) and so on the recording's (the LSL clock and
``time.monotonic()`` are related by one reading of both at the start). A gap in the stream longer than 2.5 sample
periods is a dropout: counted, and an event (kind ``mocap``) in the recording. When the recording is closed,
:func:`append_live_mocap` fits the segments and writes ``/mocap`` into it, ``clock_offset_how`` saying the samples
were stamped at capture.

Out: :class:`LslPublisher` publishes ``SenSnake-forces`` (type ``Force``: each board sample's forces in N, or its
conductance in µS for a channel without a calibration; the channel's ``unit`` says which), ``SenSnake-joints``
(type ``Position``, rad, when a robot's states are given) and ``SenSnake-events`` (type ``Markers``, strings), each
sample stamped with its host time on the LSL clock.

Threads: the inlet's reader thread; everything else on the controlling thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.core.errors import MocapFileError
from app.core.mocap import UNITS_TO_M, MocapResult, Take, fit_take, place_markers, write_in_place
from devices.config import MocapConfig

CORRECTION_EVERY_S = 2.0
RESOLVE_TIMEOUT_S = 5.0
GAP_PERIODS = 2.5  # a gap longer than this many sample periods is a dropout


def lsl_name(spec: str) -> str:
    """``lsl:NAME`` → NAME; anything else is refused naming the form."""
    if not spec.startswith("lsl:") or not spec[4:].strip():
        raise ValueError(f"--mocap {spec!r}: give lsl:NAME (a Lab Streaming Layer stream's name; else the first "
                         "stream of type MoCap is taken)")
    return spec[4:].strip()


def lsl_minus_monotonic() -> float:
    """The LSL clock minus ``time.monotonic()`` (s), read back to back (the same clock on Linux: ~0)."""
    import pylsl

    before = time.monotonic()
    lsl = pylsl.local_clock()
    after = time.monotonic()
    return float(lsl - 0.5 * (before + after))


@dataclass(frozen=True)
class Dropout:
    host_time_s: float  # time.monotonic() of the first sample after the gap
    missing: int  # samples missing


class MocapInlet:
    """One LSL motion-capture stream followed on a reader thread; see the module docstring."""

    def __init__(self, spec: str, resolve_timeout_s: float | None = None,
                 on_dropout: Callable[[Dropout], None] | None = None) -> None:
        self.name = lsl_name(spec)
        self.resolve_timeout_s = RESOLVE_TIMEOUT_S if resolve_timeout_s is None else resolve_timeout_s
        self.on_dropout = on_dropout
        self.channels: list[tuple[str, str, str]] = []  # (marker, axis, unit) per channel
        self.rate_hz = 0.0
        self.stream_name = ""
        self.dropouts = 0
        self.missing = 0
        self._inlet: Any = None
        self._chunks: list[tuple[np.ndarray, np.ndarray]] = []  # (host monotonic (n,), values (n, C))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lsl_minus_mono = 0.0

    def start(self) -> None:
        """Resolve the stream (by name, else by type MoCap), read its channels and start following it. Raises
        ConnectionError naming what was looked for when no stream answers within ``resolve_timeout_s``."""
        import pylsl

        found = pylsl.resolve_byprop("name", self.name, 1, self.resolve_timeout_s)
        if not found:
            found = pylsl.resolve_byprop("type", "MoCap", 1, min(1.0, self.resolve_timeout_s))
        if not found:
            raise ConnectionError(f"--mocap lsl:{self.name}: no Lab Streaming Layer stream named {self.name!r} nor "
                                  f"of type MoCap answered within {self.resolve_timeout_s:g} s")
        self._inlet = pylsl.StreamInlet(found[0], max_buflen=60, recover=True)
        info = self._inlet.info(self.resolve_timeout_s)
        self.stream_name = info.name()
        self.rate_hz = float(info.nominal_srate())
        channel = info.desc().child("channels").child("channel")
        while not channel.empty():
            label, marker = channel.child_value("label"), channel.child_value("marker")
            kind, unit = channel.child_value("type"), channel.child_value("unit")
            if marker and kind.lower().startswith("position") and kind[-1:].upper() in "XYZ":
                self.channels.append((marker, kind[-1].upper(), unit))
            elif label[-1:].upper() in ("X", "Y", "Z") and len(label) > 1:
                self.channels.append((label[:-1].rstrip(" _.:/-"), label[-1].upper(), unit))
            else:
                self.channels.append(("", "", unit))
            channel = channel.next_sibling()
        if len(self.channels) != info.channel_count():
            raise MocapFileError(f"--mocap lsl:{self.name}: stream {self.stream_name!r} describes "
                                 f"{len(self.channels)} of its {info.channel_count()} channels: its channel labels "
                                 "are needed to know the markers")
        units = {u for m, _, u in self.channels if m}
        if len(units) != 1 or next(iter(units)).strip().lower() not in UNITS_TO_M:
            raise MocapFileError(f"--mocap lsl:{self.name}: stream {self.stream_name!r} gives units {sorted(units)}:"
                                 " one length unit (mm, cm or m) is needed")
        self._inlet.open_stream(self.resolve_timeout_s)
        self._lsl_minus_mono = lsl_minus_monotonic()
        self._thread = threading.Thread(target=self._run, name=f"lsl-mocap:{self.stream_name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        correction = self._inlet.time_correction(1.0)
        corrected_at = time.monotonic()
        last = np.nan
        period = 1.0 / self.rate_hz if self.rate_hz > 0 else np.nan
        while not self._stop.is_set():
            values, stamps = self._inlet.pull_chunk(timeout=0.05)
            if not stamps:
                continue
            if time.monotonic() - corrected_at > CORRECTION_EVERY_S:
                correction = self._inlet.time_correction(1.0)
                corrected_at = time.monotonic()
            host = np.asarray(stamps, dtype=float) + correction - self._lsl_minus_mono
            steps = np.diff(np.concatenate([[last], host]))
            for k in np.flatnonzero(steps > GAP_PERIODS * period):
                missing = int(round(steps[k] / period)) - 1
                self.dropouts += 1
                self.missing += missing
                if self.on_dropout is not None:
                    self.on_dropout(Dropout(float(host[k]), missing))
            last = host[-1]
            with self._lock:
                self._chunks.append((host, np.asarray(values, dtype=float)))

    def close(self) -> None:
        """Stop following (joins the reader thread) and close the inlet."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._inlet is not None:
            self._inlet.close_stream()
            self._inlet = None

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Every sample so far: host times (M,) on ``time.monotonic()`` and values (M, C)."""
        with self._lock:
            chunks = list(self._chunks)
        if not chunks:
            return np.zeros(0), np.zeros((0, len(self.channels)))
        return np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks])

    def take(self, mocap: MocapConfig, n_segments: int, t0_monotonic_s: float) -> Take:
        """The samples as a :class:`Take` whose source clock is the recording's (``t0_monotonic_s`` = its start)."""
        host, values = self.samples()
        if len(host) < 2:
            raise MocapFileError(f"--mocap lsl:{self.name}: fewer than two samples arrived from stream "
                                 f"{self.stream_name!r}")
        coordinates: dict[str, dict[str, int]] = {}
        unit = ""
        for i, (marker, axis, channel_unit) in enumerate(self.channels):
            if marker:
                coordinates.setdefault(marker, {})[axis] = i
                unit = channel_unit
        whole = {m: c for m, c in coordinates.items() if set(c) == {"X", "Y", "Z"}}
        names = list(whole)
        xyz = np.stack([values[:, [whole[m]["X"], whole[m]["Y"], whole[m]["Z"]]] for m in names], axis=1)
        xyz = xyz * UNITS_TO_M[unit.strip().lower()]
        where = Path(f"lsl:{self.stream_name}")
        markers, flat, missing, ignored = place_markers(where, names, xyz, mocap, n_segments)
        return Take(where, "LSL", host - t0_monotonic_s, markers, flat, self.rate_hz, unit, missing, ignored,
                    note=f"stamped at capture, {self.dropouts} dropouts, {self.missing} samples missing")


def append_live_mocap(recording: str | Path, take: Take, mocap: MocapConfig, axes: Sequence[str]) -> MocapResult:
    """Fit ``take`` (already on the recording's clock) and write ``/mocap`` into the closed ``recording``."""
    layout, fit, angles = fit_take(take, mocap, axes)
    result = MocapResult(take, layout, fit, angles, 0.0, None, mocap.max_residual_m,
                         stamped="stamped at capture on the recording's clock (LSL time_correction())")
    write_in_place(recording, result)
    return result


class LslPublisher:
    """Outlets ``SenSnake-forces``, ``SenSnake-joints`` and ``SenSnake-events``; see the module docstring."""

    def __init__(self, channel_names: Sequence[str], forces_unit: Sequence[str], rate_hz: float,
                 joint_count: int = 12) -> None:
        import pylsl

        self._lsl_minus_mono = lsl_minus_monotonic()
        self.forces = pylsl.StreamOutlet(self._info("SenSnake-forces", "Force", list(channel_names),
                                                    list(forces_unit), rate_hz, pylsl))
        self.joints = pylsl.StreamOutlet(self._info("SenSnake-joints", "Position",
                                                    [f"joint{j:02d}" for j in range(1, joint_count + 1)],
                                                    ["rad"] * joint_count, 0.0, pylsl))
        events = pylsl.StreamInfo("SenSnake-events", "Markers", 1, 0.0, "string", "sensnake-events")
        self.events = pylsl.StreamOutlet(events)

    @staticmethod
    def _info(name: str, kind: str, labels: list[str], units: list[str], rate_hz: float, pylsl: Any) -> Any:
        info = pylsl.StreamInfo(name, kind, len(labels), rate_hz, "double64", f"sensnake-{kind.lower()}")
        channels = info.desc().append_child("channels")
        for label, unit in zip(labels, units, strict=True):
            channel = channels.append_child("channel")
            channel.append_child_value("label", label)
            channel.append_child_value("unit", unit)
        return info

    def push_forces(self, host_time_s: np.ndarray, values: np.ndarray) -> None:
        """Board samples (N, C) at their host times (``time.monotonic()``)."""
        for t, row in zip(host_time_s, values):
            self.forces.push_sample(np.asarray(row, dtype=float).tolist(), float(t) + self._lsl_minus_mono)

    def push_joints(self, host_time_s: float, angles_rad: np.ndarray) -> None:
        self.joints.push_sample(np.asarray(angles_rad, dtype=float).tolist(), host_time_s + self._lsl_minus_mono)

    def push_event(self, text: str, host_time_s: float | None = None) -> None:
        when = time.monotonic() if host_time_s is None else host_time_s
        self.events.push_sample([text], when + self._lsl_minus_mono)

    def close(self) -> None:
        """Withdraw the streams (an outlet ends when the last reference to it goes)."""
        del self.forces, self.joints, self.events
