"""Posing the limp robot by hand, quickly: how often does the physics lab end invalid, and how soon is a pose reached?

The Teach tab on the simulated lab poses a limp robot through ``PhysicsWorld.set_joint_angle``, every joint of a
pose at once, and a user may set the next pose before the body has come to rest. Each case here is what such a user
does, headless: the world on the paper's obstacle (``PhysicsWorld()``), left limp for ``SETTLE_S`` to drape, then a
sequence of poses, each set joint by joint and followed by ``gap_s`` of stepping, then ``HOLD_S`` more with the last
pose held. The world steps in batches of ``BATCHES_STEPS`` (the app's 20 ms control tick, so the validity checks see
what the live lab's would, and single steps, where they see every step: docs/PHYSICS_LAB.md, "Runs that check
themselves"; the limits are not changed here).

The cases (fixed before any run): the three poses of ``tools/screenshot.py``'s ``_demo_poses`` (an S-curve, the head
lifted, a C-curve of the yaw joints), and for each seed of ``SEEDS`` three poses with every joint drawn from
U(−``POSE_RAD``, ``POSE_RAD``) (``numpy.random.default_rng(seed)``), each sequence with each gap of ``GAPS_S`` and
each batch size.

Per case: valid or not (and why), the deepest contact after the settle (mm), and per pose how long until every joint
was within ``REACHED_RAD`` of its pose (s; empty: not within the gap) and the largest joint error at the gap's end.

``python -m benchmarks.bench_hand_posing [--seeds N] [--out CSV]``: a table per case and the counts; with ``--out``
the rows as CSV (``benchmarks/results/hand_posing_after.csv`` is today's, ``hand_posing_before.csv`` the hand that
put a pose in at once).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SETTLE_S = 2.0  # limp on the obstacle before the first pose (the drape is under way, the body still moving)
GAPS_S = (0.2, 0.6, 1.0, 2.0)  # between one pose and the next (the last pose: this, then HOLD_S)
HOLD_S = 2.0  # the last pose held on after its gap (a user capturing it)
SEEDS = tuple(range(50))  # random pose sequences
POSES_PER_SEQUENCE = 3
POSE_RAD = 0.5  # every joint of a random pose drawn from U(-POSE_RAD, POSE_RAD)
BATCHES_STEPS = (10, 1)  # steps per batch: the app's 20 ms control tick, and one (the checks run after each batch)
REACHED_RAD = 0.01  # a pose is reached when every joint is within this of it (the encoder's ~0.0015 rad × 6)


def demo_poses(n_joints: int) -> list[list[float]]:
    """The three poses of ``tools/screenshot.py``'s ``_demo_poses`` (an S-curve, the head lifted, a C-curve)."""
    s_curve = [0.35 * math.sin(2 * math.pi * j / n_joints) for j in range(n_joints)]
    lift = [(-0.45 if j in (0, 2) else 0.2 if j == 4 else 0.0) + (0.25 if j % 2 else 0.0) for j in range(n_joints)]
    c_curve = [0.28 if j % 2 else 0.0 for j in range(n_joints)]
    return [s_curve, lift, c_curve]


def random_poses(seed: int, n_joints: int) -> list[list[float]]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-POSE_RAD, POSE_RAD, (POSES_PER_SEQUENCE, n_joints)).tolist()


@dataclass(frozen=True)
class Case:
    name: str  # "demo" or "seed N"
    gap_s: float
    batch_steps: int
    poses: list[list[float]]


@dataclass(frozen=True)
class Outcome:
    case: Case
    valid: bool
    reason: str
    deepest_mm: float
    reach_s: list[float | None]  # per pose: time from setting it until every joint was within REACHED_RAD
    error_rad: list[float]  # per pose: the largest joint error at the end of its gap (and hold, the last)
    cpu_s: float


def cases(seeds: tuple[int, ...], n_joints: int) -> list[Case]:
    sequences = [("demo", demo_poses(n_joints))] + [(f"seed {s}", random_poses(s, n_joints)) for s in seeds]
    return [Case(name, gap, batch, poses) for batch in BATCHES_STEPS for name, poses in sequences for gap in GAPS_S]


