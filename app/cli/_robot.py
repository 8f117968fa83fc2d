"""CLI plumbing shared by the robot commands (``scan``, ``teach``, ``play``): the robot config from the options,
and a checked :class:`devices.controller.RobotController`. Not a command itself (the leading underscore keeps it out
of the parser's list). Called from the CLI's main thread.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from devices.config import MAX_BAUD, LabConfig, RobotConfig, load_config

if TYPE_CHECKING:
    from devices.controller import RobotController

BUS_TIMEOUT_S = 5.0  # how long a command waits for one job on the bus thread (torque, capture, hold)


def robot_config(args: argparse.Namespace) -> RobotConfig:
    """The robot config from ``--config`` (or the defaults) with ``--robot`` and ``--baud`` (bps) applied.

    ValueError for a non-positive ``--baud``; ConfigError (a ValueError) for a bad config file."""
    config = load_config(args.config) if getattr(args, "config", None) else LabConfig()
    robot = replace(config.robot, port=args.robot.strip())
    if args.baud is not None:
        if args.baud <= 0:
            raise ValueError(f"--baud must be a positive rate in bps, got {args.baud}")
        if args.baud > MAX_BAUD:
            raise ValueError(f"--baud {args.baud} is faster than any serial port here (at most {MAX_BAUD} bps)")
        robot = replace(robot, baud=int(args.baud))
    return robot


def start_controller(robot: RobotConfig, on_state: Callable[[Any], None] | None = None) -> RobotController:
    """Open the robot's bus, check every configured servo answers with the expected model, check the bus can keep
    ``robot.control_rate_hz`` (baud, servo count, each servo's Return Delay Time: refused, or a warning on stderr,
    with the fix), and start the control loop. Raises PortOpenError / NoReplyError / ModelMismatchError / RateError
    (one clear line each) with the port closed again. The caller owns the returned controller and must ``close()``
    it."""
    from devices.controller import RobotController
    from devices.servo_chain import ServoChain

    chain = ServoChain(robot, device="robot")
    chain.open()
    try:
        chain.check_models()
        warning = chain.check_rate(robot.control_rate_hz)
        if warning:
            print(f"sensnake: warning: {warning}", file=sys.stderr)
        controller = RobotController(chain, robot, on_state=on_state)
        controller.start()
    except BaseException:  # cleanup only: the error itself goes on to the CLI's one-line report
        chain.close()
        raise
    return controller
