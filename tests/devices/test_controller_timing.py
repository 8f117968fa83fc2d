"""RobotController timing policy: late ticks versus skipped slots, and health reads confined to the slack."""

from __future__ import annotations

import dataclasses
import gc
import os
import sys
import threading
import weakref

import numpy as np
import pytest

from devices import control_table as ct
from devices import controller as controller_module
from devices import factory
from devices.config import RobotConfig
from devices.controller import HoldPose, RobotController
from devices.realtime import SHORT_SLICE_S, time_slice_s
from devices.servo_chain import ServoChain
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import ChainLab, VirtualChain

WAIT_S = 10.0


class States:
    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.count = 0
        self.health: list[list] = []

    def on_state(self, _state) -> None:
        with self.cond:
            self.count += 1
            self.cond.notify_all()

    def on_health(self, health) -> None:
        with self.cond:
            self.health.append(health)
            self.cond.notify_all()

    def wait(self, predicate, what: str) -> None:
        with self.cond:
            assert self.cond.wait_for(predicate, WAIT_S), f"timed out waiting for {what}"

    def wait_more(self, n: int) -> None:
        target = self.count + n
        self.wait(lambda: self.count >= target, f"{n} more states")


def _run_controller(robot: RobotConfig, clock_speed: float, return_delay_time: int, read_delays: bool = False):
    """``read_delays``: the servos' Return Delay Times are read first, as the loop's start does (check_models),
    so each read's bus time is known."""
    chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=SimClock(clock_speed), seed=9,
                         return_delay_time=return_delay_time)
    previous = factory.install_sim_lab(ChainLab(chain))
    rec = States()
    servos = ServoChain(robot)
    if read_delays:
        servos.open()
        servos.read_return_delays()
    ctl = RobotController(servos, robot, on_state=rec.on_state, on_health=rec.on_health)
    ctl.start()
    return ctl, rec, chain, previous


def test_an_overrun_runs_the_next_tick_late_and_only_whole_slots_count_as_missed():
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=5.0)  # 200 ms slots: scheduler noise cannot blur
    ctl, rec, _, previous = _run_controller(robot, 20.0, 0)
    try:
        rec.wait_more(2)
        before = ctl.stats()
        # A bus command holding the thread (a stand-in for a slow transaction) through 1.25 slots: the next tick
        # runs at once, late; no slot passed without a tick.
        ctl.submit(lambda chain: threading.Event().wait(0.25)).result(WAIT_S)
        rec.wait_more(2)
        after_overrun = ctl.stats()
        assert after_overrun.missed_ticks == before.missed_ticks
        assert after_overrun.late_ticks >= before.late_ticks + 1
        # Through 2.5 slots: one slot went by entirely and is counted; the next is not caught up twice.
        ctl.submit(lambda chain: threading.Event().wait(0.5)).result(WAIT_S)
        rec.wait_more(2)
        after_stall = ctl.stats()
        assert after_stall.missed_ticks >= after_overrun.missed_ticks + 1
        assert after_stall.late_ticks >= after_overrun.late_ticks + 1
    finally:
        ctl.close()
        factory.install_sim_lab(previous)


def test_slots_skipped_while_a_command_holds_the_bus_on_purpose_are_counted_apart_and_not_warned_about():
    """A scan, a reboot or a link check holds the bus for whole periods on purpose: those slots go into held_ticks,
    not missed_ticks, and their long period is not kept (the timing warning counts missed_ticks only)."""
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=5.0)
    ctl, rec, _, previous = _run_controller(robot, 20.0, 0)
    try:
        rec.wait_more(2)
        before = ctl.stats()
        ctl.submit(lambda chain: threading.Event().wait(0.9), holds_bus=True).result(WAIT_S)  # ~4 slots held
        rec.wait_more(2)
        after = ctl.stats()
        assert after.missed_ticks == before.missed_ticks
        assert after.held_ticks >= before.held_ticks + 3
        assert after.period_max_s < 0.5, "the held period was kept in the loop's periods"
        # The same stall without the flag is the loop's own: missed, kept.
        ctl.submit(lambda chain: threading.Event().wait(0.5)).result(WAIT_S)
        rec.wait_more(2)
        assert ctl.stats().missed_ticks >= after.missed_ticks + 1 and ctl.stats().held_ticks == after.held_ticks
    finally:
        ctl.close()
        factory.install_sim_lab(previous)


