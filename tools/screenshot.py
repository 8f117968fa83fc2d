"""Open the app on the simulated lab, visit every tab and save docs/screenshots/<tab>.png, read back from an X server.

    python tools/screenshot.py [--out docs/screenshots] [--size 1280x800] [--settle-ms 1500] [--tabs teach gait …]
    python tools/screenshot.py --offscreen …     # Qt's offscreen platform and QWidget.grab() instead (no X)
    python tools/screenshot.py --mocap [--scene flat] --out /tmp/shots   # the motion capture: mocap*.png

By default the pictures are what an X server shows: the tool starts a private Xvfb (unless ``DISPLAY`` is set and
``--xvfb`` is not given), runs the app with Qt's xcb platform and reads the window's pixels back with
``QScreen.grabWindow``. A view that does not repaint on a real display (the Forces plots once did) looks stale here
too; ``QWidget.grab()`` re-renders on request and would hide it.

Waits for the robot to connect (and for live values) before grabbing, so the pictures show a working lab. Each tab
is staged the way a user would use it: Teach captures three keyframes by posing the limp simulated robot and saves
them as a shape; Gait plays that shape follow-the-leader and is grabbed mid-motion (the motion keeps running for the
Forces and Hardware pictures, so they show a moving robot); Forces loads the simulated sensors' own models as its
calibration (without one it shows µS) and shows the last 10 s of live forces while recording; Hardware scans and checks the link. The user's saved window geometry, shape library and recordings are
not touched (settings, shapes and the recording go to a temporary folder).

``--mocap`` pictures the motion capture instead, as ``sensnake gui`` runs it on the physics lab with ``[lab] mocap =
true`` (the lab in its own process, on flat ground unless ``--scene``): the simulated sensors' calibration loaded and
a serpenoid gait playing, ``mocap-picker.png`` is the Forces tab with the **Mocap:** picker's menu open beside Record
(the simulated lab's source ticked), ``mocap.png`` the 3-D tab with the captured markers over the simulated body and
the kinematics panel (the side view, each segment's lateral y against time) filled for a few seconds.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _on_x(argv: list[str]) -> int | None:
    """Re-run this tool on a private Xvfb with Qt's xcb platform; None when already there (or offscreen)."""
    if "--offscreen" in argv:
        os.environ["QT_QPA_PLATFORM"] = "offscreen"
        return None
    if os.environ.get("QT_QPA_PLATFORM") == "xcb" and os.environ.get("DISPLAY") and "--xvfb" not in argv:
        return None
    from tests.realdisplay.xserver import XServer, XUnavailable, probe_env

    try:
        server = XServer.start("1600x1000x24")
    except XUnavailable as exc:
        print(f"screenshot: no X server ({exc}); use --offscreen for QWidget.grab() pictures",  # noqa: T201
              file=sys.stderr)
        return 1
    try:
        args = [a for a in argv if a != "--xvfb"]
        return subprocess.run([sys.executable, __file__, *args], env=probe_env(server.display), cwd=ROOT).returncode
    finally:
        server.stop()


