"""The one place that decides between real and simulated hardware.

A port named ``sim`` (SPEC §1) connects to the process-wide simulated lab; anything else is an OS serial device.
Drivers never import ``devices.sim``; they ask this module for a port. Tests install their own seeded, faster-than-
real-time lab with :func:`install_sim_lab`.
"""

from __future__ import annotations

import atexit
import os
import threading
from typing import TYPE_CHECKING, Any, Protocol, cast

import serial

from devices.config import SIM_PORT, LabConfig
from devices.errors import PortOpenError, os_words
from devices.gauge import DEFAULT_RESOLUTION_M, TravelGauge, TypedGauge
from devices.realtime import _switched_off

if TYPE_CHECKING:  # pragma: no cover
    from devices.scene import Scene
    from devices.sim.lab import SimLab
    from devices.sim.lab_process import LabProcess
    from devices.sim.physics.headless import HeadlessPhysicsLab

DEVICE_KINDS = ("robot", "board", "rig")


class SimPorts(Protocol):
    """What the factory needs from whatever stands behind the ``sim`` ports: the wire endpoint of a device kind.
    :class:`devices.sim.lab.SimLab` is the real one; tests and benchmarks install stand-ins with fewer devices."""

    def endpoint(self, device: str) -> Any: ...


_lab_lock = threading.Lock()
_lab: SimPorts | None = None


def is_sim(port: str) -> bool:
    return port.strip().lower() == SIM_PORT


def sim_lab(config: LabConfig | None = None) -> SimLab:
    """The process-wide simulated lab, created on first use (from ``config`` or the defaults)."""
    global _lab
    with _lab_lock:
        if _lab is None:
            from devices.sim.lab import SimLab

            lab = SimLab(config)
            lab.start_background()  # the physics lab keeps stepping between driver events
            # Stop that thread before the interpreter shuts down: a daemon thread still inside MuJoCo while Python
            # finalizes crashed `sensnake record --daq sim` with SIGSEGV after its own error message.
            atexit.register(lab.close)
            _lab = lab
        # A stand-in installed by a test or benchmark (install_sim_lab) answers only for the devices it simulates.
        return cast("SimLab", _lab)


def start_sim_lab(config: LabConfig | None = None, *, speed: float = 1.0,
                  seed: int = 0) -> tuple[SimLab, SimPorts | None]:
    """Create a simulated lab from ``config`` whose clock runs ``speed``× real time, start it and install it behind
    the ``sim`` ports; returns (the new lab, the one it replaced — put it back with :func:`install_sim_lab`)."""
    from devices.sim.lab import SimLab

    lab = SimLab(config, seed=seed, speed=speed)
    lab.start_background()
    return lab, install_sim_lab(lab)


SIMULATED_TRUTH_NOTE = ("the simulated lab's sensors' true parameters: the simulation's truth, not a measurement "
                        "(on a real robot, calibrate each sensor on the rig)")


def simulated_sensors_calibration(config: LabConfig | None = None, *, seed: int = 0) -> dict:
    """The calibration (SPEC §3.3 document) of every sensor of the simulated lab that ``config`` and ``seed`` make
    (the app's and the CLI's lab use seed 0): the true parameters its board computes conductance from, with
    ``source`` saying so. The same document as the running lab's ``board.ground_truth_calibration()``, computed
    without starting a lab: the sensors' spread comes from the seed alone, not from the physics."""
    from dataclasses import replace

    from devices.sim.lab import SimLab

    config = config or LabConfig()
    lab = SimLab(replace(config, lab=replace(config.lab, physics="scripted")), seed=seed)
    try:
        document = dict(lab.board.ground_truth_calibration())
    finally:
        lab.close()
    document["source"] = SIMULATED_TRUTH_NOTE
    return document


LAB_PROCESS_SWITCH = "SENSNAKE_LAB_PROCESS"  # "0" keeps the simulated lab in the app's process


def lab_process_wanted() -> tuple[bool, str]:
    """Whether the app's simulated lab gets its own process, and if not, why (one line)."""
    if os.name != "posix" or not hasattr(os, "openpty"):
        return False, "the simulated lab's own process needs Linux or macOS (pseudo-terminals)"
    if _switched_off(LAB_PROCESS_SWITCH):
        return False, f"{LAB_PROCESS_SWITCH}=0"
    return True, ""


def start_lab_process(config: LabConfig | None = None) -> LabProcess:
    """Start the simulated lab in its own process (:mod:`devices.sim.lab_process`: its devices on ptys, the robot's
    control loop then in a process of its own too) and install it behind the ``sim`` ports. Raises
    :class:`devices.errors.LabProcessUnavailable` when the child cannot run; the caller then uses :func:`sim_lab`."""
    from devices.sim.lab_process import LabProcess

    lab = LabProcess(config).start()
    atexit.register(lab.close)
    install_sim_lab(lab)
    return lab


