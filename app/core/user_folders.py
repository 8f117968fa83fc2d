"""One per-user folder for everything the lab saves: recordings, shapes, calibrations and settings.

The folder is the platform's user data folder, chosen by ``platformdirs``: ``~/.local/share/sensnake`` on Linux
(``$XDG_DATA_HOME`` respected), ``~/Library/Application Support/sensnake`` on macOS, ``%APPDATA%\\sensnake`` on
Windows. Inside it::

    recordings/      HDF5 recordings (the Forces tab's default, `record` files you choose to keep there)
    shapes/          the shape library (Teach saves, Gait and `play` load)
    calibrations/    calibration JSON files and the rig's run folders (trial CSVs + protocol.json)
    plots/           plot layouts saved from the Plots dock while it shows the live lab (app.core.series)
    settings.ini     the window's settings (geometry, last tab, …)
    catalog.sqlite   the run catalog (app.core.catalog): the recordings' run documents indexed; rebuilt from the files

``$SENSNAKE_DATA_DIR`` moves the whole tree (a shared lab disk, a test's temporary folder); the older per-kind
variables ``$SENSNAKE_RECORDINGS_DIR`` and ``$SENSNAKE_SHAPES_DIR`` still move one kind. File dialogs start in these
folders, never in the process's current directory. Functions here only compute paths; :func:`ensure_folder` creates
one. Any thread.
"""

from __future__ import annotations

import os
from pathlib import Path

import platformdirs

APP_DIR_NAME = "sensnake"
DATA_DIR_ENV = "SENSNAKE_DATA_DIR"
RECORDINGS_DIR_ENV = "SENSNAKE_RECORDINGS_DIR"
SHAPES_DIR_ENV = "SENSNAKE_SHAPES_DIR"

RECORDINGS = "recordings"
SHAPES = "shapes"
CALIBRATIONS = "calibrations"
PLOTS = "plots"
SETTINGS_FILE = "settings.ini"


def data_dir() -> Path:
    """The per-user data folder (not created here)."""
    override = os.environ.get(DATA_DIR_ENV, "").strip()
    if override:
        return Path(override).expanduser()
    # roaming=True: on Windows, %APPDATA% (follows the user between lab machines), as the shape library always did.
    return platformdirs.user_data_path(APP_DIR_NAME, appauthor=False, roaming=True)


def _kind_dir(kind: str, env: str | None = None) -> Path:
    override = os.environ.get(env, "").strip() if env else ""
    return Path(override).expanduser() if override else data_dir() / kind


def recordings_dir() -> Path:
    """Where recordings go by default."""
    return _kind_dir(RECORDINGS, RECORDINGS_DIR_ENV)


def shapes_dir() -> Path:
    """The shape library's folder."""
    return _kind_dir(SHAPES, SHAPES_DIR_ENV)


def calibrations_dir() -> Path:
    """Calibration files and the calibration rig's run folders."""
    return _kind_dir(CALIBRATIONS)


def plot_layouts_dir() -> Path:
    """Plot layouts saved while the Plots dock shows the live lab (a recording's goes beside the recording)."""
    return _kind_dir(PLOTS)


def settings_path() -> Path:
    """The GUI's settings file (INI)."""
    return data_dir() / SETTINGS_FILE


def ensure_folder(folder: Path) -> Path:
    """Create ``folder`` (and its parents) if needed and return it; ``OSError`` naming the folder if that fails."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot create the folder {folder}: {exc.strerror or exc}") from exc
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder} exists but is not a folder; move it away or set ${DATA_DIR_ENV}")
    return folder


def dialog_folder(folder: Path) -> str:
    """A file dialog's start folder: ``folder``, created if it can be; else its nearest existing parent (never the
    current directory)."""
    try:
        return str(ensure_folder(folder))
    except OSError:
        for parent in folder.parents:
            if parent.is_dir():
                return str(parent)
        return str(Path.home())