def _grab(window):
    """The window's pixels: from the X server on xcb (what the screen shows), else re-rendered."""
    from PySide6.QtCore import QPoint
    from PySide6.QtGui import QGuiApplication

    if QGuiApplication.platformName() != "xcb":
        return window.grab()
    top_left = window.mapToGlobal(QPoint(0, 0))
    return QGuiApplication.primaryScreen().grabWindow(0, top_left.x(), top_left.y(), window.width(), window.height())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/screenshots", help="folder for the PNGs")
    parser.add_argument("--size", default="1280x800", help="window size WxH in pixels")
    parser.add_argument("--settle-ms", type=int, default=1500, help="time each tab gets to fill in live data")
    parser.add_argument("--tabs", nargs="*", default=None, help="only these tabs (default: all)")
    parser.add_argument("--offscreen", action="store_true", help="no X server: Qt offscreen and QWidget.grab()")
    parser.add_argument("--xvfb", action="store_true", help="start a private Xvfb even when DISPLAY is set")
    parser.add_argument("--physics", action="store_true",
                        help="run on the physics lab ([lab] physics = \"mujoco\"); the 3-D lab tab needs it: "
                             "--physics --tabs scene")
    parser.add_argument("--scene", default=None, metavar="SCENE",
                        help="the physics lab's scene ([lab] scene: a file or a built-in name); the 3-D picture "
                             "is then saved as scene-<name>.png")
    parser.add_argument("--feedback", action="store_true",
                        help="the Gait picture plays with force feedback (the Forces tab gets the simulated "
                             "sensors' calibration first); saved as gait-feedback.png")
    parser.add_argument("--no-calibration", action="store_true",
                        help="Forces as the app opens, with no calibration file: conductance in µS")
    parser.add_argument("--log", action="store_true",
                        help="after the tabs, the Event log dock open at a fault (a reboot asked of a servo that is "
                             "not on the bus): event-log.png")
    parser.add_argument("--mocap", action="store_true",
                        help="the motion capture ([lab] mocap = true on the physics lab, a serpenoid playing): the "
                             "Forces tab's Mocap picker open (mocap-picker.png) and the 3-D tab with the markers and "
                             "the kinematics panel (mocap.png); only these, unless --tabs")
    parser.add_argument("--plots", action="store_true",
                        help="after the tabs, the Plots dock (View > Plots) with joint 5's goal, present angle and "
                             "current and S06B's force on linked time axes while joint 5 swings: plots-dock.png "
                             "(with --size 1600x800: the dock beside the whole Forces tab)")
    parser.add_argument("--replay", default=None, metavar="REC.h5",
                        help="the 3-D tab replaying this recording, scrubbed to its middle: scene-replay.png")
    args = parser.parse_args(argv)
    if args.mocap:  # the pictures' streams stay on this machine unless LSLAPICFG says otherwise
        from app.core.lsl_link import keep_lsl_on_this_machine

        keep_lsl_on_this_machine("sensnake-screenshot-lsl-")
    code = _on_x(sys.argv[1:] if argv is None else list(argv))
    if code is not None:
        return code
    width, height = (int(v) for v in args.size.lower().split("x"))

    from PySide6.QtCore import QCoreApplication, QEventLoop, QSettings
    from PySide6.QtWidgets import QApplication

    from app.gui.lab import LabContext
    from app.gui.main_window import TABS, MainWindow
    from devices.config import SIM_PORT, load_config

    app = QApplication.instance() or QApplication(sys.argv[:1])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sensnake-demo-") as tmp:
        os.environ["XDG_DATA_HOME"] = str(Path(tmp) / "data")  # the shape library the Teach picture saves into
        os.environ["SENSNAKE_RECORDINGS_DIR"] = str(Path(tmp) / "recordings")  # the Forces picture records
        settings = QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat)
        config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
        from dataclasses import replace

        # The README's pictures are of the scripted lab, posed by hand; --physics for the 3-D lab's picture.
        if args.mocap:  # the physics lab filming its robot; on flat ground a serpenoid keeps its LEDs up
            args.physics = True
            config = replace(config, lab=replace(config.lab, mocap="sim", scene=args.scene or "flat"))
        config = replace(config, lab=replace(config.lab, physics="mujoco" if args.physics else "scripted",
                                             scene=args.scene or config.lab.scene))
        lab = LabContext(config, lab_process=args.mocap)  # as sensnake gui: the lab and its cameras' stream apart
        window = MainWindow(lab, settings=settings)
        window.resize(width, height)
        window.move(0, 0)
        window.show()
        lab.connect_all()

        def pump(ms: int, until=None) -> None:
            deadline = time.monotonic() + ms / 1000.0
            while time.monotonic() < deadline:
                QCoreApplication.processEvents(QEventLoop.ProcessEventsFlag.AllEvents, 50)
                if until is not None and until():
                    return
                time.sleep(0.01)  # a script, not a test: idle between event batches

        pump(150_000 if args.mocap else 10_000,  # the lab's own process builds its world first
             until=lambda: lab.robot.is_connected or "could not" in window.status.message)
        if not args.physics:
            _pose_by_hand(config)  # (the physics lab's limp robot drapes over the obstacle by itself)
        names = args.tabs or ([] if args.mocap else [spec.name for spec in TABS])
        if args.mocap and not _take_mocap(window, lab, out, pump, Path(tmp), args.settle_ms):
            return 1
        if args.feedback:  # the feedback controller needs forces: the Forces tab estimates them from the start
            _load_simulated_sensors_calibration(window.show_tab("forces"), Path(tmp))
            from app.core.shapes import Shape, ShapeLibrary

            wrap = [0.0] * len(config.robot.axes)
            for joint in (2, 4, 6, 8):
                wrap[joint] = -0.3  # the obstacle's drape, roughly: what the feedback picture plays
            ShapeLibrary().save(Shape(FEEDBACK_SHAPE, tuple(config.robot.axes), tuple(wrap)))
        for name in names:
            if name == "scene" and not args.physics:
                print("skipped scene: the 3-D lab shows the physics lab; run with --physics --tabs scene")  # noqa: T201
                continue
            page: Any = window.show_tab(name)  # each tab page has its own widgets, reached by name below
            if name == "scene":
                pump(20_000, until=lambda p=page: p.view.frames_shown > 5 or bool(p.render_error))
                pump(7_000)  # torque is off at start: the limp robot settles over the obstacle
            if name == "teach":
                _stage_teach(page, pump)
            if name == "gait":
                _stage_gait(page, pump, feedback=args.feedback)
            if name == "forces":
                if not args.no_calibration:
                    _load_simulated_sensors_calibration(page, Path(tmp))
                page.controls.window_combo.setCurrentIndex(page.controls.window_combo.findText("10 s"))
                pump(4_000)
                page.controls.record.click()  # recording while the robot moves: REC in the status bar
                pump(6_000)  # the tab keeps what arrives after it opens: fill the 10 s window
            if name == "hardware":
                # A scan holds the bus, so it is refused while a motion plays: end the gait first (the picture
                # shows the scan list, as a user who scans would see it).
                if lab.robot.motion_state in ("running", "paused"):
                    lab.robot.stop_motion()
                    pump(5_000, until=lambda: lab.robot.motion_state not in ("running", "paused"))
                page.panel.scan_id_to.setValue(20)
                page.panel.scan_button.click()
                pump(20_000, until=lambda p=page: p.panel.scan_button.isEnabled())
                page.panel.link_check_button.click()
                pump(20_000, until=lambda p=page: p.panel.link_check_button.isEnabled())
            if name == "calibration" and hasattr(page, "add_trial_files"):
                _load_demo_trials(page, Path(tmp))
                pump(60_000, until=lambda p=page: p.result is not None or not p.is_fitting)
                if hasattr(page, "source_tabs"):
                    page.source_tabs.setCurrentWidget(page.protocol_form)  # the rig panel beside the fit
            pump(args.settle_ms)
            path = out / (f"scene-{Path(args.scene).stem}.png" if name == "scene" and args.scene
                          else "gait-feedback.png" if name == "gait" and args.feedback else f"{name}.png")
            window.raise_()
            pump(200)  # the X server has the last frame
            if not _grab(window).save(str(path)):
                print(f"screenshot: cannot write {path}", file=sys.stderr)  # noqa: T201
                return 1
            print(f"saved {path}")  # noqa: T201 - a command-line script reports what it wrote
            if out.resolve() == SCREENSHOTS.resolve():
                record_sources(path.name)
            if name == "hardware":
                for extra in _hardware_extras(window, page, lab, out, pump):
                    print(f"saved {extra}")  # noqa: T201
                    if out.resolve() == SCREENSHOTS.resolve():
                        record_sources(extra.name)
        if args.replay:
            import numpy as np

            page = window.show_tab("scene")
            if not page.open_replay(args.replay):
                print(f"screenshot: {page.scene_label.text()}", file=sys.stderr)  # noqa: T201
                return 1
            replay = page.replay
            page.replay_view.set_speed(0.5)
            busiest = replay.start_s
            if replay.forces_n is not None and replay.force_time_s is not None:  # where the body presses most
                busiest = float(replay.force_time_s[int(np.nanargmax(np.nansum(replay.forces_n, axis=1)))])
            page.replay_view.slider.setValue(int((busiest - replay.start_s) * 1000))
            page.replay_view.set_camera(-60.0, 30.0)
            pump(args.settle_ms)
            saved = _save(window, out / "scene-replay.png", pump)
            if saved is None:
                return 1
        if args.plots and not _take_plots(window, lab, out, pump, args.settle_ms):
            return 1
        if args.log:
            lab.robot.reboot(99)  # no servo 99 on the bus: a real fault, with its whole text
            pump(5_000, until=lambda: window.event_log.count("fault") > 0)
            window.show_log()
            # the entries in view, the tab above it keeping the height its layout needs (a forced taller dock
            # squeezes the tab below its minimum and its widgets overlap)
            window.log_dock.setMinimumHeight(300)
            pump(300)
            pump(args.settle_ms)
            if _save(window, out / "event-log.png", pump) is None:
                return 1
        window.close()
        app.processEvents()
    return 0


