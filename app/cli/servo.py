"""``sensnake servo get|set|dump|restore|reset|zero|reboot|torque|led [--robot PORT | --config LAB.toml] …``: the
servos' control tables without Dynamixel Wizard, through :mod:`app.core.servo_settings` (the rules: one read per
servo, read before write, torque off around an EEPROM write, range checks, read-back, nothing that would cut the app
off from a servo). The port is opened here, on the main thread; the control loop does not run, so nothing else uses
the bus meanwhile. The port is ``--robot``'s, else the ``[robot] port`` of ``--config``.

    sensnake servo get --robot /dev/ttyUSB0 --id 3                      every item of servo 3
    sensnake servo set --robot sim --id 3 "Position P Gain" 640         one item
    sensnake servo dump --robot /dev/ttyUSB0 --out servos.json          every servo to a new file
    sensnake servo restore servos.json --robot /dev/ttyUSB0 [--id 3]    back, differences only, all checked first
    sensnake servo zero --config my_lab.toml                            the straight pose becomes 0 rad
    sensnake servo reset --robot /dev/ttyUSB0 --id 3 --yes              factory settings, ID and baud kept
    sensnake servo reboot --robot /dev/ttyUSB0 --id 5                   clears a latched hardware error (or --all)
    sensnake servo torque on|off --robot /dev/ttyUSB0 [--id 5 | --all]  torque on holds each joint where it is
    sensnake servo led on|off --robot /dev/ttyUSB0 [--id 5 | --all]     find a servo on the robot
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from app.cli._robot import reworded, robot_config, usage_error

if TYPE_CHECKING:
    from devices.config import RobotConfig
    from devices.servo_chain import ServoChain

ONE_SERVO = ("get", "set", "reset")


def run(args: argparse.Namespace) -> int:
    from app.core import servo_settings as ss
    from devices import control_table as ct
    from devices.servo_chain import ServoChain

    action = args.servo_command
    for sid in args.ids or ():
        if not 0 <= sid <= ct.MAX_ID:
            why = " (the broadcast ID: every servo hears it, none answers to it as its own)" if sid == ct.BROADCAST_ID else ""
            raise ValueError(f"--id {sid} is not a servo ID: IDs are 0 … {ct.MAX_ID}{why}")
    if action == "zero":
        if not args.config:
            raise ValueError("servo zero needs --config FILE: the lab config whose [robot] zero_offsets_rad it sets "
                             "(copy resources/default_lab.toml to start one)")
        return _zero(args, robot_config(args))
    if action == "reboot" and not (args.ids or args.all):
        usage_error(args, "servo reboot needs --id N (repeatable) or --all: a rebooted servo comes back with torque "
                          "off, so a joint carrying load drops")
    robot = robot_config(args)
    ids = list(dict.fromkeys(args.ids)) if args.ids else list(robot.joint_ids)
    if action in ONE_SERVO and len(ids) != 1:
        raise ValueError(f"servo {action} needs one --id N (the servo to {'read' if action == 'get' else 'write'})")
    if action == "set":
        ss.check_value(ss.item(args.item), args.value)  # refused before the port is opened
    if action == "restore":
        document = ss.read_document(args.settings)  # the whole file checked before the port is opened
    if action == "dump":
        ss.check_new_file(args.out)
    if action == "reset" and not args.yes:
        raise ValueError(f"a factory reset erases servo {ids[0]}'s settings (gains, limits, Return Delay Time, …; "
                         "its ID and baud rate are kept): save them first with 'sensnake servo dump', then add --yes")
    with ServoChain(robot, device="robot") as chain:
        if action == "restore":
            return _restore(chain, document, ids if args.ids else None, args.settings)
        return _act(args, chain, ids)


def _act(args: argparse.Namespace, chain: ServoChain, ids: list[int]) -> int:
    """Every action but ``restore`` and ``zero``, on the open chain."""
    from app.core import servo_settings as ss
    from devices import control_table as ct

    action = args.servo_command
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
        ss.factory_reset(chain, ids[0])
        print(f"servo {ids[0]}: factory settings restored (ID and baud rate kept); it answers again, torque off")
        return 0
    if action == "dump":
        document = ss.dump(chain, ids)
        ss.write_document(args.out, document)
        print(f"{len(ids)} servo(s), {len(ct.XM430_W350_ITEMS)} items each, written to {args.out}")
        return 0
    if action == "reboot":
        return _reboot(chain, ids)
    if action == "torque":
        return _torque(chain, ids, args.state == "on")
    if action == "led":
        for sid in ids:
            chain.set_led(sid, args.state == "on")
        print(f"LED {args.state}: servo(s) {_id_list(ids)}")
        return 0
    raise ValueError(f"unknown servo action {action!r}")  # the parser offers no other


def _restore(chain: ServoChain, document: dict[str, object], ids: list[int] | None, source: str) -> int:
    from app.core import servo_settings as ss
    from app.core.errors import SettingsError

    try:
        changes = ss.restore(chain, document, ids)
    except SettingsError as exc:  # the servos' checks and a refusal midway: the line names the file too
        raise SettingsError(f"{source}: {exc}") from exc
    written = [c for c in changes if c.written]
    for change in written:
        print(f"servo {change.servo_id}: {change.item} {change.before} → {change.after}")
    servos = len({c.servo_id for c in changes})
    print(f"restored {servos} servo(s) from {source}: {len(written)} item(s) written, "
          f"{len(changes) - len(written)} already as saved", file=sys.stderr)
    return 0


def _reboot(chain: ServoChain, ids: list[int]) -> int:
    """Reboot each servo, then read its Hardware Error Status and say it. A servo that does not come back, or still
    reports an error afterwards, does not stop the others; the command then fails naming them."""
    from app.cli._robot import hardware_error
    from app.core import servo_settings as ss
    from devices import control_table as ct
    from devices.errors import DeviceError

    problems = []
    rebooted = []
    for sid in ids:
        try:
            before, after = ss.reboot(chain, sid)
        except DeviceError as exc:
            problems.append(f"servo {sid}: {' '.join(str(exc).split())}")
            continue
        rebooted.append(sid)
        print(f"servo {sid}: rebooted (torque off); Hardware Error Status {_status(before)} → {_status(after)}")
        if after:
            still = hardware_error(sid, ct.hardware_error_names(after), "still set after the reboot")
            problems.append(str(still))
    if problems:
        done = f" (rebooted: {_id_list(rebooted)})" if rebooted and len(ids) > 1 else ""
        raise RuntimeError("; ".join(problems) + done)
    return 0


def _status(value: int | None) -> str:
    from devices import control_table as ct

    if value is None:
        return "unread (it answered no read)"
    return f"{value} ({', '.join(ct.hardware_error_names(value)) or 'no error'})"


def _torque(chain: ServoChain, ids: list[int], on: bool) -> int:
    """Torque on (each joint held where it is: goals = present first) or off, servo by servo, acknowledged."""
    from devices.errors import ServoHardwareError

    try:
        chain.set_torque(on, ids)
    except ServoHardwareError as exc:
        raise reworded(exc, "its torque stays off") from None
    held = " (each holding where it is)" if on else " (limp: a joint carrying load drops)"
    print(f"torque {'on' if on else 'off'}: servo(s) {_id_list(ids)}{held}")
    return 0


def _id_list(ids: list[int]) -> str:
    return ", ".join(str(i) for i in ids)


def _zero(args: argparse.Namespace, robot: RobotConfig) -> int:
    """The present pose becomes every joint's 0: reads the angles, shows them before and after, and writes the new
    ``zero_offsets_rad`` into ``--config`` (the old file kept as ``<name>.bak-N``), then checks the file loads."""
    from app.core import servo_settings as ss
    from devices.config import load_config
    from devices.errors import ServoHardwareError
    from devices.servo_chain import ServoChain

    with ServoChain(robot, device="robot") as chain:
        chain.check_models()
        try:
            present = [float(a) for a in chain.read_state().position_rad]
        except ServoHardwareError as exc:  # nothing moves here: never "motion stopped"
            raise reworded(exc, "found while reading the pose, nothing written") from None
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
