"""Inside a subprocess on a real X display (QT_QPA_PLATFORM=xcb): the Trials dock run as an operator runs it, its
prompt, buttons and table read back from the widgets and from the X server's pixels. Prints one JSON line.

    DISPLAY=:N QT_QPA_PLATFORM=xcb python -m tests.realdisplay.trials_probe crash|resume FOLDER

- ``crash``: a 3-trial series on the simulated lab — trial 1 marked traversed, Esc during trial 2 (kept, marked
  aborted), trial 3 started — then, while trial 3 records, the JSON line and this process killed (SIGKILL): what a
  crash leaves in FOLDER.
- ``resume``: the same folder resumed in a new app: trial 3 set aside and run again, marked failed, the series
  complete.

GUI thread only.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from PySide6.QtCore import QPoint, Qt, QTimer
from PySide6.QtGui import QColor, QImage
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication, QWidget

from tests.realdisplay.probe import WAIT_S, _save, fail, grab, open_app, pump, pump_until

TRIAL_WAIT_S = 40.0


def click(button: QWidget) -> None:
    """A real mouse press and release on ``button`` (through Qt's event queue, as the X server's would come)."""
    if not button.isEnabled():
        fail(f"{button.text()!r} is disabled")  # type: ignore[attr-defined]
    QTest.mouseClick(button, Qt.MouseButton.LeftButton)
    pump(50)


def colours(image: QImage) -> set[str]:
    """The colours of an image's pixels (every 3rd pixel; hex)."""
    seen = set()
    for y in range(0, image.height(), 3):
        for x in range(0, image.width(), 3):
            seen.add(QColor(image.pixel(x, y)).name().upper())
    return seen


def cell_image(table: Any, row: int, column: int) -> QImage:
    rect = table.visualItemRect(table.item(row, column))
    viewport = table.viewport()
    top_left = viewport.mapToGlobal(rect.topLeft())
    from PySide6.QtGui import QGuiApplication

    return QGuiApplication.primaryScreen().grabWindow(0, top_left.x() + 2, top_left.y() + 2, rect.width() - 4,
                                                      rect.height() - 4).toImage()


def prompt_on_x(panel: Any, timeout_s: float = 10.0) -> QImage:
    """The prompt as the X server shows it, once it shows the background the prompt's style asks for: on a busy
    machine the server's pixels lag the widget (the phase changed, the new colour not yet drawn). After
    ``timeout_s`` as it is (the test then names the colours seen)."""
    label = panel.prompt_label
    wanted = re.search(r"background: (#[0-9A-Fa-f]{6})", label.styleSheet())
    deadline = time.monotonic() + timeout_s
    image = grab(label)
    while wanted and wanted.group(1).upper() not in colours(image) and time.monotonic() < deadline:
        pump(20)
        image = grab(label)
    return image


def seen_on_x(panel: Any) -> dict:
    """What the panel shows: its prompt and table from the widgets, the prompt's and outcome cells' colours from X."""
    table = panel.table
    rows = [[table.item(r, c).text() if table.item(r, c) else "" for c in range(table.columnCount())]
            for r in range(table.rowCount())]
    outcome_colours = [sorted(colours(cell_image(table, r, 1))) if table.item(r, 1) else [] for r in
                       range(table.rowCount())]
    prompt = prompt_on_x(panel)
    return {"prompt": panel.prompt_label.text(), "detail": panel.detail_label.text(), "rows": rows,
            "prompt_colours": sorted(colours(prompt)), "outcome_colours": outcome_colours,
            "prompt_size": [prompt.width(), prompt.height()],
            "buttons": {"start_trial": [panel.start_trial_button.text(), panel.start_trial_button.isEnabled()],
                        "go_start": panel.go_start_button.isEnabled(),
                        "outcomes": any(b.isEnabled() for b in panel.outcome_buttons.values())}}


def wait_phase(session: Any, phase: str, timeout_s: float = TRIAL_WAIT_S) -> None:
    pump_until(lambda: session.phase == phase, timeout_s, f"the Trials panel's phase {phase!r} (now {session.phase})")


