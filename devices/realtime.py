"""What a thread that keeps a beat asks of the machine: a short interpreter-lock switch interval and real-time
scheduling (the control loop's bus thread, the loop's process, the simulated lab's servos on their ptys)."""

from __future__ import annotations

import os
import sys

GIL_SWITCH_INTERVAL_S = 0.001  # see _lower_switch_interval
BUS_THREAD_RT_PRIORITY = 20  # SCHED_FIFO priority of the bus thread when permitted (see _raise_thread_priority)


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


def _raise_thread_priority() -> str:
    """Ask for real-time scheduling (SCHED_FIFO, priority ``BUS_THREAD_RT_PRIORITY``) for the calling thread only
    (Linux: scheduling is per thread), as a control loop on a PC should have: then another program busy on the
    machine cannot delay a tick's wake-up. Needs the privilege (root, CAP_SYS_NICE or an ``rtprio`` limit, e.g.
    ``@dialout - rtprio 20`` in /etc/security/limits.conf); without it the thread keeps normal scheduling. The
    environment variable ``SENSNAKE_REALTIME=0`` turns it off. Returns what was obtained, in words."""
    if _switched_off("SENSNAKE_REALTIME"):
        return "normal scheduling (SENSNAKE_REALTIME=0)"
    if not sys.platform.startswith("linux") or not hasattr(os, "sched_setscheduler"):
        return "normal scheduling (real-time priority is only asked for on Linux)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(BUS_THREAD_RT_PRIORITY))
    except OSError:
        return ("normal scheduling (no privilege for real-time priority: a busy machine may delay ticks; allow "
                "it with an rtprio limit, see the README)")
    return f"real-time scheduling (SCHED_FIFO {BUS_THREAD_RT_PRIORITY})"