class _SwingJoint5:
    """A motion source: joint 5 swings ±0.25 rad at 0.5 Hz from where the body is (its current and the forces
    under it change with it)."""

    def __init__(self) -> None:
        self.start: Any = None

    def goal_at(self, t_s: float, present_rad: Any) -> Any:
        import math

        if self.start is None:
            self.start = present_rad.copy()
        goal = self.start.copy()
        goal[4] += 0.25 * math.sin(2 * math.pi * 0.5 * t_s)
        return goal


def _take_plots(window: Any, lab: Any, out: Path, pump: Any, settle_ms: int) -> bool:
    """The Plots dock as a user fills it from its series tree while joint 5 swings: its goal and present angle on one
    plot, its current on a second, S06B's force (the simulated sensors' calibration loaded) on a third, linked in
    time."""
    from PySide6.QtCore import Qt

    from widgets.plots_view import NEW_PLOT

    forces = window.show_tab("forces")
    _load_simulated_sensors_calibration(forces, out)
    robot = lab.robot
    if robot.motion_state in ("running", "paused"):
        robot.stop_motion()
        pump(5_000, until=lambda: robot.motion_state not in ("running", "paused"))
    robot.set_torque(True).result(timeout=30)
    robot.run_motion(_SwingJoint5(), "swing joint 5")
    window.plots_action.trigger()  # View > Plots
    dock = window.plots_dock
    pump(10_000, until=lambda: dock.isVisible() and dock.subscribed)
    dock.add_series(["robot/J5/goal_rad", "robot/J5/present_rad"], NEW_PLOT)  # several keys: one plot
    dock.add_series(["robot/J5/current_mA"], NEW_PLOT)
    dock.add_series(["forces/S06B/force_N"], NEW_PLOT)
    # As wide as the Forces tab beside it lets it be (a user drags the splitter; a forced minimum width would squeeze
    # the tab's toolbar over itself): take this picture with a wide window, e.g. --size 1600x800.
    window.resizeDocks([dock], [int(0.5 * window.width())], Qt.Orientation.Horizontal)
    pump(max(settle_ms, 8_000))  # a few swings of every series on screen
    return _save(window, out / "plots-dock.png", pump) is not None


