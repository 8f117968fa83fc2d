"""Force feedback at run time: the latest estimated forces in a shared page, and a motion source that corrects the
feedforward goals with :class:`models.force_feedback.ForceFeedbackLaw`.

The data path: board frame → estimated forces (the app's :class:`app.core.forces_pipeline.ForcesPipeline`, 30 Hz) →
:meth:`ForcePage.publish` (the frame's arrival time, every channel's force, whether each may be trusted) → the control
loop's tick (50 Hz, in the loop's own process or the app's) reads the page in :meth:`ForceFeedbackMotion.goal_at` →
feedforward goal + correction → the controller's joint-limit clamp and speed limit → the servos. So the latency from a
board frame to the goal it changes is at most one board period (the frame waits for its estimate and publication)
plus one control tick (the page waits for the next tick); :attr:`FeedbackProgress.force_age_s` says, each tick, how
old the forces it used were.

Stale forces never drive a correction: a page older than ``stale_s`` (100 ms: three board frames), a sensor the
health monitor flags, an uncalibrated sensor (no force) — that segment's node falls back to the feedforward, and
:attr:`FeedbackProgress.fallback` says which and why.

:class:`ForcePage` is a small file in shared memory (``/dev/shm`` where it exists) holding a ring of publications, so a
reader in another process never sees half a write and never waits on the writer; a :class:`ForceFeedbackMotion` crosses to the loop's process by pickling and
opens the page there by its path. Qt-free; the writer is one thread, the reader the control loop's thread.
"""

from __future__ import annotations

import json
import math
import mmap
import os
import struct
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, astuple, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from devices.scene import channel_map
from models.force_feedback import FeedbackGains, ForceFeedbackLaw
from models.trajectory import Progress

STALE_S = 0.1
_MAGIC = b"SSFP"
_LAYOUT = 2
_HEADER = struct.Struct("<4sIIIQQ")  # magic, layout, channel count, slots, latest force publication, latest gains one
_LATEST_FORCES_AT = 16
_LATEST_GAINS_AT = 24
_SLOTS = 4
_GAIN_NAMES = tuple(f.name for f in fields(FeedbackGains))


def _round8(n: int) -> int:
    return (n + 7) // 8 * 8


class _SlotRing:
    """Single-writer, wait-free publications in shared memory: a ring of ``slots`` slots, each a sequence word
    (``2·p + 1`` while publication ``p`` is written into it, ``2·p`` once complete) and ``payload`` bytes, plus a word
    elsewhere holding the latest complete publication, written last.

    A reader takes the latest publication, copies its slot and checks the slot's word again; if the writer got there
    meanwhile (it would have to publish ``slots`` more times during one copy) it tries the publication before, and
    if none is whole it returns the last one it read. So a reader never waits and never raises, and a writer stopped
    half-way through a write (descheduled, SIGSTOPped, killed) leaves the previous publication readable: the ring
    replaces the spinning sequence lock, which a descheduled writer could make fail. A reader also never returns a
    publication older than the one it returned before (:attr:`last_publication`)."""

    def __init__(self, mm: mmap.mmap, latest_at: int, slots_at: int, payload: int, slots: int) -> None:
        self._map = mm
        self._latest_at = latest_at
        self._slots_at = slots_at
        self._payload = payload
        self._stride = 8 + _round8(payload)
        self._slots = slots
        self.last_publication = 0
        self._last_payload = b""

    @property
    def size(self) -> int:
        return self._stride * self._slots

    def publish(self, payload: bytes) -> None:
        """Write one publication (the writer's thread only: one writer per ring)."""
        publication = struct.unpack_from("<Q", self._map, self._latest_at)[0] + 1
        at = self._slots_at + (publication % self._slots) * self._stride
        struct.pack_into("<Q", self._map, at, 2 * publication + 1)
        self._map[at + 8:at + 8 + self._payload] = payload
        struct.pack_into("<Q", self._map, at, 2 * publication)
        struct.pack_into("<Q", self._map, self._latest_at, publication)

    def writing(self) -> bool:
        """Whether a publication is under way (a writer stopped half-way through one leaves this True)."""
        following = struct.unpack_from("<Q", self._map, self._latest_at)[0] + 1
        at = self._slots_at + (following % self._slots) * self._stride
        return bool(struct.unpack_from("<Q", self._map, at)[0] == 2 * following + 1)

    def read(self) -> tuple[int, bytes]:
        """(publication number, its payload) of the newest complete publication not older than the last one read;
        (0, b"") before the first. Never waits."""
        latest = struct.unpack_from("<Q", self._map, self._latest_at)[0]
        for publication in range(latest, max(latest - self._slots, 0), -1):
            if publication <= self.last_publication:
                break
            at = self._slots_at + (publication % self._slots) * self._stride
            if struct.unpack_from("<Q", self._map, at)[0] != 2 * publication:
                continue  # being rewritten with a newer one (the writer lapped this reader), or torn
            payload = self._map[at + 8:at + 8 + self._payload]
            if struct.unpack_from("<Q", self._map, at)[0] != 2 * publication:
                continue
            self.last_publication, self._last_payload = publication, payload
            break
        return self.last_publication, self._last_payload


