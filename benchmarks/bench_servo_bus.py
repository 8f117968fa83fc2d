"""Servo bus timing on the simulated 12-servo chain at 1 Mbps (real-time simulated clock).

(a) one sync write + sync read cycle (ServoChain on dynamixel-sdk), with the factory Return Delay Time (500 µs)
    and with it set to 0: wall time, bus-thread CPU time and wake-ups (sleeps waiting for replies) per cycle;
(b) a 50 Hz RobotController loop's tick period over 60 s (10 s with --quick): p50/p99/max, missed and late ticks;
(c) the control loop at 50, 100 and 200 Hz holding a pose;
(d) the same loop inside the running app (``MainWindow`` on the simulated lab, a wave motion playing, the board's 36
    channels streaming; the Forces, Gait and Hardware tabs shown in turn) at 50 Hz (factory 500 µs Return Delay
    Time) and 100 Hz (Return Delay Time 0); QT_QPA_PLATFORM=xcb under Xvfb paints for real; with
    ``--gui-chain pty --gui-loop both`` the loop in the app's process and in its own process, back to back, and
    ``--kills N`` how fast the app notices its loop process killed; ``--trace DIR`` says why each late tick was
    late (benchmarks/late_tick_trace: the loop's marks, the emulator's log, real-time probes of the machine);
(e) one late reply and what it costs the reads after it (the cause of the in-app bursts), on the simulated chain
    and on the independent emulator;
(f) ``sensnake play`` at 50 Hz on the independent emulator (tests/emulators) of twelve XM430s on a pty.

    python -m benchmarks.bench_servo_bus [--quick] [--case bare|gui|pty|…] [--seconds S] [--gui-rate 50]
        [--rotate S] [--plays N] [--gui-chain lab|sim|pty] [--gui-loop auto|app|process|both] [--kills N]
        [--trace DIR]

Columns: ``missed`` are tick slots that passed without a tick (skipped, never caught up in a burst); ``late`` are
ticks that started more than a quarter period after their slot (an overrunning tick is followed at once by the next,
late). Periods are start to start. The virtual chain charges real wire time (10 bits per byte, return delay per
reply), so these figures are what the protocol costs plus this machine's scheduling; the machine's load average is
printed first because a shared machine's other work shows up in p99/max. A U2D2 adds its USB latency (set
latency_timer to 1 ms).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import late_tick_trace
from benchmarks.sources import Wave
from devices import dxl_wire as wire
from devices import factory, tick_trace
from devices.config import SIM_PORT, RobotConfig
from devices.controller import HoldPose, RobotController
from devices.servo_chain import ServoChain
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import ChainLab, VirtualChain

RATES_HZ = (50.0, 100.0, 200.0)


def _install_chain(return_delay_time: int, robot: RobotConfig) -> tuple[VirtualChain, factory.SimPorts | None]:
    chain = VirtualChain(ids=robot.joint_ids, baud=robot.baud, clock=SimClock(1.0), seed=11,
                         return_delay_time=return_delay_time)
    return chain, factory.install_sim_lab(ChainLab(chain))


def bench_cycle(n_cycles: int) -> None:
    robot = RobotConfig()
    print(f"(a) one 12-servo sync write + sync read cycle at {robot.baud} bps ({n_cycles} cycles)")
    print(f"    {'return delay':>14} {'mean ms':>9} {'p50 ms':>9} {'p99 ms':>9} {'max ms':>9} {'CPU ms':>8} "
          f"{'wake-ups':>9}")
    for delay in (250, 0):
        chain, previous = _install_chain(delay, robot)
        try:
            with ServoChain(robot) as servos:
                servos.check_models()  # as the app and the CLI do: reads each servo's Return Delay Time
                servos.set_torque(True)
                goal = np.zeros(robot.n_joints)
                times = np.empty(n_cycles)
                wakeups0, cpu0 = servos.reply_wakeups, time.thread_time()
                for i in range(n_cycles):
                    t0 = time.perf_counter()
                    servos.write_goals(goal)
                    servos.read_state()
                    times[i] = time.perf_counter() - t0
                cpu_ms = (time.thread_time() - cpu0) / n_cycles * 1e3
                wakeups = (servos.reply_wakeups - wakeups0) / n_cycles
        finally:
            factory.install_sim_lab(previous)
        ms = times * 1e3
        print(f"    {delay * 2:>11} µs {ms.mean():9.2f} {np.percentile(ms, 50):9.2f} {np.percentile(ms, 99):9.2f} "
              f"{ms.max():9.2f} {cpu_ms:8.2f} {wakeups:9.2f}")


def _run_loop(rate_hz: float, seconds: float, return_delay_time: int = 0, wave: bool = False) -> tuple[dict, int]:
    """The bare loop (no GUI) for ``seconds``: holding a pose, or with ``wave`` a motion whose goals change every
    tick. Periods are collected every 30 s, so the window may exceed the controller's period history."""
    robot = dataclasses.replace(RobotConfig(), control_rate_hz=rate_hz)
    chain, previous = _install_chain(return_delay_time, robot)
    done = threading.Event()
    try:
        controller = RobotController(ServoChain(robot), robot)
        controller.start()
        try:
            controller.set_torque(True).result(5)
            source = Wave() if wave else HoldPose(np.zeros(robot.n_joints), duration_s=seconds)
            s0 = controller.stats()
            future = controller.run_motion(source, "bench")
            future.add_done_callback(lambda _: done.set())
            t0, chunks, taken = time.monotonic(), [], s0.ticks
            while not done.wait(min(30.0, max(0.0, seconds - (time.monotonic() - t0)))):
                s = controller.stats()
                chunks.append(controller.recent_periods_s(s.ticks - taken))
                taken = s.ticks
                if time.monotonic() - t0 >= seconds:
                    break
            controller.stop_motion()
            s1 = controller.stats()
            chunks.append(controller.recent_periods_s(s1.ticks - taken))
        finally:
            controller.close()
    finally:
        factory.install_sim_lab(previous)
    periods = np.concatenate(chunks)
    jitter = np.abs(periods - 1.0 / rate_hz)
    stats = {"ticks": s1.ticks - s0.ticks, "missed_ticks": s1.missed_ticks - s0.missed_ticks,
             "late_ticks": s1.late_ticks - s0.late_ticks, "period_p50_s": float(np.median(periods)),
             "period_p99_s": float(np.percentile(periods, 99)), "period_max_s": float(periods.max()),
             "jitter_p50_s": float(np.median(jitter)), "jitter_p99_s": float(np.percentile(jitter, 99))}
    return stats, chain.count(wire.SYNC_WRITE)


