"""The simulated lab in its own process (devices.sim.lab_process): its robot, board and rig answer on ptys through
the same drivers as any serial port, the Teach hand and fault injection reach it, the 3-D view's copy of the world
follows it, and it ends with its app."""

from __future__ import annotations

import os
import sys
import time

import numpy as np
import pytest

from devices import factory
from devices.board import BoardReader
from devices.config import LabConfig
from devices.rig import CalibrationRig
from devices.servo_chain import ServoChain
from devices.sim.lab_process import LabProcess, read_qpos
from tests.conftest import scripted_config
from tests.waiting import wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ptys (Linux)")


@pytest.fixture
def lab_process():
    """A :class:`LabProcess` (physics lab unless the test says otherwise) installed behind the ``sim`` ports."""
    made: list[LabProcess] = []
    previous: list[object] = []

    def start(config: LabConfig | None = None) -> LabProcess:
        lab = LabProcess(config or LabConfig()).start()
        made.append(lab)
        previous.append(factory.install_sim_lab(lab))
        return lab

    yield start
    if previous:
        factory.install_sim_lab(previous[0])
    for lab in made:
        lab.close()


def test_the_robot_board_and_rig_answer_on_their_ptys_through_the_usual_drivers(lab_process):
    config = scripted_config()
    lab = lab_process(config)
    assert factory.sim_serial_path("robot") == lab.paths["robot"] and os.path.realpath(lab.paths["robot"]).startswith(
        "/dev/pts/")
    assert len(set(lab.paths.values())) == 3
    # A host on port sim waits for the lab's replies as for any pty's (a process the scheduler may delay).
    from devices.servo_chain import _is_pty

    assert _is_pty("sim", "robot") and _is_pty("sim", "rig")

    chain = ServoChain(config.robot, device="robot")  # port "sim": the factory opens the lab's robot pty
    chain.open()
    try:
        assert chain._port is not None and chain._port.ser.port == lab.paths["robot"]
        chain.check_models()
        state = chain.read_state()
        assert len(state.position_rad) == 12 and np.all(np.isfinite(state.position_rad))
    finally:
        chain.close()

    reader = BoardReader(config.board)
    reader.start()
    try:
        assert reader.wait_for_frames(10, timeout_s=10.0)
        block = reader.read_block()
        assert block is not None and block.counts.shape[1] == config.board.n_channels
        seq = block.seq.astype(np.int64)
        assert np.all(np.diff(seq) == 1)  # every frame whole and in order
        assert reader.stats.crc_errors == 0
    finally:
        reader.close()

    rig = CalibrationRig(config.rig)
    rig.open()
    try:
        assert np.isfinite(rig.position_rad())
    finally:
        rig.close()


def test_the_teach_hand_and_fault_injection_reach_the_lab_and_its_errors_come_back(lab_process):
    config = scripted_config()
    lab = lab_process(config)
    assert lab.call("chain.servo_ids") == tuple(config.robot.joint_ids)
    chain = ServoChain(config.robot, device="robot")
    chain.open()
    try:
        chain.set_torque(False)
        lab.chain.set_limp_position(3, 2048 + 300)  # what SimHand does
        assert wait_until(lambda: abs(chain.ticks_from_angles(chain.read_state().position_rad)[2] - 2348) <= 2,
                          5.0), "joint 3 did not follow the hand"
        with pytest.raises(ValueError):  # a joint holding torque cannot be bent: the lab's own error, here
            chain.set_torque(True, ids=[4])
            lab.chain.set_limp_position(4, 2500)
    finally:
        chain.close()
    with pytest.raises(AttributeError):
        lab.call("chain._lock")  # only the lab's public names
    # Faults are injected as on the in-process lab, by the same names.
    assert lab.call("board.unplugged") is False
    lab.board.unplug()
    assert lab.call("board.unplugged") is True
    lab.board.replug()
    assert lab.call("board.unplugged") is False


