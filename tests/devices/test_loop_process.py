"""The control loop in its own process (devices.loop_process) against the independent XM430 emulator, itself in its
own process on a pty: play, STOP, named commands, errors as the same one-line messages as in-process, and a killed
loop process noticed at once. No timing assertions beyond a generous bound on noticing a death (the figure itself is
measured in benchmarks/bench_servo_bus)."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import signal
import sys
import threading
import time

import numpy as np
import pytest

from app.core.teach import _read_pose
from devices import bus_commands
from devices.bus_commands import bus_command
from devices.config import RobotConfig
from devices.controller import RobotController
from devices.errors import LinkLostError, LoopDiedError, LoopProcessUnavailable, RateError, ServoLostError
from devices.loop_process import HUNG_KILL_S, ControllerProcess, loop_process_wanted
from devices.realtime import BUS_THREAD_RT_PRIORITY
from devices.servo_chain import ServoChain
from models.trajectory import FollowTheLeader
from tests.emulators.xm430_emulator import EmulatorProcess
from tests.waiting import wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the emulator needs a pty (Linux)")

WAIT_S = 30.0  # subprocesses on a loaded 2-core machine
DEATH_NOTICED_BOUND_S = 5.0  # generous: the watcher reads the end of file at once (bench: a few ms)


class Recorder:
    """The callbacks, recorded (called from the watcher thread)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.states: list = []
        self.events: list[str] = []
        self.errors: list[tuple[float, BaseException]] = []
        self.health: list = []

    def callbacks(self) -> dict:
        return dict(on_state=self._state, on_health=self.health.append, on_event=self.events.append,
                    on_error=self._error)

    def _state(self, state) -> None:
        with self.lock:
            self.states.append(state)

    def _error(self, exc: BaseException) -> None:
        self.errors.append((time.monotonic(), exc))


def robot_on(path: str, **changes) -> RobotConfig:
    return dataclasses.replace(RobotConfig(), port=path, **changes)


def wave(robot: RobotConfig, amplitude: float, speed: float) -> FollowTheLeader:
    return FollowTheLeader([amplitude * (-1) ** i for i in range(12)], robot.axes, speed, 1,
                           rate_hz=robot.control_rate_hz)


@pytest.fixture
def child(emulator):
    robot = robot_on(emulator.path)
    recorder = Recorder()
    process = ControllerProcess(robot, **recorder.callbacks())
    process.start()
    try:
        yield process, recorder, robot
    finally:
        process.close()
    assert process._process.poll() is not None  # the child is gone after close


def test_the_loop_process_is_used_on_real_ports_only():
    assert loop_process_wanted("/dev/ttyUSB0") == (True, "")
    wanted, why = loop_process_wanted("sim")
    assert not wanted and "simulated lab" in why


def test_play_through_the_child_process_reaches_the_servos_and_reports_back(child, emulator):
    process, recorder, robot = child
    assert process.pid != os.getpid() and process.running and process.connected
    assert "scheduling" in process.scheduling
    assert any("Return Delay Time" in w for w in process.timing_warnings)  # read in the child at start
    source = wave(robot, 0.2, 1.0)
    assert process.play(source, "wave").result(WAIT_S) == "finished"
    assert source.progress.done  # the child's progress copied onto the caller's source
    # The servos hold the last goal written (nothing is written after "finished"), and the loop's states report
    # that goal and read back that position.
    final = np.array([(emulator.state(sid)["goal"] - 2048) * 2 * np.pi / 4096 for sid in range(1, 13)])
    assert all(emulator.state(sid)["torque"] == 1 for sid in range(1, 13))
    assert np.max(np.abs(final)) == pytest.approx(0.2, abs=2e-3)

    def reported() -> bool:
        last = process.latest_state
        return (last is not None and last.goal_rad is not None and np.allclose(last.goal_rad, final, atol=2e-3)
                and np.allclose(last.position_rad, final, atol=2e-3))

    assert wait_until(reported, WAIT_S)
    with recorder.lock:
        times = [s.host_time_s for s in recorder.states]
    assert len(times) > 10 and all(b > a for a, b in zip(times, times[1:]))  # every tick's state, in order
    assert "motion 'wave' started" in recorder.events and "motion 'wave' finished" in recorder.events
    stats = process.stats()
    assert stats.ticks >= len(times) - 1 and stats.sync_writes > 0


