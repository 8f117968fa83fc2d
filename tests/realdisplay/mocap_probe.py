"""Inside a subprocess on a real X display: the app as ``sensnake gui`` opens it on the physics lab with ``[lab] mocap
= true`` (the lab and the control loop in their own processes) on flat ground, a serpenoid gait playing, a recording of SECONDS
made from the Forces tab while the 3-D tab shows the motion capture. Prints one JSON line: what the widgets and the
X server's pixels showed, what the recording holds, and the control loop's ticks while it recorded.

    LSLAPICFG=loopback.cfg DISPLAY=:N QT_QPA_PLATFORM=xcb python -m tests.realdisplay.mocap_probe [SECONDS [off]]

``off``: the same without motion capture (``[lab] mocap`` unset), the benchmark's baseline.

Used by ``tests/realdisplay/test_mocap_view.py`` (a few seconds) and ``benchmarks/bench_mocap_gui.py`` (60 s).
GUI thread only.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from PySide6.QtCore import QCoreApplication, QSettings, QTimer
from PySide6.QtGui import QImage
from PySide6.QtWidgets import QApplication

from tests.realdisplay.probe import WINDOW_SIZE, PaintCounter, fail, grab, measure, pump, pump_until

MOCAP_RGB = (0x00, 0x72, 0xB2)  # widgets.kinematics_view.MOCAP_COLOR
COLOUR_TOLERANCE = 40
LOADED_WAIT_S = 150.0  # the lab's process builds its world and the loop's process starts: slow on a loaded machine


def mocap_pixels(image: QImage) -> int:
    """How many pixels are near the motion capture's blue (the markers drawn into the 3-D picture, the body in the
    side view)."""
    rgb = image.convertToFormat(QImage.Format.Format_RGB888)
    width, height, stride = rgb.width(), rgb.height(), rgb.bytesPerLine()
    pixels = np.frombuffer(rgb.constBits(), np.uint8, count=stride * height).reshape(height, stride)
    pixels = pixels[:, : 3 * width].reshape(height, width, 3).astype(int)
    near = np.abs(pixels - np.array(MOCAP_RGB)).max(axis=-1) <= COLOUR_TOLERANCE
    return int(near.sum())


def _save(image: QImage, name: str) -> str:
    folder = os.environ.get("PROBE_PICTURES")
    if not folder:
        return ""
    path = Path(folder) / f"{name}.png"
    image.save(str(path))
    return str(path)


def run(seconds: float, tmp: Path, with_mocap: bool = True) -> dict:
    os.environ["XDG_DATA_HOME"] = str(tmp / "data")
    os.environ["SENSNAKE_DATA_DIR"] = str(tmp / "data")
    os.environ["SENSNAKE_RECORDINGS_DIR"] = str(tmp / "recordings")
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from app.gui.robot_bridge import MOTION_RUNNING
    from devices.config import SIM_PORT, load_config

    config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    # Flat ground: a serpenoid gait keeps the robot upright there (over the paper's obstacle it rolls onto its back,
    # its LEDs face the floor and no camera sees them, as a real motion capture would not).
    config = replace(config, lab=replace(config.lab, physics="mujoco", mocap="sim" if with_mocap else "",
                                         scene="flat"))
    lab = LabContext(config, lab_process=True)
    window = MainWindow(lab, settings=QSettings(str(tmp / "settings.ini"), QSettings.Format.IniFormat))
    window.resize(*WINDOW_SIZE)
    window.move(0, 0)
    forces = window.show_tab("forces")
    window.show()
    window.raise_()
    pump_until(lambda: window.windowHandle() is not None and window.windowHandle().isExposed(), what="the window")
    lab.connect_all()
    result: dict = {"seconds": seconds, "lab_where": lab.lab_where, "with_mocap": with_mocap}
    if with_mocap:
        pump_until(lambda: lab.mocap.inlet is not None or "not following" in lab.mocap.status, timeout_s=LOADED_WAIT_S,
                   what="the simulated motion capture's stream")
        if lab.mocap.inlet is None:
            fail(f"no motion capture: {lab.mocap.status}")
    result["picker"] = forces.mocap_picker.text() if forces.mocap_picker is not None else None
    result["mocap_status"] = lab.mocap.status
    deadline = time.monotonic() + LOADED_WAIT_S
    while not (lab.robot.is_connected and lab.robot.latest_state is not None):
        if time.monotonic() > deadline:
            fail(f"the robot did not connect within {LOADED_WAIT_S:g} s: {lab.robot.connection_text}")
        pump(50)
    gait = window.show_tab("gait")
    panel = gait.panel
    panel.set_mode("serpenoid")
    panel.repeat_spin.setValue(1000)
    pump_until(panel.play_button.isEnabled, what="Play to be enabled")
    panel.play_button.click()
    pump_until(lambda: lab.robot.motion_state == MOTION_RUNNING, what="the gait to start")
    window.show_tab("forces")
    pump(1000)
    recorded = tmp / "recordings" / "mocap-gait.h5"
    stopped: list[str] = []
    at_stop: list = []  # the loop's counters the moment the timed recording stops (before /mocap is written)
    forces._auto_stop_timer.timeout.connect(lambda: at_stop.append(lab.robot.loop_stats()))
    before = lab.robot.loop_stats()
    session = forces.start_recording(recorded, duration_s=seconds)
    if session is None:
        fail("the recording did not start")
    session.stopped.connect(stopped.append)
    started = time.monotonic()
    scene = window.show_tab("scene")
    scene.kinematics.coordinate_combo.setCurrentIndex(1)  # lateral y: what a serpenoid on flat ground moves most
    pump_until(lambda: scene.view.frames_shown > 2 or bool(scene.render_error), what="the 3-D picture")
    if with_mocap:
        pump_until(lambda: scene.kinematics.frames_drawn > 5, what="the kinematics panel")
    pump(1500)  # the kinematics plot fills
    views = {"scene": scene.view.picture, "kinematics_body": scene.kinematics.body_plot,
             "kinematics_time": scene.kinematics.time_plot}
    shown = measure(views, PaintCounter(), min(2.0, 0.3 * seconds))
    result["views"] = shown["views"]
    result["render_error"] = scene.render_error
    pictures = {name: grab(widget) for name, widget in views.items()}
    result["mocap_pixels"] = {name: mocap_pixels(image) for name, image in pictures.items()}
    result["pictures"] = {name: _save(image, f"mocap-{name}") for name, image in pictures.items()}
    result["window_picture"] = _save(grab(window), "mocap-window")
    snapshot = lab.mocap.live_snapshot()
    result["live_poses"] = 0 if snapshot is None else len(snapshot.time_s)
    result["kinematics_window_s"] = (0.0 if snapshot is None else
                                     float(snapshot.time_s[-1] - snapshot.time_s[0]))
    pump_until(lambda: bool(at_stop) and not session.is_active, timeout_s=seconds + 60.0,
               what="the recording to stop")
    result["recorded_for_s"] = time.monotonic() - started
    pump_until(lambda: bool(stopped), timeout_s=120.0, what="/mocap to be written")
    result["written_after_s"] = time.monotonic() - started
    after = lab.robot.loop_stats()
    result["stopped"] = stopped[0]
    stop = at_stop[0]
    if before is not None and stop is not None and after is not None:
        result["ticks"] = stop.ticks - before.ticks  # while recording, the stream arriving
        result["missed_ticks"] = stop.missed_ticks - before.missed_ticks
        result["late_ticks"] = stop.late_ticks - before.late_ticks
        result["ticks_writing"] = after.ticks - stop.ticks  # while /mocap was written
        result["missed_ticks_writing"] = after.missed_ticks - stop.missed_ticks
        result["period_p99_ms"] = 1000 * after.period_p99_s
    inlet = lab.mocap.inlet
    result["stream_dropouts"] = inlet.dropouts if inlet is not None else None
    result["load_average"] = os.getloadavg()[0]
    import h5py

    with h5py.File(recorded, "r") as f:
        result["has_mocap"] = "mocap" in f
        if "mocap" in f:
            group = f["mocap"]
            t = group["time_s"][:]
            centers = group["segment_center_m"][:]
            result["mocap_samples"] = int(len(t))
            result["mocap_span_s"] = [float(t[0]), float(t[-1])] if len(t) else None
            result["mocap_rate_hz"] = float(group.attrs["rate_hz"])
            result["posed_fraction"] = float(np.isfinite(centers[..., 0]).mean()) if len(t) else 0.0
            result["clock_offset_how"] = str(group.attrs["clock_offset_how"])
            steps = np.diff(t)
            result["max_gap_s"] = float(steps.max()) if steps.size else None
        result["daq_span_s"] = [float(f["daq/time_s"][0]), float(f["daq/time_s"][-1])]
    lab.robot.stop_motion()
    pump(500)
    window.close()
    QCoreApplication.processEvents()  # one turn for the close's deferred deletes before the probe exits
    return result


def main(argv: list[str]) -> int:
    seconds = float(argv[0]) if argv else 6.0
    with_mocap = not (len(argv) > 1 and argv[1] == "off")
    if os.environ.get("QT_QPA_PLATFORM") != "xcb":
        fail("run this on an X display with QT_QPA_PLATFORM=xcb")
    app = QApplication.instance() or QApplication([sys.argv[0]])
    QTimer.singleShot(int(1000 * (seconds * 2 + 400)), lambda: fail("probe timed out"))
    with tempfile.TemporaryDirectory(prefix="sensnake-mocap-probe-") as tmp:
        result = run(seconds, Path(tmp), with_mocap)
        print(json.dumps(result), flush=True)  # noqa: T201 - the result for the test or the benchmark
    del app
    os._exit(0)  # device threads were closed with the window; skip Qt's teardown at exit


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
