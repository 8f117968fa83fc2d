"""HardwarePanel as a passive view: what it shows for given data, what it emits for user actions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QHeaderView

from devices.bus_commands import LinkCheckRow
from devices.servo_chain import ServoHealth, ServoInfo
from widgets import theme
from widgets.hardware_panel import (
    COL_CUR,
    COL_DEG,
    COL_ERR,
    COL_LED,
    COL_RAD,
    COL_TEMP,
    COL_TORQUE,
    COL_VOLT,
    DXL_BAUDS_BPS,
    LIVE_SAMPLE_TEXT,
    HardwarePanel,
)

IDS = tuple(range(1, 13))
AXES = tuple("pitch" if i % 2 else "yaw" for i in IDS)


def health(servo_id: int, errors: tuple[str, ...] = (), torque: bool = True, led: bool = False,
           temperature_c: float = 31.0, voltage_v: float = 12.1) -> ServoHealth:
    return ServoHealth(servo_id=servo_id, hardware_error=32 if errors else 0, error_names=errors,
                       temperature_c=temperature_c, voltage_v=voltage_v, torque_on=torque, led_on=led)


@pytest.fixture
def panel(qtbot):
    view = HardwarePanel()
    qtbot.addWidget(view)
    view.set_servos(IDS, AXES)
    view.set_port_baud("sim", 1_000_000)
    return view


def test_one_row_per_servo_with_live_values(panel):
    assert panel.servo_table.rowCount() == 12
    angles = np.linspace(-0.5, 0.6, 12)
    panel.set_state(angles, np.full(12, 0.25), np.arange(12) * 10.0)
    assert panel.cell_text(4, COL_RAD) == f"{angles[3]:+.3f}"
    assert panel.cell_text(4, COL_DEG) == f"{math.degrees(angles[3]):+.1f}"
    panel.set_health([health(i, temperature_c=30 + i, voltage_v=12.0) for i in IDS])
    assert panel.cell_text(12, COL_TEMP) == "42"
    assert panel.cell_text(12, COL_VOLT) == "12.0"


def test_hardware_errors_are_red_with_names(panel):
    panel.set_health([health(i) for i in IDS if i != 7] + [health(7, errors=("overload",), torque=False)])
    assert panel.errors_text(7) == "overload"
    assert panel.errors_text(6) == "none"
    row7 = panel.servo_table.item(6, 8)
    assert row7.background().color().name().upper() == theme.STATUS_COLORS[theme.ERROR].upper()
    assert "hardware error" in panel.servo_summary_label.text()
    assert not panel.toggle(7, COL_TORQUE).isChecked()


def test_health_updates_toggles_without_sending_commands(panel, qtbot):
    panel.set_connection(True, "12 servos on sim")
    sent: list[tuple[int, bool]] = []
    panel.torque_requested.connect(lambda sid, on: sent.append((sid, on)))
    panel.led_requested.connect(lambda sid, on: sent.append((sid, on)))
    panel.set_health([health(i, torque=True, led=(i == 3)) for i in IDS])
    assert panel.toggle(3, COL_LED).isChecked() and panel.toggle(3, COL_LED).text() == "On"
    assert sent == []
    qtbot.mouseClick(panel.toggle(5, COL_TORQUE), Qt.MouseButton.LeftButton)
    assert sent == [(5, False)]


def test_controls_follow_the_connection(panel):
    panel.set_connection(False, "not connected")
    assert not panel.toggle(1, COL_TORQUE).isEnabled()
    assert not panel.all_torque_off_button.isEnabled()
    assert panel.port_edit.isEnabled()
    panel.set_connection(True, "12 servos on sim")
    assert panel.toggle(1, COL_TORQUE).isEnabled()
    assert not panel.port_edit.isEnabled() and not panel.connect_button.isEnabled()


def test_connect_asks_with_port_and_baud_and_rejects_a_bad_baud(panel, qtbot):
    panel.set_connection(False, "not connected")
    with qtbot.waitSignal(panel.connect_requested) as blocker:
        qtbot.mouseClick(panel.connect_button, Qt.MouseButton.LeftButton)
    assert blocker.args == ["sim", 1_000_000]
    asked: list = []
    panel.connect_requested.connect(lambda *a: asked.append(a))
    panel.baud_combo.setEditText("fast")
    qtbot.mouseClick(panel.connect_button, Qt.MouseButton.LeftButton)
    assert asked == []
    assert "not a whole number" in panel.connection_label.text()


def test_scan_request_and_results(panel, qtbot):
    panel.scan_id_from.setValue(1)
    panel.scan_id_to.setValue(20)
    with qtbot.waitSignal(panel.scan_requested) as blocker:
        qtbot.mouseClick(panel.scan_button, Qt.MouseButton.LeftButton)
    ids, bauds = blocker.args
    assert ids == list(range(1, 21)) and bauds == [1_000_000]
    panel.scan_all_bauds.setChecked(True)
    with qtbot.waitSignal(panel.scan_requested) as blocker:
        qtbot.mouseClick(panel.scan_button, Qt.MouseButton.LeftButton)
    assert blocker.args[1] == list(DXL_BAUDS_BPS)
    panel.set_scan_running(2, "scanning")
    assert not panel.scan_button.isEnabled()
    panel.add_scan_results([ServoInfo(3, 1020, "XM430-W350", 52, 1_000_000)])
    panel.set_scan_finished("1 servo(s) found")
    assert panel.scan_result_ids == [3]
    assert panel.scan_table.item(0, 1).text() == "XM430-W350 (1020)"
    assert panel.scan_button.isEnabled()


def test_link_report_counts_failures(panel):
    rows = [LinkCheckRow(1, 0.61, 0.70, 0, 0), LinkCheckRow(2, None, None, 5, 0), LinkCheckRow(3, 0.8, 1.2, 0, 2)]
    panel.set_link_report(rows, rounds=5)
    summary = panel.link_summary_label.text()
    assert "2/3 servos answered" in summary and "5 no reply" in summary and "2 CRC errors" in summary
    assert panel.link_table.item(1, 5).text() == "no reply"
    assert panel.link_table.item(2, 5).text() == "CRC errors"
    assert panel.link_table.item(0, 5).text() == "ok"


def test_timing_warnings_shown_with_their_fix(panel):
    panel.set_timing_warnings(["USB latency timer is 16 ms: fix with `echo 1 | sudo tee /sys/...`"])
    assert "echo 1 | sudo tee" in panel.timing_text.toPlainText()
    assert "1 timing warning" in panel.timing_summary_label.text()
    panel.set_timing_warnings([])
    assert "No timing problems" in panel.timing_summary_label.text()


def test_a_clicked_toggle_is_not_undone_by_stale_health(panel, qtbot):
    panel.set_connection(True, "12 servos on sim")
    panel.set_health([health(i, torque=False) for i in IDS])
    qtbot.mouseClick(panel.toggle(2, COL_TORQUE), Qt.MouseButton.LeftButton)
    panel.set_health([health(i, torque=False) for i in IDS])  # polled before the write reached the servo
    assert panel.toggle(2, COL_TORQUE).isChecked()
    panel.set_health([health(i, torque=(i == 2)) for i in IDS])  # confirmed
    panel.set_health([health(i, torque=False) for i in IDS])  # later the servo really turned off (e.g. overload)
    assert not panel.toggle(2, COL_TORQUE).isChecked()


def test_loop_stats_warn_when_ticks_are_missed(panel):
    panel.set_loop_stats(50.0, ticks=1000, missed_ticks=0, period_p50_s=0.020, period_p99_s=0.0231)
    assert panel.loop_label.text() == ("Control loop 50 Hz: period p50 20.0 ms, p99 23.1 ms; 0 of 1000 ticks missed")
    assert theme.STATUS_COLORS[theme.OK] in panel.loop_label.styleSheet()
    panel.set_loop_stats(50.0, ticks=800, missed_ticks=200, period_p50_s=0.020, period_p99_s=0.080)
    assert theme.STATUS_COLORS[theme.ERROR] in panel.loop_label.styleSheet()
    # Ticks skipped while the app held the bus on purpose (a scan): said apart, not a warning.
    panel.set_loop_stats(50.0, ticks=1000, missed_ticks=0, period_p50_s=0.020, period_p99_s=0.0231, held_ticks=40)
    assert panel.loop_label.text().endswith("0 of 1000 ticks missed; 40 held on purpose")
    assert theme.STATUS_COLORS[theme.OK] in panel.loop_label.styleSheet() and "scan" in panel.loop_label.toolTip()
    panel.set_connection(False, "not connected")
    assert panel.loop_label.text() == ""


def _count_changes(panel):
    changed: list[tuple[int, int]] = []
    panel.servo_table.model().dataChanged.connect(
        lambda top, bottom, roles=(): changed.extend((r, c) for r in range(top.row(), bottom.row() + 1)
                                                     for c in range(top.column(), bottom.column() + 1)))
    return changed


def test_set_state_touches_only_cells_whose_text_changed(panel):
    angles, velocity, current = np.radians(np.arange(12) * 10.0), np.full(12, 0.25), np.arange(12) * 10.0
    panel.set_state(angles, velocity, current)
    changed = _count_changes(panel)
    panel.set_state(angles + 1e-4, velocity, current)  # encoder noise below the shown precision: same text
    assert changed == []
    angles[3] += 0.01  # joint 4 moved: its radians and degrees change, nothing else
    panel.set_state(angles, velocity, current)
    assert sorted(changed) == [(3, COL_RAD), (3, COL_DEG)]
    assert panel.cell_text(4, COL_RAD) == f"{angles[3]:+.3f}"


def test_live_columns_are_not_measured_per_update_and_fit_their_text(panel):
    # ResizeToContents made every setText re-measure the whole table (30 ms per state update for 48 cells).
    table = panel.servo_table
    header = table.horizontalHeader()
    for col in range(table.columnCount()):
        assert header.sectionResizeMode(col) != QHeaderView.ResizeMode.ResizeToContents, col
    metrics = table.fontMetrics()
    for col, sample in LIVE_SAMPLE_TEXT.items():
        assert table.columnWidth(col) >= metrics.horizontalAdvance(sample), col
    width = table.columnWidth(COL_CUR)
    panel.set_state(np.zeros(12), np.zeros(12), np.full(12, -1.5e12))  # a garbage reading, wider than the header
    assert table.columnWidth(COL_CUR) > width
    assert table.columnWidth(COL_CUR) >= metrics.horizontalAdvance("-1500000000000")


def test_repeated_health_touches_nothing_and_warnings_come_and_go(panel):
    warn = theme.STATUS_COLORS[theme.WARN].upper()
    panel.set_health([health(i, errors=("overload",) if i == 2 else ()) for i in IDS])
    changed = _count_changes(panel)
    panel.set_health([health(i, errors=("overload",) if i == 2 else ()) for i in IDS])
    assert changed == []
    panel.set_health([health(i, temperature_c=75.0 if i == 5 else 31.0, voltage_v=9.0 if i == 6 else 12.1)
                      for i in IDS])
    assert panel.servo_table.item(4, COL_TEMP).foreground().color().name().upper() == warn
    assert panel.servo_table.item(5, COL_VOLT).foreground().color().name().upper() == warn
    assert panel.errors_text(2) == "none"
    assert panel.servo_table.item(1, COL_ERR).background().style() == Qt.BrushStyle.NoBrush
    panel.set_health([health(i) for i in IDS])
    assert panel.servo_table.item(4, COL_TEMP).foreground().style() == Qt.BrushStyle.NoBrush
    assert panel.cell_text(5, COL_TEMP) == "31"


def test_values_come_back_after_a_disconnect_cleared_them(panel):
    panel.set_connection(True, "12 servos on sim")
    angles = np.full(12, 0.5)
    panel.set_state(angles, np.zeros(12), np.zeros(12))
    panel.set_health([health(i) for i in IDS])
    panel.set_connection(False, "not connected")
    assert panel.cell_text(1, COL_RAD) == "—" and panel.cell_text(1, COL_TEMP) == "—"
    panel.set_connection(True, "12 servos on sim")
    panel.set_state(angles, np.zeros(12), np.zeros(12))  # the same values as before the disconnect
    panel.set_health([health(i) for i in IDS])
    assert panel.cell_text(1, COL_RAD) == "+0.500" and panel.cell_text(1, COL_TEMP) == "31"


def test_a_hardware_error_is_explained_with_what_to_do(panel):
    """What each bit means and what to do (the e-manual's table, devices.errors), in the cell's tooltip and on the
    summary line; an input-voltage error is not told to "remove the load"."""
    from devices.errors import hardware_error_advice

    panel.set_error_advice(hardware_error_advice)
    panel.set_health([health(i) for i in IDS if i != 4] + [health(4, errors=("input voltage error",))])
    summary = panel.servo_summary_label.text()
    assert "servo 4: input voltage error" in summary and "power supply" in summary and "remove the load" not in summary
    assert "keeps its position" in summary and "torque comes back off" in summary
    tooltip = panel.servo_table.item(3, 8).toolTip()
    assert "Min/Max Voltage Limit" in tooltip
    panel.set_health([health(i) for i in IDS if i != 4] + [health(4, errors=("overload", "overheating"))])
    tooltip = panel.servo_table.item(3, 8).toolTip()
    assert "remove the load" in tooltip and "let it cool" in tooltip
    panel.set_health([health(i) for i in IDS])
    assert panel.servo_table.item(3, 8).toolTip() == "" and panel.servo_summary_label.text() == ""


def test_the_error_a_motion_stops_on_names_the_fix_for_its_kind():
    from devices.errors import ServoHardwareError

    assert "remove the load" in str(ServoHardwareError(3, ("overload",)))
    voltage = str(ServoHardwareError(3, ("input voltage error",)))
    assert "power supply" in voltage and "remove the load" not in voltage and "reboot servo 3" in voltage