def test_health_is_read_one_servo_per_tick_when_the_sync_cycle_leaves_no_slack(monkeypatch):
    monkeypatch.setattr(controller_module, "HEALTH_OVERDUE_S", 0.05)
    # Real-time wire with the factory 500 µs Return Delay Time: the state sync read alone takes ~9.5 ms of each
    # 10 ms tick, so no health read ever fits before the next deadline; an overdue poll reads one servo per tick.
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=100.0, status_rate_hz=5.0)
    ctl, rec, chain, previous = _run_controller(robot, 1.0, 250, read_delays=True)
    try:
        rec.wait(lambda: len(rec.health) >= 1, "a complete health poll")
    finally:
        ctl.close()
        factory.install_sim_lab(previous)
    assert [h.servo_id for h in rec.health[0]] == list(robot.joint_ids)
    assert rec.health[0][0].voltage_v == pytest.approx(12.0)  # the first poll reads the supply too
    health_reads = [ids for address, _, ids in chain.sync_reads()
                    if address in (ct.HEALTH_BLOCK_ADDRESS, ct.SUPPLY_BLOCK_ADDRESS)]
    assert len(health_reads) >= 2 * len(robot.joint_ids)
    assert all(len(ids) == 1 for ids in health_reads)


@pytest.mark.parametrize(("rate_hz", "return_delay_time", "fills_the_tick"), [(50.0, 0, False), (100.0, 250, True)])
def test_a_feedback_read_is_given_up_before_the_next_slot_but_not_before_its_bus_time(rate_hz, return_delay_time,
                                                                                      fills_the_tick):
    """The feedback read is given up in time for the tick to write its goals before the next slot, but never sooner
    than twice its own bus time after it starts: at a rate that only just fits (the sync read alone ~9.5 ms of a
    10 ms tick with the factory Return Delay Time) replies on time are read, not given up every tick."""
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=rate_hz)
    chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=SimClock(20.0), seed=9,
                         return_delay_time=return_delay_time)
    previous = factory.install_sim_lab(ChainLab(chain))
    try:
        with ServoChain(robot) as servos:
            servos.read_return_delays()  # as the loop's start does (check_models): the reads' bus time is known
            ctl = RobotController(servos, robot)  # not started: the rule only
            n = len(robot.joint_ids)
            read_s = servos.sync_read_time_s(n, ct.STATE_BLOCK_SIZE)
            period_s = 1.0 / rate_hz
            deadline = ctl._feedback_deadline_s(100.0, 100.0 + period_s)
    finally:
        factory.install_sim_lab(previous)
    slot_rule = 100.0 + period_s - controller_module.FEEDBACK_DEADLINE_MARGIN_S - servos.sync_write_time_s(n)
    assert (read_s > 0.5 * period_s) == fills_the_tick
    if fills_the_tick:
        assert deadline == pytest.approx(100.0 + 2.0 * read_s)
    else:
        assert deadline == pytest.approx(slot_rule)  # in time to write the goals before the next slot


def test_health_is_read_in_one_go_when_the_tick_has_time_for_it():
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=50.0, status_rate_hz=10.0)
    ctl, rec, chain, previous = _run_controller(robot, 20.0, 0)  # a fast wire: the sync cycle is ~0.3 ms
    try:
        rec.wait(lambda: len(rec.health) >= 3, "three health polls")
    finally:
        ctl.close()
        factory.install_sim_lab(previous)
    assert all([h.servo_id for h in health] == list(robot.joint_ids) for health in rec.health)
    status_reads = [ids for address, _, ids in chain.sync_reads() if address == ct.HEALTH_BLOCK_ADDRESS]
    assert any(len(ids) == len(robot.joint_ids) for ids in status_reads)


def _bus_thread_policy(ctl: RobotController, rec: States) -> int:
    rec.wait_more(1)  # the thread has set its scheduling before its first tick
    return os.sched_getscheduler(ctl._thread.native_id)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread scheduling is Linux's")
