"""``sensnake report repeatability REC.h5… [--align onset|contact|mocap] [--mixed] --out DIR``: the paper's Fig. 7 from
any recordings of one condition (:mod:`app.core.repeatability`): ``alignment.csv``, ``repeatability.csv``,
``repeatability_summary.csv``, ``repeatability.svg`` and ``.png`` in DIR. Refuses fewer than two recordings, an
invalid simulated run, and recordings of different conditions unless ``--mixed`` (the difference named). Main thread.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.core.repeatability import AlignOptions, Repeatability, analyse, summary_rows, write_report


def align_options(args: argparse.Namespace) -> AlignOptions:
    return AlignOptions(event=args.align, contact_force_n=args.contact_force, contact_sensor=args.contact_sensor,
                        position_segment=args.segment, position_x_m=args.position_x,
                        position_move_m=args.position_move)


def make_report(paths: list[str], out: str | Path, options: AlignOptions, mixed: bool = False,
                step_s: float | None = None) -> Repeatability:
    """Analyse and write the report (the PNG through Qt's SVG renderer, loaded only here)."""
    result, _ = analyse(paths, options, mixed=mixed, step_s=step_s)
    from app.gui.figure_png import svg_to_png

    write_report(result, out, rasterise=svg_to_png)
    return result


def print_summary(result: Repeatability, out: str | Path) -> None:
    print(f"{result.n_trials} trials aligned on {result.align}; {len(result.time_s)} instants over "
          f"{result.time_s[-1] - result.time_s[0]:.1f} s")
    for path, offset in zip(result.paths, result.offsets_s):
        print(f"  {path.name}: event at {offset:.3f} s on its clock")
    for difference in result.differences:
        print(f"  mixed: {difference}")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"{'quantity':<9} {'peak mean':>10} {'± s.d.':>8} {'at s':>7} {'rms diff':>9} {'ICC':>6}")
    for row in summary_rows(result):
        icc = f"{row['icc']:6.3f}" if row["icc"] == row["icc"] else f"{'—':>6}"
        print(f"{row['quantity']:<9} {row['peak_mean']:10.3g} {row['peak_sd']:8.2g} {row['peak_time_mean_s']:7.2f} "
              f"{row['rms_difference']:9.3g} {icc}")
    print(f"wrote alignment.csv, repeatability.csv, repeatability_summary.csv, repeatability.svg and .png in {out}")


def run(args: argparse.Namespace) -> int:
    if args.kind != "repeatability":  # argparse's choices refuse others; kept for a direct call
        raise ValueError(f"unknown report {args.kind!r}; known: repeatability")
    if args.step is not None and not args.step > 0:
        raise ValueError(f"--step must be positive, got {args.step}")
    result = make_report(args.recordings, args.out, align_options(args), mixed=args.mixed, step_s=args.step)
    print_summary(result, args.out)
    return 0
