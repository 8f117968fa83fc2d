"""How much faster than real time one headless physics-lab run goes (``sensnake experiment run``), on one core.

    python -m benchmarks.bench_rtf [--seconds 30] [--repeats 3] [--controller feedback|feedforward|both]
                                   [--scene paper_obstacle] [--ideal-sensing] [--profile OUT.prof]

Each run is :func:`app.core.experiment.run_experiment` as the command line calls it (the settle, the play, the
recording with ``/sim``), without the wait for rest (``rest_cap_s`` 0, so every repeat simulates the same seconds).
Printed per run: the simulated seconds, the wall seconds of the run (``ExperimentResult.wall_s``: from the lab's
start to the recording's end; the imports and MuJoCo's model compilation before it are printed apart), the real-time
factor on the wall clock, and on this process's CPU time (what the machine's other work does not change much: the
2-core machine is shared). The best of the repeats is the figure (the least disturbed).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _one(scene: str, controller: str, seconds: float, ideal: bool, out: Path) -> tuple[float, float, float]:
    from app.core.experiment import run_experiment
    from devices.config import LabConfig

    cpu0 = time.process_time()
    options = {"ideal_sensing": True} if ideal else {}
    result = run_experiment(out, LabConfig(), scene=scene, seconds=seconds, rest_cap_s=0.0, controller=controller,
                            **options)  # type: ignore[arg-type]
    cpu = time.process_time() - cpu0
    return result.simulated_s, result.wall_s, cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="simulated seconds of play (after a 6 s settle)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scene", default="paper_obstacle")
    parser.add_argument("--controller", choices=("feedback", "feedforward", "both"), default="both")
    parser.add_argument("--ideal-sensing", action="store_true", help="the controller reads the simulation's truth")
    parser.add_argument("--profile", metavar="OUT.prof", help="cProfile the first run into this file")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    import mujoco  # noqa: F401 - the imports' share, printed apart

    import app.core.experiment  # noqa: F401
    print(f"imports: {time.perf_counter() - started:.2f} s")  # noqa: T201
    controllers = ("feedforward", "feedback") if args.controller == "both" else (args.controller,)
    print(f"{'controller':<12} {'simulated s':>11} {'wall s':>7} {'RTF wall':>8} {'RTF CPU':>8}")  # noqa: T201
    with tempfile.TemporaryDirectory() as scratch:
        for controller in controllers:
            best_wall = best_cpu = 0.0
            for k in range(args.repeats):
                out = Path(scratch) / f"{controller}-{k}.h5"
                if args.profile and k == 0:
                    import cProfile

                    profiler = cProfile.Profile()
                    profiler.enable()
                    simulated, wall, cpu = _one(args.scene, controller, args.seconds, args.ideal_sensing, out)
                    profiler.disable()
                    profiler.dump_stats(f"{args.profile}.{controller}")
                    continue
                simulated, wall, cpu = _one(args.scene, controller, args.seconds, args.ideal_sensing, out)
                best_wall, best_cpu = max(best_wall, simulated / wall), max(best_cpu, simulated / cpu)
                print(f"{controller:<12} {simulated:11.1f} {wall:7.2f} {simulated / wall:8.1f} "  # noqa: T201
                      f"{simulated / cpu:8.1f}")
            print(f"{controller:<12} best of {args.repeats}: {best_wall:.1f}× real time (wall), "  # noqa: T201
                  f"{best_cpu:.1f}× (CPU)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
