"""``sensnake servo get|set|dump|restore --robot PORT …`` (issue 26): the servos' control tables without Dynamixel
Wizard, through :mod:`app.core.servo_settings` (the rules: one read per servo, read before write, torque off around
an EEPROM write, range checks, read-back). The port is opened here, on the main thread; the control loop does not
run, so nothing else uses the bus meanwhile.

    sensnake servo get --robot /dev/ttyUSB0 --id 3                      every item of servo 3
    sensnake servo set --robot sim --id 3 "Position P Gain" 640         one item
    sensnake servo dump --robot /dev/ttyUSB0 --out servos.json          every servo to a file
    sensnake servo restore servos.json --robot /dev/ttyUSB0 [--id 3]    back, differences only
    sensnake servo zero --robot /dev/ttyUSB0 --config my_lab.toml       the straight pose becomes 0 rad
    sensnake servo reset --robot /dev/ttyUSB0 --id 3 --yes              factory settings, ID and baud kept
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from app.cli._robot import robot_config

if TYPE_CHECKING:
    from devices.config import RobotConfig


def run(args: argparse.Namespace) -> int:
    from app.core import servo_settings as ss
    from devices import control_table as ct
    from devices.servo_chain import ServoChain

    robot = robot_config(args)
    ids = list(args.ids) if args.ids else list(robot.joint_ids)
    action = args.servo_command
    if action == "zero":
        return _zero(args, robot)
    if action in ("get", "set", "reset") and len(ids) != 1:
        raise ValueError(f"servo {action} needs one --id N (the servo to {'read' if action == 'get' else 'write'})")
    if action == "set":
        ss.check_value(ss.item(args.item), args.value)  # refused before the port is opened
    if action == "restore":
        document = ss.read_document(args.settings)
    if action == "reset" and not args.yes:
        raise ValueError(f"a factory reset erases servo {ids[0]}'s settings (gains, limits, Return Delay Time, …; "
                         "its ID and baud rate are kept): save them first with 'sensnake servo dump', then add --yes")
    with ServoChain(robot, device="robot") as chain:
        if action == "get":
            values = ss.read_table(chain, ids[0])
            names = [ss.item(args.item).name] if args.item else [entry.name for entry in ct.XM430_W350_ITEMS]
            for name in names:
                entry = ct.ITEMS_BY_NAME[name]
                area = "EEPROM" if entry.eeprom else "RAM"
                access = "RW" if entry.writable else "R"
                span = f"{entry.minimum} … {entry.maximum}" if entry.writable else ""
                print(f"{entry.address:4d}  {entry.size}  {access:2s} {area:6s} {name:<24s} {values[name]:>10d}  "
                      f"{ss.UNITS.get(name, ''):<18s} {span}")
            return 0
        if action == "set":
            change = ss.set_item(chain, ids[0], args.item, args.value)
            if change.written:
                print(f"servo {change.servo_id}: {change.item} {change.before} → {change.after} (read back)")
                if ss.baud_note(change):
                    print(ss.baud_note(change), file=sys.stderr)
            else:
                print(f"servo {change.servo_id}: {change.item} already {change.after}: not written")
            return 0
        if action == "reset":
            chain.factory_reset(ids[0])
            print(f"servo {ids[0]}: factory settings restored (ID and baud rate kept); it answers again, torque off")
            return 0
        if action == "dump":
            document = ss.dump(chain, ids)
            ss.write_document(args.out, document)
            print(f"{len(ids)} servo(s), {len(ct.XM430_W350_ITEMS)} items each, written to {args.out}")
            return 0
        restore_ids = list(args.ids) if args.ids else None
        changes = ss.restore(chain, document, restore_ids)
    written = [c for c in changes if c.written]
    for change in written:
        print(f"servo {change.servo_id}: {change.item} {change.before} → {change.after}")
    servos = len({c.servo_id for c in changes})
    print(f"restored {servos} servo(s) from {args.settings}: {len(written)} item(s) written, "
          f"{len(changes) - len(written)} already as saved", file=sys.stderr)
    return 0


def _zero(args: argparse.Namespace, robot: RobotConfig) -> int:
    """The present pose becomes every joint's 0: reads the angles, shows them before and after, and writes the new
    ``zero_offsets_rad`` into ``--config`` (the old file kept as ``<name>.bak-N``), then checks the file loads."""
    from app.core import servo_settings as ss
    from devices.config import load_config
    from devices.servo_chain import ServoChain

    if not args.config:
        raise ValueError("servo zero needs --config FILE: the lab config whose [robot] zero_offsets_rad it sets "
                         "(copy resources/default_lab.toml to start one)")
    with ServoChain(robot, device="robot") as chain:
        chain.check_models()
        present = [float(a) for a in chain.read_state().position_rad]
    offsets = ss.zero_offsets(robot.zero_offsets_rad, present)
    print("joint  ID  present (rad)  → after   offset (rad) old → new")
    for k, (sid, now, old, new) in enumerate(zip(robot.joint_ids, present, robot.zero_offsets_rad, offsets)):
        print(f"J{k + 1:<4d} {sid:3d}  {now:+13.4f}  → {0.0:+.4f}   {old:+.4f} → {new:+.4f}")
    if args.dry_run:
        print("dry run: nothing written", file=sys.stderr)
        return 0
    backup = ss.write_zero_offsets(args.config, offsets)
    loaded = load_config(args.config).robot.zero_offsets_rad
    if [round(v, 4) for v in loaded] != offsets:
        raise RuntimeError(f"{args.config}: the offsets did not load back as written; the old file is {backup}")
    print(f"zero offsets written to {args.config} (the old file kept as {backup})", file=sys.stderr)
    return 0
