"""The one sample-validation rule in front of every conductance → force path.

``sensnake estimate``, the live Forces pipeline (``app.core.forces_pipeline``) and the estimators of
:mod:`models.estimators` all pass their samples through a :class:`SampleValidator` before the SLS recursion or the
linear inverse sees them. Per sample (S, siemens) the rule is, first match wins:

=====================  ======================================================  ========================================
code (ForceStatus)     condition                                               what happens
=====================  ======================================================  ========================================
``NAN_INPUT``          not finite (NaN, ±inf, an empty CSV cell)               rejected: a gap, force NaN
``NEGATIVE_CONDUCTANCE`` ``C < 0`` (a reading cannot be negative)               rejected: a gap, force NaN
``ABOVE_CEILING``      ``C > 1/R_C`` (above what the readout can report; a     rejected: a gap, force NaN
                       1e300 S glitch lands here)
``READOUT_SATURATED``  ``C = 1/R_C`` (counts = 0, or the board's saturation    kept at the ceiling: the force is a
                       bit)                                                    lower bound, "saturated: force ≥ X N"
``FLAT``               the same non-zero reading, bit for bit, for longer      rejected: a gap, force NaN (no force is
                       than the sensor's own history makes likely (below)     claimed for a frozen line)
=====================  ======================================================  ========================================

After the inverse, a force below the smallest (or above the largest) calibrated force is flagged ``EXTRAPOLATED``
by the estimators (value kept).

**How the creep state crosses a gap.** A rejected sample reaches the recursion as NaN: its output is NaN, and the
creep state keeps evolving over the gap's elapsed time under a zero-order hold of the last accepted stress (the
exact "hold" update with the gap's length). Time therefore passes: after a gap the creep strain is what it would be
had the force stayed at its last good value. A single rejected glitch thus changes the state by no more than one
sample of that hold; it never feeds an impossible value into the state.

**When a repeated reading is a stuck channel.** A healthy sensor's reading changes from one sample to the next with a
rate ``p`` of its own (readout noise against the ADC step: ~0.5 at the simulated board's 0.5-count noise, lower for a
quieter sensor). A healthy sensor repeats its present value with probability at most ``sqrt(1 − p)`` per sample (the
most frequent of values at frequencies ``f_i`` has ``f_1² ≤ Σ f_i² = 1 − p``; a two-level sensor on its usual level
reaches it), so a run of ``L`` identical samples has probability at most ``(1 − p)^(L/2)``; the run is called flat once
that falls below ``flat_false_alarm`` (1e-6): ``L = 2 ln(1e-6) / ln(1 − p)`` samples, with ``p`` a low
estimate (3 σ below the count) of the rate seen on the sensor's samples before the run began — never before
``flat_min_s`` (1 s), never later than ``flat_max_s`` (60 s). A sensor with fewer than ``FLAT_MIN_HISTORY``
comparisons before the run, or none of them changes (stuck from the start), waits ``flat_s`` (10 s). Measured at 30
Hz on a resting sensor after 20 s of history (tests/models/test_validation.py, benchmarks/bench_flat_line.py): at the
simulated board's 0.5-count noise a stuck channel is flagged 1.0 s after it froze, at 0.3 counts ~1.3 s; a healthy
sensor at 0.15–0.5 counts is never flagged in an hour.

A validator carries the flat-line run of each sensor across blocks (a stream split into blocks is judged exactly
like the whole record). Not thread-safe: use it from the thread that feeds the estimator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.sls import ForceStatus

# The default readout of SPEC §4 (R_C = 900 Ω): counts = 0 reads 1/R_C.
DEFAULT_R_C_OHM = 900.0
DEFAULT_FLAT_S = 10.0  # the longest a repeated reading is trusted (a sensor with no history, or a very quiet one)
DEFAULT_FLAT_MIN_S = 1.0  # the shortest run ever called flat
DEFAULT_FLAT_FALSE_ALARM = 1e-6  # the chance a healthy sensor repeats itself that long (at most; module docstring)
FLAT_MIN_HISTORY = 30  # comparisons before a run needed to trust the sensor's own change rate
# A reading within this relative distance of the ceiling is the ceiling (the CSV's %.17g round trip, V arithmetic).
_CEILING_REL = 1e-9

REJECTED = (ForceStatus.NAN_INPUT, ForceStatus.NEGATIVE_CONDUCTANCE, ForceStatus.ABOVE_CEILING, ForceStatus.FLAT)


@dataclass(frozen=True)
class ValidationRule:
    """``ceiling_s``: the readout's largest reading 1/R_C in S (None: no readout limit known, only the other checks
    apply); ``flat_s``: a non-zero reading unchanged for this many seconds is flat-lined (≤ 0 turns it off)."""

    ceiling_s: float | None = 1.0 / DEFAULT_R_C_OHM
    flat_s: float = DEFAULT_FLAT_S
    flat_min_s: float = DEFAULT_FLAT_MIN_S
    flat_max_s: float = 60.0  # a reading repeated this long is stuck, however quiet the sensor was
    flat_false_alarm: float = DEFAULT_FLAT_FALSE_ALARM

    @classmethod
    def for_readout(cls, r_c_ohm: float, flat_s: float = DEFAULT_FLAT_S) -> ValidationRule:
        if not (np.isfinite(r_c_ohm) and r_c_ohm > 0):
            raise ValueError(f"readout resistor R_C must be a positive number of ohms, got {r_c_ohm!r}")
        return cls(ceiling_s=1.0 / r_c_ohm, flat_s=flat_s)


@dataclass(frozen=True)
class CheckedBlock:
    """``conductance_s`` (N, S): the input with every rejected sample replaced by NaN and saturated ones set to the
    ceiling; ``status`` (N, S) int8 :class:`ForceStatus` codes (0 where the sample passed)."""

    conductance_s: np.ndarray
    status: np.ndarray


class SampleValidator:
    """Applies a :class:`ValidationRule` to blocks of ``n_sensors`` columns, carrying flat-line runs across blocks."""

    def __init__(self, n_sensors: int, rule: ValidationRule | None = None) -> None:
        if n_sensors < 1:
            raise ValueError(f"n_sensors must be ≥ 1, got {n_sensors}")
        self.n_sensors = int(n_sensors)
        self.rule = rule or ValidationRule()
        self.reset()

    def reset(self) -> None:
        """Forget the flat-line runs and the sensors' change rates (a new record, or after the clock restarted)."""
        self._last_value = np.full(self.n_sensors, np.nan)
        self._run_start_s = np.full(self.n_sensors, np.nan)
        self._run_length = np.zeros(self.n_sensors, dtype=np.int64)  # samples in the current run
        self._run_needs = np.full(self.n_sensors, np.inf)  # samples the current run needs to be flat
        self._changes = np.zeros(self.n_sensors, dtype=np.int64)  # sample-to-sample changes seen
        self._compares = np.zeros(self.n_sensors, dtype=np.int64)  # sample-to-sample comparisons made

    def check(self, t_s: np.ndarray, conductance_s: np.ndarray, saturated: np.ndarray | None = None) -> CheckedBlock:
        """Validate a block: ``t_s`` (N,) s, ``conductance_s`` (N, S) S, optional ``saturated`` (N, S) bool from the
        board (counts = 0). Timestamps are assumed already checked (finite, not decreasing)."""
        t = np.asarray(t_s, dtype=np.float64)
        cond = np.array(conductance_s, dtype=np.float64, copy=True)
        if cond.ndim == 1:
            cond = cond[:, None]
        if cond.shape != (t.size, self.n_sensors):
            raise ValueError(f"expected conductance ({t.size}, {self.n_sensors}), got {cond.shape}")
        status = np.zeros(cond.shape, dtype=np.int8)
        if t.size == 0:
            return CheckedBlock(cond, status)
        ceiling = self.rule.ceiling_s
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(cond)
            status[~finite] = ForceStatus.NAN_INPUT
            status[finite & (cond < 0.0)] = ForceStatus.NEGATIVE_CONDUCTANCE
            if ceiling is not None:
                at_ceiling = finite & (np.abs(cond - ceiling) <= _CEILING_REL * ceiling)
                status[finite & (cond > ceiling) & ~at_ceiling] = ForceStatus.ABOVE_CEILING
                status[at_ceiling] = ForceStatus.READOUT_SATURATED
                cond[at_ceiling] = ceiling
            if saturated is not None:
                mask = np.asarray(saturated, dtype=bool)
                if mask.ndim == 1:
                    mask = mask[:, None]
                if mask.shape != cond.shape:
                    raise ValueError(f"saturated mask has shape {mask.shape}, the conductance block {cond.shape}")
                status[mask & (status == 0)] = ForceStatus.READOUT_SATURATED
        if self.rule.flat_s > 0:
            flat = self._flat(t, cond) & (status == 0)
            status[flat] = ForceStatus.FLAT
        rejected = np.isin(status, REJECTED)
        cond[rejected] = np.nan
        return CheckedBlock(cond, status)

    def _flat(self, t: np.ndarray, cond: np.ndarray) -> np.ndarray:
        """Samples whose non-zero reading has been identical for longer than the sensor's history makes likely
        (module docstring), and at least ``flat_min_s``, or for ``flat_s`` whatever the history."""
        rule = self.rule
        n, _s = cond.shape
        rows = np.arange(n)[:, None]
        previous = np.vstack([self._last_value[None, :], cond[:-1]])
        changed = ~(cond == previous)  # NaN never equals: a gap ends a run
        compared = np.isfinite(cond) & np.isfinite(previous)
        changes = self._changes + np.cumsum(changed & compared, axis=0)
        compares = self._compares + np.cumsum(compared, axis=0)
        index = np.where(changed, rows, -1)
        np.maximum.accumulate(index, axis=0, out=index)
        started = index >= 0
        at = np.maximum(index, 0)
        start_s = np.where(started, t[at], self._run_start_s[None, :])
        length = np.where(started, rows - index + 1, self._run_length[None, :] + rows + 1)
        # The run's threshold in samples, from the change rate before it began (carried for a run from earlier).
        cols = np.arange(cond.shape[1])[None, :]
        before_changes = np.take_along_axis(changes, at, axis=0) - (changed & compared)[at, cols]
        before_compares = np.take_along_axis(compares, at, axis=0) - compared[at, cols]
        needs = np.where(started, self._needs(before_changes, before_compares), self._run_needs[None, :])
        elapsed = t[:, None] - start_s
        # Without a usable history (needs = inf) flat_s decides; with one, the history does (a quiet sensor can
        # legitimately repeat itself longer than flat_s), up to flat_max_s.
        judged = np.isfinite(needs)
        flat = (np.where(judged, (length >= needs) & (elapsed >= rule.flat_min_s), elapsed >= rule.flat_s)
                | (elapsed >= rule.flat_max_s)) & (cond != 0.0)
        self._last_value = cond[-1].copy()
        self._run_start_s = start_s[-1].copy()
        self._run_length = length[-1].astype(np.int64)
        self._run_needs = needs[-1].copy()
        self._changes = changes[-1].astype(np.int64)
        self._compares = compares[-1].astype(np.int64)
        return flat

    def _needs(self, changes: np.ndarray, compares: np.ndarray) -> np.ndarray:
        """Run length (samples) past which a healthy sensor with this history repeats itself with probability below
        ``flat_false_alarm``; inf without enough history (then ``flat_s`` decides)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            # A low estimate of the rate (3 σ of a count below what was seen): a short or lucky history must not make
            # a quiet sensor look lively, and a flat run of it look unlikely.
            low = np.maximum(changes - 3.0 * np.sqrt(changes), 0.0)
            p = np.where(compares > 0, low / np.maximum(compares, 1), 0.0)
            # The chance to repeat the current value: at most sqrt(1 − p) whatever the noise's shape (with values at
            # frequencies f_i, p = 1 − Σ f_i², so the most frequent value's f_1 ≤ sqrt(1 − p)); a two-level sensor
            # sitting on its usual level reaches it.
            stay = 0.5 * np.log1p(-np.minimum(p, 1.0 - 1e-12))  # ln sqrt(1 − p) < 0
            needs = np.where(p > 0, np.log(self.rule.flat_false_alarm) / stay, np.inf)
        return np.where(compares >= FLAT_MIN_HISTORY, np.ceil(needs), np.inf)


def saturated_lower_bounds(force_n: np.ndarray, status: np.ndarray) -> np.ndarray:
    """Per sensor (S,), the smallest force estimated at a saturated reading (NaN where none): the force was at least
    this whenever the readout saturated."""
    sat = status == ForceStatus.READOUT_SATURATED
    values = np.where(sat & np.isfinite(force_n), force_n, np.inf)
    low = values.min(axis=0) if values.size else np.full(status.shape[1], np.inf)
    return np.where(np.isfinite(low), low, np.nan)


def summarise(names: list[str] | tuple[str, ...], force_n: np.ndarray, status: np.ndarray,
              force_range_n: list[tuple[float, float] | None] | None = None) -> list[str]:
    """One line per sensor with any flag: '<name>: 3 rejected (ABOVE_CEILING 2, NEGATIVE_CONDUCTANCE 1), 12
    saturated: force ≥ 5.1 N, 40 extrapolated (calibrated 1.75–5.25 N), …'. Empty when every sample is OK."""
    lines = []
    bounds = saturated_lower_bounds(force_n, status)
    for j, name in enumerate(names):
        column = status[:, j]
        if not np.any((column != 0) & (column != ForceStatus.OPEN_CIRCUIT)):
            continue
        parts = []
        rejected = {ForceStatus(code).name: int(np.sum(column == code)) for code in REJECTED}
        rejected = {key: count for key, count in rejected.items() if count}
        if rejected:
            detail = ", ".join(f"{key} {count}" for key, count in rejected.items())
            parts.append(f"{sum(rejected.values())} sample(s) rejected, force NaN ({detail})")
        n_sat = int(np.sum(column == ForceStatus.READOUT_SATURATED))
        if n_sat:
            parts.append(f"{n_sat} saturated: force ≥ {bounds[j]:.3g} N")
        extrapolated = column == ForceStatus.EXTRAPOLATED
        if extrapolated.any():
            values = force_n[extrapolated, j]
            span = force_range_n[j] if force_range_n else None
            where = f" outside the calibrated range {span[0]:g}–{span[1]:g} N" if span else ""
            parts.append(f"{int(extrapolated.sum())} extrapolated (forces {values.min():.3g}–{values.max():.3g} N"
                         f"{where})")
        # OPEN_CIRCUIT is a correct 0 N (no contact): listed, but never the reason for a line of its own.
        for code in (ForceStatus.OPEN_CIRCUIT, ForceStatus.BELOW_BASELINE, ForceStatus.SATURATED,
                     ForceStatus.NOT_CONVERGED):
            count = int(np.sum(column == code))
            if count:
                parts.append(f"{count} {code.name}")
        lines.append(f"{name}: " + ", ".join(parts))
    return lines
