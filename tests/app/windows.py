"""The main window as the tests open it: on a lab config, its settings in the test's folder, shown, the robot
connected (GUI thread; pytest-qt's ``qtbot``)."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import QSettings

from app.gui.lab import LabContext
from app.gui.main_window import MainWindow
from devices.config import LabConfig


def open_connected_window(qtbot, config: LabConfig, tmp_path: Path, timeout_ms: int) -> MainWindow:
    """A shown ``MainWindow`` on ``config`` whose robot has connected (fails the test if it did not within
    ``timeout_ms``). The caller closes it (which closes the lab)."""
    lab = LabContext(config)
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.show()
    with qtbot.waitSignal(lab.robot.connected, timeout=timeout_ms) as blocker:
        lab.robot.connect_robot()
    assert blocker.args == [True]
    return win
