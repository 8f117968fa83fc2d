"""A helper process of the app: a fresh interpreter (``python -m MODULE``, what multiprocessing's "spawn" does,
without re-importing the app's ``__main__``; never a fork of a process with Qt and threads) in its own session (a
Ctrl-C in the terminal reaches the app, which closes it), one socket pair for pickled messages and one file of
shared memory. The control loop's process (:mod:`devices.loop_process`) and the simulated lab's
(:mod:`devices.sim.lab_process`) are such children. No Qt, no devices: the bottom layer."""

from __future__ import annotations

import argparse
import contextlib
import logging
import mmap
import os
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path


@dataclass
class Child:
    """A started child: its process, this end of the socket, and the shared file (descriptor and mapping)."""

    process: subprocess.Popen
    conn: Connection
    shared_fd: int
    shared: mmap.mmap


def spawn(module: str, pages: int, prefix: str) -> Child:
    """Start ``python -m module --fd N --shared-fd M`` with ``pages`` pages of memory shared with it (an unlinked
    temporary file: gone with both processes). Raises what ``subprocess.Popen`` raises (OSError, or ValueError where
    ``pass_fds``/``start_new_session`` are unsupported), having released what it made."""
    ours, theirs = socket.socketpair()
    fd, path = tempfile.mkstemp(prefix=prefix)
    os.unlink(path)  # the open descriptors keep it
    shared: mmap.mmap | None = None
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])  # the checkout this package comes from
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    # One thread of numeric work: a BLAS pool (OpenBLAS starts one thread per core at numpy's import) would be threads
    # of a real-time process at normal priority, which a tick using numpy waits for behind the machine's load.
    for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[variable] = "1"
    try:
        os.ftruncate(fd, mmap.PAGESIZE * pages)
        shared = mmap.mmap(fd, mmap.PAGESIZE * pages)
        process = subprocess.Popen(
            [sys.executable, "-m", module, "--fd", str(theirs.fileno()), "--shared-fd", str(fd)],
            pass_fds=(theirs.fileno(), fd), env=env, cwd=root, stdin=subprocess.DEVNULL, start_new_session=True)
    except BaseException:
        ours.close()
        if shared is not None:
            shared.close()
        os.close(fd)
        raise
    finally:
        theirs.close()
    return Child(process, Connection(ours.detach()), fd, shared)


def release_shared(fd: int | None, shared: mmap.mmap | None) -> None:
    """Unmap and close a shared file (a view still held elsewhere keeps the mapping until it goes)."""
    if shared is not None:
        with contextlib.suppress(BufferError, ValueError):
            shared.close()
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)


def child_setup(argv: Sequence[str] | None, prog: str, description: str, shared_help: str,
                log_name: str) -> tuple[Connection, mmap.mmap | None]:
    """The child's side of :func:`spawn`: its arguments, logging, SIGINT ignored (the app closes it); returns the
    socket to the app and the shared memory (None without ``--shared-fd``)."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--fd", type=int, required=True, help="the socket to the app (inherited)")
    parser.add_argument("--shared-fd", type=int, help=shared_help)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format=f"{log_name}: %(levelname)s %(name)s: %(message)s")
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the app closes us; a terminal's Ctrl-C is for the app
    shared = None
    if args.shared_fd is not None:
        shared = mmap.mmap(args.shared_fd, os.fstat(args.shared_fd).st_size)
    return Connection(args.fd), shared
