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
Target: 93–97 %. With ``--drift`` the drift figures instead: the fitted rate, τ and E1 of the plain fit
and of the drift-separating one (:func:`models.calibration.calibrate_with_drift`) for a few rates.

Run: ``python -m benchmarks.bench_coverage [--noise 0.002 0.01] [--sensors 24] [--trend] [--drift] [--jobs 2]``.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.calibration import TrialInput, calibrate_sensor, calibrate_with_drift
from models.fit_output import PARAM_NAMES
from models.physics import PhysicsConstants
from models.synthetic import (
    PAPER_RATE_HZ,
    TYPICAL_TRUTH,
    Readout,
    SensorTruth,
    SyntheticTrial,
    paper_protocol,
    random_sensor,
    trial_interval_hits,
)

PHYS = PhysicsConstants()
READOUT = Readout()
TARGET = (0.93, 0.97)
PAPER_TRIALS = 12  # the paper's protocol: 4 forces × 3 trials per sensor


def wilson(hits: int, n: int) -> tuple[float, float]:
    """95 % Wilson interval of a proportion ``hits/n``."""
    if n == 0:
        return math.nan, math.nan
    z = 1.959964
    p = hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


PIPELINES = ("fit", "sensor")  # fit: what `sensnake fit` runs by default; sensor: calibrate_sensor, no drift search
# A run of only the sensors that reach the readout's ceiling (--ceiling-only) is stored under its pipeline's name with
# this suffix (its rows are a table row of their own).
CEILING_ONLY = ":ceiling"
RESULTS_CSV = Path(__file__).resolve().parent / "results" / "coverage.csv"


def one_sensor(seed: int, noise_rel: float, trend: bool, rate_hz: float = PAPER_RATE_HZ,
               pipeline: str = "sensor") -> dict[str, list[bool]]:
    """Fit one fresh sensor; per interval name, whether each of its intervals held the truth."""
    return sensor_record(seed, noise_rel, trend, rate_hz, pipeline)[0]


def sensor_record(seed: int, noise_rel: float, trend: bool, rate_hz: float = PAPER_RATE_HZ,
                  pipeline: str = "sensor") -> tuple[dict[str, list[bool]], dict[str, float]]:
    """Fit one fresh sensor: (per interval name, whether each interval held the truth; what else was seen —
    whether it reached the readout's ceiling, the drift claimed (µS/s), the fit's CPU seconds).

    ``pipeline`` ``"fit"``: what ``sensnake fit`` runs by default (:func:`models.calibration.calibrate_with_drift`,
    force trend on, block-averaging to 5 Hz); ``"sensor"``: :func:`models.calibration.calibrate_sensor` with the force
    trend only on trend sensors (the figures before the drift search was the default)."""
    pipeline = pipeline.removesuffix(CEILING_ONLY)
    truth, trials = fresh_trials(seed, noise_rel, trend, rate_hz)
    inputs = [TrialInput(t.name, t.time_s, t.force_n, t.conductance_s) for t in trials]
    start = time.process_time()
    if pipeline == "fit":
        cal = calibrate_with_drift(inputs, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s)
    else:
        cal = calibrate_sensor(inputs, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s, fit_trend=trend)
    cpu_s = time.process_time() - start
    hits = {f"trial {name}": values for name, values in trial_interval_hits(cal.trials, truth).items()}
    if cal.trend_ci95:
        for k, name in enumerate(PARAM_NAMES):
            intercept, slope = (truth.E0_Pa, truth.E1_Pa, truth.mu1_Pa_s)[k]
            for part, value in (("intercept", intercept), ("slope", slope)):
                lo, hi = cal.trend_ci95.get(f"{name}.{part}", (math.nan, math.nan))
                hits.setdefault(f"trend {name}.{part}", []).append(bool(lo <= value <= hi))
    if not trend:
        exact = truth.params_at(0.0)
        for name in PARAM_NAMES:
            lo, hi = cal.sls_ci95[name]
            hits.setdefault(f"joint {name}", []).append(bool(lo <= float(getattr(exact, name)) <= hi))
    info = {"ceiling": float(any(t.saturated.any() for t in trials)),
            "drift_uS_per_s": float((cal.drift_s_per_s or 0.0) * 1e6), "cpu_s": cpu_s, "trials": float(len(trials)),
            "steps": float(len(cal.steps)), "settling": float(math.isfinite(cal.drift_tau_s))}
    return hits, info


