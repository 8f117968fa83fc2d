"""Reading and writing servos' control tables without Dynamixel Wizard: every item of a servo in one read,
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

- **never cut off**: a value that would leave the app unable to talk to the servo (Status Return Level below 2,
  Protocol Type 1) is refused with the reason (:func:`devices.control_table.cut_off_reason`).

The settings file (``sensnake-servos`` v1, JSON): ``{"format", "version", "servos": {"<id>": {"model_number": N,
"items": {"<item name>": value, …}}}}`` with every item as read. A restore writes only the writable items that are
neither volatile (torque, LED, goals: the state of the moment) nor identity (ID, baud rate: changing them would lose
the servo on the bus), and only where they differ. The whole file is checked against the servos present before
anything is written (each servo answers and is the file's model, every value may be written, the limits are in
order); a servo that refuses a value midway stops the restore with a message naming what was and was not written.

Files are written through a temporary created exclusively beside the target (never through a symbolic link planted
at its name); a settings file never replaces an existing file, a lab config is rewritten only after its backup.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import stat
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from app.core import outputs
from app.core.errors import SettingsError
from app.core.outputs import create_temporary, write_new_file
from devices import control_table as ct
from devices.errors import DeviceError, NoReplyError
from devices.toml_files import read_json_file

FORMAT = "sensnake-servos"
VERSION = 1
# The largest settings file read: a dump of all 253 IDs, every item, is about 0.5 MB.
MAX_SETTINGS_BYTES = 4_000_000
RESTART_TIMEOUT_S = 2.0  # a servo restarting (reboot, factory reset) answers a ping again within this
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

    def reboot(self, servo_id: int) -> None: ...


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
    meaningless = ct.invalid_reason(entry.name, value)  # in range, yet no value of it (Operating Mode 2)
    if meaningless:
        raise SettingsError(meaningless)
    cut_off = ct.cut_off_reason(entry.name, value)
    if cut_off:
        raise SettingsError(f"{entry.name} = {value} would cut the app off from the servo: {cut_off}")


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
    answers again (torque off) and returns its table as it is now. Also brings back a servo that answers only pings
    (Status Return Level 0, see :func:`_restart`)."""
    _restart(bus, servo_id, bus.factory_reset, "a factory reset")
    return read_table(bus, servo_id)


def reboot(bus: Bus, servo_id: int) -> tuple[int | None, int]:
    """Reboot one servo (the Reboot instruction: it clears a latched hardware error, keeps its position and comes
    back with torque off and its RAM items at their defaults); waits until it answers again. Returns its Hardware
    Error Status before (None when it did not answer a read) and after."""
    before: int | None
    try:
        before = bus.read_item(servo_id, "Hardware Error Status")
    except NoReplyError:
        before = None  # it answers pings only, perhaps (Status Return Level 0): the reboot brings it back
    _restart(bus, servo_id, bus.reboot, "a reboot")
    return before, bus.read_item(servo_id, "Hardware Error Status")


def _restart(bus: Bus, servo_id: int, instruction: Callable[[int], None], what: str) -> None:
    """Send an instruction after which the servo restarts, and wait until it answers again. A servo that answers
    nothing but pings (Status Return Level 0) sends no status packet for the instruction, yet carries it out and
    comes back answering everything (the level is a RAM item, back at its default 2): its silence to the
    instruction is then no failure, the ping that follows is the proof. NoReplyError when nothing answers."""
    try:
        instruction(servo_id)
    except NoReplyError:
        deadline = time.monotonic() + RESTART_TIMEOUT_S
        while not _answers(bus, servo_id):
            if time.monotonic() > deadline:
                raise NoReplyError(servo_id, f"to {what}, nor to a ping within {RESTART_TIMEOUT_S:g} s of it") \
                    from None


def baud_note(change: Change) -> str:
    """What a user does after a baud-rate change (empty for other items)."""
    if change.item != "Baud Rate" or not change.written:
        return ""
    bps = ct.BAUD_RATES_BPS.get(change.after, change.after)
    return (f"servo {change.servo_id} now talks at {bps} bps and no longer answers on this bus's rate (torque off): "
            f"set the other servos to the same rate, then connect at {bps} (--baud {bps}, or the Hardware tab's Baud)")


