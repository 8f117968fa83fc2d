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
``OPEN_UNDER_LOAD``    0 S straight after a clear load (below)                 rejected: a gap, force NaN
``UNCHANGED``          identical for ``flat_max_s`` where the history cannot   kept, flagged
                       judge (below)
=====================  ======================================================  ========================================

After the inverse, a force below the smallest (or above the largest) calibrated force is flagged ``EXTRAPOLATED``
by the estimators (value kept).

**How the creep state crosses a gap.** A rejected sample reaches the recursion as NaN: its output is NaN, and the
creep state keeps evolving over the gap's elapsed time under a zero-order hold of the last accepted stress (the
exact "hold" update with the gap's length). Time therefore passes: after a gap the creep strain is what it would be
had the force stayed at its last good value. A single rejected glitch thus changes the state by no more than one
sample of that hold; it never feeds an impossible value into the state.

**When a repeated reading is a stuck channel.** Two pieces of the sensor's recent history say how soon a healthy
reading must change: its noise — the rate ``p`` at which it changes from sample to sample (a healthy sensor repeats
its present value with probability at most ``sqrt(1 − p)`` per sample: the most frequent of values at frequencies
``f_i`` has ``f_1² ≤ Σ f_i² = 1 − p``), so a run of ``L`` identical samples is unlikely below ``flat_false_alarm``
(1e-6) once ``(1 − p)^(L/2)`` is, ``p`` a low estimate (3 σ of the count below) weighted towards the last
:data:`HISTORY_COMPARISONS` comparisons — and its trend (a creep after a load moves the level by a steady number of
ADC steps: :data:`TREND_ROWS`). Only readings that can move count (an open line and a readout at its ceiling repeat
themselves whatever the sensor does), and a change of more than :data:`MOVING_STEPS` ADC steps is the load moving,
not noise. Whatever those say, a run is not flat before :data:`GUARD_FACTOR` × the longest recent pause of the
reading, nor before ``flat_min_s`` (1 s). A sensor that never changed (stuck from the start) waits ``flat_s`` (10
s); a run that reaches its threshold only after ``flat_max_s`` (60 s) is ``UNCHANGED`` (force kept, flagged): its
history cannot tell a stuck line from a still one. Measured at 30 Hz (tests/models/test_validation.py,
tests/models/test_validation_loaded.py, new seeds): a line that freezes 1.5 s after a 3 N load is flagged within 2 s
at 0.1–0.5 counts of noise, on a resting sensor at 0.5 counts 1.0–2.0 s; healthy loaded sensors at 0.1–0.3 counts
held 400–600 s and resting ones at 0.15–0.5 counts for 20 minutes: no sample rejected (one of 64 loaded sensors
lost 1.8 % of its samples late in a quiet hold: docs/NUMERICS.md).

**An open line under load.** A reading at or below ``open_s`` (1e-9 S) straight after one above ``open_jump_s``
(100 µS) is ``OPEN_UNDER_LOAD`` (a gap) for up to ``open_release_s`` (0.5 s); a longer one, or one reached through
smaller readings, is an open circuit at rest (0 N). Other readings at or below ``open_s`` read as 0 S.

A validator carries the flat-line run of each sensor across blocks (a stream split into blocks is judged exactly
like the whole record). Not thread-safe: use it from the thread that feeds the estimator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.sls import ForceStatus