def fresh_trials(seed: int, noise_rel: float, trend: bool, rate_hz: float = PAPER_RATE_HZ
                 ) -> tuple[SensorTruth, list[SyntheticTrial]]:
    """The fresh sensor of ``seed`` and its trials (the paper's protocol, the 12-bit readout)."""
    rng = np.random.default_rng(seed)
    truth = random_sensor(rng, trend)
    return truth, paper_protocol(truth, PHYS, seed=int(rng.integers(1 << 30)), noise_rel=noise_rel, readout=READOUT,
                                 rate_hz=rate_hz)


def reaches_ceiling(seed: int, noise_rel: float, trend: bool, rate_hz: float = PAPER_RATE_HZ) -> bool:
    """Whether the fresh sensor of ``seed`` reaches the readout's ceiling in some trial (simulated, not fitted)."""
    return any(t.saturated.any() for t in fresh_trials(seed, noise_rel, trend, rate_hz)[1])


def coverage(noise_rel: float, sensors: int, seed: int = 29, trend: bool = False, jobs: int = 2,
             rate_hz: float = PAPER_RATE_HZ, pipeline: str = "sensor") -> dict[str, list[bool]]:
    """Pooled hits over ``sensors`` fresh sensors (seeded from ``seed``), fitted in ``jobs`` processes."""
    return pooled_hits(records(noise_rel, sensors, seed, trend, jobs, rate_hz, pipeline))


def sensor_seeds(seed: int, sensors: int) -> list[int]:
    """The sensors' seeds drawn from ``seed`` (the i-th sensor of a run is the same whatever the count)."""
    return [int(s) for s in np.random.SeedSequence(seed).generate_state(sensors)]


def records(noise_rel: float, sensors: int, seed: int = 29, trend: bool = False, jobs: int = 2,
            rate_hz: float = PAPER_RATE_HZ, pipeline: str = "sensor",
            ) -> list[tuple[dict[str, list[bool]], dict[str, float]]]:
    """:func:`sensor_record` of ``sensors`` fresh sensors, in seed order (a ``pipeline`` ending in
    :data:`CEILING_ONLY`: the first ``sensors`` of the seed's sequence that reach the readout's ceiling)."""
    return [record for _, record in indexed_records(noise_rel, sensors, seed, trend, jobs, rate_hz, pipeline)]


def indexed_records(noise_rel: float, sensors: int, seed: int = 29, trend: bool = False, jobs: int = 2,
                    rate_hz: float = PAPER_RATE_HZ, pipeline: str = "sensor",
                    ) -> list[tuple[int, tuple[dict[str, list[bool]], dict[str, float]]]]:
    """:func:`records` with each sensor's index in the seed's sequence (:func:`sensor_seeds`)."""
    if pipeline.endswith(CEILING_ONLY):
        indices: list[int] = []
        index = 0
        while len(indices) < sensors:
            if index >= 50 * sensors:
                raise RuntimeError(f"fewer than {sensors} of {index} fresh sensors reach the readout's ceiling")
            candidate = sensor_seeds(seed, index + 1)[index]
            if reaches_ceiling(candidate, noise_rel, trend, rate_hz):
                indices.append(index)
            index += 1
    else:
        indices = list(range(sensors))
    all_seeds = sensor_seeds(seed, max(indices) + 1)
    seeds = [all_seeds[i] for i in indices]
    n = len(seeds)
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        return list(zip(indices, pool.map(sensor_record, seeds, [noise_rel] * n, [trend] * n, [rate_hz] * n,
                                          [pipeline] * n), strict=True))