def test_stop_freezes_the_goals_in_the_child(child, emulator):
    process, recorder, robot = child
    playing = process.play(wave(robot, 0.5, 0.05), "slow")
    assert wait_until(lambda: emulator.counts()["sync_write"] >= 5, WAIT_S)
    process.emergency_stop()
    assert playing.result(WAIT_S) == "stopped"
    assert wait_until(lambda: any(e.startswith("emergency stop") for e in list(recorder.events)), WAIT_S)
    writes = emulator.counts()["sync_write"]
    ticks = process.ticks_seen
    assert wait_until(lambda: process.ticks_seen >= ticks + 10, WAIT_S)
    assert emulator.counts()["sync_write"] == writes  # nothing written after the freeze
    assert process.motion_name is None


def test_pause_resume_and_named_commands_run_in_the_child(child, emulator):
    process, recorder, robot = child
    pose = process.submit(bus_command(_read_pose)).result(WAIT_S)
    assert pose.angles_rad.shape == (12,)
    rows = process.submit(bus_command(bus_commands.link_check, [1, 2], rounds=2)).result(WAIT_S)
    assert [r.servo_id for r in rows] == [1, 2] and all(r.ok for r in rows)
    with pytest.raises(TypeError, match="named bus command"):
        process.submit(lambda chain: chain.ping(1)).result(WAIT_S)
    process.set_torque(False, [3]).result(WAIT_S)
    assert emulator.state(3)["torque"] == 0
    playing = process.play(wave(robot, 0.5, 0.05), "slow")
    assert wait_until(lambda: process.motion_name == "slow", WAIT_S)
    process.pause()
    assert wait_until(lambda: process.paused, WAIT_S)
    process.resume()
    assert wait_until(lambda: not process.paused, WAIT_S)
    process.stop_motion()
    assert playing.result(WAIT_S) == "stopped"
    assert [i.servo_id for i in process.scan(ids=range(1, 4)).result(WAIT_S)] == [1, 2, 3]


def test_a_device_error_at_start_is_raised_as_itself():
    emulator = EmulatorProcess()
    try:
        process = ControllerProcess(robot_on(emulator.path, control_rate_hz=100.0))
        with pytest.raises(RateError, match=r"100 Hz cannot be kept: .* set Return Delay Time to 0"):
            process.start()
        assert process._process.wait(WAIT_S) is not None
    finally:
        emulator.close()


def test_a_child_that_cannot_start_says_why(monkeypatch, emulator):
    monkeypatch.setattr(sys, "executable", "/nonexistent/python3")
    with pytest.raises(LoopProcessUnavailable, match="cannot start /nonexistent/python3"):
        ControllerProcess(robot_on(emulator.path)).start()


def test_killing_the_loop_process_mid_play_is_noticed_at_once_and_said_so(child, emulator):
    process, recorder, robot = child
    playing = process.play(wave(robot, 0.5, 0.05), "slow")
    assert wait_until(lambda: process.motion_name == "slow", WAIT_S)
    with recorder.lock:
        received = len(recorder.states)
    killed_at = time.monotonic()
    os.kill(process.pid, signal.SIGKILL)
    with pytest.raises(LoopDiedError) as caught:
        playing.result(WAIT_S)
    assert wait_until(lambda: recorder.errors, WAIT_S)
    noticed_at, error = recorder.errors[-1]
    assert error is caught.value  # one object: the bridge reports it once
    assert noticed_at - killed_at < DEATH_NOTICED_BOUND_S
    message = str(error)
    assert "\n" not in message and f"pid {process.pid}" in message and "killed by SIGKILL" in message
    assert "motion 'slow' stopped" in message and "Reconnect the robot" in message
    assert not process.running and not process.connected
    with pytest.raises(LoopDiedError):
        process.set_torque(True).result(WAIT_S)  # later commands fail at once with the same reason
    with recorder.lock:
        assert len(recorder.states) >= received  # what was received stays


def _fault_message(make_controller, emulator: EmulatorProcess, fault: str) -> BaseException:
    """Play a slow wave, inject ``fault`` into the emulator, return the error that stopped the motion."""
    controller, robot = make_controller()
    try:
        playing = controller.play(wave(robot, 0.5, 0.05), "slow")
        assert wait_until(lambda: emulator.counts()["sync_write"] >= 15, WAIT_S)
        assert emulator.command(fault).startswith("ok")
        with pytest.raises(Exception) as caught:  # noqa: PT011 - the type is compared below
            playing.result(WAIT_S)
        return caught.value
    finally:
        controller.close()