def run_case(case: Case) -> Outcome:
    from devices.sim.physics.world import PhysicsWorld

    started = time.process_time()
    world = PhysicsWorld()
    dt = world.scene.timestep_s
    world.step(int(round(SETTLE_S / dt)))  # limp from the start: the world is made with every torque off
    world.validity.peak_depth_m = 0.0  # the posing's deepest contact, not the drape's
    reach: list[float | None] = []
    errors: list[float] = []
    for k, pose in enumerate(case.poses):
        target = np.asarray(pose)
        for joint, angle in enumerate(pose):
            world.set_joint_angle(joint, angle)
        span_s = case.gap_s + (HOLD_S if k == len(case.poses) - 1 else 0.0)
        batches = int(round(span_s / (case.batch_steps * dt)))
        reached: float | None = None
        if np.abs(world.joint_state().position_rad - target).max() <= REACHED_RAD:
            reached = 0.0
        for b in range(batches):
            world.step(case.batch_steps)
            if world.invalid is not None:
                break
            if reached is None and np.abs(world.joint_state().position_rad - target).max() <= REACHED_RAD:
                reached = (b + 1) * case.batch_steps * dt
        reach.append(reached if reached is None or reached <= case.gap_s else None)
        errors.append(float(np.abs(world.joint_state().position_rad - target).max()))
        if world.invalid is not None:
            break
    invalid = world.invalid
    return Outcome(case, invalid is None, "" if invalid is None else invalid.what, 1000 * world.validity.peak_depth_m,
                   reach, errors, time.process_time() - started)


def _fmt_reach(reach: list[float | None]) -> str:
    return " ".join("-" if r is None else f"{r:.2f}" for r in reach)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=len(SEEDS), help="how many of the random sequences (default all)")
    parser.add_argument("--out", type=Path, help="write the rows as CSV here")
    args = parser.parse_args(argv)
    from devices.sim.physics.model import SceneParams

    all_cases = cases(SEEDS[:args.seeds], SceneParams().n_segments)
    outcomes = []
    for case in all_cases:
        outcome = run_case(case)
        outcomes.append(outcome)
        print(f"{case.name:<8} gap {case.gap_s:3.1f} s  batch {case.batch_steps:2d}  valid {int(outcome.valid)}  deepest {outcome.deepest_mm:5.2f} mm  "
              f"reached after (s) {_fmt_reach(outcome.reach_s):<16} error at gap end (rad) "
              f"{' '.join(f'{e:.3f}' for e in outcome.error_rad):<18} cpu {outcome.cpu_s:4.1f} s"
              + (f"  {outcome.reason}" if not outcome.valid else ""), flush=True)
    print()
    for batch, gap in [(batch, gap) for batch in BATCHES_STEPS for gap in GAPS_S]:
        of_gap = [o for o in outcomes if o.case.gap_s == gap and o.case.batch_steps == batch]
        reaches = [r for o in of_gap for r in o.reach_s if r is not None]
        unreached = sum(r is None for o in of_gap for r in o.reach_s)
        print(f"batch {batch:2d}, gap {gap:3.1f} s: invalid {sum(not o.valid for o in of_gap)} of {len(of_gap)}, deepest "
              f"{max(o.deepest_mm for o in of_gap):.2f} mm, poses reached within the gap: {len(reaches)} "
              f"(slowest {max(reaches, default=math.nan):.2f} s), not reached: {unreached}")
    print(f"all: invalid {sum(not o.valid for o in outcomes)} of {len(outcomes)}, deepest "
          f"{max(o.deepest_mm for o in outcomes):.2f} mm")
    if args.out is not None:
        with args.out.open("w", newline="", encoding="utf-8") as f:
            writer = csv.writer(f)
            writer.writerow(["sequence", "gap_s", "batch_steps", "valid", "invalid_reason", "deepest_mm", "reach_s", "error_rad",
                             "cpu_s"])
            for o in outcomes:
                writer.writerow([o.case.name, o.case.gap_s, o.case.batch_steps, int(o.valid), o.reason, f"{o.deepest_mm:.2f}",
                                 _fmt_reach(o.reach_s), " ".join(f"{e:.4f}" for e in o.error_rad), f"{o.cpu_s:.1f}"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
