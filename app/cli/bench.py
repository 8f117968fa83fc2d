"""``sensnake bench [--quick]``: run every ``benchmarks/bench_*.py`` module's ``run(quick)`` in turn.

The benchmarks sit *above* the app (they drive its core, its devices and its views), so the app never imports them:
the registry is the package's name, :data:`BENCHMARK_PACKAGE`, and its ``bench_*`` modules are found on the path and
loaded by name only when this command runs, the way pytest loads test modules. Benchmarks join by existing. An
import-linter layers contract (pyproject) keeps ``benchmarks`` above ``app``, so a static upward import cannot come
back. A module that fails prints one line (on stderr) and the others still run; the exit code is then 1. Runs on the
CLI's main thread.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import pkgutil
import sys
import time

BENCHMARK_PACKAGE = "benchmarks"
BENCHMARK_PREFIX = "bench_"


def discover(package: str = BENCHMARK_PACKAGE) -> list[str]:
    """Names of the benchmark modules in ``package`` (found on ``sys.path``, not imported), sorted; [] if absent."""
    loaded = sys.modules.get(package)
    locations: list[str] | None
    if loaded is not None and hasattr(loaded, "__path__"):
        locations = list(loaded.__path__)  # an imported package's live path (what import_module will search)
    else:
        spec = importlib.util.find_spec(package)
        locations = list(spec.submodule_search_locations or []) if spec is not None else None
    if not locations:
        return []
    return sorted(m.name for m in pkgutil.iter_modules(list(locations)) if m.name.startswith(BENCHMARK_PREFIX))


def run(args: argparse.Namespace) -> int:
    names = discover()
    if not names:
        print(f"no benchmarks found in {BENCHMARK_PACKAGE}/{BENCHMARK_PREFIX}*.py")
        return 0
    failed = []
    for name in names:
        print(f"\n=== {name}{' (quick)' if args.quick else ''} ===", flush=True)
        start = time.perf_counter()
        try:
            module = importlib.import_module(f"{BENCHMARK_PACKAGE}.{name}")
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
