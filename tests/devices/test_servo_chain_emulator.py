"""The driver and the CLI robot commands against the independent XM430 emulator (``tests/emulators``): a separate
process on a pseudo-terminal, written from the Protocol 2.0 spec and the XM430-W350 e-manual, sharing no code with
``devices/`` or ``devices/sim``."""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import json
import os
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from devices import controller as controller_module
from devices.config import RobotConfig
from devices.controller import HoldPose, RobotController
from devices.errors import (
    BusBusyError,
    BusQuietError,
    DeadlinePassedError,
    JointLimitError,
    NoReplyError,
    RepliesHeldError,
    ServoHardwareError,
)
from devices.servo_chain import ServoChain
from models.trajectory import FollowTheLeader
from tests.emulators import xm430_emulator as emu_module
from tests.emulators.xm430_emulator import EmulatorProcess
from tests.waiting import wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")),
                                reason="the emulator needs os.openpty (Linux or macOS)")


def robot_on(path: str, **changes) -> RobotConfig:
    return dataclasses.replace(RobotConfig(), port=path, **changes)


@contextlib.contextmanager
def running_controller(robot: RobotConfig) -> Iterator[RobotController]:
    """A started control loop on the chain at ``robot.port`` (servo models checked), closed afterwards."""
    with ServoChain(robot) as chain:
        chain.check_models()
        controller = RobotController(chain, robot)
        controller.start()
        try:
            yield controller
        finally:
            controller.close()


def test_the_emulator_shares_no_code_with_the_driver_or_the_simulator():
    tree = ast.parse(Path(emu_module.__file__).read_text(encoding="utf-8"))
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert not {m for m in imported if m.split(".")[0] in ("devices", "app", "models", "widgets", "dynamixel_sdk")}


def test_the_emulator_packets_match_the_protocol_2_examples():
    # The e-manual's Protocol 2.0 examples: ping to ID 1 and the status packet of an XM430 (model 1030, fw 38).
    assert emu_module.packet(1, emu_module.INST_PING, b"") == bytes.fromhex("FFFFFD0001030001194E")
    assert emu_module.status_packet(1, 0, bytes.fromhex("060426")) == bytes.fromhex("FFFFFD00010700550006042665 5D")
    # Byte stuffing: FF FF FD inside the parameters gains an FD, and the parser takes it out again.
    stuffed = emu_module.packet(1, emu_module.INST_WRITE, bytes.fromhex("7400FFFFFD00"))
    assert bytes.fromhex("FFFFFDFD") in stuffed[7:]
    assert emu_module.Parser().feed(b"\x00garbage" + stuffed) == [(1, emu_module.INST_WRITE,
                                                                    bytes.fromhex("7400FFFFFD00"))]


def test_a_sync_read_pays_the_factory_return_delay_on_the_wire(emulator):
    with ServoChain(robot_on(emulator.path)) as chain:
        chain.read_state()
        t0 = time.perf_counter()
        for _ in range(5):
            chain.read_state()
        per_read_s = (time.perf_counter() - t0) / 5
    # 12 replies × (500 µs Return Delay Time + 21 bytes at 1 Mbps) plus the 26-byte instruction: ≥ 8.8 ms.
    assert per_read_s >= 12 * (500e-6 + 21e-5) + 26e-5


def test_scan_teach_and_play_commands_on_the_independent_chain(emulator, tmp_path, capsys):
    assert main(["scan", "--robot", emulator.path]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[1] for line in lines] == [str(i) for i in range(1, 13)]
    assert all("XM430-W350 (model 1020)" in line for line in lines)

    emulator.command("push 4 300")  # a person bends joint 4 by ~0.46 rad before the capture
    taught = tmp_path / "taught.json"
    assert main(["teach", "--robot", emulator.path, "--after", "0", "--out", str(taught)]) == 0
    angles = json.loads(taught.read_text())["angles_rad"]
    assert angles[3] == pytest.approx(300 * 2 * np.pi / 4096, abs=2e-3)
    assert emulator.state(4)["torque"] == 1  # teach ends holding the captured pose

    shape = json.loads(taught.read_text())
    shape["angles_rad"] = [0.2 * (-1) ** i for i in range(12)]
    played = tmp_path / "wave.json"
    played.write_text(json.dumps(shape))
    log = tmp_path / "play.csv"
    assert main(["play", str(played), "--robot", emulator.path, "--speed", "1", "--shifts", "1",
                 "--log", str(log)]) == 0
    assert "finished" in capsys.readouterr().out
    # The servos hold the last goal the log reports, and their present positions are what the log read back.
    rows = log.read_text().splitlines()
    assert len(rows) > 10
    last = [float(v) for v in rows[-1].split(",")]
    assert any(abs(a) > 0.1 for a in last[1:13])  # the wave moved the joints
    for k, sid in enumerate(range(1, 13)):
        state = emulator.state(sid)
        assert state["goal_writes"] > 0
        assert (state["goal"] - 2048) * 2 * np.pi / 4096 == pytest.approx(last[1 + k], abs=2e-3)


# -- faults (reboots, limits, a killed bus), each against the emulator in its own process ------------------------------------
def _write_shape(path: Path, angles: list[float]) -> Path:
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": path.stem,
                                "axes": ["pitch", "yaw"] * 6, "angles_rad": angles}))
    return path