def sim_serial_path(device: str) -> str | None:
    """The pty behind the ``sim`` port of ``device`` when the simulated lab runs in its own process, else None
    (the lab is in this process, or none is made yet)."""
    path = getattr(installed_sim_lab(), "serial_path", None)
    return path(device) if callable(path) else None


def move_simulated_probe(sensor: str) -> bool:
    """Put ``sensor`` under the simulated rig's probe (``SimLab.move_rig_to``: what a person does on the real rig
    before calibrating it), in this process's lab or in the lab's own process. Returns whether a lab moved it (False:
    no simulated lab, or a stand-in without a rig). ValueError when the board has no such channel."""
    lab = installed_sim_lab()
    call = getattr(lab, "call", None)  # the lab's own process (LabProcess)
    if callable(call):
        call("move_rig_to", sensor)
        return True
    move = getattr(lab, "move_rig_to", None)
    if callable(move):
        move(sensor)
        return True
    return False


def start_sim_rig_bench(config: LabConfig, *, speed: float = 1.0, seed: int = 0, gauge_force_n: float = 0.0,
                        gauge_rate_n_per_m: float = 0.0) -> tuple[SimPorts, SimPorts | None]:
    """The simulated calibration rig alone (no robot, no board) behind the ``sim`` rig port, its clock at ``speed``×
    real time, with a segment's compliant shell under the probe as ``config``'s ``[lab.physics]`` has it (stiffness,
    damping, travel) and a dial gauge on the probe whose measuring force is ``gauge_force_n`` at rest, falling by
    ``gauge_rate_n_per_m`` as the probe goes in. Returns (the bench, the lab it replaced: put it back with
    :func:`install_sim_lab`)."""
    from devices.sim.clock import SimClock
    from devices.sim.rig import RigBench, ShellSpecimen

    physical = config.lab.physical
    bench = RigBench(config.rig, SimClock(speed), seed=seed)
    bench.rig.mount_shell(ShellSpecimen(physical.shell_stiffness_n_per_m, physical.shell_damping_n_s_per_m,
                                        physical.shell_travel_m, gauge_force_n, gauge_rate_n_per_m))
    return bench, install_sim_lab(bench)


def travel_gauge(rig_port: str, resolution_m: float = DEFAULT_RESOLUTION_M, *, ask: Any = input,
                 seed: int = 0) -> TravelGauge:
    """The dial gauge on the probe of the rig on ``rig_port``: on ``sim``, the simulated rig's gauge (its readings
    made from the simulated probe); on a real rig, a person reading the gauge and typing each value (``ask``)."""
    if is_sim(rig_port):
        from devices.sim.gauge import SimDialGauge

        rig = getattr(installed_sim_lab(), "rig", None)
        if rig is None or not callable(getattr(rig, "probe_travel_m", None)):
            raise RuntimeError("the simulated lab behind 'sim' has no rig whose probe a gauge could read "
                               "(start it with start_sim_rig_bench)")
        return SimDialGauge(rig, resolution_m, seed=seed)
    return TypedGauge(resolution_m, ask)


def installed_sim_lab() -> SimPorts | None:
    """The simulated lab behind the ``sim`` ports, without making one (None if none is made yet)."""
    with _lab_lock:
        return _lab


def install_sim_lab(lab: SimPorts | None) -> SimPorts | None:
    """Replace the process-wide simulated lab (``None`` drops it); returns the previous one."""
    global _lab
    with _lab_lock:
        previous, _lab = _lab, lab
        return previous


def headless_physics_lab(config: LabConfig, seed: int = 0, terrain: Scene | None = None) -> HeadlessPhysicsLab:
    """A physics lab (MuJoCo) that its caller steps as fast as the machine goes, for batch experiments; its devices
    are reached through their wire protocol (see ``devices.sim.physics.headless``). ``terrain``: a scene to build it
    on instead of the config's ``[lab] scene``. Needs the ``mujoco`` package."""
    from devices.sim.physics.headless import HeadlessPhysicsLab

    return HeadlessPhysicsLab(config, seed=seed, terrain=terrain)


def open_serial(port: str, baud: int, device: str, timeout_s: float | None = 0.0) -> serial.SerialBase:
    """Open ``port`` for ``device`` (one of :data:`DEVICE_KINDS`); ``sim`` gives the simulated device's port."""
    if device not in DEVICE_KINDS:
        raise ValueError(f"unknown device kind {device!r}; expected one of {DEVICE_KINDS}")
    if is_sim(port):
        path = sim_serial_path(device)
        if path is not None:
            port = path  # the lab's own process: its device is a pty, opened as any serial port
        else:
            from devices.sim.transport import SimSerial

            return SimSerial(sim_lab().endpoint(device), port=SIM_PORT, baudrate=baud, timeout=timeout_s)
    try:
        return serial.Serial(port=port, baudrate=baud, timeout=timeout_s)
    except (serial.SerialException, OSError) as exc:
        raise PortOpenError(
            f"cannot open {device} port {port}: {os_words(exc)}. Check the cable and the port name "
            "(Linux: /dev/ttyUSB0, Windows: COM3), or use 'sim' for the simulated lab"
        ) from exc
