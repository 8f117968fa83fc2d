"""What a physics-lab run's controller senses: the forces a real robot would have, or the simulation's own truth.

A real robot's forces come through three things the simulation's truth does not have: the board's readout noise
(12-bit counts), the sensors' creep (the standard linear solid) and a calibration fitted on the rig, with its errors.
The simulated board has the first two already (``devices.sim.board``: every run's frames carry them). The third is
what this module adds: :func:`rig_calibration` is the simulated sensors' true calibration with each sensor's SLS
parameters (E0, E1, μ1) off by what a calibration on the rig is off by — a per-sensor error drawn (seeded) from the
distribution measured by fitting the simulated rig's trials (:data:`RIG_FIT_ERRORS`,
``benchmarks/bench_calibration_errors.py``).

Why drawn errors and not a fit per run: the rig calibrates one sensor at a time (4 forces × 3 trials of 370 s each),
so a fit of the robot's 36 sensors is hours of simulated time per run, and a real robot is calibrated once, not
before every run. Drawing each sensor's error from the measured distribution gives every run a calibration as good
(and as bad) as the rig's, independently per sensor, for the cost of a few random numbers.

``sensing = "robot"`` (the default) uses it; ``"ideal"`` (``--ideal-sensing``) the true calibration, the lab's path
before (noise and creep are the board's in both). Pure numerics: any thread.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.physics import PhysicsConstants, conductance_from_strain
from models.sls import SLSParams

SENSING = ("robot", "ideal")
CALIBRATION_FORCES_N = (1.75, 3.0, 4.0, 5.25)  # the paper's calibration forces: the linear model's fit points
SEED_STREAM = 0x5E4510  # the calibration errors' own random stream, apart from the lab's (same seed, other numbers)


@dataclass(frozen=True)
class FitErrors:
    """How far a rig calibration's SLS parameters are from the sensor's truth, as natural-log ratios (fitted / true)
    of (E0, E1, μ1): their mean and covariance over the sensors calibrated, and how many there were."""

    mean: tuple[float, float, float]
    cov: tuple[tuple[float, float, float], ...]
    sensors: int
    source: str

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 3) log ratios, one row per sensor."""
        return rng.multivariate_normal(np.asarray(self.mean), np.asarray(self.cov), size=n)


# Measured: benchmarks/bench_calibration_errors.py (its CSV: benchmarks/results/calibration_errors.csv), the simulated
# rig's protocol (the paper's 4 forces, 1 trial each, 370 s holds at 6 Hz, 500 s rests) fitted by `sensnake
# calibrate` on 5 sensors of the default simulated lab (S06B, S02B, S09B, S11B, S04B) against their true parameters:
# mean −0.21 % (E0), +0.34 % (E1), −0.07 % (μ1), s.d. 0.14 %, 0.36 %, 0.71 %, E1 and μ1 correlated (τ = μ1/E1 off
# by up to 1.1 %), with the loading ramp paced by the rig servo (decision 0031; with one goal per sample the s.d. of
# E1 was 1.0 % and τ was off by up to 2 %). Five sensors make a rough covariance; the simulated rig has no error of
# its own (its spring constant and the probe's area are exact), so a real rig's errors are larger.
RIG_FIT_ERRORS = FitErrors(
    mean=(-0.00208, 0.00344, -0.0007),
    cov=((1.9e-06, -4.75e-06, -9.5e-06), (-4.75e-06, 1.33e-05, 2.36e-05), (-9.5e-06, 2.36e-05, 5.05e-05)),
    sensors=5, source="benchmarks/bench_calibration_errors.py (the simulated rig, 5 sensors, 1 trial per force)")


def rig_calibration(truth: dict[str, Any], seed: int, errors: FitErrors = RIG_FIT_ERRORS) -> tuple[dict[str, Any],
                                                                                                     np.ndarray]:
    """The calibration document a rig would have given for the sensors of ``truth`` (a SPEC §3.3 document of
    their true parameters): each sensor's E0, E1 and μ1 times exp of its drawn log ratio (seeded by ``seed``), its
    linear model refitted at the paper's forces from them; and the (sensors, 3) log ratios drawn (E0, E1, μ1)."""
    fitted = copy.deepcopy(truth)
    fitted["source"] = (f"physics lab: the simulated sensors' true calibration with rig-fit errors drawn (seed "
                        f"{seed}) from {errors.source}")
    physics = PhysicsConstants.from_dict(truth["physics"]) if "physics" in truth else PhysicsConstants()
    names = list(truth["sensors"])
    ratios = errors.draw(np.random.default_rng([SEED_STREAM, seed]), len(names))
    forces = np.array(CALIBRATION_FORCES_N)
    for name, (e0, e1, mu1) in zip(names, np.exp(ratios)):
        entry = fitted["sensors"][name]
        sls = entry["sls"]
        params = SLSParams(E0_Pa=sls["E0_Pa"] * e0, E1_Pa=sls["E1_Pa"] * e1, mu1_Pa_s=sls["mu1_Pa_s"] * mu1)
        entry["sls"] = {key: float(value) for key, value in params.to_dict().items()}
        steady = conductance_from_strain(forces / entry["area_m2"] / params.b, forces, physics)
        slope, intercept = np.polyfit(forces, steady, 1)
        entry["linear"] = {"m_S_per_N": float(slope), "d_S": float(intercept)}
    return fitted, ratios


def sensing_calibration(truth: dict[str, Any], sensing: str, seed: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The calibration a run's forces are estimated with (``sensing``: ``robot`` or ``ideal``, :data:`SENSING`) and
    what to record about it (``/sim`` attribute ``sensing``: the path, and for ``robot`` the errors' source and
    each sensor's drawn error in per cent)."""
    if sensing not in SENSING:
        raise ValueError(f"sensing must be one of {', '.join(SENSING)}, got {sensing!r}")
    if sensing == "ideal":
        return truth, {"sensing": "ideal", "calibration": "the simulated sensors' true parameters"}
    fitted, ratios = rig_calibration(truth, seed)
    percent = {name: [round(100.0 * (math.exp(r) - 1.0), 3) for r in row]
               for name, row in zip(truth["sensors"], ratios.tolist())}
    return fitted, {"sensing": "robot", "calibration": "rig fit errors drawn per sensor",
                    "errors_source": RIG_FIT_ERRORS.source, "errors_sensors": RIG_FIT_ERRORS.sensors,
                    "error_percent_E0_E1_mu1": percent}