def bench_jitter(seconds: float) -> None:
    print(f"(b) the bare 50 Hz control loop (no GUI), {seconds:g} s, a wave motion writing new goals every tick, "
          "factory return delay 500 µs")
    stats, writes = _run_loop(50.0, seconds, return_delay_time=250, wave=True)
    _print_stats_header()
    _print_stats(50.0, stats, writes)


def bench_rates(seconds: float) -> None:
    print(f"(c) the bare control loop at several rates, {seconds:g} s each, holding a pose (return delay 0)")
    _print_stats_header()
    for rate in RATES_HZ:
        stats, writes = _run_loop(rate, seconds)
        _print_stats(rate, stats, writes)


GUI_CASES = ((50.0, 250), (100.0, 0))  # (rate Hz, Return Delay Time register): the two in-app targets
GUI_TABS = ("forces", "gait", "hardware")
# Not a tab but a page: the Hardware tab's Servo settings page with "Live" on (the control table re-read at 2 Hz).
SETTINGS_LIVE = "servo-settings"


def _show(window: Any, name: str) -> None:
    """Show tab ``name``; ``servo-settings``: the Hardware tab's Servo settings page polling live."""
    if name != SETTINGS_LIVE:
        window.show_tab(name)
        return
    tab = window.show_tab("hardware")
    tab.pages.setCurrentWidget(tab.settings)
    tab.settings.live_check.setChecked(True)