def test_the_3d_views_copy_of_the_world_follows_the_lab(lab_process):
    lab = lab_process(LabConfig())  # the physics lab
    if lab.physics is None:
        pytest.skip(f"no physics lab here: {lab.physics_note}")
    config = lab.config
    page, nq = lab.physics.posed._page, lab.physics.posed._nq
    wait_until(lambda: read_qpos(page, nq) is not None, 10.0)
    first = read_qpos(page, nq)
    assert first is not None
    chain = ServoChain(config.robot, device="robot")
    chain.open()
    try:
        chain.set_torque(True)
        goal = np.zeros(12)
        goal[:2] = (0.6, 0.5)  # lift the head and turn it
        chain.write_goals(goal)
        qadr = lab.physics.posed.world._qadr  # each joint's place in qpos
        deadline = time.monotonic() + 15.0
        while True:
            # Deliberate: the world moves on between two looks (nothing announces a step to wait on).
            time.sleep(0.1)
            state = chain.read_state()
            newest = read_qpos(page, nq)
            assert newest is not None
            shown = newest[1][qadr]
            if np.all(np.abs(state.position_rad[:2] - goal[:2]) < 0.03) and np.all(
                    np.abs(shown - state.position_rad) < 0.03):
                break
            assert time.monotonic() < deadline, f"the copy shows {shown[:2]}, the servos read {state.position_rad[:2]}"
        assert newest[0] > first[0]  # the world's time went on
    finally:
        chain.close()
    try:
        frame = lab.physics.render_rgb(160, 120)
    except RuntimeError as exc:  # no OpenGL here
        pytest.skip(str(exc))
    finally:
        lab.physics.release_renderer()
    assert frame.shape == (120, 160, 3) and frame.std() > 1.0
    assert lab.physics.shown_time_s is not None


def test_closing_ends_the_lab_process_and_its_ptys(lab_process):
    from devices.servo_chain import _is_pty

    lab = lab_process(scripted_config())
    path = lab.paths["robot"]
    assert lab.alive
    lab.close()
    assert not lab.alive
    assert not os.path.exists(path) or not _answers(path)
    factory.install_sim_lab(None)
    assert not _is_pty("sim", "rig")  # no lab process behind sim: the in-process lab's port is no pty
    with pytest.raises(RuntimeError, match="closed"):
        lab.call("chain.servo_ids")


def _answers(path: str) -> bool:
    import serial

    try:
        with serial.Serial(path, 1_000_000, timeout=0.2) as port:
            port.write(bytes([0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E]))  # ping servo 1
            return bool(port.read(14))
    except (serial.SerialException, OSError):
        return False


def test_a_lab_process_that_dies_is_told_to_its_listeners_with_the_cause(lab_process):
    import signal as signal_module
    import threading

    lab = lab_process(scripted_config())
    told: list[str] = []
    arrived = threading.Event()

    def listen(text: str) -> None:
        told.append(text)
        arrived.set()

    lab.add_died_listener(listen)
    os.kill(lab.pid, signal_module.SIGKILL)
    assert arrived.wait(10.0)
    assert f"pid {lab.pid}" in told[0] and "killed by SIGKILL" in told[0] and "restart the app" in told[0]
    late: list[str] = []
    lab.add_died_listener(late.append)  # a listener added after the death hears it at once
    assert late == told
    with pytest.raises(RuntimeError, match="gone|closed"):
        lab.call("chain.servo_ids")


def test_a_board_port_nobody_reads_holds_no_more_than_a_second_of_old_frames(lab_process):
    """Nobody reading the board's pty: its frames are discarded beyond BOARD_BACKLOG_S of wall time (as a USB
    adapter's buffer), so the lab's process neither blocks on a full pty nor piles them up in memory."""
    import fcntl
    import struct
    import termios

    from devices.sim.lab_process import BOARD_BACKLOG_S

    config = scripted_config()
    lab = lab_process(config)
    # Deliberate: time passes with nobody reading (75 frames go out, more than the pty holds); that is what is tested.
    time.sleep(2.5)
    frame_bytes = 16 + 2 * config.board.n_channels
    fd = os.open(lab.paths["board"], os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)  # no flush on open (pyserial does)
    try:
        waiting = struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
    finally:
        os.close(fd)
    kept = BOARD_BACKLOG_S * config.board.rate_hz * frame_bytes
    assert kept < 3500  # below what the pty holds (4 kB): the discarding, not the pty's size, is what is seen
    assert 0 < waiting <= kept + 2 * frame_bytes
