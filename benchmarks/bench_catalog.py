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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1,000 recordings instead of 10,000")
    parser.add_argument("--n", type=int, default=None, help="how many recordings")
    args = parser.parse_args()
    n = args.n or (1000 if args.quick else 10_000)
    with tempfile.TemporaryDirectory(prefix="bench-catalog-") as scratch:
        os.environ["SENSNAKE_DATA_DIR"] = str(Path(scratch) / "data")
        folder = Path(scratch) / "runs"
        for block in range(0, n, 1000):
            sub = folder / f"series-{block // 1000:02d}"
            sub.mkdir(parents=True)
            for i in range(block, min(block + 1000, n)):
                write_small_recording(sub / f"trial-{i:05d}.h5", i)
        from app.cli.main import main as sensnake

        started = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            sensnake(["runs", "reindex", "--dir", str(folder)])
        print(f"indexed {n} recordings (runs reindex) in {time.perf_counter() - started:.1f} s")
        for label, extra in (("all", []), ("scene=paper_obstacle", ["--where", "scene=paper_obstacle"])):
            times: list[float] = []
            rows = 0
            for _ in range(3):
                elapsed, rows = _timed(["runs", "list", "--dir", str(folder), "--format", "csv", *extra])
                times.append(elapsed)
            print(f"runs list --dir ({label}, csv): {rows} rows in {min(times) * 1000:.0f} ms (best of 3, "
                  f"in-process; every file's size and time checked)")
        started = time.perf_counter()
        result = subprocess.run([sys.executable, "-m", "app", "runs", "list", "--dir", str(folder), "--format", "csv"],
                                capture_output=True, text=True, check=True)
        wall = time.perf_counter() - started
        print(f"sensnake runs list --dir (all, csv) as a command: {result.stdout.count(chr(10)) - 1} rows in "
              f"{wall * 1000:.0f} ms (Python start-up included)")
        verdict = "under" if min(times) < 1.0 else "NOT under"
        print(f"{n} indexed recordings list {verdict} a second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
