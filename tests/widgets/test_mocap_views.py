"""The motion-capture views: KinematicsView (side view of the captured body, positions against time, gaps kept) and
MocapSourceButton (the Forces tab's source picker and LSL switch)."""

from __future__ import annotations

import numpy as np
import pytest

from widgets import theme
from widgets.kinematics_view import KinematicsView, segment_colour
from widgets.mocap_picker import SIM_SOURCE, MocapSourceButton


@pytest.fixture
def kinematics(qtbot):
    view = KinematicsView(12)
    qtbot.addWidget(view)
    view.resize(500, 600)
    view.show()
    return view


def test_the_side_view_joins_the_centres_and_shows_every_seen_marker(kinematics):
    centres = np.zeros((12, 3))
    centres[:, 0] = -0.08 * np.arange(12)
    centres[:, 2] = 0.036
    centres[5] = np.nan  # no pose this frame: a gap in the line
    markers = np.repeat(centres[:, None, :], 4, axis=1) + np.array([0.0, 0.0, 0.03])
    markers[0, 0] = np.nan  # unseen
    kinematics.show_body(centres, markers)
    x, z = kinematics._body.getData()
    assert len(x) == 12 and np.isnan(x[5]) and z[0] == pytest.approx(0.036)
    assert len(kinematics._centres.data) == 11 and len(kinematics._markers.data) == 12 * 4 - 5
    assert kinematics.frames_drawn == 1
    kinematics.show_body(None, None)
    assert kinematics._body.getData()[0] is None or len(kinematics._body.getData()[0]) == 0


def test_positions_against_time_follow_the_chosen_coordinate_with_gaps_kept(kinematics):
    t = np.linspace(0.0, 3.0, 91)
    centres = np.zeros((91, 12, 3))
    centres[..., 0] = 0.1 * t[:, None]
    centres[..., 1] = np.sin(t)[:, None]
    centres[40:45, 3] = np.nan
    kinematics.show_positions(t, centres)
    x_t, x = kinematics._curves[3].getData()
    np.testing.assert_allclose(x_t, t)
    assert np.isnan(x[40:45]).all() and x[90] == pytest.approx(0.3)
    kinematics.coordinate_combo.setCurrentIndex(1)  # lateral y
    assert kinematics.coordinate == "y"
    kinematics.show_positions(t, centres)
    assert kinematics._curves[0].getData()[1][30] == pytest.approx(np.sin(t[30]))
    assert segment_colour(0, 12) != segment_colour(11, 12)


def test_the_picker_asks_for_sources_and_shows_what_it_is_told(qtbot, monkeypatch):
    button = MocapSourceButton()
    qtbot.addWidget(button)
    asked: list[str] = []
    published: list[bool] = []
    button.source_requested.connect(asked.append)
    button.publish_toggled.connect(published.append)
    assert button.text() == "Mocap: off"
    button.sim_action.trigger()
    monkeypatch.setattr("widgets.mocap_picker.QInputDialog.getText", lambda *_a, **_k: ("PhaseSpace ", True))
    button.ask_action.trigger()
    assert asked == [SIM_SOURCE, "lsl:PhaseSpace"]
    button.show_source("lsl:PhaseSpace", "following LSL stream 'PhaseSpace'", theme.OK)
    assert button.text() == "Mocap: PhaseSpace" and "following" in button.toolTip()
    assert any(a.text() == "LSL stream 'PhaseSpace'" and a.isChecked() for a in button.menu_.actions())
    button.publish_action.trigger()
    assert published == [True]
    button.set_publishing(True)
    assert button.text() == "Mocap: PhaseSpace · LSL out" and published == [True]
    button.set_sim_available(False, "this robot is real")
    assert not button.sim_action.isEnabled() and "real" in button.sim_action.toolTip()