ALL_TABS = ("teach", "gait", "calibration", "forces", "hardware", "scene")


def bench_gui(seconds: float, cases=GUI_CASES, tabs=GUI_TABS, rotate_s: float | None = None,
              chain: str = "sim", prebuild: bool = False, loops: tuple[str, ...] = ("auto",), kills: int = 0,
              trace_dir: str | None = None) -> None:
    """The loop inside the running app: GUI thread, board reader and the simulated devices share the interpreter.
    The Forces tab plots the board's 36 channels live; a wave motion writes goals every tick.

    Without ``rotate_s``: one ``seconds`` window per tab in ``tabs``. With it: one window of ``seconds`` per case in
    which the shown tab changes every ``rotate_s`` through ``tabs`` (every tab live in turn); periods are collected
    in chunks, so the window may be longer than the controller's period history.

    ``chain="lab"`` (``sensnake gui``'s default): the simulated lab in its own process, its devices on ptys, the
    loop in a process of its own. ``chain="sim"``: the simulated lab in the app's process (and with it the loop).
    ``chain="pty"``: the robot is the independent emulator of twelve XM430s in its own process on a pty (as real
    servos are outside the app), the board and the rest of the lab stay simulated in the app. ``prebuild``: show
    every tab once before the motion starts (a tab is built on its first show; building the 3-D lab takes the
    interpreter for a while, once per session).

    ``loops``: where the control loop runs, one run each: ``app`` (the app's process, SENSNAKE_LOOP_PROCESS=0),
    ``process`` (its own process: the app's default on a real port, so only with ``chain="pty"``), ``auto`` (the
    app's choice). ``kills``: after the windows, kill the loop process this many times and print how long until the
    app noticed (the watcher thread) and said so (the error on the GUI thread); the app reconnects after each.

    ``trace_dir``: trace every late tick in the loop's process (the app's own when the loop runs there), the
    emulator's instruction times (robot on the pty chain) and the machine's own wake-up gaps, and print why each late
    tick was late (benchmarks/late_tick_trace)."""
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    from PySide6.QtCore import QEventLoop, QTimer
    from PySide6.QtWidgets import QApplication

    import widgets  # noqa: F401 - installs the PySide6 refcount guard before Qt is used
    from app.gui.lab import LabContext
    from app.gui.main_window import MainWindow
    from devices.config import load_config
    from devices.sim.lab import SimLab
    from devices.sim.lab_process import LabProcess

    shown = f"every {rotate_s:g} s through {'/'.join(tabs)}" if rotate_s else "per tab"
    where = {"pty": "robot on the independent pty chain", "lab": "simulated lab in its own process (the app's default)",
             "sim": "simulated lab in the app's process"}[chain]
    print(f"(d) control loop in the running app ({os.environ['QT_QPA_PLATFORM']}, {where}, wave motion, board "
          f"streaming 36 channels), {seconds:g} s {shown}. Targets: 50 Hz p99 jitter ≤ 2 ms and no late tick; "
          "100 Hz (return delay 0) p99 jitter ≤ 2 ms")
    print(f"    {'rate Hz':>8} {'RDT µs':>7} {'tab':>9} {'ticks':>7} {'missed':>7} {'late':>6} {'period p50':>11} "
          f"{'p99':>7} {'max':>7} {'jitter p99':>11} {'CPU %':>6} {'bursts':>7}   (ms; CPU: the whole process, % of one "
          "core, the loop's own process not included; bursts: runs of ≥ 5 consecutive periods > 1.25 periods)")
    app = QApplication.instance() or QApplication([])
    loop = QEventLoop()

    def spin(seconds_: float, until=lambda: False) -> None:
        end = time.monotonic() + seconds_
        while time.monotonic() < end and not until():
            QTimer.singleShot(20, loop.quit)
            loop.exec()

    base = load_config(None).with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    runs = [(rate, delay, where) for rate, delay in cases for where in loops]
    for rate, delay, where in runs:
        if where == "process" and chain == "sim":
            print(f"    {rate:8.0f}  loop 'process' needs --gui-chain pty or lab (with the lab in the app's process the "
                  "loop stays there)")
            continue
        saved_switch = os.environ.get("SENSNAKE_LOOP_PROCESS")
        if where != "auto":
            os.environ["SENSNAKE_LOOP_PROCESS"] = "1" if where == "process" else "0"
        config = dataclasses.replace(base, robot=dataclasses.replace(base.robot, control_rate_hz=rate))
        emulator = None
        tracing = late_tick_trace.start(trace_dir) if trace_dir else None
        if tracing is not None and (chain != "pty" or where == "app"):
            tick_trace.enable_from_env()  # the loop runs in this process: trace it here
        traced: list[tuple[float, float]] = []
        if chain == "pty":
            from tests.emulators.xm430_emulator import EmulatorProcess

            emulator = EmulatorProcess()
            config = config.with_ports(robot=emulator.path)
        sim = LabProcess(config).start() if chain == "lab" else SimLab(config)
        previous = factory.install_sim_lab(sim)
        world = sim.physics.world if isinstance(sim, SimLab) and chain == "sim" and sim.physics is not None else None
        with ServoChain(config.robot) as servos:  # the Hardware tab's Return Delay Time button, before connecting
            servos.check_models()
            servos.set_return_delay(delay * 2)
        lab = LabContext(config)
        window = MainWindow(lab)
        try:
            window.show()
            lab.connect_all()
            spin(10.0, lambda robot=lab.robot: robot.is_connected)
            if not lab.robot.is_connected:
                print(f"    {rate:8.0f}  the robot did not connect within 10 s")
                continue
            robot_errors: list[str] = []
            lab.robot.error.connect(robot_errors.append)
            lab.robot.set_torque(True)
            spin(0.3)
            for tab in tabs if prebuild else ():  # each tab is built on its first show (once per session)
                _show(window, tab)
                spin(0.5)
            lab.robot.run_motion(Wave(), "bench wave")
            windows = [(tab, seconds) for tab in tabs] if not rotate_s else [("rotating", seconds)]
            for name, length in windows:
                _show(window, name if not rotate_s else tabs[0])
                spin(0.5)
                load0 = os.getloadavg()[0]
                if tracing is not None:
                    late_tick_trace.start_probes(tracing, length + 2.0)
                s0 = lab.robot.loop_stats()
                chain0 = getattr(lab.robot.controller, "chain", None)
                wakeups0 = chain0.reply_wakeups if chain0 is not None else 0
                t0, cpu0 = time.monotonic(), time.process_time()
                others = {"lab": getattr(sim, "pid", None), "loop": getattr(lab.robot.controller, "pid", None)}
                others0 = {name_: _process_cpu_s(pid) for name_, pid in others.items()}
                physics0 = (world.stepping_s, world.lagged_s) if world is not None else None
                chunks, taken, k = [], s0.ticks, 0
                while time.monotonic() - t0 < length:
                    spin(min(rotate_s or length, length - (time.monotonic() - t0)))
                    if lab.robot.controller is None:  # the loop died (said on robot.error): the window ends here
                        break
                    s = lab.robot.loop_stats()
                    chunks.append(lab.robot.controller.recent_periods_s(s.ticks - taken))
                    taken = s.ticks
                    if rotate_s:
                        k += 1
                        _show(window, tabs[k % len(tabs)])
                traced.append((t0, time.monotonic()))
                if lab.robot.controller is None:
                    print(f"    {rate:8.0f}  the window ended after {time.monotonic() - t0:.0f} s: "
                          f"{' / '.join(robot_errors) or 'the robot disconnected'}", flush=True)
                    break
                s1 = lab.robot.loop_stats()
                chunks.append(lab.robot.controller.recent_periods_s(s1.ticks - taken))
                wall = time.monotonic() - t0
                cpu = (time.process_time() - cpu0) / wall * 100
                note = f"load {load0:.2f}->{os.getloadavg()[0]:.2f}; loop in {lab.robot.loop_where}"
                note += f"; {s1.failed_reads - s0.failed_reads} failed feedback reads"
                if name == SETTINGS_LIVE:
                    hardware: Any = window.show_tab("hardware")
                    note += f"; {hardware.table_reads} control-table reads by the settings page"
                for name_, pid in others.items():
                    used0, used1 = others0[name_], _process_cpu_s(pid)
                    if used0 is not None and used1 is not None:
                        note += f"; {name_} process CPU {(used1 - used0) / wall * 100:.0f} %"
                in_app = getattr(lab.robot.controller, "chain", None)  # None when the loop has its own process
                if in_app is not None:
                    # A read waiting out the SDK's packet timeout (~37 ms here) shows as ticks of ~39 ms.
                    note += (f", {(in_app.reply_wakeups - wakeups0) / max(1, s1.ticks - s0.ticks):.1f} reply "
                             f"wake-ups per tick, replies paced {'by the device' if in_app.replies_paced_by_device else 'by the wire'}")
                if world is not None and physics0 is not None:
                    # The simulated servos answer from the physics world: when stepping it cannot keep up with
                    # the clock, replies wait for it (the simulator's limit, not the loop's) -- said here.
                    note += (f"; physics lab stepping {100 * (world.stepping_s - physics0[0]) / wall:.0f} % of the "
                             f"wall time, {world.lagged_s - physics0[1]:.1f} s of simulated time skipped (behind)")
                _print_window(rate, delay * 2, name, s1.ticks - s0.ticks, s1.missed_ticks - s0.missed_ticks,
                              s1.late_ticks - s0.late_ticks, np.concatenate(chunks), cpu, note)
            if kills and lab.robot.is_connected and where != "app":
                _kill_loop_process(lab, spin, kills)
        finally:
            if saved_switch is None:
                os.environ.pop("SENSNAKE_LOOP_PROCESS", None)
            else:
                os.environ["SENSNAKE_LOOP_PROCESS"] = saved_switch
            window.close()
            lab.close()
            factory.install_sim_lab(previous)
            if isinstance(sim, LabProcess):
                sim.close()
            if emulator is not None:
                emulator.close()
            if tracing is not None:
                tick_trace.disable()
                late_tick_trace.stop(tracing)
                for w0, w1 in traced:
                    late_tick_trace.report(tracing, w0, w1)
    del app


