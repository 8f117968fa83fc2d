"""Servo bus timing on the simulated 12-servo chain at 1 Mbps (real-time simulated clock).

(a) one sync write + sync read cycle (ServoChain on dynamixel-sdk), with the factory Return Delay Time (500 µs)
    and with it set to 0;
(b) a 50 Hz RobotController loop's tick period over 60 s (10 s with --quick): p50/p99/max, missed ticks;
(c) the control loop at 50, 100 and 200 Hz holding a pose: period p50/p99 and missed ticks.

    python -m benchmarks.bench_servo_bus [--quick]

The virtual chain charges real wire time (10 bits per byte, return delay per reply), so these figures are what the
protocol costs plus this machine's scheduling; a U2D2 adds its USB latency (set latency_timer to 1 ms).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import threading
import time

import numpy as np

from devices import dxl_wire as wire
from devices import factory
from devices.config import RobotConfig
from devices.controller import HoldPose, RobotController
from devices.servo_chain import ServoChain
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import ChainLab, VirtualChain


def _install_chain(return_delay_time: int, robot: RobotConfig) -> tuple[VirtualChain, object]:
    chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=SimClock(1.0), seed=11,
                         return_delay_time=return_delay_time)
    return chain, factory.install_sim_lab(ChainLab(chain))


def bench_cycle(n_cycles: int) -> None:
    robot = RobotConfig()
    print(f"(a) one 12-servo sync write + sync read cycle at {robot.baud} bps ({n_cycles} cycles)")
    print(f"    {'return delay':>14} {'mean ms':>9} {'p50 ms':>9} {'p99 ms':>9} {'max ms':>9}")
    for delay in (250, 0):
        chain, previous = _install_chain(delay, robot)
        try:
            with ServoChain(robot) as servos:
                servos.set_torque(True)
                goal = np.zeros(robot.n_joints)
                times = np.empty(n_cycles)
                for i in range(n_cycles):
                    t0 = time.perf_counter()
                    servos.write_goals(goal)
                    servos.read_state()
                    times[i] = time.perf_counter() - t0
        finally:
            factory.install_sim_lab(previous)
        ms = times * 1e3
        print(f"    {delay * 2:>11} µs {ms.mean():9.2f} {np.percentile(ms, 50):9.2f} {np.percentile(ms, 99):9.2f} "
              f"{ms.max():9.2f}")


def _run_loop(rate_hz: float, seconds: float) -> tuple[dict, int]:
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=rate_hz)
    chain, previous = _install_chain(0, robot)
    done = threading.Event()
    try:
        controller = RobotController(ServoChain(robot), robot)
        controller.start()
        try:
            controller.set_torque(True).result(5)
            future = controller.run_motion(HoldPose(np.zeros(robot.n_joints), duration_s=seconds), "bench")
            future.add_done_callback(lambda _: done.set())
            done.wait(seconds + 10)
            stats = controller.stats()
        finally:
            controller.close()
    finally:
        factory.install_sim_lab(previous)
    return dataclasses.asdict(stats), chain.count(wire.SYNC_WRITE)


def bench_jitter(seconds: float) -> None:
    print(f"(b) 50 Hz control loop, {seconds:g} s (write + read every tick, return delay 0)")
    stats, writes = _run_loop(50.0, seconds)
    _print_stats_header()
    _print_stats(50.0, stats, writes)


def bench_rates(seconds: float) -> None:
    print(f"(c) control loop at several rates, {seconds:g} s each (return delay 0)")
    _print_stats_header()
    for rate in (50.0, 100.0, 200.0):
        stats, writes = _run_loop(rate, seconds)
        _print_stats(rate, stats, writes)


def _print_stats_header() -> None:
    print(f"    {'rate Hz':>8} {'ticks':>7} {'missed':>7} {'period p50':>11} {'p99':>7} {'max':>7} "
          f"{'jitter p50':>11} {'p99':>7} {'writes':>7}   (ms)")


def _print_stats(rate: float, s: dict, writes: int) -> None:
    ms = {k: v * 1e3 for k, v in s.items() if k.endswith("_s")}
    print(f"    {rate:8.0f} {s['ticks']:7d} {s['missed_ticks']:7d} {ms['period_p50_s']:11.2f} "
          f"{ms['period_p99_s']:7.2f} {ms['period_max_s']:7.2f} {ms['jitter_p50_s']:11.3f} "
          f"{ms['jitter_p99_s']:7.2f} {writes:7d}")


def run(quick: bool) -> None:
    print(f"machine load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    bench_cycle(100 if quick else 500)
    bench_jitter(10.0 if quick else 60.0)
    bench_rates(3.0 if quick else 10.0)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    run(parser.parse_args().quick)
