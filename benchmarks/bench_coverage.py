"""How often the calibration's 95 % intervals hold the truth, and what a drifting baseline does to a fit.

Fresh sensors, none of them the ones the fitter was developed on (:func:`models.synthetic.random_sensor`: E0
10^5.5–10^6.3 Pa, E1 10^5.6–10^6.4 Pa, τ 60–140 s; about a third reach the readout's ceiling at 5.25 N for part of
the hold); with ``--trend`` every parameter also grows with the force, ``P(F) = P_ref·(1 + u·(F − F_ref)/F_ref)``
with u ∈ [0, 0.5] per parameter. The paper's protocol (4 forces ×
3 trials, 370 s at 6 Hz, loading ramp), Gaussian conductance noise and the board's 12-bit readout. Each sensor goes
through the whole pipeline ``sensnake fit`` runs (:func:`models.calibration.calibrate_sensor`, no drift search).

Printed per noise level: the share of per-trial intervals (E0, E1, μ1 of each trial's own fit) that hold the truth
at the trial's force, with a 95 % Wilson interval for that share (so a figure from a few hundred trials is read
with its own uncertainty); the joint fit's (constant sensors) or the force trend's slope and intercept (``--trend``).
Target (issue 29): 93–97 %. With ``--drift`` the drift figures instead: the fitted rate, τ and E1 of the plain fit
and of the drift-separating one (:func:`models.calibration.calibrate_with_drift`) for a few rates.

Run: ``python -m benchmarks.bench_coverage [--noise 0.002 0.01] [--sensors 24] [--trend] [--drift] [--jobs 2]``.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from models.calibration import TrialInput, calibrate_sensor, calibrate_with_drift
from models.fit_output import PARAM_NAMES
from models.physics import PhysicsConstants
from models.synthetic import (
    PAPER_RATE_HZ,
    TYPICAL_TRUTH,
    Readout,
    paper_protocol,
    random_sensor,
    trial_interval_hits,
)

PHYS = PhysicsConstants()
READOUT = Readout()
TARGET = (0.93, 0.97)


def wilson(hits: int, n: int) -> tuple[float, float]:
    """95 % Wilson interval of a proportion ``hits/n``."""
    if n == 0:
        return math.nan, math.nan
    z = 1.959964
    p = hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def one_sensor(seed: int, noise_rel: float, trend: bool, rate_hz: float = PAPER_RATE_HZ) -> dict[str, list[bool]]:
    """Fit one fresh sensor; per interval name, whether each of its intervals held the truth."""
    rng = np.random.default_rng(seed)
    truth = random_sensor(rng, trend)
    trials = paper_protocol(truth, PHYS, seed=int(rng.integers(1 << 30)), noise_rel=noise_rel, readout=READOUT,
                            rate_hz=rate_hz)
    inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
    cal = calibrate_sensor(inputs, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s, fit_trend=trend)
    hits = {f"trial {name}": values for name, values in trial_interval_hits(cal.trials, truth).items()}
    if trend:
        for k, name in enumerate(PARAM_NAMES):
            intercept, slope = (truth.E0_Pa, truth.E1_Pa, truth.mu1_Pa_s)[k]
            for part, value in (("intercept", intercept), ("slope", slope)):
                lo, hi = cal.trend_ci95.get(f"{name}.{part}", (math.nan, math.nan))
                hits.setdefault(f"trend {name}.{part}", []).append(bool(lo <= value <= hi))
    else:
        exact = truth.params_at(0.0)
        for name in PARAM_NAMES:
            lo, hi = cal.sls_ci95[name]
            hits.setdefault(f"joint {name}", []).append(bool(lo <= float(getattr(exact, name)) <= hi))
    return hits


def coverage(noise_rel: float, sensors: int, seed: int = 29, trend: bool = False, jobs: int = 2,
             rate_hz: float = PAPER_RATE_HZ) -> dict[str, list[bool]]:
    """Pooled hits over ``sensors`` fresh sensors (seeded from ``seed``), fitted in ``jobs`` processes."""
    seeds = [int(s) for s in np.random.SeedSequence(seed).generate_state(sensors)]
    pooled: dict[str, list[bool]] = {}
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        for hits in pool.map(one_sensor, seeds, [noise_rel] * sensors, [trend] * sensors, [rate_hz] * sensors):
            for key, values in hits.items():
                pooled.setdefault(key, []).extend(values)
    return pooled


def print_coverage(noise_levels: Sequence[float], sensors: int, seed: int, trend: bool, jobs: int,
                   rate_hz: float = PAPER_RATE_HZ) -> None:
    kind = "force-trend sensors" if trend else "constant sensors"
    print(f"\n95 % interval coverage on fresh {kind} ({sensors} per noise level, seed {seed}, {rate_hz:g} Hz; target "
          f"{100 * TARGET[0]:.0f}–{100 * TARGET[1]:.0f} %)")
    print(f"{'noise':>6}  {'interval':<24} {'n':>5} {'coverage':>9}  {'95 % Wilson':>13}  {'time':>6}")
    for noise in noise_levels:
        start = time.perf_counter()
        pooled = coverage(noise, sensors, seed, trend, jobs, rate_hz)
        took = time.perf_counter() - start
        for key, values in pooled.items():
            n, hit = len(values), int(sum(values))
            lo, hi = wilson(hit, n)
            print(f"{100 * noise:>5.2g}%  {key:<24} {n:>5} {100 * hit / n:>8.1f}%  {100 * lo:>5.1f}–{100 * hi:<5.1f}%"
                  f"  {took:>5.0f}s")
            took = 0.0


def print_drift(seed: int) -> None:
    """The plain fit and the drift-separating one on the typical sensor with a baseline ramp (0.2 % noise)."""
    print("\nBaseline drift (paper protocol, typical sensor τ = 100 s, 0.2 % noise, 12-bit readout)")
    print(f"{'drift µS/s':>10}  {'fit':<6} {'found µS/s':>10} {'τ s':>7} {'E1 err':>7}  {'time':>5}")
    truth = TYPICAL_TRUTH.params_at(0.0)
    for rate in (0.0, 0.02, 0.2):
        trials = paper_protocol(TYPICAL_TRUTH, PHYS, seed=seed, noise_rel=0.002, readout=READOUT,
                                drift_s_per_s=rate * 1e-6)
        inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
        for label, fit in (("plain", calibrate_sensor), ("drift", calibrate_with_drift)):
            start = time.perf_counter()
            cal = fit(inputs, TYPICAL_TRUTH.area_m2, PHYS, saturation_s=READOUT.saturation_s, fit_trend=False)
            took = time.perf_counter() - start
            found = "—" if cal.drift_s_per_s is None else f"{cal.drift_s_per_s * 1e6:+.4f}"
            e1 = float(cal.sls.E1_Pa) / float(truth.E1_Pa) - 1
            print(f"{rate:>+10.2f}  {label:<6} {found:>10} {float(cal.sls.tau_s):>7.1f} {100 * e1:>+6.1f}%"
                  f"  {took:>4.1f}s")


def run(noise_levels: Sequence[float] = (0.002, 0.01), sensors: int = 24, seed: int = 29, trend: bool = False,
        drift: bool = False, jobs: int = 2, rate_hz: float = PAPER_RATE_HZ) -> None:
    if drift:
        print_drift(seed)
        return
    print_coverage(noise_levels, sensors, seed, trend, jobs, rate_hz)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--noise", type=float, nargs="+", default=[0.002, 0.01],
                        help="conductance noise, relative to the hold level (default 0.002 0.01)")
    parser.add_argument("--sensors", type=int, default=24, help="fresh sensors per noise level (12 trials each)")
    parser.add_argument("--seed", type=int, default=29)
    parser.add_argument("--trend", action="store_true", help="parameters that grow with the force")
    parser.add_argument("--drift", action="store_true", help="the drift figures instead of the coverage")
    parser.add_argument("--jobs", type=int, default=2, help="processes")
    parser.add_argument("--rate", type=float, default=PAPER_RATE_HZ,
                        help="sample rate of the trials (Hz; the paper's 6 by default; faster ones are block-averaged "
                             "to 5 Hz by the fit)")
    args = parser.parse_args(argv)
    if args.sensors < 1 or args.jobs < 1 or not args.rate > 0:
        parser.error("--sensors and --jobs must be at least 1, --rate positive")
    run(args.noise, args.sensors, args.seed, args.trend, args.drift, args.jobs, args.rate)


if __name__ == "__main__":
    main()
