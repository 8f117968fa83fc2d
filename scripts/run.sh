#!/usr/bin/env bash
# Install what the app needs (from pyproject.toml) and open it. This is the README's "open the app" command.
#
# - pip runs only when something changed: the install is skipped when this python already has this checkout
#   installed (editable) from the same pyproject.toml (a stamp in .sensnake-install-stamp, plus a check that
#   `import app` resolves here). SENSNAKE_REINSTALL=1 forces it. A warm start costs one short python run.
# - On Linux with an X display, Qt's xcb plugin needs system libraries (libxcb-cursor0 and friends) that a fresh
#   machine may lack; Qt then aborts with a core dump. They are checked first: installed with apt-get when root,
#   otherwise the one command that installs them is printed and the app is not started.
set -euo pipefail
case "${1:-}" in -h|--help)
    echo "usage: scripts/run.sh [COMMAND ARGS...]"
    echo "Install SenSnake Studio if needed, then open the app (no arguments: on the built-in simulated lab) or run"
    echo "one sensnake command, e.g. scripts/run.sh record --help. 'sensnake --help' lists the commands."
    exit 0 ;;
esac
cd "$(dirname "$0")/.."
here=$(pwd -P)
stamp=.sensnake-install-stamp

# One python start answers everything (each start costs ~0.1 s): the interpreter, whether this checkout is what
# `import app` finds (an editable install of here, or here on PYTHONPATH) with its metadata installed, and where
# PySide6's Qt lives (for the xcb check below; found without importing it).
probe_python() {
    python3 - "$here" <<'EOF' 2>/dev/null
import importlib.metadata, importlib.util, os, sys
print(sys.executable, sys.version.split()[0])
try:
    importlib.metadata.version("sensnake-studio")
    spec = importlib.util.find_spec("app")
    here = bool(spec and spec.origin and os.path.realpath(spec.origin).startswith(sys.argv[1] + os.sep))
except Exception:  # not installed, or a broken install: reinstall
    here = False
print("installed" if here else "missing")
spec = importlib.util.find_spec("PySide6")
print(os.path.join(os.path.dirname(spec.origin), "Qt") if spec and spec.origin else "")
EOF
}

probe=$(probe_python || true)
interpreter=$(echo "$probe" | sed -n 1p)
state=$(echo "$probe" | sed -n 2p)
# What an install depends on: the interpreter and the project's declared dependencies.
key=$( { echo "$interpreter"; cat pyproject.toml; } | cksum | cut -d' ' -f1)
if [ "${SENSNAKE_REINSTALL:-0}" != "1" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$key" ] \
        && [ "$state" = "installed" ]; then
    XCB_QT_DIR=$(echo "$probe" | sed -n 3p)  # nothing changed since the last install
else
    echo "Installing SenSnake Studio and what it needs (pip install -e .)…"
    python3 -m pip install --quiet --disable-pip-version-check -e .
    echo "$key" > "$stamp"
    XCB_QT_DIR=""  # PySide6 may have just arrived: xcb_deps.sh finds it
fi
export XCB_QT_DIR

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