def pooled_hits(rows: Sequence[tuple[dict[str, list[bool]], dict[str, float]]],
                ceiling: bool | None = None) -> dict[str, list[bool]]:
    """The hits of ``rows`` pooled per interval name (``ceiling``: only sensors that reached / did not reach the
    readout's ceiling; None: all)."""
    pooled: dict[str, list[bool]] = {}
    for hits, info in rows:
        if ceiling is not None and bool(info["ceiling"]) != ceiling:
            continue
        for key, values in hits.items():
            pooled.setdefault(key, []).extend(values)
    return pooled


def summary_rows(rows: Sequence[tuple[dict[str, list[bool]], dict[str, float]]]) -> list[tuple[str, int, int]]:
    """(label, hits, n) per interval name, then the pooled per-trial and force-trend figures and the per-trial
    figure of the sensors that did / did not reach the ceiling: the lines of the printed table and of
    docs/NUMERICS.md."""
    out: list[tuple[str, int, int]] = []
    pooled = pooled_hits(rows)
    for key, values in pooled.items():
        out.append((key, int(sum(values)), len(values)))
    for label, prefix, subset in (("per trial, all", "trial ", None), ("per trial, ceiling sensors", "trial ", True),
                                  ("per trial, no ceiling", "trial ", False), ("trend, all", "trend ", None)):
        values = [h for key, v in pooled_hits(rows, subset).items() if key.startswith(prefix) for h in v]
        if values:
            out.append((label, int(sum(values)), len(values)))
    # A refused trial (τ unresolved alone, or its likelihood flatter at the ceiling than its interval assumes) has no
    # interval: counted as a miss, the share of all trials whose three intervals hold the truth.
    trials = sum(int(info.get("trials", PAPER_TRIALS)) for _, info in rows)
    given = sum(len(hits.get("trial E0_Pa", [])) for hits, _ in rows)
    held = sum(int(sum(v)) for hits, _ in rows for key, v in hits.items() if key.startswith("trial "))
    out.append(("trials refused (no interval)", trials - given, trials))
    out.append(("per trial, refused = miss", held, 3 * trials))
    return out


def print_coverage(noise_levels: Sequence[float], sensors: int, seed: int, trend: bool, jobs: int,
                   rate_hz: float = PAPER_RATE_HZ, pipeline: str = "sensor", csv_path: Path | None = None) -> None:
    kind = ("force-trend sensors" if trend else "constant sensors") + (
        " that reach the readout's ceiling" if pipeline.endswith(CEILING_ONLY) else "")
    what = ("`sensnake fit` (drift search, force trend)" if pipeline.removesuffix(CEILING_ONLY) == "fit"
            else "calibrate_sensor (no drift search)")
    print(f"\n95 % interval coverage on fresh {kind} ({sensors} per noise level, seed {seed}, {rate_hz:g} Hz, "
          f"{what}; target {100 * TARGET[0]:.0f}–{100 * TARGET[1]:.0f} %)")
    print(f"{'noise':>6}  {'interval':<28} {'n':>5} {'coverage':>9}  {'95 % Wilson':>13}")
    lines: list[str] = []
    for noise in noise_levels:
        start, cpu_start = time.perf_counter(), time.process_time()
        indexed = indexed_records(noise, sensors, seed, trend, jobs, rate_hz, pipeline)
        rows = [record for _, record in indexed]
        took = time.perf_counter() - start
        print_rows(noise, rows)
        print(f"{100 * noise:>5.2g}%  {took:.0f} s wall ({time.process_time() - cpu_start:.0f} s CPU in this process)")
        for i, (hits, info) in indexed:
            cells = ";".join(f"{key}={int(sum(v))}/{len(v)}" for key, v in hits.items())
            lines.append(f"{pipeline},{int(trend)},{rate_hz:g},{noise:g},{seed},{i},{int(info['ceiling'])},"
                         f"{info['drift_uS_per_s']:.6g},{info['cpu_s']:.3f},{cells}")
    if csv_path is not None:
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        header = "pipeline,trend,rate_hz,noise_rel,seed,sensor,ceiling,drift_uS_per_s,cpu_s,hits\n"
        csv_path.write_text(header + "".join(line + "\n" for line in lines))
        print(f"per-sensor hits written to {csv_path}")