@pytest.mark.parametrize("fault", ["reboot 5 0.05 700", "kill"])
def test_errors_from_the_child_are_the_in_process_one_line_messages(fault):
    def in_process(emulator):
        def make():
            robot = robot_on(emulator.path)
            chain = ServoChain(robot)
            chain.open()
            chain.check_models()
            controller = RobotController(chain, robot)
            controller.start()
            return controller, robot
        return make

    def in_child(emulator):
        def make():
            robot = robot_on(emulator.path)
            controller = ControllerProcess(robot)
            controller.start()
            return controller, robot
        return make

    errors = []
    for factory in (in_process, in_child):
        emulator = EmulatorProcess()
        try:
            errors.append(_fault_message(factory(emulator), emulator, fault))
        finally:
            emulator.close()
    local, remote = errors
    assert type(remote) is type(local)
    assert isinstance(remote, ServoLostError if fault.startswith("reboot") else LinkLostError)
    shape = [re.sub(r"\d+(\.\d+)?", "N", str(e)) for e in errors]
    assert shape[0] == shape[1] and "\n" not in str(remote)
    if isinstance(remote, ServoLostError):
        assert remote.servo_id == 5 and str(remote).startswith("servo 5 ")


def test_a_hung_loop_process_is_reported_then_ended_and_said_so(child, emulator):
    """A child alive but not ticking (SIGSTOP: as hung as a process gets) is reported after a few of its periods,
    then killed after HUNG_KILL_S and reported as dead with the reason, so the user can reconnect."""
    process, recorder, robot = child
    pid = process.pid
    playing = process.play(wave(robot, 0.5, 0.05), "slow")
    assert wait_until(lambda: process.motion_name == "slow", WAIT_S)
    os.kill(pid, signal.SIGSTOP)
    try:
        assert wait_until(lambda: any("has not ticked" in e for e in list(recorder.events)), WAIT_S)
        stall = next(e for e in recorder.events if "has not ticked" in e)
        assert f"pid {pid}" in stall and "periods at 50 Hz" in stall and "ended if it stays silent" in stall
        with pytest.raises(LoopDiedError) as caught:
            playing.result(WAIT_S + HUNG_KILL_S)
        assert wait_until(lambda: recorder.errors, WAIT_S)
        error = recorder.errors[-1][1]
        assert error is caught.value
        message = str(error)
        assert "\n" not in message and f"pid {pid}" in message
        assert re.search(r"did not tick for \d+\.\d s; ended it", message), message
        assert "motion 'slow' stopped" in message and "servos hold their last goal" in message
        assert "Reconnect the robot" in message
        assert process._process.poll() is not None  # ended, not left stopped
        assert not process.running and not process.connected
        assert not any("ticks again" in e for e in recorder.events)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)


def test_a_stall_that_ends_is_said_so_and_the_loop_goes_on(child, emulator):
    process, recorder, _robot = child
    pid = process.pid
    os.kill(pid, signal.SIGSTOP)
    try:
        assert wait_until(lambda: any("has not ticked" in e for e in list(recorder.events)), WAIT_S)
    finally:
        os.kill(pid, signal.SIGCONT)
    assert wait_until(lambda: any("ticks again" in e for e in list(recorder.events)), WAIT_S)
    ticks = process.ticks_seen
    assert wait_until(lambda: process.ticks_seen > ticks + 10, WAIT_S)
    assert process.running and process.died is None and not recorder.errors


def test_a_loop_descheduled_mid_play_is_named_as_the_loop_not_as_a_servo(child, emulator):
    """The loop's process stopped for 300 ms in the middle of a play (a busy machine at its worst): the stall is
    reported as the loop's, with the machine's load, no servo is blamed and the play goes on to its end."""
    process, recorder, robot = child
    playing = process.play(wave(robot, 0.3, 0.5), "wave")
    assert wait_until(lambda: emulator.counts()["sync_write"] >= 5, WAIT_S)
    os.kill(process.pid, signal.SIGSTOP)
    # Deliberate: the loop process stays descheduled for 300 ms
    time.sleep(0.3)
    os.kill(process.pid, signal.SIGCONT)
    assert wait_until(lambda: any("ticks again" in e for e in list(recorder.events)), WAIT_S)
    stall = next(e for e in recorder.events if "has not ticked" in e)
    assert "control loop process" in stall and "load" in stall
    assert playing.result(WAIT_S) == "finished"
    assert not recorder.errors, recorder.errors


