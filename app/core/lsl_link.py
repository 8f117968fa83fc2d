"""Lab Streaming Layer, in and out, around a live session (docs/MOCAP.md, "Live"): what ``sensnake record --mocap
lsl:NAME --lsl-out`` and the app's Forces tab (its motion-capture source and LSL switch) share.

In: :class:`MocapInlet` follows one motion-capture stream (``lsl:NAME``: the stream of that name, else the first of
type MoCap) on its own thread. Its channels are named by their metadata (``label`` ending in X/Y/Z, or ``marker`` +
``type`` PositionX/Y/Z) in their ``unit``; every sample is stamped at capture on this machine's LSL clock
(``time_correction()``, refreshed every :data:`CORRECTION_EVERY_S`) and so on ``time.monotonic()`` (the two are
related by one reading of both at the start). A gap in the stream longer than :data:`GAP_PERIODS` sample periods is
a dropout: counted, and an event (kind ``mocap``) in the recording. While a take is being collected
(:meth:`MocapInlet.begin_take` … :meth:`MocapInlet.end_take`) every sample is kept, or handed with its fitted poses
to a sink that writes it into a recording (then nothing is kept: memory stays bounded whatever the take's length);
with ``live_rate_hz`` the reader
also fits the segments' poses of a few samples a second (:class:`LivePoses`: the newest markers and a bounded
history of the segment centres) for the app's 3-D view and kinematics plot.

Out: :class:`LslPublisher` publishes ``SenSnake-forces`` (type ``Force``: each board sample's forces in N, or its
conductance in µS for a channel without a calibration; each channel's ``unit`` says which, and the stream is
published again when that changes), ``SenSnake-joints`` (type ``Position``, the present angles in rad at the control
rate) and ``SenSnake-events`` (type ``Markers``, strings), each sample stamped with the time its board frame
arrived or its servo read was sent, on the LSL clock.

:class:`LslLinks` ties both to a :class:`app.core.live_session.LiveSession` and a recording: a take from the
recording's start to its stop (:meth:`LslLinks.start`, :meth:`LslLinks.stop`) written into it as ``/mocap`` as the
samples arrive (appended by the recorder's writer, flushed with the rest; ``clock_offset_how`` saying the samples
were stamped at capture), a :class:`LiveTake` saying what was written (:meth:`LiveTake.write`: an inlet without the
layout's poses keeps its take and writes it into the closed recording there), the robot's states published as they
come (:meth:`LslLinks.push_robot_states`).

Threads: the inlet's reader thread (:attr:`MocapInlet.on_dropout` is called there); :meth:`MocapInlet.start` blocks
up to the resolve timeout (the app calls it on a worker); :meth:`LivePoses` snapshots may be read from any thread;
everything else on the controlling thread (the CLI's main thread, the GUI thread). :meth:`LiveTake.write` on any
one thread (the app writes on a worker).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.errors import MocapFileError
from app.core.live_session import LiveSession, LiveUpdate
from app.core.mocap import (
    FLAG_LEGEND,
    UNITS_TO_M,
    MocapResult,
    Take,
    fit_take,
    layout_labels,
    place_markers,
    write_in_place,
)
from app.core.recorder import Recorder
from devices.config import MocapConfig
from models.mocap import SegmentFit, check_layout, fit_segments, joint_angles

CORRECTION_EVERY_S = 2.0
RESOLVE_TIMEOUT_S = 5.0
MOCAP_TYPE = "MoCap"  # the stream type looked for when no stream has the asked name (XDF's motion-capture type)
GAP_PERIODS = 2.5  # a gap longer than this many sample periods is a dropout
PULL_TIMEOUT_S = 0.05
# At a recording's stop, how long the take waits for samples captured before the stop but still on their way (the
# sender's chunk, this reader's pull: ~50-75 ms; without the wait every take lost its last ~50 ms, measured at 480 Hz).
IN_TRANSIT_WAIT_S = 0.1  # (on the GUI thread when the app records: within its 100 ms budget)
LIVE_WINDOW_S = 120.0  # segment centres kept for the kinematics plot


def lsl_name(spec: str) -> str:
    """``lsl:NAME`` → NAME; anything else is refused naming the form."""
    if not spec.startswith("lsl:") or not spec[4:].strip():
        raise ValueError(f"--mocap {spec!r}: give lsl:NAME (a Lab Streaming Layer stream's name; else the first "
                         "stream of type MoCap is taken)")
    return spec[4:].strip()


# liblsl's configuration that keeps discovery on this machine: the tests (tests/conftest.py), the benchmarks and the
# screenshot tool use it; the app itself leaves lsl_api.cfg to the lab. [tuning] MulticastMinRTT: with the
# defaults a resolve on a loopback-only configuration waits out a whole multicast wave (5.5 s); on one machine an
# answer takes well under a millisecond.
LSL_LOOPBACK_CONFIG = ("[multicast]\nResolveScope = machine\nMachineAddresses = {127.0.0.1}\n\n[ports]\n"
                       "IPv6 = disable\n\n[lab]\nKnownPeers = {127.0.0.1}\n\n[tuning]\nMulticastMinRTT = 0.1\n")


def keep_lsl_on_this_machine(prefix: str = "sensnake-lsl-") -> Path | None:
    """Unless ``LSLAPICFG`` names a configuration already, write :data:`LSL_LOOPBACK_CONFIG` to a temporary folder
    (removed at exit) and set ``LSLAPICFG`` to it, for this process and the processes it starts; liblsl reads it
    once, when first used, so call this before anything touches pylsl. Returns the file written (None: left as it
    was)."""
    import atexit
    import os
    import shutil
    import tempfile

    if os.environ.get("LSLAPICFG"):
        return None
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, folder, True)
    config = folder / "lsl_api.cfg"
    config.write_text(LSL_LOOPBACK_CONFIG, encoding="utf-8")
    os.environ["LSLAPICFG"] = str(config)
    return config


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


@dataclass(frozen=True)
class LiveSnapshot:
    """What the reader fitted last: segment centres (N, S, 3) at ``time_s`` (N,) (``time.monotonic()``), oldest
    first, NaN where a segment had no pose; the newest sample's markers (S, K, 3) and centres (S, 3), and its time."""

    time_s: np.ndarray
    center_m: np.ndarray
    markers_m: np.ndarray
    newest_center_m: np.ndarray
    newest_time_s: float


