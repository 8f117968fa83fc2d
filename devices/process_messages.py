"""The messages between the app and its child processes — the simulated lab's (:mod:`devices.sim.lab_process`) and
the control loop's (:mod:`devices.loop_process`) — one frozen dataclass per message, in one place.

Both sides send these objects through a ``multiprocessing`` socket (pickled) and check what they receive with
:func:`expect`: a message of another kind, or of another :data:`VERSION` (a child from another checkout), is a
:class:`ProtocolError` naming both, never a tuple unpacked into the wrong fields. A reply carries the id of its request
and is matched to it (:func:`reply_for`). An exception crosses as an :class:`ErrorPayload` (the class's module and
name, its arguments and attributes, the device it concerns) and is raised on the other side as the project's own
class (``ServoLostError`` stays ``ServoLostError``), or as :class:`DeviceError` with the message when that class
cannot be imported there.

Qt-free; any thread (the objects are immutable).
"""

from __future__ import annotations

import importlib
import pickle
from dataclasses import dataclass, field
from typing import Any, TypeVar

from devices.errors import DeviceError, ProtocolError

VERSION = 1  # bump when a message's fields change: a child and an app of different versions refuse each other


@dataclass(frozen=True, slots=True)
class ErrorPayload:
    """An exception, as it crosses a process boundary: rebuilt by :meth:`rebuild` as the same class."""

    key: int  # the exception's id() in the sender: one exception sent twice is rebuilt once (ControllerProcess)
    module: str
    qualname: str
    args: tuple[Any, ...]
    state: dict[str, Any]
    device: str = ""  # the device it concerns ("robot", "board", "rig", "lab"), when the sender knows

    @classmethod
    def of(cls, exc: BaseException, device: str = "") -> ErrorPayload:
        """The payload of ``exc``: attributes that do not pickle stay behind (the message always crosses)."""
        state = {}
        for key, value in vars(exc).items():
            try:
                pickle.dumps(value)
            except Exception:  # noqa: BLE001 - an attribute that cannot cross is left behind
                continue
            state[key] = value
        try:
            pickle.dumps(exc.args)
            args = tuple(exc.args)
        except Exception:  # noqa: BLE001
            args = (str(exc),)
        return cls(id(exc), type(exc).__module__, type(exc).__qualname__, args, state, device)

    @property
    def message(self) -> str:
        return " ".join(str(a) for a in self.args) or self.qualname

    def rebuild(self) -> BaseException:
        """The exception as this process's class of the same module and name (not ``cls(*args)``: an ``__init__``
        may take other arguments; the message is in ``args``, the attributes in ``state``); DeviceError with the
        message when the class cannot be found here."""
        try:
            cls: Any = importlib.import_module(self.module)
            for part in self.qualname.split("."):
                cls = getattr(cls, part)
            if not (isinstance(cls, type) and issubclass(cls, BaseException)):
                raise TypeError(self.qualname)
            exc = (OSError if issubclass(cls, OSError) else BaseException).__new__(cls)
            exc.args = tuple(self.args)
            exc.__dict__.update(self.state)
            return exc
        except Exception:  # noqa: BLE001 - a class this process cannot import: keep the message
            return DeviceError(self.message)


@dataclass(frozen=True, slots=True)
class Message:
    """Every message carries the protocol version it was written with."""

    version: int = field(default=VERSION, kw_only=True)


# -- the simulated lab's process ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class LabStart(Message):
    """App → lab: build the lab from this config."""

    config: Any  # devices.config.LabConfig
    seed: int
    speed: float


@dataclass(frozen=True, slots=True)
class LabReady(Message):
    """Lab → app: running; where each device's pty is, the clock's origin, the physics world's size."""

    paths: dict[str, str]
    wall0: float
    nq: int | None  # joint positions shared (physics lab) or None
    physics_note: str


@dataclass(frozen=True, slots=True)
class Failed(Message):
    """Child → app, instead of ready: why it could not start (an exception, raised in the app as itself)."""

    error: ErrorPayload


@dataclass(frozen=True, slots=True)
class Call(Message):
    """App → child: call ``name`` with these arguments; ``request_id`` None: no answer wanted."""

    request_id: int | None
    name: str
    args: tuple[Any, ...] = ()
    kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Result(Message):
    """Child → app: the answer to the call ``request_id``: its value, or the exception it raised."""

    request_id: int
    value: Any = None
    error: ErrorPayload | None = None


# -- the control loop's process ----------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class LoopStart(Message):
    """App → loop: open this robot's bus and run its loop."""

    robot: Any  # devices.config.RobotConfig
    simulated: bool


@dataclass(frozen=True, slots=True)
class LoopReady(Message):
    """Loop → app: running, with the bus's timing warnings and the loop thread's scheduling."""

    timing_warnings: tuple[str, ...]
    scheduling: str


@dataclass(frozen=True, slots=True)
class Broken(Message):
    """Child → app: it cannot run at all (not a device problem): the app runs the loop in its own process."""

    reason: str


@dataclass(frozen=True, slots=True)
class Close(Message):
    """App → child: end (stop the motion, close the port, exit)."""


@dataclass(frozen=True, slots=True)
class Bye(Message):
    """Child → app: the last message before it exits when asked to."""


@dataclass(frozen=True, slots=True)
class Tick(Message):
    """Loop → app, once per control tick: the tick's states and the motion's state."""

    states: tuple[Any, ...]  # devices.servo_chain.ChainState
    connected: bool
    motion_name: str | None
    paused: bool
    motion_request: int | None  # the request that started the motion (its progress goes to that source)
    progress: Any
    scheduling: str
    tick_s: float


@dataclass(frozen=True, slots=True)
class Health(Message):
    health: tuple[Any, ...]  # devices.servo_chain.ServoHealth


@dataclass(frozen=True, slots=True)
class Event(Message):
    text: str


@dataclass(frozen=True, slots=True)
class MotionHalted(Message):
    """Loop → app: the watchdog stopped this motion on a bus that sent no byte; its cause follows (its Result)."""

    name: str


@dataclass(frozen=True, slots=True)
class ErrorReport(Message):
    """Loop → app: an error outside any request (a motion stopped by a servo fault)."""

    error: ErrorPayload


M = TypeVar("M", bound=Message)


def expect(message: object, *kinds: type[M]) -> M:
    """``message`` if it is one of ``kinds`` in this :data:`VERSION`; ProtocolError naming what came instead."""
    if not isinstance(message, Message):
        raise ProtocolError(f"expected {' or '.join(k.__name__ for k in kinds)}, got {type(message).__name__} "
                            "(not a protocol message: a child process from another version?)")
    if message.version != VERSION:
        raise ProtocolError(f"{type(message).__name__} of protocol version {message.version}; this side speaks "
                            f"{VERSION}: the app and its child processes come from different checkouts")
    if kinds and not isinstance(message, kinds):
        raise ProtocolError(f"expected {' or '.join(k.__name__ for k in kinds)}, got {type(message).__name__}")
    return message  # type: ignore[return-value]


def reply_for(message: object, request_id: int) -> Result:
    """``message`` as the :class:`Result` of request ``request_id``; ProtocolError if it answers another one."""
    result = expect(message, Result)
    if result.request_id != request_id:
        raise ProtocolError(f"the answer to request {result.request_id} came where {request_id}'s was awaited")
    return result
