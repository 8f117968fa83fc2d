"""The Hardware tab: wires :class:`widgets.hardware_panel.HardwarePanel` to ``lab.robot``.

Live values come from a ≤ 10 Hz timer reading the bridge's latest state and health (never per sample), and the timer
runs only while the tab is on screen. Scans run one baud rate per bus call so progress can be shown; the link check
pings every servo a few times on the bus thread and times each round trip there. GUI thread only.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from PySide6.QtCore import QTimer
from PySide6.QtGui import QHideEvent, QShowEvent
from PySide6.QtWidgets import QMessageBox, QVBoxLayout, QWidget

from app.gui.lab import LabContext
from app.gui.robot_bridge import describe_error
from devices import bus_commands
from devices.bus_commands import LINK_CHECK_ROUNDS, bus_command
from devices.errors import hardware_error_advice
from devices.servo_chain import scan_problems
from widgets.hardware_panel import HardwarePanel

REFRESH_INTERVAL_MS = 100  # 10 Hz: enough for a table a person reads
LOOP_STATS_EVERY = 5  # refreshes between control-loop statistics updates (2 Hz; they sort 4096 periods)


class HardwareTab(QWidget):
    """Connect, scan, watch and command the servos of ``lab.robot``."""

    def __init__(self, lab: LabContext, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        self.robot = lab.robot
        self.panel = HardwarePanel()
        self.panel.set_error_advice(hardware_error_advice)  # the e-manual's meaning of each error bit, and the fix
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.panel)

        config = self.robot.config
        self.panel.set_servos(config.joint_ids, config.axes)
        self.panel.set_port_baud(self.robot.port, self.robot.baud)
        self.refresh_count = 0
        self._shown_state: Any = None
        self._scan_ids: list[int] = []
        self._scan_queue: list[int] = []  # baud rates still to scan
        self._scan_found = 0
        self._scan_steps = 0
        self._scan_started_s = 0.0

        self.refresh_timer = QTimer(self)
        self.refresh_timer.setInterval(REFRESH_INTERVAL_MS)
        self.refresh_timer.timeout.connect(self.refresh)

        panel = self.panel
        panel.connect_requested.connect(self._connect)
        panel.disconnect_requested.connect(self.robot.disconnect_robot)
        panel.scan_requested.connect(self.start_scan)
        panel.torque_requested.connect(lambda sid, on: self.robot.set_torque(on, [sid]))
        panel.all_torque_requested.connect(lambda on: self.robot.set_torque(on))
        panel.led_requested.connect(self.robot.set_led)
        panel.reboot_requested.connect(self.ask_reboot)
        panel.link_check_requested.connect(self.start_link_check)
        panel.timing_check_requested.connect(self.start_timing_check)
        panel.fix_return_delay_requested.connect(self.fix_return_delay)

        self.robot.connection_changed.connect(self._connection_changed)
        self.robot.connected.connect(self._connected_changed)
        self._connection_changed(self.robot.connection_text)
        if self.robot.is_connected:
            self.panel.set_timing_warnings(self.robot.timing_warnings)

    # -- live view -------------------------------------------------------------------------------------------------
    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt override
        super().showEvent(event)
        self.refresh_timer.start()
        self.refresh()

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt override
        self.refresh_timer.stop()
        super().hideEvent(event)

    def refresh(self) -> None:
        """Show the latest state and health (GUI thread; skipped while the tab is hidden)."""
        if not self.isVisible() or not self.robot.is_connected:
            return
        self.refresh_count += 1
        state = self.robot.latest_state
        if state is not None and state is not self._shown_state:
            self._shown_state = state
            self.panel.set_state(state.position_rad, state.velocity_rad_s, state.current_ma)
        health = self.robot.latest_health
        if health:
            self.panel.set_health(health)
        if self.refresh_count % LOOP_STATS_EVERY == 1:
            stats = self.robot.loop_stats()
            if stats is not None:
                self.panel.set_loop_stats(self.robot.config.control_rate_hz, stats.ticks, stats.missed_ticks,
                                          stats.period_p50_s, stats.period_p99_s, stats.held_ticks)

    # -- connection ------------------------------------------------------------------------------------------------
    def _connect(self, port: str, baud: int) -> None:
        self.robot.connect_robot(port, baud)

    def _connection_changed(self, text: str) -> None:
        robot = self.robot
        self.panel.set_connection(robot.is_connected, text, busy=robot.is_connecting or text.endswith("…"))

    def _connected_changed(self, connected: bool) -> None:
        self._connection_changed(self.robot.connection_text)
        self._shown_state = None
        if connected:
            self.panel.set_timing_warnings(self.robot.timing_warnings)
            self.refresh()
        else:
            self.panel.set_timing_warnings([], checked=False)

    # -- reboot ----------------------------------------------------------------------------------------------------
    def ask_reboot(self, servo_id: int) -> None:
        """Reboot after the user confirms: the servo comes back limp, so a joint carrying load drops."""
        question = (f"Reboot servo {servo_id}? It clears a latched hardware error, but the servo comes back with "
                    "torque OFF: a joint carrying weight will drop. Support the robot first.")
        if self.confirm(question):
            self.robot.reboot(servo_id)

    def confirm(self, question: str) -> bool:
        """Ask a yes/no question (modal); tests replace this method."""
        answer = QMessageBox.question(self, "Reboot servo", question,
                                      QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No,
                                      QMessageBox.StandardButton.No)
        return answer == QMessageBox.StandardButton.Yes

    # -- scan ------------------------------------------------------------------------------------------------------
    def start_scan(self, ids: Sequence[int], bauds: Sequence[int]) -> None:
        """Scan ``ids`` at each baud rate in turn (one bus call per baud rate, so progress can be shown)."""
        self._scan_ids = list(ids)
        self._scan_queue = list(bauds)
        self._scan_steps = len(self._scan_queue)
        self._scan_found = 0
        self._scan_infos: list = []
        self._scan_started_s = time.monotonic()
        self.panel.set_scan_running(self._scan_steps, f"scanning IDs {ids[0]}–{ids[-1]}…")
        self._scan_next()

    def _scan_next(self) -> None:
        if not self._scan_queue:
            elapsed_s = time.monotonic() - self._scan_started_s
            found = self._scan_found
            problems = scan_problems(self._scan_infos, self.robot.config.joint_ids, self._scan_ids)
            if problems:
                self.panel.set_scan_finished(f"{found} servo(s) found; " + " ".join(problems), ok=False)
                return
            self.panel.set_scan_finished(
                f"{found} servo(s) found in {elapsed_s:.1f} s" if found else
                "no servo answered: check power, cable, port and baud rate (try 'all baud rates')", ok=found > 0)
            return
        baud = self._scan_queue.pop(0)
        done = self._scan_steps - len(self._scan_queue) - 1
        self.panel.set_scan_progress(done, f"{baud} baud ({done + 1}/{self._scan_steps})")
        port = self.panel.port or None
        future = self.robot.scan(bauds=[baud], ids=self._scan_ids, port=port, report_errors=False)
        self.robot.when_done(future, self._scan_step_done, self._scan_failed)

    def _scan_step_done(self, infos: list) -> None:
        self._scan_found += len(infos)
        self._scan_infos += list(infos)
        self.panel.add_scan_results(infos)
        self._scan_next()

    def _scan_failed(self, exc: BaseException) -> None:
        self._scan_queue = []
        self.panel.set_scan_finished(f"scan stopped: {describe_error(exc)}", ok=False)

    # -- link check and timing -------------------------------------------------------------------------------------
    def start_link_check(self) -> None:
        ids = list(self.robot.config.joint_ids)
        self.panel.set_link_check_running()
        future = self.robot.run_on_bus(bus_command(bus_commands.link_check, ids), report_errors=False,
                                       holds_bus=True)
        self.robot.when_done(future, lambda rows: self.panel.set_link_report(rows, LINK_CHECK_ROUNDS),
                             lambda exc: self.panel.set_link_check_failed(f"link check failed: {describe_error(exc)}"))

    def start_timing_check(self) -> None:
        self._check_timing(bus_command(bus_commands.timing_warnings))

    def fix_return_delay(self) -> None:
        """Return Delay Time → 0 on every joint (EEPROM: refused while torque is on), then re-check timing."""
        self._check_timing(bus_command(bus_commands.fix_return_delay, list(self.robot.config.joint_ids)))

    def _check_timing(self, fn: Any) -> None:
        future = self.robot.run_on_bus(fn, report_errors=False)

        def done(warnings: list[str]) -> None:
            self.robot.timing_warnings = warnings
            self.panel.set_timing_warnings(warnings)

        def failed(exc: BaseException) -> None:
            self.panel.set_timing_warnings([*self.robot.timing_warnings, f"could not do that: {describe_error(exc)}"])

        self.robot.when_done(future, done, failed)


def create_tab(lab: LabContext) -> QWidget:
    return HardwareTab(lab)