class LivePoses:
    """A ring of segment centres (preallocated, ``window_s`` at ``rate_hz``) and the newest markers; written by the
    inlet's reader thread, read by any thread (:meth:`snapshot`)."""

    def __init__(self, n_segments: int, n_markers: int, rate_hz: float, window_s: float = LIVE_WINDOW_S) -> None:
        self.capacity = max(16, int(np.ceil(window_s * rate_hz)))
        self._time = np.full(self.capacity, np.nan)
        self._center = np.full((self.capacity, n_segments, 3), np.nan)
        self._markers = np.full((n_segments, n_markers, 3), np.nan)
        self._count = 0
        self._lock = threading.Lock()

    def append(self, time_s: np.ndarray, center_m: np.ndarray, newest_markers_m: np.ndarray) -> None:
        with self._lock:
            for t, c in zip(time_s, center_m):
                slot = self._count % self.capacity
                self._time[slot] = t
                self._center[slot] = c
                self._count += 1
            self._markers[:] = newest_markers_m

    def snapshot(self) -> LiveSnapshot | None:
        """Copies, oldest first; None before the first pose."""
        with self._lock:
            n = min(self._count, self.capacity)
            if n == 0:
                return None
            order = (np.arange(self._count - n, self._count)) % self.capacity
            times, centers = self._time[order], self._center[order]
            return LiveSnapshot(times, centers, self._markers.copy(), centers[-1].copy(), float(times[-1]))

    def __len__(self) -> int:
        return min(self._count, self.capacity)


