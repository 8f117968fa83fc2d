"""``sensnake runs list|show|reindex``: the run catalog (:mod:`app.core.catalog`) from the command line.

``list [--dir DIR] [--where KEY=VALUE …] [--since DATE] [--format table|csv|json]``: the recordings under DIR (default:
the data folder's recordings, and every other recording the app indexed when it wrote it), after reading again
those that are new or changed; ``csv`` is a header line then one line per recording. ``show FILE``: its run documents
and what the catalog holds of it. ``reindex [--dir DIR]``: read every recording under DIR again. Main thread.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path
from typing import Any

from app.core.catalog import COLUMNS, Catalog, unreadable_words
from app.core.recording import check_input
from app.core.run_documents import read_documents
from app.core.user_folders import recordings_dir

TABLE_COLUMNS = (("started", 16), ("plan_name", 19), ("scene", 16), ("controller", 11), ("speed_rad_s", 6),
                 ("seed", 4), ("trial", 5), ("outcome", 13), ("exit_status", 10))
PROGRESS_EVERY_S = 0.5  # how often a long reading's line on a terminal is rewritten


def _folder(args: argparse.Namespace) -> tuple[Path, bool]:
    if args.dir:
        folder = Path(args.dir)
        if not folder.is_dir():
            raise ValueError(f"{folder}: no such folder (--dir names a folder of recordings)")
        return folder, True
    return recordings_dir(), False


class _Reading:
    """``progress(done, total)`` for :meth:`Catalog.sync`: on a terminal, one stderr line rewritten at most every
    :data:`PROGRESS_EVERY_S` ("reading recordings: 340 of 1,000"), wiped at the end; elsewhere silent (a log or a
    pipe keeps only the result)."""

    def __init__(self) -> None:
        self._tty = sys.stderr.isatty()
        self._told = -float("inf")
        self._width = 0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if not self._tty or (now - self._told < PROGRESS_EVERY_S and done < total):
            return
        self._told = now
        text = f"reading recordings: {done:,} of {total:,}"
        sys.stderr.write("\r" + text.ljust(self._width))
        self._width = len(text)
        if done == total:
            sys.stderr.write("\r" + " " * self._width + "\r")
            self._width = 0
        sys.stderr.flush()


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _list(args: argparse.Namespace) -> int:
    folder, given = _folder(args)
    with Catalog() as catalog:
        if catalog.note:
            print(f"sensnake runs: {catalog.note}", file=sys.stderr)
        if folder.is_dir():
            catalog.sync(folder, progress=_Reading())
            if catalog.unreadable:
                print(f"sensnake runs: note: {unreadable_words(catalog.unreadable)}", file=sys.stderr)
        if not given:
            catalog.prune()
        rows = catalog.query(folder if given else None, args.where, args.since)
    names = [c.name for c in COLUMNS]
    if args.format == "csv":
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(["file", *names[1:]])
        for row in rows:
            writer.writerow([_cell(row.get(n)) for n in names])
    elif args.format == "json":
        json.dump([{("file" if n == "path" else n): row.get(n) for n in names} for row in rows], sys.stdout,
                  indent=1)
        print()
    else:
        print("  ".join(f"{name.removesuffix('_name').removesuffix('_rad_s'):<{width}}"
                        for name, width in TABLE_COLUMNS) + "  file")
        root = str(folder.resolve()) + "/"
        for row in rows:
            cells = []
            for name, width in TABLE_COLUMNS:
                text = _cell(row.get(name))
                text = text[:16].replace("T", " ") if name == "started" else text
                cells.append(f"{text[:width]:<{width}}")
            path = str(row["path"])
            cells.append(path[len(root):] if path.startswith(root) else path)
            print("  ".join(cells))
        print(f"{len(rows)} run(s)" + (f" under {folder}" if given else ""))
    return 0


def _show(args: argparse.Namespace) -> int:
    path = Path(args.file)
    if not path.is_file():
        check_input(path)  # a FIFO, a device, a link loop: named for what it is
        raise ValueError(f"{path}: no such recording")
    with Catalog() as catalog:
        entry = catalog.index(path)
    if entry.get("problem"):
        raise ValueError(f"{path}: {entry['problem']}")
    start, stop = read_documents(path)
    print(f"{path}")
    print("run_start: " + (json.dumps(start, indent=2, ensure_ascii=False) if start else
                           "none (recorded before run documents; what the file says is below)"))
    print("run_stop: " + (json.dumps(stop, indent=2, ensure_ascii=False) if stop else
                          ("none: the run was cut short" if start else "none")))
    print("catalog:")
    for column in COLUMNS:
        if column.name != "path" and entry.get(column.name) is not None:
            print(f"  {column.name}: {_cell(entry[column.name])}")
    return 0


def _reindex(args: argparse.Namespace) -> int:
    folder, _ = _folder(args)
    if not folder.is_dir():
        print(f"no recordings folder yet ({folder}): nothing to index")
        return 0
    started = time.perf_counter()
    with Catalog() as catalog:
        if catalog.note:
            print(f"sensnake runs: {catalog.note}", file=sys.stderr)
        read, forgotten = catalog.sync(folder, force=True, progress=_Reading())
        if catalog.unreadable:
            print(f"sensnake runs: note: {unreadable_words(catalog.unreadable)}", file=sys.stderr)
        where = catalog.path
    print(f"indexed {read} recording(s) under {folder} in {time.perf_counter() - started:.1f} s"
          + (f"; {forgotten} gone, forgotten" if forgotten else "") + f"; catalog {where}")
    return 0


def run(args: argparse.Namespace) -> int:
    actions = {"list": _list, "show": _show, "reindex": _reindex}
    if args.runs_command not in actions:  # argparse's choices refuse others; kept for a direct call
        raise ValueError(f"unknown action {args.runs_command!r}; known: {', '.join(actions)}")
    return actions[args.runs_command](args)
