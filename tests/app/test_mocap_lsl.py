"""`sensnake record --mocap lsl:NAME --lsl-out`: a motion-capture stream followed live, every sample stamped at
capture on the recording's clock, dropouts counted in /events, and the recording's streams published. Lab Streaming
Layer traffic stays on this machine (LSLAPICFG below)."""

from __future__ import annotations

import os
import threading
import time

import h5py
import numpy as np
import pytest

from app.cli import main
from devices.config import LabConfig, MocapConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel
from models.kinematics import forward_kinematics
from models.mocap import markers_from_poses

SPEED_M_S = 0.2  # the body slides forward: a sample stamped at its arrival would be off by up to 5 mm here
CHUNK_S = 0.025  # the stream's samples arrive in chunks this far apart, as a mocap system's network sends them
GAP = (0.6, 0.7)  # seconds into the stream without samples: a dropout


@pytest.fixture(scope="module", autouse=True)
def lsl_on_this_machine_only(tmp_path_factory):
    config = tmp_path_factory.mktemp("lsl") / "lsl_api.cfg"
    config.write_text("[multicast]\nResolveScope = machine\nMachineAddresses = {127.0.0.1}\n\n[ports]\n"
                      "IPv6 = disable\n\n[lab]\nKnownPeers = {127.0.0.1}\n", encoding="utf-8")
    previous = os.environ.get("LSLAPICFG")
    os.environ["LSLAPICFG"] = str(config)
    yield
    if previous is None:
        os.environ.pop("LSLAPICFG", None)
    else:
        os.environ["LSLAPICFG"] = previous


@pytest.fixture
def real_time_board(install_sim_device):
    config = LabConfig()
    board = VirtualBoard(config.board, SimClock(1.0), ContactModel(config, None, seed=5).forces_n, seed=6)
    return install_sim_device("board", board)


class MocapSender:
    """A 960 Hz MoCap stream of the straight body sliding along x, stamped at generation, sent in chunks."""

    def __init__(self, name: str) -> None:
        import pylsl

        mocap = MocapConfig()
        info = pylsl.StreamInfo(name, "MoCap", 48 * 3, 960.0, "float32", f"{name}-test")
        channels = info.desc().append_child("channels")
        for s in range(1, 13):
            for k in range(1, 5):
                for axis in "XYZ":
                    channel = channels.append_child("channel")
                    channel.append_child_value("label", f"{mocap.label(s, k)}_{axis}")
                    channel.append_child_value("unit", "mm")
        self.outlet = pylsl.StreamOutlet(info)
        pose = forward_kinematics(np.zeros(12), ("pitch", "yaw") * 6)
        self.centers = pose.segment_midpoints_m
        self.frames = pose.frames
        self.layout = np.array([mocap.marker_layout_m] * 12)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="test-mocap-sender")
        self.start_lsl = 0.0

    def markers_mm(self, lsl_time: float) -> np.ndarray:
        shift = np.array([SPEED_M_S * (lsl_time - self.start_lsl), 0.0, 0.036])
        centers = (self.centers + shift)[None]
        return markers_from_poses(centers, self.frames[None], self.layout)[0].reshape(-1) * 1000.0

    def _run(self) -> None:
        import pylsl

        self.start_lsl = pylsl.local_clock()
        sent = self.start_lsl
        while not self.stop.is_set():
            self.stop.wait(CHUNK_S)
            now = pylsl.local_clock()
            stamps = np.arange(sent, now, 1 / 960.0)
            if len(stamps):
                sent = stamps[-1] + 1 / 960.0
            keep = ~((stamps - self.start_lsl >= GAP[0]) & (stamps - self.start_lsl < GAP[1]))
            for stamp in stamps[keep]:
                self.outlet.push_sample(self.markers_mm(float(stamp)).tolist(), float(stamp))

    def __enter__(self) -> MocapSender:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()


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
    out = tmp_path / "none.h5"
    started = time.monotonic()
    assert main(["record", "--daq", "sim", "--seconds", "1", "--mocap", "lsl:NoSuchStream", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "NoSuchStream" in err and "MoCap" in err and not out.exists()
    # refused after the resolve's 0.5 s (twice): the rest is the simulated board starting and stopping (6-11 s on a
    # 2-core machine); a recording made meanwhile would have been refused above (not out.exists())
    assert time.monotonic() - started < 30