def _answers(bus: Bus, servo_id: int) -> bool:
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
    """Write ``document`` into a NEW file at ``path``, whole or not at all; an existing file is never replaced (a
    settings file may be the only copy of a servo's settings), and a device, FIFO or socket is refused."""
    text = json.dumps(document, indent=1, sort_keys=False) + "\n"
    return write_new_file(path, text.encode("utf-8"), _KEPT)


@dataclass(frozen=True)
class _Temporary:
    fd: int
    path: str


def _temporary_beside(path: Path, mode: int | None = None) -> _Temporary:
    """A hidden temporary in ``path``'s folder (:func:`app.core.outputs.create_temporary`): an unpredictable name
    carrying this process's pid, opened with O_CREAT | O_EXCL | O_NOFOLLOW, so a file or symbolic link planted there
    is never written through; one a killed writer left is removed here. Its mode is ``mode``, else what any new file
    of the user gets (0666 less the umask)."""
    fd, work = create_temporary(path, ".tmp", 0o600)
    try:
        os.fchmod(fd, _new_file_mode() if mode is None else mode)
    except OSError:
        os.close(fd)
        os.unlink(work)
        raise
    return _Temporary(fd, str(work))


def _new_file_mode() -> int:
    """0666 less the process's umask, read without changing it where the system says it (Linux)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text(encoding="ascii").splitlines():
            if line.startswith("Umask:"):
                return 0o666 & ~int(line.split()[1], 8)
    mask = os.umask(0o022)  # elsewhere: read by setting it, and set back at once
    os.umask(mask)
    return 0o666 & ~mask


def _special_kind(mode: int) -> str | None:
    """What a file that is not a regular file is, in words (None for a regular file)."""
    for test, kind in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return None if stat.S_ISREG(mode) else "not a regular file"


_KEPT = ("a settings file is never written over (it may be the only copy of those settings); choose a new name, or "
         "remove the old file first")


def check_new_file(path: str | os.PathLike[str]) -> None:
    """OSError (the message naming ``path``) when something is at ``path`` (a file, a symbolic link, a device, …:
    FileExistsError) or its folder is missing (FileNotFoundError): a settings file is only ever written as a new file
    (:func:`write_document`). OSErrors, so a caller handling a failed write handles these too."""
    outputs.check_new_file(path, _KEPT)


def _servo_key(source: Path, key: object) -> int:
    """A settings file's servo key as an ID: the decimal number a dump writes, 0 … 252."""
    if isinstance(key, str) and key.isascii() and key.isdigit() and str(int(key)) == key and int(key) <= ct.MAX_ID:
        return int(key)
    why = " (254 is the broadcast ID: every servo hears it, none answers to it as its own)" \
        if key == str(ct.BROADCAST_ID) else ""
    raise SettingsError(f"{source}: servo {key!r} is not a servo ID: servos are keyed by their ID, a whole number "
                        f"0 … {ct.MAX_ID}{why}")


