"""Imported by the forkserver an embedded Dask cluster's workers are forked from (``engines.WORKER_PRELOAD``), and
acting only there: the forkserver's end skips the interpreter's teardown.

The forkserver runs nothing itself; it holds the imports its workers are forked with (distributed, MuJoCo, the physics
lab). When the command stops it (``engines.stop_worker_server``), the standard library's server exits the ordinary
way, tearing down every module it imported: 0.17-0.29 s measured, which the command waited for after every sweep. Its
workers have left by then (each forked child of the server ends with ``os._exit``, so nothing here runs in them), and
nothing in the server needs flushing: it ends with ``os._exit(0)`` as soon as the interpreter starts to finish.

The server is recognised by :data:`SERVER_ENV`, which ``engines.start_worker_server`` sets to its own process id only
while it starts the server: a process whose parent is that process and which imports this module during its start is
the server. Imported anywhere else, this module does nothing.
"""

from __future__ import annotations

import atexit
import os
import signal

SERVER_ENV = "SENSNAKE_WORKER_SERVER_PARENT"


def _is_the_server() -> bool:
    parent = os.environ.get(SERVER_ENV, "")
    return parent.isdigit() and int(parent) == os.getppid() and int(parent) != os.getpid()


if _is_the_server():
    atexit.register(os._exit, 0)
    # The workers forked from the server keep the signal handlers the server had before it started serving: Ctrl-C
    # ignored. The terminal sends it to the whole process group; the command decides (it cancels the pending runs and
    # stops the cluster, whose nannies end the workers), as the local pool's workers leave it to the command too.
    # Without this each Dask worker also printed a KeyboardInterrupt traceback over the command's one line.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
