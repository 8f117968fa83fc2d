"""Reading and writing servos' control tables without Dynamixel Wizard (issue 26): every item of a servo in one read,
a checked write of one item, and a settings file to back servos up and restore them. Qt-free; the ``sensnake servo``
commands run it on a :class:`devices.servo_chain.ServoChain` they own.

The rules Wizard's users ask for (DynamixelSDK issues #160, #269, #274, #306):

- **one request per servo** for the whole table (a read of addresses 0…147), decoded item by item;
- **read before write**: an item that already holds the value is not written (spares the EEPROM, which takes a
  limited number of writes);
- **EEPROM items need torque off**: a servo whose torque is on gets it turned off for the write and back on after
  (the servo refuses an EEPROM write otherwise);
- **range checked** before anything is sent, naming the item and its range; read-only items are refused;
- **confirmed**: every write is read back; a value that did not stick is an error naming the servo and the item.

The settings file (``sensnake-servos`` v1, JSON): ``{"format", "version", "servos": {"<id>": {"model_number": N,
"items": {"<item name>": value, …}}}}`` with every item as read. A restore writes only the writable items that are
neither volatile (torque, LED, goals: the state of the moment) nor identity (ID, baud rate: changing them would lose
the servo on the bus), and only where they differ.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from app.core.errors import SettingsError
from devices import control_table as ct

FORMAT = "sensnake-servos"
VERSION = 1
# Items a restore never writes: the moment's state, and what would lose the servo on the bus.
NOT_RESTORED = frozenset({"Torque Enable", "LED", "Goal PWM", "Goal Current", "Goal Velocity", "Goal Position",
                          "ID", "Baud Rate", "Registered Instruction"})
# Units from the XM430-W350 e-manual ("Control Table"), for display.
UNITS = {
    "Return Delay Time": "2 µs", "Homing Offset": "0.088°", "Moving Threshold": "0.229 rpm",
    "Temperature Limit": "°C", "Max Voltage Limit": "0.1 V", "Min Voltage Limit": "0.1 V", "PWM Limit": "0.113 %",
    "Current Limit": "2.69 mA", "Velocity Limit": "0.229 rpm", "Max Position Limit": "0.088°",
    "Min Position Limit": "0.088°", "Bus Watchdog": "20 ms", "Goal PWM": "0.113 %", "Goal Current": "2.69 mA",
    "Goal Velocity": "0.229 rpm", "Profile Acceleration": "214.577 rev/min²", "Profile Velocity": "0.229 rpm",
    "Goal Position": "0.088°", "Realtime Tick": "ms", "Present PWM": "0.113 %", "Present Current": "2.69 mA",
    "Present Velocity": "0.229 rpm", "Present Position": "0.088°", "Velocity Trajectory": "0.229 rpm",
    "Position Trajectory": "0.088°", "Present Input Voltage": "0.1 V", "Present Temperature": "°C",
}


class Bus(Protocol):
    """What this module needs of :class:`devices.servo_chain.ServoChain`."""

    def read_block(self, servo_id: int, address: int, length: int) -> bytes: ...

    def read_item(self, servo_id: int, name: str) -> int: ...

    def write_item(self, servo_id: int, name: str, value: int) -> None: ...

    def ping(self, servo_id: int) -> Any: ...

    def change_baud(self, servo_id: int, index: int) -> None: ...

    def factory_reset(self, servo_id: int) -> None: ...


@dataclass(frozen=True)
class Change:
    """One item a write or a restore considered: ``written`` False when it already held the value."""

    servo_id: int
    item: str
    before: int
    after: int
    written: bool


def item(name: str) -> ct.Item:
    """The control-table item called ``name`` (case-insensitive); SettingsError naming the close ones."""
    found = ct.ITEMS_BY_NAME.get(name) or next(
        (i for i in ct.XM430_W350_ITEMS if i.name.lower() == name.strip().lower()), None)
    if found is None:
        import difflib

        names = {i.name.lower(): i.name for i in ct.XM430_W350_ITEMS}
        close = [names[n] for n in difflib.get_close_matches(name.strip().lower(), names, n=4, cutoff=0.6)]
        close += [i.name for i in ct.XM430_W350_ITEMS if name.strip().lower() in i.name.lower() and i.name not in close]
        hint = f" (did you mean {', '.join(repr(c) for c in close[:4])}?)" if close else \
            " ('sensnake servo get --robot PORT --id N' lists them)"
        raise SettingsError(f"no control-table item {name!r} on the XM430-W350{hint}")
    return found


def read_table(bus: Bus, servo_id: int) -> dict[str, int]:
    """Every item of servo ``servo_id`` from ONE read of the whole table, by item name (signed where it is)."""
    raw = bus.read_block(servo_id, 0, ct.CONTROL_TABLE_SIZE)
    model = int.from_bytes(raw[0:2], "little")
    items = ct.TABLES_BY_MODEL.get(model)
    if items is None:
        known = ", ".join(str(m) for m in ct.TABLES_BY_MODEL)
        raise SettingsError(f"servo {servo_id} is model {model}, whose control table this app does not know (it knows "
                            f"model(s) {known}: the XM430-W350); add it to devices/control_table.TABLES_BY_MODEL")
    values = {}
    for entry in items:
        value = int.from_bytes(raw[entry.address:entry.address + entry.size], "little")
        values[entry.name] = ct.to_signed(value, entry.size) if entry.signed else value
    return values


def check_value(entry: ct.Item, value: int) -> None:
    """SettingsError unless ``value`` may be written to ``entry``."""
    if not entry.writable:
        raise SettingsError(f"{entry.name} is read-only")
    if not entry.minimum <= value <= entry.maximum:
        unit = f" ({UNITS[entry.name]} units)" if entry.name in UNITS else ""
        raise SettingsError(f"{entry.name} = {value} is out of its range {entry.minimum} … {entry.maximum}{unit}")


def set_item(bus: Bus, servo_id: int, name: str, value: int) -> Change:
    """Write ``name`` := ``value`` on one servo: range-checked, skipped when it already holds it, with torque turned
    off around an EEPROM write (and restored), confirmed by reading it back."""
    entry = item(name)
    check_value(entry, value)
    before = bus.read_item(servo_id, entry.name)
    if before == value:
        return Change(servo_id, entry.name, before, value, written=False)
    if entry.name == "Baud Rate":
        return _change_baud(bus, servo_id, before, value)
    if entry.name == "ID" and _answers(bus, value):
        raise SettingsError(f"ID {value} is already on the bus (a servo answers to it): choose a free ID, or two "
                            "servos would share it")
    torque_on = entry.eeprom and bus.read_item(servo_id, "Torque Enable") == 1
    if torque_on:
        bus.write_item(servo_id, "Torque Enable", 0)
    try:
        bus.write_item(servo_id, entry.name, value)
    finally:
        if torque_on and entry.name != "ID":
            bus.write_item(servo_id, "Torque Enable", 1)
    read_back_id = value if entry.name == "ID" else servo_id
    after = bus.read_item(read_back_id, entry.name)
    if after != value:
        raise SettingsError(f"servo {servo_id}: {entry.name} reads {after} after writing {value}: the write did not "
                            "stick")
    return Change(servo_id, entry.name, before, after, written=True)


def _change_baud(bus: Bus, servo_id: int, before: int, value: int) -> Change:
    """Move one servo to another baud rate: torque off (EEPROM), the write, and the servo found at its new rate and
    read back there (:meth:`devices.servo_chain.ServoChain.change_baud`). Its torque stays off: at the new rate it no
    longer hears this bus."""
    if bus.read_item(servo_id, "Torque Enable") == 1:
        bus.write_item(servo_id, "Torque Enable", 0)
    bus.change_baud(servo_id, value)
    return Change(servo_id, "Baud Rate", before, value, written=True)


def factory_reset(bus: Bus, servo_id: int) -> dict[str, int]:
    """Factory settings on one servo, keeping its ID and baud rate (Dynamixel Wizard's option); waits until it
    answers again (torque off) and returns its table as it is now."""
    bus.factory_reset(servo_id)
    return read_table(bus, servo_id)


def baud_note(change: Change) -> str:
    """What a user does after a baud-rate change (empty for other items)."""
    if change.item != "Baud Rate" or not change.written:
        return ""
    bps = ct.BAUD_RATES_BPS.get(change.after, change.after)
    return (f"servo {change.servo_id} now talks at {bps} bps and no longer answers on this bus's rate (torque off): "
            f"set the other servos to the same rate, then connect at {bps} (--baud {bps}, or the Hardware tab's Baud)")


def _answers(bus: Bus, servo_id: int) -> bool:
    from devices.errors import NoReplyError

    try:
        bus.ping(servo_id)
    except NoReplyError:
        return False
    return True


def dump(bus: Bus, ids: Iterable[int]) -> dict[str, Any]:
    """The settings document (module docstring) of servos ``ids``, each read in one request."""
    servos = {}
    for sid in ids:
        values = read_table(bus, sid)
        servos[str(sid)] = {"model_number": values["Model Number"], "items": values}
    return {"format": FORMAT, "version": VERSION, "servos": servos}


def write_document(path: str | os.PathLike[str], document: dict[str, Any]) -> Path:
    """Write ``document`` to ``path`` whole or not at all (a hidden temporary moved into place)."""
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        temporary.write_text(json.dumps(document, indent=1, sort_keys=False) + "\n", encoding="utf-8")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return path


def read_document(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A settings file, checked: SettingsError naming the file and what is wrong."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SettingsError(f"{path}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise SettingsError(f"{path}: not a servo settings file ({type(exc).__name__})") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise SettingsError(f"{path}: not a servo settings file (format {FORMAT!r} expected)")
    if document.get("version") != VERSION:
        raise SettingsError(f"{path}: settings file version {document.get('version')!r}; this app reads {VERSION}")
    servos = document.get("servos")
    if not isinstance(servos, dict) or not servos:
        raise SettingsError(f"{path}: no servos in it")
    for sid, entry in servos.items():
        if not sid.isdigit() or not isinstance(entry, dict) or not isinstance(entry.get("items"), dict):
            raise SettingsError(f"{path}: servo {sid!r} is malformed (expected {{'items': {{name: value}}}})")
        for name, value in entry["items"].items():
            if not isinstance(value, int) or isinstance(value, bool):
                raise SettingsError(f"{path}: servo {sid}, {name}: {value!r} is not an integer")
            if name in ct.ITEMS_BY_NAME and name not in NOT_RESTORED and ct.ITEMS_BY_NAME[name].writable:
                try:
                    check_value(ct.ITEMS_BY_NAME[name], value)
                except SettingsError as exc:
                    raise SettingsError(f"{path}: servo {sid}: {exc}") from None
    return document


def restore(bus: Bus, document: dict[str, Any], ids: Sequence[int] | None = None) -> list[Change]:
    """Write back the restorable items of ``document`` (all its servos, or ``ids``) where the servo differs; every
    item considered is returned (``written`` False where it already held the value)."""
    servos = document["servos"]
    chosen = [int(sid) for sid in servos] if ids is None else list(ids)
    missing = [sid for sid in chosen if str(sid) not in servos]
    if missing:
        raise SettingsError(f"the settings file has no servo {', '.join(str(m) for m in missing)}")
    changes = []
    for sid in chosen:
        saved = servos[str(sid)]["items"]
        present = read_table(bus, sid)
        for name, value in saved.items():
            entry = ct.ITEMS_BY_NAME.get(name)
            if entry is None or not entry.writable or name in NOT_RESTORED:
                continue
            if present.get(name) == value:
                changes.append(Change(sid, name, value, value, written=False))
            else:
                changes.append(set_item(bus, sid, name, value))
    return changes


def apply_profile(bus: Bus, ids: Iterable[int], profile: Sequence[tuple[str, int]]) -> list[Change]:
    """The lab's ``[servos]`` profile onto servos ``ids``: each servo's table is read once and compared; only the items
    that differ are written (with :func:`set_item`'s rules: torque off around EEPROM, read back). Every item considered
    is returned, ``written`` False where the servo already held it."""
    changes = []
    for sid in ids:
        present = read_table(bus, sid)
        for name, value in profile:
            if present.get(name) == value:
                changes.append(Change(sid, name, value, value, written=False))
            else:
                changes.append(set_item(bus, sid, name, value))
    return changes


def describe_changes(changes: Sequence[Change]) -> str:
    """One line: how many items were written on which servos, how many already held their value."""
    written = [c for c in changes if c.written]
    if not written:
        return f"all {len(changes)} item(s) already held their values: nothing written"
    servos = sorted({c.servo_id for c in written})
    items = sorted({c.item for c in written})
    return (f"{len(written)} item(s) written on servo(s) {', '.join(str(s) for s in servos)} "
            f"({', '.join(items)}); {len(changes) - len(written)} already held their values")


# -- zero pose ----------------------------------------------------------------------------------------------------
ZERO_KEY = "zero_offsets_rad"


def zero_offsets(old_offsets_rad: Sequence[float], present_rad: Sequence[float]) -> list[float]:
    """The offsets that make the present pose read 0 on every joint (angle = raw + offset, so new = old − present),
    rounded to 0.1 mrad (a tick is 1.5 mrad)."""
    if len(old_offsets_rad) != len(present_rad):
        raise ValueError(f"{len(old_offsets_rad)} offsets for {len(present_rad)} joints")
    return [round(float(old) - float(now), 4) + 0.0 for old, now in zip(old_offsets_rad, present_rad)]


def write_zero_offsets(config_path: str | os.PathLike[str], offsets_rad: Sequence[float]) -> Path:
    """Set ``[robot] zero_offsets_rad`` in the lab config at ``config_path`` (see :func:`write_robot_key`); returns
    the backup of the file as it was."""
    return write_robot_key(config_path, ZERO_KEY, [repr(float(v)) for v in offsets_rad])


def write_robot_key(config_path: str | os.PathLike[str], key: str, values: Sequence[str]) -> Path:
    """Set ``[robot] <key> = [values…]`` in the lab config at ``config_path``, keeping every other line (comments
    too); the file as it was is first copied to ``<name>.bak-N`` (a new name, never over an older backup), which is
    returned. The key's line is replaced where it is, or added at the top of ``[robot]`` (a ``[robot]`` table is
    added when there is none)."""
    path = Path(config_path)
    text = path.read_text(encoding="utf-8")
    line = f"{key} = [{', '.join(values)}]"
    lines = text.splitlines()
    section = None
    robot_at = None
    replaced = False
    for index, raw in enumerate(lines):
        header = re.match(r"\s*\[([^\[\]]+)\]\s*(#.*)?$", raw)
        if header:
            section = header.group(1).strip()
            if section == "robot" and robot_at is None:
                robot_at = index
            continue
        if section == "robot" and re.match(rf"\s*{key}\s*=", raw):
            if "]" not in raw:
                raise SettingsError(f"{path}: {key} spans several lines; put it on one line to have it set here")
            comment = raw[raw.index("]") + 1:].strip()
            lines[index] = line + (f"  {comment}" if comment.startswith("#") else "")
            replaced = True
    if not replaced:
        if robot_at is None:
            lines = ["[robot]", line, ""] + lines
        else:
            lines.insert(robot_at + 1, line)
    backup = _backup_name(path)
    shutil.copy2(path, backup)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")
        shutil.copymode(path, temporary)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return backup


def _backup_name(path: Path) -> Path:
    for n in range(1, 10_000):
        candidate = path.with_name(f"{path.name}.bak-{n}")
        if not candidate.exists():
            return candidate
    raise SettingsError(f"{path}: too many backups beside it; remove some")
