"""The simulated force-sensor board, emulated at the wire (SPEC §4).

:class:`VirtualBoard` is a :class:`devices.sim.transport.SimEndpoint`. It samples every sensor at
``board.rate_hz`` on the :class:`SimClock`, turns each sensor's force into conductance with the paper's sensor physics
(standard linear solid creep, Eq. 2, and the resistance–strain law with the contact term, Eq. 3), runs the readout
circuit backwards to 12-bit ADC counts with seeded noise, and streams SPEC §4 frames whose bytes become readable only
when baud-rate time says they have arrived. A host that opens the port mid-stream sees the tail of a frame first,
as on the real board.

Faults a test or the GUI can inject from Python (any thread): garbage bytes, CRC errors, dropped frames, a
flat-lined sensor, a loose/noisy sensor (the paper's sensor 10), a saturated sensor, a pulled cable and a wrong
channel count; a host opening the port at another baud rate than ``board.baud`` reads noise. Ground truth (the
conductance before noise and quantisation) of recent frames is kept for tests.

Cost: the per-frame work is a handful of vector operations over the channels, so 36 channels at 30 Hz is
negligible and 1024 channels at 100 Hz is a few per cent of a core (note that 1024 channels at 100 Hz need more
than 2 Mbaud on the wire: 2064-byte frames × 10 bits × 100 Hz ≈ 2.06 Mbit/s).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import serial

from devices.board_wire import FLAG_SATURATED, counts_from_conductance, encode_frame
from devices.config import BoardConfig
from devices.sim.clock import SimClock
from models.physics import PhysicsConstants, conductance_from_strain
from models.sls import SLSParams

BITS_PER_BYTE = 10  # start + 8 data + stop
# Frames older than this (wall seconds: what the OS's serial buffer holds while the host is busy) that nobody can
# receive are skipped, not generated. On an accelerated clock that is speed × as many simulated seconds.
CATCH_UP_LIMIT_S = 1.0
TRUTH_FRAMES = 512

# Sensor physics: the paper's Sec. IV models, with the constants of models.physics (the same code the estimators
# invert). Each sensor's SLS parameters and area vary by a few per cent (seeded); the resistance–strain constants
# are shared, as a calibration file stores them (SPEC §3.3).
AREA_M2 = 0.0014
E0_PA = 2.0e6
E1_PA = 4.0e6
TAU_S = 100.0  # retardation time mu1/E1: the paper's creep is ~10² s
PARAM_SPREAD = 0.05
CALIBRATION_FORCES_N = (1.75, 3.0, 4.0, 5.25)  # the paper's calibration forces, for the linear model


@dataclass
class SensorBank:
    """S sensors with SLS creep (Eq. 2) and the resistance–strain law (Eq. 3); state carried between calls.

    Strain is split as ``ε = σ/E0 + q`` with ``τ·q̇ + q = σ/E1``; the force is held between samples, the
    ``interp="hold"`` rule of :mod:`models.sls` (exact for non-uniform steps, O(1) per sample). ``F = 0`` reads 0 S.
    """

    params: SLSParams
    area_m2: np.ndarray
    physics: PhysicsConstants
    q: np.ndarray  # creep part of the strain, (S,)
    t_s: float | None = None
    sigma_pa: np.ndarray | None = None  # stress held since t_s

    @classmethod
    def create(cls, n_sensors: int, rng: np.random.Generator, physics: PhysicsConstants | None = None, *,
               e0_pa: float = E0_PA, e1_pa: float = E1_PA, tau_s: float = TAU_S, area_m2: float = AREA_M2,
               spread: float = PARAM_SPREAD) -> SensorBank:
        """``n_sensors`` sensors whose E0, E1, τ and area are the given values times ``N(1, spread)`` each, clipped
        to ±4 s.d. (seeded by ``rng``)."""
        def vary(value: float) -> np.ndarray:
            return value * np.clip(rng.normal(1.0, spread, n_sensors), 1.0 - 4 * spread, 1.0 + 4 * spread)

        e1 = vary(e1_pa)
        params = SLSParams(E0_Pa=vary(e0_pa), E1_Pa=e1, mu1_Pa_s=e1 * vary(tau_s))
        return cls(params=params, area_m2=vary(area_m2), physics=physics or PhysicsConstants(),
                   q=np.zeros(n_sensors))

    def forget_creep(self, index: int) -> None:
        """Sensor ``index`` has rested long enough to have recovered: its creep strain is zero again."""
        self.q[index] = 0.0

    def step(self, t_s: float, force_n: np.ndarray) -> np.ndarray:
        """Advance to ``t_s`` (force held since the previous call), apply ``force_n`` (S,), return conductance (S,)."""
        force = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        sigma = force / self.area_m2
        params = self.params
        if self.t_s is not None and self.sigma_pa is not None and t_s > self.t_s:
            alpha = np.exp(-(t_s - self.t_s) / params.tau_s)
            self.q = alpha * self.q + (1.0 - alpha) * self.sigma_pa / params.E1_Pa
        self.t_s = t_s
        self.sigma_pa = sigma
        strain = np.clip(sigma / params.E0_Pa + self.q, 0.0, 0.999)  # ε → 1 is outside the model
        return conductance_from_strain(strain, force, self.physics)

    def calibration(self, names: tuple[str, ...]) -> dict:
        """The sensors' true parameters as a SPEC §3.3 calibration document (``linear``: the steady state fitted
        at the paper's calibration forces)."""
        forces = np.array(CALIBRATION_FORCES_N)
        sensors = {}
        for k, name in enumerate(names):
            one = self.params.sensor(k)
            steady_strain = forces / self.area_m2[k] / one.b
            steady = conductance_from_strain(steady_strain, forces, self.physics)
            slope, intercept = np.polyfit(forces, steady, 1)
            sensors[name] = {"area_m2": float(self.area_m2[k]),
                             "linear": {"m_S_per_N": float(slope), "d_S": float(intercept)},
                             "sls": {key: float(value) for key, value in one.to_dict().items()}}
        return {"format": "sensnake-calibration", "version": 1, "physics": self.physics.to_dict(),
                "sensors": sensors}


