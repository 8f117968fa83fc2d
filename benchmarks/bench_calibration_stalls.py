"""A calibration on a busy computer: ``sensnake calibrate`` on the simulated rig with the rig's thread held up, against
the simulated sensor's truth.

    python -m benchmarks.bench_calibration_stalls [--runs 4] [--stall-ms 40] [--share 0.02] [--time-scale 60]

Each run: the paper's 4 forces, one trial each, a sensor creeping with τ = 20 s (100 s holds and rests) at
``--time-scale`` × real time, the rig's force reads held up ``--stall-ms`` before and after a ``--share`` of them,
at random (seeded by the run). Prints per run the exit code, the trials run again (a loading edge the record missed)
and the fitted E0, E1, μ1 against the truth, and the wall time; ``--share 0`` measures a quiet run (run it beside a
load generator to measure a busy machine). A kept calibration is accurate or the run ends saying why: never a
"poor fit" or a modulus several per cent off from the host's timing.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import random
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("E0_Pa", "E1_Pa", "mu1_Pa_s")
LAB_TOML = '[board]\nrate_hz = 12.0\n[lab]\nphysics = "scripted"\nsensor_tau_s = 20.0\n'


def run_once(seed: int, stall_s: float, share: float, time_scale: float) -> dict:
    """One calibration with the rig's reads held up; its outcome against the truth."""
    from app.cli.main import main
    from devices import rig as rig_module
    from devices.config import load_config
    from devices.sim.lab import SimLab

    rng = random.Random(seed)
    read = rig_module.CalibrationRig.applied_force_n

    def held_up(self: rig_module.CalibrationRig) -> float:
        if rng.random() < share:
            time.sleep(stall_s)
        force = read(self)
        if rng.random() < share:
            time.sleep(stall_s)
        return force

    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        config = folder / "lab.toml"
        config.write_text(LAB_TOML, encoding="utf-8")
        out = folder / "cal.json"
        said = io.StringIO()
        rig_module.CalibrationRig.applied_force_n = held_up  # type: ignore[method-assign]
        started = time.perf_counter()
        try:
            with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
                code = main(["calibrate", "--config", str(config), "--rig", "sim", "--daq", "sim", "--forces",
                             "1.75,3,4,5.25", "--trials", "1", "--hold", "100", "--rest", "100", "--time-scale",
                             f"{time_scale:g}", "--out", str(out)])
        finally:
            rig_module.CalibrationRig.applied_force_n = read  # type: ignore[method-assign]
        wall_s = time.perf_counter() - started
        redone = said.getvalue().count("runs again after its rest")
        result: dict[str, Any] = {"seed": seed, "rc": code, "redone": redone, "wall_s": wall_s, "errors": None, "poor": 0}
        if out.exists():
            truth = SimLab(load_config(config), seed=0).rig_sensor_truth()
            entry = json.loads(out.read_text(encoding="utf-8"))["sensors"]["S06B"]
            result["errors"] = {k: entry["sls"][k] / truth[k] - 1.0 for k in KEYS}
            result["poor"] = sum(w.startswith("poor fit") for t in entry["trials"] for w in t["warnings"])
        return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--stall-ms", type=float, default=40.0, help="how long a held-up read waits (wall ms)")
    parser.add_argument("--share", type=float, default=0.02, help="the share of reads held up before, and after")
    parser.add_argument("--time-scale", type=float, default=60.0)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    print(f"{args.runs} runs at {args.time_scale:g}× real time, {args.share:g} of the rig's reads held up "  # noqa: T201
          f"{args.stall_ms:g} ms before and after")
    for seed in range(args.runs):
        r = run_once(seed, args.stall_ms / 1000.0, args.share, args.time_scale)
        errors = ("  ".join(f"{k.split('_')[0]} {100 * v:+.1f} %" for k, v in r["errors"].items())
                  if r["errors"] else "no calibration")
        print(f"run {seed}: exit {r['rc']}, {r['redone']} trial(s) run again, poor fits {r['poor']}, "  # noqa: T201
              f"{errors}, {r['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
