"""How well ``sensnake lab identify`` recovers the physics lab's parameters from recordings made with known values.

    python -m benchmarks.bench_identify [--cases fast,mocap,paper,rest] [--screen] [--out DIR]

Each case makes a recording in the physics lab with :data:`TRUTH` (shell stiffness, ground and obstacle friction
away from the defaults the fit starts from) on the paper's obstacle, then runs identify on what a real recording
holds (a copy without ``/sim``; the scene given as ``--scene``) and prints each value against the truth, its error,
its 95 % interval, the tool's verdict (fixed or not, and why), the replays and the CPU time. Cases:

* ``fast``: the settled drape played follow-the-leader at 0.3 rad/s, the whole play (9 s): the body slides over the
  PTFE and the floor.
* ``mocap``: the same recording with a simulated motion-capture take imported (``/mocap``: the segments' positions,
  0.3 mm marker noise, dropouts, a hidden segment), the positions a fourth signal.
* ``paper``: the paper's speed, 0.034 rad/s, the first 20 s: the body barely slides.
* ``rest``: the drape held nearly still (0.002 rad/s) for 10 s.

``--screen`` adds, on the first case, how far each [lab.physics] key not fitted moves the signals. Writes the table
to ``DIR/identify.md`` (default benchmarks/results).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RESULTS = Path(__file__).resolve().parent / "results"
TRUTH = {"shell_stiffness_n_per_m": 1500.0, "ground_friction": 0.36, "obstacle_friction": 0.13}  # defaults 2000, 0.3, 0.1
SCENE = """[ground]
friction = {ground_friction}

[[obstacle]]
shape = "half_cylinder"
x_m = 0.0
radius_m = 0.2688
friction = {obstacle_friction}

[robot]
head_x_m = 0.44
start = "settle"
"""
CASES = {  # name: (speed rad/s, play s (None: the whole motion), window s, with motion capture)
    "fast": (0.3, None, 9.0, False),
    "mocap": (0.3, None, 9.0, True),
    "paper": (0.034, 20.0, 20.0, False),
    "rest": (0.002, 10.0, 10.0, False),
}


def _record(folder: Path, name: str, speed: float, seconds: float | None, mocap: bool) -> tuple[Path, Path]:
    """The case's recording as a real robot's would be (no /sim), and its scene file."""
    import h5py

    from app.cli.main import main
    from app.core.experiment import run_experiment
    from devices.config import load_config

    scene = folder / "scene.toml"
    scene.write_text(SCENE.format(**TRUTH), encoding="utf-8")
    lab = folder / "lab.toml"
    lab.write_text(f"[lab.physics]\nshell_stiffness_n_per_m = {TRUTH['shell_stiffness_n_per_m']}\n", encoding="utf-8")
    rec = folder / f"{name}.h5"
    result = run_experiment(rec, load_config(lab), scene=str(scene), speed_rad_s=speed, seconds=seconds,
                            rest_cap_s=0.0)
    if not result.valid:
        raise SystemExit(f"{name}: the recording's run is invalid ({result.invalid_reason})")
    if mocap:
        take, with_mocap = folder / f"{name}.c3d", folder / f"{name}-mocap.h5"
        if main(["mocap", "simulate", str(rec), "--out", str(take)]) or \
                main(["mocap", "import", str(take), "--rec", str(rec), "--out", str(with_mocap)]):
            raise SystemExit(f"{name}: the simulated take did not import")
        rec = with_mocap
    real = folder / f"{name}-real.h5"
    real.write_bytes(rec.read_bytes())
    with h5py.File(real, "a") as f:
        del f["sim"]  # the simulation's truth: a real recording has none
    return real, scene


def run(cases: list[str], screen: bool = False, out: Path = RESULTS) -> str:
    from app.core.identify import SIGNALS, identify, summary_lines

    lines = ["| case | key | truth | fitted | error | 95 % interval | verdict | replays | CPU s |",
             "|---|---|---|---|---|---|---|---|---|"]
    extra: list[str] = []
    with tempfile.TemporaryDirectory() as scratch:
        for k, name in enumerate(cases):
            speed, seconds, window, mocap = CASES[name]
            folder = Path(scratch) / name
            folder.mkdir()
            made = time.process_time()
            real, scene = _record(folder, name, speed, seconds, mocap)
            print(f"{name}: recorded in {time.process_time() - made:.0f} s of CPU", flush=True)  # noqa: T201
            result = identify([real], tuple(TRUTH), window_s=window, scene_text=scene.read_text(encoding="utf-8"),
                              screen=screen and k == 0, progress=lambda line: print(line, flush=True))  # noqa: T201
            for line in summary_lines(result):
                print(line)  # noqa: T201
            for key, truth in TRUTH.items():
                value = result.value[key]
                low, high = result.interval[key]
                verdict = "not fixed: " + result.not_fixed[key] if key in result.not_fixed else "fixed"
                lines.append(f"| {name} | `{key}` | {truth:g} | {value:.4g} | {100 * (value / truth - 1):+.1f} % | "
                             f"{low:.4g}–{high:.4g} | {verdict} | {result.evaluations} | {result.cpu_s:.0f} |")
            signals = ", ".join(f"{SIGNALS[s].label} {v:.3g}" for s, v in result.residual_fit.items())
            extra.append(f"- {name}: residual RMS at the fit (units: rad, mA, N, m): {signals}")
            if result.screened:
                extra.append(f"- {name}, keys not fitted: a 10 % rise moves the signals by (RMS):")
                for key, row in result.screened.items():
                    extra.append(f"  - `{key}`: " + ", ".join(f"{SIGNALS[s].label} {v:.3g}" for s, v in row.items()))
    text = "\n".join(lines + [""] + extra)
    out.mkdir(parents=True, exist_ok=True)
    (out / "identify.md").write_text(text + "\n", encoding="utf-8")
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    parser.add_argument("--screen", action="store_true", help="the first case also screens the keys not fitted")
    parser.add_argument("--out", default=str(RESULTS), help="folder for identify.md (default benchmarks/results)")
    args = parser.parse_args(argv)
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    for case in cases:
        if case not in CASES:
            parser.error(f"unknown case {case!r}; known: {', '.join(CASES)}")
    print(run(cases, args.screen, Path(args.out)))  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
