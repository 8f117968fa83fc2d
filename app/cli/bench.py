"""``sensnake bench [--quick]``: run every ``benchmarks/bench_*.py`` module's ``run(quick)`` in turn.

Modules are discovered with pkgutil, so other engineers' benchmarks join by existing. A module that fails prints one
line (on stderr) and the others still run; the exit code is then 1. Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import time

import benchmarks


def discover() -> list[str]:
    """Names of the benchmark modules, sorted."""
    return sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__) if m.name.startswith("bench_"))


def run(args: argparse.Namespace) -> int:
    names = discover()
    if not names:
        print("no benchmarks found in benchmarks/bench_*.py")
        return 0
    failed = []
    for name in names:
        print(f"\n=== {name}{' (quick)' if args.quick else ''} ===", flush=True)
        start = time.perf_counter()
        try:
            module = importlib.import_module(f"benchmarks.{name}")
            module.run(quick=bool(args.quick))
        except KeyboardInterrupt:
            raise
        # A benchmark is another engineer's code run as a plug-in: whatever it raises is reported in one line and
        # must not stop the others (the same rule as a thread boundary).
        except Exception as exc:  # noqa: BLE001
            text = " ".join(str(exc).split()) or type(exc).__name__
            print(f"sensnake bench: {name} failed: {type(exc).__name__}: {text}", file=sys.stderr, flush=True)
            failed.append(name)
            continue
        print(f"--- {name}: {time.perf_counter() - start:.1f} s", flush=True)
    if failed:
        print(f"sensnake bench: {len(failed)} of {len(names)} benchmark module(s) failed: {', '.join(failed)}",
              file=sys.stderr)
        return 1
    return 0
