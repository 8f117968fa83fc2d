"""The Calibration tab (placeholder until the rig workflow lands): says what the tab will do.

GUI thread only.
"""

from __future__ import annotations

from PySide6.QtWidgets import QWidget

from app.lab import LabContext
from widgets.placeholder import PlaceholderPage

DESCRIPTION = (
    "Drive the calibration rig through the 4-force × 3-trial protocol and fit the sensor models. The rig servo winds "
    "a cable through a spring onto the probe (F = k·r·(θ − θ_contact)); each trial holds one force while the "
    "sensor's conductance is recorded. The fit gives the linear model and the creep-aware SLS model per sensor, "
    "written to the calibration file used by the Forces tab and `sensnake estimate`."
)


def create_tab(lab: LabContext) -> QWidget:
    rig = lab.config.rig
    note = (f"Rig on port {rig.port}: servo {rig.servo_id}, wheel radius {rig.wheel_radius_m * 1000:.0f} mm, "
            f"spring {rig.spring_k_n_per_m:.0f} N/m, sensor {rig.sensor}. Until this tab is built, fit trials "
            "from the command line: sensnake fit TRIAL.csv… --sensor NAME --area M2 --out CAL.json")
    return PlaceholderPage("Calibration", DESCRIPTION, note)
