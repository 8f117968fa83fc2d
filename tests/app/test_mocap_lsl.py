"""`sensnake record --mocap lsl:NAME --lsl-out`: a motion-capture stream followed live, every sample stamped at
capture on the recording's clock, dropouts counted in /events, and the recording's streams published. Lab Streaming
Layer traffic stays on this machine (LSLAPICFG, tests/conftest.py)."""

from __future__ import annotations

import os
import threading
import time
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from app.cli import main
from app.core.live_session import LiveSession
from app.core.lsl_link import LslLinks, MocapInlet
from app.core.recorder import Recorder
from devices.config import LabConfig, MocapConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel
from tests.mocap_streams import SPEED_M_S, MocapSender
from tests.waiting import wait_until


@pytest.fixture
def real_time_board(install_sim_device):
    config = LabConfig()
    board = VirtualBoard(config.board, SimClock(1.0), ContactModel(config, None, seed=5).forces_n, seed=6)
    return install_sim_device("board", board)


def test_a_live_mocap_stream_is_stamped_at_capture_and_its_dropouts_counted(real_time_board, tmp_path, capsys):
    import pylsl

    out = tmp_path / "live.h5"
    published: list[float] = []

    def listen() -> None:  # another program on the LSL network, reading what the recording publishes
        streams = pylsl.resolve_byprop("name", "SenSnake-forces", 1, 5.0)
        if streams:
            inlet = pylsl.StreamInlet(streams[0])
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline and len(published) < 10:
                _, stamps = inlet.pull_chunk(timeout=0.2)
                published.extend(stamps)
            inlet.close_stream()

    with MocapSender("TestMocap"):
        listener = threading.Thread(target=listen, name="test-lsl-listener")
        listener.start()
        code = main(["record", "--daq", "sim", "--seconds", "1.5", "--mocap", "lsl:TestMocap", "--lsl-out",
                     "--out", str(out)])
        listener.join()
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "written to" in printed.out and "1 dropout(s)" in printed.out
    assert len(published) >= 10  # SenSnake-forces reached another program
    with h5py.File(out, "r") as f:
        group = f["mocap"]
        time_s, centers = group["time_s"][:], group["segment_center_m"][:]
        how = group.attrs["clock_offset_how"]
        kinds = [k.decode() for k in f["events/kind"][:]]
        texts = [t.decode() for t in f["events/text"][:]]
    assert "stamped at capture" in how and time_s[-1] - time_s[0] > 1.0
    gaps = np.diff(time_s)
    assert np.sum(gaps > 0.05) == 1 and gaps.max() == pytest.approx(0.1, abs=0.01)  # the dropout, only it
    assert kinds.count("mocap") >= 2 and any("dropout" in t for t in texts)
    # stamped at capture: the head's x against time is the sliding line to within noise, though samples arrived in
    # 25 ms chunks (arrival stamps would scatter it by up to 5 mm)
    head_x = centers[:, 0, 0]
    line = np.polyfit(time_s, head_x, 1)
    assert line[0] == pytest.approx(SPEED_M_S, rel=0.01)
    assert np.abs(head_x - np.polyval(line, time_s)).max() < 0.0003