def test_bus_commands_that_hold_the_ticks_are_not_taken_for_a_hung_loop(child, emulator):
    """A scan of the whole bus (a broadcast ping waits its ~0.8 s window) and a reboot (waits for the servo to
    answer) hold the ticks far longer than the stall limit: announced in the heartbeat, they are not a stall."""
    process, recorder, _robot = child
    infos = process.scan().result(WAIT_S)  # every ID: one broadcast ping
    assert [i.servo_id for i in infos] == list(range(1, 13))
    process.reboot(5).result(WAIT_S)
    process.submit(bus_command(bus_commands.timing_warnings)).result(WAIT_S)
    ticks = process.ticks_seen
    assert wait_until(lambda: process.ticks_seen > ticks + 25, WAIT_S)
    # Each command makes one long period; if no other period reached the stall limit (a loaded machine can hold a
    # normal-priority loop that long by itself), there must have been no stall report.
    others = np.sort(process.recent_periods_s(4096))[:-3]
    assert others.size > 10
    if others.max() < process.stall_limit_s:
        assert not any("has not ticked" in e for e in recorder.events), recorder.events
    assert process.running and not recorder.errors


def test_a_watcher_held_up_here_is_not_taken_for_a_stalled_loop(emulator):
    """The app's side judges by the child's own tick times (the shared heartbeat), not by when its watcher ran: a
    subscriber that holds the watcher for 1 s is no stall of the loop."""
    recorder = Recorder()
    held = threading.Event()

    def slow_subscriber(state) -> None:
        if not held.is_set():
            held.set()
            # Deliberate: a subscriber that holds the watcher thread for a second (nothing else to wait on).
            time.sleep(1.0)
        recorder._state(state)

    callbacks = {**recorder.callbacks(), "on_state": slow_subscriber}
    process = ControllerProcess(robot_on(emulator.path), **callbacks)
    process.start()
    try:
        assert wait_until(held.is_set, WAIT_S)
        ticks = process.ticks_seen
        assert wait_until(lambda: process.ticks_seen > ticks + 60, WAIT_S)
        periods = process.recent_periods_s(4096)
        if periods.size and periods.max() < process.stall_limit_s:  # the child itself ticked throughout
            assert not any("has not ticked" in e for e in recorder.events), recorder.events
        assert process.running and not recorder.errors
    finally:
        process.close()


def _can_be_realtime() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (OSError, AttributeError):
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


@pytest.mark.skipif(not _can_be_realtime(), reason="real-time priority not permitted here")
def test_every_thread_of_the_loop_process_runs_at_the_loops_priority(emulator, monkeypatch):
    """A thread at normal priority in the loop's process (a BLAS pool started at numpy's import was one) is one the
    real-time bus thread can end up waiting for behind the machine's load."""
    monkeypatch.setenv("SENSNAKE_REALTIME", "1")
    recorder = Recorder()
    process = ControllerProcess(robot_on(emulator.path), **recorder.callbacks())
    process.start()
    try:
        assert wait_until(lambda: process.ticks_seen > 5, WAIT_S)
        policies = {}
        for task in os.listdir(f"/proc/{process.pid}/task"):
            with open(f"/proc/{process.pid}/task/{task}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            policies[int(task)] = (int(fields[38]), int(fields[37]))  # policy, real-time priority
        assert set(policies.values()) == {(os.SCHED_FIFO, BUS_THREAD_RT_PRIORITY)}, policies
    finally:
        process.close()


def test_a_motion_stopped_on_a_quiet_bus_is_said_stopped_before_its_cause_is_known(emulator):
    """Not a byte on the bus: the loop stops the motion at once (no more goals) and waits seconds for the replies it
    gave up on before it names the cause. The app hears of the stop at once (``on_motion_halted``), before the
    motion's Future fails with the cause, so the GUI never shows the motion running meanwhile."""
    robot = robot_on(emulator.path)
    recorder = Recorder()
    halted: list[tuple[str, bool]] = []
    process = ControllerProcess(robot, **recorder.callbacks(),
                                on_motion_halted=lambda name: halted.append((name, playing.done())))
    process.start()
    try:
        playing = process.play(wave(robot, 0.5, 0.05), "slow")
        assert wait_until(lambda: process.motion_name == "slow", WAIT_S)
        assert emulator.command("silent all").startswith("ok")
        assert wait_until(lambda: halted, WAIT_S), recorder.events
        assert halted == [("slow", False)]  # said while the cause was still open
    finally:
        process.close()
    assert playing.done() and playing.exception() is not None  # the cause (a quiet bus, the loop closed)
