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
``FLAT``               the same non-zero reading, bit for bit, for at least    rejected: a gap, force NaN (no force is
                       ``flat_s`` seconds (a stuck channel)                    claimed for a frozen line)
=====================  ======================================================  ========================================

After the inverse, a force below the smallest (or above the largest) calibrated force is flagged ``EXTRAPOLATED``
by the estimators (value kept).

**How the creep state crosses a gap.** A rejected sample reaches the recursion as NaN: its output is NaN, and the
creep state keeps evolving over the gap's elapsed time under a zero-order hold of the last accepted stress (the
exact "hold" update with the gap's length). Time therefore passes: after a gap the creep strain is what it would be
had the force stayed at its last good value. A single rejected glitch thus changes the state by no more than one
sample of that hold; it never feeds an impossible value into the state.

A validator carries the flat-line run of each sensor across blocks (a stream split into blocks is judged exactly
like the whole record). Not thread-safe: use it from the thread that feeds the estimator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.sls import ForceStatus

# The default readout of SPEC §4 (R_C = 900 Ω): counts = 0 reads 1/R_C.
DEFAULT_R_C_OHM = 900.0
DEFAULT_FLAT_S = 10.0
# A reading within this relative distance of the ceiling is the ceiling (the CSV's %.17g round trip, V arithmetic).
_CEILING_REL = 1e-9

REJECTED = (ForceStatus.NAN_INPUT, ForceStatus.NEGATIVE_CONDUCTANCE, ForceStatus.ABOVE_CEILING, ForceStatus.FLAT)


@dataclass(frozen=True)
class ValidationRule:
    """``ceiling_s``: the readout's largest reading 1/R_C in S (None: no readout limit known, only the other checks
    apply); ``flat_s``: a non-zero reading unchanged for this many seconds is flat-lined (≤ 0 turns it off)."""

    ceiling_s: float | None = 1.0 / DEFAULT_R_C_OHM
    flat_s: float = DEFAULT_FLAT_S

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
        """Forget the flat-line runs (a new record, or after the clock restarted)."""
        self._last_value = np.full(self.n_sensors, np.nan)
        self._run_start_s = np.full(self.n_sensors, np.nan)

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
        """Samples whose non-zero reading has been identical since at least ``flat_s`` seconds before them."""
        n, s = cond.shape
        previous = np.vstack([self._last_value[None, :], cond[:-1]])
        changed = ~(cond == previous)  # NaN never equals: a gap ends a run
        first = changed.copy()
        index = np.where(first, np.arange(n)[:, None], -1)
        np.maximum.accumulate(index, axis=0, out=index)
        start_s = np.where(index >= 0, t[np.maximum(index, 0)], self._run_start_s[None, :])
        flat = (t[:, None] - start_s >= self.rule.flat_s) & (cond != 0.0)
        self._last_value = cond[-1].copy()
        self._run_start_s = start_s[-1].copy()
        return flat


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
