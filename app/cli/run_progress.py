"""What the commands that run many physics-lab runs print while they go (``experiment sweep``, ``evaluate``,
``tune``): the progress line, and the one line of a run set cut short by Ctrl-C, SIGTERM or SIGHUP."""

from __future__ import annotations

import sys
from pathlib import Path

from app.core.errors import RunsInterrupted

EXIT_INVALID = 3  # SPEC §7: a physics run that is invalid (experiment run, obstacle; a sweep with an invalid run)
EXIT_INTERRUPTED = 130


def progress_line(line: str) -> None:
    """One line rewritten in place on a terminal; one line per report when piped to a file."""
    end = "\r" if sys.stdout.isatty() else "\n"
    print(line, end=end, flush=True)


def interrupted(stop: RunsInterrupted, out: str) -> int:
    """One line for runs cut short by Ctrl-C, SIGTERM or SIGHUP: what was kept, how to resume; exit 130."""
    if sys.stdout.isatty():
        print()
    print(f"sensnake experiment: interrupted ({stop.signal_name}): pending runs cancelled, workers stopped; "
          f"{stop.finished} of {stop.total} runs finished and kept in {out}; the same command resumes",
          file=sys.stderr)
    return EXIT_INTERRUPTED


def finished(out: str, figure: str) -> Path:
    """A run set that went to its end: close the progress line and render ``out/<figure>.svg`` as a PNG beside it;
    returns the folder."""
    if sys.stdout.isatty():
        print()
    folder = Path(out)
    from app.gui.figure_png import svg_to_png  # the figure's pixels only: Qt's SVG renderer, loaded here

    svg_to_png((folder / f"{figure}.svg").read_text(encoding="utf-8"), folder / f"{figure}.png")
    return folder
