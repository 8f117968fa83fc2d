"""Device errors: a small hierarchy whose members also inherit the builtin a caller would expect.

Messages are written for the lab user: they say what happened, to which servo or port, and what to do.
"""

from __future__ import annotations

import errno
import os

# Protocol 2.0 status packet error numbers (ROBOTIS e-manual, "Status Packet"): what a servo says when it refuses.
ERRNUM_RESULT_FAIL = 1
ERRNUM_INSTRUCTION = 2
ERRNUM_CRC = 3
ERRNUM_DATA_RANGE = 4
ERRNUM_DATA_LENGTH = 5
ERRNUM_DATA_LIMIT = 6
ERRNUM_ACCESS = 7
ERRNUM_NAMES: dict[int, str] = {
    ERRNUM_RESULT_FAIL: "result fail",
    ERRNUM_INSTRUCTION: "instruction error",
    ERRNUM_CRC: "CRC error",
    ERRNUM_DATA_RANGE: "data range error",
    ERRNUM_DATA_LENGTH: "data length error",
    ERRNUM_DATA_LIMIT: "data limit error",
    ERRNUM_ACCESS: "access error",
}


class DeviceError(RuntimeError):
    """Base of every hardware error raised by ``devices``."""


class PortOpenError(DeviceError, OSError):
    """A serial port could not be opened (missing device, permissions, in use)."""


class LinkLostError(DeviceError, ConnectionError):
    """The cable was pulled or the adapter vanished while the port was open."""


class NoReplyError(DeviceError, TimeoutError):
    """A servo did not answer within the packet timeout."""

    def __init__(self, servo_id: int, detail: str = "") -> None:
        self.servo_id = servo_id
        extra = f" ({detail})" if detail else ""
        super().__init__(f"no reply from servo {servo_id}{extra}: check its cable, power, ID and baud rate")


class BusQuietError(NoReplyError):
    """Not a byte on the servo bus for seconds, every reply given up on still missing: what is known then, said as
    such. Either every servo went quiet (their power, the cable from the adapter to the first servo) or this computer
    holds the port's received bytes (on Linux the kernel's tty worker, at normal priority, behind other programs).
    Names the first servo (``servo_id``), as a silent servo is named; if the replies then arrive, late and together,
    the loop corrects this with :class:`RepliesHeldError`."""

    def __init__(self, servo_id: int, quiet_s: float, polls: int, stopped: str) -> None:
        self.servo_id = servo_id
        self.quiet_s = quiet_s
        DeviceError.__init__(
            self, f"no reply from servo {servo_id} nor any other: not a byte on the bus for {quiet_s:.2f} s "
                  f"({polls} polls unanswered); {stopped}. Either the servos went quiet (check their power and the "
                  f"cable from the adapter to servo {servo_id}) or this computer is holding the port's bytes (a busy "
                  "PC's serial delivery; if the replies arrive late, together, the app says so)")


class CorruptPacketError(DeviceError):
    """A status packet failed its CRC or was malformed."""

    def __init__(self, servo_id: int | None, detail: str = "") -> None:
        self.servo_id = servo_id
        who = f"servo {servo_id}" if servo_id is not None else "the bus"
        extra = f" ({detail})" if detail else ""
        super().__init__(f"corrupt packet from {who}{extra}: check the bus wiring and termination")


class DuplicateIdError(DeviceError):
    """Two servos answer to one ID (their status packets collide): nothing may play until each has its own ID."""

    def __init__(self, collided: list[int], missing: list[int]) -> None:
        self.collided, self.missing = list(collided), list(missing)
        ids = ", ".join(str(i) for i in collided)
        also = (f"; configured ID(s) {', '.join(str(i) for i in missing)} do not answer (likely the servo that was "
                "set to the other's ID)") if missing else ""
        super().__init__(
            f"servo ID {ids}: its replies arrive garbled or twice while other servos answer cleanly — two servos are "
            f"set to the same ID{also}. Fix: ID inspection — power one servo at a time and scan it, then give each its own "
            "ID (Dynamixel Wizard's ID change); nothing plays until then")


