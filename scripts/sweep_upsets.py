"""Re-analyse a sweep folder of ``sensnake experiment sweep`` for falls: when each run's body lost the ground or
rolled onto its side, how far it had crawled by then, whether it traversed crawling (not falling off a crest), and
how far its tail advanced and how it lay at the end, from its recordings alone (:func:`app.core.sweep.with_upsets`). For a summary written before those columns existed.

    python scripts/sweep_upsets.py SWEEP_DIR [OUT.csv]

Writes ``OUT.csv`` (default ``SWEEP_DIR/summary_upsets.csv``; an existing file is refused, never overwritten) and
prints, per feedback gain set, the traversal rates where feedforward fails, all of them and the crawled ones.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from app.core.sweep import SUMMARY_COLUMNS, compare, read_summary, with_upsets  # noqa: E402


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("folder", help="a folder written by sensnake experiment sweep (summary.csv and recordings)")
    parser.add_argument("out", nargs="?", help="the CSV to write (default: FOLDER/summary_upsets.csv)")
    args = parser.parse_args(argv)
    folder = args.folder
    out = args.out or os.path.join(folder, "summary_upsets.csv")
    summary = os.path.join(folder, "summary.csv")
    if not os.path.isfile(summary):
        sys.stderr.write(f"{summary}: no such file (not a sweep folder)\n")
        return 1
    rows = with_upsets(read_summary(summary), folder)
    try:
        with open(out, "x", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
            writer.writeheader()
            writer.writerows(rows)
    except FileExistsError:
        sys.stderr.write(f"{out}: exists; not overwritten (name another file)\n")
        return 1
    for index in sorted({int(r["gains_index"]) for r in rows if r["controller"] == "feedback"}):
        c = compare(rows, index)
        sys.stdout.write(f"g{index}: where feedforward fails ({c.ff_fail_cases} cases) traversed "
                         f"{100 * c.fb_success_in_those:.0f}% against {100 * c.ff_success_in_those:.0f}%, crawling "
                         f"{100 * c.fb_crawled_in_those:.0f}% against {100 * c.ff_crawled_in_those:.0f}%, median crawl "
                         f"{c.fb_crawl_in_those:.2f} against {c.ff_crawl_in_those:.2f} m; median advance ratio "
                         f"{c.median_advance_ratio:.2f} (the tail point's {c.median_tail_advance_ratio:.2f}, the "
                         f"centroid's where both traverse {c.median_advance_ratio_both_traversed:.2f})\n")
    sys.stdout.write(f"wrote {out}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
