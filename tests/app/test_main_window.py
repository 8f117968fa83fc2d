"""The main window without a robot attached: tabs, placeholders, status bar, STOP/Esc, settings, menus."""

from __future__ import annotations

import pytest
from PySide6.QtCore import QSettings, Qt

from app.gui.lab import LabContext
from app.gui.main_window import DEFAULT_SIZE, TABS, MainWindow, TabSpec, tab_index
from devices.config import LabConfig, RobotConfig
from widgets import theme
from widgets.placeholder import PlaceholderPage

# A port that does not exist: nothing in these tests may reach a device.
NO_PORT_CONFIG = LabConfig(robot=RobotConfig(port="/dev/sensnake-test-no-such-port"))


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)


@pytest.fixture
def window(qtbot, settings):
    lab = LabContext(NO_PORT_CONFIG)
    win = MainWindow(lab, settings=settings)
    qtbot.addWidget(win)
    yield win
    win.close()


def test_tabs_in_contract_order(window):
    titles = [window.tabs.tabText(i) for i in range(window.tabs.count())]
    assert titles == ["Teach", "Gait", "Calibration", "Forces", "Hardware", "3-D lab"]
    assert [spec.name for spec in TABS] == ["teach", "gait", "calibration", "forces", "hardware", "scene"]


def test_tabs_are_built_only_when_shown(window):
    current = TABS[window.tabs.currentIndex()].name
    assert window.tab_widget(current) is not None
    others = [spec.name for spec in TABS if spec.name != current]
    assert all(window.tab_widget(name) is None for name in others)
    page = window.show_tab("calibration")
    assert window.tab_widget("calibration") is page
    assert window.tabs.currentIndex() == tab_index("calibration")


def test_missing_tab_module_shows_what_it_will_do(window):
    spec = TabSpec("does_not_exist_yet", "Future", "Will do something useful with the robot.")
    page = window._create_page(spec)
    assert isinstance(page, PlaceholderPage)
    assert page.description == spec.description
    assert "not part of this build" in page.note_label.text()


def test_every_tab_builds_or_says_what_it_will_do(window):
    for spec in TABS:
        page = window.show_tab(spec.name)
        assert page is not None
        if isinstance(page, PlaceholderPage):
            assert page.description  # a placeholder always says what the tab will do
    assert "4-force × 3-trial" in TABS[tab_index("calibration")].description


def test_unknown_tab_name_is_a_lookup_error():
    with pytest.raises(LookupError, match="no tab named"):
        tab_index("nonsense")


def test_status_bar_shows_states_and_an_always_visible_stop(window, qtbot):
    window.show()
    qtbot.waitExposed(window)
    status = window.status
    assert status.stop_button.isVisible()
    assert "STOP" in status.stop_button.text()
    assert status.robot_label.text().startswith("Robot: not connected")
    assert status.recording_label.text() == "Not recording"
    board = window.lab.board_if_created
    if board is None:
        assert status.board_label.text() == "Board: not available"
    # A long message must not push STOP out of view.
    status.show_message("x" * 2000, theme.ERROR)
    assert status.stop_button.isVisible()
    assert status.stop_button.geometry().right() <= status.width()


def test_stop_button_and_escape_reach_emergency_stop(window, qtbot):
    window.show()
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow)  # shortcuts fire only in the active window
    events: list[str] = []
    window.lab.robot.event.connect(events.append)
    qtbot.mouseClick(window.status.stop_button, Qt.MouseButton.LeftButton)
    assert events and events[-1].startswith("STOP")
    events.clear()
    # Esc is the window's shortcut: it works whatever widget of the window has focus.
    focus = window.tabs.currentWidget()
    focus.setFocus()
    qtbot.keyClick(focus, Qt.Key.Key_Escape)
    assert events and events[-1].startswith("STOP")
    assert window.stop_shortcut.context() == Qt.ShortcutContext.WindowShortcut
    assert window.stop_shortcut.key().toString() == "Esc"
    assert "not connected" in window.status.message


