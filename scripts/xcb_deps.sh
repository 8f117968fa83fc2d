#!/usr/bin/env bash
# Print the Debian packages missing for Qt's xcb platform plugin (a real X display), space-separated; nothing when
# all are there. Sourced by run.sh and test.sh; needs PySide6 installed. Qt loads libxcb-cursor with dlopen (ldd does
# not list it), so that one is checked by name. Package names follow Debian's rule for a soname: libfoo.so.N ->
# libfooN, libfoo1.so.N -> libfoo1-N (lower case).
xcb_missing_packages() {
    local qt libs lib base version pkg
    qt=${XCB_QT_DIR:-}  # run.sh already knows it (saves a python start)
    if [ -z "$qt" ]; then
        qt=$(python3 -c "import os, PySide6; print(os.path.join(os.path.dirname(PySide6.__file__), 'Qt'))" \
            2>/dev/null) || return 0
    fi
    libs=$( { for f in "$qt"/plugins/platforms/libqxcb.so "$qt"/lib/libQt6XcbQpa.so.6; do
                  [ -e "$f" ] && ldd "$f" 2>/dev/null | awk '/not found/ {print $1}'; done
              ldconfig -p 2>/dev/null | grep -q "libxcb-cursor.so.0" || echo "libxcb-cursor.so.0"; } | sort -u)
    for lib in $libs; do
        base=${lib%%.so.*}
        version=${lib##*.so.}
        version=${version%%.*}
        case "$base" in *[0-9]) pkg="$base-$version" ;; *) pkg="$base$version" ;; esac
        printf '%s ' "$(echo "$pkg" | tr '[:upper:]' '[:lower:]')"
    done
}

# Install the missing packages (and, with "xvfb", the Xvfb server) when root with apt-get; otherwise print why not
# and the one command that does it. Returns 0 when everything is there afterwards.
ensure_x_packages() {
    local want missing
    missing=$(xcb_missing_packages)
    want="$missing"
    if [ "${1:-}" = "xvfb" ] && ! command -v Xvfb >/dev/null 2>&1; then
        want="$want xvfb"
    fi
    want=$(echo "$want" | xargs)
    [ -z "$want" ] && return 0
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
        echo "Installing system packages for a real X display: $want"
        if DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $want >/dev/null 2>&1 \
            || { apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $want >/dev/null 2>&1; }; then
            return 0
        fi
        echo "Could not install them with apt-get: $want"
        return 1
    fi
    echo "Missing system packages for a real X display: $want"
    echo "Install them with:  sudo apt-get install $want"
    return 1
}

# Run directly (not sourced): say what is missing, or --help.
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    case "${1:-}" in
        "") missing=$(xcb_missing_packages | xargs)
            if [ -n "$missing" ]; then echo "missing: $missing"; exit 1; fi
            echo "Qt's xcb platform has every system library it needs"; exit 0 ;;
        -h|--help) echo "usage: scripts/xcb_deps.sh"
            echo "Print the Debian packages Qt's xcb platform (a real X display) still needs; run.sh and test.sh"
            echo "source it and install them when root."; exit 0 ;;
        *) echo "usage: scripts/xcb_deps.sh [--help]" >&2; exit 2 ;;
    esac
fi
