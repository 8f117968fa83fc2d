"""The Hardware, Forces and Gait tabs' fault states read from their widgets with the app on a real X display (Xvfb,
Qt's xcb platform), as a user sees them: the tests that read those widgets, run again in a pytest of their own on the
session's X server (the rest of the suite runs offscreen).

- Hardware tab: while the link is lost or a servo is silent its row shows "—" / unknown (no old position, no
  Torque On) and "reconnecting" is not green;
- Forces tab: a board pulled mid-session is amber or red, never green;
- status bar and event log: a board missing at start-up is a visible warning;
- Gait tab: a fault in a running motion says "stopped: …", not "cannot start".
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.realdisplay.xserver import ROOT

pytestmark = pytest.mark.realdisplay

WIDGET_STATE_TESTS = (
    "tests/app/test_main_window_sim.py::test_hardware_rows_say_unknown_while_the_link_is_lost_or_a_servo_is_silent",
    "tests/app/test_forces_tab.py::"
    "test_a_pulled_board_is_amber_or_red_never_green_and_simulated_skips_are_not_lost_frames",
    "tests/app/test_main_window.py::test_a_board_missing_at_start_is_a_warning_in_the_status_bar",
    "tests/app/test_tabs_teach_gait.py::test_a_fault_after_the_gait_started_says_stopped_not_cannot_start",
)
RUN_TIMEOUT_S = 600.0


@pytest.mark.timeout(RUN_TIMEOUT_S + 60)  # four app tests in a pytest of their own (≈ 4 min on a loaded machine)
def test_fault_states_read_from_the_widgets_on_a_real_display(x_display):
    env = dict(os.environ, QT_QPA_PLATFORM="xcb", DISPLAY=x_display)
    for name in [name for name in env if name.startswith("PYTEST_XDIST")]:  # a plain pytest of its own, even when
        del env[name]  # this one runs on an xdist worker (pytest-benchmark would warn, and warnings are errors)
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:benchmark", *WIDGET_STATE_TESTS],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    tail = (done.stdout + done.stderr)[-3000:]
    assert done.returncode == 0, tail
    assert " passed" in done.stdout and "skipped" not in done.stdout.splitlines()[-1], tail
