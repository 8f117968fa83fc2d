"""scripts/run.sh on a machine it does not know: pip only when something changed, and missing xcb libraries found
before Qt aborts (installed when root with apt, else the one command printed and the app not started).

The script runs for real (bash) in a copy of the scripts folder; ``python3``, ``ldd``, ``ldconfig``, ``id`` and
``apt-get`` are stand-ins on PATH that log what they were asked to do, so nothing is installed and no app opens.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FAKE_PYTHON = """#!/usr/bin/env bash
echo "python3 $*" >> "$LOG"
case "$1" in
  -m) [ "$2" = "pip" ] && exit 0; [ "$2" = "app" ] && exit 0 ;;
  -c) case "$2" in *PySide6*) echo "$QT_DIR" ;; *) echo "/usr/bin/python3 3.11.7" ;; esac; exit 0 ;;
  -) cat > /dev/null; echo "/usr/bin/python3 3.11.7"
     if [ "${INSTALLED_EXIT:-0}" = "0" ]; then echo installed; else echo missing; fi
     echo "$QT_DIR"; exit 0 ;;
esac
exit 0
"""


def _tool(folder: Path, name: str, body: str) -> None:
    path = folder / name
    path.write_text(body)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)


@pytest.fixture
def checkout(tmp_path: Path) -> dict:
    if shutil.which("bash") is None:
        pytest.skip("no bash here")
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    for name in ("run.sh", "xcb_deps.sh"):
        shutil.copy(ROOT / "scripts" / name, repo / "scripts" / name)
    shutil.copy(ROOT / "pyproject.toml", repo / "pyproject.toml")
    qt = tmp_path / "qt"
    (qt / "plugins" / "platforms").mkdir(parents=True)
    (qt / "lib").mkdir()
    (qt / "plugins" / "platforms" / "libqxcb.so").write_bytes(b"")
    (qt / "lib" / "libQt6XcbQpa.so.6").write_bytes(b"")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    _tool(bin_dir, "python3", FAKE_PYTHON)
    log = tmp_path / "log.txt"
    log.write_text("")
    env = {"PATH": f"{bin_dir}{os.pathsep}/usr/bin{os.pathsep}/bin", "LOG": str(log), "QT_DIR": str(qt),
           "HOME": str(tmp_path)}
    return {"repo": repo, "bin": bin_dir, "log": log, "env": env}


def _run(checkout: dict, **env: str) -> tuple[subprocess.CompletedProcess, str]:
    checkout["log"].write_text("")
    done = subprocess.run(["bash", str(checkout["repo"] / "scripts" / "run.sh"), "--sim"], capture_output=True,
                          text=True, env={**checkout["env"], **env}, timeout=60)
    return done, checkout["log"].read_text()


def test_pip_runs_on_the_first_start_and_again_only_when_something_changed(checkout):
    done, log = _run(checkout)
    assert done.returncode == 0, done.stderr
    assert "-m pip install" in log and "-m app --sim" in log
    done, log = _run(checkout)
    assert done.returncode == 0, done.stderr
    assert "-m pip" not in log, "warm start reinstalled although nothing changed"
    assert "-m app --sim" in log
    pyproject = checkout["repo"] / "pyproject.toml"
    pyproject.write_text(pyproject.read_text() + "\n# a new dependency\n")
    _done, log = _run(checkout)
    assert "-m pip install" in log, "a changed pyproject.toml must reinstall"
    _done, log = _run(checkout, INSTALLED_EXIT="1")  # another checkout (or nothing) is what python imports now
    assert "-m pip install" in log
    _done, log = _run(checkout, SENSNAKE_REINSTALL="1")
    assert "-m pip install" in log


def _missing_xcb(checkout: dict, uid: int) -> None:
    _tool(checkout["bin"], "ldd", "#!/usr/bin/env bash\nprintf '\\tlibxkbcommon-x11.so.0 => not found\\n"
                                  "\\tlibc.so.6 => /lib/libc.so.6\\n'\n")
    _tool(checkout["bin"], "ldconfig", "#!/usr/bin/env bash\necho 'libxcb.so.1 (libc6,x86-64) => /lib/libxcb.so.1'\n")
    _tool(checkout["bin"], "id", f"#!/usr/bin/env bash\necho {uid}\n")
    _tool(checkout["bin"], "apt-get", '#!/usr/bin/env bash\necho "apt-get $*" >> "$LOG"\n')


def test_missing_xcb_libraries_are_named_with_the_command_and_the_app_is_not_started(checkout):
    _missing_xcb(checkout, uid=1000)
    done, log = _run(checkout, DISPLAY=":0")
    assert done.returncode == 1
    assert "sudo apt-get install libxcb-cursor0 libxkbcommon-x11-0" in done.stdout
    assert "-m app" not in log and "apt-get" not in log


def test_missing_xcb_libraries_are_installed_with_apt_when_root(checkout):
    _missing_xcb(checkout, uid=0)
    done, log = _run(checkout, DISPLAY=":0")
    assert done.returncode == 0, done.stdout
    assert "apt-get install -y -qq libxcb-cursor0 libxkbcommon-x11-0" in log
    assert "-m app --sim" in log


def test_no_check_without_an_x_display_or_off_xcb(checkout):
    _missing_xcb(checkout, uid=1000)
    for env in ({}, {"DISPLAY": ":0", "QT_QPA_PLATFORM": "offscreen"}, {"DISPLAY": ":0", "WAYLAND_DISPLAY": "w-0"}):
        done, log = _run(checkout, **env)
        assert done.returncode == 0, (env, done.stdout)
        assert "-m app --sim" in log