def _start_play(emulator: EmulatorProcess, shape: Path) -> subprocess.Popen:
    """``sensnake play`` in its own process (so stderr shows everything, thread tracebacks included), slow enough
    to still be playing when a fault is injected."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    env.pop("SENSNAKE_DEBUG", None)
    return subprocess.Popen([sys.executable, "-m", "app", "play", str(shape), "--robot", emulator.path,
                             "--speed", "0.05"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _wait_for_goals(emulator: EmulatorProcess, n_writes: int, proc: subprocess.Popen) -> None:
    """Until play has written ``n_writes`` goal frames; a play that ended first fails with what it said. 90 s: a
    fresh `sensnake play` process starts in ~2 s on a quiet machine, several times that on a loaded one."""
    written = wait_until(lambda: emulator.counts()["sync_write"] >= n_writes or proc.poll() is not None, 90.0)
    if proc.poll() is not None:
        _, err = proc.communicate()
        raise AssertionError(f"play ended (exit {proc.returncode}) before {n_writes} goal writes: {err}")
    assert written, "play never wrote goals"


def test_a_shape_beyond_the_joint_limits_is_refused_before_any_goal(emulator, tmp_path, capsys):
    shape = _write_shape(tmp_path / "wild.json", [0.0, 0.0, 10.0] + [0.0] * 9)
    assert main(["play", str(shape), "--robot", emulator.path, "--speed", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "joint 3 (index 2) = 10.000 rad is beyond its limit +1.570 rad" in err[0]
    assert emulator.counts()["sync_write"] == 0
    assert all(emulator.state(sid)["goal_writes"] == 0 for sid in range(1, 13))


def test_a_plan_beyond_a_joint_limit_is_refused_on_the_bus_thread_before_any_goal(emulator):
    # Each angle is within its own joint's limits, but follow-the-leader carries joint 1's 1.0 rad down the body to
    # joint 3, whose limit is 0.5 rad: only the plan shows it.
    limits = [1.57] * 12
    limits[2] = 0.5
    robot = robot_on(emulator.path, joint_max_rad=tuple(limits))
    with running_controller(robot) as controller:
        source = FollowTheLeader([1.0] + [0.0] * 11, robot.axes, 1.0, 1, rate_hz=robot.control_rate_hz)
        with pytest.raises(JointLimitError, match=r"target \d+ of \d+: joint 3 \(index 2\) = 1\.000 rad"):
            controller.play(source, "too far down").result(10)
    assert emulator.counts()["sync_write"] == 0
    assert emulator.state(1)["torque"] == 0  # refused before the hold: the servos were not even torqued


def test_play_turns_torque_on_holding_the_pose_it_just_read_in_sync_writes(emulator):
    # The play command fits in a tick's slack: it starts from the pose the tick just read and turns torque on with
    # two sync writes (goal := present, torque enable), not twelve acknowledged writes after a second read (which
    # took ~30 ms at the factory Return Delay Time: every `sensnake play` missed a tick there).
    emulator.command("push 4 300")  # a limp joint bent by hand: it must be held there, not jump back
    robot = robot_on(emulator.path)
    with running_controller(robot) as controller:
        assert wait_until(lambda: controller.stats().ticks >= 3, 15.0)
        before = emulator.counts()
        source = FollowTheLeader([0.1] * 12, robot.axes, 0.02, 1, rate_hz=robot.control_rate_hz)
        playing = controller.play(source, "slow")
        assert wait_until(lambda: controller.motion_name == "slow" or playing.done(), 15.0)
        assert not playing.done() or playing.exception() is None
        held = [emulator.state(sid) for sid in range(1, 13)]
        after = emulator.counts()
        controller.stop_motion()
    assert after["write"] == before["write"]  # no acknowledged write: no status packet to wait for
    assert all(state["torque"] == 1 for state in held)
    assert abs(held[3]["goal"] - (2048 + 300)) <= 3  # held where the hand left it (+ at most a step of the motion)
    assert abs(held[3]["position"] - (2048 + 300)) <= 3


@pytest.mark.parametrize("jump_ticks", [700, 0])
def test_a_servo_that_reboots_mid_play_stops_it_naming_the_servo(emulator, tmp_path, jump_ticks):
    # 700 ticks: the limp joint sagged 1.07 rad (caught at the next tick by the tracking error); 0: it only
    # dropped its torque (caught by the next status poll, 5 Hz).
    proc = _start_play(emulator, _write_shape(tmp_path / "slow.json", [0.5 * (-1) ** i for i in range(12)]))
    try:
        _wait_for_goals(emulator, 15, proc)
        assert emulator.command(f"reboot 5 0.05 {jump_ticks}").startswith("ok")
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("sensnake play: error: servo 5 ")
    assert ("from its goal" if jump_ticks else "dropped its torque") in lines[0]
    assert "Traceback" not in out + err


def test_play_names_replies_held_on_this_computer_not_a_silent_servo(emulator, tmp_path):
    """`sensnake play` (the loop in its own process, a pty's whole reply timeout, ~0.29 s) while the emulator holds
    every reply for 4 s, then writes them at once (the kernel's tty worker on a busy PC, as seen for 2.3 s): one
    line naming the hold on this computer, never "no reply from servo"."""
    proc = _start_play(emulator, _write_shape(tmp_path / "slow.json", [0.5 * (-1) ** i for i in range(12)]))
    try:
        _wait_for_goals(emulator, 15, proc)
        assert emulator.command("hold 4").startswith("ok")
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out + err, err
    assert lines[0].startswith("sensnake play: error: the servos' replies came back "), err
    assert "held on this computer" in lines[0] and "not a silent servo" in lines[0] and "no reply from" not in err


def test_killing_the_bus_mid_play_is_one_line_never_a_traceback(tmp_path):
    for attempt in range(3):  # the traceback came in 2 runs of 4: the I/O call the kill lands in varies
        emulator = EmulatorProcess()
        proc = _start_play(emulator, _write_shape(tmp_path / "slow.json", [0.5 * (-1) ** i for i in range(12)]))
        try:
            _wait_for_goals(emulator, 10 + 7 * attempt, proc)
            assert emulator.command("kill") == "ok killed"
            out, err = proc.communicate(timeout=30)
        finally:
            proc.kill()
            emulator.close()
        assert proc.returncode == 1, (out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err, err
        assert lines[0].startswith("sensnake play: error: lost the link to the servo bus"), err


def test_torque_on_after_an_overload_and_reboot_holds_the_present_position(emulator):
    with ServoChain(robot_on(emulator.path)) as chain:
        chain.check_models()
        chain.set_torque(True)
        goal = np.zeros(12)
        goal[2] = 0.6
        chain.write_goals(goal)
        assert wait_until(lambda: abs(emulator.state(3)["position"] - emulator.state(3)["goal"]) <= 1)
        emulator.command("overload 3")
        with pytest.raises(ServoHardwareError, match="servo 3 overload"):
            chain.read_state()
        chain.reboot(3)  # the latched error cleared; the servo is limp
        emulator.command("push 3 -500")  # the limp joint sags while nobody holds it
        # Goals still go out (a motion, a hold) while it is limp: its goal register now holds 0.6 rad again.
        chain.write_goals(goal)
        assert emulator.state(3)["goal"] - emulator.state(3)["position"] >= 400
        chain.set_torque(True, [3])
        state = emulator.state(3)
        assert state["torque"] == 1 and abs(state["goal"] - state["position"]) <= 1  # holds where it sagged to


def test_a_scan_while_a_motion_plays_is_refused_with_the_reason(emulator):
    robot = robot_on(emulator.path)
    with running_controller(robot) as controller:
        source = FollowTheLeader([0.5] * 12, robot.axes, 0.05, 1, rate_hz=robot.control_rate_hz)
        playing = controller.play(source, "slow")
        assert wait_until(lambda: controller.motion_name == "slow")
        pings = emulator.counts()["ping"]
        with pytest.raises(BusBusyError, match=r"scan refused while motion 'slow' plays: .*~0\.8 s \(40 control"):
            controller.scan().result(10)
        assert emulator.counts()["ping"] == pings
        controller.stop_motion()
        assert playing.result(10) == "stopped"
        assert [i.servo_id for i in controller.scan(ids=range(1, 13)).result(10)] == list(range(1, 13))


def test_a_rate_the_bus_cannot_keep_is_refused_with_the_fix_before_it_starts(emulator, tmp_path, capsys):
    shape = _write_shape(tmp_path / "small.json", [0.1 * (-1) ** i for i in range(12)])
    # Factory Return Delay Time: 12 × (500 µs + 21 bytes) + the instruction + the goals' sync write ≈ 9.5 ms.
    assert main(["play", str(shape), "--robot", emulator.path, "--rate", "100", "--speed", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "100 Hz cannot be kept: a tick has 10.0 ms" in err[0] and "take 9.5 ms on the bus" in err[0]
    assert "set Return Delay Time to 0" in err[0] and "or run at ≤ 84 Hz" in err[0]
    assert emulator.counts()["sync_write"] == 0
    with ServoChain(robot_on(emulator.path)) as chain:
        chain.check_models()
        assert chain.rate_problem(50.0) is None
        verdict, message = chain.rate_problem(60.0)
        assert verdict == "warn" and "60 Hz leaves little room" in message


def test_with_return_delay_0_the_same_rate_plays(tmp_path, capsys):
    emulator = EmulatorProcess("--return-delay", "0")
    try:
        shape = _write_shape(tmp_path / "small.json", [0.1 * (-1) ** i for i in range(12)])
        # The point here is the rate check's verdict (no refusal, no rate warning), not the machine's: a tick whose
        # replies came late on a busy machine is play's other warning (once in CI: 1 of 22 ticks at 1 rad/s, 4.5 %,
        # over its 1 %), so the play is longer (0.2 rad at 0.1 rad/s, ~220 ticks) and that warning is not asserted.
        assert main(["play", str(shape), "--robot", emulator.path, "--rate", "100", "--speed", "0.1",
                     "--shifts", "1"]) == 0
        captured = capsys.readouterr()
        assert "finished" in captured.out
        assert "cannot be kept" not in captured.err and "little room" not in captured.err
        assert "Return Delay" not in captured.err
    finally:
        assert emulator.close() == 0


def test_a_health_read_given_up_at_its_deadline_never_feeds_its_late_replies_to_the_next_read(emulator):
    """The control loop gives a health read in a tick's slack a deadline (the next slot), so late replies (measured:
    bytes crossing the pty ~40 ms late) never hold a tick. The replies still come, later, in the middle of the next
    read: they are skipped (another length), never read as its data."""
    emulator.command("push 3 250")  # a joint away from the others, to recognise its value
    expected = np.array([(emulator.state(sid)["position"] - 2048) * 2 * np.pi / 4096 for sid in range(1, 13)])
    with ServoChain(robot_on(emulator.path)) as chain:
        chain.read_state()
        skipped = 0
        for _attempt in range(5):  # the late replies must arrive after the next instruction: a starved test may miss
            assert emulator.command("stall 0.015").startswith("ok")
            with pytest.raises(DeadlinePassedError, match=r"servos 1, 2, .*, 12 given up at the next control tick.s slot"):
                chain.read_health(supply=False, deadline_s=time.monotonic() + 0.003)
            state = chain.read_state()  # the 12 late health replies cross while this read waits for its own
            np.testing.assert_allclose(state.position_rad, expected, atol=0.02)
            skipped = chain._state_reader.stale_packets
            if skipped:
                break
        assert skipped == 12
        health = chain.read_health(supply=False)  # and health reads go on
        assert [h.servo_id for h in health] == list(range(1, 13)) and all(h.hardware_error == 0 for h in health)


def test_a_feedback_read_given_up_at_its_deadline_leaves_its_late_replies_out_of_the_next_read(emulator):
    """The control loop gives its feedback read a deadline (before the next slot), so replies the kernel hands over
    late never hold the next tick. The given-up read's replies still come; those in the port when the next
    instruction goes out are discarded and counted, and the next read returns the servos' present state, not the
    given-up read's."""
    reply_bytes = 12 * (11 + 10)  # 12 status packets of the 10-byte feedback block
    with ServoChain(robot_on(emulator.path)) as chain:
        chain.read_state()
        assert chain.late_bytes_discarded == 0
        assert emulator.command("stall 0.05").startswith("ok")
        with pytest.raises(DeadlinePassedError, match="given up at the control tick's deadline"):
            chain.read_state(deadline_s=time.monotonic() + 0.003)
        # Waited for the late replies themselves (written 50 ms after the instruction), not for a time.
        assert wait_until(lambda: chain._require_port().ser.in_waiting >= reply_bytes, 10.0), "no late replies"
        emulator.command("push 3 300")  # the joint moves after the given-up read answered
        expected = np.array([(emulator.state(sid)["position"] - 2048) * 2 * np.pi / 4096 for sid in range(1, 13)])
        state = chain.read_state()
        np.testing.assert_allclose(state.position_rad, expected, atol=0.02)
        assert chain.late_bytes_discarded == reply_bytes
        assert chain.late_replies_discarded == 12  # status packets, told from line noise by their header


def test_a_reply_late_while_connecting_is_asked_for_again_and_an_absent_servo_still_named(emulator, monkeypatch):
    """The reads made while connecting (the model check's pings, the timed cycles) wait a reply timeout; a reply held
    longer on this computer (the simulated lab's process or the tty worker behind other programs) is asked for again
    instead of failing the connection on a servo that is there. A servo that does not answer is named as before."""
    from devices import control_table as ct
    from devices import servo_chain

    asked: list[tuple] = []
    ping = ServoChain.ping
    monkeypatch.setattr(ServoChain, "ping", lambda self, sid: (asked.append(("ping", sid)), ping(self, sid))[1])
    with ServoChain(robot_on(emulator.path)) as chain:
        stall_s = 0.4  # past the pty's reply timeout (its wire time + 250 ms), under two of them
        assert emulator.command(f"stall {stall_s}").startswith("ok")  # the first ping's reply starts late
        chain.check_models()
        assert asked[:2] == [("ping", 1), ("ping", 1)] and sum(1 for a in asked if a == ("ping", 1)) == 2
        assert emulator.command(f"stall {stall_s} {ct.STATE_BLOCK_ADDRESS} 1").startswith("ok")
        cycle_s = chain.measure_cycle_s(3)
        assert cycle_s < 0.1, f"{cycle_s} s: the late read's time counted, not the answered one's"
        # A servo that is not there answers no asking: named, after CONNECT_ATTEMPTS of them.
        assert emulator.command("silent 5").startswith("ok")
        asked.clear()
        with pytest.raises(NoReplyError, match="servo 5"):
            chain.check_models()
        assert asked.count(("ping", 5)) == servo_chain.CONNECT_ATTEMPTS


def _time_health_reads(chain, monkeypatch, reads: list) -> None:
    """Record every ``chain.read_health`` as (called, returned, deadline_s, outcome) in ``reads``: answered, given up
    (its deadline passed) or timed out."""
    read_health = chain.read_health

    def timed_read_health(*args, deadline_s=None, **kwargs):
        called = time.monotonic()
        outcome = "answered"
        try:
            return read_health(*args, deadline_s=deadline_s, **kwargs)
        except DeadlinePassedError:
            outcome = "given up"
            raise
        except NoReplyError:
            outcome = "timed out"
            raise
        finally:
            reads.append((called, time.monotonic(), deadline_s, outcome))

    monkeypatch.setattr(chain, "read_health", timed_read_health)


def test_an_overdue_health_read_is_given_up_at_the_next_slot_and_read_again(emulator, monkeypatch):
    """An overdue health poll reads one servo per tick even without slack. When its replies are late (here the
    emulator answers the health block's reads 0.15 s late, as a busy PC's tty worker hands bytes over late), the read
    is given up before the next slot like the feedback read, counted, and made again in a later tick: no tick waits
    the read's reply timeout (~0.28 s on a pty), no servo is blamed, and the poll completes once replies are on
    time."""
    monkeypatch.setattr(controller_module, "HEALTH_MARGIN_S", 1.0)  # no chunk fits the slack: only overdue reads
    monkeypatch.setattr(controller_module, "HEALTH_OVERDUE_S", 0.0)  # every poll is overdue as it falls due
    robot = robot_on(emulator.path, status_rate_hz=5.0)
    errors: list[BaseException] = []
    polls: list[list] = []
    reads: list[tuple[float, float, float | None, str]] = []  # (called, returned, deadline_s, outcome)
    with ServoChain(robot) as chain:
        chain.check_models()
        _time_health_reads(chain, monkeypatch, reads)
        controller = RobotController(chain, robot, on_error=errors.append, on_health=polls.append)
        controller.start()
        try:
            assert wait_until(lambda: len(polls) >= 1, 15.0), "no health poll completed"
            start = len(reads)
            assert emulator.command("stall 0.15 64 3").startswith("ok")  # the next 3 health-block reads, late

            def late() -> list[tuple[float, float, float | None, str]]:  # the stalled reads: given up, or waited
                return [r for r in reads[start:] if r[3] != "answered" or r[1] - r[0] >= 0.1]

            assert wait_until(lambda: len(late()) >= 3, 15.0), reads[start:]
            polls_before = len(polls)
            assert wait_until(lambda: len(polls) > polls_before + 1, 15.0), "the polls did not complete again"
            stats = controller.stats()
        finally:
            controller.close()
    period_s = 1.0 / robot.control_rate_hz
    # Given up before the next slot, never waited for: without a deadline the overdue read held its tick until the
    # late replies came (0.15 s here: 7 missed ticks at 50 Hz), or its reply timeout (~0.28 s on a pty).
    assert all(r[2] is not None and r[2] - r[0] < period_s for r in reads[start:]), "a health read without deadline"
    assert all(outcome == "given up" and returned - called < 0.1 for called, returned, _, outcome in late()), late()
    assert stats.health_reads_given_up >= 3
    assert not errors, errors  # replies that came late blame no servo
    assert [h.servo_id for h in polls[-1]] == list(range(1, 13)) and all(h.hardware_error == 0 for h in polls[-1])


def test_the_alert_bits_health_read_is_given_up_at_the_next_slot_and_read_again(emulator, monkeypatch):
    """A status packet with the alert bit makes the loop read every servo's health to name the error. When that
    read's replies are late (here 0.15 s: a busy PC's tty worker), it is given up at the next slot like every other
    health read, counted, and made again in the next tick: no tick waits the late replies (or a pty's ~0.28 s reply
    timeout), nothing is written meanwhile, and the error is then named."""
    robot = robot_on(emulator.path, status_rate_hz=0.01)  # one scheduled poll at the start, then none for 100 s
    errors: list[BaseException] = []
    polls: list[list] = []
    reads: list[tuple[float, float, float | None, str]] = []  # (called, returned, deadline_s, outcome)
    with ServoChain(robot) as chain:
        chain.check_models()
        _time_health_reads(chain, monkeypatch, reads)
        controller = RobotController(chain, robot, on_error=errors.append, on_health=polls.append)
        controller.start()
        try:
            assert wait_until(lambda: len(polls) >= 1, 15.0), "the first health poll did not complete"
            playing = controller.play(HoldPose(np.zeros(12)), "hold")
            assert wait_until(lambda: controller.motion_name == "hold", 15.0)
            start = len(reads)
            assert emulator.command("stall 0.15 64 1").startswith("ok")  # the next health-block read, late
            assert emulator.command("overload 3").startswith("ok")
            error = playing.exception(timeout=15.0)
            stats = controller.stats()
        finally:
            controller.close()
    assert isinstance(error, ServoHardwareError) and error.servo_id == 3 and "overload" in str(error), error
    alert_reads = reads[start:]
    period_s = 1.0 / robot.control_rate_hz
    assert alert_reads and all(r[2] is not None and r[2] - r[0] < period_s for r in alert_reads), alert_reads
    given_up = [r for r in alert_reads if r[3] == "given up"]
    assert given_up and all(r[1] - r[0] < 0.1 for r in given_up), alert_reads  # never waited for the 0.15 s
    assert alert_reads[-1][3] == "answered"  # made again, and it named the error
    assert stats.health_reads_given_up >= 1
    assert errors == [error]


def _stopped_by(emulator: EmulatorProcess, robot: RobotConfig, fault: list[str],
                after_stop: tuple[str, ...] = (), errors: list[BaseException] | None = None,
                until: Callable[[], bool] | None = None) -> tuple[BaseException, list[str]]:
    """Play a held pose on the emulated chain, apply ``fault`` (emulator commands), then ``after_stop`` once the
    loop has stopped the motion on a quiet bus, and return the error that stopped the motion and the loop's
    events (``errors``: every error the loop reported, in order; ``until``: waited for before the loop is
    closed). The loop's reads wait a USB adapter's reply timeout (~37 ms), not a pty's (+250 ms), so that a test
    of the watchdog takes a second, not several."""
    errors = [] if errors is None else errors
    events: list[str] = []
    with ServoChain(robot) as chain:
        chain.check_models()  # with the pty's margin: a loaded machine may take longer than a USB timeout here
        chain._require_port()._extra_timeout_ms = 0.0
        controller = RobotController(chain, robot, on_error=errors.append, on_event=events.append)
        controller.start()
        try:
            assert wait_until(lambda: controller.stats().ticks >= 5, 15.0)
            playing = controller.play(HoldPose(np.zeros(12)), "hold")
            assert wait_until(lambda: controller.motion_name == "hold", 15.0)
            for line in fault:
                assert emulator.command(line).startswith("ok")
            if after_stop:
                assert wait_until(lambda: any(e.startswith("no reply byte on the servo bus") for e in events), 15.0)
                for line in after_stop:
                    assert emulator.command(line).startswith("ok")
            error = playing.exception(timeout=15.0)
            assert error is not None and wait_until(lambda: error in errors, 5.0)
            if until is not None:
                assert wait_until(until, 15.0), (errors, events)
        finally:
            controller.close()
    return error, events


def test_replies_held_on_this_computer_are_named_with_their_hold_never_as_a_silent_servo(emulator):
    """The kernel of a busy PC has held a port's received bytes for seconds (its tty worker at normal priority):
    no byte comes, the loop stops the motion, and then the replies it gave up on arrive together. The stop message
    names that (held on this computer, with the measured hold), not a silent servo. Here the emulator answers on
    time but holds every reply for 2 s and then writes them at once."""
    hold_s = 2.0
    error, events = _stopped_by(emulator, robot_on(emulator.path), [f"hold {hold_s}"])
    assert isinstance(error, RepliesHeldError), error
    message = str(error)
    assert "held on this computer" in message and "not a silent servo" in message and "motion stopped" in message
    assert "no reply from servo" not in message
    # Measured from the first unanswered read to the replies' arrival (seen at the next instruction or read).
    assert hold_s - 0.1 <= error.held_s <= hold_s + 1.0, error.held_s
    assert any(e.startswith("no reply byte on the servo bus") for e in events), events


def test_replies_held_longer_than_the_wait_correct_the_verdict_given(emulator, monkeypatch):
    """The replies held longer than the loop waits for them (here 3 s against a 0.5 s wait; the kernel's tty worker
    has held a pty's bytes for 2.3 s): the verdict given at the wait's end says what is known then (not a byte:
    the servos went quiet, or this computer holds the port's bytes), and when the held replies then arrive together
    the loop corrects it, naming the hold. The last word is "held on this computer", never only a cable."""
    monkeypatch.setattr(controller_module, "SILENCE_VERDICT_WAIT_S", 0.5)
    hold_s = 3.0
    errors: list[BaseException] = []
    error, events = _stopped_by(emulator, robot_on(emulator.path), [f"hold {hold_s}"], errors=errors,
                                until=lambda: any(isinstance(e, RepliesHeldError) for e in errors))
    assert isinstance(error, BusQuietError), error  # the stop, said when nothing had come yet
    assert "nor any other: not a byte on the bus" in str(error) and "this computer is holding" in str(error)
    last = errors[-1]
    assert isinstance(last, RepliesHeldError), errors
    assert "held on this computer" in str(last) and "not a silent servo" in str(last)
    assert 'this corrects the earlier "no reply from servo 1 nor any other" verdict' in str(last)
    assert hold_s - 0.1 <= last.held_s <= hold_s + 1.0, last.held_s
    assert errors.count(last) == 1 and len(errors) == 2, errors


def test_a_bus_that_goes_quiet_still_names_the_servo(emulator, monkeypatch):
    """No byte at all and none later (every servo silent: power or cable): after waiting for late replies, the
    servo is named as before."""
    monkeypatch.setattr(controller_module, "SILENCE_VERDICT_WAIT_S", 0.5)
    error, _ = _stopped_by(emulator, robot_on(emulator.path), ["silent all"])
    assert isinstance(error, NoReplyError) and error.servo_id == 1, error
    assert "no reply from servo 1" in str(error) and "not a byte on the bus" in str(error)


def test_a_quiet_bus_that_answers_again_without_the_late_replies_names_the_servo(emulator):
    """The servos stop answering, then answer again (power or a cable back) within the wait for late replies:
    fresh answers with none of the given-up reads' replies are no hold on this computer; the servo is named."""
    error, _ = _stopped_by(emulator, robot_on(emulator.path), ["silent all"],
                           after_stop=("answer all",))
    assert isinstance(error, NoReplyError) and error.servo_id == 1, error
    assert "the bus answers again" in str(error)


def test_instructions_never_wait_for_the_port_to_become_writable(emulator, monkeypatch):
    """pyserial's write (no write timeout) selects on the port after writing until it is writable again: on a pty
    that waits for the kernel's tty worker, which a busy PC holds off for tens of milliseconds. Instructions are
    handed over with one non-blocking write instead, so the control tick never waits there."""
    with ServoChain(robot_on(emulator.path)) as chain:
        port = chain._require_port()

        def waiting_write(data):
            raise AssertionError("pyserial's waiting write was used for an instruction")

        monkeypatch.setattr(port.ser, "write", waiting_write)
        state = chain.read_state()
        chain.write_goals(state.position_rad)
        assert emulator.counts()["sync_write"] >= 1 and emulator.counts()["sync_read"] >= 1


def _open_on(path: Path) -> int:
    """How many of this process's open files are ``path``."""
    fds = Path("/proc/self/fd")
    return sum(1 for fd in fds.iterdir() if os.path.realpath(fd) == str(path.resolve()))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PM QoS (/dev/cpu_dma_latency) is Linux's")
def test_on_a_real_port_the_loop_holds_the_cpus_wakeup_latency_at_0_while_it_runs(emulator, monkeypatch, tmp_path):
    device = tmp_path / "cpu_dma_latency"  # stands in for the kernel's device: what is written, and while open
    device.write_bytes(b"")
    monkeypatch.setattr(controller_module, "CPU_LATENCY_DEVICE", str(device))
    monkeypatch.setattr(controller_module, "_raise_thread_priority", lambda: "normal scheduling (test)")
    monkeypatch.setenv("SENSNAKE_REALTIME", "1")
    monkeypatch.delenv("SENSNAKE_CPU_LATENCY", raising=False)
    with running_controller(robot_on(emulator.path)) as controller:
        assert controller.wait_started(10.0)
        assert device.read_bytes() == struct.pack("i", 0)
        assert controller.scheduling == "normal scheduling (test); CPU idle states held shallow"
        assert _open_on(device) == 1
    assert _open_on(device) == 0  # the request ends with the loop

    device.write_bytes(b"")
    monkeypatch.setenv("SENSNAKE_CPU_LATENCY", "0")
    with running_controller(robot_on(emulator.path)) as controller:
        assert controller.wait_started(10.0)
        assert "CPU idle states not held (SENSNAKE_CPU_LATENCY=0)" in controller.scheduling
    assert device.read_bytes() == b""

    monkeypatch.delenv("SENSNAKE_CPU_LATENCY")
    monkeypatch.setattr(controller_module, "CPU_LATENCY_DEVICE", str(tmp_path / "missing"))
    with running_controller(robot_on(emulator.path)) as controller:
        assert controller.wait_started(10.0)
        rec_ticks = controller.stats().ticks
        assert wait_until(lambda: controller.stats().ticks > rec_ticks + 2, 10.0)  # it ticks anyway
        assert f"cannot open {tmp_path / 'missing'}" in controller.scheduling


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PM QoS (/dev/cpu_dma_latency) is Linux's")
def test_on_sim_the_cpus_wakeup_latency_is_held_only_while_a_motion_plays(monkeypatch, tmp_path):
    """The simulated lab runs whenever the app is open: idle CPUs that poll all that time would cost power for
    nothing, so on ``sim`` the request is held while a motion plays (when the loop's beat shows) and let go after."""
    from devices import factory
    from devices.sim.clock import SimClock
    from devices.sim.dxl_chain import ChainLab, VirtualChain

    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(controller_module, "CPU_LATENCY_DEVICE", str(device))
    monkeypatch.setattr(controller_module, "_raise_thread_priority", lambda: "normal scheduling (test)")
    monkeypatch.setenv("SENSNAKE_REALTIME", "1")
    monkeypatch.delenv("SENSNAKE_CPU_LATENCY", raising=False)
    robot = robot_on("sim")
    chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=SimClock(1.0), seed=3, return_delay_time=0)
    previous = factory.install_sim_lab(ChainLab(chain))
    try:
        with running_controller(robot) as controller:
            assert controller.wait_started(10.0)
            assert controller.scheduling == ("normal scheduling (test); CPU idle states to be held shallow while a "
                                             f"motion plays (write access to {device} checked)")
            ticks = controller.stats().ticks
            assert wait_until(lambda: controller.stats().ticks > ticks + 5, 10.0)
            assert _open_on(device) == 0  # connected, nothing playing: not held
            controller.set_torque(True).result(10)
            source = FollowTheLeader([0.3] * 12, robot.axes, 0.2, 1, rate_hz=robot.control_rate_hz)
            playing = controller.play(source, "wave")
            # (the bus thread opens the device, then writes the 0: wait for both)
            held = wait_until(lambda: (_open_on(device) == 1 and device.read_bytes() == struct.pack("i", 0))
                              or playing.done(), 10.0)
            assert held and not playing.done(), (_open_on(device), device.read_bytes())
            controller.stop_motion()
            assert playing.result(10) == "stopped"
            assert wait_until(lambda: _open_on(device) == 0, 10.0)  # let go when the motion ends
            assert controller.stats().ticks > 0
    finally:
        factory.install_sim_lab(previous)
    assert _open_on(device) == 0