def print_rows(noise: float, rows: Sequence[tuple[dict[str, list[bool]], dict[str, float]]]) -> None:
    """The table's lines of one noise level (:func:`summary_rows`, with Wilson intervals) and what else was seen."""
    for label, hit, n in summary_rows(rows):
        lo, hi = wilson(hit, n)
        print(f"{100 * noise:>5.2g}%  {label:<28} {n:>5} {100 * hit / n:>8.1f}%  {100 * lo:>5.1f}–{100 * hi:<5.1f}%")
    ceiling = sum(int(info["ceiling"]) for _, info in rows)
    drift = sum(abs(info["drift_uS_per_s"]) > 0 for _, info in rows)
    cpu = [info["cpu_s"] for _, info in rows]
    steps = sum(info.get("steps", 0.0) > 0 for _, info in rows)
    settling = sum(info.get("settling", 0.0) > 0 for _, info in rows)
    print(f"{100 * noise:>5.2g}%  {ceiling} of {len(rows)} sensors reach the ceiling; a drift claimed on {drift} "
          f"(none drifts), a settling baseline on {settling}, a step in the reading on {steps} (none has either); "
          f"fit CPU {np.median(cpu):.2f} s median, {max(cpu):.2f} s max per sensor")


def docs_table(runs: dict[tuple[str, int, float, float], list[tuple[dict[str, list[bool]], dict[str, float]]]]
               ) -> list[str]:
    """The coverage table of docs/NUMERICS.md, one row per run of a CSV written by ``--csv`` (tests/test_fit_figures.py
    checks the page holds these lines)."""
    lines = ["| sensors, rate | noise | sensors (at the ceiling) | trials refused | per trial E0 / E1 / μ1 | per trial "
             "pooled (95 % Wilson) | ceiling sensors / the rest | refused counted as misses | force trend pooled | "
             "joint E0 / E1 / μ1 |",
             "|---|---|---|---|---|---|---|---|---|---|"]

    def pct(hit: int, n: int) -> str:
        return f"{100 * hit / n:.1f}" if n else "—"

    for (pipeline, trend, rate, noise), rows in runs.items():
        figures = {label: (hit, n) for label, hit, n in summary_rows(rows)}

        def share(label: str, figures: dict[str, tuple[int, int]] = figures) -> str:
            return pct(*figures.get(label, (0, 0)))

        pooled = figures["per trial, all"]
        lo, hi = wilson(*pooled)
        joint = " / ".join(share(f"joint {n}") for n in PARAM_NAMES) + " %" if f"joint {PARAM_NAMES[0]}" in figures \
            else "—"
        base = pipeline.removesuffix(CEILING_ONLY)
        kind = (("trend" if trend else "constant") + ("" if base == "fit" else f" ({base})")
                + (", only sensors at the ceiling" if pipeline.endswith(CEILING_ONLY) else ""))
        refused, trials = figures["trials refused (no interval)"]
        lines.append(
            f"| {kind}, {rate:g} Hz | {100 * noise:g} % | {len(rows)} ({sum(int(i['ceiling']) for _, i in rows)}) | "
            f"{refused} of {trials} | {' / '.join(share(f'trial {n}') for n in PARAM_NAMES)} % | "
            f"**{pct(*pooled)} %** ({100 * lo:.1f}–{100 * hi:.1f}) | {share('per trial, ceiling sensors')} / "
            f"{share('per trial, no ceiling')} % | {share('per trial, refused = miss')} % | {share('trend, all')} % | "
            f"{joint} |")
    return lines


