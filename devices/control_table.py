"""The Dynamixel XM430-W350 control table (Protocol 2.0) and its unit conversions.

One description shared by the driver (:mod:`devices.servo_chain`, which needs addresses and units) and the
simulated servo (:mod:`devices.sim.dxl_chain`, which needs sizes, access rights, defaults and ranges), so the two
cannot disagree about where Goal Position lives. Values follow the ROBOTIS e-manual for the XM430-W350.
Pure data: any thread may read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from devices.errors import (  # noqa: F401 - re-exported: the status packet's error numbers live with their error
    ERRNUM_ACCESS,
    ERRNUM_CRC,
    ERRNUM_DATA_LENGTH,
    ERRNUM_DATA_LIMIT,
    ERRNUM_DATA_RANGE,
    ERRNUM_INSTRUCTION,
    ERRNUM_NAMES,
    ERRNUM_RESULT_FAIL,
)

MODEL_NUMBER_XM430_W350 = 1020
MODEL_NAMES: dict[int, str] = {
    1020: "XM430-W350",
    1030: "XM430-W210",
    1060: "XL430-W250",
    1120: "XM540-W270",
    1200: "XW540-T260",
    1080: "XC430-W150",
}

BROADCAST_ID = 254
MAX_ID = 252

# Baud Rate (address 8) register value -> bits per second.
BAUD_RATES_BPS: dict[int, int] = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
BAUD_INDEX_FROM_BPS: dict[int, int] = {bps: index for index, bps in BAUD_RATES_BPS.items()}

TICKS_PER_REV = 4096
CENTER_TICKS = 2048
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
VELOCITY_RPM_PER_LSB = 0.229
RAD_S_PER_VELOCITY_LSB = VELOCITY_RPM_PER_LSB * 2.0 * math.pi / 60.0
ACCELERATION_RPM2_PER_LSB = 214.577
RAD_S2_PER_ACCELERATION_LSB = ACCELERATION_RPM2_PER_LSB * 2.0 * math.pi / 3600.0
CURRENT_MA_PER_LSB = 2.69
VOLTAGE_V_PER_LSB = 0.1
RETURN_DELAY_S_PER_LSB = 2e-6
MAX_RETURN_DELAY_S = 254 * RETURN_DELAY_S_PER_LSB  # Return Delay Time's largest value (254 units)

EEPROM_END = 64  # addresses below this are EEPROM: writable only with torque off

# Hardware Error Status (address 70) bits.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0: "input voltage error",
    2: "overheating",
    3: "motor encoder error",
    4: "electrical shock",
    5: "overload",
}
OVERLOAD_BIT = 5


def hardware_error_names(status: int) -> tuple[str, ...]:
    """Names of the bits set in a Hardware Error Status byte, lowest bit first."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if status & (1 << bit)]
    unknown = status & ~sum(1 << bit for bit in HARDWARE_ERROR_BITS) & 0xFF
    if unknown:
        names.append(f"unknown hardware error 0x{unknown:02X}")
    return tuple(names)


# Protocol 2.0 status packet error byte.
ERROR_ALERT_BIT = 0x80


@dataclass(frozen=True)
class Item:
    """One control-table entry: ``size`` bytes at ``address``, little-endian."""

    name: str
    address: int
    size: int
    writable: bool
    default: int = 0
    minimum: int = 0
    maximum: int = 0
    signed: bool = False

    @property
    def eeprom(self) -> bool:
        return self.address < EEPROM_END