def test_errors_are_shown_and_not_hidden_by_events(window):
    window.show_error("servo 7 overload: motion stopped")
    window.show_event("something routine")
    assert window.status.message == "servo 7 overload: motion stopped"
    assert window.status.message_level == theme.ERROR


def test_recording_state_follows_the_lab(window, tmp_path):
    class Session:
        path = tmp_path / "trial-03.h5"

        def stop(self):
            pass

    window.lab.recording = Session()
    assert "trial-03.h5" in window.status.recording_label.text()
    window.lab.recording = None
    assert window.status.recording_label.text() == "Not recording"


def test_geometry_and_tab_are_restored(qtbot, settings):
    first = MainWindow(LabContext(NO_PORT_CONFIG), settings=settings)
    qtbot.addWidget(first)
    first.show()
    first.resize(1003, 677)
    first.show_tab("calibration")
    first.close()
    second = MainWindow(LabContext(NO_PORT_CONFIG), settings=settings)
    qtbot.addWidget(second)
    second.show()
    assert second.tabs.currentIndex() == tab_index("calibration")
    # The offscreen screen is 800 px wide, so the width is clamped to the minimum; the height shows the restore.
    assert second.height() == 677 != DEFAULT_SIZE[1]
    second.close()


def test_bad_config_file_is_reported_and_the_lab_kept(window, tmp_path, monkeypatch):
    from PySide6.QtWidgets import QMessageBox

    shown: list[str] = []
    monkeypatch.setattr(QMessageBox, "warning", lambda _parent, _title, text: shown.append(text))
    bad = tmp_path / "lab.toml"
    bad.write_text("[robot]\nbaud = 'fast'\n", encoding="utf-8")
    lab_before = window.lab
    assert window.open_config(bad) is False
    assert window.lab is lab_before
    assert shown and "robot.baud" in shown[0]
    assert "robot.baud" in window.status.message


def test_failed_connect_says_why_and_what_to_do(window, qtbot):
    robot = window.lab.robot
    with qtbot.waitSignal(robot.connected, timeout=10_000) as blocker:
        robot.connect_robot()
    assert blocker.args == [False]
    message = window.status.message
    assert "could not connect" in message and "/dev/sensnake-test-no-such-port" in message
    assert "Traceback" not in message
    assert window.status.robot_label.text() == "Robot: not connected"


def test_open_config_restarts_the_lab_on_it(window, qtbot, tmp_path):
    path = tmp_path / "bench_lab.toml"
    # (the rig stays on the simulated lab the tests run, the scripted one: its lab is not restarted)
    path.write_text('[robot]\nport = "/dev/sensnake-test-robot"\nbaud = 57600\n'
                    '[board]\nport = "/dev/sensnake-test-board"\n[lab]\nphysics = "scripted"\n', encoding="utf-8")
    old_lab = window.lab
    old_page = window.tab_widget(TABS[window.tabs.currentIndex()].name)
    assert window.open_config(path) is True
    assert window.lab is not old_lab and old_lab._closed
    assert window.lab.robot.port == "/dev/sensnake-test-robot" and window.lab.robot.baud == 57600
    assert "bench_lab.toml" in window.windowTitle()
    assert window.tab_widget(TABS[window.tabs.currentIndex()].name) is not old_page
    qtbot.waitUntil(lambda: "could not connect" in window.status.message, timeout=10_000)
    assert "/dev/sensnake-test-robot" in window.status.message


@pytest.mark.parametrize("modal", [True, False])
def test_escape_in_a_dialog_only_closes_the_dialog(window, qtbot, modal):
    """Esc in a dialog (modal or not) closes it and says nothing of a STOP; back in the window Esc stops again, and
    the STOP button always does."""
    from PySide6.QtWidgets import QMessageBox

    window.show()
    events: list[str] = []
    window.lab.robot.event.connect(events.append)
    box = QMessageBox(QMessageBox.Icon.Question, "Reboot servo", "Reboot?", QMessageBox.StandardButton.Yes
                      | QMessageBox.StandardButton.No, window)
    if modal:
        box.open()  # window-modal, without a nested event loop
    else:
        box.setModal(False)
        box.show()
    box.activateWindow()
    qtbot.waitUntil(box.isActiveWindow)
    qtbot.keyClick(box, Qt.Key.Key_Escape)
    qtbot.waitUntil(lambda: not box.isVisible())
    assert not any(e.startswith("STOP") for e in events), events
    assert "STOP" not in window.status.message

    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow)
    qtbot.keyClick(window.focusWidget() or window, Qt.Key.Key_Escape)
    assert events and events[-1].startswith("STOP")
    events.clear()
    qtbot.mouseClick(window.status.stop_button, Qt.MouseButton.LeftButton)
    assert events and events[-1].startswith("STOP")


