"""The paper's obstacle experiment (Sec. III-C, Fig. 6) against the physics lab's: the numbers the paper states, and
what the lab gives for each, from one ``sensnake experiment obstacle`` run (defaults: the paper's 0.28 × body length
PTFE half cylinder, the settled drape played follow-the-leader at 0.034 rad/s, seed 0, judged at rest).

    python -m benchmarks.bench_paper_figures [--out DIR] [--from REC.h5] [--vary]

Prints the table docs/PHYSICS_LAB.md shows ("What the lab reproduces of the paper's figures"), every lab number
measured here from the recording as a robot with motion capture would measure it: forces from ``/forces`` (the
board's frames estimated through a rig calibration), positions from the simulated body's points (what the paper's
motion capture gave). ``--from`` reads a recording made before instead of running; ``--vary`` also runs the
experiment with each parameter in :data:`VARIANTS` changed and prints how each number moves (the parameters that
move it). Writes the table to ``DIR/paper_figures.md`` (default benchmarks/results).

Definitions (the paper's words, Sec. III-C, and what is measured for each):

* *first 10 s* — "substantial normal forces (~5 N, ~22 % robot weight) on the segments contacting the front of the
  obstacle and the horizontal surface", motion "smooth": over the first 10 s of the play, the median force of each
  bottom sensor whose segment's centre lies on the obstacle's front face (the face toward +x, where the head went
  down: its normal force pushes the robot forward) or on the floor beyond it; the largest of those; and the
  centroid's speed then.
* *slow-down* — "until the middle of the robot passed over the middle of the obstacle, the robot slowed down
  momentarily": the centroid's least forward speed (over 2 s) between 10 s and the first slip, when, and where the
  body's middle point was against the obstacle's top.
* *front-face peak* — "the segment contacting the front side of the obstacle pushed harder and generated a very
  large force (23 N, 98 % robot weight)", then the slip: the largest force on a front-face bottom sensor before the
  first slip, which and when; and the largest of the whole play.
* *slip* — "this buildup of forward propulsion eventually helped the robot overcome frictional drag and slip forward
  rapidly": the first second after 10 s in which the centroid advances faster than :data:`SLIP_CM_S`, how fast, and
  what the body did (the head tip dropping more than 5 cm in it: the lifted head falling to the floor).
* *backward propagation* — "all the contact force patterns propagated backward relative to the robot": the peak
  times of the bottom sensors whose segments pass over the obstacle's top (peak with the segment's centre within
  0.15 m of it), their rank correlation with the segment (+1: strictly later toward the tail) and the speed at which
  the peak moves back along the body (segments/s, a line through them) against the speed the played shape moves
  back (follow-the-leader: two segments per shift).
* *traversal* — the paper's robot traverses: the lab's outcome at rest.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RESULTS = Path(__file__).resolve().parent / "results"
# Each variant: a [lab.physics] key or a friction ([lab] key) and the factor it is multiplied by.
VARIANTS = (("obstacle_friction", 2.0), ("obstacle_friction", 0.5), ("ground_friction", 1.5),
            ("shell_stiffness_n_per_m", 2.0), ("servo_position_gain_nm_per_rad", 2.0))


@dataclass(frozen=True)
class PaperFigures:
    """What one run gives for each of the paper's numbers (see the module docstring); forces in N, times in s,
    speeds in cm/s."""

    weight_n: float
    first10_n: float
    first10_sensor: str
    first10_others: tuple[str, ...]
    first10_speed: float
    slow_speed: float
    slow_s: float
    slow_middle_cm: float
    peak_n: float
    peak_s: float
    peak_sensor: str
    largest_n: float
    largest_s: float
    largest_sensor: str
    slip_speed: float
    slip_s: float
    slip_head_drop_cm: float
    rank_correlation: float
    passing: tuple[str, ...]
    pattern_segments_per_s: float
    shape_segments_per_s: float
    outcome: str
    margin_cm: float
    advance_cm: float


SLIP_CM_S = 1.0  # a second's advance faster than this is a slip: four times the play's steady 0.2-0.25 cm/s
PASSING_M = 0.15  # a sensor's peak counts for the propagation when its segment's centre is this near the top (x)


def measure(path: str | Path) -> PaperFigures:
    """The paper's numbers from a recording of ``sensnake experiment obstacle`` (module docstring)."""
    import h5py

    from devices.scene import parse_scene

    with h5py.File(path, "r") as f:
        names = [c.decode() if isinstance(c, bytes) else str(c) for c in f["daq"].attrs["channels"]]
        force_t = f["daq/time_s"][:]
        forces = f["forces/force_N"][:]
        sim = f["sim"]
        sim_t, points = sim["time_s"][:], sim["points_m"][:]
        weight = float(sim.attrs["weight_N"])
        motion_end = float(sim.attrs.get("motion_end_s", sim_t[-1]))
        terrain = parse_scene(str(sim.attrs["scene"]))
        outcome = str(sim.attrs.get("outcome", ""))
        margin = float(sim.attrs.get("rest_margin_m", math.nan))
        advance = float(sim.attrs.get("advance_at_rest_m", math.nan))
        goals = f["robot/goal_rad"][:]
        goal_t = f["robot/time_s"][:]
    bottom = [k for k, name in enumerate(names) if name.endswith("B")]
    labels = [names[k] for k in bottom]
    play = (force_t >= 0) & (force_t <= motion_end)
    t, bottom_n = force_t[play], np.nan_to_num(forces[play][:, bottom])
    # each segment's centre at each force sample (the nearest /sim tick)
    ticks = np.clip(np.searchsorted(sim_t, t), 0, sim_t.size - 1)
    centres_x = 0.5 * (points[ticks, :-1, 0] + points[ticks, 1:, 0])
    first = min(terrain.obstacles, key=lambda o: o.x_m)
    top = first.x_m if first.shape == "half_cylinder" else first.x_range_m[0]
    front = centres_x >= top  # on the face toward +x, or on the floor beyond it
    # the centroid's motion over the play
    sim_play = sim_t <= motion_end
    st, centroid, head_z = sim_t[sim_play], points[sim_play, :, 0].mean(axis=1), points[sim_play, 0, 2]
    middle = points[sim_play, points.shape[1] // 2, 0]  # the body's middle point (segment 6's back end)
    early = t <= 10.0
    medians = np.array([np.median(bottom_n[early & front[:, s], s]) if np.any(early & front[:, s]) else 0.0
                        for s in range(len(bottom))])
    best = int(np.argmax(medians))
    ten = int(np.searchsorted(st, 10.0))
    first10_speed = 100 * (centroid[ten] - centroid[0]) / (st[ten] - st[0])
    # the slip: the first second after 10 s advancing faster than SLIP_CM_S
    speed1 = _speed(st, centroid, 1.0)
    fast = np.flatnonzero((st > 10.0) & (np.nan_to_num(speed1) * 100 > SLIP_CM_S))
    slip_k = int(fast[0]) if fast.size else int(np.nanargmax(speed1))
    slip_k = slip_k + int(np.nanargmax(speed1[slip_k:slip_k + int(np.searchsorted(st, st[slip_k] + 1.0) - slip_k)
                                              + 1]))
    half = int(np.searchsorted(st, st[slip_k] + 0.5)) - slip_k
    drop = head_z[max(slip_k - half, 0)] - head_z[min(slip_k + half, st.size - 1)]
    slip_s = float(st[slip_k])
    # the slow-down: the least 2 s speed between 10 s and the slip
    speed2 = _speed(st, centroid, 2.0)
    between = (st >= 10.0) & (st <= slip_s - 1.0) & np.isfinite(speed2)
    slow_k = int(np.nanargmin(np.where(between, speed2, np.nan))) if between.any() else 0
    # the front-face peaks: before the slip, and over the play
    on_face = np.where(front & (centres_x <= first.x_range_m[1]), bottom_n, -np.inf)
    before = np.where((t <= slip_s)[:, None], on_face, -np.inf)
    row, col = np.unravel_index(int(np.argmax(before)), before.shape)
    big_row, big_col = np.unravel_index(int(np.argmax(on_face)), on_face.shape)
    # backward propagation: the peaks of the sensors whose segments pass over the top
    near_top = np.abs(centres_x - top) <= PASSING_M
    peaks_near = np.where(near_top, bottom_n, -np.inf)
    peak_rows = np.argmax(peaks_near, axis=0)
    passing = np.array([np.isfinite(peaks_near[peak_rows[s], s]) and peaks_near[peak_rows[s], s] > 0.15 * weight
                        for s in range(len(bottom))])
    seg = np.flatnonzero(passing)
    peak_t = t[peak_rows[passing]]
    rank = _spearman(seg, peak_t) if seg.size > 2 else math.nan
    pattern = float(np.polyfit(peak_t, seg, 1)[0]) if seg.size > 2 else math.nan
    shape = _shape_speed(goal_t[goal_t <= motion_end], goals[goal_t <= motion_end])
    return PaperFigures(
        weight, float(medians[best]), labels[best],
        tuple(labels[s] for s in np.argsort(-medians) if s != best and medians[s] > 0.1 * weight),
        float(first10_speed), float(100 * speed2[slow_k]), float(st[slow_k]), float(100 * (middle[slow_k] - top)),
        float(bottom_n[row, col]), float(t[row]), labels[col], float(bottom_n[big_row, big_col]), float(t[big_row]),
        labels[big_col], float(100 * speed1[slip_k]), slip_s, float(100 * drop), rank,
        tuple(labels[s] for s in seg), pattern, shape, outcome, 100 * margin, 100 * advance)


def _speed(t: np.ndarray, x: np.ndarray, span_s: float) -> np.ndarray:
    """(x(t + span/2) − x(t − span/2)) / span at each sample (NaN where the span leaves the record)."""
    out = np.full(t.size, np.nan)
    lo = np.searchsorted(t, t - span_s / 2)
    hi = np.searchsorted(t, t + span_s / 2) - 1
    ok = (t - span_s / 2 >= t[0]) & (t + span_s / 2 <= t[-1]) & (hi > lo)
    out[ok] = (x[hi[ok]] - x[lo[ok]]) / (t[hi[ok]] - t[lo[ok]])
    return out


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def _shape_speed(t: np.ndarray, goals: np.ndarray) -> float:
    """How fast the played shape moves back along the body (segments per second): follow-the-leader shifts it by one
    joint of each axis, i.e. two segments, per shift; the shifts' count over the play's time."""
    moving = np.any(np.abs(np.diff(goals, axis=0)) > 1e-9, axis=1)
    if not moving.any():
        return math.nan
    span = float(t[1:][moving][-1] - t[:-1][moving][0])
    shifts = goals.shape[1] // 2  # K = m per axis (SPEC §5), each shift moves the shape one joint of its axis back
    return 2.0 * shifts / span if span > 0 else math.nan


def rows(fig: PaperFigures) -> list[tuple[str, str, str]]:
    """(the paper's number, its value, the lab's) for the docs' table."""
    w = fig.weight_n
    falls = f"the head tip dropping {fig.slip_head_drop_cm:.0f} cm: the lifted head falls to the floor" \
        if fig.slip_head_drop_cm > 5.0 else "the body slides forward"
    return [
        ("first 10 s: load on the segments on the obstacle's front face and the floor",
         "~5 N (~22 % of the weight); forward motion smooth",
         f"{fig.first10_n:.1f} N ({100 * fig.first10_n / w:.0f} %) on {fig.first10_sensor} (median over 0–10 s; "
         f"also above 10 %: {', '.join(fig.first10_others) or 'none'}); the centroid advancing steadily at "
         f"{fig.first10_speed:.2f} cm/s"),
        ("slow-down as the body's middle passes over the obstacle's middle", "\"slowed down momentarily\"",
         f"{fig.slow_speed:.2f} cm/s at {fig.slow_s:.0f} s (2 s speed; the body's middle {fig.slow_middle_cm:+.1f} "
         f"cm from the top), from {fig.first10_speed:.2f} cm/s over the first 10 s"),
        ("front-face peak, before the slip", "23 N (98 % of the weight)",
         f"{fig.peak_n:.1f} N ({100 * fig.peak_n / w:.0f} %) on {fig.peak_sensor} at {fig.peak_s:.1f} s; the "
         f"play's largest {fig.largest_n:.1f} N ({100 * fig.largest_n / w:.0f} %) on {fig.largest_sensor} at "
         f"{fig.largest_s:.1f} s"),
        ("slip", "the push overcomes friction: \"slip forward rapidly\", then steady motion",
         f"{fig.slip_speed:.1f} cm/s over 1 s at {fig.slip_s:.1f} s, {falls}"),
        ("backward propagation of the force pattern", "\"all the contact force patterns propagated backward\"",
         f"the peaks of the {len(fig.passing)} sensors passing the top ({fig.passing[0]}–{fig.passing[-1]}) "
         f"come later toward the tail: rank "
         f"correlation {fig.rank_correlation:+.2f}, moving back {fig.pattern_segments_per_s:.3f} segments/s; the "
         f"played shape {fig.shape_segments_per_s:.3f} segments/s" if fig.passing else "no sensor peaks at the top"),
        ("traversal", "traverses",
         f"{fig.outcome} at rest (the rearmost point {fig.margin_cm:+.1f} cm past the far edge; centroid "
         f"{fig.advance_cm:+.0f} cm)"),
    ]


def table(fig: PaperFigures) -> str:
    lines = ["| the paper's number (Sec. III-C, Fig. 6) | paper (robot) | physics lab (`experiment obstacle`, seed 0) |",
             "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows(fig)]
    return "\n".join(lines)


def _run(out: Path, config: object, say: str) -> Path:
    from app.core.experiment import run_obstacle_experiment

    started = time.process_time()
    result = run_obstacle_experiment(out, config)  # type: ignore[arg-type]
    print(f"{say}: {result.simulated_s:.0f} simulated s, {time.process_time() - started:.0f} s of CPU, "  # noqa: T201
          f"{result.outcome}")
    if not result.valid:
        raise SystemExit(f"{say}: invalid run ({result.invalid_reason})")
    return out


def _varied(key: str, factor: float) -> object:
    from dataclasses import replace

    from devices.config import LabConfig

    config = LabConfig()
    lab = config.lab
    if key in ("obstacle_friction", "ground_friction"):
        return replace(config, lab=replace(lab, **{key: getattr(lab, key) * factor}))
    return replace(config, lab=replace(lab, physical=replace(lab.physical,
                                                             **{key: getattr(lab.physical, key) * factor})))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(RESULTS), help="folder for paper_figures.md (default benchmarks/results)")
    parser.add_argument("--from", dest="recording", metavar="REC.h5", help="measure this recording instead of running")
    parser.add_argument("--vary", action="store_true", help="also run each of VARIANTS and say how each number moves")
    args = parser.parse_args(argv)
    from devices.config import LabConfig

    with tempfile.TemporaryDirectory() as scratch:
        path = Path(args.recording) if args.recording else _run(Path(scratch) / "paper.h5", LabConfig(),
                                                                  "default lab")
        base = measure(path)
        text = table(base)
        print(text)  # noqa: T201
        if args.vary:
            moved = ["", "| parameter changed | first 10 s (N) | slowest (cm/s, s) | front-face peak before the slip "
                     "(N, s) | slip (cm/s, s; head drop) | propagation (rank; segments/s) | outcome at rest |",
                     "|---|---|---|---|---|---|---|"]
            for fig, label in [(base, "none (the defaults)")] + [
                    (measure(_run(Path(scratch) / f"{key}-{factor:g}.h5", _varied(key, factor), f"{key} × {factor:g}")),
                     f"{key} × {factor:g}") for key, factor in VARIANTS]:
                moved.append(f"| {label} | {fig.first10_n:.1f} | {fig.slow_speed:.2f} at {fig.slow_s:.0f} | "
                             f"{fig.peak_n:.1f} at {fig.peak_s:.0f} | {fig.slip_speed:.1f} at {fig.slip_s:.0f}; "
                             f"{fig.slip_head_drop_cm:.0f} cm | {fig.rank_correlation:+.2f}; "
                             f"{fig.pattern_segments_per_s:.3f} | {fig.outcome} ({fig.margin_cm:+.1f} cm) |")
            print("\n".join(moved))  # noqa: T201
            text += "\n" + "\n".join(moved)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "paper_figures.md").write_text(text + "\n", encoding="utf-8")
    print(f"wrote {out / 'paper_figures.md'}")  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
