"""``sensnake gui``: SIGTERM, SIGHUP and Ctrl-C close the window like its close button (the signal fault for the
GUI face): a recording in progress is closed, kept whole and opens in plain h5py; the previous handlers come back."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest
from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication

from app.cli.gui import close_on_signals
from app.core.recording import open_recording
from app.gui.lab import LabContext
from app.gui.main_window import MainWindow
from devices.config import LabConfig

pytestmark = [pytest.mark.skipif(sys.platform.startswith("win"), reason="POSIX signals"),
              pytest.mark.usefixtures("sim_lab_fast")]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_closes_the_window_and_keeps_the_recording(qtbot, tmp_path, monkeypatch, signum):
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)}
    lab = LabContext(LabConfig())
    window = MainWindow(lab, settings=QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(window)
    window.show()
    closed_by, restore = close_on_signals(QApplication.instance(), window)
    try:
        lab.connect_all()
        tab = window.show_tab("forces")
        out = tmp_path / "gui.h5"
        session = tab.start_recording(out)
        assert session is not None
        qtbot.waitUntil(lambda: session.n_daq_samples >= 30, timeout=20_000)
        os.kill(os.getpid(), signum)
        qtbot.waitUntil(lambda: not window.isVisible(), timeout=20_000)
        assert closed_by() == signum
        assert not session.recorder.running and session.recorder.kept and not session.error
    finally:
        restore()
        window.close()
        lab.close()
    assert {s: signal.getsignal(s) for s in before} == before
    done = subprocess.run([sys.executable, "-c", "import sys, h5py\nwith h5py.File(sys.argv[1], 'r') as f:\n"
                           "    print(f['daq/seq'].shape[0])", str(out)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) == session.n_daq_samples == open_recording(out).n_samples