class MocapInlet:
    """One LSL motion-capture stream followed on a reader thread; see the module docstring. ``mocap`` (the lab's
    ``[mocap]``) lets :meth:`start` check the stream's labels against the layout at once, and is needed for the
    live poses (``live_rate_hz`` > 0). ``collect``: keep every sample from the start (``sensnake record``); else
    only between :meth:`begin_take` and :meth:`end_take` (the app follows a stream for hours)."""

    def __init__(self, spec: str, resolve_timeout_s: float | None = None,
                 on_dropout: Callable[[Dropout], None] | None = None, *, mocap: MocapConfig | None = None,
                 n_segments: int = 12, collect: bool = True, live_rate_hz: float = 0.0) -> None:
        self.name = lsl_name(spec)
        self.resolve_timeout_s = RESOLVE_TIMEOUT_S if resolve_timeout_s is None else resolve_timeout_s
        self.on_dropout = on_dropout
        self.mocap = mocap
        self.n_segments = n_segments
        self.channels: list[tuple[str, str, str]] = []  # (marker, axis, unit) per channel
        self.rate_hz = 0.0
        self.stream_name = ""
        self.unit = ""
        self.dropouts = 0
        self.missing = 0
        self.received = 0
        self.last_host_s = np.nan  # time.monotonic() of the newest sample's capture
        self.live: LivePoses | None = None
        self._live_rate_hz = float(live_rate_hz)
        self._columns: np.ndarray | None = None  # (S, K, 3) channel of each layout marker's coordinate, -1 none
        self._layout: np.ndarray | None = None
        self._inlet: Any = None
        # (host monotonic (n,), values (n, C) float32, the segments' poses (None without ``mocap``)) per chunk
        self._chunks: list[tuple[np.ndarray, np.ndarray, SegmentFit | None]] = []
        self._collecting = collect
        self._sink: Callable[[np.ndarray, np.ndarray, SegmentFit], None] | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lsl_minus_mono = 0.0
        self._last_taken = np.nan  # capture time of the newest sample taken in
        self._live_cell = -np.inf  # the live grid's cell of the newest sample fitted for the live view

    def start(self) -> None:
        """Resolve the stream (by name, else by type MoCap), read its channels and start following it. Raises
        ConnectionError naming what was looked for when no stream answers within ``resolve_timeout_s``, and
        :class:`MocapFileError` when its channels do not say which marker and unit they carry (or, with ``mocap``,
        do not carry the layout's markers)."""
        import pylsl

        found = pylsl.resolve_byprop("name", self.name, 1, self.resolve_timeout_s)
        if not found:
            found = pylsl.resolve_byprop("type", MOCAP_TYPE, 1, min(1.0, self.resolve_timeout_s))
        if not found:
            raise ConnectionError(f"--mocap lsl:{self.name}: no Lab Streaming Layer stream named {self.name!r} nor "
                                  f"of type {MOCAP_TYPE} answered within {self.resolve_timeout_s:g} s")
        inlet = pylsl.StreamInlet(found[0], max_buflen=60, recover=True)
        try:
            self._describe(inlet.info(self.resolve_timeout_s))
            inlet.open_stream(self.resolve_timeout_s)
        except BaseException:
            inlet.close_stream()
            raise
        self._inlet = inlet
        self._lsl_minus_mono = lsl_minus_monotonic()
        self._thread = threading.Thread(target=self._run, name=f"lsl-mocap:{self.stream_name}", daemon=True)
        self._thread.start()

    def _describe(self, info: Any) -> None:
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
        self.unit = next(iter(units)).strip()
        if self.mocap is not None:
            names, columns = self._coordinates()
            index = np.arange(len(names) * 3, dtype=float).reshape(1, len(names), 3) + 1.0  # (0, 0, 0) reads unseen
            placed, *_ = place_markers(Path(f"lsl:{self.stream_name}"), names, index, self.mocap, self.n_segments)
            flat = np.nan_to_num(placed[0], nan=0.0).astype(int) - 1  # (S, K, 3): a position in ``columns``
            self._columns = np.where(flat >= 0, np.asarray(columns).reshape(-1)[np.maximum(flat, 0)], -1)
            self._layout = check_layout(self.mocap.marker_layout_m, self.n_segments)
            if self._live_rate_hz > 0:
                self.live = LivePoses(self.n_segments, self._layout.shape[1], self._live_rate_hz)

    def _coordinates(self) -> tuple[list[str], list[list[int]]]:
        """Every marker with X, Y and Z channels, and its three channel numbers."""
        coordinates: dict[str, dict[str, int]] = {}
        for i, (marker, axis, _unit) in enumerate(self.channels):
            if marker:
                coordinates.setdefault(marker, {})[axis] = i
        whole = {m: c for m, c in coordinates.items() if set(c) == {"X", "Y", "Z"}}
        return list(whole), [[c["X"], c["Y"], c["Z"]] for c in whole.values()]

    def _run(self) -> None:
        correction = self._inlet.time_correction(1.0)
        corrected_at = time.monotonic()
        while not self._stop.is_set():
            values, stamps = self._inlet.pull_chunk(timeout=PULL_TIMEOUT_S, as_numpy=True)
            if not len(stamps):
                continue
            if time.monotonic() - corrected_at > CORRECTION_EVERY_S:
                correction = self._inlet.time_correction(1.0)
                corrected_at = time.monotonic()
            self.take_in(np.asarray(stamps, dtype=float) + correction - self._lsl_minus_mono, values)

    def take_in(self, host: np.ndarray, values: np.ndarray) -> None:
        """One chunk of samples captured at ``host`` (``time.monotonic()``; (n,)) with channel values (n, C): its
        dropouts counted, kept for the take, fitted for the live view. The reader thread's (a test or benchmark
        may feed an inlet it did not start)."""
        period = 1.0 / self.rate_hz if self.rate_hz > 0 else np.nan
        host = np.asarray(host, dtype=float)
        values = np.asarray(values, dtype=np.float32)
        steps = np.diff(np.concatenate([[self._last_taken], host]))
        for k in np.flatnonzero(steps > GAP_PERIODS * period):
            missing = int(round(steps[k] / period)) - 1
            self.dropouts += 1
            self.missing += missing
            if self.on_dropout is not None:
                self.on_dropout(Dropout(float(host[k]), missing))
        last = host[-1]
        self._last_taken = last
        if self._collecting:  # fitted as it comes (a minute at 960 Hz fitted at the end took 10-20 s)
            fit = self._fit(values) if self._layout is not None else None
            with self._lock:
                if self._collecting and self._sink is not None and fit is not None:
                    self._sink(host, values, fit)  # written as it comes: nothing of the take kept here
                elif self._collecting:
                    self._chunks.append((host, values, fit))
        self.last_host_s = float(last)
        self.received += len(host)  # counted once kept: a reader of both never sees more received than kept
        live_step = 1.0 / self._live_rate_hz if self.live is not None else 0.0
        if live_step:  # the first sample of each new cell of the live grid is fitted
            cells = np.floor(host / live_step)
            picked = np.flatnonzero(np.diff(cells, prepend=self._live_cell) > 0)
            if picked.size:
                self._fit_live(host[picked], values[picked])
                self._live_cell = cells[-1]

    def markers_m(self, values: np.ndarray) -> np.ndarray:
        """Channel values (N, C) as the layout's markers (N, S, K, 3) in metres, NaN unseen (needs ``mocap``)."""
        assert self._columns is not None
        columns = self._columns
        picked = np.asarray(values, dtype=float)[:, np.maximum(columns, 0)]
        picked[:, columns < 0] = np.nan
        picked[np.all(picked == 0.0, axis=-1)] = np.nan
        return picked * UNITS_TO_M[self.unit.lower()]

    def _fit(self, values: np.ndarray) -> SegmentFit:
        assert self._layout is not None and self.mocap is not None
        return fit_segments(self.markers_m(values), self._layout, self.mocap.max_residual_m)

    def _fit_live(self, host: np.ndarray, values: np.ndarray) -> None:
        assert self.live is not None
        self.live.append(host, self._fit(values).center_m, self.markers_m(values[-1:])[0])

    def begin_take(self, sink: Callable[[np.ndarray, np.ndarray, SegmentFit], None] | None = None) -> None:
        """Keep every sample from now on (what came before is forgotten); with ``sink`` (and ``mocap``), hand each
        chunk (capture times, values, the segments' poses) to it instead, on the reader thread, and keep nothing:
        a take of any length then takes no memory here."""
        with self._lock:
            self._chunks = []
            self._collecting = True
            self._sink = sink

    def end_take(self) -> tuple[np.ndarray, np.ndarray, SegmentFit | None]:
        """Stop keeping samples; what was kept (as :meth:`samples`) and the segments' poses in each sample (None
        without ``mocap``), forgotten here."""
        with self._lock:
            self._collecting = False
            self._sink = None
            chunks, self._chunks = self._chunks, []
        fits = [c[2] for c in chunks]
        fit = _joined_fits(fits) if fits and all(f is not None for f in fits) else None  # type: ignore[arg-type]
        return (*_joined(chunks, len(self.channels)), fit)

    def close(self) -> None:
        """Stop following (joins the reader thread) and close the inlet."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._inlet is not None:
            self._inlet.close_stream()
            self._inlet = None

    @property
    def following(self) -> bool:
        return self._thread is not None

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Every sample kept so far: host times (M,) on ``time.monotonic()`` and values (M, C)."""
        with self._lock:
            chunks = list(self._chunks)
        return _joined(chunks, len(self.channels))

    def take(self, mocap: MocapConfig, n_segments: int, t0_monotonic_s: float) -> Take:
        """The samples kept so far as a :class:`Take` on the recording's clock (``t0_monotonic_s`` = its start)."""
        host, values = self.samples()
        return self.live_take(host, values).as_take(mocap, n_segments, t0_monotonic_s)

    def live_take(self, host: np.ndarray, values: np.ndarray, dropouts: int | None = None,
                  missing: int | None = None, fit: SegmentFit | None = None) -> LiveTake:
        """``host``/``values`` (and their poses, when fitted already) with what is needed to make a take of them,
        apart from this inlet."""
        return LiveTake(self.name, self.stream_name, tuple(self.channels), self.rate_hz, host, values,
                        self.dropouts if dropouts is None else dropouts, self.missing if missing is None else missing,
                        fit)


