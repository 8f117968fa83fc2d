"""The README's calibration walk-through pictures, taken from a real display: the app on the simulated lab (its clock
15× real time), the Calibration tab running a short protocol on the simulated rig, then its review views.

    python tools/calibration_walkthrough.py [--out docs/screenshots] [--size 1400x900] [--speed 15]

Starts a private Xvfb (``tools/screenshot.py``'s), runs the app with Qt's xcb platform and reads the window's pixels
back with ``QScreen.grabWindow``. Walks the tab's wizard and writes calibration_0_setup.png (the sensor on the body
drawing, the readout), calibration_0_check.png (the rig check, every line passed), calibration_0_contact.png (the contact
found, the conditioning fields), calibration_1_protocol.png (form,
live trace mid-trial and the fit of the trials before it), calibration_2_fit.png (conductance vs time with the SLS fit, Fig. 8B),
calibration_3_means.png (Fig. 9ii), calibration_4_params.png (Fig. 9iii) and calibration_5_history.png (after Save).
Nothing of the user's is touched (settings and calibrations go to a temporary folder).

Exits 1 naming the reason when a step does not happen (the rig check fails, the run ends without trials, the fit is
refused or not fit to use) instead of waiting for it until its time limit. On a busy machine the fit of the trials so
far (a background fit at a lower CPU priority, so that it never takes the cores the lab needs) can take longer than a
trial: the protocol picture then waits for it into a later trial, and is taken without it (said on stdout) only if
none comes before the last trial.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))


def _on_x(argv: list[str]) -> int | None:
    """Re-run this tool on a private Xvfb with Qt's xcb platform; None when already there."""
    import subprocess

    if os.environ.get("QT_QPA_PLATFORM") == "xcb" and os.environ.get("DISPLAY"):
        return None
    from tests.realdisplay.xserver import XServer, XUnavailable, probe_env

    try:
        server = XServer.start("1600x1000x24")
    except XUnavailable as exc:
        print(f"calibration_walkthrough: no X server ({exc})", file=sys.stderr)  # noqa: T201
        return 1
    try:
        return subprocess.run([sys.executable, __file__, *argv], env=probe_env(server.display), cwd=ROOT).returncode
    finally:
        server.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/screenshots")
    parser.add_argument("--size", default="1400x900")
    parser.add_argument("--speed", type=float, default=15.0, help="the simulated lab's clock × real time")
    args = parser.parse_args(argv)
    from screenshot import _grab

    code = _on_x(sys.argv[1:] if argv is None else list(argv))
    if code is not None:
        return code
    width, height = (int(v) for v in args.size.lower().split("x"))

    from PySide6.QtCore import QCoreApplication, QEventLoop, QSettings
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication(sys.argv[:1])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sensnake-cal-") as tmp:
        os.environ["XDG_DATA_HOME"] = str(Path(tmp) / "data")
        from app.core import user_folders
        from app.gui.lab import LabContext
        from app.gui.main_window import MainWindow
        from devices import factory
        from devices.config import SIM_PORT, load_config

        config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
        from dataclasses import replace

        # The scripted lab, as tools/screenshot.py's pictures: the physics lab is not meant to run at 15×.
        config = replace(config, lab=replace(config.lab, physics="scripted"))
        # The lab in this process (its devices answer in the caller's thread, at 15× on a busy machine too; in a
        # process of its own the rig's servo answered late under load: "no reply from servo 1").
        factory.start_sim_lab(config, speed=args.speed)
        settings = QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat)
        lab = LabContext(config)
        window = MainWindow(lab, settings=settings)
        window.resize(width, height)
        window.move(0, 0)
        window.show()

        def pump(seconds: float, until=None) -> None:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                QCoreApplication.processEvents(QEventLoop.ProcessEventsFlag.AllEvents, 50)
                if until is not None and until():
                    return
                time.sleep(0.01)  # a script, not a test

        def shot(name: str) -> None:
            pump(0.8)
            _grab(window).save(str(out / name))
            print(f"wrote {out / name}")  # noqa: T201

        tab: Any = window.show_tab("calibration")  # the CalibrationTab, reached by its widgets below

        def fail(what: str) -> int:
            print(f"calibration_walkthrough: {what}", file=sys.stderr)  # noqa: T201
            window.close()
            lab.close()
            return 1

        from app.core.rig_protocol import parse_forces
        from app.gui.tabs.calibration import CONTACT, PROTOCOL, RIG_CHECK

        tab.sensor_picker.buttons[config.rig.sensor].click()
        shot("calibration_0_setup.png")
        tab.go_to_step(RIG_CHECK)
        checked: list[bool] = []
        tab.rig_check_finished.connect(checked.append)
        tab.start_rig_check()
        pump(60, until=lambda: bool(checked))
        if checked != [True]:
            return fail(f"the rig check did not pass: {tab.check_lines()}")
        shot("calibration_0_check.png")
        tab.go_to_step(CONTACT)
        tab.protocol_form.condition_check.setChecked(True)  # shown ticked; cleared before the run (time)
        if not tab.find_contact():
            return fail(f"the contact search did not start: {tab.contact_label.text()}")
        pump(120, until=lambda: not tab.rig_session.is_running)
        if not tab.contact_label.text().startswith("contact found"):
            return fail(f"no contact: {tab.contact_label.text()}")
        shot("calibration_0_contact.png")
        tab.protocol_form.condition_check.setChecked(False)
        form = tab.protocol_form
        form.forces_edit.setText("1.75, 3, 4, 5.25")
        form.trials_spin.setValue(1)
        form.hold_spin.setValue(300.0)
        form.rest_spin.setValue(300.0)
        form.folder_edit.setText(str(user_folders.calibrations_dir()))
        tab.go_to_step(PROTOCOL)
        if not tab.start_run():
            return fail(f"the run did not start: {form.message_label.text()}")
        # In a trial after the first, once the fit of the trials before it ("fit so far") is on the protocol page and
        # the trace has some length; on a busy machine that fit (at a lower CPU priority) may come trials later, and
        # in the last trial the picture is taken without it.
        last = form.trials_spin.value() * len(parse_forces(form.forces_edit.text())) - 1
        pump(1200, until=lambda: not tab.rig_session.is_running or (
            tab.live_plot.trial >= 1 and tab.live_plot.n_samples > 600
            and (tab.live_fits_shown >= 1 or tab.live_plot.trial >= last)))
        if not tab.rig_session.is_running:
            return fail(f"the run ended before a trial after the first was under way with its fit so far shown "
                        f"({tab.live_fits_shown} fit(s) of the trials so far shown): {form.message_label.text()}")
        if not tab.live_fits_shown:
            print("calibration_walkthrough: the fit of the trials so far had not come by the last trial (a busy "  # noqa: T201
                  "machine): the protocol picture is without it")
        shot("calibration_1_protocol.png")
        # Until the run has ended and its fit too — or the run ended without a fit (failed, aborted, fit refused):
        # say why instead of waiting out the limit (what made earlier runs of this tool time out).
        pump(1200, until=lambda: not tab.rig_session.is_running and not tab.is_fitting
             and (tab.result is not None or tab.rig_session.outcome is not None
                  and (tab.rig_session.outcome.status != "completed" or "refused" in tab.status_label.text())))
        if tab.result is None:
            outcome = tab.rig_session.outcome
            return fail(f"no fit to show: run {outcome.status if outcome else 'still going'}: "
                        f"{outcome.message if outcome else ''}; status: {tab.status_label.text()}")
        if tab.result.problems:
            return fail(f"the fit is not fit to use: {'; '.join(tab.result.problems)}")
        tab.view_tabs.setCurrentIndex(0)
        shot("calibration_2_fit.png")
        tab.view_tabs.setCurrentWidget(tab.mean_plot)
        shot("calibration_3_means.png")
        tab.view_tabs.setCurrentWidget(tab.param_plot)
        shot("calibration_4_params.png")
        tab.confirm_save = lambda _problems: True
        tab.next_button.click()  # Review → Save
        tab.save(Path(tmp) / "calibration.json")
        tab.view_tabs.setCurrentWidget(tab.history_table)
        shot("calibration_5_history.png")
        window.close()
        lab.close()
    del app
    return 0


if __name__ == "__main__":
    sys.exit(main())