@dataclass
class _LooseSensor:
    noise_counts: float
    dropout_prob: float


class VirtualBoard:
    """A simulated board streaming SPEC §4 frames; see the module docstring.

    ``force_source(t_s) -> (C,)`` gives the force in newtons on each configured channel at simulated time ``t_s``
    (e.g. :meth:`devices.sim.contact.ContactModel.forces_n`); ``None`` means no load. The SimEndpoint methods are
    called from the thread that owns the port; the fault methods from any thread.
    """

    def __init__(self, board: BoardConfig, clock: SimClock, force_source: Callable[[float], np.ndarray] | None = None,
                 seed: int = 0, noise_counts: float = 0.5, truth_frames: int = TRUTH_FRAMES,
                 board_clock_offset_us: int = 0, sensor_nominal: dict[str, float] | None = None) -> None:
        self.board = board
        self.board_clock_offset_us = int(board_clock_offset_us)  # boards power up at any time: t_us wraps
        self.clock = clock
        self.force_source = force_source
        self.noise_counts = float(noise_counts)
        self._rng = np.random.default_rng(seed)
        # sensor_nominal: keyword arguments of SensorBank.create (e0_pa, e1_pa, tau_s, area_m2, spread)
        nominal = sensor_nominal or {}
        self.sensors = SensorBank.create(board.n_channels, self._rng, e0_pa=nominal.get("e0_pa", E0_PA),
                                         e1_pa=nominal.get("e1_pa", E1_PA), tau_s=nominal.get("tau_s", TAU_S),
                                         area_m2=nominal.get("area_m2", AREA_M2),
                                         spread=nominal.get("spread", PARAM_SPREAD))
        self._lock = threading.RLock()
        self._period_s = 1.0 / board.rate_hz
        self._next_index = 0  # frame index k, sampled at k·period; seq = k mod 2³²
        self._host_open = False
        self._host_baud = board.baud
        self._deliver_after_s = math.inf  # bytes arriving before this sim time are lost (host not listening)
        self._wire_free_s = 0.0
        self._segments: deque[tuple[float, bytes]] = deque()  # (first byte's start time, bytes), in wire order
        self._segment_offset = 0  # bytes of the head segment already delivered
        # faults
        self._unplugged = False
        self._garbage = bytearray()
        self._corrupt_next = 0
        self._drop_next = 0
        self._flat: dict[int, int | None] = {}
        self._loose: dict[int, _LooseSensor] = {}
        self._saturated: set[int] = set()
        self._channel_count: int | None = None
        unloaded = np.rint(counts_from_conductance(np.zeros(board.n_channels), board))
        self._last_counts = np.clip(unloaded, 0, board.adc_max_counts).astype(np.uint16)
        # ground truth of recent frames, by frame index
        self._truth_frames = truth_frames
        self._truth_conductance = np.zeros((truth_frames, board.n_channels))
        self._truth_force = np.zeros((truth_frames, board.n_channels))
        self._truth_index = np.full(truth_frames, -1, dtype=np.int64)
        self.frames_sent = 0
        self.frames_lost = 0  # sampled while nobody could receive them (port closed, cable pulled, dropped)
        self.bytes_sent = 0

    # -- SimEndpoint -----------------------------------------------------------------------------------------
    def host_opened(self, baud: int) -> None:
        with self._lock:
            if self._unplugged:
                raise serial.SerialException("board cable unplugged (simulated): no such device")
            if not self._host_open:
                self._deliver_after_s = self.clock.now()
            self._host_open = True
            self._host_baud = int(baud)

    def host_closed(self) -> None:
        with self._lock:
            self._host_open = False
            self._deliver_after_s = math.inf
            self._segments.clear()
            self._segment_offset = 0

    def host_write(self, data: bytes, now_s: float) -> None:
        """The board ignores what the host sends (SPEC §4: board → host only)."""
        with self._lock:
            if self._unplugged:
                raise serial.SerialException("board cable unplugged (simulated)")

    def host_read(self, now_s: float) -> bytes:
        sim_now = self.clock.sim_from_wall(now_s)
        with self._lock:
            if self._unplugged:
                raise serial.SerialException("board cable unplugged (simulated)")
            self._emit_until(sim_now)
            return self._deliver_until(sim_now)

    # -- faults (any thread) ---------------------------------------------------------------------------------
    def inject_garbage(self, data: bytes | int) -> None:
        """Send ``data`` (or that many seeded random bytes) before the next frame."""
        with self._lock:
            if isinstance(data, int):
                data = self._rng.integers(0, 256, data, dtype=np.uint8).tobytes()
            self._garbage += data

    def corrupt_frames(self, n: int = 1) -> None:
        """Flip one bit in each of the next ``n`` frames (the host must see CRC errors)."""
        with self._lock:
            self._corrupt_next += n

    def drop_frames(self, n: int = 1) -> None:
        """Skip sending the next ``n`` frames (``seq`` still advances: the host sees a gap)."""
        with self._lock:
            self._drop_next += n

    def set_flatline(self, channel: int, counts: int | None = None) -> None:
        """Freeze a channel at ``counts`` (default: its current reading)."""
        with self._lock:
            self._flat[channel] = counts

    def set_loose(self, channel: int, noise_counts: float = 250.0, dropout_prob: float = 0.05) -> None:
        """A loose connection: large noise and random drop-outs to an open circuit (the paper's sensor 10)."""
        with self._lock:
            self._loose[channel] = _LooseSensor(noise_counts, dropout_prob)

    def set_saturated(self, channel: int, saturated: bool = True) -> None:
        """Make a channel read 0 counts (beyond the readout's range)."""
        with self._lock:
            if saturated:
                self._saturated.add(channel)
            else:
                self._saturated.discard(channel)

    def set_channel_count(self, n: int | None) -> None:
        """Send ``n`` channels per frame instead of the configured count (``None`` restores it)."""
        with self._lock:
            self._channel_count = n

    def unplug(self) -> None:
        """Pull the cable: host reads raise ``serial.SerialException`` until :meth:`replug`."""
        with self._lock:
            self._unplugged = True
            self._segments.clear()
            self._segment_offset = 0

    def replug(self) -> None:
        with self._lock:
            self._unplugged = False
            # Whatever was on the wire while unplugged is gone; the host re-syncs on the next frame.
            self._deliver_after_s = self.clock.now() if self._host_open else math.inf

    @property
    def unplugged(self) -> bool:
        return self._unplugged

    def clear_faults(self) -> None:
        with self._lock:
            self._garbage.clear()
            self._corrupt_next = self._drop_next = 0
            self._flat.clear()
            self._loose.clear()
            self._saturated.clear()
            self._channel_count = None

    # -- ground truth (any thread) ---------------------------------------------------------------------------
    def ground_truth_calibration(self) -> dict:
        """The simulated sensors' true parameters as a SPEC §3.3 calibration document (for the sim lab's demos)."""
        return self.sensors.calibration(self.board.channel_names)

    def true_conductance_s(self, seq: np.ndarray) -> np.ndarray:
        """Conductance (N×C, siemens) before noise and quantisation of the frames with these ``seq`` numbers.

        Only the last ``truth_frames`` frames are kept; older ones raise ``KeyError``.
        """
        return self._truth(seq, self._truth_conductance)

    def true_force_n(self, seq: np.ndarray) -> np.ndarray:
        """The force (N×C, newtons) each frame was computed from."""
        return self._truth(seq, self._truth_force)

    def _truth(self, seq: np.ndarray, table: np.ndarray) -> np.ndarray:
        with self._lock:
            seq = np.asarray(seq, dtype=np.int64)
            base = self._next_index - (self._next_index % (1 << 32))
            index = base + seq
            index = np.where(index >= self._next_index, index - (1 << 32), index)
            slots = index % self._truth_frames
            if not np.array_equal(self._truth_index[slots], index):
                raise KeyError("ground truth for these frames is no longer kept")
            return table[slots].copy()

    def next_delivery_wall_s(self) -> float:
        """Wall time (``time.monotonic()``) at which the bytes on the wire now, or else the next frame, will have
        fully arrived: a server forwarding the board onto a real port (the lab's own process) sleeps until then.
        A time already past means bytes wait (or nobody is listening): such a server polls at its own pace."""
        with self._lock:
            if self._segments:
                start, payload = self._segments[0]
                end_s = start + len(payload) * self._byte_time_s()
            else:
                end_s = self._next_index * self._period_s + self._frame_airtime_s()
            return self.clock.wall_from_sim(end_s)

    # -- emission --------------------------------------------------------------------------------------------
    def _byte_time_s(self) -> float:
        return BITS_PER_BYTE / self.board.baud  # the board's UART sets the pace, whatever the host expects

    def _emit_until(self, sim_now: float) -> None:
        last_due = math.floor(sim_now / self._period_s)
        if last_due < self._next_index:
            return
        receivable_from = self._deliver_after_s - self._frame_airtime_s()
        limit_s = CATCH_UP_LIMIT_S * max(1.0, self.clock.speed)
        skip_to = math.floor((min(sim_now - limit_s, receivable_from)) / self._period_s)
        if skip_to > self._next_index:
            # Nobody can receive these frames: advance the sensors in one exact step instead of frame by frame.
            self.frames_lost += skip_to - self._next_index
            self._sample(skip_to - 1)
            self._next_index = skip_to
        for index in range(self._next_index, last_due + 1):
            self._emit_frame(index)
        self._next_index = last_due + 1

    def _frame_airtime_s(self) -> float:
        n = self._channel_count or self.board.n_channels
        return (16 + 2 * n) * self._byte_time_s()

    def _sample(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        t_s = index * self._period_s
        if self.force_source is None:
            force = np.zeros(self.board.n_channels)
        else:
            force = np.asarray(self.force_source(t_s), dtype=np.float64)
        conductance = self.sensors.step(t_s, force)
        slot = index % self._truth_frames
        self._truth_conductance[slot] = conductance
        self._truth_force[slot] = force
        self._truth_index[slot] = index
        return force, conductance

    def _emit_frame(self, index: int) -> None:
        _, conductance = self._sample(index)
        t_s = index * self._period_s
        if self._drop_next > 0:
            self._drop_next -= 1
            self.frames_lost += 1
            return
        counts = self._counts(conductance)
        t_us = int(round(t_s * 1e6)) + self.board_clock_offset_us
        frame = bytearray(encode_frame(index, t_us, counts, flags=self._flags(counts)))
        if self._corrupt_next > 0:
            self._corrupt_next -= 1
            position = int(self._rng.integers(2, len(frame)))
            frame[position] ^= 1 << int(self._rng.integers(0, 8))
        payload = bytes(self._garbage) + bytes(frame)
        self._garbage.clear()
        start = max(t_s, self._wire_free_s)
        if start > t_s + self._period_s:
            # The UART is a whole frame behind (baud too low for rate × channels): the board drops the frame.
            self.frames_lost += 1
            return
        self._wire_free_s = start + len(payload) * self._byte_time_s()
        self._segments.append((start, payload))
        self.frames_sent += 1

    @staticmethod
    def _flags(counts: np.ndarray) -> int:
        return FLAG_SATURATED if bool((counts == 0).any()) else 0

    def _counts(self, conductance: np.ndarray) -> np.ndarray:
        raw = counts_from_conductance(conductance, self.board)
        if self.noise_counts > 0:
            raw = raw + self._rng.normal(0.0, self.noise_counts, raw.shape)
        for channel, loose in self._loose.items():
            if channel < raw.size:
                raw[channel] += self._rng.normal(0.0, loose.noise_counts)
                if self._rng.random() < loose.dropout_prob:
                    raw[channel] = self.board.adc_max_counts
        counts = np.clip(np.rint(raw), 0, self.board.adc_max_counts).astype(np.uint16)
        for channel in self._saturated:
            if channel < counts.size:
                counts[channel] = 0
        for channel, value in self._flat.items():
            if channel < counts.size:
                if value is None:
                    value = int(self._last_counts[channel])
                    self._flat[channel] = value
                counts[channel] = value
        self._last_counts = counts
        if self._channel_count is not None and self._channel_count != counts.size:
            n = self._channel_count
            unloaded = int(round(float(counts_from_conductance(np.zeros(1), self.board)[0])))
            counts = np.concatenate([counts, np.full(max(0, n - counts.size), unloaded, np.uint16)])[:n]
        return counts

    def _deliver_until(self, sim_now: float) -> bytes:
        if not self._host_open:
            return b""
        byte_time = self._byte_time_s()
        out = bytearray()
        while self._segments:
            start, payload = self._segments[0]
            arrived = min(len(payload), int((sim_now - start) / byte_time))
            if arrived <= self._segment_offset:
                break
            first = self._segment_offset
            lost_upto = math.floor((self._deliver_after_s - start) / byte_time)
            if lost_upto > first:
                # The host was not listening when these bytes went by.
                first = min(arrived, lost_upto)
            out += payload[first:arrived]
            if arrived < len(payload):
                self._segment_offset = arrived
                break
            self._segments.popleft()
            self._segment_offset = 0
        self.bytes_sent += len(out)
        if self._host_baud != self.board.baud:
            # A UART at the wrong rate reads framing noise, not the board's bytes.
            return self._rng.integers(0, 256, len(out), dtype=np.uint8).tobytes()
        return bytes(out)