def _joined(chunks: list[tuple[np.ndarray, np.ndarray, SegmentFit | None]],
            n_channels: int) -> tuple[np.ndarray, np.ndarray]:
    if not chunks:
        return np.zeros(0), np.zeros((0, n_channels), np.float32)
    return np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks])


def _joined_fits(fits: Sequence[SegmentFit]) -> SegmentFit:
    return SegmentFit(*(np.concatenate([getattr(f, field.name) for f in fits]) for field in fields(SegmentFit)))


def _kept(fit: SegmentFit, keep: np.ndarray) -> SegmentFit:
    return SegmentFit(*(getattr(fit, field.name)[keep] for field in fields(SegmentFit)))


@dataclass(frozen=True)
class LiveTake:
    """The samples one recording received from a stream, stamped at capture (``host_s``: ``time.monotonic()``)."""

    spec_name: str
    stream_name: str
    channels: tuple[tuple[str, str, str], ...]
    rate_hz: float
    host_s: np.ndarray
    values: np.ndarray
    dropouts: int
    missing: int
    fit: SegmentFit | None = None  # each sample's segment poses, fitted as they came (None: fitted when written)
    streamed: int = 0  # samples written into the recording as they came (then none is kept here)
    posed: float = 0.0  # the fraction of the streamed samples' segment-frames with a pose

    @property
    def n_samples(self) -> int:
        return self.streamed or len(self.host_s)

    def as_take(self, mocap: MocapConfig, n_segments: int, t0_monotonic_s: float) -> Take:
        """A :class:`Take` whose source clock is the recording's (``t0_monotonic_s`` = its start)."""
        if len(self.host_s) < 2:
            raise MocapFileError(f"--mocap lsl:{self.spec_name}: fewer than two samples arrived from stream "
                                 f"{self.stream_name!r}")
        coordinates: dict[str, dict[str, int]] = {}
        unit = ""
        for i, (marker, axis, channel_unit) in enumerate(self.channels):
            if marker:
                coordinates.setdefault(marker, {})[axis] = i
                unit = channel_unit
        whole = {m: c for m, c in coordinates.items() if set(c) == {"X", "Y", "Z"}}
        names = list(whole)
        values = np.asarray(self.values, dtype=float)
        xyz = np.stack([values[:, [whole[m]["X"], whole[m]["Y"], whole[m]["Z"]]] for m in names], axis=1)
        xyz = xyz * UNITS_TO_M[unit.strip().lower()]
        where = Path(f"lsl:{self.stream_name}")
        markers, flat, missing, ignored = place_markers(where, names, xyz, mocap, n_segments)
        return Take(where, "LSL", self.host_s - t0_monotonic_s, markers, flat, self.rate_hz, unit, missing, ignored,
                    note=_stamped_note(self.dropouts, self.missing))

    def write(self, recording: str | Path, t0_monotonic_s: float, mocap: MocapConfig,
              axes: Sequence[str]) -> MocapResult | None:
        """Fit the take (unless it was as it came) and write ``/mocap`` into the closed ``recording``; None when
        the recording holds it already (written into it as it came)."""
        if self.streamed or not len(self.host_s):
            if self.n_samples < 2:
                with h5py.File(recording, "a") as f:
                    if "mocap" in f:
                        del f["mocap"]
                raise MocapFileError(f"--mocap lsl:{self.spec_name}: fewer than two samples arrived from stream "
                                     f"{self.stream_name!r}")
            return None
        fit = self.fit if self.fit is not None and len(self.fit.center_m) == len(self.host_s) else None
        return append_live_mocap(recording, self.as_take(mocap, len(axes), t0_monotonic_s), mocap, axes, fit)

    def summary(self, result: MocapResult | None, out: str | Path) -> str:
        """One line for the user (``result``: :meth:`write`'s)."""
        if result is not None:
            posed = float(np.isfinite(result.fit.center_m[..., 0]).mean())
        else:
            posed = self.posed
        return (f"mocap: {self.n_samples} samples from LSL stream {self.stream_name!r} written to {out} as /mocap "
                f"({posed:.1%} of segment-frames posed; {self.dropouts} dropout(s), {self.missing} sample(s) "
                "missing)")