XM430_W350_ITEMS: tuple[Item, ...] = (
    Item("Model Number", 0, 2, False, MODEL_NUMBER_XM430_W350),
    Item("Model Information", 2, 4, False, 0),
    Item("Firmware Version", 6, 1, False, 46),
    Item("ID", 7, 1, True, 1, 0, MAX_ID),
    Item("Baud Rate", 8, 1, True, 1, 0, 7),
    Item("Return Delay Time", 9, 1, True, 250, 0, 254),
    Item("Drive Mode", 10, 1, True, 0, 0, 13),
    Item("Operating Mode", 11, 1, True, 3, 0, 16),
    Item("Secondary ID", 12, 1, True, 255, 0, 255),
    Item("Protocol Type", 13, 1, True, 2, 1, 2),
    Item("Homing Offset", 20, 4, True, 0, -1_044_479, 1_044_479, signed=True),
    Item("Moving Threshold", 24, 4, True, 10, 0, 1023),
    Item("Temperature Limit", 31, 1, True, 80, 0, 100),
    Item("Max Voltage Limit", 32, 2, True, 160, 95, 160),
    Item("Min Voltage Limit", 34, 2, True, 95, 95, 160),
    Item("PWM Limit", 36, 2, True, 885, 0, 885),
    Item("Current Limit", 38, 2, True, 1193, 0, 1193),
    Item("Velocity Limit", 44, 4, True, 200, 0, 1023),
    Item("Max Position Limit", 48, 4, True, 4095, 0, 4095),
    Item("Min Position Limit", 52, 4, True, 0, 0, 4095),
    Item("Startup Configuration", 60, 1, True, 0, 0, 3),
    Item("Shutdown", 63, 1, True, 52, 0, 255),
    Item("Torque Enable", 64, 1, True, 0, 0, 1),
    Item("LED", 65, 1, True, 0, 0, 1),
    Item("Status Return Level", 68, 1, True, 2, 0, 2),
    Item("Registered Instruction", 69, 1, False, 0),
    Item("Hardware Error Status", 70, 1, False, 0),
    Item("Velocity I Gain", 76, 2, True, 1920, 0, 16383),
    Item("Velocity P Gain", 78, 2, True, 100, 0, 16383),
    Item("Position D Gain", 80, 2, True, 0, 0, 16383),
    Item("Position I Gain", 82, 2, True, 0, 0, 16383),
    Item("Position P Gain", 84, 2, True, 800, 0, 16383),
    Item("Feedforward 2nd Gain", 88, 2, True, 0, 0, 16383),
    Item("Feedforward 1st Gain", 90, 2, True, 0, 0, 16383),
    Item("Bus Watchdog", 98, 1, True, 0, 0, 127),
    Item("Goal PWM", 100, 2, True, 0, -885, 885, signed=True),
    Item("Goal Current", 102, 2, True, 0, -1193, 1193, signed=True),
    Item("Goal Velocity", 104, 4, True, 0, -1023, 1023, signed=True),
    Item("Profile Acceleration", 108, 4, True, 0, 0, 32767),
    Item("Profile Velocity", 112, 4, True, 0, 0, 32767),
    Item("Goal Position", 116, 4, True, 2048, -1_048_575, 1_048_575, signed=True),  # limits checked separately
    Item("Realtime Tick", 120, 2, False, 0),
    Item("Moving", 122, 1, False, 0),
    Item("Moving Status", 123, 1, False, 0),
    Item("Present PWM", 124, 2, False, 0, signed=True),
    Item("Present Current", 126, 2, False, 0, signed=True),
    Item("Present Velocity", 128, 4, False, 0, signed=True),
    Item("Present Position", 132, 4, False, 2048, signed=True),
    Item("Velocity Trajectory", 136, 4, False, 0, signed=True),
    Item("Position Trajectory", 140, 4, False, 0, signed=True),
    Item("Present Input Voltage", 144, 2, False, 120),
    Item("Present Temperature", 146, 1, False, 32),
    Item("Backup Ready", 147, 1, False, 0),
)
CONTROL_TABLE_SIZE = 148  # reads must end at or before this address

# Each model's control table by its Model Number (item 0): another model is one more entry.
TABLES_BY_MODEL: dict[int, tuple[Item, ...]] = {MODEL_NUMBER_XM430_W350: XM430_W350_ITEMS}
ITEMS_BY_NAME: dict[str, Item] = {item.name: item for item in XM430_W350_ITEMS}
ITEMS_BY_ADDRESS: dict[int, Item] = {item.address: item for item in XM430_W350_ITEMS}


# The app talks Protocol 2.0 and waits for a status packet after every instruction it sends one by one (reads, and
# writes it confirms): a servo set otherwise stops answering the app, which then cannot even set it back.
STATUS_RETURN_ALL = 2  # Status Return Level: a status packet for every instruction
PROTOCOL_2 = 2  # Protocol Type


