"""``sensnake teach --robot PORT [--baud B] [--after SECONDS] --out SHAPE.json`` (SPEC §1).

Torque off, a person poses the robot by hand, the pose is captured after Enter (or after ``--after`` seconds), then
torque comes back on holding the captured pose (goals = present first, so nothing jumps) and the shape is written.
A servo in hardware error is refused at connect, before anyone poses the robot; the message names the command that
clears it (``sensnake servo reboot --id N``). Without ``--robot`` the port is the ``--config`` file's.
The robot is driven through :class:`devices.controller.RobotController` and :class:`app.core.teach.TeachSession`, the
same code as the Teach tab. Runs on the main thread; bus work happens on the controller thread.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
from pathlib import Path

from app.cli._robot import BUS_TIMEOUT_S, reworded, robot_config, start_controller
from app.core.shapes import Shape, write_shape
from app.core.teach import TeachSession
from devices.errors import ServoHardwareError


def run(args: argparse.Namespace) -> int:
    if args.after is not None and not (math.isfinite(args.after) and args.after >= 0):
        raise ValueError(f"--after must be 0 s or more, got {args.after}")
    out = Path(args.out)
    robot = robot_config(args)
    controller = start_controller(robot)
    try:
        session = TeachSession(controller.submit, robot, controller.set_torque)
        session.torque_off().result(timeout=BUS_TIMEOUT_S)
        if args.after is not None:
            print(f"torque off on {robot.n_joints} joints: pose the robot by hand; capturing in {args.after:g} s")
            # Waiting on an Event (not sleep) keeps Ctrl+C responsive on every platform.
            threading.Event().wait(args.after)
        else:
            print(f"torque off on {robot.n_joints} joints: pose the robot by hand, then press Enter to capture")
            if sys.stdin.readline() == "":
                raise RuntimeError("standard input closed before Enter: nothing captured (use --after SECONDS)")
        # Nothing moves while the robot is posed by hand: a hardware error then says so, never "motion stopped".
        try:
            pose = session.capture().result(timeout=BUS_TIMEOUT_S)
        except ServoHardwareError as exc:
            raise reworded(exc, "found at the capture, nothing moved, no shape written") from None
        try:
            session.hold().result(timeout=BUS_TIMEOUT_S)
        except ServoHardwareError as exc:
            raise reworded(exc, "its torque stays off, the pose is not held and the shape not written") from None
    finally:
        controller.close()
    shape = Shape(out.stem, tuple(robot.axes), tuple(float(a) for a in pose.angles_rad))
    write_shape(shape, out)
    angles = " ".join(f"{a:+.3f}" for a in pose.angles_rad)
    print(f"captured and holding (torque on): {angles} rad")
    print(f"wrote {out}")
    return 0
