"""How far a calibration on the simulated rig is from the simulated sensor's truth: the error distribution that
``app.core.sensing.RIG_FIT_ERRORS`` draws a physics-lab run's calibration errors from.

    python -m benchmarks.bench_calibration_errors [--sensors S06B,S02B,S09B,S11B,S04B] [--trials 1] [--out DIR]

For each sensor: a lab config putting it under the rig's probe (``[rig] sensor``), then ``sensnake calibrate --rig
sim --daq sim`` (the paper's forces 1.75, 3, 4, 5.25 N, ``--trials`` each, 370 s holds at 6 Hz, 500 s rests, the lab at
60× real time: about a minute a sensor), against ``sensnake calibrate --simulated-truth``. Writes
``benchmarks/results/calibration_errors.csv`` (sensor, then fitted / true − 1 of E0, E1, μ1 and τ) and prints the mean
and covariance of the natural-log ratios (E0, E1, μ1), the numbers :data:`app.core.sensing.RIG_FIT_ERRORS` holds.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "calibration_errors.csv"
KEYS = ("E0_Pa", "E1_Pa", "mu1_Pa_s")


def _calibrate(args: list[str]) -> None:
    subprocess.run([sys.executable, "-m", "app", "calibrate", *args], cwd=ROOT, check=True, capture_output=True)


def log_ratios(truth: dict, fitted: dict, sensor: str) -> np.ndarray:
    """ln(fitted / true) of E0, E1, μ1 for ``sensor``."""
    true, fit = truth["sensors"][sensor]["sls"], fitted["sensors"][sensor]["sls"]
    return np.array([math.log(fit[k] / true[k]) for k in KEYS])


def summarise(ratios: np.ndarray) -> tuple[list[float], list[list[float]]]:
    """Mean and covariance (ddof 1) of the log ratios (sensors × 3)."""
    return ratios.mean(axis=0).tolist(), np.atleast_2d(np.cov(ratios, rowvar=False)).tolist()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", default="S06B,S02B,S09B,S11B,S04B")
    parser.add_argument("--trials", type=int, default=1, help="trials per force (the paper's protocol: 3)")
    parser.add_argument("--out", type=Path, default=None, help="keep the calibration files here (default: scratch)")
    parser.add_argument("--from-dir", type=Path, default=None,
                        help="summarise calibrations already made: truth.json and fit_<SENSOR>.json in this folder")
    args = parser.parse_args(argv)
    sensors = [s.strip() for s in args.sensors.split(",") if s.strip()]
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.from_dir or args.out or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        if args.from_dir is None:
            _calibrate(["--simulated-truth", "--out", str(folder / "truth.json")])
            for sensor in sensors:
                config = folder / f"lab_{sensor}.toml"
                config.write_text(f'[rig]\nsensor = "{sensor}"\n', encoding="utf-8")
                _calibrate(["--config", str(config), "--rig", "sim", "--daq", "sim", "--forces", "1.75,3,4,5.25",
                            "--trials", str(args.trials), "--rest", "500", "--time-scale", "60",
                            "--out", str(folder / f"fit_{sensor}.json")])
        truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
        rows, ratios = [], []
        for sensor in sensors:
            path = folder / f"fit_{sensor}.json"
            if not path.exists():
                print(f"{sensor}: no calibration ({path.name})", file=sys.stderr)  # noqa: T201
                continue
            fitted = json.loads(path.read_text(encoding="utf-8"))
            r = log_ratios(truth, fitted, sensor)
            ratios.append(r)
            tau = (fitted["sensors"][sensor]["sls"]["mu1_Pa_s"] / fitted["sensors"][sensor]["sls"]["E1_Pa"]) / (
                truth["sensors"][sensor]["sls"]["mu1_Pa_s"] / truth["sensors"][sensor]["sls"]["E1_Pa"])
            rows.append([sensor, *(f"{math.exp(v) - 1:.5f}" for v in r), f"{tau - 1:.5f}"])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with RESULTS.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sensor", "E0_rel_error", "E1_rel_error", "mu1_rel_error", "tau_rel_error"])
        writer.writerows(rows)
    for row in rows:
        print(" ".join(f"{v:>13}" for v in row))  # noqa: T201
    if len(ratios) >= 2:
        mean, cov = summarise(np.array(ratios))
        print(f"log ratios (E0, E1, mu1) over {len(ratios)} sensors: mean {np.round(mean, 5).tolist()}")  # noqa: T201
        print(f"covariance {np.round(cov, 6).tolist()}")  # noqa: T201
    print(f"wrote {RESULTS}")  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
