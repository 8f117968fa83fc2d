"""``sensnake scan --robot PORT [--baud B | --all-bauds] [--config LAB.toml]`` (SPEC §1): list the servos answering
on a bus. Without ``--robot`` the port is the config's ``[robot] port``.

One line per servo on stdout: ID, model name and number, firmware, baud rate. Exits 1 with one line on stderr when
nothing answers, or when two servos answer to one ID (their replies collide; the line names the ID, the configured
IDs that did not answer and the fix); a configured joint that does not answer is a warning line, and so is a servo
that answers pings only (Status Return Level 0: found by its PING, which a servo answers at every level; its line
and the warning say what the level means and how to bring 2 back) or pings and reads (level 1). ``--all-bauds``
tries every Dynamixel baud rate (about 12 s in all: a broadcast ping waits its full window at each rate) and reports
progress on stderr. Runs on the main thread, which owns the port here.
"""

from __future__ import annotations

import argparse
import sys

from app.cli._robot import robot_config

EXIT_NOTHING_FOUND = 1
EXIT_ID_CONFLICT = 1  # two servos answer to one ID


def run(args: argparse.Namespace) -> int:
    from devices.control_table import BAUD_RATES_BPS, MAX_ID, STATUS_RETURN_ALL
    from devices.servo_chain import ServoChain, scan_problems

    robot = robot_config(args)
    # Fastest rates first: they are the likely ones and their broadcast window is the shortest.
    bauds = sorted(BAUD_RATES_BPS.values(), reverse=True) if args.all_bauds else [robot.baud]
    found = []
    with ServoChain(robot, device="robot") as chain:
        for baud in bauds:
            if args.all_bauds:
                print(f"scanning {robot.port} at {baud} bps …", file=sys.stderr, flush=True)
            found += chain.scan(bauds=[baud])
    if not found:
        where = "any Dynamixel baud rate" if args.all_bauds else f"{robot.baud} bps"
        hint = "" if args.all_bauds else " or try --all-bauds"
        print(f"sensnake scan: error: no servo answered on {robot.port} at {where}: check the servo power and "
              f"cable{hint}", file=sys.stderr)
        return EXIT_NOTHING_FOUND
    for info in found:
        if info.collided:
            print(f"ID {info.servo_id:3d}  ?  two servos answer (garbled or double replies)  {info.baud} bps")
            continue
        level = info.status_return_level
        quiet = f"  Status Return Level {level}: {'pings only' if level == 0 else 'pings and reads only'}" \
            if level is not None and level < STATUS_RETURN_ALL else ""
        print(f"ID {info.servo_id:3d}  {info.model_name} (model {info.model_number})  firmware {info.firmware}  "
              f"{info.baud} bps{quiet}")
    problems = scan_problems(found, robot.joint_ids, range(MAX_ID + 1))
    for problem in problems:
        print(f"sensnake scan: {'error' if 'same ID' in problem else 'warning'}: {problem}", file=sys.stderr)
    return EXIT_ID_CONFLICT if any(info.collided for info in found) else 0
