"""The whole window on the simulated lab: Hardware tab, STOP (button and Esc), errors, clean shutdown, `sensnake gui`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PySide6.QtCore import Qt

from app.gui.robot_bridge import MOTION_RUNNING, MOTION_STOPPED
from devices import dxl_wire as wire
from devices.config import SIM_PORT, load_config
from tests.app.windows import open_connected_window
from tests.motion_sources import JointRamp
from widgets.hardware_panel import COL_DEG, COL_RAD, COL_REBOOT, COL_TEMP, COL_TORQUE

CONNECT_TIMEOUT_MS = 10_000
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def window(qtbot, sim_lab_fast, tmp_path):
    config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    win = open_connected_window(qtbot, config, tmp_path, CONNECT_TIMEOUT_MS)
    yield win
    win.close()  # closes the lab: the autouse fixture then fails the test if any device thread survived


def moving_then_stop(qtbot, window, sim_lab_fast, press_stop) -> None:
    robot = window.lab.robot
    chain = sim_lab_fast.chain
    robot.set_torque(True).result(timeout=30)
    robot.run_motion(JointRamp(index=2), "ramp")
    assert robot.motion_state == MOTION_RUNNING
    before = chain.goal_positions_ticks()[2]
    qtbot.waitUntil(lambda: abs(chain.goal_positions_ticks()[2] - before) > 20, timeout=15_000)
    # The controller announces the freeze after writing it. (Waiting for "2 more states" instead was the flaky
    # flaky STOP test: the first states delivered after the press can all predate the freeze tick when the
    # GUI thread is slow, so `frozen` was sometimes read before the freeze was written.)
    with qtbot.waitSignal(robot.event, timeout=10_000, check_params_cb=lambda text: "goals frozen" in text):
        press_stop()
    assert robot.motion_state == MOTION_STOPPED
    frozen = chain.goal_positions_ticks().copy()
    ticks: list = []
    robot.state_block.connect(ticks.extend)
    qtbot.waitUntil(lambda: len(ticks) >= 8, timeout=10_000)
    np.testing.assert_array_equal(chain.goal_positions_ticks(), frozen)
    present_ticks = chain.present_positions_rad()[2] * 4096 / (2 * np.pi) + 2048
    assert abs(frozen[2] - present_ticks) < 40  # frozen near where the joint was, not at the ramp's end
    assert all(chain.register(sid, "Torque Enable") == 1 for sid in range(1, 13))
    assert "stop" in window.status.message.lower()


def test_stop_button_freezes_motion(window, qtbot, sim_lab_fast):
    moving_then_stop(qtbot, window, sim_lab_fast,
                     lambda: qtbot.mouseClick(window.status.stop_button, Qt.MouseButton.LeftButton))


def test_escape_freezes_motion_from_any_tab(window, qtbot, sim_lab_fast):
    window.show_tab("calibration")
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow)

    def press_escape() -> None:
        target = window.focusWidget() or window
        qtbot.keyClick(target, Qt.Key.Key_Escape)

    moving_then_stop(qtbot, window, sim_lab_fast, press_escape)


def test_hardware_tab_scans_twelve_servos_and_shows_live_state(window, qtbot, sim_lab_fast):
    tab = window.show_tab("hardware")
    panel = tab.panel
    assert panel.port == "sim" and panel.baud == 1_000_000
    assert panel.disconnect_button.isEnabled() and not panel.connect_button.isEnabled()
    panel.scan_id_from.setValue(0)
    panel.scan_id_to.setValue(30)
    qtbot.mouseClick(panel.scan_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: panel.scan_button.isEnabled(), timeout=10_000)
    assert panel.scan_result_ids == list(range(1, 13))
    assert "12 servo(s) found" in panel.scan_status_label.text()
    # At the default window size the scan list shows well over four rows, and the servo table all twelve servos.
    window.resize(1280, 800)
    qtbot.waitUntil(lambda: panel.scan_table.viewport().height() // panel.scan_table.rowHeight(0) >= 6)
    assert panel.servo_table.viewport().height() >= 12 * panel.servo_table.rowHeight(0)
    assert not panel.scan_progress.isVisible() and panel.scan_status_label.isVisible()

    sim_lab_fast.chain.set_limp_position(5, 2048 + 512)  # torque is off at start: pose joint 5 by hand, +45°
    qtbot.waitUntil(lambda: panel.cell_text(5, COL_DEG) == "+45.0", timeout=15_000)
    assert panel.cell_text(5, COL_RAD) == f"{np.pi / 4:+.3f}"
    qtbot.waitUntil(lambda: panel.cell_text(5, COL_TEMP) not in ("—", ""), timeout=15_000)  # from health


def test_hardware_tab_torque_toggle_reaches_the_servo(window, qtbot, sim_lab_fast):
    panel = window.show_tab("hardware").panel
    chain = sim_lab_fast.chain
    assert chain.register(3, "Torque Enable") == 0
    button = panel.toggle(3, COL_TORQUE)
    qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: chain.register(3, "Torque Enable") == 1, timeout=15_000)
    assert chain.register(4, "Torque Enable") == 0
    qtbot.mouseClick(panel.all_torque_on_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: all(chain.register(i, "Torque Enable") == 1 for i in range(1, 13)), timeout=15_000)
    qtbot.waitUntil(lambda: all(panel.toggle(i, COL_TORQUE).isChecked() for i in range(1, 13)), timeout=15_000)
    qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: chain.register(3, "Torque Enable") == 0, timeout=15_000)
    qtbot.waitUntil(lambda: not panel.toggle(3, COL_TORQUE).isChecked() and panel.toggle(4, COL_TORQUE).isChecked(),
                    timeout=15_000)


def test_overload_names_the_servo_in_status_and_table_and_reboot_clears_it(window, qtbot, sim_lab_fast):
    tab = window.show_tab("hardware")
    panel = tab.panel
    questions: list[str] = []
    answer = {"yes": False}
    tab.confirm = lambda question: questions.append(question) or answer["yes"]  # the modal question, answered
    window.lab.robot.set_torque(True).result(timeout=30)
    sim_lab_fast.chain.inject_overload(7)
    qtbot.waitUntil(lambda: "servo 7" in window.status.message, timeout=15_000)
    assert "overload" in window.status.message.lower()
    qtbot.waitUntil(lambda: "overload" in panel.errors_text(7).lower(), timeout=15_000)
    assert panel.errors_text(6) == "none"
    reboots = sim_lab_fast.chain.count(wire.REBOOT)
    qtbot.mouseClick(panel.toggle(7, COL_REBOOT), Qt.MouseButton.LeftButton)  # asked, and declined: nothing sent
    assert len(questions) == 1 and "servo 7" in questions[0] and "torque OFF" in questions[0]
    assert sim_lab_fast.chain.count(wire.REBOOT) == reboots
    answer["yes"] = True
    qtbot.mouseClick(panel.toggle(7, COL_REBOOT), Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: panel.errors_text(7) == "none", timeout=15_000)


def test_link_check_pings_every_servo(window, qtbot, sim_lab_fast):
    panel = window.show_tab("hardware").panel
    sim_lab_fast.chain.set_no_reply(11)
    qtbot.mouseClick(panel.link_check_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(panel.link_check_button.isEnabled, timeout=10_000)
    summary = panel.link_summary_label.text()
    assert "11/12 servos answered" in summary
    row_11 = [panel.link_table.item(r, 5).text() for r in range(12) if panel.link_table.item(r, 0).text() == "11"]
    assert row_11 == ["no reply"]


def test_hardware_tab_refresh_skips_when_hidden(window, qtbot):
    tab = window.show_tab("hardware")
    qtbot.waitUntil(lambda: tab.refresh_count >= 2, timeout=10_000)
    qtbot.waitUntil(lambda: tab.panel.loop_label.text().startswith("Control loop 50 Hz"), timeout=10_000)
    window.show_tab("calibration")
    assert not tab.refresh_timer.isActive()
    count = tab.refresh_count
    tab.refresh()
    assert tab.refresh_count == count


def test_disconnect_and_reconnect_from_the_tab(window, qtbot):
    panel = window.show_tab("hardware").panel
    robot = window.lab.robot
    with qtbot.waitSignal(robot.connected, timeout=CONNECT_TIMEOUT_MS) as blocker:
        qtbot.mouseClick(panel.disconnect_button, Qt.MouseButton.LeftButton)
    assert blocker.args == [False]
    assert panel.connect_button.isEnabled() and panel.cell_text(1, COL_RAD) == "—"
    assert window.status.robot_label.text() == "Robot: not connected"
    with qtbot.waitSignal(robot.connected, timeout=CONNECT_TIMEOUT_MS) as blocker:
        qtbot.mouseClick(panel.connect_button, Qt.MouseButton.LeftButton)
    assert blocker.args == [True]
    assert "12 servos on sim" in window.status.robot_label.text()


@pytest.mark.slow
def test_sensnake_gui_sim_starts_and_quits(tmp_path):
    """The real start-up, offscreen: asked to quit 1 ms in, the app still waits for the robot it is connecting (a
    loaded machine once took longer than a fixed 2.5 s) and reports where the start-up ended."""
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", SENSNAKE_QUIT_AFTER_MS="1",
               XDG_CONFIG_HOME=str(tmp_path))  # keep the user's window settings out of it
    result = subprocess.run([sys.executable, "-m", "app", "gui", "--sim"], cwd=REPO, env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "Robot: 12 servos on sim (simulated)" in result.stdout
    assert "Traceback" not in result.stderr


def test_timing_warning_and_its_fix_from_the_tab(window, qtbot, sim_lab_fast):
    panel = window.show_tab("hardware").panel
    chain = sim_lab_fast.chain
    assert "Return Delay Time" in panel.timing_text.toPlainText()  # the sim servos ship with 500 µs, as real ones
    window.lab.robot.set_torque(True, [2]).result(timeout=30)
    qtbot.mouseClick(panel.fix_return_delay_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "could not do that" in panel.timing_text.toPlainText(), timeout=15_000)
    assert "servo 2" in panel.timing_text.toPlainText()  # EEPROM write refused with torque on, naming the servo
    window.lab.robot.set_torque(False).result(timeout=30)
    qtbot.mouseClick(panel.fix_return_delay_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "Return Delay" not in panel.timing_text.toPlainText(), timeout=15_000)
    assert all(chain.register(sid, "Return Delay Time") == 0 for sid in range(1, 13))


def test_link_check_counts_crc_errors_on_a_quiet_bus(window, qtbot, sim_lab_fast):
    panel = window.show_tab("hardware").panel
    robot = window.lab.robot
    with qtbot.waitSignal(robot.connected, timeout=CONNECT_TIMEOUT_MS):
        robot.disconnect_robot()  # no control loop: only the link check talks on the bus
    sim_lab_fast.chain.corrupt_next_replies(2, servo_id=3)
    qtbot.mouseClick(panel.link_check_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(panel.link_check_button.isEnabled, timeout=10_000)
    crc_by_id = {int(panel.link_table.item(r, 0).text()): int(panel.link_table.item(r, 4).text()) for r in range(12)}
    assert crc_by_id[3] == 2
    assert sum(crc_by_id.values()) == 2
    assert "12/12 servos answered" in panel.link_summary_label.text()
    assert "2 CRC errors" in panel.link_summary_label.text()


def test_a_scan_from_the_hardware_tab_while_a_motion_plays_is_refused_with_the_reason(window, qtbot, sim_lab_fast):
    # A scan holds the bus for whole periods: while a motion plays it is refused (with the bus time and the fix),
    # sends nothing and leaves the motion running; once the motion stops, the same scan works.
    robot = window.lab.robot
    chain = sim_lab_fast.chain
    panel = window.show_tab("hardware").panel
    robot.set_torque(True).result(timeout=30)
    robot.run_motion(JointRamp(index=2), "ramp")
    assert robot.motion_state == MOTION_RUNNING
    pings = chain.count(wire.PING)
    panel.scan_id_from.setValue(1)
    panel.scan_id_to.setValue(12)
    qtbot.mouseClick(panel.scan_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: panel.scan_button.isEnabled(), timeout=10_000)
    text = panel.scan_status_label.text()
    assert text.startswith("scan stopped: scan refused while motion 'ramp' plays")
    assert "stop the motion, then scan" in text
    assert chain.count(wire.PING) == pings
    assert robot.motion_state == MOTION_RUNNING
    before = chain.goal_positions_ticks()[2]
    qtbot.waitUntil(lambda: abs(chain.goal_positions_ticks()[2] - before) > 5, timeout=15_000)  # still moving
    robot.stop_motion()
    qtbot.waitUntil(lambda: robot.motion_state != MOTION_RUNNING, timeout=15_000)
    qtbot.mouseClick(panel.scan_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: panel.scan_button.isEnabled(), timeout=10_000)
    assert panel.scan_result_ids == list(range(1, 13))


def test_hardware_rows_say_unknown_while_the_link_is_lost_or_a_servo_is_silent(window, qtbot, sim_lab_fast):
    from widgets import theme
    from widgets.hardware_panel import COL_ERR, UNKNOWN_TEXT

    tab = window.show_tab("hardware")
    panel = tab.panel
    robot = window.lab.robot
    robot.set_torque(True).result(timeout=30)
    qtbot.waitUntil(lambda: panel.toggle(3, COL_TORQUE).text() == "On" and panel.cell_text(3, COL_RAD) != "—",
                    timeout=CONNECT_TIMEOUT_MS)

    sim_lab_fast.chain.disconnect()  # the cable pulled
    qtbot.waitUntil(lambda: robot.is_link_lost and panel.cell_text(3, COL_RAD) == "—", timeout=CONNECT_TIMEOUT_MS)
    assert all(panel.toggle(sid, COL_TORQUE).text() == UNKNOWN_TEXT for sid in robot.config.joint_ids)
    label = panel.connection_label
    assert "reconnecting" in label.text() and theme.STATUS_COLORS[theme.OK] not in label.styleSheet()
    sim_lab_fast.chain.reconnect()
    qtbot.waitUntil(lambda: not robot.is_link_lost and panel.cell_text(3, COL_RAD) != "—"
                    and panel.toggle(3, COL_TORQUE).text() == "On", timeout=CONNECT_TIMEOUT_MS)
    assert theme.STATUS_COLORS[theme.OK] in label.styleSheet()

    sim_lab_fast.chain.set_no_reply(5)  # one servo goes silent
    qtbot.waitUntil(lambda: panel.cell_text(5, COL_ERR) == "no reply", timeout=CONNECT_TIMEOUT_MS)
    assert panel.cell_text(5, COL_RAD) == "—" and panel.cell_text(5, COL_DEG) == "—"
    assert panel.toggle(5, COL_TORQUE).text() == UNKNOWN_TEXT
    assert panel.cell_text(4, COL_RAD) == "—"  # the bus's sync read needs every servo: nothing is fresh
    sim_lab_fast.chain.set_no_reply(5, False)
    qtbot.waitUntil(lambda: panel.cell_text(5, COL_RAD) != "—" and panel.cell_text(5, COL_ERR) == "none"
                    and panel.toggle(5, COL_TORQUE).text() == "On", timeout=CONNECT_TIMEOUT_MS)