@pytest.mark.parametrize("modal", [True, False], ids=["modal", "non-modal"])
def test_escape_in_a_dialog_while_something_moves_stops_it_and_closes_the_dialog(window, qtbot, modal, monkeypatch):
    """A modal dialog blocks clicks on STOP: while a gait or a calibration run moves, Esc in any dialog still stops
    it (and the dialog closes as usual)."""
    from PySide6.QtWidgets import QMessageBox

    window.show()
    stops: list[bool] = []
    monkeypatch.setattr(window, "something_moves", lambda: True)
    monkeypatch.setattr(window.lab, "emergency_stop", lambda: stops.append(True))
    box = QMessageBox(QMessageBox.Icon.Question, "Save", "Save the shape?", QMessageBox.StandardButton.Yes
                      | QMessageBox.StandardButton.No, window)
    if modal:
        box.open()
    else:
        box.setModal(False)
        box.show()
    box.activateWindow()
    qtbot.waitUntil(box.isActiveWindow)
    qtbot.keyClick(box, Qt.Key.Key_Escape)
    qtbot.waitUntil(lambda: not box.isVisible())
    assert stops == [True]


def test_gui_with_a_missing_config_fails_in_one_line(tmp_path, capsys):
    from app.cli import main

    missing = tmp_path / "nowhere.toml"
    assert main(["gui", "--config", str(missing)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("sensnake gui: error:") and "nowhere.toml" in err
    assert len(err.splitlines()) == 1


def test_a_board_missing_at_start_is_a_warning_in_the_status_bar(window, qtbot, tmp_path):
    from devices.config import BoardConfig

    config = LabConfig(robot=NO_PORT_CONFIG.robot, board=BoardConfig(port="/dev/sensnake-test-no-such-board"))
    window.replace_lab(LabContext(config))
    label = window.status.board_label
    assert label.level == theme.IDLE  # not tried yet
    window.lab.board.start()
    qtbot.waitUntil(lambda: label.level in (theme.WARN, theme.ERROR), timeout=10_000)
    assert "missing" in label.text() and "/dev/sensnake-test-no-such-board" in label.text()
    assert "retrying" in label.toolTip()


def test_a_tab_whose_module_is_still_importing_says_opening_and_the_window_keeps_running(qtbot, settings,
                                                                                         monkeypatch):
    """The tabs' modules are imported on a worker thread once the window is up: a tab chosen before its module is
    there says "Opening…" (the event loop runs meanwhile) and is built as soon as the module arrives."""
    import sys
    import threading

    from PySide6.QtCore import QTimer

    import app.gui.main_window as main_window
    from tests.app import slow_tab_gate

    sys.modules.pop("tests.app.slow_tab", None)
    slow_tab_gate.GATE.clear()
    slow_tab_gate.IMPORTED_ON.clear()
    slow = TabSpec("slow", "Slow", "A tab whose module takes long to import.")
    monkeypatch.setattr(main_window, "TABS", (*TABS, slow))
    monkeypatch.setattr(main_window, "_tab_module",
                        lambda spec: "tests.app.slow_tab" if spec is slow else f"app.gui.tabs.{spec.name}")
    lab = LabContext(NO_PORT_CONFIG)
    win = MainWindow(lab, settings=settings)
    qtbot.addWidget(win)
    try:
        qtbot.waitUntil(lambda: bool(slow_tab_gate.IMPORTED_ON))  # the loader reached it
        win.tabs.setCurrentIndex(len(TABS))  # the user clicks it
        assert win.tab_widget("slow") is None
        container = win.tabs.currentWidget()
        notes = [p.note_label.text() for p in container.findChildren(PlaceholderPage)]
        assert notes == ["Opening…"]
        ticks: list[int] = []
        timer = QTimer()
        timer.timeout.connect(lambda: ticks.append(1))
        timer.start(5)
        try:
            qtbot.waitUntil(lambda: len(ticks) >= 10)  # the window answers while the import goes on
        finally:
            timer.stop()
        slow_tab_gate.GATE.set()
        qtbot.waitUntil(lambda: win.tab_widget("slow") is not None)
        assert win.tab_widget("slow").text() == "the slow tab"
        assert not container.findChildren(PlaceholderPage)  # "Opening…" is gone
        assert slow_tab_gate.IMPORTED_ON and threading.main_thread() not in slow_tab_gate.IMPORTED_ON  # a worker's
    finally:
        slow_tab_gate.GATE.set()
        win.close()
        sys.modules.pop("tests.app.slow_tab", None)


def test_the_forces_tab_opened_by_a_click_builds_its_plots_one_step_at_a_time(qtbot, window):
    """A click gets the Forces tab at once and its 12 segment plots follow, one per turn of the event loop, each
    told what the grid was told before it existed; show_tab() (a caller that needs the whole page) gets it whole."""
    window.tabs.setCurrentIndex(tab_index("forces"))
    qtbot.waitUntil(lambda: window.tab_widget("forces") is not None)
    page = window.tab_widget("forces")
    assert page.plots.plots_pending > 0 and not window.tab_is_complete("forces")
    qtbot.waitUntil(lambda: window.tab_is_complete("forces"))
    assert page.plots.plots_pending == 0 and len(page.plots.plots) == 12
    legends = [label for plot in page.plots.plots for label in plot.legend.labels()]
    assert legends.count("S06B (µS, uncal.)") == 1 and all("uncal." in label for label in legends)
    assert all(plot.units == "µS" for plot in page.plots.plots)
    calibration = window.show_tab("calibration")
    assert window.tab_is_complete("calibration")  # whole at once: its review views are there
    assert calibration.view_tabs.count() == 5 and calibration.mean_plot is not None


def test_a_tab_asked_for_while_it_says_opening_leaves_no_window_behind(qtbot, settings, monkeypatch):
    """The user clicks a tab whose module is still importing, and show_tab() wants it in the same turn of the event
    loop: the "Opening…" placeholder goes, and never becomes a window of its own (the layout's queued show of a
    just-added widget would show an unparented one as a top-level window over the app's corner)."""
    import sys

    from PySide6.QtCore import QCoreApplication
    from PySide6.QtWidgets import QApplication

    import app.gui.main_window as main_window
    from tests.app import slow_tab_gate

    sys.modules.pop("tests.app.slow_tab", None)
    slow_tab_gate.GATE.clear()
    slow_tab_gate.IMPORTED_ON.clear()
    slow = TabSpec("slow", "Slow", "A tab whose module takes long to import.")
    monkeypatch.setattr(main_window, "TABS", (*TABS, slow))
    monkeypatch.setattr(main_window, "_tab_module",
                        lambda spec: "tests.app.slow_tab" if spec is slow else f"app.gui.tabs.{spec.name}")
    lab = LabContext(NO_PORT_CONFIG)
    win = MainWindow(lab, settings=settings)
    qtbot.addWidget(win)
    win.show()
    try:
        qtbot.waitUntil(lambda: bool(slow_tab_gate.IMPORTED_ON))
        win.tabs.setCurrentIndex(len(TABS))  # "Opening…" added (its show queued by the layout)
        slow_tab_gate.GATE.set()
        page = win.show_tab("slow")  # same turn: waits for the import, builds, drops "Opening…"
        QCoreApplication.sendPostedEvents()  # the queued show runs now
        assert page.text() == "the slow tab"
        strays = [w for w in QApplication.topLevelWidgets() if isinstance(w, PlaceholderPage) and w.isVisible()]
        assert strays == []
    finally:
        slow_tab_gate.GATE.set()
        win.close()
        sys.modules.pop("tests.app.slow_tab", None)
