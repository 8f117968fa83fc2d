"""What a thread that keeps a beat asks of the machine: a short interpreter-lock switch interval and real-time
scheduling (the control loop's bus thread, the loop's process, the simulated lab's servos on their ptys)."""

from __future__ import annotations

import ctypes
import os
import struct
import sys

GIL_SWITCH_INTERVAL_S = 0.001  # see _lower_switch_interval
BUS_THREAD_RT_PRIORITY = 20  # SCHED_FIFO priority of the bus thread when permitted (see _raise_thread_priority)
SHORT_SLICE_S = 0.0001  # the time slice a loop thread asks for under normal scheduling (see _ask_short_slice)
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}  # sched_setattr(2)'s number; sched_getattr is the next one
_SCHED_ATTR = struct.Struct("<IIQiIQQQII")  # struct sched_attr, SCHED_ATTR_SIZE_VER1 (56 bytes)


def _lower_switch_interval() -> None:
    """Hand the GIL over within 1 ms instead of CPython's default 5 ms (process-wide; never raised back).

    The bus thread sleeps through every reply and wakes at every deadline; each wake-up waits for the GIL while
    another thread (the GUI, a simulated device) runs Python. With the default interval one tick can wait 5 ms at
    each of its two or three wake-ups, a quarter of a 50 Hz period.
    """
    if sys.getswitchinterval() > GIL_SWITCH_INTERVAL_S:
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)


def _switched_off(variable: str) -> bool:
    """An on/off environment switch (on unless set to 0, no, off or false)."""
    return os.environ.get(variable, "1").strip().lower() in ("0", "no", "off", "false")


def raise_thread_priority_of(native_id: int) -> bool:
    """Real-time scheduling for another thread of this process (Linux: its ``native_id`` is its TID), as
    :func:`_raise_thread_priority` asks it for the calling one; False when not permitted or switched off."""
    if _switched_off("SENSNAKE_REALTIME") or not sys.platform.startswith("linux"):
        return False
    try:
        os.sched_setscheduler(native_id, os.SCHED_FIFO, os.sched_param(BUS_THREAD_RT_PRIORITY))
    except OSError:
        return False
    return True


def _ask_short_slice() -> str | None:
    """Ask Linux's fair scheduler (EEVDF, Linux 6.12 and later) for a short time slice for the calling thread: a
    thread that wakes with a shorter slice than the one running is let in at once instead of after the running
    program's slice (1.4 ms and more, several programs deep on a busy PC). No privilege is needed, and the thread's
    share of the CPU is unchanged (its weight, the nice value, is what sets that); it only trades longer runs for an
    earlier turn, which is what a thread that wakes 100 times a second and runs briefly wants. Returns the words for
    it, or None when not obtained (another OS or kernel, or ``SENSNAKE_SHORT_SLICE=0``): then the thread keeps the
    default slice."""
    if _switched_off("SENSNAKE_SHORT_SLICE") or not sys.platform.startswith("linux"):
        return None
    want_ns = int(SHORT_SLICE_S * 1e9)
    attr = ctypes.create_string_buffer(_SCHED_ATTR.pack(_SCHED_ATTR.size, os.SCHED_OTHER, 0, os.getpriority(
        os.PRIO_PROCESS, 0), 0, want_ns, 0, 0, 0, 0))
    if not _sched_attr_call(0, 0, attr, 0):
        return None
    if time_slice_s() != want_ns * 1e-9:  # a kernel before 6.12 takes the call and ignores the slice
        return None
    return f"a {SHORT_SLICE_S * 1e3:g} ms time slice"


def time_slice_s(thread_id: int = 0) -> float | None:
    """The fair scheduler's time slice of a thread (Linux: its TID; 0 the calling one), or None where it cannot be
    read (another OS, a real-time thread has none, a kernel before 6.12 reports 0)."""
    got = ctypes.create_string_buffer(_SCHED_ATTR.size)
    if not _sched_attr_call(1, thread_id, got, _SCHED_ATTR.size, 0):
        return None
    fields = _SCHED_ATTR.unpack(got.raw)
    return fields[5] * 1e-9 if fields[1] == os.SCHED_OTHER and fields[5] else None


def _sched_attr_call(which: int, *args: object) -> bool:
    """sched_setattr(2) (``which`` 0) or sched_getattr(2) (1) with ``args``; False where the call failed or this
    machine has neither (another OS or architecture)."""
    number = _SYS_SCHED_SETATTR.get(os.uname().machine) if sys.platform.startswith("linux") else None
    if number is None:
        return False
    try:
        return bool(ctypes.CDLL(None, use_errno=True).syscall(number + which, *args) == 0)
    except (OSError, AttributeError):
        return False


def _raise_thread_priority() -> str:
    """Ask for real-time scheduling (SCHED_FIFO, priority ``BUS_THREAD_RT_PRIORITY``) for the calling thread only
    (Linux: scheduling is per thread), as a control loop on a PC should have: then another program busy on the
    machine cannot delay a tick's wake-up. Needs the privilege (root, CAP_SYS_NICE or an ``rtprio`` limit, e.g.
    ``@dialout - rtprio 20`` in /etc/security/limits.conf); without it the thread keeps normal scheduling and asks
    for a short time slice (:func:`_ask_short_slice`). The environment variable ``SENSNAKE_REALTIME=0`` turns the
    real-time request off. Returns what was obtained, in words."""
    if _switched_off("SENSNAKE_REALTIME"):
        return _normal_scheduling("SENSNAKE_REALTIME=0")
    if not sys.platform.startswith("linux") or not hasattr(os, "sched_setscheduler"):
        return "normal scheduling (real-time priority is only asked for on Linux)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(BUS_THREAD_RT_PRIORITY))
    except OSError:
        return _normal_scheduling("no privilege for real-time priority: a busy machine may delay ticks; allow it "
                                  "with an rtprio limit, see the README")
    return f"real-time scheduling (SCHED_FIFO {BUS_THREAD_RT_PRIORITY})"


def _normal_scheduling(why: str) -> str:
    """Normal scheduling for the calling thread, with a short time slice where the kernel grants one; in words."""
    short = _ask_short_slice()
    return f"normal scheduling with {short} ({why})" if short else f"normal scheduling ({why})"
