"""``sensnake bench`` finds the benchmark modules by name without the app importing the benchmarks package."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from app.cli import bench

ROOT = Path(__file__).resolve().parents[2]


def test_discovery_lists_the_bench_modules_on_disk():
    on_disk = sorted(p.stem for p in (ROOT / "benchmarks").glob("bench_*.py"))
    assert on_disk and bench.discover() == on_disk


def test_an_absent_package_is_an_empty_registry():
    assert bench.discover("no_such_benchmarks_package") == []


def test_importing_the_cli_and_discovering_does_not_import_the_benchmarks():
    code = ("import sys\nfrom app.cli import bench, main\nnames = bench.discover()\n"
            "assert names, 'nothing discovered'\n"
            "assert not [m for m in sys.modules if m == 'benchmarks' or m.startswith('benchmarks.')], 'imported'\n")
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
