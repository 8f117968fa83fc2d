"""The calibration's 95 % intervals hold the truth about 95 % of the time, on sensors the fitter was not tuned on.

Fresh random sensors (models.synthetic.random_sensor, seeds of this file only), the paper's protocol, the 12-bit
readout (a third of the sensors reach its ceiling for part of their 5.25 N holds), the whole pipeline
``sensnake fit`` runs. The wider benchmark (720 trials per row through the default pipeline with its drift search,
force trends and 30/100 Hz too) is ``python -m benchmarks.bench_coverage``; the figures are in docs/NUMERICS.md.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.calibration import TrialInput, calibrate_sensor
from models.fit_output import PARAM_NAMES
from models.physics import PhysicsConstants
from models.synthetic import Readout, SensorTruth, paper_protocol, random_sensor, trial_interval_hits

PHYS = PhysicsConstants()
READOUT = Readout()


def _fit(truth: SensorTruth, seed: int, noise_rel: float, trend: bool = False, rate_hz: float = 6.0):
    trials = paper_protocol(truth, PHYS, seed=seed, noise_rel=noise_rel, readout=READOUT, rate_hz=rate_hz)
    inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
    return trials, calibrate_sensor(inputs, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s, fit_trend=trend)


@pytest.mark.parametrize("noise_rel", [0.002, 0.01])
def test_per_trial_intervals_cover_the_truth_on_240_fresh_trials(noise_rel):
    rng = np.random.default_rng(2029 + int(noise_rel * 1e4))
    hits: dict[str, list[bool]] = {name: [] for name in PARAM_NAMES}
    for _ in range(20):
        truth = random_sensor(rng)
        _, cal = _fit(truth, int(rng.integers(1 << 30)), noise_rel)
        for name, values in trial_interval_hits(cal.trials, truth).items():
            hits[name] += values
        for report in (r for r in cal.trials if r.refused is None):  # an interval holds its own estimate
            for name in PARAM_NAMES:
                assert report.ci95[name][0] <= float(getattr(report.params, name)) <= report.ci95[name][1]
    n = len(hits["E0_Pa"])
    assert n >= 200
    pooled = float(np.mean([h for values in hits.values() for h in values]))
    # The target is 93–97 %; each parameter's share from ~230 trials has a standard error of ~1.4 points.
    assert 0.93 <= pooled <= 0.97, f"pooled coverage {pooled:.3f} over {n} trials"
    for name, values in hits.items():
        assert 0.90 <= float(np.mean(values)) <= 0.99, f"{name}: {np.mean(values):.3f} over {n} trials"


def test_trials_a_quarter_saturated_are_not_biased():
    """Near the readout's ceiling the noise decides which samples come out as numbers: fitted as if those were the
    whole story (a one-sided penalty on the censored ones), E1 came out 2–4 standard errors high on every such trial.
    The censored likelihood leaves the standardised errors centred and of unit spread, E1's included: such trials'
    E1 intervals are not said to be possibly too narrow any more, because they are not."""
    rng = np.random.default_rng(77)
    z: list[float] = []
    z_e1: list[float] = []
    saturated_trials = 0
    for _ in range(60):
        if saturated_trials >= 24:
            break
        # Soft enough that the 5.25 N holds reach the ceiling (a quarter to a half of them on about half the draws).
        e0, e1 = 10 ** rng.uniform(5.6, 5.8), 10 ** rng.uniform(5.7, 6.1)
        truth = SensorTruth.constant(e0, e1, e1 * rng.uniform(70.0, 130.0))
        seed = int(rng.integers(1 << 30))
        trials = paper_protocol(truth, PHYS, seed=seed, noise_rel=0.002, readout=READOUT)
        if not any(0.05 < float(np.mean(t.saturated)) < 0.5 for t in trials):
            continue  # no trial of this draw is one of those looked at: not fitted (the test's time)
        trials, cal = _fit(truth, seed, 0.002)
        for trial, report in zip(trials, cal.trials):
            fraction = float(np.mean(trial.saturated))
            if report.refused is not None or not 0.05 < fraction < 0.5:
                continue
            saturated_trials += 1
            assert not any("interval may be too narrow" in w for w in report.warnings)
            for name in PARAM_NAMES:
                lo, hi = report.ci95[name]
                se = (math.log(hi) - math.log(lo)) / (2 * 1.96)
                z.append((math.log(float(getattr(report.params, name))) - math.log(float(getattr(trial.params, name))))
                         / se)
                if name == "E1_Pa":
                    z_e1.append(z[-1])
    assert saturated_trials >= 24
    z_arr = np.array(z)
    assert abs(float(np.mean(z_arr))) < 0.4, f"mean standardised error {np.mean(z_arr):+.2f}"
    assert 0.7 < float(np.std(z_arr)) < 1.3, f"spread of standardised errors {np.std(z_arr):.2f}"
    # E1's own intervals are no longer too narrow on these trials (s.d. 1.5–1.9 once, and a warning said so): they
    # are given without that warning, and its standardised errors have no more than unit spread (measured 0.74).
    assert float(np.std(z_e1)) < 1.3, f"E1's standardised errors: s.d. {np.std(z_e1):.2f}"
    assert float(np.mean(np.abs(z_e1) <= 1.96)) >= 0.85, "E1's intervals hold the truth too rarely"


def test_force_trend_intervals_cover_the_truth():
    """Slope and intercept of each parameter's force trend (delta-method intervals) on fresh trend sensors."""
    rng = np.random.default_rng(4242)
    hits: list[bool] = []
    for _ in range(12):
        truth = random_sensor(rng, trend=True)
        _, cal = _fit(truth, int(rng.integers(1 << 30)), 0.002, trend=True)
        for k, name in enumerate(PARAM_NAMES):
            intercept, slope = (truth.E0_Pa, truth.E1_Pa, truth.mu1_Pa_s)[k]
            for part, value in (("intercept", intercept), ("slope", slope)):
                lo, hi = cal.trend_ci95[f"{name}.{part}"]
                hits.append(lo <= value <= hi)
    # 72 intervals (6 per sensor, correlated): the benchmark measured 92.5–95.3 % pooled (60 sensors per row).
    assert 0.86 <= float(np.mean(hits)) <= 1.0, f"force-trend coverage {np.mean(hits):.3f}"


def test_intervals_cover_on_trials_recorded_at_the_boards_30_hz():
    """Faster trials are block-averaged to 5 Hz before the fit; averaging through the loading ramp and at the
    ceiling too put these intervals at 35 % coverage. Blocks are now averaged only where the force holds still and
    the readout is clear of its ceiling, each weighed by the samples it stands for."""
    rng = np.random.default_rng(3030)
    hits: list[bool] = []
    for _ in range(10):
        truth = random_sensor(rng)
        _, cal = _fit(truth, int(rng.integers(1 << 30)), 0.002, rate_hz=30.0)
        hits += [h for values in trial_interval_hits(cal.trials, truth).values() for h in values]
    assert len(hits) >= 300
    assert 0.91 <= float(np.mean(hits)) <= 0.99, f"coverage {np.mean(hits):.3f} over {len(hits) // 3} trials"