def _shown(value: object) -> str:
    """A file's value in a message: whole when short, else its start and its length (a 400-digit number, a long
    text)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**12:
        return f"a {len(str(abs(value)))}-digit integer"
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:30]}… ({len(text)} characters)"


def _restorable(entry: ct.Item) -> bool:
    return entry.writable and entry.name not in NOT_RESTORED


# Items whose two values must stay in order on a servo: (the lower, the higher).
ORDERED_PAIRS = (("Min Position Limit", "Max Position Limit"), ("Min Voltage Limit", "Max Voltage Limit"))


def _check_order(values: dict[str, int], where: str) -> None:
    for low, high in ORDERED_PAIRS:
        if low in values and high in values and values[low] > values[high]:
            raise SettingsError(f"{where}: {low} = {values[low]} is above {high} = {values[high]} (the servo would "
                                "have no room to move)")


def read_document(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A settings file, checked whole before anything uses it: SettingsError naming the file, the servo, the item
    and what is wrong. Returned with its item names as the e-manual spells them (a file may use any case)."""
    path = Path(path)
    # Only a regular file of at most MAX_SETTINGS_BYTES is read: a FIFO would block, /dev/zero fill the memory. A
    # servo given twice is refused: json would restore one of them without a word.
    document = read_json_file(path, "servo settings file", SettingsError, MAX_SETTINGS_BYTES,
                              refuse_repeated_keys=True)
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise SettingsError(f"{path}: not a servo settings file (format {FORMAT!r} expected)")
    if document.get("version") != VERSION:
        raise SettingsError(f"{path}: settings file version {document.get('version')!r}; this app reads {VERSION}")
    servos = document.get("servos")
    if not isinstance(servos, dict) or not servos:
        raise SettingsError(f"{path}: no servos in it")
    checked: dict[str, Any] = {}
    for key, entry in servos.items():
        sid = _servo_key(path, key)
        if not isinstance(entry, dict) or not isinstance(entry.get("items"), dict):
            raise SettingsError(f"{path}: servo {key!r} is malformed (expected {{'items': {{name: value}}}})")
        where = f"{path}: servo {sid}"
        items: dict[str, int] = {}
        for name, value in entry["items"].items():
            try:
                found = item(name)
            except SettingsError as exc:
                raise SettingsError(f"{where}: {exc}") from None
            if found.name in items:
                raise SettingsError(f"{where}: {found.name} is given twice")
            if not isinstance(value, int) or isinstance(value, bool):
                raise SettingsError(f"{where}, {found.name}: {_shown(value)} is not an integer")
            if abs(value) > 2**32:  # no item holds more than 4 bytes: the number is named, not printed whole
                raise SettingsError(f"{where}, {found.name}: {_shown(value)} is beyond any control-table item "
                                    "(4 bytes at most)")
            if _restorable(found):
                try:
                    check_value(found, value)
                except SettingsError as exc:
                    raise SettingsError(f"{where}: {exc}") from None
            items[found.name] = value
        models = {value for value in (entry.get("model_number"), items.get("Model Number")) if value is not None}
        if len(models) != 1 or not all(isinstance(m, int) and not isinstance(m, bool) for m in models):
            what = "two model numbers" if len(models) > 1 else "no model_number" if not models else "a model_number " \
                "that is not an integer"
            raise SettingsError(f"{where} has {what}: which servo model its items are for is unknown "
                                "(a dump writes it)")
        _check_order(items, where)
        checked[str(sid)] = {"model_number": models.pop(), "items": items}
    return {"format": FORMAT, "version": VERSION, "servos": checked}


@dataclass(frozen=True)
class _Planned:
    """One servo's restore, checked: every restorable item of the file with the value the servo holds now."""

    servo_id: int
    items: tuple[tuple[str, int, int], ...]  # (item, present value, saved value)


def restore(bus: Bus, document: dict[str, Any], ids: Sequence[int] | None = None) -> list[Change]:
    """Write back the restorable items of ``document`` (all its servos, or ``ids``) where the servo differs; every
    item considered is returned (``written`` False where it already held the value).

    Every servo is checked before anything is written: it answers, it is the model the file was made for, each
    value may be written, the position and voltage limits stay in order (SettingsError naming the servo and the
    item; nothing written). A servo that refuses a write midway (or stops answering) ends the restore with a
    SettingsError naming the servos and items that were written and those that were not."""
    servos = document["servos"]
    chosen = [int(sid) for sid in servos] if ids is None else list(ids)
    missing = [sid for sid in chosen if str(sid) not in servos]
    if missing:
        raise SettingsError(f"the settings file has no servo {', '.join(str(m) for m in missing)}")
    plans = [_plan(bus, sid, servos[str(sid)]) for sid in chosen]
    changes: list[Change] = []
    for index, plan in enumerate(plans):
        for position, (name, present, saved) in enumerate(plan.items):
            if present == saved:
                changes.append(Change(plan.servo_id, name, saved, saved, written=False))
                continue
            try:
                changes.append(set_item(bus, plan.servo_id, name, saved))
            except (SettingsError, DeviceError) as exc:
                left = [(plan.servo_id, plan.items[position:])] + [(p.servo_id, p.items) for p in plans[index + 1:]]
                raise SettingsError(_stopped_message(plan.servo_id, name, saved, exc, changes, left)) from exc
    return changes


