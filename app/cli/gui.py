"""``sensnake`` / ``sensnake gui [--config FILE] [--sim]``: open the desktop app.

With no config the packaged default (every device on the simulated lab) is used; ``--sim`` forces every port to
``sim``. The robot (and the board, when its bridge is part of the build) connect at start-up on worker threads.

``SENSNAKE_QUIT_AFTER_MS=N`` closes the window N ms after start-up and prints the status bar's device lines, so a
smoke test can run the real start-up offscreen (``QT_QPA_PLATFORM=offscreen``) and check what it reached.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

QUIT_AFTER_ENV = "SENSNAKE_QUIT_AFTER_MS"


def run(args: argparse.Namespace) -> int:
    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QApplication

    from app.gui.lab import LabContext
    from app.gui.main_window import APP_NAME, ORGANIZATION, MainWindow
    from devices.config import SIM_PORT, load_config

    config = load_config(args.config)  # None → packaged default: the simulated lab
    if args.sim:
        config = config.with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    quit_after_ms = _quit_after_ms()

    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setOrganizationName(ORGANIZATION)
    app.setApplicationName(APP_NAME)

    lab = LabContext(config)
    window = MainWindow(lab)
    if args.config:
        window.config_path = Path(args.config)
        window.setWindowTitle(f"{APP_NAME} — {window.config_path.name}")
    window.show()
    lab.connect_all()

    if quit_after_ms is not None:
        def report_and_close() -> None:
            status = window.status
            for label in (status.robot_label, status.board_label, status.recording_label):
                print(label.text())
            if status.message:
                print(f"message: {status.message}")
            window.close()

        QTimer.singleShot(quit_after_ms, report_and_close)

    exit_code = app.exec()
    window.lab.close()  # the window closes it already; a second call is a no-op, kept for app.quit() paths
    return int(exit_code)


def _quit_after_ms() -> int | None:
    raw = os.environ.get(QUIT_AFTER_ENV, "").strip()
    if not raw:
        return None
    try:
        value = int(raw)
    except ValueError as exc:
        raise ValueError(f"{QUIT_AFTER_ENV}={raw!r} must be a whole number of milliseconds") from exc
    if value < 0:
        raise ValueError(f"{QUIT_AFTER_ENV}={raw!r} must not be negative")
    return value