def cut_off_reason(name: str, value: int) -> str | None:
    """Why writing ``value`` into item ``name`` would cut the app off from the servo, or None if it would not. (ID
    and Baud Rate move a servo, not silence it: the settings code handles them apart.)"""
    if name == "Status Return Level" and value < STATUS_RETURN_ALL:
        what = "pings only" if value == 0 else "pings and reads, never a write"
        return (f"the servo would then answer {what}, and the app needs its answer to every read and write (torque, "
                f"settings): keep it at {STATUS_RETURN_ALL}")
    if name == "Protocol Type" and value != PROTOCOL_2:
        return (f"the servo would then speak Protocol 1.0, which this app does not: it would answer nothing; keep it "
                f"at {PROTOCOL_2}")
    return None


# -- what each item's value means (XM430-W350 e-manual, "Control Table": each item's section) -------------------
# Dynamixel Wizard 2.0 shows these beside the raw number; the Hardware tab's Servo settings page does the same.
@dataclass(frozen=True)
class Decoding:
    """How an item's raw value reads: ``names`` (value → name) for an enumeration, ``bits`` (bit → name) for a bit
    field, else ``scale`` physical units of ``unit`` per raw unit (0: a plain number). ``notes``: the e-manual's
    remark shown with the item (e.g. which profile the units hold in)."""

    unit: str = ""
    scale: float = 0.0
    names: tuple[tuple[int, str], ...] = ()
    bits: tuple[tuple[int, str], ...] = ()
    notes: str = ""

    @property
    def kind(self) -> str:
        """"enum", "bits", "scaled" or "plain"."""
        return "enum" if self.names else "bits" if self.bits else "scaled" if self.scale else "plain"

    @property
    def bit_mask(self) -> int:
        return sum(1 << bit for bit, _name in self.bits)


DEGREES_PER_TICK = 360.0 / TICKS_PER_REV  # 0.088° in the e-manual
OFF_ON = ((0, "Off"), (1, "On"))
# Baud Rate (8): the e-manual's names for each value.
BAUD_RATE_NAMES: tuple[tuple[int, str], ...] = (
    (0, "9,600 bps"), (1, "57,600 bps"), (2, "115,200 bps"), (3, "1 Mbps"), (4, "2 Mbps"), (5, "3 Mbps"),
    (6, "4 Mbps"), (7, "4.5 Mbps"))
OPERATING_MODE_NAMES: tuple[tuple[int, str], ...] = (
    (0, "Current Control"), (1, "Velocity Control"), (3, "Position Control"),
    (4, "Extended Position Control (Multi-turn)"), (5, "Current-based Position Control"),
    (16, "PWM Control (Voltage Control)"))
# Shutdown (63) and Hardware Error Status (70): the same bits, the e-manual's names.
ERROR_BIT_NAMES: tuple[tuple[int, str], ...] = (
    (0, "Input Voltage Error"), (2, "Overheating Error"), (3, "Motor Encoder Error"), (4, "Electrical Shock Error"),
    (5, "Overload Error"))