def _take_mocap(window: Any, lab: Any, out: Path, pump: Any, folder: Path, settle_ms: int) -> bool:
    """mocap-picker.png and mocap.png (see the module docstring); False, and why on stderr, when they cannot be."""
    link = lab.mocap
    pump(150_000, until=lambda: link.inlet is not None or "not following" in link.status)
    if link.inlet is None:
        print(f"screenshot: no motion capture: {link.status}", file=sys.stderr)  # noqa: T201
        return False
    pump(150_000, until=lambda: lab.robot.is_connected and lab.robot.latest_state is not None)
    if not lab.robot.is_connected:
        print(f"screenshot: the robot did not connect: {lab.robot.connection_text}", file=sys.stderr)  # noqa: T201
        return False
    forces: Any = window.show_tab("forces")
    _load_simulated_sensors_calibration(forces, folder)
    gait: Any = window.show_tab("gait")
    gait.panel.set_mode("serpenoid")
    gait.panel.repeat_spin.setValue(1000)  # plays on through both pictures
    pump(10_000, until=gait.panel.play_button.isEnabled)
    gait.panel.play_button.click()
    pump(10_000, until=lambda: lab.robot.motion_state == "running")

    forces = window.show_tab("forces")
    forces.controls.window_combo.setCurrentIndex(forces.controls.window_combo.findText("10 s"))
    pump(max(settle_ms, 4_000))  # the plots fill with the moving robot's forces, the picker counts samples
    picker = forces.mocap_picker
    if picker is None:
        print("screenshot: the Forces tab has no Mocap picker", file=sys.stderr)  # noqa: T201
        return False
    window.raise_()  # first: raised after, the window would cover the menu
    pump(200)
    picker.menu_.popup(picker.mapToGlobal(picker.rect().bottomLeft()))  # as a click on it opens it
    pump(600)
    saved = _save(window, out / "mocap-picker.png", pump, raise_window=False)
    picker.menu_.hide()
    if saved is None:
        return False

    scene: Any = window.show_tab("scene")
    scene.kinematics.coordinate_combo.setCurrentIndex(1)  # lateral y: what a serpenoid on flat ground moves most
    pump(60_000, until=lambda: scene.view.frames_shown > 2 or bool(scene.render_error))
    pump(30_000, until=lambda: scene.kinematics.frames_drawn > 5)
    pump(max(settle_ms, 6_000))  # the positions against time fill a few seconds
    if scene.render_error:
        print(f"screenshot: the 3-D picture: {scene.render_error}", file=sys.stderr)  # noqa: T201
        return False
    saved = _save(window, out / "mocap.png", pump)
    lab.robot.stop_motion()
    return saved is not None


