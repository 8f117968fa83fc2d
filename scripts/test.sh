#!/usr/bin/env bash
# Install what the tests need (from pyproject.toml), run ruff, mypy and the import contracts, then the tests. This is
# the README's test command (and all that .ci/run runs).
# Everything runs on Qt's offscreen platform except tests/realdisplay, which start their own Xvfb and run the app on
# it with the xcb platform (repaint bugs show only on a real display). Xvfb and the xcb libraries are installed here
# when root with apt; otherwise those tests are skipped and this script says so.
set -euo pipefail
case "${1:-}" in -h|--help)
    echo "usage: scripts/test.sh [PYTEST ARGS...]"
    echo "Install the test dependencies, run ruff, mypy and the import contracts, then pytest: without arguments the"
    echo "whole suite (on two workers per core, then the tests that measure time alone); with PYTEST ARGS (e.g."
    echo "tests/widgets -k legend) one plain pytest run of those. Real-display tests need Xvfb (installed here when"
    echo "root with apt)."
    exit 0 ;;
esac
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e ".[test]"
# shellcheck source=scripts/xcb_deps.sh
source scripts/xcb_deps.sh
if ! ensure_x_packages xvfb; then
    echo "NOTE: the real-display tests (tests/realdisplay) will be SKIPPED: no usable Xvfb/xcb here (see above)."
fi
export QT_QPA_PLATFORM=offscreen
# Static checks first (a few seconds together); any error fails the run before the tests start.
echo "== ruff (lint, every file)"
python3 -m ruff check .
echo "== mypy (every package, scripts and tools; [tool.mypy] in pyproject.toml)"
python3 -m mypy
echo "== import contracts (lint-imports; [tool.importlinter] in pyproject.toml)"
# (through this python3, like ruff and mypy, so a console-script directory missing from PATH does not matter)
python3 -c 'import sys; from importlinter.cli import lint_imports; sys.exit(lint_imports(no_logo=True))'
export SENSNAKE_STATIC_CHECKS_PASSED=1  # (set -e: only reached when all three passed) the tests skip repeating them
# pytest's "no tests collected" (exit 5) counts as a pass here; any other exit code is the run's.
run_pytest() {
    local rc=0
    python3 -m pytest -q -p no:benchmark "$@" || rc=$?
    [ "$rc" -eq 5 ] && rc=0
    return "$rc"
}
if [ "$#" -gt 0 ]; then
    echo "== tests (as asked: $*)"
    run_pytest "$@"
    exit $?
fi
# Tests that measure wall-clock behaviour or share a machine-wide resource are marked `serial` (tests/conftest.py):
# the rest runs first on two workers per core (up to 4; a module's tests stay on one worker), then the serial ones on
# one worker per core, each module whole on one worker and those sharing LSL or Dask on one together. Two per core
# first, because most of these tests wait on clock-paced simulated labs and subprocesses (one per core kept a quiet
# 2-core machine only ~50 % busy); the serial ones together keep about half a core busy, so each still runs on a
# machine with room to spare, as a lab PC running motion capture beside the app has. Each pass prints its 15 slowest
# tests: where the run's time goes.
workers=$(python3 -c 'import os; print(max(1, min(4, 2 * len(os.sched_getaffinity(0)))))')
echo "== tests ($workers workers; those that measure time run after)"
rc=0
run_pytest -n "$workers" --dist loadfile -m "not serial" --durations=15 || rc=$?
serial_workers=$(python3 -c 'import os; print(max(1, min(4, len(os.sched_getaffinity(0)))))')
echo "== tests that measure time or share the machine ($serial_workers workers, each module on one)"
run_pytest -n "$serial_workers" --dist loadgroup -m serial --durations=15 || rc=$?
exit "$rc"
