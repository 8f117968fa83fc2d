"""Motion capture in the app (offscreen): the Forces tab's source picker beside Record follows an LSL stream by name,
a recording made from the tab stores /mocap as ``sensnake record --mocap`` does, the LSL switch publishes the app's
forces and the loop's joint angles, and the 3-D tab's kinematics panel draws the captured body. The physics lab's
own stream and the X screen's pixels: tests/realdisplay/test_mocap_view.py. LSL stays on this machine
(tests/conftest.py)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from app.gui.lab import LabContext
from app.gui.mocap_link import MocapLink
from app.gui.tabs.forces import create_tab
from app.gui.tabs.scene import SceneTab
from devices.config import LabConfig
from tests.mocap_streams import SPEED_M_S, MocapSender

pytestmark = pytest.mark.usefixtures("sim_lab_fast")


@pytest.fixture
def lab(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    lab = LabContext(LabConfig())
    yield lab
    lab.close()


@pytest.fixture
def tab(qtbot, lab):
    tab = create_tab(lab)
    qtbot.addWidget(tab)
    tab.resize(1400, 900)
    tab.show()
    yield tab
    tab.shutdown()


def test_a_recording_from_the_forces_tab_stores_the_stream_picked_beside_record(qtbot, lab, tab, tmp_path):
    picker = tab.mocap_picker
    assert isinstance(lab.mocap, MocapLink) and picker is not None
    row = tab.controls._record_row
    assert row.indexOf(picker) == row.indexOf(tab.controls.record) + 1  # beside Record
    assert picker.text() == "Mocap: off"
    assert not picker.sim_action.isEnabled()  # the scripted lab: nothing to film
    lab.board.start()
    with MocapSender("TabMocap", gap=None):
        picker.source_requested.emit("lsl:TabMocap")  # as the menu's "LSL stream by name…" does
        qtbot.waitUntil(lambda: lab.mocap.inlet is not None, timeout=20_000)
        assert picker.text() == "Mocap: TabMocap" and "following" in picker.toolTip()
        qtbot.waitUntil(lambda: len(tab.force_history) > 10, timeout=20_000)
        session = tab.start_recording(tmp_path / "with-mocap.h5", duration_s=None)
        assert session is not None and session.mocap is lab.mocap
        qtbot.waitUntil(lambda: session.elapsed_s > 1.5, timeout=20_000)
        picker.none_action.trigger()  # refused while recording: the take would lose what it kept
        assert lab.mocap.source == "lsl:TabMocap" and lab.mocap.inlet is not None and "stays" in picker.toolTip()
        assert picker.text() == "Mocap: TabMocap"
        with qtbot.waitSignal(session.stopped, timeout=60_000) as stopped:
            tab.stop_recording()
    assert "mocap:" in stopped.args[0] and "written to with-mocap.h5 as /mocap" in stopped.args[0]
    assert "/mocap" in tab.controls.message.text()
    with h5py.File(tmp_path / "with-mocap.h5", "r") as f:
        time_s, centres = f["mocap/time_s"][:], f["mocap/segment_center_m"][:]
        daq = f["daq/time_s"][:]
        how = f["mocap"].attrs["clock_offset_how"]
        source = f["mocap"].attrs["source"]
    assert "stamped at capture" in how and "TabMocap" in source
    assert time_s[0] >= 0.0 and time_s[-1] - time_s[0] > 1.2 and len(time_s) >= 0.97 * 960 * (time_s[-1] - time_s[0])
    assert abs(time_s[-1] - daq[-1]) < 0.3  # one clock with the board
    line = np.polyfit(time_s, centres[:, 0, 0], 1)  # the head slides: stamped at capture, not arrival
    assert line[0] == pytest.approx(SPEED_M_S, rel=0.02)
    assert np.abs(centres[:, 0, 0] - np.polyval(line, time_s)).max() < 0.0005


def test_the_lsl_switch_publishes_the_forces_and_the_loops_joint_angles(qtbot, lab, tab):
    import pylsl

    lab.robot.connect_robot()
    qtbot.waitUntil(lambda: lab.robot.is_connected, timeout=20_000)
    tab.mocap_picker.publish_action.trigger()
    assert lab.mocap.publishing and tab.mocap_picker.text().endswith("LSL out")
    found = pylsl.resolve_byprop("name", "SenSnake-joints", 1, 10.0)
    assert found
    inlet = pylsl.StreamInlet(found[0])
    inlet.open_stream(5.0)
    samples: list = []
    qtbot.waitUntil(lambda: samples.extend(inlet.pull_chunk(timeout=0.0)[0]) or len(samples) >= 20, timeout=20_000)
    inlet.close_stream()
    assert len(samples[0]) == 12
    assert lab.mocap.links.publisher is not None and lab.mocap.links.publisher.joint_samples >= 20
    tab.mocap_picker.publish_action.trigger()
    assert not lab.mocap.publishing


def test_the_3d_tab_shows_the_captured_body_and_each_segments_position(qtbot, lab):
    scene = SceneTab(lab)
    qtbot.addWidget(scene)
    scene.resize(1200, 700)
    scene.show()
    try:
        assert not scene.kinematics.isVisible()  # no source: no panel
        with MocapSender("SceneMocap", gap=None):
            lab.mocap.set_source("lsl:SceneMocap")
            assert scene.kinematics.isVisible()
            qtbot.waitUntil(lambda: scene.kinematics.frames_drawn >= 5, timeout=20_000)
            head = scene.kinematics._curves[0]
            qtbot.waitUntil(lambda: head.xData is not None and len(head.xData) >= 10, timeout=20_000)
            marks = scene.mocap_marks()
        assert len(marks) == 2 and marks[0][0].shape == (48, 3)  # markers and centres for the 3-D picture
        times, head_x = scene.kinematics._curves[0].xData, scene.kinematics._curves[0].yData
        assert np.all(np.diff(times) > 0)
        assert (head_x[-1] - head_x[0]) / (times[-1] - times[0]) == pytest.approx(SPEED_M_S, rel=0.05)
        assert "following" in scene.kinematics.status.text()
        lab.mocap.set_source("")
        assert not scene.kinematics.isVisible()
    finally:
        scene.shutdown()
