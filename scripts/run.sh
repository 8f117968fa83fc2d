#!/usr/bin/env bash
# Install what the app needs (from pyproject.toml) and open it. This is the README's "open the app" command.
#
# - pip runs only when something changed: the install is skipped when this python already has this checkout
#   installed (editable) from the same pyproject.toml (a stamp in .sensnake-install-stamp, plus a check that
#   `import app` resolves here). SENSNAKE_REINSTALL=1 forces it.
# - On Linux with an X display, Qt's xcb plugin needs system libraries (libxcb-cursor0 and friends) that a fresh
#   machine may lack; Qt then aborts with a core dump. They are checked first: installed with apt-get when root,
#   otherwise the one command that installs them is printed and the app is not started.
set -euo pipefail
cd "$(dirname "$0")/.."
here=$(pwd -P)
stamp=.sensnake-install-stamp

install_key() {
    # What an install depends on: the python interpreter and the project's declared dependencies.
    { python3 -c "import sys; print(sys.executable, sys.version)"; cat pyproject.toml; } | cksum | cut -d' ' -f1
}

installed_here() {
    # This checkout's package is what python3 imports (an editable install of here, or here on PYTHONPATH).
    python3 - "$here" <<'EOF' 2>/dev/null
import importlib.metadata, importlib.util, os, sys
importlib.metadata.version("sensnake-studio")
spec = importlib.util.find_spec("app")
sys.exit(0 if spec and spec.origin and os.path.realpath(spec.origin).startswith(sys.argv[1] + os.sep) else 1)
EOF
}

key=$(install_key)
if [ "${SENSNAKE_REINSTALL:-0}" != "1" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$key" ] && installed_here; then
    :  # nothing changed since the last install
else
    echo "Installing SenSnake Studio and what it needs (pip install -e .)…"
    python3 -m pip install --quiet --disable-pip-version-check -e .
    echo "$key" > "$stamp"
fi

qpa=${QT_QPA_PLATFORM:-}
if [ -z "$qpa" ] && [ -n "${WAYLAND_DISPLAY:-}" ]; then qpa=wayland; fi  # Qt prefers Wayland there
if [ "$(uname -s)" = "Linux" ] && [ -n "${DISPLAY:-}" ] && [ "${qpa:-xcb}" = "xcb" ]; then
    # shellcheck source=scripts/xcb_deps.sh
    source scripts/xcb_deps.sh
    if ! ensure_x_packages; then
        echo "The app cannot open a window without them (Qt's xcb platform plugin would abort)."
        exit 1
    fi
fi
exec python3 -m app "$@"
