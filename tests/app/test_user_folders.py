"""One per-user data folder (platformdirs) for recordings, shapes, calibrations and settings; every file dialog starts
in it, never in the process's current directory."""

from __future__ import annotations

from pathlib import Path

import platformdirs
import pytest
from PySide6.QtWidgets import QFileDialog

from app.core import user_folders
from app.core.shapes import ShapeLibrary

ENV_VARS = (user_folders.DATA_DIR_ENV, user_folders.RECORDINGS_DIR_ENV, user_folders.SHAPES_DIR_ENV)


@pytest.fixture
def clean_env(monkeypatch):
    for name in ENV_VARS:
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


def test_the_default_is_the_platforms_user_data_folder(clean_env, tmp_path):
    clean_env.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))  # honoured on Linux, as the platform wants
    expected = platformdirs.user_data_path("sensnake", appauthor=False, roaming=True)
    assert user_folders.data_dir() == expected
    assert {user_folders.recordings_dir().parent, user_folders.shapes_dir().parent,
            user_folders.calibrations_dir().parent, user_folders.settings_path().parent} == {expected}
    assert ShapeLibrary().root == user_folders.shapes_dir()


def test_one_variable_moves_the_whole_tree_and_the_old_per_kind_ones_still_work(clean_env, tmp_path):
    clean_env.setenv(user_folders.DATA_DIR_ENV, str(tmp_path / "lab"))
    assert user_folders.recordings_dir() == tmp_path / "lab" / "recordings"
    assert user_folders.shapes_dir() == tmp_path / "lab" / "shapes"
    assert user_folders.calibrations_dir() == tmp_path / "lab" / "calibrations"
    assert user_folders.settings_path() == tmp_path / "lab" / "settings.ini"
    clean_env.setenv(user_folders.SHAPES_DIR_ENV, str(tmp_path / "shared-shapes"))
    assert user_folders.shapes_dir() == tmp_path / "shared-shapes"
    assert user_folders.recordings_dir() == tmp_path / "lab" / "recordings"


def test_a_dialog_folder_is_created_or_falls_back_to_an_existing_parent(tmp_path):
    folder = tmp_path / "a" / "b"
    assert user_folders.dialog_folder(folder) == str(folder) and folder.is_dir()
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert user_folders.dialog_folder(blocker / "recordings") == str(tmp_path)
    with pytest.raises(OSError, match=str(blocker)):
        user_folders.ensure_folder(blocker / "recordings")


@pytest.fixture
def dialogs(monkeypatch):
    """Every QFileDialog call records (title, start folder) and returns as if cancelled."""
    calls: list[tuple[str, str]] = []

    def recorder(cancelled):
        def dialog(_parent, title, start="", *_args, **_kwargs):
            calls.append((title, str(start)))
            return cancelled
        return staticmethod(dialog)

    monkeypatch.setattr(QFileDialog, "getOpenFileName", recorder(("", "")))
    monkeypatch.setattr(QFileDialog, "getSaveFileName", recorder(("", "")))
    monkeypatch.setattr(QFileDialog, "getOpenFileNames", recorder(([], "")))
    return calls


def test_every_file_dialog_of_the_window_starts_in_the_user_folder(qtbot, dialogs, clean_env, tmp_path,
                                                                     monkeypatch):
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from devices.config import LabConfig, RobotConfig

    clean_env.setenv(user_folders.DATA_DIR_ENV, str(tmp_path / "data"))
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    lab = LabContext(LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port")))
    window = MainWindow(lab)  # default settings: settings.ini in the user folder
    qtbot.addWidget(window)
    try:
        assert Path(window.settings.fileName()) == tmp_path / "data" / "settings.ini"
        window._choose_config()
        calibration = window.show_tab("calibration")
        for name in ("_choose_trials", "_choose_physics", "_choose_save"):
            getattr(calibration, name)()
        forces = window.show_tab("forces")
        for name in ("_browse_recording_path", "_choose_calibration", "_choose_recording", "_choose_overlay"):
            getattr(forces, name)()
    finally:
        window.close()
    assert len(dialogs) >= 7, dialogs
    data = tmp_path / "data"
    for title, start in dialogs:
        assert Path(start) == data or data in Path(start).parents, (title, start)
        assert not (Path(start) == elsewhere or elsewhere in Path(start).parents), (title, start)
