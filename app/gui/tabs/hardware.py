"""The Hardware tab: wires :class:`widgets.hardware_panel.HardwarePanel` (bus, servos, scan, link check, timing) and
:class:`widgets.servo_settings_view.ServoSettingsView` (each servo's control table, settings files, zero pose) to
``lab.robot``.

Live values come from a ≤ 10 Hz timer reading the bridge's latest state and health (never per sample), and the timer
runs only while the tab is on screen. Scans run one baud rate per bus call so progress can be shown; the link check
pings every servo a few times on the bus thread and times each round trip there. The settings page reads one servo's
whole table in one request (at most 2 Hz while "Live" is on and the page is shown, one read in flight at a time, between
the control loop's ticks) and writes through :mod:`app.core.servo_settings` (range-checked, read before write, torque
off around an EEPROM write after the user agrees, read back). GUI thread only.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from PySide6.QtCore import QTimer
from PySide6.QtGui import QHideEvent, QShowEvent
from PySide6.QtWidgets import QFileDialog, QMessageBox, QTabWidget, QVBoxLayout, QWidget

from app.core import direction_check, servo_settings, user_folders
from app.core.errors import SettingsError
from app.core.outputs import write_new_file
from app.gui.lab import LabContext
from app.gui.robot_bridge import HALTED_TEXT, MOTION_HALTED, describe_error
from devices import bus_commands
from devices import control_table as ct
from devices.bus_commands import LINK_CHECK_ROUNDS, bus_command
from devices.config import default_config_path
from devices.errors import hardware_error_advice
from devices.servo_chain import scan_problems
from widgets import theme
from widgets.hardware_panel import HardwarePanel
from widgets.servo_settings_view import LIVE_INTERVAL_MS, ServoSettingsView, TableRow
from widgets.zero_pose_dialog import ZeroPoseDialog

REFRESH_INTERVAL_MS = 100  # 10 Hz: enough for a table a person reads
# Feedback older than this is not shown as the servos' present state (the controller's watchdog calls a servo silent
# after 0.2 s of unanswered polling; a busy GUI delivers states late but the newest is read when shown).
STALE_FEEDBACK_S = 0.5
LOOP_STATS_EVERY = 5  # refreshes between control-loop statistics updates (2 Hz; they sort 4096 periods)


class HardwareTab(QWidget):
    """Connect, scan, watch and command the servos of ``lab.robot``."""

    def __init__(self, lab: LabContext, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        self.robot = lab.robot
        self.panel = HardwarePanel()
        self.panel.set_error_advice(hardware_error_advice)  # the e-manual's meaning of each error bit, and the fix
        self.settings = ServoSettingsView()
        self.settings.set_rows(table_rows())
        self.pages = QTabWidget()
        self.pages.setDocumentMode(True)
        # Pages on the side: the bus page's scan and link tables need the height a tab bar on top would take.
        self.pages.setTabPosition(QTabWidget.TabPosition.West)
        self.pages.addTab(self.panel, "Bus and servos")
        self.pages.addTab(self.settings, "Servo settings")
        self.pages.currentChanged.connect(lambda _i: self._settings_page_shown())
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.pages)
        self._reading = False  # a table read is in flight (the live poll never stacks reads)
        self.table_reads = 0  # reads sent (tests: the live poll's rate)

        config = self.robot.config
        self.panel.set_servos(config.joint_ids, config.axes)
        self.settings.set_servos(config.joint_ids, config.axes)
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
        self.live_timer = QTimer(self)
        self.live_timer.setInterval(LIVE_INTERVAL_MS)
        self.live_timer.timeout.connect(self._live_read)

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
        settings = self.settings
        settings.read_requested.connect(self.read_table)
        settings.live_toggled.connect(lambda _on: self._settings_page_shown())
        settings.write_requested.connect(self.write_item)
        settings.save_requested.connect(self.save_settings)
        settings.restore_requested.connect(self.restore_settings)
        settings.zero_requested.connect(self.set_zero_pose)
        settings.direction_requested.connect(self.check_direction)
        settings.reset_requested.connect(self.factory_reset)
        self.robot.profile_applied.connect(self._profile_applied)
        if self.robot.last_profile_changes:
            self._profile_applied(self.robot.last_profile_changes)

        self.robot.connection_changed.connect(self._connection_changed)
        self.robot.connected.connect(self._connected_changed)
        self._connection_changed(self.robot.connection_text)
        if self.robot.is_connected:
            self.panel.set_timing_warnings(self.robot.timing_warnings, notes=self.robot.timing_notes)
        self.settings.set_enabled(self.robot.is_connected, "" if self.robot.is_connected else NOT_CONNECTED)

    # -- live view -------------------------------------------------------------------------------------------------
    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt override
        super().showEvent(event)
        self.refresh_timer.start()
        self.refresh()
        self._settings_page_shown()

    def hideEvent(self, event: QHideEvent) -> None:  # noqa: N802 - Qt override
        self.refresh_timer.stop()
        self.live_timer.stop()
        super().hideEvent(event)

    def refresh(self) -> None:
        """Show the latest state and health (GUI thread; skipped while the tab is hidden)."""
        if not self.isVisible() or not self.robot.is_connected:
            return
        self.refresh_count += 1
        robot = self.robot
        ids = robot.config.joint_ids
        age_s = robot.feedback_age_s()
        if robot.is_link_lost or (age_s is not None and age_s > STALE_FEEDBACK_S):
            # Nothing is read now: every row says so, none keeps the last values (or Torque On) it showed.
            silent = robot.silent_ids
            if robot.is_link_lost:
                why = f"the link to the servo bus on {robot.port} is lost (reconnecting)"
            elif silent:
                named = ", ".join(str(i) for i in sorted(silent))
                why = (f"no feedback for {age_s:.1f} s: servo {named} does not answer, and the bus's sync read "
                       "needs every servo")
            else:
                why = f"no feedback from the servos for {age_s:.1f} s"
            if robot.motion_state == MOTION_HALTED:
                why += f"; motion {robot.motion_name!r} {HALTED_TEXT}"
            self.panel.set_unknown(ids, why, silent)
            self._shown_state = None
            return
        state = robot.latest_state
        if state is not None and state is not self._shown_state:
            self._shown_state = state
            self.panel.set_state(state.position_rad, state.velocity_rad_s, state.current_ma)
        health = robot.latest_health
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
        level = theme.ERROR if robot.is_link_lost else None  # "link lost … reconnecting…" is never green
        self.panel.set_connection(robot.is_connected, text, busy=robot.is_connecting or text.endswith("…"),
                                  level=level)
        if robot.is_link_lost:
            self.refresh()  # the rows say unknown at once, not at the next tick of the timer

    def _connected_changed(self, connected: bool) -> None:
        self._connection_changed(self.robot.connection_text)
        self._shown_state = None
        self.settings.set_enabled(connected, "" if connected else NOT_CONNECTED)
        self._settings_page_shown()
        if connected:
            self.panel.set_timing_warnings(self.robot.timing_warnings, notes=self.robot.timing_notes)
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

    def confirm(self, question: str, title: str = "Reboot servo") -> bool:
        """Ask a yes/no question (modal); tests replace this method."""
        answer = QMessageBox.question(self, title, question,
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

        def done(findings: list[str]) -> None:
            self.robot.set_timing_findings(findings)
            self.panel.set_timing_warnings(self.robot.timing_warnings, notes=self.robot.timing_notes)

        def failed(exc: BaseException) -> None:
            self.panel.set_timing_warnings([*self.robot.timing_warnings, f"could not do that: {describe_error(exc)}"])

        self.robot.when_done(future, done, failed)


    # -- servo settings --------------------------------------------------------------------------------------------
    def _settings_message(self, text: str, level: str = theme.IDLE) -> None:
        """The settings page's message line, also in the event log (source "Servo settings")."""
        self.settings.set_message(text, level)
        log = getattr(self.lab, "event_log", None)
        if log is not None and text:
            log.add({theme.ERROR: "fault", theme.WARN: "warning"}.get(level, "info"), text, "Servo settings")

    def _settings_page_shown(self) -> None:
        """Read the shown servo when the page comes up; poll it while "Live" is on and the page is on screen."""
        on_page = self.pages.currentWidget() is self.settings and self.isVisible() and self.robot.is_connected
        if on_page and self.settings.live_check.isChecked():
            if not self.live_timer.isActive():
                self.live_timer.start()
        else:
            self.live_timer.stop()
        if on_page and not self.settings.values and self.settings.servo_id is not None:
            self.read_table(self.settings.servo_id)

    def _live_read(self) -> None:
        if not self.isVisible() or self.pages.currentWidget() is not self.settings:
            self.live_timer.stop()
            return
        if self.settings.servo_id is not None and not self._reading:
            self.read_table(self.settings.servo_id)

    def read_table(self, servo_id: int) -> None:
        """Every item of ``servo_id`` in one request, shown when it comes back."""
        if not self.robot.is_connected:
            self.settings.set_enabled(False, NOT_CONNECTED)
            return
        self._reading = True
        self.table_reads += 1
        future = self.robot.run_on_bus(bus_command(servo_settings.read_table, servo_id), report_errors=False)

        def done(values: dict[str, int]) -> None:
            self._reading = False
            self.settings.set_values(servo_id, values)

        def failed(exc: BaseException) -> None:
            self._reading = False
            self._settings_message(f"servo {servo_id}: could not read its table: {describe_error(exc)}",
                                      theme.ERROR)

        self.robot.when_done(future, done, failed)

    def write_item(self, servo_id: int, name: str, value: int) -> None:
        """Write one item (range already checked by the page); an EEPROM item on a servo with torque on asks first."""
        entry = ct.ITEMS_BY_NAME[name]
        if name == "Baud Rate" and not self.confirm(
                f"Move servo {servo_id} to {ct.BAUD_RATES_BPS.get(value, value)} bps? It leaves this bus's "
                f"{self.robot.baud} bps at once: the robot loses it (torque off) until the other servos and the app "
                "use the same rate. Dynamixel Wizard does the same.", "Change a servo's baud rate"):
            self._settings_message("Baud Rate not written", theme.IDLE)
            self.settings.restore_value(name)
            self.read_table(servo_id)  # and what the servo holds, read again
            return
        if entry.eeprom and name != "Baud Rate" and self.settings.values.get("Torque Enable") == 1 and not self.confirm(
                f"{name} lives in EEPROM: servo {servo_id} accepts the write only with its torque off. Turn its "
                "torque off, write, and turn it back on? The joint goes limp for a moment: support the robot.",
                "Write an EEPROM item"):
            self._settings_message(f"{name} not written (torque stays on)", theme.WARN)
            self.settings.restore_value(name)  # the cell shows the servo's value again, at once
            self.read_table(servo_id)  # and what the servo holds, read again
            return
        self._settings_message(f"writing {name} = {value} on servo {servo_id}…", theme.WARN)
        future = self.robot.run_on_bus(bus_command(servo_settings.set_item, servo_id, name, value),
                                       report_errors=False)

        def done(change: servo_settings.Change) -> None:
            if change.written:
                self._settings_message(f"servo {servo_id}: {name} {change.before} → {change.after}, read back "
                                          "✔" + ("; put the new ID into the lab config's [robot] joint_ids"
                                                 if name == "ID" else ""), theme.OK)
            else:
                self._settings_message(f"servo {servo_id}: {name} already held {value}: not written", theme.IDLE)
            self.settings.show_changes(f"Last write (servo {servo_id})", [change])
            if servo_settings.baud_note(change):
                self._settings_message(servo_settings.baud_note(change), theme.WARN)
                return  # it no longer answers at this bus's rate: nothing to read back here
            self.read_table(servo_id)

        def failed(exc: BaseException) -> None:
            self._settings_message(f"servo {servo_id}: {name} not written: {describe_error(exc)}", theme.ERROR)
            self.read_table(servo_id)

        self.robot.when_done(future, done, failed)

    def save_settings(self) -> None:
        """Back up every joint's control table into a new file (an existing file is never replaced)."""
        path = self.ask_path("save", "Save servo settings", "servos.json")
        if not path:
            return
        try:  # before the servos are read: a name taken, a FIFO or a missing folder is said at once
            servo_settings.check_new_file(path)
        except OSError as exc:
            self._settings_message(f"settings not saved: {exc.strerror or exc}", theme.ERROR)
            return
        ids = list(self.robot.config.joint_ids)
        self._settings_message(f"reading {len(ids)} servos…", theme.WARN)
        future = self.robot.run_on_bus(bus_command(servo_settings.dump, ids), report_errors=False, holds_bus=True)

        def done(document: dict[str, Any]) -> None:
            try:
                written = servo_settings.write_document(path, document)
            except OSError as exc:
                self._settings_message(f"{path}: not written: {exc.strerror or exc}", theme.ERROR)
                return
            self._settings_message(f"{len(ids)} servos' settings saved to {written}", theme.OK)

        self.robot.when_done(future, done, lambda exc: self._settings_message(
            f"settings not saved: {describe_error(exc)}", theme.ERROR))

    def restore_settings(self, servo_id: int) -> None:
        """Write a saved file back onto ``servo_id`` (0: every servo in the file), only where the servo differs."""
        path = self.ask_path("open", "Restore servo settings", "")
        if not path:
            return
        try:
            document = servo_settings.read_document(path)
        except (SettingsError, OSError, ValueError) as exc:
            self._settings_message(str(exc), theme.ERROR)
            return
        ids = [servo_id] if servo_id else None
        who = f"servo {servo_id}" if servo_id else f"{len(document['servos'])} servo(s)"
        self._settings_message(f"restoring {who} from {Path(path).name}…", theme.WARN)
        future = self.robot.run_on_bus(bus_command(servo_settings.restore, document, ids), report_errors=False,
                                       holds_bus=True)

        def done(changes: list[servo_settings.Change]) -> None:
            self.settings.show_changes(f"Restore of {who} from {Path(path).name}", changes)
            self._settings_message(servo_settings.describe_changes(changes), theme.OK)
            if self.settings.servo_id is not None:
                self.read_table(self.settings.servo_id)

        self.robot.when_done(future, done, lambda exc: self._settings_message(
            f"restore stopped: {describe_error(exc)} (items before it were written; see the table)", theme.ERROR))

    def factory_reset(self, servo_id: int) -> None:
        """Factory settings on ``servo_id`` (ID and baud kept) after the user agrees; the table shows it after."""
        if not self.confirm(f"Factory reset servo {servo_id}? Its gains, limits, Return Delay Time and every other "
                            "setting go back to the factory's (its ID and baud rate are kept); it restarts with torque "
                            "OFF. Save servo settings first to be able to go back.", "Factory reset"):
            self._settings_message("factory reset not done", theme.IDLE)
            return
        self._settings_message(f"factory reset of servo {servo_id}…", theme.WARN)
        future = self.robot.run_on_bus(bus_command(servo_settings.factory_reset, servo_id), report_errors=False,
                                       holds_bus=True)

        def done(values: dict[str, int]) -> None:
            self.settings.set_values(servo_id, values)
            self._settings_message(f"servo {servo_id}: factory settings restored (ID and baud rate kept); it "
                                      "answers again, torque off", theme.OK)

        self.robot.when_done(future, done, lambda exc: self._settings_message(
            f"factory reset of servo {servo_id} failed: {describe_error(exc)}", theme.ERROR))

    def _profile_applied(self, changes: list[servo_settings.Change]) -> None:
        self.settings.show_changes("On connect, the lab config's [servos]: "
                                   + servo_settings.describe_changes(changes), changes)

    def set_zero_pose(self) -> None:
        """Make the present pose read 0 rad on every joint: preview, then the offsets into the lab config."""
        state = self.robot.latest_state
        if state is None:
            self._settings_message("no joint angles yet: connect the robot first", theme.ERROR)
            return
        config = self.robot.config
        present = [float(a) for a in state.position_rad]
        old = list(config.zero_offsets_rad)
        new = servo_settings.zero_offsets(old, present)
        target = self.lab.config_path
        if target is None:
            target_text = "a new lab config file (the packaged default cannot be changed; you choose where)"
        else:
            target_text = str(target)
        if not self.ask_zero(ZeroPoseDialog(config.joint_ids, config.axes, present, old, new, target_text, self)):
            self._settings_message("zero pose not written", theme.IDLE)
            return
        self._write_config("zero offsets", "the zero pose", lambda path: servo_settings.write_zero_offsets(path, new))

    def _write_config(self, what: str, for_what: str, write: Any) -> None:
        """``write(path)`` into the lab config the app was opened with, or (on the packaged one) into a new file the
        user names, a copy of the config (an existing file is never written over); says where it went."""
        target = self.lab.config_path
        if target is None:
            chosen = self.ask_path("save", f"New lab config with {for_what}", "my_lab.toml")
            if not chosen:
                return
            target = Path(chosen)
            text = self.lab.config.source_text or default_config_path().read_text(encoding="utf-8")
            try:  # whole or not at all, and never over a file that is there
                write_new_file(target, text.encode("utf-8"), "choose a new name (a config is never written over)")
            except OSError as exc:
                self._settings_message(f"{what} not written: {exc.strerror or exc}", theme.ERROR)
                return
        try:
            backup = write(target)
        except (SettingsError, OSError) as exc:
            self._settings_message(f"{what} not written: {exc}", theme.ERROR)
            return
        self._settings_message(f"{what} written into {target} (the file before kept as {backup.name}); they "
                                  "apply when that config is loaded: File ▸ Open config…", theme.OK)

    def check_direction(self, servo_id: int) -> None:
        """Move ``servo_id``'s joint +0.15 rad and back (torque on, holding the rest), then ask which way it went;
        "no" flips that joint's sign in the lab config."""
        config = self.robot.config
        if servo_id not in config.joint_ids:
            self._settings_message(f"servo {servo_id} is not a joint of the robot ([robot] joint_ids)", theme.ERROR)
            return
        if self.robot.motion_state in ("running", "paused"):
            self._settings_message("a motion is playing: stop it first (the check moves one joint)", theme.ERROR)
            return
        joint = list(config.joint_ids).index(servo_id)
        axis = config.axes[joint]
        self._settings_message(f"moving joint {joint + 1} (servo {servo_id}) by +{direction_check.NUDGE_RAD:g} rad "
                                  "and back — watch which way it goes…", theme.WARN)
        future = self.robot.run_motion(direction_check.JointNudge(joint), f"direction check J{joint + 1}", play=True)

        def done(outcome: str) -> None:
            if outcome != "finished":
                self._settings_message(f"direction check {outcome}: nothing asked, nothing written", theme.WARN)
                return
            answer = self.ask_direction(direction_check.question(joint, servo_id, axis))
            if answer is None:
                self._settings_message("direction check: no answer, nothing written", theme.IDLE)
            elif answer:
                self._settings_message(f"joint {joint + 1} (servo {servo_id}) moves the way the app expects",
                                          theme.OK)
            else:
                signs = direction_check.flipped_signs(config.signs, joint)
                self._write_config(f"joint {joint + 1}'s sign ({config.signs[joint]:+d} → {signs[joint]:+d})",
                                   "the joint signs", lambda path: direction_check.write_signs(path, signs))

        self.robot.when_done(future, done, lambda exc: self._settings_message(
            f"direction check stopped: {describe_error(exc)}", theme.ERROR))

    # -- questions (tests replace these) ---------------------------------------------------------------------------
    def ask_direction(self, question: str) -> bool | None:
        """Yes / No / Cancel (None)."""
        answer = QMessageBox.question(self, "Joint direction", question,
                                      QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No
                                      | QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Cancel)
        return {QMessageBox.StandardButton.Yes: True, QMessageBox.StandardButton.No: False}.get(answer)

    def ask_zero(self, dialog: ZeroPoseDialog) -> bool:
        return dialog.exec() == ZeroPoseDialog.DialogCode.Accepted

    def ask_path(self, mode: str, title: str, name: str) -> str:
        folder = user_folders.dialog_folder(user_folders.data_dir())
        if mode == "save":
            path, _filter = QFileDialog.getSaveFileName(self, title, str(Path(folder) / name) if folder else name,
                                                        "JSON or TOML (*.json *.toml);;All files (*)",
                                                        options=QFileDialog.Option.DontConfirmOverwrite)
        else:
            path, _filter = QFileDialog.getOpenFileName(self, title, folder, "Servo settings (*.json);;All files (*)")
        return path


NOT_CONNECTED = "Connect the robot (Bus and servos) to read and change its servos' settings."


def table_rows() -> list[TableRow]:
    """The XM430-W350's control table as the settings page lists it, each item with its decoding (names, bits, unit:
    :data:`devices.control_table.DECODINGS`, from the e-manual)."""
    rows = []
    for item in ct.XM430_W350_ITEMS:
        how = ct.decoding(item.name)
        rows.append(TableRow(item.address, item.name, item.size, item.writable, item.eeprom,
                             servo_settings.UNITS.get(item.name, ""), item.minimum, item.maximum, names=how.names,
                             bits=how.bits, scale=how.scale, quantity_unit=how.unit, notes=how.notes))
    return rows


def create_tab(lab: LabContext) -> QWidget:
    return HardwareTab(lab)
