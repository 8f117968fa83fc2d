"""The event log (Qt-free): entries in order with their whole text, filters, a recording's /events, CSV never
written over a file; and in the window: a fault one click away, whole, in the Event log dock."""

from __future__ import annotations

import csv
from types import SimpleNamespace

import pytest
from PySide6.QtCore import QSettings, Qt

from app.core import event_log
from app.core.event_log import EventLog, matches, write_csv

LONG_FAULT = ("servo 7 overload: the motion stopped at t = 12.4 s; the force page is being rebuilt from the board's "
              "blocks and the joint 7 current was 2.31 A for 0.6 s. Reboot the servo from the Hardware tab "
              "(Bus and servos, Reboot) or 'sensnake servo reboot --id 7', then lower the gait's speed.")


def test_entries_keep_their_order_kind_and_whole_text():
    log = EventLog(capacity=3)
    seen: list[tuple[int, bool]] = []
    log.subscribe(lambda new, reset: seen.append((len(new), reset)))
    log.add(event_log.INFO, "robot connected", "robot")
    fault = log.add(event_log.FAULT, LONG_FAULT, "robot")
    log.add(event_log.ACTION, "STOP (button or Esc)", "robot")
    assert [e.number for e in log.entries] == [1, 2, 3]
    assert log.latest(event_log.FAULT) is fault and fault.text == LONG_FAULT
    log.add(event_log.WARNING, "board missing", "board")  # over capacity: the oldest goes, numbers go on
    assert [e.number for e in log.entries] == [2, 3, 4]
    assert seen == [(1, False), (1, False), (1, False), (1, True)]
    assert matches(fault, [event_log.FAULT], "FORCE PAGE") and not matches(fault, [event_log.INFO])
    with pytest.raises(ValueError, match="not one of"):
        log.add("chatter", "x")


def test_a_recordings_events_are_added_once_at_their_time(tmp_path):
    log = EventLog()
    events = [SimpleNamespace(time_s=1.5, kind="gap", text="board gap 0.2 s"),
              SimpleNamespace(time_s=3.0, kind="health", text="S04B flat-lined")]
    rec = tmp_path / "run.h5"
    log.add_recorded(rec, "2026-03-02T10:00:00+00:00", events)
    log.add_recorded(rec, "2026-03-02T10:00:00+00:00", events)  # opened again: replaced, not repeated
    recorded = [e for e in log.entries if e.kind == event_log.RECORDED]
    assert [e.text for e in recorded] == ["board gap 0.2 s", "S04B flat-lined"]
    assert recorded[0].wall_time_s == pytest.approx(event_log.parse_started("2026-03-02T10:00:00Z") + 1.5)
    assert recorded[1].source == "run.h5 (health)" and recorded[1].recording_time_s == 3.0


def test_csv_holds_every_entry_and_never_replaces_a_file(tmp_path):
    log = EventLog()
    log.add(event_log.FAULT, LONG_FAULT, "robot")
    log.add(event_log.INFO, 'a "quoted", comma message', "Forces")
    out = write_csv(log.entries, tmp_path / "events.csv")
    with out.open(encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["text"] for r in rows] == [LONG_FAULT, 'a "quoted", comma message']
    assert rows[0]["kind"] == "fault" and rows[0]["source"] == "robot"
    with pytest.raises(FileExistsError, match="never over one"):
        write_csv(log.entries, out)
    (tmp_path / "link.csv").symlink_to(tmp_path / "elsewhere.csv")
    with pytest.raises(FileExistsError):
        write_csv(log.entries, tmp_path / "link.csv")
    assert not (tmp_path / "elsewhere.csv").exists()


@pytest.fixture
def window(qtbot, tmp_path):
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from devices.config import LabConfig, RobotConfig

    lab = LabContext(LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port")))
    win = MainWindow(lab, settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(win)
    win.resize(900, 600)
    win.show()
    yield win
    win.close()


def test_the_log_lists_a_fault_with_its_full_text_one_click_away(window, qtbot, tmp_path):
    window.lab.robot.error.emit(LONG_FAULT)  # what a servo's fault reaches the window as
    window.show_event("gait finished")  # an information does not hide the fresh fault, but is logged
    status = window.status
    assert status.message == LONG_FAULT and "1 fault" in status.log_button.text()
    assert status.message_label.text().endswith("…")  # the bar cuts it short
    qtbot.mouseClick(status.message_label, Qt.MouseButton.LeftButton)  # one click
    view = window.log_view
    qtbot.waitUntil(lambda: window.log_dock.isVisible())
    assert view.selected_entry().text == LONG_FAULT
    assert LONG_FAULT in view.detail_text
    assert [e.kind for e in view.visible_entries()][-2:] == ["fault", "info"]
    assert status.log_button.text() == "Log"  # seen
    # Filter by kind, search, copy, save.
    view.set_kind_visible("info", False)
    assert all(e.kind != "info" for e in view.visible_entries())
    view.set_search("OVERLOAD")
    assert [e.text for e in view.visible_entries()] == [LONG_FAULT]
    view.table.selectAll()
    assert LONG_FAULT in view.copy_selected()
    out = window.save_log(tmp_path / "log.csv")
    assert out is not None and LONG_FAULT in out.read_text(encoding="utf-8")
    assert window.save_log(tmp_path / "log.csv") is None  # never over the file just written
    assert "exists" in status.message and out.read_text(encoding="utf-8").count("overload") == 1
    # An operator action is logged as one.
    window.emergency_stop()
    assert window.event_log.latest(event_log.ACTION).text == "STOP (button or Esc)"


def _recording_with_events(path, channels):
    import time

    import numpy as np

    from app.core.recording import RecordingWriter
    from devices.board import SampleBlock

    n, c = 30, len(channels)
    t0 = time.monotonic()
    t = np.arange(n) / 30.0
    block = SampleBlock(counts=np.ones((n, c), dtype=np.uint16), conductance_s=np.full((n, c), 1e-6),
                        board_time_s=t, host_time_s=t0 + t, seq=np.arange(n, dtype=np.uint32),
                        saturated=np.zeros((n, c), dtype=bool), gap_before=None)
    with RecordingWriter(path, "", channels, t0_monotonic_s=t0) as writer:
        writer.append_daq(block)
        writer.log_event("S04B flat-lined for 0.5 s", t0 + 0.5, kind="health")


def test_a_recording_opened_in_the_forces_tab_brings_its_events(window, tmp_path):
    forces = window.show_tab("forces")
    path = tmp_path / "trial.h5"
    _recording_with_events(path, forces.channel_names)
    assert forces.open_recording_file(path) is not None
    recorded = [e for e in window.event_log.entries if e.kind == event_log.RECORDED]
    assert [(e.source, e.text) for e in recorded] == [("trial.h5 (health)", "S04B flat-lined for 0.5 s")]
    assert recorded[0].recording_time_s == pytest.approx(0.5)
    assert window.event_log.latest(event_log.ACTION).text == f"open recording {path}"