def test_the_bus_thread_gets_real_time_priority_when_permitted_and_says_which_it_got(monkeypatch):
    monkeypatch.setenv("SENSNAKE_REALTIME", "1")  # tests/conftest.py turns it off for the rest of the suite
    ctl, rec, _, previous = _run_controller(RobotConfig(), 1.0, 0)
    try:
        policy = _bus_thread_policy(ctl, rec)
        if ctl.scheduling.startswith("real-time"):
            assert policy == os.SCHED_FIFO
            assert os.sched_getparam(ctl._thread.native_id).sched_priority == controller_module.BUS_THREAD_RT_PRIORITY
        else:
            assert policy == os.SCHED_OTHER and "no privilege" in ctl.scheduling
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # only the bus thread: not the caller, not the process
    finally:
        ctl.close()
        factory.install_sim_lab(previous)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread scheduling is Linux's")
@pytest.mark.parametrize("short_slice", ["1", "0"])
def test_sensnake_realtime_0_keeps_normal_scheduling(monkeypatch, short_slice):
    monkeypatch.setenv("SENSNAKE_REALTIME", "0")
    monkeypatch.setenv("SENSNAKE_SHORT_SLICE", short_slice)
    ctl, rec, _, previous = _run_controller(RobotConfig(), 1.0, 0)
    try:
        assert _bus_thread_policy(ctl, rec) == os.SCHED_OTHER
        slice_s = time_slice_s(ctl._thread.native_id)
        if short_slice == "0":  # the kernel's default slice, and the words say nothing of one
            assert ctl.scheduling == "normal scheduling (SENSNAKE_REALTIME=0)"
            assert slice_s is None or slice_s > SHORT_SLICE_S
        else:  # Linux 6.12+ grants the short slice without privilege; then the thread has it and says so
            assert ctl.scheduling.startswith("normal scheduling") and "(SENSNAKE_REALTIME=0)" in ctl.scheduling
            if "time slice" in ctl.scheduling:
                assert slice_s == pytest.approx(SHORT_SLICE_S)
            else:
                assert slice_s is None or slice_s > SHORT_SLICE_S
    finally:
        ctl.close()
        factory.install_sim_lab(previous)


def test_without_the_privilege_the_loop_runs_with_normal_scheduling_and_says_how_to_allow_it(monkeypatch):
    def refuse(*_args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setenv("SENSNAKE_REALTIME", "1")
    monkeypatch.setattr(os, "sched_setscheduler", refuse, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    ctl, rec, _, previous = _run_controller(RobotConfig(), 1.0, 0)
    try:
        rec.wait_more(2)  # it ticks anyway
        assert ctl.scheduling.startswith("normal scheduling") and "(no privilege for real-time priority" in ctl.scheduling
        assert "rtprio" in ctl.scheduling
    finally:
        ctl.close()
        factory.install_sim_lab(previous)


class _Cycle:
    def __init__(self) -> None:
        self.me = self


def test_objects_alive_when_the_loop_starts_are_skipped_by_the_collector_until_the_last_loop_stops():
    # A full collection in the running app held the interpreter 190-350 ms (a missed tick); objects older than the
    # loop are left out of collections while a loop runs, and handed back when the last one stops.
    assert gc.get_freeze_count() == 0
    old = _Cycle()
    old_ref = weakref.ref(old)
    first, rec1, _, previous = _run_controller(RobotConfig(), 1.0, 0)
    try:
        rec1.wait_more(1)
        del old
        gc.collect()
        assert old_ref() is not None  # frozen: the collector skipped it
        young = _Cycle()
        young_ref = weakref.ref(young)
        del young
        gc.collect()
        assert young_ref() is None  # garbage made while the loop runs is collected as usual
        built_later = _Cycle()  # e.g. a tab built after connecting, alive when a motion starts
        later_ref = weakref.ref(built_later)
        first.run_motion(HoldPose(np.zeros(12), duration_s=0.01), "hold").result(WAIT_S)
        del built_later
        gc.collect()
        assert later_ref() is not None
        second = RobotController(ServoChain(RobotConfig()), RobotConfig())
        second.start()
        second.close()
        assert gc.get_freeze_count() > 0  # the first loop still runs
    finally:
        first.close()
        factory.install_sim_lab(previous)
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert old_ref() is None and later_ref() is None
