"""How much the force-feedback controller's results move when it senses as a robot does instead of the truth.

    python -m benchmarks.bench_sensing [--quick] [--jobs 2]

Each condition runs twice with the same seed, once with ``[lab] sensing = "ideal"`` (the sensors' true calibration)
and once with ``"robot"`` (a rig calibration's errors drawn per sensor, ``app.core.sensing``); the board's noise and
the sensors' creep are in both. Conditions: the paper's obstacle, its settled drape played follow-the-leader at the
paper's 0.034 rad/s and at 0.1 rad/s, by the feedback law with its default gains, seeds 0-2, no tail load and 1 N;
``--quick``: 0.1 rad/s, seed 0 and 1, no load. Written: ``benchmarks/results/sensing_effect.csv`` (one row per run)
and a table per condition: the outcome at rest, the centroid's advance at rest, the play's advance, the
controller's correction (RMS over the play) and how far apart the two runs' corrections are (RMS of the
difference), the estimated bottom forces' error against the truth (RMS over the play, N).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RESULTS = Path(__file__).resolve().parent / "results" / "sensing_effect.csv"


def _run(task: dict[str, Any]) -> dict[str, Any]:
    import h5py

    from app.core.experiment import run_experiment
    from devices.config import LabConfig

    config = LabConfig()
    config = replace(config, lab=replace(config.lab, sensing=task["sensing"]))
    result = run_experiment(task["out"], config, scene="paper_obstacle", speed_rad_s=task["speed"],
                            seed=task["seed"], controller="feedback", tail_load_n=task["load"])
    with h5py.File(task["out"], "r") as f:
        end = float(f["sim"].attrs.get("motion_end_s", math.nan))
        sim_t = f["sim/time_s"][:]
        play = sim_t < end if math.isfinite(end) else np.ones(sim_t.size, bool)
        correction = f["control/correction_rad"][:][play]
        true_bottom = f["sim/bottom_true_N"][:][play]
        names = [c.decode() if isinstance(c, bytes) else str(c) for c in f["daq"].attrs["channels"]]
        bottom = [k for k, name in enumerate(names) if name.endswith("B")]
        forces = f["forces/force_N"][:][:, bottom]
        # the recording's clock: /robot's first row is the capture, /sim's time 0
        daq_t = f["daq/time_s"][:] - float(f["robot/time_s"][0])
    # the estimate at each /sim tick: the last frame at or before it
    index = np.clip(np.searchsorted(daq_t, sim_t[play], side="right") - 1, 0, max(len(daq_t) - 1, 0))
    error = forces[index] - true_bottom if len(daq_t) else np.full_like(true_bottom, np.nan)
    return {**{k: v for k, v in task.items() if k != "out"}, "valid": int(result.valid), "outcome": result.outcome,
            "advance_at_rest_m": result.advance_at_rest_m, "advance_m": result.advance_m,
            "traversed_play": int(result.traversed), "overloads": len(result.overloads),
            "correction_rms_rad": float(np.sqrt(np.mean(correction ** 2))) if correction.size else math.nan,
            "force_error_rms_n": float(np.sqrt(np.nanmean(error ** 2))) if error.size else math.nan,
            "correction": correction.tolist()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    if args.quick:
        conditions = [(0.1, seed, 0.0) for seed in (0, 1)]
    else:
        conditions = [(speed, seed, load) for speed in (0.034, 0.1) for seed in (0, 1, 2) for load in (0.0, 1.0)]
    with tempfile.TemporaryDirectory() as scratch:
        tasks = [{"speed": speed, "seed": seed, "load": load, "sensing": sensing,
                  "out": str(Path(scratch) / f"{speed}-{seed}-{load}-{sensing}.h5")}
                 for speed, seed, load in conditions for sensing in ("ideal", "robot")]
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            rows = list(pool.map(_run, tasks))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    columns = [k for k in rows[0] if k != "correction"]
    with RESULTS.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    print(f"{'rad/s':>6} {'seed':>4} {'load N':>6} | {'outcome ideal → robot':<34} | {'advance at rest m':>17} | "  # noqa: T201
          f"{'play advance m':>15} | {'correction RMS rad':>18} | {'apart rad':>9} | {'force err N':>11}")
    for k in range(0, len(rows), 2):
        ideal, robot = rows[k], rows[k + 1]
        a, b = np.array(ideal["correction"]), np.array(robot["correction"])
        n = min(len(a), len(b))
        apart = float(np.sqrt(np.mean((a[:n] - b[:n]) ** 2))) if n else math.nan
        print(f"{ideal['speed']:6g} {ideal['seed']:4d} {ideal['load']:6g} | "  # noqa: T201
              f"{ideal['outcome'] + ' → ' + robot['outcome']:<34} | "
              f"{ideal['advance_at_rest_m']:+.3f} → {robot['advance_at_rest_m']:+.3f} | "
              f"{ideal['advance_m']:+.3f} → {robot['advance_m']:+.3f} | "
              f"{ideal['correction_rms_rad']:.3f} → {robot['correction_rms_rad']:.3f} | {apart:9.3f} | "
              f"{ideal['force_error_rms_n']:.3f} → {robot['force_error_rms_n']:.3f}")
    print(f"wrote {RESULTS}")  # noqa: T201
    print(json.dumps({"runs": len(rows)}))  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
