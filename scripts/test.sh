#!/usr/bin/env bash
# Install what the tests need (from pyproject.toml), run ruff, mypy and the import contracts, then the tests. This is
# the README's test command (and all that .ci/run runs).
# Everything runs on Qt's offscreen platform except tests/realdisplay, which start their own Xvfb and run the app on
# it with the xcb platform (repaint bugs show only on a real display). Xvfb and the xcb libraries are installed here
# when root with apt; otherwise those tests are skipped and this script says so.
set -euo pipefail
case "${1:-}" in -h|--help)
    echo "usage: scripts/test.sh [PYTEST ARGS...]"
    echo "Install the test dependencies, run ruff, mypy and the import contracts, then pytest (with PYTEST ARGS,"
    echo "e.g. tests/widgets -k legend). Real-display tests need Xvfb (installed here when root with apt)."
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
echo "== tests"
python3 -m pytest -q "$@"