STAMPED_HOW = "stamped at capture on the recording's clock (LSL time_correction())"


def _stamped_note(dropouts: int, missing: int) -> str:
    return f"stamped at capture, {dropouts} dropouts, {missing} samples missing"


class _TakeIntoRecording:
    """A take written into a running recording as it comes (``/mocap``, the same datasets and attributes as
    :func:`append_live_mocap` writes at the end): each chunk's rows go to the recorder's queue, flushed with the
    rest of the file; only counts are kept. Called on the inlet's reader thread."""

    def __init__(self, inlet: MocapInlet, recorder: Recorder, mocap: MocapConfig, axes: Sequence[str]) -> None:
        self.inlet, self.recorder, self.mocap, self.axes = inlet, recorder, mocap, tuple(axes)
        self.counts = (inlet.dropouts, inlet.missing)  # the inlet's when the take began
        self.rows = 0
        self.posed = 0  # segment-frames with a pose

    def __call__(self, host: np.ndarray, values: np.ndarray, fit: SegmentFit) -> None:
        keep = host >= self.recorder.t0_monotonic_s  # captured before the recording began: not its (as the board's)
        if not keep.all():
            if not keep.any():
                return
            host, values, fit = host[keep], values[keep], _kept(fit, keep)
        n = len(host)
        markers = self.inlet.markers_m(values)
        time_s = host - self.recorder.t0_monotonic_s
        columns = {"time_s": time_s, "markers_m": markers.reshape(n, -1, 3),
                   "segment_center_m": fit.center_m, "segment_rotation": fit.rotation, "residual_m": fit.residual_m,
                   "joint_angle_rad": joint_angles(fit.rotation, self.axes)[0],
                   "fit_flag": fit.flag.astype(np.int8), "markers_used": fit.n_used.astype(np.int8)}
        attrs = self._attrs(float(time_s[0])) if self.rows == 0 else {}
        self.recorder.add_mocap(columns, attrs)
        self.rows += n
        self.posed += int(np.isfinite(fit.center_m[..., 0]).sum())

    def _attrs(self, take_start_s: float) -> dict[str, Any]:
        inlet = self.inlet
        units = [unit for marker, _, unit in inlet.channels if marker]
        return {"labels": np.array([label for row in layout_labels(self.mocap, len(self.axes)) for label in row],
                                   dtype=h5py.string_dtype()),
                "source": self.source(inlet.dropouts - self.counts[0], inlet.missing - self.counts[1]), "rate_hz": float(inlet.rate_hz),
                "clock_offset_s": 0.0, "marker_layout_m": check_layout(self.mocap.marker_layout_m, len(self.axes)),
                "take_start_s": take_start_s, "clock_offset_how": STAMPED_HOW, "clock_offset_confidence": np.nan,
                "clock_offset_uncertainty_s": np.nan, "max_residual_m": float(self.mocap.max_residual_m),
                "units": units[-1] if units else "", "fit_flags": FLAG_LEGEND}

    def source(self, dropouts: int, missing: int) -> str:
        return f"LSL lsl:{self.inlet.stream_name} ({_stamped_note(dropouts, missing)})"