def read_records(csv_path: Path = RESULTS_CSV) -> dict[tuple[str, int, float, float], list[
        tuple[dict[str, list[bool]], dict[str, float]]]]:
    """The per-sensor rows of a CSV written by ``--csv``, keyed by (pipeline, trend, rate, noise), as
    :func:`records` returns them (hits as counts expanded to booleans)."""
    out: dict[tuple[str, int, float, float], list[tuple[dict[str, list[bool]], dict[str, float]]]] = {}
    for line in csv_path.read_text().splitlines()[1:]:
        pipeline, trend, rate, noise, _seed, _i, ceiling, drift, cpu, cells = line.split(",", 9)
        hits: dict[str, list[bool]] = {}
        for cell in cells.split(";"):
            key, counts = cell.split("=")
            hit, n = (int(x) for x in counts.split("/"))
            hits[key] = [True] * hit + [False] * (n - hit)
        info = {"ceiling": float(ceiling), "drift_uS_per_s": float(drift), "cpu_s": float(cpu)}
        out.setdefault((pipeline, int(trend), float(rate), float(noise)), []).append((hits, info))
    return out


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


BASELINES = ("none", "linear", "settling", "step")


@dataclass(frozen=True)
class BaselineResult:
    """One sensor of :func:`baseline_record`: what the baseline was named as, whether the fit is degenerate, τ's
    relative error, and whether each per-trial and joint interval held the truth."""

    named: str
    degenerate: bool
    tau_error: float
    trial: list[bool]
    joint: list[bool]


def baseline_record(seed: int, kind: str) -> BaselineResult:
    """One fresh sensor (paper protocol, 0.2 % noise, 12-bit readout) whose readings carry a baseline of ``kind``:
    none; a linear drift of 0.02–0.2 µS/s; one settling by 10–40 µS with a time constant of 80–300 s; a step of
    8–15 µS at 120–300 s into each trial (the force unchanged). Fitted as ``sensnake fit`` does: what it was named,
    τ's error, and whether the per-trial and joint intervals hold the truth."""
    rng = np.random.default_rng(seed)
    truth = random_sensor(rng)
    trials = paper_protocol(truth, PHYS, seed=int(rng.integers(1 << 30)), noise_rel=0.002)
    rate, amplitude, tau_b = rng.uniform(0.02e-6, 0.2e-6), rng.uniform(10e-6, 40e-6), rng.uniform(80.0, 300.0)
    inputs = []
    for t in trials:
        baseline = {"none": np.zeros(t.time_s.size), "linear": rate * t.time_s,
                    "settling": amplitude * -np.expm1(-t.time_s / tau_b),
                    "step": rng.uniform(8e-6, 15e-6) * (t.time_s >= rng.uniform(120.0, 300.0))}[kind]
        inputs.append(TrialInput(t.name, t.time_s, t.force_n, READOUT.quantise(t.conductance_s + baseline)[0]))
    cal = calibrate_with_drift(inputs, truth.area_m2, PHYS, saturation_s=READOUT.saturation_s)
    named = ("step" if cal.steps else "settling" if math.isfinite(cal.drift_tau_s)
             else "linear" if cal.drift_s_per_s else "none")
    exact = truth.params_at(0.0)
    return BaselineResult(named, cal.degenerate, float(cal.sls.tau_s) / float(exact.tau_s) - 1,
                          [h for values in trial_interval_hits(cal.trials, truth).values() for h in values],
                          [bool(cal.sls_ci95[n][0] <= float(getattr(exact, n)) <= cal.sls_ci95[n][1])
                           for n in PARAM_NAMES])


def print_baselines(seed: int, sensors: int, jobs: int) -> None:
    """What each kind of baseline is named as, τ's error and the intervals' coverage (:func:`baseline_record`)."""
    print(f"\nBaselines on fresh sensors ({sensors} per kind, seed {seed}, paper protocol, 0.2 % noise, 12-bit readout, "
          "`sensnake fit`)")
    print(f"{'baseline':<9} {'named as':<40} {'degenerate':>10} {'τ error median / max':>21} {'per trial':>15} "
          f"{'joint':>13}")
    seeds = sensor_seeds(seed, sensors)
    for kind in BASELINES:
        with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
            rows = list(pool.map(baseline_record, seeds, [kind] * sensors))
        names = ", ".join(f"{name} {sum(r.named == name for r in rows)}" for name in BASELINES
                          if any(r.named == name for r in rows))
        errors = np.abs([r.tau_error for r in rows])
        trial = [h for r in rows for h in r.trial]
        joint = [h for r in rows for h in r.joint]
        degenerate = sum(r.degenerate for r in rows)
        trial_share = f"{100 * np.mean(trial):>6.1f} % of {len(trial):<4}" if trial else f"{'— (all refused)':>15}"
        print(f"{kind:<9} {names:<40} {degenerate:>10} {100 * np.median(errors):>9.1f} / {100 * errors.max():.1f} % "
              f"{trial_share} {100 * np.mean(joint):>5.1f} % of {len(joint)}")


