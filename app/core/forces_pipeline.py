"""Conductance → force for the live Forces tab, with each sensor's calibration status.

Per sensor the status is one of:

- ``calibrated``: the loaded calibration JSON (SPEC §3.3, read by :mod:`app.core.calfiles`) has this sensor's model;
- ``uncalibrated``: no calibration file is loaded, or the loaded one does not hold this sensor (or its model), or
  its SLS fit was marked degenerate by ``sensnake fit`` (at a bound, τ unresolved, no creep resolved; the reason
  goes to :attr:`ForcesPipeline.problems`): the sensor shows conductance in µS, labelled, never a made-up force.
  (Before, with no file at all a "typical sensor" stood in and its forces were shown in N: an uncalibrated sensor
  shown as newtons, with the physics constants from a hidden default — SPEC §5 says never. A sensor is shown in N
  only from its own calibration.)

The estimator (``sls`` creep-aware, or ``linear``) is applied live to new blocks; switching it restarts the estimator
state (the creep history starts afresh). Time stamps fed to the estimators are the board clock (seconds). Every block
passes the one sample-validation rule of :mod:`models.validation` inside the estimators (non-finite, negative,
above-ceiling and flat-lined readings are rejected: NaN force, flagged; the board's saturation mask flags
READOUT_SATURATED; the ceiling 1/R_C is the board's, set by :meth:`ForcesPipeline.set_readout`); the
per-sample :class:`models.sls.ForceStatus` codes come back in :attr:`ForcesBlock.status`.

Not thread-safe: the Forces tab calls it from the GUI thread as blocks arrive.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from app.core import calfiles
from models.estimators import ESTIMATOR_RULE, LinearEstimator, SLSEstimator
from models.linear import LinearModel
from models.physics import DEFAULT_PHYSICS, PhysicsConstants
from models.sls import SLSParams
from models.validation import ValidationRule

CALIBRATED = "calibrated"
UNCALIBRATED = "uncalibrated"
ESTIMATORS = ("sls", "linear")
NO_CALIBRATION_TEXT = "no calibration file: all sensors in µS, not N"
NO_CALIBRATION_HINT = ("No sensor has a calibration, so none is shown in newtons. Calibrate sensors on the Calibration "
                       "tab (the saved file is used here at once), or load a calibration file with Calibration…")
US_PER_S = 1e6


@dataclass(frozen=True)
class ForcesBlock:
    """One processed block: ``display`` (N×C) what the force view plots (N for estimated sensors, µS for the
    others), ``force_n`` (N×C) forces in N with NaN for sensors without an estimate, ``status`` (N×C) int8
    :class:`models.sls.ForceStatus` codes (0 = ok, also for sensors shown as conductance)."""

    display: np.ndarray
    force_n: np.ndarray
    status: np.ndarray | None = None


class ForcesPipeline:
    """Live force estimation for ``channel_names``; see the module docstring."""

    def __init__(self, channel_names: tuple[str, ...] | list[str], estimator: str = "sls") -> None:
        self.channel_names = tuple(channel_names)
        self._estimator_kind = "sls"
        self.calibration: dict | None = None
        self.calibration_source = ""
        self.physics: PhysicsConstants = DEFAULT_PHYSICS
        self._estimator: LinearEstimator | SLSEstimator | None = None
        self._columns = np.zeros(0, dtype=np.intp)
        self.status: tuple[str, ...] = ()
        self.problems: list[str] = []
        self.last_block_problem: str | None = None  # why the last block got no force, if it did not
        self._t_last_s: float | None = None
        self._rule = ESTIMATOR_RULE
        self.set_estimator(estimator)

    def set_readout(self, r_c_ohm: float) -> None:
        """The board's readout resistor (Ω): readings above 1/R_C are rejected (ABOVE_CEILING), at it saturated.
        The live session calls it with its board's value; the state restarts."""
        self._rule = ValidationRule.for_readout(r_c_ohm)
        self._build()

    # -- configuration ---------------------------------------------------------------------------------------------
    @property
    def estimator_kind(self) -> str:
        return self._estimator_kind

    @property
    def estimated(self) -> np.ndarray:
        """Boolean mask (C,) of the sensors that get a force."""
        mask = np.zeros(len(self.channel_names), dtype=bool)
        mask[self._columns] = True
        return mask

    @property
    def calibration_json(self) -> str | None:
        """The loaded calibration document as JSON text (stored in recordings), or None."""
        return None if self.calibration is None else json.dumps(self.calibration)

    def set_estimator(self, kind: str) -> None:
        """``sls`` (creep-aware) or ``linear``; the state restarts."""
        if kind not in ESTIMATORS:
            raise ValueError(f"unknown estimator {kind!r}; expected one of {', '.join(ESTIMATORS)}")
        self._estimator_kind = kind
        self._build()

    def load_calibration(self, path: str | os.PathLike) -> None:
        """Read a calibration JSON via :mod:`app.core.calfiles`; raises CalFileError (a ValueError) with the reason."""
        document = calfiles.read_calibration(path)
        physics = calfiles.physics_from_calibration(document, str(path))
        self.calibration, self.calibration_source, self.physics = document, str(path), physics
        self._build()

    def fresh_copy(self, estimator: str | None = None) -> ForcesPipeline:
        """A pipeline for the same channels and readout rule with this one's calibration and ``estimator`` (default:
        this one's), its state at rest: run it over the past on a worker thread, then hand it to :meth:`adopt`."""
        copy = ForcesPipeline(self.channel_names, estimator or self._estimator_kind)
        copy._rule = self._rule
        copy.calibration, copy.calibration_source, copy.physics = (self.calibration, self.calibration_source,
                                                                   self.physics)
        copy._build()
        return copy

    def adopt(self, other: ForcesPipeline) -> None:
        """Take over ``other``'s calibration, estimator and estimator state (a :meth:`fresh_copy` that was run over
        the history up to now), so whoever holds this pipeline (the live session) goes on from there. ``other``
        must not be used afterwards."""
        if other.channel_names != self.channel_names:
            raise ValueError(f"cannot adopt a pipeline of {len(other.channel_names)} channels into one of "
                             f"{len(self.channel_names)}")
        for name in ("_estimator_kind", "calibration", "calibration_source", "physics", "_estimator", "_columns",
                     "status", "problems", "last_block_problem", "_t_last_s", "_rule"):
            setattr(self, name, getattr(other, name))

    def clear_calibration(self) -> None:
        self.calibration, self.calibration_source, self.physics = None, "", DEFAULT_PHYSICS
        self._build()

    def reset(self) -> None:
        """Restart the estimator's state (after a gap in the data, or a new session)."""
        self._build()

    def label(self, index: int) -> str:
        """Legend text for channel ``index``: ``S06B`` when it gets a force (from its calibration), ``S06B (µS,
        uncal.)`` when it shows conductance."""
        name = self.channel_names[index]
        if self.status[index] == UNCALIBRATED:
            return f"{name} (µS, uncal.)"
        return name

    def summary(self) -> tuple[str, str]:
        """(text, level) for the calibration label: how many sensors are calibrated / shown as conductance."""
        counts = {key: self.status.count(key) for key in (CALIBRATED, UNCALIBRATED)}
        if self.calibration is None:
            return (NO_CALIBRATION_TEXT, "warn")
        name = os.path.basename(self.calibration_source)
        if counts[UNCALIBRATED]:
            return (f"{name}: {counts[CALIBRATED]} calibrated, {counts[UNCALIBRATED]} shown as conductance", "warn")
        return (f"{name}: all {counts[CALIBRATED]} sensors calibrated", "ok")

    # -- processing ------------------------------------------------------------------------------------------------
    def process(self, t_s: np.ndarray, conductance_s: np.ndarray,
                saturated: np.ndarray | None = None) -> ForcesBlock:
        """Estimate forces for a block: ``t_s`` (N,) board seconds, ``conductance_s`` (N×C) siemens, ``saturated``
        (N×C) bool the board's counts = 0 mask (optional)."""
        conductance_s = np.asarray(conductance_s, dtype=float)
        t_s = np.asarray(t_s, dtype=float)
        self.last_block_problem = None
        force_n = np.full(conductance_s.shape, np.nan)
        status = np.zeros(conductance_s.shape, dtype=np.int8)
        display = conductance_s * US_PER_S
        if self._estimator is not None and self._columns.size and t_s.size:
            if self._t_last_s is not None and t_s[0] < self._t_last_s:
                self._build()  # the board clock restarted (new board or power cycle): the creep state is stale
            columns_saturated = None if saturated is None else np.asarray(saturated, dtype=bool)[:, self._columns]
            try:
                estimated = self._estimator.update(t_s, conductance_s[:, self._columns], columns_saturated)
            except ValueError as exc:
                # A block the estimator refuses (clock jumping back inside a block, non-finite time): show its
                # conductance, say why, and start the estimator afresh from the next block.
                self._build()
                self.last_block_problem = f"force estimate skipped for one block: {exc}"
                self.problems.insert(0, self.last_block_problem)
                return ForcesBlock(display=display, force_n=force_n, status=status)
            force_n[:, self._columns] = estimated
            display[:, self._columns] = estimated
            status[:, self._columns] = self._estimator.last_status
            self._t_last_s = float(t_s[-1])
        return ForcesBlock(display=display, force_n=force_n, status=status)

    # -- internals -------------------------------------------------------------------------------------------------
    def _build(self) -> None:
        kind = self._estimator_kind
        status: list[str] = []
        self.problems = []
        e0, e1, mu1, area, linear_models = [], [], [], [], []
        for name in self.channel_names:
            if self.calibration is None:
                status.append(UNCALIBRATED)
                continue
            try:
                entry = calfiles.sensor_entry(self.calibration, name, kind, self.calibration_source)
            except calfiles.CalFileError as exc:
                status.append(UNCALIBRATED)
                if name in self.calibration.get("sensors", {}):
                    self.problems.append(str(exc))  # present but unusable: worth telling the user why
                continue
            if kind == "sls" and self.calibration["sensors"][name].get("degenerate") is True:
                status.append(UNCALIBRATED)
                why = "; ".join(self.calibration["sensors"][name].get("degenerate_reasons", [])) or "marked degenerate"
                self.problems.append(f"{self.calibration_source}: sensor '{name}' has a degenerate SLS fit ({why}): "
                                     "shown as conductance; recalibrate, or use the linear estimator")
                continue
            status.append(CALIBRATED)
            if kind == "sls":
                sls = entry["sls"]
                e0.append(sls["E0_Pa"])
                e1.append(sls["E1_Pa"])
                mu1.append(sls["mu1_Pa_s"])
                area.append(entry["area_m2"])
            else:
                linear = entry["linear"]
                linear_models.append(LinearModel(m_S_per_N=linear["m_S_per_N"], d_S=linear["d_S"]))
        self.status = tuple(status)
        self._columns = np.array([i for i, s in enumerate(status) if s != UNCALIBRATED], dtype=np.intp)
        self._t_last_s = None
        if not self._columns.size:
            self._estimator = None
        elif kind == "sls":
            params = SLSParams(E0_Pa=np.array(e0, dtype=float), E1_Pa=np.array(e1, dtype=float),
                               mu1_Pa_s=np.array(mu1, dtype=float))
            self._estimator = SLSEstimator(params, np.array(area, dtype=float), self.physics,
                                           n_sensors=int(self._columns.size), validation=self._rule)
        else:
            self._estimator = LinearEstimator(linear_models, validation=self._rule)
