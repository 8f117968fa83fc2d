"""Run time against error, as a table, for every estimation and fitting mode the CLI exposes; the default of each is
the fastest mode within 1 % of the best error. Also the speed targets: the contact-term inverse at 36 and
1024 sensors (≥ 10 M sensor-samples/s).

Estimation (``sensnake estimate --engine/--interp/--no-contact/--float32``): 36 sensors, 1 kHz, sine forces
1–4.5 N with random phases, the typical sensor (contact term on), 0.1 % Gaussian conductance noise; error = RMS of
the estimated force against the applied one over all samples (N). Time = process time of the estimate (validation
rule + recursion, no CSV I/O), best of 3.

Fitting (``sensnake fit --fit-rate/--solver``): the paper's 4 forces, 370 s trials at 100 Hz (50 Hz with --quick),
0.2 % noise, known truth; error = the largest relative error of E0, E1, mu1 (%). Time = process time of
:func:`models.calibration.calibrate_sensor`.

"Within 1 % of the best error": errors are relative (fitting: % of the true parameter; estimation: RMS error in % of
the mean applied force), and a mode qualifies when its error is at most the best one + 1 percentage point. Among
the qualifying modes the fastest wins; times within 5 % of each other are timing noise on this shared machine and
count as a tie, which the CLI default keeps. Times are one core, process time: noisy, repeat before concluding.
Then (``--only coverage``) how often the fit's 95 % intervals hold the truth on fresh sensors, and the drift
figures (:mod:`benchmarks.bench_coverage`).
Run: ``python -m benchmarks.bench_pareto [--quick] [--only throughput|estimation|fitting|coverage]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.cli.estimate import run_estimator
from benchmarks import bench_coverage
from models.calibration import DEFAULT_FIT_RATE_HZ, DEFAULT_SOLVER, TrialInput, calibrate_sensor
from models.estimators import SLSEstimator
from models.physics import DEFAULT_PHYSICS, PhysicsConstants
from models.sls import TYPICAL_AREA_M2, TYPICAL_SLS, SLSInverse, conductance_from_force
from models.synthetic import TYPICAL_TRUTH, paper_protocol
from models.validation import ValidationRule

NOISE_REL = 1e-3
REPEATS = 3


@dataclass
class Row:
    label: str
    time: float  # ns per sensor-sample (estimation) or CPU s (fitting)
    error: float
    default: bool  # the CLI's default mode


def _pick(rows: list[Row], percent: Callable[[float], float]) -> Row:
    """The fastest row whose error (in % via ``percent``) is within 1 percentage point of the best; a CLI default
    within 5 % of its time is a tie and is kept."""
    best = min(percent(r.error) for r in rows)
    qualifying = [r for r in rows if percent(r.error) <= best + 1.0]
    fastest = min(qualifying, key=lambda r: r.time)
    default = next((r for r in qualifying if r.default), None)
    return default if default is not None and default.time <= 1.05 * fastest.time else fastest


def _estimation_table(quick: bool) -> None:
    n_sensors, rate_hz = 36, 1000.0
    seconds = 10.0 if quick else 60.0
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    rng = np.random.default_rng(7)
    force = 2.75 + 1.75 * np.sin(2 * np.pi * 0.2 * t[:, None] + rng.uniform(0, 2 * np.pi, n_sensors))
    clean = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    cond = clean * (1 + rng.normal(0.0, NOISE_REL, clean.shape))
    rule = ValidationRule.for_readout(900.0)
    rows: list[Row] = []
    for engine in ("compiled", "reference"):
        for contact in (True, False):
            for float32 in (False, True):
                for interp in ("hold", "linear"):
                    if engine == "reference" and (float32 or interp == "linear"):
                        continue  # same numbers as compiled; the slow path is timed once per contact setting
                    n = t.size
                    best_dt = np.inf
                    for _ in range(REPEATS if engine == "compiled" else 1):
                        est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, interp=interp,
                                           with_contact=contact, n_sensors=n_sensors, validation=rule)
                        start = time.process_time()
                        out, _ = run_estimator(est, cond[:n], t[:n], engine, float32)
                        best_dt = min(best_dt, time.process_time() - start)
                    err = float(np.sqrt(np.nanmean((out - force[:n]) ** 2)))
                    label = (f"{engine:<9} contact {'on ' if contact else 'off'} "
                             f"{'float32' if float32 else 'float64'} {interp}")
                    rows.append(Row(label, best_dt / (n * n_sensors) * 1e9, err,
                                    engine == "compiled" and contact and not float32 and interp == "hold"))
    mean_force = float(np.mean(force))
    pick = _pick(rows, lambda err: 100 * err / mean_force)
    print(f"\nestimation: {n_sensors} sensors at {rate_hz:g} Hz, {seconds:g} s, typical sensor with the contact term, "
          f"{NOISE_REL:.1%} noise")
    header = (f"{'mode (sensnake estimate)':<40} {'ns/sample':>10} {'M samples/s':>12} {'RMS err N':>10} "
              f"{'err %':>7}  note")
    print(header)
    print("-" * len(header))
    for r in sorted(rows, key=lambda r: r.time):
        note = ("CLI default" if r.default else "") + ("; fastest within 1 %" if r is pick else "")
        print(f"{r.label:<40} {r.time:10.1f} {1e3 / r.time:12.2f} {r.error:10.5f} {100 * r.error / mean_force:7.3f}"
              f"  {note.strip('; ')}")


def _throughput(quick: bool) -> None:
    print("\ncontact-term inverse alone (SLSInverse, compiled, float64, hold), 1 kHz sines, process time, best of 3")
    header = f"{'sensors':>8} {'samples':>9} {'M sensor-samples/s':>19} {'max err N':>10}  target ≥ 10 M/s"
    print(header)
    print("-" * len(header))
    for n_sensors, n in ((36, 20_000 if quick else 100_000), (1024, 1000 if quick else 4000)):
        t = np.arange(n) / 1000.0
        force = 3.0 + 1.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + np.linspace(0, 6, n_sensors))
        cond = conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        SLSInverse(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, n_sensors).update(t[:100], cond[:100])  # warm-up
        best = np.inf
        for _ in range(REPEATS):
            inverse = SLSInverse(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, n_sensors)
            start = time.process_time()
            out = inverse.update(t, cond)
            best = min(best, time.process_time() - start)
        rate = cond.size / best / 1e6
        err = float(np.max(np.abs(out.force_n - force)))
        print(f"{n_sensors:8d} {n:9d} {rate:19.1f} {err:10.1e}  {'met' if rate >= 10 else 'NOT met'}")


def _fitting_table(quick: bool) -> None:
    phys = PhysicsConstants()
    rate_hz = 50.0 if quick else 100.0
    seeds = (3,) if quick else (3, 4, 5)
    truth = TYPICAL_TRUTH.params_at(3.0)
    modes = [(fit_rate, solver) for fit_rate in (0.0, 30.0, 10.0, 5.0) for solver in ("gauss-newton", "scipy")]
    times = {mode: 0.0 for mode in modes}
    errors: dict[tuple[float, str], list[float]] = {mode: [] for mode in modes}
    for seed in seeds:
        trials = paper_protocol(TYPICAL_TRUTH, phys, seed=seed, repeats=1, noise_rel=0.002, rate_hz=rate_hz)
        inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
        for fit_rate, solver in modes:
            start = time.process_time()
            cal = calibrate_sensor(inputs, TYPICAL_TRUTH.area_m2, phys, saturation_s=1 / 900, solver=solver,
                                   fit_rate_hz=fit_rate or None)
            times[(fit_rate, solver)] += (time.process_time() - start) / len(seeds)
            errors[(fit_rate, solver)].append(max(abs(float(getattr(cal.sls, n)) / float(getattr(truth, n)) - 1)
                                                  for n in ("E0_Pa", "E1_Pa", "mu1_Pa_s")))
    rows: list[Row] = []
    for fit_rate, solver in modes:
        label = f"--fit-rate {fit_rate:g} --solver {solver}" if fit_rate else f"every sample, --solver {solver}"
        rows.append(Row(label, times[(fit_rate, solver)], 100 * float(np.mean(errors[(fit_rate, solver)])),
                        fit_rate == DEFAULT_FIT_RATE_HZ and solver == DEFAULT_SOLVER))
    pick = _pick(rows, lambda err: err)  # already in %
    print(f"\nfitting: 4 trials × 370 s at {rate_hz:g} Hz (0.2 % noise), known truth; error = worst of E0, E1, mu1, "
          f"mean over {len(seeds)} noise draw(s)")
    header = f"{'mode (sensnake fit)':<40} {'CPU s':>7} {'max param err %':>16}  note"
    print(header)
    print("-" * len(header))
    for r in sorted(rows, key=lambda r: r.time):
        note = ("CLI default" if r.default else "") + ("; fastest within 1 %" if r is pick else "")
        print(f"{r.label:<40} {r.time:7.2f} {r.error:16.3f}  {note.strip('; ')}")


def run(quick: bool, only: str = "") -> None:
    if only in ("", "throughput"):
        _throughput(quick)
    if only in ("", "estimation"):
        _estimation_table(quick)
    if only in ("", "fitting"):
        _fitting_table(quick)
    if only in ("", "coverage"):
        bench_coverage.run(sensors=8 if quick else 40)
        bench_coverage.run(drift=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter records")
    parser.add_argument("--only", choices=("throughput", "estimation", "fitting", "coverage"), default="")
    arguments = parser.parse_args()
    run(arguments.quick, arguments.only)
