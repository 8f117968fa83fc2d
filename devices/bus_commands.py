"""Named bus commands: what callers ask the thread that owns the servo bus to do, as data.

A :class:`BusCommand` is a module-level function plus its arguments. Calling it with the chain runs it, so the
in-process :class:`devices.controller.RobotController` runs it exactly as it ran the closures it used to get; but
unlike a closure it can be pickled, so the same command can cross to the control loop's own process
(:mod:`devices.loop_process`) and run there through the same ``submit``. Every bus operation the app submits is
one of these (teach capture/hold, the Hardware tab's link check, timing check and Return Delay Time fix, a scan).

Qt-free; any thread may build one; the function runs on the bus thread.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from devices.errors import CorruptPacketError, DeviceError, NoReplyError

LINK_CHECK_ROUNDS = 5


@dataclass(frozen=True)
class BusCommand:
    """``fn(chain, *args, **kwargs)`` as data. ``fn`` must be a module-level function (so it pickles by name)."""

    fn: Callable[..., Any]
    args: tuple = ()
    kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        qualname = getattr(self.fn, "__qualname__", "")
        if not callable(self.fn) or "<" in qualname or not getattr(self.fn, "__module__", None):
            raise TypeError(f"a bus command needs a module-level function, not {self.fn!r} (a lambda or nested "
                            "function cannot run in the control loop's process)")

    @property
    def name(self) -> str:
        return self.fn.__name__

    def __call__(self, chain: Any) -> Any:
        return self.fn(chain, *self.args, **self.kwargs)


def bus_command(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> BusCommand:
    """``BusCommand(fn, args, kwargs)``: run ``fn(chain, *args, **kwargs)`` on the bus thread."""
    return BusCommand(fn, tuple(args), dict(kwargs))


# -- the commands ----------------------------------------------------------------------------------------------------
def set_torque(chain: Any, enabled: bool, ids: Sequence[int] | None = None) -> None:
    chain.set_torque(enabled, None if ids is None else list(ids))


def scan(chain: Any, ids: Sequence[int], bauds: Sequence[int] | None = None) -> list:
    return chain.scan(list(ids), None if bauds is None else list(bauds))


def timing_warnings(chain: Any) -> list[str]:
    return list(chain.timing_warnings())


def fix_return_delay(chain: Any, ids: Sequence[int]) -> list[str]:
    """Return Delay Time → 0 on ``ids`` (EEPROM: refused while torque is on), then the timing warnings left."""
    chain.set_return_delay(0, list(ids))
    return list(chain.timing_warnings())


@dataclass(frozen=True)
class LinkCheckRow:
    """One servo's link-check result: round-trip times of the pings that answered, and the failures."""

    servo_id: int
    rtt_mean_ms: float | None
    rtt_max_ms: float | None
    no_reply: int
    crc_errors: int
    other_errors: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.no_reply == 0 and self.crc_errors == 0 and not self.other_errors


def link_check(chain: Any, servo_ids: Sequence[int], rounds: int = LINK_CHECK_ROUNDS) -> list[LinkCheckRow]:
    """Ping each servo ``rounds`` times; round-trip times in ms, timed on the bus thread."""
    rows = []
    for servo_id in servo_ids:
        rtts_ms: list[float] = []
        no_reply = crc = 0
        others: list[str] = []
        for _ in range(rounds):
            start = time.perf_counter()
            try:
                chain.ping(servo_id)
            except NoReplyError:
                no_reply += 1
                continue
            except CorruptPacketError:
                crc += 1
                continue
            except DeviceError as exc:
                others.append(str(exc))
                continue
            rtts_ms.append((time.perf_counter() - start) * 1000.0)
        rows.append(LinkCheckRow(
            servo_id=int(servo_id),
            rtt_mean_ms=sum(rtts_ms) / len(rtts_ms) if rtts_ms else None,
            rtt_max_ms=max(rtts_ms) if rtts_ms else None,
            no_reply=no_reply, crc_errors=crc, other_errors=tuple(dict.fromkeys(others)),
        ))
    return rows
