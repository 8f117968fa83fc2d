"""How near runs that are physics come to the validity limits, and where they come to rest.

Each run is ``sensnake experiment run`` (the settled drape played follow-the-leader) on a built-in scene or one of
``benchmarks/scenes/terrain/``, at the paper's 0.034 rad/s and at 0.3 rad/s, with and without a tail load friction
can hold: its ``/sim`` attributes say how deep its deepest contact went, how fast its fastest point moved and how
much energy it gained beyond what its powered servos could give (``devices.sim.physics.validity``: the limits a run
is invalid beyond), whether it was valid, and its outcome judged at rest after the motion (docs/PHYSICS_LAB.md,
"Runs that check themselves"). A limit far above every peak here flags only what is not physics.

``python -m benchmarks.bench_validity [--quick] [--out DIR]`` (``--quick``: 0.3 rad/s only, 20 s plays).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import h5py

from app.core.experiment import run_experiment

TERRAIN = Path(__file__).parent / "scenes" / "terrain"
SCENES = ("paper_obstacle", "flat", "step", "wedge", "two_obstacles", str(TERRAIN / "tall_step.toml"),
          str(TERRAIN / "step_down.toml"), str(TERRAIN / "steep_wedge.toml"))
TAIL_LOADS_N = (0.0, 5.0)


def run(quick: bool, out_dir: Path) -> list[dict[str, object]]:
    rows = []
    speeds = (0.3,) if quick else (0.034, 0.3)
    for scene in SCENES:
        for speed in speeds:
            for load in TAIL_LOADS_N:
                seconds = 20.0 if quick else 60.0 if speed < 0.1 else 30.0
                out = out_dir / f"{Path(scene).stem}_{speed:g}_{load:g}N.h5"
                started = time.perf_counter()
                result = run_experiment(out, scene=scene, speed_rad_s=speed, seconds=seconds, tail_load_n=load)
                with h5py.File(out, "r") as f:
                    attrs = dict(f["sim"].attrs)
                limits = json.loads(str(attrs["limits"]))
                row = {"scene": Path(scene).stem, "rad_s": speed, "load_N": load, "valid": result.valid,
                       "reason": result.invalid_reason, "outcome": result.outcome, "rest_s": result.at_rest_s,
                       "margin_m": result.rest_margin_m, "depth_mm": 1000 * float(attrs["peak_depth_m"]),
                       "depth_limit_mm": 1000 * limits["depth_m"], "speed_m_s": float(attrs["peak_speed_m_s"]),
                       "speed_limit_m_s": limits["speed_m_s"], "energy_J": float(attrs["peak_energy_gain_J"]),
                       "wall_s": time.perf_counter() - started}
                rows.append(row)
                print(f"{row['scene']:<14} {speed:5.3f} rad/s {load:3.0f} N  valid {int(result.valid)}  "
                      f"{result.outcome:<13} rest {result.at_rest_s:6.1f} s  margin {result.rest_margin_m:+.3f} m  "
                      f"deepest {row['depth_mm']:5.2f} mm (held > {row['depth_limit_mm']:.0f} mm for 50 ms: invalid)  "
                      f"fastest {row['speed_m_s']:5.2f} m/s (limit {row['speed_limit_m_s']:.1f})  energy gain "
                      f"{row['energy_J']:.3f} J (margin {limits['energy_margin_J']:g})  {row['wall_s']:.0f} s"
                      + (f"  {result.invalid_reason}" if not result.valid else ""), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=None, help="keep the recordings here (default: a scratch folder)")
    args = parser.parse_args()
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        run(args.quick, args.out)
        return
    with tempfile.TemporaryDirectory() as scratch:
        run(args.quick, Path(scratch))


if __name__ == "__main__":
    main()