@pytest.mark.parametrize("skew_bits", ["3", "400"], ids=["colliding", "one-after-the-other"])
def test_two_servos_on_one_id_are_named_by_scan_and_refused_at_connect_and_play(tmp_path, capsys, skew_bits):
    """The emulator's second servo set to ID 1 (once: scan exited 0 listing 11 servos, silent about it; play
    blamed "corrupt packet … check the bus wiring"). Its replies and its twin's collide on the wire (3 bits apart),
    or arrive whole one after the other (400 bits apart: the twin's Return Delay Time is longer)."""
    from devices.errors import DuplicateIdError

    emulator = EmulatorProcess("--ids", "1,1,3-12", "--twin-skew-bits", skew_bits)
    try:
        assert main(["scan", "--robot", emulator.path]) == 1
        captured = capsys.readouterr()
        assert "ID   1  ?  two servos answer" in captured.out and "ID   3  XM430" in captured.out
        error = [line for line in captured.err.splitlines() if line.startswith("sensnake scan: error")]
        assert len(error) == 1 and "servo ID 1" in error[0] and "same ID" in error[0], captured.err
        assert "ID(s) 2 do not answer" in error[0] and "power one servo at a time" in error[0]
        with ServoChain(robot_on(emulator.path)) as chain, pytest.raises(DuplicateIdError) as caught:
            chain.check_models()
        assert caught.value.collided == [1] and caught.value.missing == [2]
        shape = _write_shape(tmp_path / "small.json", [0.1 * (-1) ** i for i in range(12)])
        assert main(["play", str(shape), "--robot", emulator.path, "--speed", "1", "--shifts", "1"]) == 1
        err = capsys.readouterr().err
        assert "two servos are set to the same ID" in err and "wiring" not in err and "Traceback" not in err
    finally:
        assert emulator.close() == 0


