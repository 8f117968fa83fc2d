"""The run catalog at scale: 10,000 indexed recordings listed in under a second (``sensnake runs list``).

Writes N small recordings (the root attributes and run documents of a physics-lab trial, 30 board samples each) in a
temporary folder, indexes them once (``runs reindex``), then times ``runs list --dir DIR`` as a user runs it — which
checks every file's size and time against the catalog before answering — in CSV, unfiltered and with ``--where
scene=paper_obstacle``; in-process, then as a whole command (Python's start-up included). The catalog lives in a
temporary data folder (``$SENSNAKE_DATA_DIR``): the user's is never touched.
Run: ``python -m benchmarks.bench_catalog [--quick] [--n N]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from app.core.run_documents import condition, run_start_document, run_stop_document

SCENES = ("paper_obstacle", "step", "wedge", "flat")


def write_small_recording(path: Path, index: int) -> None:
    scene = SCENES[index % len(SCENES)]
    start = run_start_document("experiment trials", condition(scene=scene, mode="follow", speed_rad_s=0.034,
                                                              controller="feedforward", tail_load_n=0.0),
                               seed=index, trial=index % 10, series_uid=f"series-{index // 10}")
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["version"] = 1
        f.attrs["started"] = "2026-12-01T10:00:00.000+00:00"
        f.attrs["config"] = ""
        f.attrs["duration_s"] = 1.0
        f.attrs["run_start"] = json.dumps(start)
        f.attrs["run_stop"] = json.dumps(run_stop_document(start, "success", "", "traversed"))
        f.create_group("daq")["time_s"] = np.arange(30) / 30.0


def _timed(argv: list[str]) -> tuple[float, int]:
    """(seconds, rows printed after the header) of one in-process ``sensnake`` command."""
    from app.cli.main import main

    started = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()) as out:
        code = main(argv)
    elapsed = time.perf_counter() - started
    if code != 0:
        raise SystemExit(f"{' '.join(argv)} exited {code}")
    return elapsed, out.getvalue().count("\n") - 1


def run(quick: bool, n: int | None = None) -> None:
    """``sensnake bench``'s entry: N recordings (10,000; 1,000 with ``quick``) written, indexed and listed."""
    n = n or (1000 if quick else 10_000)
    previous = os.environ.get("SENSNAKE_DATA_DIR")
    with tempfile.TemporaryDirectory(prefix="bench-catalog-") as scratch:
        os.environ["SENSNAKE_DATA_DIR"] = str(Path(scratch) / "data")  # never the user's catalog
        try:
            _measure(Path(scratch) / "runs", n)
        finally:
            if previous is None:
                os.environ.pop("SENSNAKE_DATA_DIR", None)
            else:
                os.environ["SENSNAKE_DATA_DIR"] = previous


def _measure(folder: Path, n: int) -> None:
    from app.cli.main import main as sensnake

    for block in range(0, n, 1000):
        sub = folder / f"series-{block // 1000:02d}"
        sub.mkdir(parents=True)
        for i in range(block, min(block + 1000, n)):
            write_small_recording(sub / f"trial-{i:05d}.h5", i)
    started = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        sensnake(["runs", "reindex", "--dir", str(folder)])
    print(f"indexed {n} recordings (runs reindex) in {time.perf_counter() - started:.1f} s")
    times: list[float] = []
    for label, extra in (("all", []), ("scene=paper_obstacle", ["--where", "scene=paper_obstacle"])):
        times = []
        rows = 0
        for _ in range(3):
            elapsed, rows = _timed(["runs", "list", "--dir", str(folder), "--format", "csv", *extra])
            times.append(elapsed)
        print(f"runs list --dir ({label}, csv): {rows} rows in {min(times) * 1000:.0f} ms (best of 3, "
              f"in-process; every file's size and time checked)")
        if label == "all":
            best_all = min(times)
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "app", "runs", "list", "--dir", str(folder), "--format", "csv"],
                            capture_output=True, text=True, check=True, env=dict(os.environ))
    wall = time.perf_counter() - started
    print(f"sensnake runs list --dir (all, csv) as a command: {result.stdout.count(chr(10)) - 1} rows in "
          f"{wall * 1000:.0f} ms (Python start-up included)")
    print(f"{n} indexed recordings list {'under' if best_all < 1.0 else 'NOT under'} a second "
          f"({best_all:.2f} s)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1,000 recordings instead of 10,000")
    parser.add_argument("--n", type=int, default=None, help="how many recordings")
    args = parser.parse_args()
    run(args.quick, args.n)
    return 0


if __name__ == "__main__":
    sys.exit(main())