def _plan(bus: Bus, servo_id: int, saved: dict[str, Any]) -> _Planned:
    """Check one servo of a settings file against the servo on the bus (see :func:`restore`); reads its table."""
    try:
        present = read_table(bus, servo_id)
    except NoReplyError:
        raise SettingsError(f"servo {servo_id} of the settings file does not answer on this bus: nothing written "
                            "(check its cable and power; --id restores the others)") from None
    model = saved.get("model_number", saved["items"].get("Model Number"))
    if model != present["Model Number"]:
        raise SettingsError(f"servo {servo_id}: the settings file is for model {model} ({ct.model_name(model)}), but "
                            f"servo {servo_id} is model {present['Model Number']} "
                            f"({ct.model_name(present['Model Number'])}): nothing written")
    after = dict(present)
    planned = []
    for name, value in saved["items"].items():
        entry = ct.ITEMS_BY_NAME.get(name)
        if entry is None:
            raise SettingsError(f"servo {servo_id}: no control-table item {name!r}: nothing written")
        if not _restorable(entry):
            continue
        try:
            check_value(entry, value)
        except SettingsError as exc:
            raise SettingsError(f"servo {servo_id}: {exc}: nothing written") from None
        after[name] = value
        planned.append((name, present[name], value))
    _check_order(after, f"servo {servo_id} after the restore")
    return _Planned(servo_id, tuple(planned))


def _stopped_message(servo_id: int, name: str, value: int, exc: BaseException, changes: Sequence[Change],
                     left: Sequence[tuple[int, Sequence[tuple[str, int, int]]]]) -> str:
    """One line: which write failed and why, what was written before it, what was not written."""
    def by_servo(pairs: Iterable[tuple[int, str]]) -> str:
        grouped: dict[int, list[str]] = {}
        for sid, item_name in pairs:
            grouped.setdefault(sid, []).append(item_name)
        return "; ".join(f"servo {sid} ({', '.join(names)})" for sid, names in grouped.items()) or "nothing"

    written = by_servo((c.servo_id, c.item) for c in changes if c.written)
    not_written = by_servo((sid, item_name) for sid, items in left for item_name, present, saved in items
                           if present != saved)
    return (f"restore stopped at servo {servo_id}, {name} = {value}: {' '.join(str(exc).split())}. Written: "
            f"{written}. Not written: {not_written}")


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
    added when there is none). A config reached through a symbolic link is rewritten where it lives (the link
    kept); one that is not a regular file (a device, a FIFO) is refused before it is read."""
    path = Path(os.path.realpath(config_path))
    try:
        info = os.stat(path)
    except OSError as exc:
        raise SettingsError(f"{config_path}: cannot read the lab config ({exc.strerror or exc})") from None
    kind = _special_kind(info.st_mode)
    if kind is not None:
        raise SettingsError(f"{config_path} is {kind}, not a lab config: nothing written")
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
    mode = stat.S_IMODE(info.st_mode)
    backup = _write_backup(path, text.encode("utf-8"), mode)
    temporary = _temporary_beside(path, mode)
    try:
        with os.fdopen(temporary.fd, "w", encoding="utf-8") as file:
            file.write("\n".join(lines) + "\n")
        os.replace(temporary.path, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary.path)
    return backup


def _write_backup(path: Path, content: bytes, mode: int) -> Path:
    """``content`` into ``<name>.bak-N`` beside ``path``, the first N free: each candidate is created exclusively
    (O_CREAT | O_EXCL | O_NOFOLLOW), so an older backup, or a link planted at the name, is never written through."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
    for n in range(1, 10_000):
        candidate = path.with_name(f"{path.name}.bak-{n}")
        try:
            fd = os.open(candidate, flags, mode)
        except FileExistsError:
            continue
        try:
            os.fchmod(fd, mode)  # the config's own mode, whatever the umask
            with os.fdopen(fd, "wb") as file:
                file.write(content)
        except BaseException:
            candidate.unlink(missing_ok=True)
            raise
        return candidate
    raise SettingsError(f"{path}: too many backups beside it; remove some")