def _save(window: Any, path: Path, pump: Any, raise_window: bool = True) -> Path | None:
    """Grab ``window`` into ``path`` and note its sources (the README's pictures); None if it cannot be written.
    ``raise_window=False``: as it is stacked (a menu open over it stays on top)."""
    if raise_window:
        window.raise_()
    pump(200)  # the X server has the last frame
    if not _grab(window).save(str(path)):
        print(f"screenshot: cannot write {path}", file=sys.stderr)  # noqa: T201
        return None
    print(f"saved {path}")  # noqa: T201 - a command-line script reports what it wrote
    if path.parent.resolve() == SCREENSHOTS.resolve():
        record_sources(path.name)
    return path


SCREENSHOTS = ROOT / "docs" / "screenshots"


def _hardware_extras(window: Any, page: Any, lab: Any, out: Path, pump: Any) -> list[Path]:
    """The Servo settings page after the lab's [servos] profile was applied (the changes it made beside the table),
    and the Set zero pose dialog over the window."""
    from widgets.zero_pose_dialog import ZeroPoseDialog

    saved = []
    robot = lab.robot
    robot.servo_profile = (("Position P Gain", 640), ("Profile Acceleration", 20), ("Return Delay Time", 0))
    robot.last_profile_changes = []
    robot.apply_profile()
    page.pages.setCurrentWidget(page.settings)
    pump(20_000, until=lambda: bool(robot.last_profile_changes))
    page.settings.servo_combo.setCurrentIndex(3)
    page.settings.live_check.setChecked(True)
    pump(2_000)
    page.settings.table.scrollToItem(page.settings.table.item(40, 0))
    page.settings.table.selectRow(next(k for k, row in enumerate(page.settings.rows) if row.name == "Position P Gain"))
    pump(1_000)
    path = out / "hardware-settings.png"
    window.raise_()
    pump(200)
    if _grab(window).save(str(path)):
        saved.append(path)
    # The control table decoded (Wizard's view): names, units, and the Shutdown item's named bits in the item panel.
    page.settings.table.scrollToTop()
    page.settings.select_item("Shutdown")
    pump(1_000)
    path = out / "hardware-control-table.png"
    window.raise_()
    pump(200)
    if _grab(window).save(str(path)):
        saved.append(path)
    page.settings.live_check.setChecked(False)
    state = robot.latest_state
    config = robot.config
    present = [float(a) for a in state.position_rad] if state is not None else [0.0] * config.n_joints
    from app.core.servo_settings import zero_offsets

    dialog = ZeroPoseDialog(config.joint_ids, config.axes, present, list(config.zero_offsets_rad),
                            zero_offsets(config.zero_offsets_rad, present), "my_lab.toml", window)
    dialog.show()
    dialog.adjustSize()
    pump(1_000)
    dialog.raise_()
    pump(200)
    path = out / "zero-pose.png"
    if _grab(dialog).save(str(path)):
        saved.append(path)
    dialog.close()
    page.pages.setCurrentWidget(page.panel)
    return saved


def sources_hash(files: list[str]) -> str:
    """A hash of the contents of ``files`` (repository paths): what a picture of them was taken from."""
    import hashlib

    digest = hashlib.sha256()
    for name in files:
        digest.update(name.encode())
        digest.update((ROOT / name).read_bytes())
    return digest.hexdigest()[:16]


def record_sources(picture: str) -> None:
    """Note in docs/screenshots/manifest.json the hash of the code ``picture`` was just taken from (pictures not
    listed in sources.json are not tracked)."""
    import json

    sources = json.loads((SCREENSHOTS / "sources.json").read_text(encoding="utf-8"))["pictures"]
    if picture not in sources:
        return
    manifest_path = SCREENSHOTS / "manifest.json"
    manifest = json.loads(manifest_path.read_text(encoding="utf-8")) if manifest_path.exists() else {}
    manifest[picture] = sources_hash(sources[picture])
    manifest_path.write_text(json.dumps(dict(sorted(manifest.items())), indent=1) + "\n", encoding="utf-8")