def run(noise_levels: Sequence[float] = (0.002, 0.01), sensors: int = 24, seed: int = 29, trend: bool = False,
        drift: bool = False, jobs: int = 2, rate_hz: float = PAPER_RATE_HZ, pipeline: str = "fit",
        csv_path: Path | None = None, quick: bool | None = None) -> None:
    """The coverage table (or the drift figures); ``quick`` (``sensnake bench``): 8 sensors per noise level."""
    if quick is not None:
        sensors = 8 if quick else sensors
    if drift:
        print_drift(seed)
        return
    print_coverage(noise_levels, sensors, seed, trend, jobs, rate_hz, pipeline, csv_path)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--noise", type=float, nargs="+", default=[0.002, 0.01],
                        help="conductance noise, relative to the hold level (default 0.002 0.01)")
    parser.add_argument("--sensors", type=int, default=24, help="fresh sensors per noise level (12 trials each)")
    parser.add_argument("--seed", type=int, default=29)
    parser.add_argument("--trend", action="store_true", help="parameters that grow with the force")
    parser.add_argument("--drift", action="store_true", help="the drift figures instead of the coverage")
    parser.add_argument("--baselines", action="store_true",
                        help="fresh sensors with no baseline, a linear drift, a settling baseline and a step in each "
                             "trial: what each is named as, τ's error and the intervals' coverage")
    parser.add_argument("--jobs", type=int, default=2, help="processes")
    parser.add_argument("--rate", type=float, default=PAPER_RATE_HZ,
                        help="sample rate of the trials (Hz; the paper's 6 by default; faster ones are block-averaged "
                             "to 5 Hz by the fit)")
    parser.add_argument("--pipeline", choices=PIPELINES, default="fit",
                        help="fit: what `sensnake fit` runs by default (drift search, force trend; the default); "
                             "sensor: calibrate_sensor alone")
    parser.add_argument("--ceiling-only", action="store_true",
                        help="only fresh sensors that reach the readout's ceiling (the first --sensors of the seed's "
                             "sequence that do; a table row of their own)")
    parser.add_argument("--csv", type=Path, default=None,
                        help=f"write every sensor's hits here (the docs' figures: {RESULTS_CSV.name} in "
                             "benchmarks/results/)")
    parser.add_argument("--from-csv", type=Path, default=None,
                        help="print the tables of a CSV written by --csv instead of fitting")
    args = parser.parse_args(argv)
    if args.from_csv is not None:
        for (pipeline, trend, rate, noise), rows in read_records(args.from_csv).items():
            print(f"\n{pipeline}, {'force-trend' if trend else 'constant'} sensors, {rate:g} Hz, {len(rows)} sensors")
            print_rows(noise, rows)
        print("\nThe table of docs/NUMERICS.md:")
        print("\n".join(docs_table(read_records(args.from_csv))))
        return
    if args.sensors < 1 or args.jobs < 1 or not args.rate > 0:
        parser.error("--sensors and --jobs must be at least 1, --rate positive")
    if args.baselines:
        print_baselines(args.seed, args.sensors, args.jobs)
        return
    pipeline = args.pipeline + (CEILING_ONLY if args.ceiling_only else "")
    run(args.noise, args.sensors, args.seed, args.trend, args.drift, args.jobs, args.rate, pipeline, args.csv)


if __name__ == "__main__":
    main()