def _kill_loop_process(lab, spin, kills: int) -> None:
    """Kill the loop process ``kills`` times while the wave plays and the GUI is busy; how long until the app noticed
    (its watcher thread read the end of file) and said so (the error arrived on the GUI thread). Target: 100 ms."""
    import signal

    from devices.loop_process import ControllerProcess

    noticed, said = [], []
    for _ in range(kills):
        robot = lab.robot
        controller = robot.controller
        if not isinstance(controller, ControllerProcess) or controller.pid is None:
            print(f"    kill: the loop runs in {robot.loop_where}, not in its own process")
            return
        heard: list[float] = []

        def on_error(text: str, heard=heard) -> None:
            if "control loop process" in text:
                heard.append(time.monotonic())

        robot.error.connect(on_error)
        spin(1.0)
        killed_at = time.monotonic()
        os.kill(controller.pid, signal.SIGKILL)
        spin(10.0, lambda heard=heard: bool(heard))
        robot.error.disconnect(on_error)
        if not heard or controller.died_at_s is None:
            print("    kill: the app did not say so within 10 s")
            return
        noticed.append((controller.died_at_s - killed_at) * 1e3)
        said.append((heard[0] - killed_at) * 1e3)
        robot.connect()
        spin(30.0, lambda robot=robot: robot.is_connected)
        if not robot.is_connected:
            print("    kill: the robot did not reconnect within 30 s")
            return
        robot.set_torque(True)
        spin(0.3)
        robot.run_motion(Wave(), "bench wave")
    print(f"    loop process killed {len(noticed)}×: noticed (watcher) after {_ms_list(noticed)} ms, said on the GUI "
          f"thread after {_ms_list(said)} ms (target: dead loop noticed within 100 ms); load "
          f"{os.getloadavg()[0]:.2f}", flush=True)