class ForcePage:
    """The latest estimated force of every channel, shared between processes. ``create`` makes one (the writer's
    side, which removes it on :meth:`close`); ``ForcePage(path)`` opens it (a reader). One thread publishes forces,
    one sets gains; any number of processes read. Reads never wait on a writer (:class:`_SlotRing`)."""

    def __init__(self, path: str | os.PathLike, n_channels: int | None = None, *, owner: bool = False) -> None:
        self.path = Path(path)
        self._owner = owner
        with open(self.path, "rb") as f:
            magic, layout, stored_channels, slots, _, _ = _HEADER.unpack(f.read(_HEADER.size))
        if magic != _MAGIC or layout != _LAYOUT or slots < 2:
            raise ValueError(f"{self.path}: not a force page of this version of the app")
        if n_channels is not None and int(n_channels) != stored_channels:
            raise ValueError(f"{self.path}: the page holds {stored_channels} channels, not {n_channels}")
        self.n_channels = int(stored_channels)
        force_payload = 8 + 9 * self.n_channels  # arrival time, forces, trusted flags
        self._size = _page_size(self.n_channels, slots)
        with open(self.path, "r+b") as f:
            self._map = mmap.mmap(f.fileno(), self._size)
        self._forces = _SlotRing(self._map, _LATEST_FORCES_AT, _HEADER.size, force_payload, slots)
        self._gains = _SlotRing(self._map, _LATEST_GAINS_AT, _HEADER.size + self._forces.size,
                                8 * len(_GAIN_NAMES), slots)

    @classmethod
    def create(cls, n_channels: int, folder: str | os.PathLike | None = None) -> ForcePage:
        base = folder or ("/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir())
        fd, name = tempfile.mkstemp(prefix="sensnake-forces-", suffix=".page", dir=base)
        header = _HEADER.pack(_MAGIC, _LAYOUT, n_channels, _SLOTS, 0, 0)
        with os.fdopen(fd, "wb") as f:
            f.write(header + bytes(_page_size(n_channels, _SLOTS) - len(header)))
        return cls(name, n_channels, owner=True)

    def publish(self, arrival_s: float, force_n: np.ndarray, trusted: np.ndarray) -> None:
        """The forces estimated from the board frame that reached the host at ``arrival_s`` (``time.monotonic``),
        NaN where there is no estimate, and which channels may drive a correction."""
        if self._map.closed:
            return  # closed with the app: a last block on its way is dropped
        forces = np.asarray(force_n, dtype="<f8").reshape(self.n_channels)
        ok = np.asarray(trusted, dtype=np.uint8).reshape(self.n_channels)
        self._forces.publish(struct.pack("<d", float(arrival_s)) + forces.tobytes() + ok.tobytes())

    @property
    def publication(self) -> int:
        """How many publications this reader has seen (the number of the last one :meth:`read` returned)."""
        return self._forces.last_publication

    @property
    def being_written(self) -> bool:
        """True while the writer is half-way through a publication (readers then get the one before)."""
        return not self._map.closed and self._forces.writing()

    def read(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(arrival time, forces, trusted) of the newest complete publication; (−inf, NaN…, False…) before the
        first (and once the page is closed). Never waits: a publication being written is skipped for the one before,
        and a read never returns an older publication than the read before it."""
        if self._map.closed:
            return -math.inf, np.full(self.n_channels, np.nan), np.zeros(self.n_channels, bool)
        publication, payload = self._forces.read()
        if publication == 0:
            return -math.inf, np.full(self.n_channels, np.nan), np.zeros(self.n_channels, bool)
        arrival = struct.unpack_from("<d", payload, 0)[0]
        forces = np.frombuffer(payload, dtype="<f8", count=self.n_channels, offset=8).copy()
        trusted = np.frombuffer(payload, dtype=np.uint8, count=self.n_channels, offset=8 + 8 * self.n_channels)
        return arrival, forces, trusted.astype(bool)

    def set_gains(self, gains: FeedbackGains) -> None:
        """New gains for a running feedback motion (any process reading this page takes them at its next tick)."""
        if self._map.closed:
            return
        self._gains.publish(struct.pack(f"<{len(_GAIN_NAMES)}d", *astuple(gains)))

    def gains(self) -> tuple[int, FeedbackGains | None]:
        """(version, gains) last set with :meth:`set_gains`; (0, None) before. Never waits, like :meth:`read`."""
        if self._map.closed:
            return 0, None
        version, payload = self._gains.read()
        if version == 0:
            return 0, None
        return version, FeedbackGains(*struct.unpack(f"<{len(_GAIN_NAMES)}d", payload))

    def close(self) -> None:
        self._map.close()
        if self._owner:
            self.path.unlink(missing_ok=True)


def _page_size(n_channels: int, slots: int) -> int:
    forces = (8 + _round8(8 + 9 * n_channels)) * slots
    gains = (8 + 8 * len(_GAIN_NAMES)) * slots
    return _HEADER.size + forces + gains


@dataclass(frozen=True)
class FeedbackProgress(Progress):
    """The motion's :class:`Progress` plus what the controller did this tick (the Gait tab shows it, the recording
    stores it): ``correction_rad`` per joint, ``node_joints`` and their ``node_load_n`` (NaN: not sensed) against
    ``target_n``, ``fallback`` (node joint → why it is on feedforward), ``force_age_s`` (how old the forces were),
    ``frame_latency_s`` (on the first tick that uses a new board frame: the frame's arrival at the host → the goal it
    changes, written this tick; NaN on ticks that reuse a frame), ``tick_s`` (the motion's time of this tick),
    ``handing_back`` (after the feedforward's last goal, while the correction goes back to 0)."""

    correction_rad: tuple[float, ...] = ()
    node_joints: tuple[int, ...] = ()
    node_load_n: tuple[float, ...] = ()
    target_n: float = 0.0
    fallback: tuple[tuple[int, str], ...] = ()
    force_age_s: float = math.inf
    frame_latency_s: float = math.nan  # the first tick to use a board frame: its arrival → this goal (else NaN)
    lead_rad: float = 0.0  # the lead's bend at its joint (rad, a pitch: + turns the front up and forward)
    front_load_n: float = math.nan  # the front's bottom load the lead acts on (N; NaN: not sensed)
    tick_s: float = 0.0
    handing_back: bool = False  # the feedforward has ended: the correction is going back to 0 (the hand-back)
    controller: str = "feedback"
    gains_json: str = ""


def bottom_channels(channel_names: Sequence[str], n_segments: int) -> np.ndarray:
    """Per segment, the board channel of its bottom sheet (−1: none)."""
    rows, segments = channel_map(channel_names, n_segments)
    out = np.full(n_segments, -1)
    for channel in np.flatnonzero(rows == 0):
        out[segments[channel]] = channel
    return out


@dataclass
class ForceFeedbackMotion:
    """A motion source: ``source``'s goals plus the law's correction from the forces on ``page_path`` (or ``page``,
    an object with ``read()``, for a caller that feeds it in-process). ``clock`` gives the time the page's arrival
    times are in (``time.monotonic`` by default; the headless lab passes its simulated clock)."""

    source: Any
    axes: tuple[str, ...]
    channel_names: tuple[str, ...]
    gains: FeedbackGains = field(default_factory=FeedbackGains)
    page_path: str | None = None
    rate_hz: float = 50.0
    stale_s: float = STALE_S
    page: Any = None
    clock: Any = None
    joint_min_rad: tuple[float, ...] | None = None
    joint_max_rad: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        self.law = ForceFeedbackLaw(self.axes, self.gains)
        self._bottom = bottom_channels(self.channel_names, len(self.axes))
        self._last_t: float | None = None
        self._last_goal: np.ndarray | None = None  # the feedforward's last goal (its final pose once it has ended)
        self._correction = np.zeros(len(self.axes))  # the correction sent with the last goal
        self._last_arrival = -math.inf
        self._gains_version = 0
        self._gains_json_of: tuple[FeedbackGains, str] | None = None  # (gains, their JSON)
        self.progress: Progress = getattr(self.source, "progress", Progress("shift", 0, 1, 0.0, 0.0, 0.0, 0.0))

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        if self.page_path is not None:
            state["page"] = None  # the mmap stays here; the other process opens the page by its path
        return state

    def set_gains(self, gains: FeedbackGains) -> None:
        """Live adjustment (checked against the safe ranges first)."""
        self.law.set_gains(gains)
        self.gains = gains

    def _read(self) -> tuple[float, np.ndarray, np.ndarray]:
        if self.page is None and self.page_path is not None:
            self.page = ForcePage(self.page_path)
        if self.page is None:
            return -math.inf, np.full(len(self.channel_names), np.nan), np.zeros(len(self.channel_names), bool)
        return self.page.read()  # type: ignore[no-any-return]

    def goal_at(self, t_s: float, present_rad: np.ndarray) -> np.ndarray | None:
        goal = self.source.goal_at(t_s, present_rad)
        if goal is None:
            return self._hand_back(t_s)
        dt = 1.0 / self.rate_hz if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        arrival, forces, trusted = self._read()
        if self.page is not None and hasattr(self.page, "gains"):
            version, gains = self.page.gains()
            if version != self._gains_version and gains is not None:
                self._gains_version = version
                self.set_gains(gains)  # live adjustment from the app (checked against the safe ranges)
        now = (self.clock or time.monotonic)()
        age = now - arrival
        fresh = math.isfinite(arrival) and arrival != self._last_arrival
        self._last_arrival = arrival
        n = len(self.axes)
        bottom = np.full(n, np.nan)
        valid = np.zeros(n, bool)
        why = [""] * n
        for segment, channel in enumerate(self._bottom):
            name = self.channel_names[channel] if channel >= 0 else f"segment {segment + 1}"
            if channel < 0:
                why[segment] = f"{name}: no bottom sensor"
            elif not age <= self.stale_s:
                why[segment] = (f"{name}: no force estimate for {age * 1000:.0f} ms" if math.isfinite(age)
                                else f"{name}: no force estimate yet")
            elif not np.isfinite(forces[channel]):
                why[segment] = f"{name}: uncalibrated"
            elif not trusted[channel]:
                why[segment] = f"{name}: flagged by the health monitor"
            else:
                bottom[segment], valid[segment] = forces[channel], True
        base = getattr(self.source, "progress", None)
        phase = None
        if isinstance(base, Progress) and base.kind == "shift":
            # shifts done so far, continuous: approaching target k means shift k−1 → k is under way
            phase = max(base.index - 1 + base.move_fraction, 0.0) if base.index >= 1 else 0.0
        correction = self.law.step(dt, bottom, valid, why, present_rad=np.asarray(present_rad, dtype=float),
                                   phase=phase)
        if isinstance(base, Progress):
            self.progress = FeedbackProgress(
                base.kind, base.index, base.count, base.move_fraction, base.fraction, base.elapsed_s, base.total_s,
                base.done, correction_rad=tuple(float(c) for c in correction),
                node_joints=tuple(int(j) for j in self.law.nodes),
                node_load_n=tuple(float(v) for v in self.law.node_load_n), target_n=self.law.gains.target_n,
                fallback=tuple(sorted(self.law.fallback.items())), force_age_s=float(age),
                frame_latency_s=float(age) if fresh else math.nan, lead_rad=float(self.law.lead_rad),
                front_load_n=float(self.law.front_load_n), tick_s=float(t_s),
                gains_json=self._gains_json())
        goal = np.asarray(goal, dtype=float)
        self._last_goal, self._correction = goal.copy(), correction.copy()
        return self._corrected(goal, correction)

    def _gains_json(self) -> str:
        """The law's gains as JSON, written again only when they change (a tick's progress carries them: encoding
        them every tick cost a headless run a tenth of its controller's time)."""
        gains = self.law.gains
        if self._gains_json_of is None or self._gains_json_of[0] is not gains:
            self._gains_json_of = (gains, json.dumps(asdict(gains)))
        return self._gains_json_of[1]

    @property
    def correction_rad(self) -> np.ndarray:
        """The correction (rad per joint) sent with the last goal — the law's, or during the hand-back what is left
        of it."""
        return self._correction.copy()

    def _hand_back(self, t_s: float) -> np.ndarray | None:
        """After the feedforward's last goal: the correction goes back to 0 at ``max_rate_rad_s`` per joint, so the
        motion ends in the feedforward's final pose (a play that ends straight ends straight), then the motion ends.
        Holding the last correction instead kept a bend the feedforward straightens at the end of a play, and its
        last shift is what carries a body's tail over an obstacle (measured: docs/FORCE_FEEDBACK.md)."""
        if self._last_goal is None or not np.any(self._correction):
            self.progress = getattr(self.source, "progress", self.progress)
            return None
        dt = 1.0 / self.rate_hz if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        step = self.law.gains.max_rate_rad_s * dt if self.law.gains.max_rate_rad_s > 0.0 else math.inf
        self._correction = np.sign(self._correction) * np.maximum(np.abs(self._correction) - step, 0.0)
        if isinstance(self.progress, FeedbackProgress):
            self.progress = replace(self.progress, done=False, correction_rad=tuple(float(c) for c in self._correction),
                                    frame_latency_s=math.nan, tick_s=float(t_s), handing_back=True)
        return self._corrected(self._last_goal, self._correction)

    def _corrected(self, goal: np.ndarray, correction: np.ndarray) -> np.ndarray:
        if self.joint_min_rad is not None and self.joint_max_rad is not None:
            # the correction never takes a goal past a joint limit (the controller refuses such a goal outright)
            corrected = np.clip(goal + correction, self.joint_min_rad, self.joint_max_rad)
            return np.where((goal >= self.joint_min_rad) & (goal <= self.joint_max_rad), corrected, goal + correction)
        return goal + correction
