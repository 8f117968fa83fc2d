"""Every series a recording or the live lab offers, under one name each, and a window of one for a plot.

A *series* is one quantity against time: a joint's goal, present angle, velocity or current, the feedback
controller's correction, a sensor's force, conductance, estimator status or health flags, a motion-captured or
simulated segment coordinate, a servo's hardware error, temperature or voltage. Its key names it the same way live
and in a recording (``robot/J5/current_mA``, ``forces/S06B/force_N``), so a plot layout made on the live lab opens
on a recording and the other way round.

- :class:`RecordingSeries` lists what a recording holds (SPEC §3.5 and its extensions: ``/daq``, ``/forces``,
  ``/robot``, ``/control``, ``/sim``, ``/mocap``, ``/events``) and reads a series when it is first asked for (kept
  while it is plotted, :meth:`RecordingSeries.keep_only` drops the others).
- :class:`LiveSeries` keeps the live lab's recent past in preallocated rings (a fixed number of bytes per source,
  allocated when the first sample of that source arrives), fed by whoever receives the robot's states, the board's
  blocks and the estimated forces (the GUI's Plots dock, while it is shown).
- ``window(key, t0, t1, max_points)`` of either gives (t, v) of a series over [t0, t1], min/max-decimated to about
  ``max_points`` buckets (:func:`decimate`): drawing costs what the plot's width costs, whatever the data's length.
- :class:`PlotLayout` is what a plot panel shows (stacked time plots with linked time axes, or X–Y plots, and their
  series). :func:`write_layout` saves it as a small JSON file (``sensnake-plot-layout`` v1, docs/SPEC_EXTENSIONS.md)
  beside a recording (:func:`layout_beside`) or in the data folder (:func:`app.core.user_folders.plot_layouts_dir`),
  never over an existing file unless the caller says so.

Times: a recording's clock (seconds since its start); live, seconds since ``t0_monotonic_s`` (the board bridge's
clock, which the Forces tab's plots use too). Qt-free. A :class:`LiveSeries` is fed and read on one thread (the
GUI's); a :class:`RecordingSeries` on one thread at a time.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from app.core.calfiles import write_atomically
from app.core.errors import PlotLayoutError, RecordingFormatError
from app.core.recording import check_input
from devices.toml_files import parse_json_text

# -- what a series is -----------------------------------------------------------------------------------------------
JOINTS, SENSORS, SEGMENTS, SERVOS, BODY = "Joints", "Sensors", "Segments", "Servos", "Body"
GROUPS: tuple[str, ...] = (JOINTS, SENSORS, SEGMENTS, SERVOS, BODY)

# (key part, name, unit) of the robot's per-joint quantities, in the column order of the live robot table
ROBOT_QUANTITIES: tuple[tuple[str, str, str], ...] = (
    ("goal_rad", "goal", "rad"), ("present_rad", "present", "rad"), ("velocity_rad_s", "velocity", "rad/s"),
    ("current_mA", "current", "mA"))
SERVO_QUANTITIES: tuple[tuple[str, str, str], ...] = (
    ("hardware_error", "hardware error", "bits"), ("temperature_C", "temperature", "°C"),
    ("voltage_V", "voltage", "V"))
AXES_XYZ = ("x", "y", "z")

LIVE_HISTORY_S = 600.0  # the live past kept per source (less for a wide board: TABLE_BUDGET_BYTES bounds it)
TABLE_BUDGET_BYTES = 24_000_000  # one live source's ring at most (a 1024-channel board at 100 Hz: ~58 s)
HEALTH_ROW_EVERY_S = 0.5  # unchanged sensor health flags are kept this often (a change at once)


@dataclass(frozen=True)
class SeriesInfo:
    """One series: ``key`` (its name live and in recordings), where it sits in a tree (``group`` ▸ ``item`` ▸
    ``name``), its ``unit``; ``steps`` for a code or a set of flags (drawn as steps, never interpolated)."""

    key: str
    group: str
    item: str
    name: str
    unit: str
    steps: bool = False

    @property
    def label(self) -> str:
        """``"J5 current"``."""
        return f"{self.item} {self.name}"

    @property
    def text(self) -> str:
        """``"J5 current (mA)"``."""
        return f"{self.label} ({self.unit})"


def joint_key(joint_id: int, quantity: str) -> str:
    """``robot/J5/current_mA`` and the like (``quantity`` one of :data:`ROBOT_QUANTITIES`' keys)."""
    return f"robot/J{joint_id}/{quantity}"


def force_key(channel: str) -> str:
    return f"forces/{channel}/force_N"


def conductance_key(channel: str) -> str:
    return f"daq/{channel}/conductance_uS"


def status_key(channel: str) -> str:
    return f"forces/{channel}/status"


def health_key(channel: str) -> str:
    return f"health/{channel}/flags"


def correction_key(joint_id: int) -> str:
    return f"control/J{joint_id}/correction_rad"


def servo_key(joint_id: int, quantity: str) -> str:
    return f"servo/J{joint_id}/{quantity}"


def mocap_key(segment: int, what: str) -> str:
    """``mocap/seg03/x_m``; ``what`` one of ``x_m``, ``y_m``, ``z_m``, ``residual_m``, ``fit_flag``."""
    return f"mocap/seg{segment:02d}/{what}"


def sim_segment_key(segment: int, axis: str) -> str:
    return f"sim/seg{segment:02d}/{axis}_m"


def _joint_series(joint_ids: Sequence[int], quantities: Iterable[tuple[str, str, str]]) -> list[SeriesInfo]:
    return [SeriesInfo(joint_key(j, q), JOINTS, f"J{j}", name, unit) for j in joint_ids for q, name, unit in quantities]


def _sort(infos: Iterable[SeriesInfo]) -> list[SeriesInfo]:
    """Grouped (joints, sensors, segments, servos, body), items in their natural order, quantities as listed."""
    order = {g: i for i, g in enumerate(GROUPS)}
    ranked = list(infos)

    def item_rank(info: SeriesInfo) -> tuple:
        digits = re.findall(r"\d+", info.item)
        return (order.get(info.group, len(order)), int(digits[0]) if digits else 0, info.item)

    # a stable sort keeps the order each item's quantities were listed in
    return sorted(ranked, key=item_rank)


# -- drawing a window -----------------------------------------------------------------------------------------------
def decimate(t_s: np.ndarray, values: np.ndarray, t0_s: float, t1_s: float,
             max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """(t, v) of the samples in [t0, t1] (and one either side, so a line reaches the edges), ascending times. More
    than ``2 × max_points`` of them are cut into ``max_points`` buckets drawn as each bucket's minimum then maximum
    (every peak stays visible); a bucket with no number is NaN (the line breaks there)."""
    n = t_s.shape[0]
    i0 = max(0, int(np.searchsorted(t_s, t0_s, "left")) - 1)
    i1 = min(n, int(np.searchsorted(t_s, t1_s, "right")) + 1)
    t, v = t_s[i0:i1], np.asarray(values[i0:i1], dtype=float)
    max_points = max(2, int(max_points))
    if t.size <= 2 * max_points:
        return t, v
    step = int(math.ceil(t.size / max_points))
    whole = t.size // step * step
    buckets = v[:whole].reshape(-1, step)
    low = np.fmin.reduce(buckets, axis=1)  # NaN only where the whole bucket is NaN (no warning, unlike nanmin)
    high = np.fmax.reduce(buckets, axis=1)
    x = np.repeat(t[:whole:step], 2)
    y = np.empty(x.size)
    y[0::2], y[1::2] = low, high
    if whole < t.size:  # the last, partial bucket, then the newest sample itself: a live edge never lags
        x = np.concatenate([x, t[whole:whole + 1], t[-1:]])
        y = np.concatenate([y, [np.fmin.reduce(v[whole:])], v[-1:]])
    return x, y


def as_steps(t_s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A code or flag series drawn as steps: each value held until the next sample."""
    if t_s.size < 2:
        return t_s, values
    x = np.repeat(t_s, 2)[1:]
    y = np.repeat(values, 2)[:-1]
    return x, y


def resample(t_s: np.ndarray, values: np.ndarray, at_s: np.ndarray) -> np.ndarray:
    """``values`` (sampled at ``t_s``) linearly interpolated at the times ``at_s``; NaN outside the samples' span or
    without a finite sample (for an X–Y plot of two series sampled at different times)."""
    at_s = np.asarray(at_s, dtype=float)
    finite = np.isfinite(values) & np.isfinite(t_s)
    if not finite.any():
        return np.full(at_s.shape, np.nan)
    return np.interp(at_s, t_s[finite], np.asarray(values, dtype=float)[finite], left=np.nan, right=np.nan)


def value_at(t_s: np.ndarray, values: np.ndarray, at_s: float) -> float:
    """The last sample at or before ``at_s`` (NaN before the first or without samples)."""
    i = int(np.searchsorted(t_s, at_s, "right")) - 1
    return float(values[i]) if 0 <= i < values.shape[0] else math.nan


# -- a recording ----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Column:
    """Where a series lies in a recording: its times (dataset path), its values (dataset path and the index into a
    row), a scale; ``centre`` averages points k and k+1 of ``/sim/points_m`` (a segment's centre)."""

    time: str
    data: str
    index: tuple[int, ...] = ()
    scale: float = 1.0
    centre: bool = False


def _text(value: object) -> str:
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def _recorded_joint_ids(config_text: str, n_joints: int) -> tuple[int, ...]:
    """The joint (servo) IDs of the config stored in a recording, when it says and they fit; else 1 … n."""
    if config_text.strip():
        try:
            from devices.config import parse_config

            ids = tuple(parse_config(config_text).robot.joint_ids)
        except (ValueError, LookupError, TypeError):
            ids = ()
        if len(ids) == n_joints:
            return ids
    return tuple(range(1, n_joints + 1))


def _health_flag_words() -> dict[str, int]:
    from models.health import SensorHealth, describe

    return {describe(int(flag)): int(flag) for flag in SensorHealth if int(flag)}


def health_flags_from_text(text: str) -> int:
    """The flags of a health word list as :func:`models.health.describe` writes it (``"noisy (loose?), saturated"``);
    0 for ``"ok"``."""
    words = _health_flag_words()
    flags = 0
    for word, flag in words.items():
        if word in text:
            flags |= flag
    return flags


class RecordingSeries:
    """The series of one recording (see the module docstring). :class:`RecordingFormatError` when ``path`` is not
    a SenSnake recording; an unreadable dataset is refused when it is read, naming it."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = check_input(Path(path))
        self._columns: dict[str, _Column] = {}
        self._infos: list[SeriesInfo] = []
        self._health_events: dict[str, list[tuple[float, int]]] = {}
        self._cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._times: dict[str, np.ndarray] = {}
        try:
            with h5py.File(self.path, "r") as f:
                self._index(f)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            if isinstance(exc, RecordingFormatError):
                raise
            raise RecordingFormatError(f"{self.path}: cannot be read as a SenSnake recording ({exc})") from exc

    @property
    def name(self) -> str:
        return self.path.name

    def _index(self, f: h5py.File) -> None:
        if _text(f.attrs.get("format", "")) != "sensnake-recording":
            raise RecordingFormatError(f"{self.path} is not a SenSnake recording (no format attribute "
                                       "\"sensnake-recording\")")
        config_text = _text(f.attrs.get("config", ""))
        infos: list[SeriesInfo] = []
        spans: list[tuple[float, float]] = []
        channels: tuple[str, ...] = ()

        def rows(name: str) -> int:
            item = f.get(name)
            return int(item.shape[0]) if isinstance(item, h5py.Dataset) and item.ndim >= 1 else 0

        def span(time_path: str) -> None:
            n = rows(time_path)
            if n:
                ds = f[time_path]
                spans.append((float(ds[0]), float(ds[n - 1])))

        if isinstance(f.get("daq"), h5py.Group):
            channels = tuple(_text(c) for c in f["daq"].attrs.get("channels", ()))
            span("daq/time_s")
            if rows("daq/conductance_S") and f["daq/conductance_S"].ndim == 2:
                for c, ch in enumerate(channels[: f["daq/conductance_S"].shape[1]]):
                    self._add(infos, SeriesInfo(conductance_key(ch), SENSORS, ch, "conductance", "µS"),
                              _Column("daq/time_s", "daq/conductance_S", (c,), 1e6))
            if rows("forces/force_N") and f["forces/force_N"].ndim == 2:
                for c, ch in enumerate(channels[: f["forces/force_N"].shape[1]]):
                    self._add(infos, SeriesInfo(force_key(ch), SENSORS, ch, "force", "N"),
                              _Column("daq/time_s", "forces/force_N", (c,)))
            if rows("forces/status") and f["forces/status"].ndim == 2:
                for c, ch in enumerate(channels[: f["forces/status"].shape[1]]):
                    self._add(infos, SeriesInfo(status_key(ch), SENSORS, ch, "estimator status", "code", True),
                              _Column("daq/time_s", "forces/status", (c,)))
        if rows("robot/time_s") and rows("robot/goal_rad") and f["robot/goal_rad"].ndim == 2:
            span("robot/time_s")
            joint_ids = _recorded_joint_ids(config_text, int(f["robot/goal_rad"].shape[1]))
            for j, jid in enumerate(joint_ids):
                for quantity, name, unit in ROBOT_QUANTITIES:
                    data = f"robot/{quantity}"
                    if rows(data) and f[data].ndim == 2 and f[data].shape[1] > j:
                        self._add(infos, SeriesInfo(joint_key(jid, quantity), JOINTS, f"J{jid}", name, unit),
                                  _Column("robot/time_s", data, (j,)))
        else:
            joint_ids = _recorded_joint_ids(config_text, 12)
        if rows("control/time_s") and rows("control/correction_rad") and f["control/correction_rad"].ndim == 2:
            span("control/time_s")
            for j in range(int(f["control/correction_rad"].shape[1])):
                jid = joint_ids[j] if j < len(joint_ids) else j + 1
                self._add(infos, SeriesInfo(correction_key(jid), JOINTS, f"J{jid}", "feedback correction", "rad"),
                          _Column("control/time_s", "control/correction_rad", (j,)))
        if rows("mocap/time_s"):
            span("mocap/time_s")
            if rows("mocap/segment_center_m") and f["mocap/segment_center_m"].ndim == 3:
                for s in range(int(f["mocap/segment_center_m"].shape[1])):
                    for a, axis in enumerate(AXES_XYZ):
                        self._add(infos, SeriesInfo(mocap_key(s + 1, f"{axis}_m"), SEGMENTS, f"Segment {s + 1}",
                                                    f"motion-capture {axis}", "m"),
                                  _Column("mocap/time_s", "mocap/segment_center_m", (s, a)))
            for what, name, unit, steps in (("residual_m", "motion-capture residual", "m", False),
                                            ("fit_flag", "motion-capture fit flag", "code", True)):
                data = f"mocap/{what}"
                if rows(data) and f[data].ndim == 2:
                    for s in range(int(f[data].shape[1])):
                        self._add(infos, SeriesInfo(mocap_key(s + 1, what), SEGMENTS, f"Segment {s + 1}", name, unit,
                                                    steps), _Column("mocap/time_s", data, (s,)))
            if rows("mocap/joint_angle_rad") and f["mocap/joint_angle_rad"].ndim == 2:
                for j in range(int(f["mocap/joint_angle_rad"].shape[1])):
                    jid = joint_ids[j] if j < len(joint_ids) else j + 1
                    self._add(infos, SeriesInfo(f"mocap/J{jid}/angle_rad", JOINTS, f"J{jid}",
                                                "motion-capture angle", "rad"),
                              _Column("mocap/time_s", "mocap/joint_angle_rad", (j,)))
        if rows("sim/time_s"):
            span("sim/time_s")
            if rows("sim/sheet_true_N") and f["sim/sheet_true_N"].ndim == 2:
                for c, ch in enumerate(channels[: f["sim/sheet_true_N"].shape[1]]):
                    self._add(infos, SeriesInfo(f"sim/{ch}/true_N", SENSORS, ch, "simulated true force", "N"),
                              _Column("sim/time_s", "sim/sheet_true_N", (c,)))
            if rows("sim/points_m") and f["sim/points_m"].ndim == 3:
                for s in range(int(f["sim/points_m"].shape[1]) - 1):
                    for a, axis in enumerate(AXES_XYZ):
                        self._add(infos, SeriesInfo(sim_segment_key(s + 1, axis), SEGMENTS, f"Segment {s + 1}",
                                                    f"simulated {axis}", "m"),
                                  _Column("sim/time_s", "sim/points_m", (s, a), centre=True))
            if rows("sim/support_N") and f["sim/support_N"].ndim == 1:
                self._add(infos, SeriesInfo("sim/body/support_N", BODY, "Whole body", "simulated support", "N"),
                          _Column("sim/time_s", "sim/support_N"))
        if isinstance(f.get("events"), h5py.Group) and rows("events/time_s") and channels:
            times = f["events/time_s"][:]
            kinds, texts = f["events/kind"][: times.size], f["events/text"][: times.size]
            for t, kind, text in zip(times, kinds, texts):
                kind_text, line = _text(kind), _text(text)
                if kind_text == "health" and ": " in line:
                    name, words = line.split(": ", 1)
                    self._health_events.setdefault(name, []).append((float(t), health_flags_from_text(words)))
            for ch in channels:
                infos.append(SeriesInfo(health_key(ch), SENSORS, ch, "health flags", "flags", True))
        self._infos = _sort(infos)
        self._start_s = min((a for a, _b in spans), default=0.0)
        self._end_s = max((b for _a, b in spans), default=0.0)

    def _add(self, infos: list[SeriesInfo], info: SeriesInfo, column: _Column) -> None:
        infos.append(info)
        self._columns[info.key] = column

    # -- what it holds ---------------------------------------------------------------------------------------------
    def catalog(self) -> list[SeriesInfo]:
        """Every series this recording holds, grouped (joints, sensors, segments, servos, body)."""
        return list(self._infos)

    def info(self, key: str) -> SeriesInfo | None:
        return next((i for i in self._infos if i.key == key), None)

    def has(self, key: str) -> bool:
        return key in self._columns or key.startswith("health/") and self.info(key) is not None

    def span(self) -> tuple[float, float]:
        """(first, last) time of anything recorded, on the recording's clock (s)."""
        return self._start_s, self._end_s

    # -- reading ---------------------------------------------------------------------------------------------------
    def read(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """The whole series (t, v), read on first use and kept; ``KeyError`` for a series it does not hold,
        :class:`RecordingFormatError` for a dataset that does not read."""
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        if key.startswith("health/") and self.info(key) is not None:
            name = key.split("/")[1]
            events = self._health_events.get(name, [])
            t = np.array([self._start_s] + [e[0] for e in events])
            v = np.array([0.0] + [float(e[1]) for e in events])
            order = np.argsort(t, kind="stable")
            self._cache[key] = (t[order], v[order])
            return self._cache[key]
        column = self._columns[key]
        try:
            with h5py.File(self.path, "r") as f:
                known = self._times.get(column.time)
                t = known if known is not None else np.asarray(f[column.time][:], dtype=float)
                self._times[column.time] = t
                ds = f[column.data]
                n = min(t.shape[0], int(ds.shape[0]))
                if column.centre:
                    segment, axis = column.index
                    pair = np.asarray(ds[:n, segment:segment + 2, axis], dtype=float)
                    v = pair.mean(axis=1)
                else:
                    v = np.asarray(ds[(slice(0, n), *column.index)], dtype=float)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise RecordingFormatError(f"{self.path}: {column.data} cannot be read ({exc})") from exc
        if column.scale != 1.0:
            v = v * column.scale
        self._cache[key] = (t[:n], v)
        return self._cache[key]

    def window(self, key: str, t0_s: float, t1_s: float, max_points: int) -> tuple[np.ndarray, np.ndarray]:
        """(t, v) of ``key`` over [t0, t1], decimated (:func:`decimate`); a step series as steps."""
        t, v = self.read(key)
        x, y = decimate(t, v, t0_s, t1_s, max_points)
        info = self.info(key)
        return as_steps(x, y) if info is not None and info.steps else (x, y)

    def value_at(self, key: str, t_s: float) -> float:
        t, v = self.read(key)
        return value_at(t, v, t_s)

    def keep_only(self, keys: Iterable[str]) -> None:
        """Forget what was read of every series not in ``keys`` (they are no longer plotted)."""
        wanted = set(keys)
        for key in [k for k in self._cache if k not in wanted]:
            del self._cache[key]


# -- the live lab ---------------------------------------------------------------------------------------------------
class _Ring:
    """A preallocated ring of rows (time, ``columns`` float32 values); the oldest row is overwritten first."""

    def __init__(self, capacity: int, columns: int) -> None:
        self.capacity = capacity
        self.columns = columns
        self.t = np.zeros(capacity)
        self.v = np.zeros((capacity, columns), dtype=np.float32)
        self.v.fill(0)  # commit the memory now (np.zeros maps pages lazily): it stays flat from here on
        self.write = 0
        self.count = 0

    @property
    def nbytes(self) -> int:
        return int(self.t.nbytes + self.v.nbytes)

    def push(self, t_s: np.ndarray, values: np.ndarray) -> None:
        n = t_s.shape[0]
        if n == 0:
            return
        if n > self.capacity:
            t_s, values, n = t_s[-self.capacity:], values[-self.capacity:], self.capacity
        first = min(n, self.capacity - self.write)
        self.t[self.write:self.write + first] = t_s[:first]
        self.v[self.write:self.write + first] = values[:first]
        if n > first:
            self.t[:n - first] = t_s[first:]
            self.v[:n - first] = values[first:]
        self.write = (self.write + n) % self.capacity
        self.count = min(self.capacity, self.count + n)

    def _segments(self) -> list[slice]:
        if self.count < self.capacity:
            return [slice(0, self.count)]
        return [slice(self.write, self.capacity), slice(0, self.write)]

    def between(self, t0_s: float, t1_s: float, column: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows with t0 ≤ t ≤ t1 (and one either side), oldest first: (t, v of ``column``)."""
        parts_t, parts_v = [], []
        for seg in self._segments():
            ts = self.t[seg]
            i0 = max(0, int(np.searchsorted(ts, t0_s, "left")) - 1)
            i1 = min(ts.size, int(np.searchsorted(ts, t1_s, "right")) + 1)
            if i1 > i0:
                parts_t.append(ts[i0:i1])
                parts_v.append(self.v[seg.start + i0:seg.start + i1, column])
        if not parts_t:
            return self.t[:0], self.v[:0, column]
        if len(parts_t) == 1:
            return parts_t[0], parts_v[0]
        return np.concatenate(parts_t), np.concatenate(parts_v)

    def newest_t(self) -> float:
        return float(self.t[(self.write - 1) % self.capacity]) if self.count else -math.inf

    def oldest_t(self) -> float:
        if self.count == 0:
            return math.inf
        return float(self.t[0] if self.count < self.capacity else self.t[self.write])


ROBOT, BOARD, FORCES, HEALTH, SERVO = "robot", "board", "forces", "health", "servo"


class LiveSeries:
    """The live lab's series (see the module docstring): ``channel_names`` of the board, ``joint_ids`` of the robot,
    times as seconds since ``t0_monotonic_s``; each source's ring holds up to ``history_s`` at the rate given (less
    when ``budget_bytes`` would not hold that). Feed it with :meth:`add_states`, :meth:`add_block`,
    :meth:`add_forces`, :meth:`add_health` and :meth:`add_servo_health`; :attr:`version` counts what arrived."""

    def __init__(self, channel_names: Sequence[str], joint_ids: Sequence[int], t0_monotonic_s: float, *,
                 robot_rate_hz: float = 50.0, board_rate_hz: float = 30.0, history_s: float = LIVE_HISTORY_S,
                 budget_bytes: int = TABLE_BUDGET_BYTES) -> None:
        self.channel_names = tuple(channel_names)
        self.joint_ids = tuple(joint_ids)
        self.t0_monotonic_s = float(t0_monotonic_s)
        self.history_s = float(history_s)
        self.budget_bytes = int(budget_bytes)
        self._rates = {ROBOT: robot_rate_hz, BOARD: board_rate_hz, FORCES: board_rate_hz,
                       HEALTH: 4.0, SERVO: 10.0}
        n_j, n_c = len(self.joint_ids), len(self.channel_names)
        self._widths = {ROBOT: (len(ROBOT_QUANTITIES) + 1) * n_j, BOARD: n_c, FORCES: 2 * n_c, HEALTH: n_c,
                        SERVO: len(SERVO_QUANTITIES) * n_j}
        self._rings: dict[str, _Ring] = {}
        self._where: dict[str, tuple[str, int]] = {}
        self._infos: list[SeriesInfo] = []
        self.version = 0
        self._joint_index = {jid: j for j, jid in enumerate(self.joint_ids)}
        for j, jid in enumerate(self.joint_ids):
            for q, (quantity, name, unit) in enumerate(ROBOT_QUANTITIES):
                self._declare(SeriesInfo(joint_key(jid, quantity), JOINTS, f"J{jid}", name, unit),
                              ROBOT, q * n_j + j)
            self._declare(SeriesInfo(correction_key(jid), JOINTS, f"J{jid}", "feedback correction", "rad"),
                          ROBOT, len(ROBOT_QUANTITIES) * n_j + j)
        for c, ch in enumerate(self.channel_names):
            self._declare(SeriesInfo(force_key(ch), SENSORS, ch, "force", "N"), FORCES, c)
            self._declare(SeriesInfo(conductance_key(ch), SENSORS, ch, "conductance", "µS"), BOARD, c)
            self._declare(SeriesInfo(status_key(ch), SENSORS, ch, "estimator status", "code", True), FORCES, n_c + c)
            self._declare(SeriesInfo(health_key(ch), SENSORS, ch, "health flags", "flags", True), HEALTH, c)
        for j, jid in enumerate(self.joint_ids):
            for q, (quantity, name, unit) in enumerate(SERVO_QUANTITIES):
                self._declare(SeriesInfo(servo_key(jid, quantity), SERVOS, f"J{jid}", name, unit,
                                         quantity == "hardware_error"), SERVO, q * n_j + j)
        self._infos = _sort(self._infos)
        self._info_by_key = {i.key: i for i in self._infos}

    def _declare(self, info: SeriesInfo, source: str, column: int) -> None:
        self._infos.append(info)
        self._where[info.key] = (source, column)

    # -- what it offers --------------------------------------------------------------------------------------------
    def catalog(self) -> list[SeriesInfo]:
        return list(self._infos)

    def info(self, key: str) -> SeriesInfo | None:
        return self._info_by_key.get(key)

    def has(self, key: str) -> bool:
        return key in self._where

    def source_of(self, key: str) -> str | None:
        """Which live source feeds ``key``: ``robot``, ``board``, ``forces`` (the Forces tab's estimates),
        ``health`` (its sensor health monitor) or ``servo`` (the servos' polled health); None if not a live one."""
        where = self._where.get(key)
        return where[0] if where is not None else None

    def capacity(self, source: str) -> int:
        """Rows the ring of ``source`` holds (it is allocated at this size when its first sample arrives)."""
        width = self._widths[source]
        wanted = int(self.history_s * self._rates[source] * 1.25) + 16
        return max(16, min(wanted, self.budget_bytes // (8 + 4 * max(width, 1))))

    @property
    def nbytes(self) -> int:
        """Memory the rings allocated so far."""
        return sum(r.nbytes for r in self._rings.values())

    def _ring(self, source: str) -> _Ring:
        ring = self._rings.get(source)
        if ring is None:
            ring = self._rings[source] = _Ring(self.capacity(source), max(1, self._widths[source]))
        return ring

    def clear(self) -> None:
        """Forget the past (the rings stay allocated)."""
        for ring in self._rings.values():
            ring.write = ring.count = 0
        self.version += 1

    def session_time_s(self, host_time_s: np.ndarray | float) -> np.ndarray:
        return np.asarray(host_time_s, dtype=float) - self.t0_monotonic_s

    # -- feeding (the GUI thread) ----------------------------------------------------------------------------------
    def add_states(self, states: Sequence[Any]) -> None:
        """The robot's states (:class:`devices.servo_chain.ChainState`: position, velocity, current, goal and, while
        a feedback controller plays, its correction; a missing one is NaN), in order."""
        if not states or not self.joint_ids:
            return
        n_j = len(self.joint_ids)
        rows = np.full((len(states), self._widths[ROBOT]), np.nan, dtype=np.float32)
        t = np.empty(len(states))
        for i, state in enumerate(states):
            t[i] = state.host_time_s
            for q, value in enumerate((state.goal_rad, state.position_rad, state.velocity_rad_s, state.current_ma,
                                       state.correction_rad)):
                if value is not None:
                    rows[i, q * n_j:q * n_j + min(n_j, len(value))] = np.asarray(value, dtype=float)[:n_j]
        self._ring(ROBOT).push(self.session_time_s(t), rows)
        self.version += 1

    def add_block(self, block: Any, after_s: float = -math.inf) -> None:
        """A board block (:class:`devices.board.SampleBlock`): the conductance in µS, the line broken (a NaN row)
        before every sample that follows missing frames; samples at or before ``after_s`` (session time) are left
        out (a backfill from the board's recent blocks that overlaps what is held)."""
        n = len(block)
        if n == 0 or not self.channel_names:
            return
        t = self.session_time_s(block.host_time_s)
        values = np.asarray(block.conductance_s, dtype=float)[:, :len(self.channel_names)] * 1e6
        gaps = getattr(block, "gap_before", None)
        gaps = None if gaps is None else np.asarray(gaps, dtype=bool)
        if after_s > -math.inf:
            keep = t > after_s
            if not keep.any():
                return
            t, values = t[keep], values[keep]
            gaps = None if gaps is None else gaps[keep]
        if gaps is not None and np.any(gaps):
            t, values = _with_gap_rows(t, values, gaps)
        self._ring(BOARD).push(t, values.astype(np.float32))
        self.version += 1

    def add_forces(self, host_time_s: np.ndarray, force_n: np.ndarray, status: np.ndarray | None = None) -> None:
        """Estimated forces (N×C, NaN where a sensor has no estimate) and their status codes, at the block's times."""
        n = int(np.asarray(host_time_s).shape[0])
        if n == 0 or not self.channel_names:
            return
        n_c = len(self.channel_names)
        rows = np.full((n, 2 * n_c), np.nan, dtype=np.float32)
        rows[:, :n_c] = np.asarray(force_n, dtype=float)[:, :n_c]
        if status is not None:
            rows[:, n_c:] = np.asarray(status, dtype=float)[:, :n_c]
        self._ring(FORCES).push(self.session_time_s(host_time_s), rows)
        self.version += 1

    def add_health(self, host_time_s: float, flags: np.ndarray) -> None:
        """The sensors' health flags (:class:`models.health.SensorHealth`, one per channel) as of ``host_time_s``:
        kept when they changed, else at most every :data:`HEALTH_ROW_EVERY_S` (the step reaches the present)."""
        if not self.channel_names:
            return
        row = np.asarray(flags, dtype=np.float32)[None, :len(self.channel_names)]
        t = float(self.session_time_s(host_time_s))
        ring = self._ring(HEALTH)
        if ring.count and t - ring.newest_t() < HEALTH_ROW_EVERY_S and np.array_equal(
                ring.v[(ring.write - 1) % ring.capacity], row[0]):
            return
        ring.push(np.array([t]), row)
        self.version += 1

    def add_servo_health(self, host_time_s: float, healths: Sequence[Any]) -> None:
        """Servo health as polled (:class:`devices.servo_chain.ServoHealth`): each servo's hardware error, temperature
        and voltage; a servo not in this poll keeps its previous values."""
        if not healths or not self.joint_ids:
            return
        ring = self._ring(SERVO)
        n_j = len(self.joint_ids)
        row = (ring.v[(ring.write - 1) % ring.capacity].copy() if ring.count
               else np.full(self._widths[SERVO], np.nan, dtype=np.float32))
        for health in healths:
            j = self._joint_index.get(int(health.servo_id))
            if j is None:
                continue
            for q, value in enumerate((health.hardware_error, health.temperature_c, health.voltage_v)):
                row[q * n_j + j] = float(value)
        ring.push(self.session_time_s(np.array([host_time_s])), row[None, :])
        self.version += 1

    # -- reading ---------------------------------------------------------------------------------------------------
    def newest_s(self, keys: Iterable[str] | None = None) -> float:
        """The newest time any source (or the sources of ``keys``) holds; −inf when none has data."""
        sources = self._rings.keys() if keys is None else {self._where[k][0] for k in keys if k in self._where}
        return max((self._rings[s].newest_t() for s in sources if s in self._rings), default=-math.inf)

    def span(self) -> tuple[float, float]:
        if not self._rings:
            return (math.nan, math.nan)
        return (min(r.oldest_t() for r in self._rings.values()), self.newest_s())

    def read(self, key: str, t0_s: float = -math.inf, t1_s: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """(t, v) of ``key`` held for [t0, t1] (one sample either side), undecimated; ``KeyError`` for an unknown
        series."""
        source, column = self._where[key]
        ring = self._rings.get(source)
        if ring is None:
            return np.zeros(0), np.zeros(0)
        t, v = ring.between(t0_s, t1_s, column)
        return t, v.astype(float)

    def window(self, key: str, t0_s: float, t1_s: float, max_points: int) -> tuple[np.ndarray, np.ndarray]:
        t, v = self.read(key, t0_s, t1_s)
        x, y = decimate(t, v, t0_s, t1_s, max_points)
        info = self._info_by_key.get(key)
        return as_steps(x, y) if info is not None and info.steps else (x, y)

    def value_at(self, key: str, t_s: float) -> float:
        t, v = self.read(key, t_s, t_s)
        return value_at(t, v, t_s)


def _with_gap_rows(t_s: np.ndarray, values: np.ndarray, gap_before: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A NaN row just before each sample flagged in ``gap_before``, so the line breaks over missing data."""
    cuts = np.flatnonzero(gap_before)
    gap_t = np.where(cuts > 0, (t_s[np.maximum(cuts - 1, 0)] + t_s[cuts]) / 2, t_s[cuts])
    t = np.insert(t_s, cuts, gap_t)
    v = np.insert(values, cuts, np.nan, axis=0)
    return t, v


# -- plot layouts ---------------------------------------------------------------------------------------------------
LAYOUT_FORMAT = "sensnake-plot-layout"
LAYOUT_VERSION = 1
LAYOUT_SUFFIX = ".plots.json"
TIME, XY = "time", "xy"
PLOT_KINDS = (TIME, XY)
DEFAULT_WINDOW_S = 30.0
WINDOWS_S: tuple[float, ...] = (10.0, 30.0, 60.0, 120.0, 300.0, 600.0)


@dataclass(frozen=True)
class PlotSpec:
    """One plot: ``kind`` ``time`` (series against time, its time axis linked to every other time plot's) or ``xy``
    (the first series on the x axis, the others against it); ``series`` their keys."""

    kind: str = TIME
    series: tuple[str, ...] = ()


@dataclass(frozen=True)
class PlotLayout:
    """What a plot panel shows: its plots, top to bottom, and the live time window (s)."""

    plots: tuple[PlotSpec, ...] = ()
    window_s: float = DEFAULT_WINDOW_S
    source_note: str = field(default="", compare=False)  # where it was read from (for messages), not saved

    def series_keys(self) -> list[str]:
        """Every series shown, once each, in order."""
        seen: dict[str, None] = {}
        for plot in self.plots:
            seen.update(dict.fromkeys(plot.series))
        return list(seen)

    def adding(self, key: str, plot: int = -1, kind: str = TIME) -> PlotLayout:
        """With ``key`` on plot ``plot`` (−1 or past the end: a new plot of ``kind``); unchanged if it is there."""
        plots = list(self.plots)
        if 0 <= plot < len(plots):
            if key in plots[plot].series:
                return self
            plots[plot] = replace(plots[plot], series=(*plots[plot].series, key))
        else:
            plots.append(PlotSpec(kind, (key,)))
        return replace(self, plots=tuple(plots))

    def adding_plot(self, kind: str = TIME) -> PlotLayout:
        """With an empty plot of ``kind`` at the bottom."""
        return replace(self, plots=(*self.plots, PlotSpec(kind)))

    def removing(self, plot: int, key: str | None = None) -> PlotLayout:
        """Without series ``key`` on plot ``plot`` (without the whole plot when ``key`` is None)."""
        if not 0 <= plot < len(self.plots):
            return self
        plots = list(self.plots)
        if key is None:
            del plots[plot]
        else:
            plots[plot] = replace(plots[plot], series=tuple(k for k in plots[plot].series if k != key))
        return replace(self, plots=tuple(plots))

    def to_document(self) -> dict[str, Any]:
        return {"format": LAYOUT_FORMAT, "version": LAYOUT_VERSION, "window_s": self.window_s,
                "plots": [{"kind": p.kind, "series": list(p.series)} for p in self.plots]}

    def to_json(self) -> str:
        return json.dumps(self.to_document(), indent=1) + "\n"


def parse_layout(text: str, source: str = "<layout>") -> PlotLayout:
    """A layout from its JSON text; :class:`PlotLayoutError` naming ``source`` and the key that is wrong. Series a
    reader does not know are kept (another lab's recording may hold them); keys it does not know are ignored."""
    document = parse_json_text(text, source, "plot layout", PlotLayoutError)  # too deep, huge integers: named too
    if not isinstance(document, dict) or document.get("format") != LAYOUT_FORMAT:
        raise PlotLayoutError(f"{source} is not a plot layout (format must be \"{LAYOUT_FORMAT}\")")
    if document.get("version") != LAYOUT_VERSION:
        raise PlotLayoutError(f"{source}: plot layout version {document.get('version')!r}; this program reads "
                              f"version {LAYOUT_VERSION}")
    window = document.get("window_s", DEFAULT_WINDOW_S)
    if isinstance(window, bool) or not isinstance(window, (int, float)) or not 1.0 <= window <= 3600.0:
        raise PlotLayoutError(f"{source}: window_s = {window!r} must be a number of seconds in [1, 3600]")
    plots = document.get("plots")
    if not isinstance(plots, list):
        raise PlotLayoutError(f"{source}: plots must be a list of {{\"kind\", \"series\"}} objects")
    specs = []
    for i, plot in enumerate(plots):
        where = f"{source}: plots[{i}]"
        if not isinstance(plot, dict):
            raise PlotLayoutError(f"{where} must be an object with \"kind\" and \"series\"")
        kind = plot.get("kind", TIME)
        if kind not in PLOT_KINDS:
            raise PlotLayoutError(f"{where}.kind = {kind!r} must be one of {', '.join(PLOT_KINDS)}")
        series = plot.get("series", [])
        if not isinstance(series, list) or not all(isinstance(k, str) and k for k in series):
            raise PlotLayoutError(f"{where}.series must be a list of series names (such as \"robot/J5/current_mA\")")
        specs.append(PlotSpec(kind, tuple(dict.fromkeys(series))))
    return PlotLayout(tuple(specs), float(window), source_note=source)


def read_layout(path: str | os.PathLike[str]) -> PlotLayout:
    """The layout saved at ``path``; ``OSError`` when it cannot be read, :class:`PlotLayoutError` when it is not
    one."""
    path = check_input(Path(path))
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise PlotLayoutError(f"{path} is not a plot layout (not UTF-8 text)") from None
    return parse_layout(text, str(path))


def write_layout(layout: PlotLayout, path: str | os.PathLike[str], replace_existing: bool = False) -> Path:
    """Save ``layout`` at ``path`` (all or nothing). An existing file is never written over unless
    ``replace_existing`` (the user chose to): :class:`FileExistsError` naming it; a folder, device or link loop
    there is refused (:class:`app.core.errors.OutputPathError`). Returns the path written."""
    path = Path(path)
    if not replace_existing and (path.exists() or path.is_symlink()):
        raise FileExistsError(17, f"{path} exists: a layout is saved over a file only when you choose to", str(path))
    text = layout.to_json()
    write_atomically(path, lambda handle: handle.write(text))
    return path


def layout_beside(recording_path: str | os.PathLike[str]) -> Path:
    """Where a recording's layout goes: ``RUN.h5`` → ``RUN.plots.json`` beside it."""
    path = Path(recording_path)
    return path.with_name(path.stem + LAYOUT_SUFFIX)


def free_path(path: str | os.PathLike[str]) -> Path:
    """``path`` if nothing is there, else the first of ``NAME-2.plots.json``, ``NAME-3…`` that is free."""
    path = Path(path)
    if not (path.exists() or path.is_symlink()):
        return path
    name = path.name
    stem, suffix = (name[: -len(LAYOUT_SUFFIX)], LAYOUT_SUFFIX) if name.endswith(LAYOUT_SUFFIX) else (
        path.stem, path.suffix)
    for k in range(2, 10_000):
        candidate = path.with_name(f"{stem}-{k}{suffix}")
        if not (candidate.exists() or candidate.is_symlink()):
            return candidate
    raise FileExistsError(17, f"no free name beside {path}", str(path))
