#!/usr/bin/env bash
# Install what the app needs (from pyproject.toml) and open it. This is the README's "open the app" command.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e .
exec python3 -m app "$@"