DECODINGS: dict[str, Decoding] = {
    "Model Number": Decoding(names=tuple(sorted(MODEL_NAMES.items()))),
    "Baud Rate": Decoding(names=BAUD_RATE_NAMES),
    "Return Delay Time": Decoding("µs", RETURN_DELAY_S_PER_LSB * 1e6),
    "Drive Mode": Decoding(bits=((0, "Reverse Mode"), (2, "Time-based Profile"), (3, "Torque On by Goal Update")),
                           notes="bit 0 clear: counter-clockwise is positive; bit 2 clear: velocity-based profile"),
    "Operating Mode": Decoding(names=OPERATING_MODE_NAMES),
    "Secondary ID": Decoding(notes="253 or more: no Secondary ID"),
    "Protocol Type": Decoding(names=((1, "Protocol 1.0"), (2, "Protocol 2.0"))),
    "Homing Offset": Decoding("°", DEGREES_PER_TICK),
    "Moving Threshold": Decoding("rpm", VELOCITY_RPM_PER_LSB),
    "Temperature Limit": Decoding("°C", 1.0),
    "Max Voltage Limit": Decoding("V", VOLTAGE_V_PER_LSB),
    "Min Voltage Limit": Decoding("V", VOLTAGE_V_PER_LSB),
    "PWM Limit": Decoding("%", 100.0 / 885),
    "Current Limit": Decoding("mA", CURRENT_MA_PER_LSB),
    "Velocity Limit": Decoding("rpm", VELOCITY_RPM_PER_LSB),
    "Max Position Limit": Decoding("°", DEGREES_PER_TICK),
    "Min Position Limit": Decoding("°", DEGREES_PER_TICK),
    "Startup Configuration": Decoding(bits=((0, "Startup Torque On"), (1, "RAM Restore"))),
    "Shutdown": Decoding(bits=ERROR_BIT_NAMES),
    "Torque Enable": Decoding(names=OFF_ON),
    "LED": Decoding(names=OFF_ON),
    "Status Return Level": Decoding(names=((0, "PING Instruction"), (1, "PING and READ Instructions"),
                                           (2, "All Instructions"))),
    "Registered Instruction": Decoding(names=((0, "None"), (1, "REG_WRITE received"))),
    "Hardware Error Status": Decoding(bits=ERROR_BIT_NAMES),
    "Bus Watchdog": Decoding("ms", 20.0, notes="0: off"),
    "Goal PWM": Decoding("%", 100.0 / 885),
    "Goal Current": Decoding("mA", CURRENT_MA_PER_LSB),
    "Goal Velocity": Decoding("rpm", VELOCITY_RPM_PER_LSB),
    "Profile Acceleration": Decoding("rev/min²", ACCELERATION_RPM2_PER_LSB,
                                     notes="velocity-based profile (Drive Mode bit 2 clear); time-based: ms"),
    "Profile Velocity": Decoding("rpm", VELOCITY_RPM_PER_LSB,
                                 notes="velocity-based profile (Drive Mode bit 2 clear); time-based: ms"),
    "Goal Position": Decoding("°", DEGREES_PER_TICK),
    "Realtime Tick": Decoding("ms", 1.0),
    "Moving": Decoding(names=((0, "Not moving"), (1, "Moving"))),
    "Moving Status": Decoding(bits=((0, "In-Position"), (1, "Profile Ongoing"), (3, "Following Error"),
                                    (4, "Profile type bit 0"), (5, "Profile type bit 1")),
                              notes="profile type (bits 5-4): 00 step, 01 rectangular, 10 triangular, "
                                    "11 trapezoidal"),
    "Present PWM": Decoding("%", 100.0 / 885),
    "Present Current": Decoding("mA", CURRENT_MA_PER_LSB),
    "Present Velocity": Decoding("rpm", VELOCITY_RPM_PER_LSB),
    "Present Position": Decoding("°", DEGREES_PER_TICK),
    "Velocity Trajectory": Decoding("rpm", VELOCITY_RPM_PER_LSB),
    "Position Trajectory": Decoding("°", DEGREES_PER_TICK),
    "Present Input Voltage": Decoding("V", VOLTAGE_V_PER_LSB),
    "Present Temperature": Decoding("°C", 1.0),
    "Backup Ready": Decoding(names=((0, "No backup"), (1, "Backup ready"))),
}
PLAIN = Decoding()


def decoding(name: str) -> Decoding:
    """How item ``name``'s value reads (a plain number for an item the e-manual gives no meaning or unit)."""
    return DECODINGS.get(name, PLAIN)


def describe(name: str, raw: int) -> str:
    """Item ``name``'s raw value in words: its name ("1 Mbps", "Position Control"), the bits set ("Overheating
    Error, Electrical Shock Error, Overload Error"; "none"), or the value in its unit ("180.0 °"); a value an
    enumeration does not name, or a bit it does not know, is said as such."""
    how = decoding(name)
    if how.names:
        return dict(how.names).get(raw, f"{raw}: not a value of {name}")
    if how.bits:
        named = [label for bit, label in how.bits if raw & (1 << bit)]
        unknown = raw & ~how.bit_mask
        if unknown:
            named.append(f"unknown bits 0x{unknown:02X}")
        return ", ".join(named) if named else "none"
    if how.scale:
        return f"{raw * how.scale:.{_decimals(how.scale)}f} {how.unit}"
    return str(raw)