def append_live_mocap(recording: str | Path, take: Take, mocap: MocapConfig, axes: Sequence[str],
                      fit: SegmentFit | None = None) -> MocapResult:
    """Fit ``take`` (already on the recording's clock; ``fit``: its poses, fitted already) and write ``/mocap`` into
    the closed ``recording``, uncompressed (compressing a minute at 960 Hz took 10-20 s for ~12 % less)."""
    if fit is None:
        layout, fit, angles = fit_take(take, mocap, axes)
    else:
        layout = check_layout(mocap.marker_layout_m, len(axes))
        angles, _ = joint_angles(fit.rotation, axes)
    result = MocapResult(take, layout, fit, angles, 0.0, None, mocap.max_residual_m, stamped=STAMPED_HOW)
    write_in_place(recording, result, compression=None)
    return result


class LslPublisher:
    """Outlets ``SenSnake-forces``, ``SenSnake-joints`` and ``SenSnake-events``; see the module docstring."""

    def __init__(self, channel_names: Sequence[str], forces_unit: Sequence[str], rate_hz: float,
                 joint_count: int = 12, joint_rate_hz: float = 0.0) -> None:
        import pylsl

        self._pylsl = pylsl
        self._lsl_minus_mono = lsl_minus_monotonic()
        self.channel_names = tuple(channel_names)
        self.rate_hz = float(rate_hz)
        self.forces_unit = tuple(forces_unit)
        self.forces = pylsl.StreamOutlet(self._info("SenSnake-forces", "Force", list(self.channel_names),
                                                    list(self.forces_unit), rate_hz, pylsl))
        self.joints = pylsl.StreamOutlet(self._info("SenSnake-joints", "Position",
                                                    [f"joint{j:02d}" for j in range(1, joint_count + 1)],
                                                    ["rad"] * joint_count, joint_rate_hz, pylsl))
        events = pylsl.StreamInfo("SenSnake-events", "Markers", 1, 0.0, "string", "sensnake-events")
        self.events = pylsl.StreamOutlet(events)
        self.joint_samples = 0
        self.force_samples = 0

    @staticmethod
    def _info(name: str, kind: str, labels: list[str], units: list[str], rate_hz: float, pylsl: Any) -> Any:
        info = pylsl.StreamInfo(name, kind, len(labels), rate_hz, "double64", f"sensnake-{kind.lower()}")
        channels = info.desc().append_child("channels")
        for label, unit in zip(labels, units, strict=True):
            channel = channels.append_child("channel")
            channel.append_child_value("label", label)
            channel.append_child_value("unit", unit)
        return info

    def set_forces_unit(self, units: Sequence[str]) -> None:
        """Each channel's unit ("N" or "uS"); a change publishes ``SenSnake-forces`` again (its metadata is fixed
        for the life of an outlet)."""
        units = tuple(units)
        if units == self.forces_unit:
            return
        self.forces_unit = units
        self.forces = None  # the old outlet goes first: two outlets of one name would confuse a resolver
        self.forces = self._pylsl.StreamOutlet(self._info("SenSnake-forces", "Force", list(self.channel_names),
                                                          list(units), self.rate_hz, self._pylsl))

    def push_forces(self, host_time_s: np.ndarray, values: np.ndarray) -> None:
        """Board samples (N, C) at their host times (``time.monotonic()``)."""
        stamps = np.asarray(host_time_s, dtype=float) + self._lsl_minus_mono
        if len(stamps):
            self.forces.push_chunk(np.asarray(values, dtype=float), timestamp=stamps.tolist())
            self.force_samples += len(stamps)

    def push_joints(self, host_time_s: float, angles_rad: np.ndarray) -> None:
        self.joints.push_sample(np.asarray(angles_rad, dtype=float).tolist(), host_time_s + self._lsl_minus_mono)
        self.joint_samples += 1

    def push_event(self, text: str, host_time_s: float | None = None) -> None:
        when = time.monotonic() if host_time_s is None else host_time_s
        self.events.push_sample([text], when + self._lsl_minus_mono)

    def close(self) -> None:
        """Withdraw the streams (an outlet ends when the last reference to it goes)."""
        self.forces = self.joints = self.events = None


