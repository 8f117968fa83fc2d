"""How well ``sensnake lab shell`` recovers a segment's shell from the simulated rig, and how long it takes.

    python -m benchmarks.bench_shell [--quick] [--scale X] [--out DIR]

Each case puts a shell with known ``[lab.physics]`` values (stiffness, the default 30 N·s/m damping and 3 mm travel)
under the simulated rig's probe and a dial gauge on it (0.01 mm digit, 3 µm repeatability; in the ``gauge`` cases a
plunger with 1 N of measuring force falling 150 N/m, declared to the fit as a user would from its datasheet), runs
the bench test exactly as the command does (contact from the servo's current, 3 slack and 16 loaded steps up to 8 N
nominal, back to rest) and prints the fitted stiffness and travel against the truth, the 95 % interval and whether it
holds the truth, the verdicts and the wall time (the rig's clock at ``--scale``× real time; on the bench a step takes
the servo's move and a person's reading, about 10 s, some 3-4 minutes a run). Writes ``DIR/shell_bench.csv``
(default benchmarks/results).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RESULTS = Path(__file__).resolve().parent / "results"
STIFFNESSES = (1000.0, 1400.0, 2000.0, 3000.0, 5000.0)
TRAVEL_M = 0.003


def _one(stiffness: float, seed: int, scale: float, gauge: bool) -> dict[str, object]:
    from app.core.shell_bench import ShellBenchSettings, fit_bench, run_bench
    from devices import factory
    from devices.config import LabConfig
    from devices.rig import CalibrationRig

    config = LabConfig()
    config = replace(config, lab=replace(config.lab, physical=replace(
        config.lab.physical, shell_stiffness_n_per_m=stiffness, shell_travel_m=TRAVEL_M)))
    settings = ShellBenchSettings(gauge_force_n=1.0 if gauge else 0.0, gauge_rate_n_per_m=150.0 if gauge else 0.0,
                                  clock_scale=scale)
    start = time.monotonic()
    _, previous = factory.start_sim_rig_bench(config, speed=scale, seed=seed, gauge_force_n=settings.gauge_force_n,
                                              gauge_rate_n_per_m=settings.gauge_rate_n_per_m)
    try:
        rig = CalibrationRig(config.rig)
        with rig:
            data = run_bench(rig, factory.travel_gauge("sim", settings.gauge_resolution_m, seed=seed), settings)
    finally:
        factory.install_sim_lab(previous)
    fit = fit_bench(data, config, settings).fit
    wall = time.monotonic() - start
    low, high = fit.stiffness_interval
    return {"case": "gauge" if gauge else "plain", "seed": seed, "true_n_per_m": stiffness,
            "fitted_n_per_m": round(fit.stiffness_n_per_m, 1),
            "error_pct": round(100 * (fit.stiffness_n_per_m / stiffness - 1), 2),
            "low_n_per_m": round(low, 1), "high_n_per_m": round(high, 1), "holds_truth": low <= stiffness <= high,
            "stiffness_verdict": fit.not_fixed.get("shell_stiffness_n_per_m", "fixed"),
            "true_travel_mm": TRAVEL_M * 1e3,
            "fitted_travel_mm": "" if math.isnan(fit.travel_m) else round(fit.travel_m * 1e3, 4),
            "travel_verdict": "fixed" if "shell_travel_m" not in fit.not_fixed else "not fixed (never bottomed out)"
            if "never bottomed" in fit.not_fixed["shell_travel_m"] else "not fixed",
            "residual_um": round(fit.residual_rms_m * 1e6, 2), "wall_s": round(wall, 2)}


def run(quick: bool, scale: float = 20.0, out: Path | None = None) -> None:
    """Print the table; write it as CSV to ``out`` unless None (``sensnake bench`` writes nothing)."""
    seeds = (0,) if quick else (0, 1, 2)
    stiffnesses = (1400.0, 3000.0) if quick else STIFFNESSES
    rows = [_one(k, seed, scale, gauge) for gauge in (False, True) for k in stiffnesses for seed in seeds]
    print(f"shell bench test on the simulated rig ({scale:g}× real time): fitted against true, 95 % interval")
    print(f"{'case':<6} {'seed':>4} {'true':>6} {'fitted':>8} {'error':>7} {'95 % interval':>17} {'holds':>5} "
          f"{'travel mm':>9} {'residual µm':>11} {'wall s':>6}  verdicts")
    for r in rows:
        travel = f"{r['fitted_travel_mm']}" if r["fitted_travel_mm"] != "" else "—"
        print(f"{r['case']:<6} {r['seed']:>4} {r['true_n_per_m']:>6.0f} {r['fitted_n_per_m']:>8.1f} "
              f"{r['error_pct']:>+6.2f}% {r['low_n_per_m']:>8.1f}–{r['high_n_per_m']:<8.1f} "
              f"{'yes' if r['holds_truth'] else 'NO':>5} {travel:>9} {r['residual_um']:>11} {r['wall_s']:>6}  "
              f"stiffness {r['stiffness_verdict']}; travel {r['travel_verdict']}")
    held = sum(bool(r["holds_truth"]) for r in rows)
    worst = max(abs(float(r["error_pct"])) for r in rows)  # type: ignore[arg-type]
    print(f"{held} of {len(rows)} intervals hold the truth; largest error {worst:.2f} %")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "shell_bench.csv", "w", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"wrote {out / 'shell_bench.csv'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="two stiffnesses, one seed")
    parser.add_argument("--scale", type=float, default=20.0, help="the simulated rig's speed (× real time)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="folder for shell_bench.csv")
    args = parser.parse_args()
    run(args.quick, args.scale, args.out)


if __name__ == "__main__":
    main()