def _pose_by_hand(config) -> None:
    """Bend the simulated robot (torque is off at start) into a gentle curve, so the views show a shape."""
    import math

    from devices.factory import sim_lab

    chain = sim_lab().chain
    for index, servo_id in enumerate(config.robot.joint_ids):
        angle_rad = 0.35 * math.sin(2 * math.pi * index / len(config.robot.joint_ids))
        try:
            chain.set_limp_position(servo_id, 2048 + angle_rad * 4096 / (2 * math.pi))
        except ValueError:
            return  # torque is on: leave the robot as it is


DEMO_SHAPE = "conform-obstacle"


def _demo_poses(n_joints: int) -> list[list[float]]:
    """Three poses (rad) a person might teach: an S-curve, the head lifted over an obstacle, a C-curve."""
    import math

    s_curve = [0.35 * math.sin(2 * math.pi * j / n_joints) for j in range(n_joints)]
    lift = [(-0.45 if j in (0, 2) else 0.2 if j == 4 else 0.0) + (0.25 if j % 2 else 0.0) for j in range(n_joints)]
    c_curve = [0.28 if j % 2 else 0.0 for j in range(n_joints)]
    return [s_curve, lift, c_curve]


def _stage_teach(page, pump) -> None:
    """Torque off, pose the limp robot three times (as dragging the drawing does), capture, rename, save."""
    import numpy as np

    panel = page.panel
    panel.torque_off_all_button.click()
    pump(5_000, until=lambda: all(page.limp))
    for k, pose in enumerate(_demo_poses(len(page.limp))):
        for joint, angle_rad in enumerate(pose):
            page.pose_joint(joint, angle_rad)
        pump(5_000, until=lambda pose=pose: page.robot.latest_state is not None and np.allclose(
            page.robot.latest_state.position_rad, pose, atol=0.01))
        panel.capture_button.click()
        pump(5_000, until=lambda k=k: len(page.keyframes) == k + 1)
    page.rename_keyframe(1, "lift head")
    panel.name_edit.setText(DEMO_SHAPE)
    panel.save_button.click()
    panel.keyframe_table.selectRow(0)  # the dashed overlay: keyframe 1 against the present pose
    pump(300)


FEEDBACK_SHAPE = "obstacle-wrap"


def _stage_gait(page, pump, feedback: bool = False) -> None:
    """Play the taught shape follow-the-leader at 0.1 rad/s (with force feedback if asked) and wait until it is well
    under way."""
    panel = page.panel
    panel.set_mode("follow")
    if feedback:
        panel.controller_combo.setCurrentIndex(panel.controller_combo.findData("feedback"))
        page.refresh_shapes()
    index = panel.shape_combo.findText(FEEDBACK_SHAPE if feedback else DEMO_SHAPE)
    if index < 0:
        return  # the Teach picture was not taken: nothing to play
    panel.shape_combo.setCurrentIndex(index)
    panel.speed_spin.setValue(0.1)
    panel.play_button.click()
    pump(20_000, until=lambda: page.source is not None and page.source.progress.fraction > 0.3)


def _load_simulated_sensors_calibration(page: Any, folder: Path) -> None:
    """Without a calibration file the Forces tab shows conductance (µS), never forces. For the picture it does what a
    user does on the simulated lab: Simulated truth (every simulated sensor's true calibration), so it shows newtons.
    ``folder`` is unused: the file goes to the (temporary) data folder's calibrations, as the button puts it."""
    del folder
    if not page.load_simulated_truth():
        raise SystemExit(f"screenshot: the simulated sensors' calibration did not load: {page.controls.message.text()}")
    from PySide6.QtCore import QCoreApplication

    while page.is_loading_calibration:  # the history is estimated again on a worker thread first
        QCoreApplication.processEvents()
        time.sleep(0.01)  # a script, not a test


def _load_demo_trials(page, folder: Path) -> None:
    """Synthetic trials (the paper's forces, one repeat, 0.2 % noise) written as CSVs, loaded and fitted."""
    from app.core import calfiles
    from models.physics import PhysicsConstants
    from models.synthetic import TYPICAL_TRUTH, paper_protocol

    paths = []
    for trial in paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=7, repeats=1, noise_rel=0.002):
        path = folder / f"{trial.name}.csv"
        calfiles.write_trial_csv(path, trial.time_s, trial.force_n, trial.conductance_s)
        paths.append(path)
    page.add_trial_files(paths)
    page.start_fit()


if __name__ == "__main__":
    sys.exit(main())
