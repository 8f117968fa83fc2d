"""The leak fixtures of tests/conftest.py fail a test that leaves a thread or a Qt timer running (napari's rule), and
pass one that cleans up. Each case runs in its own pytest process, with the fixtures re-exported from our conftest."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

CASES = textwrap.dedent('''
    import threading

    from PySide6.QtCore import QObject, QTimer

    KEEP = []


    def test_timer_left_running(qtbot):
        owner = QObject()
        KEEP.append(owner)  # alive after the test, like a widget nobody closed
        timer = QTimer(owner)
        timer.setObjectName("forgotten")
        timer.start(1000)


    def test_timer_stopped(qtbot):
        timer = QTimer()
        timer.start(1000)
        timer.stop()


    def test_thread_left_running():
        stop = threading.Event()
        KEEP.append(stop)
        threading.Thread(target=stop.wait, name="forgotten-thread", daemon=True).start()


    def test_thread_joined():
        thread = threading.Thread(target=lambda: None)
        thread.start()
        thread.join()
''')


@pytest.mark.slow
def test_leaked_timers_and_threads_fail_their_test_and_clean_ones_pass(tmp_path):
    (tmp_path / "conftest.py").write_text(
        "from tests.conftest import no_qt_timer_left_running, no_thread_left_running  # noqa: F401\n")
    (tmp_path / "test_cases.py").write_text(CASES)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
           "QT_QPA_PLATFORM": "offscreen"}
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rE",
                             "-o", "addopts=", "-o", "timeout=120", str(tmp_path / "test_cases.py")],
                            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    out = result.stdout + result.stderr
    assert result.returncode == 1, out
    assert "4 passed, 2 errors" in out, out
    assert "ERROR test_cases.py::test_timer_left_running" in out and "forgotten (owner QObject, 1000 ms)" in out, out
    assert "ERROR test_cases.py::test_thread_left_running" in out and "forgotten-thread" in out, out