# What each bit of a servo's Hardware Error Status means and what to do (XM430-W350 e-manual, "Hardware Error
# Status" and "Shutdown"): the servo turns its torque off on the bits set in Shutdown (factory: overheating,
# electrical shock, overload) and keeps the error until it is rebooted; a reboot keeps its position (the encoder is
# absolute) and brings it back with torque off. Names as devices.control_table.HARDWARE_ERROR_BITS gives them.
HARDWARE_ERROR_ADVICE: dict[str, tuple[str, str]] = {
    "input voltage error": ("its supply voltage is outside Min/Max Voltage Limit",
                            "check the power supply (12 V; the servo takes 9.5–14.8 V) and its cable"),
    "overheating": ("its temperature passed Temperature Limit",
                    "let it cool and give it less work (a lower speed, a lighter load)"),
    "motor encoder error": ("its position sensor malfunctions",
                            "if the error comes back after the reboot, the servo needs repair"),
    "electrical shock": ("an electrical shock on its circuit, or too little power to drive its motor",
                         "check the power supply and the cables"),
    "overload": ("a load above its maximum output lasted",
                 "remove the load (a joint pressed against something, a shape it cannot hold)"),
}
REBOOT_ADVICE = "then reboot it (Hardware tab → Reboot: it keeps its position, its torque comes back off)"


def hardware_error_advice(error_names: tuple[str, ...] | list[str]) -> str:
    """One sentence: what each error means and what to do, then how to clear it."""
    parts = []
    for name in error_names:
        meaning, action = HARDWARE_ERROR_ADVICE.get(name, ("an error this app does not know", "see the e-manual"))
        parts.append(f"{name}: {meaning} — {action}")
    return "; ".join(parts) + ("; " if parts else "") + REBOOT_ADVICE


class ServoHardwareError(DeviceError):
    """A servo reported a hardware error (overload, overheating, voltage, encoder, shock)."""

    def __init__(self, servo_id: int, error_names: tuple[str, ...]) -> None:
        self.servo_id = servo_id
        self.error_names = error_names
        what = ", ".join(error_names) or "hardware error"
        first = error_names[0] if error_names else ""
        action = HARDWARE_ERROR_ADVICE.get(first, ("", "find the cause"))[1]
        super().__init__(
            f"servo {servo_id} {what}: motion stopped; {action}, then reboot servo {servo_id} "
            "(Hardware tab → Reboot) to clear it"
        )


STATUS_RETURN_LEVEL_MEANING = {
    0: "answers pings only: it carries out reads and writes but sends no status packet, so its position, its errors "
       "and whether a command arrived cannot be read",
    1: "answers pings and reads, never a write: whether a command (torque, goal, reboot) arrived cannot be known",
}


def status_return_level_words(servo_id: int, level: int) -> str:
    """What a Status Return Level below 2 means for servo ``servo_id`` and the fix, one sentence."""
    meaning = STATUS_RETURN_LEVEL_MEANING.get(level, "does not answer every instruction")
    return (f"servo {servo_id} has Status Return Level {level}: it {meaning}. The app needs 2; the level lives in "
            f"RAM, so a restart brings 2 back: `sensnake servo reboot --id {servo_id}` or power-cycle the robot "
            "(if another tool sets it again at start-up, change that tool)")


class StatusReturnLevelError(DeviceError):
    """A servo answers pings but not every instruction (Status Return Level below 2): it cannot be controlled."""

    def __init__(self, servo_id: int, level: int) -> None:
        self.servo_id = servo_id
        self.level = level
        super().__init__(status_return_level_words(servo_id, level))


class ModelMismatchError(DeviceError, ValueError):
    """A servo answered with a model number other than the one the driver is written for."""


class JointLimitError(DeviceError, ValueError):
    """A requested motion cannot be made within the configured joint limits or speed."""


class BoardProtocolError(DeviceError, ValueError):
    """The force-sensor board's stream does not match the configuration (e.g. channel count)."""


def os_words(exc: BaseException) -> str:
    """The OS's reason for ``exc`` in plain words: "No such file or directory", not pyserial's echo ("could not
    open port P: [Errno 2] No such file …: 'P'") or Python's "[Errno 5] …" (termios.error included, which is no
    OSError)."""
    code = getattr(exc, "errno", None)
    if not isinstance(code, int) and len(exc.args) == 2 and isinstance(exc.args[0], int):
        code = exc.args[0]  # termios.error(5, 'Input/output error')
    if isinstance(code, int) and code > 0:
        return os.strerror(code)
    return " ".join(str(exc).split())


def link_lost_words(exc: BaseException) -> str:
    """Why a port stopped working, in plain words. A device that went away (unplugged, powered off, a pty's far end
    closed) shows as EIO, ENXIO or ENODEV, or as pyserial's "readiness to read but returned no data" (end of file),
    whichever the read met first: all say the same thing, so they read the same."""
    code = getattr(exc, "errno", None)
    if not isinstance(code, int) and len(exc.args) == 2 and isinstance(exc.args[0], int):
        code = exc.args[0]
    if code in (errno.EIO, errno.ENXIO, errno.ENODEV) or "returned no data" in str(exc):
        return "the device went away (unplugged, powered off, or its port closed)"
    return os_words(exc)


