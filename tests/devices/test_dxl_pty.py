"""The driver (ServoChain on dynamixel-sdk, pyserial) against the simulated chain served on a real pseudo-terminal
by a second process (``python -m devices.sim.pty_server``): real OS serial I/O and real pty timing."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from app.cli import main
from devices import control_table as ct
from devices.config import RobotConfig
from devices.controller import RobotController
from devices.errors import NoReplyError, ServoHardwareError
from devices.servo_chain import ServoChain

pytestmark = pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")),
                                reason="the pty server needs os.openpty (Linux or macOS)")


class PtyServer:
    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "devices.sim.pty_server", *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.path = self.proc.stdout.readline().strip()
        assert self.path.startswith("/dev/"), f"pty server did not start: {self.path!r}"

    def command(self, line: str) -> str:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline().strip()

    def close(self) -> int:
        self.proc.stdin.close()  # the server ends when its stdin closes
        try:
            return self.proc.wait(timeout=10)
        finally:
            self.proc.stdout.close()


@pytest.fixture
def pty_server():
    server = PtyServer("--device", "robot", "--seed", "4", "--speed", "5")
    try:
        yield server
    finally:
        assert server.close() == 0


def robot_on(path: str) -> RobotConfig:
    return dataclasses.replace(RobotConfig(), port=path)


def test_scan_sync_write_read_and_overload_over_a_pty(pty_server, read_until_at):
    with ServoChain(robot_on(pty_server.path)) as chain:
        found = chain.scan(ids=range(1, 15))
        assert [i.servo_id for i in found] == list(range(1, 13))
        assert {i.model_name for i in found} == {"XM430-W350"}
        chain.check_models()
        assert chain.latency_timer_ms() is None  # a pty has no USB latency timer
        chain.set_torque(True)
        goal = np.linspace(-0.5, 0.5, 12)
        chain.write_goals(goal)
        state = read_until_at(chain, goal)
        assert np.allclose(state.position_rad, goal, atol=3 * ct.RAD_PER_TICK)
        assert pty_server.command("overload 7") == "ok"
        with pytest.raises(ServoHardwareError, match="servo 7 overload"):
            chain.read_state()
        assert pty_server.command("no_reply 3") == "ok"
        with pytest.raises(NoReplyError, match="servo 3"):
            chain.ping(3)


class HoldForTicks:
    """Hold a pose for a number of ticks (not seconds: a loaded machine must not shorten the motion)."""

    def __init__(self, angles_rad, n_ticks):
        self.angles_rad, self.n_left = angles_rad, n_ticks

    def goal_at(self, t_s, present_rad):
        self.n_left -= 1
        return self.angles_rad if self.n_left >= 0 else None


def test_controller_runs_a_motion_over_a_pty(pty_server):
    robot = dataclasses.replace(robot_on(pty_server.path), control_rate_hz=30.0, max_joint_speed_rad_s=3.0)
    controller = RobotController(ServoChain(robot), robot)
    controller.start()
    try:
        controller.set_torque(True).result(10)
        assert controller.run_motion(HoldForTicks(np.full(12, 0.2), 10), "hold").result(10) == "finished"
        state = controller.latest_state
        assert state is not None and state.goal_rad is not None
        assert np.allclose(state.goal_rad, 0.2, atol=ct.RAD_PER_TICK)
    finally:
        controller.close()


def test_scan_command_over_a_pty(pty_server, capsys):
    assert main(["scan", "--robot", pty_server.path]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 12
    assert lines[0].split() == ["ID", "1", "XM430-W350", "(model", "1020)", "firmware", "46", "1000000", "bps"]


def test_scan_command_fails_with_one_line_when_nothing_answers(pty_server, capsys):
    assert main(["scan", "--robot", pty_server.path, "--baud", "57600"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"sensnake scan: error: no servo answered on {pty_server.path} at 57600 bps: check the servo "
                   "power and cable or try --all-bauds"]


@pytest.mark.parametrize("real_time", [True, False])
def test_a_real_time_bus_thread_never_selects_on_the_port(pty_server, monkeypatch, real_time):
    """select/poll on a tty first waits for the kernel's tty worker (normal priority) to hand over what it holds; a
    real-time thread must not wait behind it, so it sleeps and counts the port's bytes instead. A thread at normal
    priority keeps select (fewer wake-ups). Both read the same states."""
    from devices import servo_chain as servo_chain_module

    calls: list[float] = []
    real_select = servo_chain_module._FactoryPortHandler._select

    def counting_select(self, timeout_s):
        calls.append(timeout_s)
        return real_select(self, timeout_s)

    monkeypatch.setattr(servo_chain_module._FactoryPortHandler, "_select", counting_select)
    monkeypatch.setattr(servo_chain_module, "_real_time_thread", lambda: real_time)
    monkeypatch.setattr(servo_chain_module, "SELECT_SLACK_S", 1.0)  # every wait for a reply's bytes may select
    with ServoChain(robot_on(pty_server.path)) as chain:
        chain.scan(ids=range(1, 13))
        before = len(calls)
        for _ in range(20):
            positions = chain.read_state().position_rad
            assert positions.shape == (12,) and np.all(np.isfinite(positions))
        during = len(calls) - before
    if real_time:
        assert during == 0
    else:
        assert during > 0
