"""How ServoChain waits for replies: it sleeps until their bytes can first have crossed the wire (baud rate and each
servo's Return Delay Time from its control table), then waits for the missing bytes; it never polls the port and
never sleeps through a delay learned from earlier replies.

Every wake-up of the bus thread has to win the GIL back from the GUI thread, so the number of sleeps per transaction
is the cost that matters; these tests count them (``ServoChain.reply_wakeups``). The simulated chain runs at real
speed here, with the factory Return Delay Time (500 µs per reply), so the wire timings are the real ones.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from devices import factory
from devices.config import RobotConfig
from devices.errors import NoReplyError
from devices.servo_chain import ServoChain
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import ChainLab, VirtualChain

ROBOT = RobotConfig()
FACTORY_RETURN_DELAY = 250  # × 2 µs


@pytest.fixture
def servos():
    chain = VirtualChain(ids=ROBOT.joint_ids, baud=ROBOT.baud, clock=SimClock(1.0), seed=7,
                         return_delay_time=FACTORY_RETURN_DELAY)
    previous = factory.install_sim_lab(ChainLab(chain))
    try:
        with ServoChain(ROBOT) as servo_chain:
            yield servo_chain, chain
    finally:
        factory.install_sim_lab(previous)


def test_a_sync_read_costs_one_or_two_wakeups_once_the_return_delays_are_read(servos):
    chain, sim = servos
    chain.check_models()  # reads each servo's Return Delay Time
    assert chain.return_delays_s == {sid: pytest.approx(500e-6) for sid in ROBOT.joint_ids}
    before = chain.reply_wakeups
    n_reads = 10
    for _ in range(n_reads):
        state = chain.read_state()
    # Polling the port (the SDK's way) takes ~100 sleeps per 12-servo sync read at 1 Mbps.
    assert chain.reply_wakeups - before <= 2 * n_reads
    assert np.allclose(state.position_rad, sim.present_positions_rad(), atol=0.01)


def test_single_replies_and_health_reads_wait_without_polling(servos):
    chain, _ = servos
    chain.check_models()
    before = chain.reply_wakeups
    assert chain.read_item(5, "Return Delay Time") == FACTORY_RETURN_DELAY
    health = chain.read_health()  # two sync reads (status, supply)
    assert [h.servo_id for h in health] == list(ROBOT.joint_ids) and health[0].voltage_v == pytest.approx(12.0)
    assert chain.reply_wakeups - before <= 8


def test_a_silent_servo_still_times_out_by_name_with_few_wakeups(servos):
    chain, sim = servos
    chain.read_state()
    sim.set_no_reply(9)
    before = chain.reply_wakeups
    with pytest.raises(NoReplyError, match="servo 9"):
        chain.read_state()
    # The SDK's ~36 ms timeout is waited out without polling (100 µs polls would be ~300 sleeps).
    assert chain.reply_wakeups - before <= 60
    sim.set_no_reply(9, False)
    assert chain.read_state().position_rad.shape == (12,)


@pytest.mark.parametrize("clock_speed", [1.0, 20.0])
def test_no_sleep_is_planned_longer_than_the_replies_take(monkeypatch, clock_speed):
    # Regression: bytes seen right after the instruction once set the pace from the instruction's own wire time,
    # planning sleeps up to the SDK's 36 ms timeout for a 4 ms sync read.
    sim = VirtualChain(ids=ROBOT.joint_ids, baud=ROBOT.baud, clock=SimClock(clock_speed), seed=7, return_delay_time=0)
    previous = factory.install_sim_lab(ChainLab(sim))
    planned: list[float] = []
    real_sleep = time.sleep

    def recording_sleep(seconds: float) -> None:
        planned.append(seconds)
        real_sleep(seconds)

    sleeps_per_wait: list[int] = []  # one entry per time the driver found a reply incomplete and had to wait

    try:
        with ServoChain(ROBOT) as chain:
            chain.set_torque(True)
            port = chain._port
            real_wait = port._wait_for_bytes

            def counting_wait(n_bytes: int, reply_ids: tuple[int, ...]) -> None:
                before = len(planned)
                real_wait(n_bytes, reply_ids)
                sleeps_per_wait.append(len(planned) - before)

            monkeypatch.setattr(port, "_wait_for_bytes", counting_wait)
            monkeypatch.setattr(time, "sleep", recording_sleep)
            for _ in range(20):
                chain.read_state()  # back to back, with the bus idle when each starts (as in a control tick)
            monkeypatch.undo()
            cycle_s = chain.sync_read_time_s(12, 10)
    finally:
        factory.install_sim_lab(previous)
    assert max(planned, default=0.0) <= 1.5 * cycle_s
    if clock_speed == 1.0:
        # At real speed a missing reply is slept through, not polled: every wait sleeps, once or twice. This used
        # to assert ≥ 20 sleeps in 20 reads, which failed now and then on a loaded machine: a bus thread
        # descheduled for the ~2 ms of a sync read between writing the instruction and looking for the reply finds
        # it complete and rightly does not sleep at all. So count the sleeps per wait the driver actually entered.
        assert sleeps_per_wait, "no read ever waited for its reply: the simulated chain answered before the wire could"
        assert min(sleeps_per_wait) >= 1 and sum(sleeps_per_wait) <= 2 * len(sleeps_per_wait), sleeps_per_wait
    else:
        assert len(planned) <= 20  # a faster simulator has answered before the driver looks


def test_one_late_reply_costs_only_its_own_read(servos, monkeypatch):
    """The cause of in-app bursts of late ticks: one late reply taught the old driver a 2 ms per-reply gap that it
    slept through on each of the next ~32 sync reads (12 × 2 ms: ~28 ms ticks). Now no read after it plans a sleep
    longer than the bus time of a sync read."""
    chain, sim = servos
    chain.check_models()
    real_write = sim.host_write
    late = {"by_s": 0.0}

    def stamped_late(data: bytes, now_s: float) -> None:
        real_write(data, now_s + late["by_s"])
        late["by_s"] = 0.0

    sim.host_write = stamped_late
    for _ in range(3):
        chain.read_state()
    late["by_s"] = 0.015
    chain.read_state()  # its replies come 15 ms late
    planned: list[float] = []
    real_sleep = time.sleep

    def recording_sleep(seconds: float) -> None:
        planned.append(seconds)
        real_sleep(seconds)

    monkeypatch.setattr(time, "sleep", recording_sleep)
    for _ in range(10):
        chain.read_state()
    monkeypatch.undo()
    assert planned and max(planned) <= 1.05 * chain.sync_read_time_s(12, 10)
    assert chain.return_delays_s[ROBOT.joint_ids[0]] == pytest.approx(500e-6)  # nothing learned from the late one