def test_an_lsl_stream_that_does_not_answer_is_refused_before_recording(real_time_board, tmp_path, capsys,
                                                                        monkeypatch):
    monkeypatch.setattr("app.core.lsl_link.RESOLVE_TIMEOUT_S", 0.5)
    # Nothing of this type answers: a test beside this one may publish a MoCap stream on this machine, which the
    # fallback by type would then rightly take (it did once: 'TabMocap')
    monkeypatch.setattr("app.core.lsl_link.MOCAP_TYPE", f"MoCapNobody{os.getpid()}")
    out = tmp_path / "none.h5"
    started = time.monotonic()
    assert main(["record", "--daq", "sim", "--seconds", "1", "--mocap", "lsl:NoSuchStream", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "NoSuchStream" in err and "MoCap" in err and not out.exists()
    # refused after the resolve's 0.5 s (twice) and the simulated board's start and stop (~1 s in all on a quiet
    # 2-core machine; the bound leaves room for a busy one); a recording made meanwhile would have been refused above
    assert time.monotonic() - started < 15


def _wait(condition, timeout_s: float = 20.0) -> None:
    assert wait_until(condition, timeout_s), "timed out"


def test_the_inlet_fits_live_poses_a_few_times_a_second_and_keeps_samples_only_for_a_take():
    """What the app's 3-D tab draws: segment centres fitted ~30 times a second by the reader (on the sliding line,
    stamped at capture), and samples kept only between begin_take and end_take (the app follows for hours)."""
    with MocapSender("LiveMocap", gap=None):
        inlet = MocapInlet("lsl:LiveMocap", mocap=MocapConfig(), collect=False, live_rate_hz=30.0)
        inlet.start()
        try:
            assert inlet.live is not None and inlet.unit == "mm"
            _wait(lambda: len(inlet.live) >= 20)
            assert inlet.samples()[0].size == 0  # nothing kept outside a take
            inlet.begin_take()
            _wait(lambda: inlet.samples()[0].size >= 480)
            host, values, fit = inlet.end_take()
            snapshot = inlet.live.snapshot()
        finally:
            inlet.close()
    assert values.shape[1] == 144 and inlet.samples()[0].size == 0
    assert fit is not None and fit.center_m.shape == (len(host), 12, 3)  # fitted as they came
    np.testing.assert_allclose(fit.center_m[:, :, 2], 0.036, atol=0.0003)
    steps = np.diff(snapshot.time_s)
    assert np.median(steps) == pytest.approx(1 / 30.0, rel=0.15)
    head_x = snapshot.center_m[:, 0, 0]
    line = np.polyfit(snapshot.time_s, head_x, 1)
    assert line[0] == pytest.approx(SPEED_M_S, rel=0.02)
    assert np.abs(head_x - np.polyval(line, snapshot.time_s)).max() < 0.0003
    assert snapshot.markers_m.shape == (12, 4, 3) and np.isfinite(snapshot.markers_m).all()
    np.testing.assert_allclose(snapshot.newest_center_m[:, 2], 0.036, atol=0.0003)


def test_a_stream_without_the_layouts_labels_is_refused_when_found():
    import pylsl

    info = pylsl.StreamInfo("OtherLabels", "MoCap", 9, 100.0, "float32", "other-labels")
    channels = info.desc().append_child("channels")
    for marker in ("Hip", "Knee", "Ankle"):
        for axis in "XYZ":
            channel = channels.append_child("channel")
            channel.append_child_value("label", f"{marker}_{axis}")
            channel.append_child_value("unit", "mm")
    outlet = pylsl.StreamOutlet(info)
    inlet = MocapInlet("lsl:OtherLabels", mocap=MocapConfig())
    with pytest.raises(ValueError, match="lsl:OtherLabels.*none of the layout's marker labels"):
        inlet.start()
    assert not inlet.following
    del outlet


def test_lsl_links_publish_forces_in_their_units_and_the_loops_joint_angles(tmp_path):
    """SenSnake-forces carries N where a calibration gives forces and µS elsewhere (the channels' units say which);
    SenSnake-joints the present angles at the loop's rate, each stamped when its servo read was sent."""
    import pylsl

    config = LabConfig()
    pipeline = SimpleNamespace(estimated=np.array([True, False] + [False] * 34))
    live = SimpleNamespace(channel_names=tuple(config.board.channel_names), board=config.board, pipeline=pipeline,
                           subscribe=lambda _cb: None, unsubscribe=lambda _cb: None)
    links = LslLinks(live, config.mocap, config.robot.axes, joint_rate_hz=50.0)  # type: ignore[arg-type]
    links.publish(True)
    try:
        found = {name: pylsl.resolve_byprop("name", name, 1, 5.0) for name in ("SenSnake-forces", "SenSnake-joints")}
        forces_info = pylsl.StreamInlet(found["SenSnake-forces"][0]).info(5.0)
        units = []
        channel = forces_info.desc().child("channels").child("channel")
        while not channel.empty():
            units.append(channel.child_value("unit"))
            channel = channel.next_sibling()
        assert units[:3] == ["N", "uS", "uS"] and forces_info.type() == "Force"
        joints = pylsl.StreamInlet(found["SenSnake-joints"][0])
        assert joints.info(5.0).nominal_srate() == 50.0
        joints.open_stream(5.0)
        t0 = time.monotonic()
        states = [SimpleNamespace(host_time_s=t0 + k / 50.0, position_rad=np.full(12, 0.01 * k)) for k in range(10)]
        links.push_robot_states(states)
        samples, stamps = [], []
        deadline = time.monotonic() + 5.0
        while len(samples) < 10 and time.monotonic() < deadline:
            chunk, chunk_stamps = joints.pull_chunk(timeout=0.2)
            samples += chunk
            stamps += chunk_stamps
        joints.close_stream()
    finally:
        links.close()
    assert len(samples) == 10 and samples[3][0] == pytest.approx(0.03)
    lsl_minus_mono = pylsl.local_clock() - time.monotonic()
    np.testing.assert_allclose(np.asarray(stamps) - lsl_minus_mono - t0, np.arange(10) / 50.0, atol=0.002)


def test_lsl_links_collect_a_take_per_recording_and_count_its_own_dropouts(tmp_path):
    config = LabConfig()
    live = LiveSession(config.board)
    links = LslLinks(live, config.mocap, config.robot.axes)
    with MocapSender("TakeMocap", gap=(2.5, 2.6)) as sender:  # the gap falls in the recording
        links.adopt(links.open_inlet("lsl:TakeMocap", collect=False))
        inlet = links.inlet
        assert inlet is not None
        _wait(lambda: inlet.received > 100)
        recorder = Recorder(tmp_path / "r.h5", config.source_text, config.board.channel_names)
        recorder.start()
        links.start(recorder)
        _wait(lambda: time.monotonic() - recorder.t0_monotonic_s > 1.0 and inlet.dropouts >= 1)
        stopping_s = time.monotonic() - recorder.t0_monotonic_s
        take = links.stop(recorder)
        recorder.stop()
        links.close()
        assert sender.sent > 0
    assert take is not None and take.dropouts == 1 and take.missing == pytest.approx(96, abs=3)
    assert take.streamed > 100 and len(take.host_s) == 0  # written into the recording as it came, none kept
    with h5py.File(tmp_path / "r.h5", "r") as f:
        time_s = f["mocap/time_s"][:]
        assert len(time_s) == take.streamed and f["mocap/segment_center_m"].shape == (take.streamed, 12, 3)
        assert time_s[0] >= 0.0  # nothing captured before the recording began
        # … and every sample captured until the stop, those still on their way at the stop included (without the
        # wait for them the take ended ~50 ms short)
        assert time_s[-1] >= stopping_s - 0.015, (time_s[-1], stopping_s)
        assert "1 dropouts" in f["mocap"].attrs["source"]