def _ms_list(values: list[float]) -> str:
    return "/".join(f"{v:.1f}" for v in values)


def _process_cpu_s(pid: int | None) -> float | None:
    """CPU seconds (user + system) used so far by process ``pid`` (Linux /proc), None if unknown."""
    if pid is None:
        return None
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _print_window(rate: float, delay_us: int, name: str, ticks: int, missed: int, late: int, periods: np.ndarray,
                  cpu: float, note: str = "") -> None:
    ms = periods * 1e3
    jitter = np.abs(ms - 1e3 / rate)
    print(f"    {rate:8.0f} {delay_us:7d} {name:>9} {ticks:7d} {missed:7d} {late:6d} {np.median(ms):11.2f} "
          f"{np.percentile(ms, 99):7.2f} {ms.max():7.2f} {np.percentile(jitter, 99):11.2f} {cpu:6.0f} "
          f"{_bursts(periods, rate):7d}   {note}", flush=True)


def _bursts(periods_s: np.ndarray, rate_hz: float, run: int = 5) -> int:
    """Runs of ``run`` or more consecutive periods longer than 1.25 periods: bursts (~32 ticks of ~28 ms
    at 50 Hz), as opposed to isolated late ticks."""
    long_ = np.concatenate(([False], periods_s > 1.25 / rate_hz, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(long_))
    return int(np.sum(edges[1::2] - edges[::2] >= run))


def bench_pty_chain(plays: int = 1) -> None:
    """``sensnake play``'s path (RobotController.play) at 50 Hz on the independent emulator of twelve XM430s in its
    own process on a pty (factory Return Delay Time, wire time at 1 Mbps): a full follow-the-leader play, counted
    from the play command, as ``sensnake play`` counts its missed ticks (the play command's own tick is also
    printed apart: it used to miss one). Target: tick period p99 ≤ 22 ms and zero missed ticks."""
    from models.trajectory import FollowTheLeader

    try:
        from tests.emulators.xm430_emulator import EmulatorProcess
    except ImportError:
        print("(f) skipped: the emulator (tests/emulators) is not importable; run from the source tree")
        return
    print("(f) sensnake play at 50 Hz on the independent pty chain (12 emulated XM430s, own process, return delay "
          "500 µs): target period p99 ≤ 22 ms, no missed tick")
    print(f"    {'rate Hz':>8} {'RDT µs':>7} {'play':>9} {'ticks':>7} {'missed':>7} {'late':>6} {'period p50':>11} "
          f"{'p99':>7} {'max':>7} {'jitter p99':>11} {'CPU %':>6} {'bursts':>7}")
    for k in range(plays):
        emulator = EmulatorProcess()
        try:
            robot = dataclasses.replace(RobotConfig(), port=emulator.path)
            chain = ServoChain(robot)
            chain.open()
            chain.check_models()
            controller = RobotController(chain, robot)
            controller.start()
            try:
                shape = 0.3 * np.sin(0.8 * np.arange(robot.n_joints))
                source = FollowTheLeader(shape, robot.axes, 0.3, 4, rate_hz=robot.control_rate_hz)
                before = controller.stats()
                t0, cpu0 = time.monotonic(), time.process_time()
                playing = controller.play(source, "bench")
                # The play command (torque on holding the pose just read, plan and check) runs in the tick after
                # the call; its own cost is printed apart, the row counts from the call.
                while controller.motion_name != "bench" and not playing.done():
                    time.sleep(0.001)
                started = controller.stats().ticks
                while controller.stats().ticks < started + 2 and not playing.done():
                    time.sleep(0.001)
                s0 = controller.stats()
                playing.result(120)
                s1 = controller.stats()
                cpu = (time.process_time() - cpu0) / (time.monotonic() - t0) * 100
                periods = controller.recent_periods_s(s1.ticks - before.ticks)
            finally:
                controller.close()
        finally:
            emulator.close()
        _print_window(50.0, 500, f"#{k + 1}", s1.ticks - before.ticks, s1.missed_ticks - before.missed_ticks,
                      s1.late_ticks - before.late_ticks, periods, cpu,
                      f"of which the play command's ticks: {s0.missed_ticks - before.missed_ticks} missed, "
                      f"{s0.late_ticks - before.late_ticks} late")


def _late_reply_trace(read_once, inject, n_reads: int, at: int) -> np.ndarray:
    """Durations (s) of ``n_reads`` back-to-back sync reads, with ``inject()`` making the replies of read ``at``
    late once."""
    times = np.empty(n_reads)
    for i in range(n_reads):
        if i == at:
            inject()
        t0 = time.perf_counter()
        read_once()
        times[i] = time.perf_counter() - t0
    return times


def bench_late_reply(n_reads: int = 120, at: int = 20, stall_s: float = 0.012) -> None:
    """The cause of the in-app bursts: ONE late reply (the far end, or our timestamp of the instruction, delayed
    once by the scheduler) and what it costs the reads after it. Replies are made late deterministically, so this
    does not depend on the machine's load: on the simulated chain by stamping one instruction ``stall_s`` late, on
    the independent emulator by its ``stall`` command."""
    print(f"(e) one late reply ({stall_s * 1e3:g} ms) at read {at} of {n_reads} 12-servo sync reads, return delay "
          "500 µs: reads after it slower than 1.5× the median before it")
    print(f"    {'chain':>10} {'median before':>14} {'the late read':>14} {'slow reads after':>17} "
          f"{'median after':>13}   (ms)")
    robot = RobotConfig()
    sim, previous = _install_chain(250, robot)
    real_write = sim.host_write
    pending = {"stall": 0.0}

    def stamped_late(data: bytes, now_s: float) -> None:
        real_write(data, now_s + pending["stall"])
        pending["stall"] = 0.0

    sim.host_write = stamped_late  # type: ignore[method-assign]
    try:
        with ServoChain(robot) as servos:
            servos.check_models()
            times = _late_reply_trace(servos.read_state, lambda: pending.update(stall=stall_s), n_reads, at)
    finally:
        factory.install_sim_lab(previous)
    _print_late_reply("sim", times, at)
    from tests.emulators.xm430_emulator import EmulatorProcess

    emulator = EmulatorProcess()
    try:
        with ServoChain(dataclasses.replace(robot, port=emulator.path)) as servos:
            servos.check_models()
            times = _late_reply_trace(servos.read_state, lambda: emulator.command(f"stall {stall_s}"), n_reads, at)
    finally:
        emulator.close()
    _print_late_reply("emulator", times, at)


def _print_late_reply(name: str, times: np.ndarray, at: int) -> None:
    ms = times * 1e3
    before = float(np.median(ms[:at]))
    after = ms[at + 1:]
    slow = int(np.sum(after > 1.5 * before))
    print(f"    {name:>10} {before:14.2f} {ms[at]:14.2f} {slow:17d} {np.median(after[:32]):13.2f}")


def _print_stats_header() -> None:
    print(f"    {'rate Hz':>8} {'ticks':>7} {'missed':>7} {'late':>6} {'period p50':>11} {'p99':>7} {'max':>7} "
          f"{'jitter p50':>11} {'p99':>7} {'writes':>7}   (ms)")


def _print_stats(rate: float, s: dict, writes: int) -> None:
    ms = {k: v * 1e3 for k, v in s.items() if k.endswith("_s")}
    print(f"    {rate:8.0f} {s['ticks']:7d} {s['missed_ticks']:7d} {s['late_ticks']:6d} {ms['period_p50_s']:11.2f} "
          f"{ms['period_p99_s']:7.2f} {ms['period_max_s']:7.2f} {ms['jitter_p50_s']:11.3f} "
          f"{ms['jitter_p99_s']:7.2f} {writes:7d}")


CASES = ("cycle", "late", "bare", "rates", "pty", "gui")


def run(quick: bool, cases: tuple[str, ...] = CASES, seconds: float | None = None, gui_rates: tuple[float, ...] = (),
        rotate_s: float | None = None, plays: int | None = None, gui_chain: str = "lab",
        prebuild: bool = False, tabs: tuple[str, ...] = (), loops: tuple[str, ...] = ("auto",),
        kills: int = 0, trace_dir: str | None = None) -> None:
    print(f"machine load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", flush=True)
    if "cycle" in cases:
        bench_cycle(100 if quick else 500)
    if "late" in cases:
        try:
            bench_late_reply()
        except ImportError:
            print("(e) skipped: the emulator (tests/emulators) is not importable; run from the source tree")
    if "bare" in cases:
        bench_jitter(seconds or (10.0 if quick else 60.0))
    if "rates" in cases:
        bench_rates(seconds or (3.0 if quick else 10.0))
    if "pty" in cases:
        bench_pty_chain(plays or (1 if quick else 3))
    if "gui" in cases:
        gui_cases = tuple(c for c in GUI_CASES if not gui_rates or c[0] in gui_rates)
        bench_gui(seconds or (4.0 if quick else 15.0), gui_cases, tabs or (ALL_TABS if rotate_s else GUI_TABS), rotate_s,
                  gui_chain, prebuild, loops, kills, trace_dir)
    print(f"machine load average (1 min) at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="short windows (a smoke run, not the targets)")
    parser.add_argument("--case", action="append", choices=CASES,
                        help="run only this case (repeatable): cycle (a), late (e), bare (b), rates (c), pty (f), "
                             "gui (d); default all")
    parser.add_argument("--seconds", type=float, help="window length for bare, rates and gui (per tab or rotating)")
    parser.add_argument("--gui-rate", type=float, action="append", choices=[c[0] for c in GUI_CASES],
                        help="gui case: only this rate (50 = factory return delay, 100 = return delay 0)")
    parser.add_argument("--rotate", type=float, metavar="S",
                        help="gui case: one window per rate, the shown tab changing every S s through all six tabs")
    parser.add_argument("--plays", type=int, help="pty case: number of full plays")
    parser.add_argument("--gui-chain", choices=("lab", "sim", "pty"), default="lab",
                        help="gui case: the simulated lab in its own process (default, as `sensnake gui` runs it), "
                             "the simulated lab in the app's process, or the robot on the independent pty emulator")
    parser.add_argument("--prebuild", action="store_true",
                        help="gui case: show every tab once before measuring (tabs are built on first show)")
    parser.add_argument("--tabs", help=f"gui case: comma-separated tabs to show (default: with --rotate all of "
                        f"{','.join(ALL_TABS)}, else {','.join(GUI_TABS)}; '{SETTINGS_LIVE}': the Hardware tab's "
                        "Servo settings page reading a servo's table live)")
    parser.add_argument("--gui-loop", choices=("auto", "app", "process", "both"), default="auto",
                        help="gui case: where the control loop runs: the app's choice (default), the app's process, "
                             "its own process (needs --gui-chain pty), or both in turn")
    parser.add_argument("--kills", type=int, default=0,
                        help="gui case with the loop in its own process: kill it N times, print how fast the app "
                             "noticed")
    parser.add_argument("--trace", metavar="DIR",
                        help="gui case: trace every late tick (the loop's process, the emulator on the pty chain, machine "
                             "probes) into DIR and print why each was late")
    args = parser.parse_args()
    run(args.quick, tuple(args.case or CASES), args.seconds, tuple(args.gui_rate or ()), args.rotate, args.plays, args.gui_chain,
        args.prebuild, tuple(args.tabs.split(",")) if args.tabs else (),
        ("app", "process") if args.gui_loop == "both" else (args.gui_loop,), args.kills, args.trace)