def shape_file(folder: Path) -> Path:
    path = folder / "bump.json"
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": "bump",
                                "axes": ["pitch", "yaw"] * 6, "angles_rad": [0.2] + [0.0] * 11}))
    return path


def open_dock(window: Any) -> tuple[Any, Any]:
    window.trials_action.trigger()
    dock = window.trials_dock
    pump_until(dock.isVisible, WAIT_S, "the Trials dock")
    pump_until(lambda: window.lab.robot.is_connected and window.lab.board.is_connected, WAIT_S,
               "the robot and the board to connect")
    return dock.panel, dock.session


def scenario_crash(window: Any, folder: Path, tmp: Path) -> dict:
    panel, session = open_dock(window)
    session.add_shape_file(shape_file(tmp))
    panel.speed_spin.setValue(0.5)
    panel.trials_spin.setValue(3)
    panel.scene_edit.setText("flat")
    panel.folder_edit.setText(str(folder))
    click(panel.start_series_button)
    result: dict = {}
    wait_phase(session, "waiting")
    pump(300)
    result["first_prompt"] = seen_on_x(panel)
    click(panel.start_trial_button)
    wait_phase(session, "marking")
    result["marking"] = seen_on_x(panel)
    panel.outcome_note.setText("clean pass")
    click(panel.outcome_buttons["traversed"])
    wait_phase(session, "waiting")
    click(panel.start_trial_button)
    recorder = window.lab.recording
    pump_until(lambda: recorder.n_daq_samples > 0 and recorder.elapsed_s > 1.0, WAIT_S, "trial 2's data")
    window.activateWindow()
    pump_until(window.isActiveWindow, WAIT_S, "the window to be active")
    QTest.keyClick(window.focusWidget() or window, Qt.Key.Key_Escape)  # STOP
    wait_phase(session, "ready")
    pump(300)
    result["after_stop"] = seen_on_x(panel)
    _save(grab(window), "trials-after-stop")
    click(panel.go_start_button)
    wait_phase(session, "waiting")
    click(panel.start_trial_button)
    recorder = window.lab.recording
    pump_until(lambda: recorder.n_daq_samples > 0 and recorder.elapsed_s > 1.5, WAIT_S, "trial 3's data")
    result["recording"] = seen_on_x(panel)
    print(json.dumps(result), flush=True)  # noqa: T201 - the result for the test, before the crash
    os.kill(os.getpid(), signal.SIGKILL)
    return result  # never reached


def scenario_resume(window: Any, folder: Path, tmp: Path) -> dict:
    panel, session = open_dock(window)
    if not session.resume(folder):
        fail(f"not resumed: {panel.status_label.text()}")
    pump(300)
    result: dict = {"resumed": seen_on_x(panel)}
    click(panel.go_start_button)
    wait_phase(session, "waiting")
    result["waiting"] = seen_on_x(panel)
    click(panel.start_trial_button)
    wait_phase(session, "marking")
    click(panel.outcome_buttons["failed"])
    wait_phase(session, "complete")
    pump(300)
    result["complete"] = seen_on_x(panel)
    _save(grab(window), "trials-complete")
    return result


SCENARIOS = {"crash": scenario_crash, "resume": scenario_resume}


def main(argv: list[str]) -> int:
    name, folder = argv[0], Path(argv[1])
    if os.environ.get("QT_QPA_PLATFORM") != "xcb":
        fail("run this on an X display with QT_QPA_PLATFORM=xcb")
    app = QApplication.instance() or QApplication([sys.argv[0]])
    QTimer.singleShot(int(1000 * (WAIT_S + 4 * TRIAL_WAIT_S)), lambda: fail("probe timed out"))
    with tempfile.TemporaryDirectory(prefix="sensnake-trials-probe-") as tmp:
        window, _page = open_app(Path(tmp), "gait")
        window.resize(1600, 900)
        window.move(QPoint(0, 0))
        result = SCENARIOS[name](window, folder, Path(tmp))
        print(json.dumps(result), flush=True)  # noqa: T201 - the result for the test
        window.close()
    del app
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