def physical(name: str, raw: int) -> float | None:
    """The raw value in the item's unit (None for an item without one)."""
    how = decoding(name)
    return raw * how.scale if how.scale else None


def raw_from_physical(name: str, value: float) -> int:
    """The raw value nearest ``value`` given in the item's unit (ValueError for an item without one)."""
    how = decoding(name)
    if not how.scale:
        raise ValueError(f"{name} has no unit to convert from")
    return int(round(value / how.scale))


def raw_from_name(name: str, label: str) -> int:
    """The value an enumeration item ``name`` calls ``label`` (any case); ValueError listing the names."""
    how = decoding(name)
    wanted = " ".join(label.split()).lower()
    for value, text in how.names:
        if text.lower() == wanted:
            return value
    names = ", ".join(f"{v} {t!r}" for v, t in how.names) or "none"
    raise ValueError(f"{name} has no value called {label!r} (its values: {names})")


def raw_with_bit(name: str, raw: int, bit: int, on: bool) -> int:
    """``raw`` with bit ``bit`` of bit-field item ``name`` set (``on``) or cleared."""
    if bit not in dict(decoding(name).bits):
        raise ValueError(f"{name} has no bit {bit}")
    return raw | (1 << bit) if on else raw & ~(1 << bit)


def invalid_reason(name: str, raw: int) -> str | None:
    """Why ``raw`` is no value of item ``name`` although it may lie in its range (an enumeration's unnamed value, a
    bit field's unknown bit), or None."""
    how = decoding(name)
    if how.names and raw not in dict(how.names):
        names = ", ".join(f"{v} ({t})" for v, t in how.names)
        return f"{name} = {raw} is not one of its values: {names}"
    if how.bits and raw & ~how.bit_mask:
        bits = ", ".join(f"bit {b} ({t})" for b, t in how.bits)
        return f"{name} = {raw} sets a bit it does not have (its bits: {bits})"
    return None


def _decimals(scale: float) -> int:
    """Decimals that tell one raw step from the next: 0.088 → 2, 0.1 → 1, 2.69 → 0."""
    if scale >= 1:
        return 0
    return min(3, int(math.ceil(-math.log10(scale) - 1e-9)))


ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY_TIME = 9
ADDR_OPERATING_MODE = 11
ADDR_VELOCITY_LIMIT = 44
ADDR_MAX_POSITION_LIMIT = 48
ADDR_MIN_POSITION_LIMIT = 52
ADDR_TORQUE_ENABLE = 64
ADDR_LED = 65
ADDR_STATUS_RETURN_LEVEL = 68
ADDR_HARDWARE_ERROR_STATUS = 70
ADDR_PROFILE_ACCELERATION = 108
ADDR_PROFILE_VELOCITY = 112
ADDR_GOAL_POSITION = 116
ADDR_MOVING = 122
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
ADDR_PRESENT_INPUT_VOLTAGE = 144
ADDR_PRESENT_TEMPERATURE = 146

# The feedback block read every control tick: current (2), velocity (4), position (4) in ONE sync read.
STATE_BLOCK_ADDRESS = ADDR_PRESENT_CURRENT
STATE_BLOCK_SIZE = ADDR_PRESENT_POSITION + 4 - ADDR_PRESENT_CURRENT  # 10 bytes

# Health blocks: torque/LED/…/hardware error (64..70) and voltage/temperature (144..146).
HEALTH_BLOCK_ADDRESS = ADDR_TORQUE_ENABLE
HEALTH_BLOCK_SIZE = ADDR_HARDWARE_ERROR_STATUS + 1 - ADDR_TORQUE_ENABLE  # 7 bytes
SUPPLY_BLOCK_ADDRESS = ADDR_PRESENT_INPUT_VOLTAGE
SUPPLY_BLOCK_SIZE = ADDR_PRESENT_TEMPERATURE + 1 - ADDR_PRESENT_INPUT_VOLTAGE  # 3 bytes


def model_name(model_number: int) -> str:
    return MODEL_NAMES.get(model_number, f"unknown model {model_number}")


def to_signed(value: int, size: int) -> int:
    """Interpret ``size`` little-endian bytes read as unsigned as a two's-complement integer."""
    bits = 8 * size
    return value - (1 << bits) if value & (1 << (bits - 1)) else value