# The default readout of SPEC §4 (R_C = 900 Ω): counts = 0 reads 1/R_C.
DEFAULT_R_C_OHM = 900.0
DEFAULT_STEP_S = 3.3 / (2.5 * DEFAULT_R_C_OHM * 4095)  # one ADC step of the default readout (S), ≈ 0.36 µS
DEFAULT_FLAT_S = 10.0  # the longest a repeated reading is trusted (a sensor with no history, or a very quiet one)
DEFAULT_FLAT_MIN_S = 1.0  # the shortest run ever called flat
DEFAULT_FLAT_FALSE_ALARM = 1e-6  # the chance a healthy sensor repeats itself that long (at most; module docstring)
FLAT_MIN_HISTORY = 30  # comparisons before a run needed to trust the sensor's own change rate
HISTORY_COMPARISONS = 600  # the change rate's memory, in comparisons (20 s at the board's 30 Hz)
_HISTORY_CHUNK = 20_000  # rows per step of the weighted history (λ^−k stays small)
MOVING_STEPS = 3.5  # a change of more ADC steps than this in one sample is the load moving (not noise, not creep)
# A steady trend (creep after a load) shows a sensor is alive better than its noise: over the last TREND_ROWS
# samples (both windows free of movement and gaps) the reading moved by a net number of ADC steps; less a slack of
# TREND_SLACK_STEPS (the rounding at the windows' ends), that is a low estimate of the steps per sample, and a run
# over which the trend would have moved the level by TREND_STEPS steps is not a still sensor. The short window keeps
# a slowing signal (a turning point) from being judged by its earlier speed.
TREND_ROWS = (30, 90)
TREND_SLACK_STEPS = 2.0
TREND_STEPS = 3.0
# Whatever the rates say, a run is not called flat before it is GUARD_FACTOR × the longest pause of the reading in
# the last GUARD_ROWS samples (a slowly drifting quiet sensor changes in bursts where it crosses an ADC step and
# pauses between them: its per-sample rate overstates how soon it must change again).
GUARD_FACTOR = 4.0
GUARD_ROWS = 5400  # the longest pause is forgotten with e^(−samples/GUARD_ROWS): three minutes at 30 Hz
_GUARD_REBASE_ROWS = 1_000_000
_TAIL_ROWS = max(TREND_ROWS) + 1  # rows carried between blocks for the trend's windows
# A reading within this relative distance of the ceiling is the ceiling (the CSV's %.17g round trip, V arithmetic).
_CEILING_REL = 1e-9

REJECTED = (ForceStatus.NAN_INPUT, ForceStatus.NEGATIVE_CONDUCTANCE, ForceStatus.ABOVE_CEILING, ForceStatus.FLAT,
            ForceStatus.OPEN_UNDER_LOAD)
_IS_REJECTED = np.isin(np.arange(max(ForceStatus) + 1), REJECTED)  # by status code: a lookup, not np.isin per block
DEFAULT_OPEN_S = 1e-9  # a reading at or below this is an open line (the 12-bit readout's smallest step is 0.36 µS)
# A drop to open straight from a reading above this is not a release: at the contact term's C ∝ √F, 100 µS is
# ≈ 0.05 N on the typical sensor (a grazing touch of 0.02–0.04 N, 67–81 µS, can let go within one frame).
DEFAULT_OPEN_JUMP_S = 100e-6
DEFAULT_OPEN_RELEASE_S = 0.5  # an open reading that lasts this long after a load is a release (0 N), not a glitch


@dataclass(frozen=True)
class ValidationRule:
    """``ceiling_s``: the readout's largest reading 1/R_C in S (None: no readout limit known, only the other checks
    apply); ``flat_s``: a non-zero reading unchanged for this many seconds is flat-lined (≤ 0 turns it off)."""

    ceiling_s: float | None = 1.0 / DEFAULT_R_C_OHM
    flat_s: float = DEFAULT_FLAT_S
    flat_min_s: float = DEFAULT_FLAT_MIN_S
    flat_max_s: float = 60.0  # a reading repeated this long is flagged UNCHANGED (kept), however quiet the sensor
    flat_false_alarm: float = DEFAULT_FLAT_FALSE_ALARM
    open_s: float = DEFAULT_OPEN_S
    open_jump_s: float = DEFAULT_OPEN_JUMP_S
    open_release_s: float = DEFAULT_OPEN_RELEASE_S
    # One ADC step in S (the readout's resolution: 1/R_C × V_supply / (V_ref × 4095) on the board of SPEC §4), which
    # tells a moving load from noise and measures a trend; None: unknown (the noise rule alone judges).
    step_s: float | None = DEFAULT_STEP_S

    @classmethod
    def for_readout(cls, r_c_ohm: float, flat_s: float = DEFAULT_FLAT_S) -> ValidationRule:
        if not (np.isfinite(r_c_ohm) and r_c_ohm > 0):
            raise ValueError(f"readout resistor R_C must be a positive number of ohms, got {r_c_ohm!r}")
        return cls(ceiling_s=1.0 / r_c_ohm, flat_s=flat_s, step_s=DEFAULT_STEP_S * DEFAULT_R_C_OHM / r_c_ohm)


