"""``sensnake`` / ``sensnake gui [--config FILE] [--sim]``: open the desktop app.

With no config the packaged default (every device on the simulated lab) is used; ``--sim`` forces every port to
``sim``. The robot (and the board, when its bridge is part of the build) connect at start-up on worker threads.

SIGTERM, SIGHUP (a closed terminal, a logout) and Ctrl-C close the window as its close button does — a recording
in progress is closed and kept, the devices are released, the settings saved — and the app exits 128 + the signal
number, like ``sensnake record``.

``SENSNAKE_QUIT_AFTER_MS=N`` closes the window N ms after start-up and prints the status bar's device lines, so a
smoke test can run the real start-up offscreen (``QT_QPA_PLATFORM=offscreen``) and check what it reached. A robot
still connecting then (a busy machine) is waited for, up to :data:`CONNECT_GRACE_S` more, so the lines say where the
start-up ended, not how fast the machine was.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

QUIT_AFTER_ENV = "SENSNAKE_QUIT_AFTER_MS"
CONNECT_GRACE_S = 30.0  # SENSNAKE_QUIT_AFTER_MS: at most this much longer while the robot is still connecting


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

    lab = LabContext(config, lab_process=True)  # a simulated lab in its own process (devices.sim.lab_process)
    lab.config_path = Path(args.config) if args.config else None
    window = MainWindow(lab)
    if args.config:
        window.config_path = Path(args.config)
        window.setWindowTitle(f"{APP_NAME} — {window.config_path.name}")
    window.show()
    closed_by, restore_signals = close_on_signals(app, window)
    lab.connect_all()

    if quit_after_ms is not None:
        deadline = [0.0]

        def report_and_close() -> None:
            if lab.robot.is_connecting:
                if deadline[0] == 0.0:
                    deadline[0] = time.monotonic() + CONNECT_GRACE_S
                if time.monotonic() < deadline[0]:
                    QTimer.singleShot(100, report_and_close)
                    return
            status = window.status
            for label in (status.robot_label, status.board_label, status.recording_label):
                print(label.text())
            if status.message:
                print(f"message: {status.message}")
            window.close()

        QTimer.singleShot(quit_after_ms, report_and_close)

    try:
        exit_code = app.exec()
    finally:
        restore_signals()
    window.lab.close()  # the window closes it already; a second call is a no-op, kept for app.quit() paths
    signum = closed_by()
    if signum is not None:
        print(f"sensnake gui: closed by {signal.Signals(signum).name}", file=sys.stderr)
        return 128 + signum
    return int(exit_code)


STOP_SIGNALS = tuple(s for s in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None))
                     if s is not None)


def close_on_signals(app: Any, window: Any) -> tuple[Callable[[], int | None], Callable[[], None]]:
    """Make SIGINT, SIGTERM and SIGHUP close ``window`` from Qt's event loop (main thread only).

    Python runs a signal handler only between bytecodes, which never happen while Qt's loop waits; so the C-level
    handler's wake-up byte (:func:`signal.set_wakeup_fd`) goes through a pipe that a ``QSocketNotifier`` watches.
    Returns (the signal that closed the window or None, a function restoring the previous handlers).
    """
    from PySide6.QtCore import QSocketNotifier

    read_fd, write_fd = os.pipe()
    os.set_blocking(read_fd, False)
    os.set_blocking(write_fd, False)
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    previous = {s: signal.signal(s, lambda *_: None) for s in STOP_SIGNALS}  # the wake-up byte does the work
    received: list[int] = []
    notifier = QSocketNotifier(read_fd, QSocketNotifier.Type.Read, app)

    def on_signal() -> None:
        with contextlib.suppress(BlockingIOError):
            received.extend(os.read(read_fd, 64))
        if received and window.isVisible():
            window.close()

    notifier.activated.connect(on_signal)

    def restore() -> None:
        notifier.setEnabled(False)
        notifier.deleteLater()
        signal.set_wakeup_fd(previous_fd)
        for s, handler in previous.items():
            signal.signal(s, handler)
        for fd in (read_fd, write_fd):
            with contextlib.suppress(OSError):
                os.close(fd)

    return (lambda: received[0] if received else None), restore


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