class LabProcessUnavailable(RuntimeError):
    """The simulated lab's own process could not be started (not a device problem): the lab then runs in the
    app's process (:func:`devices.factory.start_lab_process`)."""


# raised by devices.controller
class BusBusyError(DeviceError):
    """A bus command that cannot share the bus with the control loop right now (says why and what to do)."""


# raised by devices.controller
class ServoLostError(DeviceError):
    """A servo stopped doing what it was told mid-motion: it dropped its torque (a reboot, a power cut) or is far
    from its goal. Names the servo."""

    def __init__(self, servo_id: int, what: str) -> None:
        self.servo_id = servo_id
        super().__init__(f"servo {servo_id} {what}: motion stopped; check its power and cable, then turn torque on "
                         "again (a rebooted servo comes back limp)")


# raised by devices.config
class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range; the message names the key."""


# raised by devices.rig
class RigForceError(DeviceError, ValueError):
    """A force the rig must not or cannot apply."""


# raised by devices.scene
class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file, the key and the problem."""


# raised by devices.servo_chain
class ServoCommandError(DeviceError, ValueError):
    """A servo answered but refused the instruction (error number in its status packet)."""

    def __init__(self, servo_id: int, errnum: int, what: str) -> None:
        self.servo_id = servo_id
        self.errnum = errnum
        name = ERRNUM_NAMES.get(errnum, f"error {errnum}")
        hint = {
            ERRNUM_ACCESS: "EEPROM items (address < 64) can only be written with torque off; "
                              "read-only items cannot be written",
            ERRNUM_DATA_LIMIT: "the value lies outside the servo's configured limits",
            ERRNUM_DATA_RANGE: "the value or address is out of range",
            ERRNUM_CRC: "the servo received a corrupted packet; check the bus wiring",
        }.get(errnum, "see the Dynamixel e-manual")
        super().__init__(f"servo {servo_id} refused {what}: {name} ({hint})")


# raised by devices.servo_chain
class RateError(DeviceError, ValueError):
    """A control rate this bus cannot keep (the message says why and how to fix it)."""


# raised by devices.servo_chain
class DeadlinePassedError(DeviceError):
    """A read given up at the caller's deadline (the next control tick's slot) before all replies came: not a fault
    of the servos; their late replies are skipped when they arrive (see :class:`_TrackingSyncRead`)."""


# raised by devices.controller
class RepliesHeldError(DeviceError, TimeoutError):
    """The control loop got no reply byte for long enough to stop, and then the replies it had given up on arrived,
    late and together: this computer held them (its serial port's delivery: on Linux the kernel's tty worker, at
    normal priority, waiting behind other programs), the servos had answered. Names the measured hold, no servo."""

    def __init__(self, held_s: float, stopped: str, corrects: str = "") -> None:
        """``corrects``: the earlier verdict this one replaces (a :class:`BusQuietError` given before the replies
        came), said so the user does not go on believing it."""
        self.held_s = held_s
        self.corrects = corrects
        correction = f" (this corrects the earlier {corrects}: the servos and their cable are fine)" if corrects else ""
        super().__init__(
            f"the servos' replies came back {held_s:.2f} s late, all at once: held on this computer (the serial "
            f"port's delivery of the bytes, e.g. the kernel's tty worker on a busy PC), not a silent servo; {stopped}"
            f"{correction}. Fix: close other busy programs; for 50 Hz on a busy PC give the loop real-time priority "
            "and raise the tty workers (docs/REALTIME.md)")


# raised by devices.loop_process
class LoopDiedError(DeviceError):
    """The control loop's process ended without being asked to (killed, crashed). Names the process and the fix."""


# raised by devices.process_messages
class ProtocolError(RuntimeError):
    """A message that is not what this side expects (another kind, another version, a reply to another request)."""


# raised by devices.loop_process
class LoopProcessUnavailable(RuntimeError):
    """The child process could not be started (not a device problem): run the loop in-process instead."""


# raised by devices.rig
class RigInterrupted(DeviceError):
    """A wait was cut short because the caller's ``interrupt`` became true (abort, STOP)."""


# raised by devices.gauge
class GaugeReadError(DeviceError, ValueError):
    """No usable dial gauge reading (the input ended, or what was typed was not a number)."""
