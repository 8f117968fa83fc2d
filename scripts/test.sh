#!/usr/bin/env bash
# Install what the tests need (from pyproject.toml) and run them, offscreen. This is the README's test command.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e ".[test]"
export QT_QPA_PLATFORM=offscreen
python3 -m pytest -q "$@"