class LslLinks:
    """The motion-capture inlet and the published streams around ``live`` and its recordings; see the module
    docstring. Controlling thread only (the inlet's own reader aside)."""

    def __init__(self, live: LiveSession | None, mocap: MocapConfig, axes: Sequence[str],
                 joint_rate_hz: float = 0.0) -> None:
        self.live = live
        self.mocap = mocap
        self.axes = tuple(axes)
        self.joint_rate_hz = joint_rate_hz
        self.inlet: MocapInlet | None = None
        self.publisher: LslPublisher | None = None
        self._recorder: Recorder | None = None
        self._take_counts = (0, 0)  # the inlet's dropouts and missing samples when the take began
        self._streamed: _TakeIntoRecording | None = None  # the take being written into the recording

    @property
    def recording(self) -> bool:
        """A recording is running (between :meth:`start` and :meth:`stop`)."""
        return self._recorder is not None

    # -- motion capture ----------------------------------------------------------------------------------------
    def open_inlet(self, spec: str, *, collect: bool = True, live_rate_hz: float = 0.0,
                   resolve_timeout_s: float | None = None) -> MocapInlet:
        """Resolve and start following ``spec`` (blocks up to the resolve timeout; any thread). Not yet this
        session's: :meth:`adopt` it."""
        inlet = MocapInlet(spec, resolve_timeout_s, on_dropout=self._dropout, mocap=self.mocap,
                           n_segments=len(self.axes), collect=collect, live_rate_hz=live_rate_hz)
        inlet.start()
        return inlet

    def adopt(self, inlet: MocapInlet | None) -> None:
        """Follow ``inlet`` from now on (None: none), closing the one followed before."""
        previous, self.inlet = self.inlet, inlet
        if previous is not None and previous is not inlet:
            previous.close()
        if inlet is not None and self._recorder is not None:  # picked up while a recording runs
            self._begin_take(inlet, self._recorder)

    def _begin_take(self, inlet: MocapInlet, recorder: Recorder) -> None:
        """``inlet``'s samples from now on are the recording's: written into it as they come when the inlet
        fits poses (it knows the layout), else kept until :meth:`stop`."""
        self._take_counts = (inlet.dropouts, inlet.missing)
        self._streamed = _TakeIntoRecording(inlet, recorder, self.mocap, self.axes) if inlet.mocap is not None \
            else None
        inlet.begin_take(self._streamed)

    def _dropout(self, dropout: Dropout) -> None:  # the inlet's reader thread
        recorder = self._recorder
        if recorder is not None:
            recorder.log_event(f"mocap dropout: {dropout.missing} sample(s) missing", dropout.host_time_s,
                               kind="mocap")

    # -- publishing --------------------------------------------------------------------------------------------
    def publish(self, on: bool) -> None:
        """Publish ``SenSnake-forces``, ``-joints`` and ``-events`` (True) or withdraw them (False)."""
        live = self.live
        if on and self.publisher is None:
            if live is None:
                raise RuntimeError("no live board session to publish the forces of")
            names = live.channel_names
            self.publisher = LslPublisher(names, self._forces_unit(live), live.board.rate_hz, len(self.axes),
                                          self.joint_rate_hz)
            live.subscribe(self._publish)
            if self._recorder is not None:
                self.publisher.push_event(f"recording running: {self._recorder.path.name}")
        elif not on and self.publisher is not None:
            if live is not None:
                live.unsubscribe(self._publish)
            self.publisher.close()
            self.publisher = None

    @staticmethod
    def _forces_unit(live: LiveSession) -> list[str]:
        pipeline = live.pipeline
        estimated = pipeline.estimated if pipeline is not None else np.zeros(len(live.channel_names), bool)
        return ["N" if e else "uS" for e in estimated]

    def _publish(self, update: LiveUpdate) -> None:
        """Each board sample's forces in N where a calibration gives them, else its conductance in µS."""
        publisher, live = self.publisher, self.live
        if publisher is None or live is None:
            return
        if update.forces is not None:
            publisher.set_forces_unit(self._forces_unit(live))
            values = update.forces.display
        else:
            values = update.block.conductance_s * 1e6
        publisher.push_forces(update.block.host_time_s, values)

    def push_robot_states(self, states: Sequence[Any]) -> None:
        """The control loop's states (each with ``host_time_s`` and ``position_rad``) on ``SenSnake-joints``."""
        publisher = self.publisher
        if publisher is not None:
            for state in states:
                publisher.push_joints(state.host_time_s, state.position_rad)

    def push_event(self, text: str) -> None:
        if self.publisher is not None:
            self.publisher.push_event(text)

    # -- a recording -------------------------------------------------------------------------------------------
    def start(self, recorder: Recorder) -> None:
        """A recording starts: its take begins, dropouts go into its events."""
        self._recorder = recorder
        if self.inlet is not None:
            self._begin_take(self.inlet, recorder)
        self.push_event(f"recording started: {recorder.path.name}")

    def stop(self, recorder: Recorder, close_inlet: bool = False) -> LiveTake | None:
        """The recording stops (before it is closed): its take ends, its dropouts are counted in its events, and
        the take is returned (None without an inlet). ``close_inlet``: stop following the stream too."""
        take = None
        inlet = self.inlet
        if inlet is not None:
            stopped_s = time.monotonic()
            if stopped_s - inlet.last_host_s < 1.0:  # a live stream: a sample captured after the stop says all
                deadline = stopped_s + IN_TRANSIT_WAIT_S  # those before it are in (a silent one is not waited on)
                while inlet.last_host_s < stopped_s and time.monotonic() < deadline:
                    time.sleep(0.005)
            host, values, fit = inlet.end_take()
            # captured before the recording began, or after it stopped: not its (as the board's)
            keep = (host >= recorder.t0_monotonic_s) & (host <= stopped_s)
            host, values, fit = host[keep], values[keep], None if fit is None else _kept(fit, keep)
            if close_inlet:
                inlet.close()
            dropouts, missing = inlet.dropouts - self._take_counts[0], inlet.missing - self._take_counts[1]
            silent = time.monotonic() - inlet.last_host_s if np.isfinite(inlet.last_host_s) else np.inf
            quiet = f"; silent for the last {silent:.1f} s" if silent > 1.0 else ""
            recorder.log_event(f"mocap: {dropouts} dropout(s), {missing} sample(s) missing from LSL stream "
                               f"{inlet.stream_name!r}{quiet}", kind="mocap")
            take = inlet.live_take(host, values, dropouts, missing, fit)
            streamed, self._streamed = self._streamed, None
            if streamed is not None:  # written into the recording already; its source says the dropouts
                if streamed.rows:
                    recorder.set_mocap_attrs({"source": streamed.source(dropouts, missing)})
                take = replace(take, streamed=streamed.rows,
                               posed=streamed.posed / max(1, streamed.rows * len(self.axes)))
        self.push_event(f"recording stopped: {recorder.path.name}")
        self._recorder = None
        return take

    def close(self) -> None:
        self.adopt(None)
        self.publish(False)