@dataclass(frozen=True)
class CheckedBlock:
    """``conductance_s`` (N, S): the input with every rejected sample replaced by NaN and saturated ones set to the
    ceiling; ``status`` (N, S) int8 :class:`ForceStatus` codes (0 where the sample passed)."""

    conductance_s: np.ndarray
    status: np.ndarray


class SampleValidator:
    """Applies a :class:`ValidationRule` to blocks of ``n_sensors`` columns, carrying flat-line runs across blocks."""

    # A one-row block takes the stuck-channel rule's one-row path (the same results; False: the general path, which
    # the tests compare it with)
    one_row_fast_path = True

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
        self._last_informative = np.zeros(self.n_sensors, dtype=bool)
        self._changes = np.zeros(self.n_sensors)  # sample-to-sample changes seen (recent ones weighted, _history)
        self._compares = np.zeros(self.n_sensors)  # sample-to-sample comparisons made (weighted alike)
        self._valid = np.zeros(self.n_sensors, dtype=np.int64)  # comparisons made (plain count)
        self._ever = np.zeros(self.n_sensors, dtype=bool)  # the reading changed at least once
        self._run_flat = np.zeros(self.n_sensors, dtype=bool)  # the run in progress has been called flat
        self._tail_signed = np.zeros((_TAIL_ROWS, self.n_sensors))  # signed ADC steps of the last rows
        self._tail_unusable = np.ones((_TAIL_ROWS, self.n_sensors), dtype=bool)  # rows no trend may span
        self._guard_mark = np.full(self.n_sensors, -np.inf)  # running max of ln(pause) + row/GUARD_ROWS
        self._guard_row = 0  # rows seen since the marks' origin
        self._last_reading = np.zeros(self.n_sensors)  # the last finite reading above open (S)
        self._open_start_s = np.full(self.n_sensors, np.nan)  # when the open run in progress began (NaN: none)

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
            opened = self._open_under_load(t, cond, finite)
            status[opened & (status == 0)] = ForceStatus.OPEN_UNDER_LOAD
            cond[finite & (cond >= 0.0) & (cond <= self.rule.open_s) & ~opened] = 0.0  # 1e-12 S is an open line
            if saturated is not None:
                mask = np.asarray(saturated, dtype=bool)
                if mask.ndim == 1:
                    mask = mask[:, None]
                if mask.shape != cond.shape:
                    raise ValueError(f"saturated mask has shape {mask.shape}, the conductance block {cond.shape}")
                status[mask & (status == 0)] = ForceStatus.READOUT_SATURATED
        if self.rule.flat_s > 0:
            informative = finite & (cond > 0.0) & (status != ForceStatus.READOUT_SATURATED)
            flat, still = self._flat(t, cond, informative)
            status[flat & (status == 0)] = ForceStatus.FLAT
            status[still & (status == 0)] = ForceStatus.UNCHANGED
        rejected = _IS_REJECTED[status]
        cond[rejected] = np.nan
        return CheckedBlock(cond, status)

    def _open_under_load(self, t: np.ndarray, cond: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """Open readings (≤ ``open_s``) that follow a reading above ``open_jump_s`` with nothing between, for at most
        ``open_release_s``: a loaded sensor does not read 0 S from one sample to the next unless its line opened
        (a release passes through smaller readings, or lasts; module docstring)."""
        rule = self.rule
        n = cond.shape[0]
        if n == 1 and self.one_row_fast_path:  # the same arithmetic on the row alone (the carried state before it)
            return self._open_one_row(float(t[0]), cond[0], finite[0])[None, :]
        rows = np.arange(n)[:, None]
        with np.errstate(invalid="ignore"):
            is_open = finite & (cond >= 0.0) & (cond <= rule.open_s)
            reading = finite & (cond > rule.open_s)
        last = np.where(reading, rows, -1)
        np.maximum.accumulate(last, axis=0, out=last)
        cols = np.arange(cond.shape[1])[None, :]
        before = np.where(last >= 0, cond[np.maximum(last, 0), cols], self._last_reading[None, :])
        # The open run's start: the sample after the last reading (this block), or the carried one.
        after = np.minimum(last + 1, n - 1)
        start_s = np.where(last >= 0, t[after], np.where(np.isnan(self._open_start_s), t[0], self._open_start_s)[None, :])
        opened = is_open & (before > rule.open_jump_s) & (t[:, None] - start_s < rule.open_release_s)
        self._last_reading = before[-1].copy()
        self._open_start_s = np.where(reading[-1], np.nan, start_s[-1])
        return opened

    def _open_one_row(self, t: float, cond: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """:meth:`_open_under_load` for one row (S,)."""
        rule = self.rule
        with np.errstate(invalid="ignore"):
            is_open = finite & (cond >= 0.0) & (cond <= rule.open_s)
            reading = finite & (cond > rule.open_s)
        before = np.where(reading, cond, self._last_reading)
        start_s = np.where(reading, t, np.where(np.isnan(self._open_start_s), t, self._open_start_s))
        opened = is_open & (before > rule.open_jump_s) & (t - start_s < rule.open_release_s)
        self._last_reading = before
        self._open_start_s = np.where(reading, np.nan, start_s)
        return opened

    def _flat(self, t: np.ndarray, cond: np.ndarray, informative: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat, still): samples whose non-zero reading has been identical for longer than the sensor's recent
        history makes likely (module docstring), and at least ``flat_min_s``, or for ``flat_s`` when the sensor never
        changed — rejected; and those identical for ``flat_max_s`` that the history cannot judge — kept, flagged.
        ``informative`` (N, S): samples whose change can show the sensor is alive (not open, not at the ceiling,
        finite). A one-row block (a live reader's usual block: one board frame) takes :meth:`_flat_one_row`, the
        same rule without the block's cumulative sums (the same numbers, bit for bit: tested)."""
        if cond.shape[0] == 1 and self.one_row_fast_path:
            flat, still = self._flat_one_row(float(t[0]), cond[0], informative[0])
            return flat[None, :], still[None, :]
        return self._flat_rows(t, cond, informative)

    def _flat_one_row(self, t: float, cond: np.ndarray, informative: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_flat_rows` for one row (S,): every per-row quantity of the general path with the row index 0, the
        carried state standing for the rows before. Each expression is the general path's, in the same order, on
        1-D arrays (the trend's windows are sums of whole ADC steps, exact in any order)."""
        rule = self.rule
        previous = self._last_value
        prev_informative = self._last_informative
        changed = ~(cond == previous)
        compared = informative & prev_informative
        step = rule.step_s
        with np.errstate(invalid="ignore"):
            steps = (cond - previous) / step if step else np.zeros(cond.shape)
            moving = compared & (np.abs(steps) > MOVING_STEPS) if step else np.zeros(cond.shape, dtype=bool)
        quiet = compared & ~moving
        # the history (_history with one row: one comparison more where quiet)
        decay = 1.0 - 1.0 / HISTORY_COMPARISONS
        k = quiet.astype(np.float64)
        grow = decay ** (-k)
        changes = decay**k * (self._changes + (changed & quiet) * grow)
        compares = decay**k * (self._compares + k * grow)
        valid = self._valid + quiet
        ever = self._ever | (changed & compared)
        start_s = np.where(changed, t, self._run_start_s)
        length = np.where(changed, 1, self._run_length + 1)
        with np.errstate(invalid="ignore"):  # a quiet comparison's steps are finite (two finite readings)
            signed = np.where(quiet, np.rint(steps), 0.0)
        # the trend over the carried tail's last rows (the rows before this one)
        tail_signed, tail_unusable = self._tail_signed, self._tail_unusable
        net_short = tail_signed[-TREND_ROWS[0]:].sum(axis=0)
        net_long = tail_signed[-TREND_ROWS[1]:].sum(axis=0)
        clean_short = ~tail_unusable[-TREND_ROWS[0]:].any(axis=0)
        clean_long = ~tail_unusable[-TREND_ROWS[1]:].any(axis=0)
        rate = np.where(clean_short, (np.abs(net_short) - TREND_SLACK_STEPS) / TREND_ROWS[0], 0.0)
        same_way = np.sign(net_short) == np.sign(net_long)
        rate = np.where(clean_long, np.where(same_way, np.minimum(
            rate, (np.abs(net_long) - TREND_SLACK_STEPS) / TREND_ROWS[1]), 0.0), rate)
        trend_needs = np.where(rate > 0, np.ceil(TREND_STEPS / np.maximum(rate, 1e-300)), np.inf)
        # the longest recent pause, this row's ended pause included
        ended = changed & prev_informative
        row_s = self._guard_row / GUARD_ROWS
        marks = np.where(ended, np.log(np.maximum(self._run_length, 1)) + row_s, -np.inf)
        best = np.maximum(self._guard_mark, marks)
        longest = np.exp(best - row_s)
        guard = np.where(changed, GUARD_FACTOR * longest, 0.0)
        judged_needs = np.maximum(np.minimum(self._needs(self._changes, self._compares, self._valid), trend_needs),
                                  guard)
        needs = np.where(changed, judged_needs, self._run_needs)
        elapsed = t - start_s
        reading = cond != 0.0
        due = np.where(ever, (length >= needs) & (elapsed >= rule.flat_min_s), elapsed >= rule.flat_s) & reading
        flat = ((due & (elapsed < rule.flat_max_s)) | (~changed & self._run_flat)) & reading
        still = (elapsed >= rule.flat_max_s) & reading & ~flat
        self._last_value = cond.copy()
        self._last_informative = informative.copy()
        self._run_start_s = start_s
        self._run_length = length.astype(np.int64)
        self._run_needs = needs
        self._changes, self._compares, self._valid = changes, compares, valid
        self._ever = ever
        self._run_flat = flat
        self._tail_signed = np.vstack([tail_signed[1:], signed[None, :]])
        self._tail_unusable = np.vstack([tail_unusable[1:], ~quiet[None, :]])
        self._guard_mark = best
        self._guard_row += 1
        if self._guard_row > _GUARD_REBASE_ROWS:
            self._guard_mark = self._guard_mark - self._guard_row / GUARD_ROWS
            self._guard_row = 0
        return flat, still

    def _flat_rows(self, t: np.ndarray, cond: np.ndarray, informative: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_flat` of a block of any number of rows (N, S)."""
        rule = self.rule
        n = cond.shape[0]
        rows = np.arange(n)[:, None]
        previous = np.vstack([self._last_value[None, :], cond[:-1]])
        prev_informative = np.vstack([self._last_informative[None, :], informative[:-1]])
        changed = ~(cond == previous)  # NaN never equals: a gap ends a run
        # Only a comparison of two readings that can move shows how lively the sensor is: an open line (0 S) or a
        # readout pinned at its ceiling repeats itself whatever the sensor does, and counting those as "no change"
        # made a sensor that had rested unloaded look so quiet that a line freezing under load went unflagged for
        # a minute.
        compared = informative & prev_informative
        step = self.rule.step_s
        with np.errstate(invalid="ignore"):
            steps = (cond - previous) / step if step else np.zeros(cond.shape)
        # A step of several ADC steps is the load moving, not the sensor's noise or creep: it says nothing about how
        # often a still sensor changes (a loading ramp changes every sample; counted, it made the pause after it
        # look like a freeze on every quiet sensor).
        moving = compared & (np.abs(steps) > MOVING_STEPS) if step else np.zeros(cond.shape, dtype=bool)
        quiet = compared & ~moving
        changes, compares, valid = self._history(changed & quiet, quiet)
        ever = self._ever[None, :] | np.logical_or.accumulate(changed & compared, axis=0)
        index = np.where(changed, rows, -1)
        np.maximum.accumulate(index, axis=0, out=index)
        started = index >= 0
        at = np.maximum(index, 0)
        start_s = np.where(started, t[at], self._run_start_s[None, :])
        length = np.where(started, rows - index + 1, self._run_length[None, :] + rows + 1)
        # The trend and the longest recent pause, from this block with the carried tail before it.
        signed = np.where(quiet, np.rint(np.nan_to_num(steps)), 0.0)
        unusable = ~quiet
        tail = _TAIL_ROWS
        all_signed = np.cumsum(np.vstack([self._tail_signed, signed]), axis=0)
        all_unusable = np.cumsum(np.vstack([self._tail_unusable, unusable]), axis=0)
        # The longest pause of a reading (that could move) ending at or before each row, forgetting with
        # e^(−rows/GUARD_ROWS): a running maximum of ln(length) + (row index)/GUARD_ROWS, read back at each row.
        # A change at a row ends the pause before it (whose length the row before holds).
        prev_length = np.vstack([self._run_length[None, :], length[:-1]])
        ended = changed & prev_informative
        with np.errstate(divide="ignore"):
            marks = np.where(ended, np.log(np.maximum(prev_length, 1)) + (rows + self._guard_row) / GUARD_ROWS, -np.inf)
        best = np.maximum.accumulate(np.vstack([self._guard_mark[None, :], marks]), axis=0)[1:]
        longest = np.exp(best - (rows + self._guard_row) / GUARD_ROWS)  # at each row, the pause just ended included
        # The history as it stood one sample before the run's first one (carried for a run from earlier).
        before = np.maximum(at - 1, 0)
        first_row = at == 0
        before_changes = np.where(first_row, self._changes[None, :], np.take_along_axis(changes, before, axis=0))
        before_compares = np.where(first_row, self._compares[None, :], np.take_along_axis(compares, before, axis=0))
        before_valid = np.where(first_row, self._valid[None, :], np.take_along_axis(valid, before, axis=0))
        c = tail + at - 1  # the combined row before the run's first sample

        def window(cum: np.ndarray, rows_back: int) -> np.ndarray:
            return np.take_along_axis(cum, c, axis=0) - np.take_along_axis(cum, c - rows_back, axis=0)

        net_short, net_long = window(all_signed, TREND_ROWS[0]), window(all_signed, TREND_ROWS[1])
        clean_short = window(all_unusable, TREND_ROWS[0]) == 0
        clean_long = window(all_unusable, TREND_ROWS[1]) == 0
        rate = np.where(clean_short, (np.abs(net_short) - TREND_SLACK_STEPS) / TREND_ROWS[0], 0.0)
        same_way = np.sign(net_short) == np.sign(net_long)
        rate = np.where(clean_long, np.where(same_way, np.minimum(
            rate, (np.abs(net_long) - TREND_SLACK_STEPS) / TREND_ROWS[1]), 0.0), rate)
        with np.errstate(divide="ignore"):
            trend_needs = np.where(rate > 0, np.ceil(TREND_STEPS / np.maximum(rate, 1e-300)), np.inf)
        # A run's own first sample ends the run before it: the guard reads the pauses up to that sample.
        guard = np.where(first_row & ~started, 0.0, GUARD_FACTOR * np.take_along_axis(longest, at, axis=0))
        judged_needs = np.maximum(np.minimum(self._needs(before_changes, before_compares, before_valid), trend_needs),
                                  guard)
        needs = np.where(started, judged_needs, self._run_needs[None, :])
        elapsed = t[:, None] - start_s
        # A sensor that never changed (stuck from the start) is trusted for flat_s; one whose history cannot judge
        # the run (needs = inf: only movement, or too quiet) is never called flat, only UNCHANGED after flat_max_s.
        reading = cond != 0.0
        # A run becomes flat when it outlasts its threshold within flat_max_s; one that only does later (the history
        # had seen pauses nearly as long: a quiet sensor whose creep has settled) is UNCHANGED, its force kept.
        due = np.where(ever, (length >= needs) & (elapsed >= rule.flat_min_s), elapsed >= rule.flat_s) & reading
        became = np.where(due & (elapsed < rule.flat_max_s), rows, -1)
        np.maximum.accumulate(became, axis=0, out=became)
        flat = ((became >= index) & (became >= 0) | (~started & self._run_flat[None, :])) & reading
        still = (elapsed >= rule.flat_max_s) & reading & ~flat
        self._last_value = cond[-1].copy()
        self._last_informative = informative[-1].copy()
        self._run_start_s = start_s[-1].copy()
        self._run_length = length[-1].astype(np.int64)
        self._run_needs = needs[-1].copy()
        self._changes, self._compares, self._valid = changes[-1].copy(), compares[-1].copy(), valid[-1].copy()
        self._ever = ever[-1].copy()
        self._run_flat = flat[-1].copy()
        self._tail_signed = np.vstack([self._tail_signed, signed])[-tail:]
        self._tail_unusable = np.vstack([self._tail_unusable, unusable])[-tail:]
        self._guard_mark = best[-1].copy()
        self._guard_row += n
        if self._guard_row > _GUARD_REBASE_ROWS:  # keep the marks' offsets small: rebase them
            self._guard_mark = self._guard_mark - self._guard_row / GUARD_ROWS
            self._guard_row = 0
        return flat, still

    def _history(self, change: np.ndarray, compared: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per row, the sensor's recent history: changes and comparisons weighted by λ^(comparisons since), λ = 1 −
        1/HISTORY_COMPARISONS (the rate follows the present: the changes of a loading ramp fade as the creep slows,
        instead of calling every later pause of a quiet sensor a freeze), and the plain count of comparisons."""
        decay = 1.0 - 1.0 / HISTORY_COMPARISONS
        weight_in = compared.astype(np.float64)
        count = self._valid[None, :] + np.cumsum(compared, axis=0)
        out_changes = np.empty(change.shape)
        out_compares = np.empty(change.shape)
        changes, compares = self._changes.copy(), self._compares.copy()
        # In chunks: λ^(−k) over one chunk stays far from overflow.
        for lo in range(0, change.shape[0], _HISTORY_CHUNK):
            hi = min(lo + _HISTORY_CHUNK, change.shape[0])
            k = np.cumsum(compared[lo:hi], axis=0).astype(np.float64)  # comparisons since the chunk's start
            grow = decay ** (-k)
            out_changes[lo:hi] = decay**k * (changes[None, :] + np.cumsum(change[lo:hi] * grow, axis=0))
            out_compares[lo:hi] = decay**k * (compares[None, :] + np.cumsum(weight_in[lo:hi] * grow, axis=0))
            changes, compares = out_changes[hi - 1].copy(), out_compares[hi - 1].copy()
        return out_changes, out_compares, count

    def _needs(self, changes: np.ndarray, compares: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """Run length (samples) past which a healthy sensor with this history repeats itself with probability below
        ``flat_false_alarm``; inf without enough history (then ``flat_s`` decides)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            # A low estimate of the rate (3 σ of a count below what was seen): a short or lucky history must not make
            # a quiet sensor look lively, and a flat run of it look unlikely.
            low = np.maximum(changes - 3.0 * np.sqrt(changes), 0.0)
            p = np.where(compares > 0, low / np.maximum(compares, 1e-300), 0.0)
            # The chance to repeat the current value: at most sqrt(1 − p) whatever the noise's shape (with values at
            # frequencies f_i, p = 1 − Σ f_i², so the most frequent value's f_1 ≤ sqrt(1 − p)); a two-level sensor
            # sitting on its usual level reaches it.
            stay = 0.5 * np.log1p(-np.minimum(p, 1.0 - 1e-12))  # ln sqrt(1 − p) < 0
            needs = np.where(p > 0, np.log(self.rule.flat_false_alarm) / stay, np.inf)
        return np.where(valid >= FLAT_MIN_HISTORY, np.ceil(needs), np.inf)


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
        if ForceStatus.OPEN_UNDER_LOAD.name in rejected:
            parts.append("0 S read straight after a load: an open circuit (loose wire or connector), not a release")
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
        unchanged = int(np.sum(column == ForceStatus.UNCHANGED))
        if unchanged:
            parts.append(f"{unchanged} unchanged for over a minute (a stuck line or a very quiet sensor: force kept, "
                         "check the channel)")
        for code in (ForceStatus.OPEN_CIRCUIT, ForceStatus.BELOW_BASELINE, ForceStatus.SATURATED,
                     ForceStatus.NOT_CONVERGED):
            count = int(np.sum(column == code))
            if count:
                parts.append(f"{count} {code.name}")
        lines.append(f"{name}: " + ", ".join(parts))
    return lines
