"""ServoChain (dynamixel-sdk driver) against the simulated chain, through devices.factory's ``sim`` port."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

from devices import control_table as ct
from devices import dxl_wire as wire
from devices import factory
from devices.config import RobotConfig
from devices.errors import (
    CorruptPacketError,
    DeadlinePassedError,
    LinkLostError,
    ModelMismatchError,
    NoReplyError,
    PortOpenError,
    ServoCommandError,
    ServoHardwareError,
)
from devices.servo_chain import ServoChain
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import ChainLab, VirtualChain

ROBOT = RobotConfig()


@pytest.fixture
def sim_chain():
    chain = VirtualChain(ids=ROBOT.joint_ids, baud=ROBOT.baud, clock=SimClock(20.0), seed=3)
    previous = factory.install_sim_lab(ChainLab(chain))
    yield chain
    factory.install_sim_lab(previous)


@pytest.fixture
def servos(sim_chain):
    with ServoChain(ROBOT) as chain:
        yield chain


def test_scan_short_id_list_pings_each(servos, sim_chain):
    found = servos.scan(ids=range(0, 15))
    assert [info.servo_id for info in found] == list(ROBOT.joint_ids)
    assert {(i.model_number, i.model_name, i.firmware, i.baud) for i in found} == {(1020, "XM430-W350", 46, 1_000_000)}
    assert sim_chain.count(wire.PING) >= 15


def test_scan_all_ids_uses_one_broadcast_ping_per_baud(servos, sim_chain):
    servos.write_item(12, "Baud Rate", 1)  # servo 12 now listens at 57600 bps
    found = servos.scan(bauds=[1_000_000, 57_600])
    assert [(i.servo_id, i.baud) for i in found] == [(12, 57_600)] + [(i, 1_000_000) for i in range(1, 12)]
    # One broadcast per baud, then each servo found pinged on its own once (a broadcast reply per ID cannot show two
    # servos on one ID; a ping followed by a second reply can): no search of the silent IDs.
    assert sim_chain.count(wire.PING) == 2 + 12
    assert servos.baud == 1_000_000  # the port is back at the configured rate
    assert servos.ping(1).servo_id == 1


def test_check_models_names_the_odd_servo(sim_chain):
    odd = VirtualChain(ids=(1, 2), baud=1_000_000, clock=SimClock(20.0), seed=1, model_number=1060)
    factory.install_sim_lab(ChainLab(odd))
    robot = dataclasses.replace(ROBOT, joint_ids=(1, 2), axes=("pitch", "yaw"), signs=(1, 1),
                                zero_offsets_rad=(0.0, 0.0), joint_min_rad=(-1.0, -1.0), joint_max_rad=(1.0, 1.0))
    with ServoChain(robot) as chain, pytest.raises(ModelMismatchError, match=r"servo 1 is a XL430-W250 \(model 1060\)"):
        chain.check_models()


def test_a_reply_left_on_the_line_from_before_the_port_opened_is_not_taken_for_a_servos_model(servos, sim_chain,
                                                                                              monkeypatch):
    """CI once read servo 1 as "model 120" when a control loop reopened the emulator's port: a status packet of the
    session before (a read's reply, 120 in its two data bytes) came in as the ping's reply. check_models first drops
    what still arrives on the line, and asks a servo whose model is wrong once more before refusing it."""
    from devices.sim.dxl_chain import _Chunk

    stale = wire.build_status(1, 0, (120).to_bytes(2, "little"))  # valid, from servo 1, not a ping's reply
    sim_chain._outgoing.append(_Chunk(time.monotonic() + 0.001, 1e-9, stale))  # arriving just after the open
    servos.check_models()  # dropped before the first ping: no DuplicateIdError, no "model 120"
    real_ping, answers = servos.ping, []

    def ping_once_stale(sid):
        info = real_ping(sid)
        answers.append(sid)
        return dataclasses.replace(info, model_number=120) if answers.count(sid) == 1 and sid == 1 else info

    monkeypatch.setattr(servos, "ping", ping_once_stale)
    servos.check_models()  # the wrong model once: asked again, right
    assert answers.count(1) == 2 and answers.count(2) == 1


def test_ticks_and_angles_follow_spec_section_2():
    robot = dataclasses.replace(ROBOT, signs=(-1,) + (1,) * 11, zero_offsets_rad=(0.1,) + (0.0,) * 11)
    chain = ServoChain(robot)
    ticks = np.array([2048 + 1024] + [2048] * 11)
    angles = chain.angles_from_ticks(ticks)
    assert angles[0] == pytest.approx(-math.pi / 2 + 0.1)
    assert angles[1] == 0.0
    assert np.array_equal(chain.ticks_from_angles(angles), ticks)


def test_write_goals_clamps_before_sending(servos, sim_chain):
    servos.set_torque(True)  # one sync write of goals := present positions first (nothing jumps)
    assert sim_chain.count(wire.SYNC_WRITE) == 1
    goal = np.linspace(-3.0, 3.0, 12)
    sent = servos.write_goals(goal)
    assert np.all(sent >= np.array(ROBOT.joint_min_rad)) and np.all(sent <= np.array(ROBOT.joint_max_rad))
    assert sent[0] == pytest.approx(-1.57, abs=ct.RAD_PER_TICK)
    assert sent[-1] == pytest.approx(1.57, abs=ct.RAD_PER_TICK)
    assert np.array_equal(sim_chain.goal_positions_ticks(), servos.ticks_from_angles(sent))
    assert sim_chain.count(wire.SYNC_WRITE) == 2
    with pytest.raises(ValueError, match="joint 3"):
        servos.write_goals(np.where(np.arange(12) == 2, np.nan, 0.0))
    assert sim_chain.count(wire.SYNC_WRITE) == 2


def test_read_state_is_one_sync_read_and_tracks_the_servos(servos, sim_chain):
    servos.set_torque(True)
    goal = np.full(12, 0.4)
    servos.write_goals(goal)
    reads_before = sim_chain.count(wire.SYNC_READ)
    state = servos.read_state()
    assert sim_chain.count(wire.SYNC_READ) == reads_before + 1
    assert state.position_rad.shape == state.velocity_rad_s.shape == state.current_ma.shape == (12,)
    for _ in range(200):  # the servos move at most 4.8 rad/s on a 20× clock
        state = servos.read_state()
        if np.allclose(state.position_rad, goal, atol=3 * ct.RAD_PER_TICK) and not state.velocity_rad_s.any():
            break
    assert np.allclose(state.position_rad, goal, atol=3 * ct.RAD_PER_TICK)
    assert np.allclose(state.position_rad, sim_chain.present_positions_rad(), atol=2 * ct.RAD_PER_TICK)


def test_limp_joint_posed_by_hand_reads_back_to_the_tick(servos, sim_chain):
    sim_chain.set_limp_position(5, 2048 + 300)
    state = servos.read_state()
    assert state.position_rad[4] == pytest.approx(300 * ct.RAD_PER_TICK)
    servos.set_torque(True, ids=[5])
    with pytest.raises(ValueError, match="torque on"):
        sim_chain.set_limp_position(5, 2048)


def test_overload_raises_hardware_error_naming_servo(servos, sim_chain):
    servos.set_torque(True)
    sim_chain.inject_overload(7)
    with pytest.raises(ServoHardwareError, match="servo 7 overload") as info:
        servos.read_state()
    assert info.value.servo_id == 7 and info.value.error_names == ("overload",)
    state = servos.read_state(raise_on_alert=False)
    assert state.alert_ids == (7,)
    health = {h.servo_id: h for h in servos.read_health()}
    assert health[7].error_names == ("overload",) and not health[7].torque_on
    assert health[6].hardware_error == 0 and health[6].torque_on and health[6].voltage_v == pytest.approx(12.0)
    with pytest.raises(ServoHardwareError, match="servo 7"):
        servos.set_torque(True, ids=[7])
    servos.reboot(7)
    assert servos.read_state().alert_ids == ()


def test_silent_servo_raises_no_reply_naming_it(servos, sim_chain):
    sim_chain.set_no_reply(9)
    with pytest.raises(NoReplyError, match="no reply from servo 9") as info:
        servos.read_state()
    assert info.value.servo_id == 9
    with pytest.raises(NoReplyError, match="servo 9"):
        servos.ping(9)


def test_corrupt_reply_raises_corrupt_packet_error(servos, sim_chain):
    sim_chain.corrupt_next_replies(1, servo_id=4)
    with pytest.raises(CorruptPacketError, match="servo 4"):
        servos.read_state()
    servos.read_state()  # the next cycle is clean


def test_eeprom_write_with_torque_on_is_refused(servos):
    servos.set_torque(True, ids=[2])
    with pytest.raises(ServoCommandError, match="servo 2 refused .*access error.*torque off"):
        servos.set_return_delay(0, ids=[2])
    servos.set_torque(False, ids=[2])
    servos.set_return_delay(0, ids=[2])
    assert servos.read_item(2, "Return Delay Time") == 0


def test_timing_warnings_name_the_fix(servos):
    warnings = servos.timing_warnings()
    assert len(warnings) == 1 and "Return Delay Time is up to 500 µs" in warnings[0]
    assert "set it to 0" in warnings[0]
    assert "ServoChain" not in warnings[0] and "Set return delay to 0 µs" in warnings[0]  # what to do in the app
    servos.set_return_delay(0)
    assert servos.timing_warnings() == []  # sim: no USB latency timer to check
    assert servos.latency_timer_ms() is None


def test_slow_cycle_is_flagged_against_the_control_rate(sim_chain):
    slow = dataclasses.replace(ROBOT, baud=57_600, control_rate_hz=200.0)
    with ServoChain(ROBOT) as chain:
        for sid in ROBOT.joint_ids:
            chain.write_item(sid, "Baud Rate", 1)
    with ServoChain(slow) as chain:
        warnings = chain.timing_warnings()
    assert any("leaves 5.0 ms per tick" in w for w in warnings)


def test_pulled_cable_is_link_lost_then_reopens(servos, sim_chain):
    sim_chain.disconnect()
    with pytest.raises(LinkLostError, match="lost the link"):
        servos.read_state()
    servos.close()
    with pytest.raises(PortOpenError):
        servos.open()
    sim_chain.reconnect()
    servos.open()
    assert servos.read_state().position_rad.shape == (12,)


def test_scan_repeats_a_broadcast_ping_whose_reply_was_corrupt(servos, sim_chain):
    sim_chain.corrupt_next_replies(1, servo_id=6)
    found = servos.scan()
    assert [info.servo_id for info in found] == list(ROBOT.joint_ids)
    assert sim_chain.count(wire.PING) == 2 + 11  # two broadcasts, and the 11 found first each checked on its own


def test_latency_timer_above_1_ms_is_flagged_with_the_fix(tmp_path, monkeypatch):
    from devices import servo_chain

    (tmp_path / "ttyUSB7").mkdir()
    (tmp_path / "ttyUSB7" / "latency_timer").write_text("16\n")
    monkeypatch.setattr(servo_chain, "LATENCY_TIMER_DIR", tmp_path)
    monkeypatch.setattr(servo_chain.sys, "platform", "linux")
    chain = ServoChain(dataclasses.replace(ROBOT, port="/dev/ttyUSB7"))
    assert chain.latency_timer_ms() == 16
    assert chain.latency_warning() == (
        f"USB latency timer of /dev/ttyUSB7 is 16 ms (each reply waits up to that long): "
        f"fix with `echo 1 | sudo tee {tmp_path / 'ttyUSB7' / 'latency_timer'}`")
    (tmp_path / "ttyUSB7" / "latency_timer").write_text("1\n")
    assert chain.latency_warning() is None
    assert ServoChain(ROBOT).latency_warning() is None  # sim: no adapter


def test_signs_and_zero_offsets_reach_the_servo_ticks(sim_chain):
    robot = dataclasses.replace(ROBOT, signs=(-1,) + (1,) * 11, zero_offsets_rad=(0.2,) + (0.0,) * 11,
                                joint_min_rad=(-1.0,) * 12, joint_max_rad=(1.0,) * 12)
    with ServoChain(robot) as chain:
        sent = chain.write_goals(np.array([0.5, 2.0] + [0.0] * 10))
        ticks = sim_chain.goal_positions_ticks()
        assert ticks[0] == round(2048 - 0.3 / ct.RAD_PER_TICK)  # mirrored about the 0.2 rad zero
        assert ticks[1] == math.floor(2048 + 1.0 / ct.RAD_PER_TICK)  # clamped inside +1.0 rad
        assert sent[1] <= 1.0 and sent[0] == pytest.approx(0.5, abs=ct.RAD_PER_TICK)
        sim_chain.set_limp_position(1, ticks[0])
        assert chain.read_state().position_rad[0] == pytest.approx(0.5, abs=ct.RAD_PER_TICK)


def test_health_without_supply_reuses_the_last_voltage_and_temperature(servos, sim_chain):
    assert math.isnan(servos.read_health([1], supply=False)[0].voltage_v)
    assert servos.read_health([1])[0].voltage_v == pytest.approx(12.0)
    sim_chain.set_supply_voltage(11.0)
    reads = sim_chain.count(wire.SYNC_READ)
    assert servos.read_health([1], supply=False)[0].voltage_v == pytest.approx(12.0)
    assert sim_chain.count(wire.SYNC_READ) == reads + 1
    assert servos.read_health([1])[0].voltage_v == pytest.approx(11.0)


def _chain_at(speed: float):
    """A simulated chain on a clock ``speed`` times real time, installed as the ``sim`` port."""
    return VirtualChain(ids=ROBOT.joint_ids, baud=ROBOT.baud, clock=SimClock(speed), seed=3)


def test_late_replies_of_a_given_up_read_never_make_a_real_time_device_look_faster_than_the_wire():
    """At real time the replies of a health read given up at its deadline cross right after the next instruction,
    before it could have left the wire. Taken as a device faster than the wire (as before), every later read was
    awaited at an extrapolated pace that waited out the SDK's timeout: the ~39 ms ticks on ``sim`` at 100 Hz."""
    previous = factory.install_sim_lab(ChainLab(_chain_at(1.0)))
    try:
        with ServoChain(ROBOT) as chain:
            chain.read_state()
            goals = chain.read_state().position_rad
            for _ in range(10):
                with pytest.raises(DeadlinePassedError):
                    chain.read_health(supply=False, deadline_s=time.monotonic() + 0.0005)
                chain.write_goals(goals)  # the loop's order: the next tick writes its goals, then reads
                chain.read_state()
                assert not chain.replies_paced_by_device
    finally:
        factory.install_sim_lab(previous)


def test_a_device_wrongly_taken_as_faster_than_the_wire_is_found_out_and_waited_for_at_wire_pace():
    previous = factory.install_sim_lab(ChainLab(_chain_at(1.0)))
    try:
        with ServoChain(ROBOT) as chain:
            chain._port.faster_than_wire = True
            for _ in range(3):
                chain.read_state()
            assert not chain.replies_paced_by_device
    finally:
        factory.install_sim_lab(previous)


@pytest.mark.parametrize("speed", [5.0, 20.0])
def test_an_accelerated_simulator_is_found_to_pace_its_own_replies(speed):
    previous = factory.install_sim_lab(ChainLab(_chain_at(speed)))
    try:
        with ServoChain(ROBOT) as chain:
            chain.read_return_delays()  # as the app and the CLI do when they connect (the rate check)
            for _ in range(400):  # a starved test may need a few of the port's early looks (every 16th read)
                chain.read_state()
                if chain.replies_paced_by_device:
                    break
            assert chain.replies_paced_by_device
    finally:
        factory.install_sim_lab(previous)