def test_a_missing_configured_id_is_a_scan_warning_and_a_clean_bus_says_nothing(capsys):
    emulator = EmulatorProcess("--ids", "1-4,6-12")
    try:
        assert main(["scan", "--robot", emulator.path]) == 0
        captured = capsys.readouterr()
        assert captured.out.count("XM430") == 11
        assert "warning" in captured.err and "joint ID(s) 5 did not answer" in captured.err
    finally:
        assert emulator.close() == 0
    emulator = EmulatorProcess()
    try:
        assert main(["scan", "--robot", emulator.path]) == 0
        err = capsys.readouterr().err
        assert "warning" not in err and "error" not in err
    finally:
        assert emulator.close() == 0


def test_reads_confirming_a_silent_bus_wait_their_reply_timeout_across_ticks_not_inside_one(emulator, monkeypatch):
    """Once given-up reads add up to the watchdog's 0.2 s, the reads that follow must wait their whole reply timeout
    before a servo is named (a pty's: ~0.29 s, 14 slots at 50 Hz). They wait it across ticks: each tick's read or
    resumed read still has the tick's deadline, and a read is counted unanswered only once its timeout, from its own
    instruction, has passed -- the same evidence as before, without holding a tick for it."""
    monkeypatch.setattr(controller_module, "SILENCE_VERDICT_WAIT_S", 0.5)
    robot = robot_on(emulator.path)
    calls: list[tuple[str, float, float | None, bool, str]] = []  # (kind, called, deadline_s, kept, outcome)
    errors: list[BaseException] = []
    with ServoChain(robot) as chain:
        chain.check_models()
        read_state, resume = chain.read_state, chain.resume_state_read

        def traced(kind, fn):
            def call(*args, deadline_s=None, keep_in_flight=False, **kwargs):
                called, outcome = time.monotonic(), "answered"
                if kind == "read":
                    kwargs["keep_in_flight"] = keep_in_flight
                try:
                    return fn(*args, deadline_s=deadline_s, **kwargs)
                except Exception as exc:
                    outcome = type(exc).__name__
                    raise
                finally:
                    calls.append((kind, called, deadline_s, keep_in_flight, outcome))
            return call

        monkeypatch.setattr(chain, "read_state", traced("read", read_state))
        monkeypatch.setattr(chain, "resume_state_read", traced("resume", resume))
        controller = RobotController(chain, robot, on_error=errors.append)
        controller.start()
        try:
            playing = controller.play(HoldPose(np.zeros(12)), "hold")
            assert wait_until(lambda: controller.motion_name == "hold", 15.0)
            start = len(calls)
            assert emulator.command("silent all").startswith("ok")
            error = playing.exception(timeout=30.0)
        finally:
            controller.close()
    assert isinstance(error, NoReplyError) and error.servo_id == 1, error  # the quiet bus still names the servo
    after = calls[start:]
    period_s = 1.0 / robot.control_rate_hz
    # Every read and every resumed read had its tick's deadline: none waited a reply timeout inside one tick.
    assert after and all(c[2] is not None and c[2] - c[1] < period_s for c in after), after
    kept = [k for k, c in enumerate(after) if c[0] == "read" and c[3] and c[4] == "DeadlinePassedError"]
    timed_out = [k for k, c in enumerate(after) if c[0] == "resume" and c[4] == "NoReplyError"]
    assert len(timed_out) >= 2, after  # reads that waited their whole timeout across ticks, unanswered
    for k in timed_out:  # each counted unanswered only after its timeout, from its own instruction
        sent = max(j for j in kept if j < k)
        assert after[k][1] - after[sent][1] >= 0.25, (after[sent], after[k])
