"""CLI plumbing shared by the commands that open a port (``scan``, ``teach``, ``play``, ``servo``, ``record``): the
ports from the options or the lab config, the robot config, a checked :class:`devices.controller.RobotController`,
and a servo's hardware error worded for the command line. Not a command itself (the leading underscore keeps it out
of the parser's list). Called from the CLI's main thread.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NoReturn

from devices.config import MAX_BAUD, LabConfig, RobotConfig, load_config, sets_port
from devices.errors import HARDWARE_ERROR_ADVICE, ServoHardwareError

if TYPE_CHECKING:
    from devices.controller import RobotController
    from devices.servo_chain import ServoChain

BUS_TIMEOUT_S = 5.0  # how long a command waits for one job on the bus thread (torque, capture, hold)
EXIT_USAGE = 2  # as argparse's own usage errors


def command_name(args: argparse.Namespace) -> str:
    """``sensnake play``, ``sensnake servo reboot``: how the user called the command, for its messages."""
    words = ["sensnake", str(getattr(args, "command", None) or "")]
    if getattr(args, "servo_command", None):
        words.append(str(args.servo_command))
    return " ".join(word for word in words if word)


def usage_error(args: argparse.Namespace, message: str) -> NoReturn:
    """One line on stderr and exit 2, exactly as argparse ends a usage error (an option missing that the parser
    cannot require: it may come from the config instead)."""
    prog = command_name(args)
    print(f"{prog}: error: {message} (see '{prog} --help')", file=sys.stderr)
    raise SystemExit(EXIT_USAGE)


def lab_config(args: argparse.Namespace) -> LabConfig | None:
    """The lab config named by ``--config`` (ConfigError, a ValueError, for a bad file), or None without one."""
    path = getattr(args, "config", None)
    return load_config(path) if path else None


def port_from(args: argparse.Namespace, option: str, section: str, config: LabConfig | None) -> str:
    """The port of ``--<option>`` (``robot``, ``daq``), else the ``[<section>] port`` of the ``--config`` file (a
    SPEC §1 extension). With neither (or a config that names no port there): one line and exit 2."""
    given = getattr(args, option, None)
    if given is not None:
        return str(given).strip()
    device = "robot" if section == "robot" else "force-sensor board"
    if config is None:
        usage_error(args, f"no {device} port: give --{option} PORT (a serial device, or sim) or --config LAB.toml "
                          f"whose [{section}] names its port")
    if not sets_port(config, section):
        usage_error(args, f"no {device} port: {args.config} names none under [{section}] (port = \"/dev/ttyUSB0\"); "
                          f"give --{option} PORT or add it there")
    return str(getattr(config, section).port)


def robot_config(args: argparse.Namespace) -> RobotConfig:
    """The robot config from ``--config`` (or the defaults) with the port (``--robot``, else the config's) and
    ``--baud`` (bps) applied.

    ValueError for a non-positive ``--baud``; ConfigError (a ValueError) for a bad config file; exit 2 (one line)
    when no port is given either way."""
    config = lab_config(args)
    port = port_from(args, "robot", "robot", config)
    robot = replace((config or LabConfig()).robot, port=port)
    if args.baud is not None:
        if args.baud <= 0:
            raise ValueError(f"--baud must be a positive rate in bps, got {args.baud}")
        if args.baud > MAX_BAUD:
            raise ValueError(f"--baud {args.baud} is faster than any serial port here (at most {MAX_BAUD} bps)")
        robot = replace(robot, baud=int(args.baud))
    return robot


def hardware_error(servo_id: int, names: Sequence[str], when: str) -> ServoHardwareError:
    """A servo's hardware error worded for the command line: what it is, ``when`` (``"motion stopped"``, ``"found at
    connect, nothing moved"``, …: never "motion stopped" when nothing moved), what to do, and how to clear it here
    (``sensnake servo reboot --id N``) as well as in the app."""
    names = tuple(names) or ("hardware error",)
    action = HARDWARE_ERROR_ADVICE.get(names[0], ("", "find the cause"))[1]
    error = ServoHardwareError(servo_id, names)
    # The same class (callers catch it), the message of this face: devices words it for the app's Hardware tab.
    error.args = (f"servo {servo_id} {', '.join(names)}: {when}; {action}, then reboot servo {servo_id} to clear it "
                  f"(sensnake servo reboot --id {servo_id}, or Hardware tab → Reboot)",)
    return error


def reworded(exc: ServoHardwareError, when: str) -> ServoHardwareError:
    """``exc`` as :func:`hardware_error` words it."""
    return hardware_error(exc.servo_id, exc.error_names, when)


def refuse_servos_in_error(chain: ServoChain, when: str = "found at connect, nothing moved") -> None:
    """Raise :func:`hardware_error` for the first servo whose Hardware Error Status is set (one sync read): a servo
    in error keeps its torque off until rebooted, so nothing can hold or move it."""
    for health in chain.read_health(supply=False):
        if health.hardware_error:
            raise hardware_error(health.servo_id, health.error_names, when)


def start_controller(robot: RobotConfig, on_state: Callable[[Any], None] | None = None,
                     on_event: Callable[[str], None] | None = None) -> RobotController:
    """Open the robot's bus, check every configured servo answers with the expected model and reports no hardware
    error, check the bus can keep ``robot.control_rate_hz`` (baud, servo count, each servo's Return Delay Time:
    refused, or a warning on stderr, with the fix), and start the control loop. Raises PortOpenError / NoReplyError
    / ModelMismatchError / ServoHardwareError / RateError (one clear line each) with the port closed again. The
    caller owns the returned controller and must ``close()`` it. ``on_state``/``on_event``: as
    :class:`devices.controller.RobotController` takes them (called on its thread)."""
    from devices.controller import RobotController
    from devices.servo_chain import ServoChain

    chain = ServoChain(robot, device="robot")
    chain.open()
    try:
        chain.check_models()
        refuse_servos_in_error(chain)
        warning = chain.check_rate(robot.control_rate_hz)
        if warning:
            print(f"sensnake: warning: {warning}", file=sys.stderr)
        controller = RobotController(chain, robot, on_state=on_state, on_event=on_event)
        controller.start()
    except BaseException:  # cleanup only: the error itself goes on to the CLI's one-line report
        chain.close()
        raise
    return controller
