#!/usr/bin/env bash
# Install what the tests need (from pyproject.toml) and run them. This is the README's test command.
# Everything runs on Qt's offscreen platform except tests/realdisplay, which start their own Xvfb and run the app on
# it with the xcb platform (repaint bugs show only on a real display). Xvfb and the xcb libraries are installed here
# when root with apt; otherwise those tests are skipped and this script says so.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e ".[test]"
# shellcheck source=scripts/xcb_deps.sh
source scripts/xcb_deps.sh
if ! ensure_x_packages xvfb; then
    echo "NOTE: the real-display tests (tests/realdisplay) will be SKIPPED: no usable Xvfb/xcb here (see above)."
fi
export QT_QPA_PLATFORM=offscreen
python3 -m pytest -q "$@"
