"""The simulated lab in its own process, its devices on pseudo-terminals: what the app runs on port ``sim``.

Why: in the app's process the simulated servos, board and physics world share the Python interpreter lock with the
GUI thread, and so does the control loop that talks to them (it cannot move to its own process while the servos it
talks to live in the app's). With the lab in a child process the app treats the simulated robot as it treats a real
one: the control loop runs in its own process (:mod:`devices.loop_process`) on the robot's pty, the board reader
and the calibration rig open their ptys as serial ports, and the GUI's work delays neither.

:class:`LabProcess` (the app's side) starts ``python -m devices.sim.lab_process`` (a fresh interpreter, its own
session, as the loop's process), hands it the :class:`devices.config.LabConfig` over a socket pair and waits until
the child has built a :class:`devices.sim.lab.SimLab` and opened one pty per device (robot, board, rig). It then
stands behind the ``sim`` ports (:func:`devices.factory.start_lab_process`):

- :meth:`LabProcess.serial_path` names a device's pty; :func:`devices.factory.open_serial` opens it as a serial port;
- ``clock`` is the lab's clock (same start, same speed: ``time.monotonic`` is one clock for every process);
- ``chain``, ``board`` and ``rig`` call the lab's methods there: the Teach tab's simulated hand poses limp joints
  (``chain.set_limp_position``), faults are injected as on the in-process lab (``board.unplug()``,
  ``chain.inject_overload(3)``); :meth:`LabProcess.call` reaches any public method or value by its dotted name;
- ``physics`` draws the physics lab: the child publishes the world's joint positions (``qpos``) in a page of memory
  shared with the app ``QPOS_RATE_HZ`` times a second and :class:`MirrorPhysics` renders a copy of the same MuJoCo
  model posed from them (rendering in the lab's process would hold *its* interpreter lock ~15 ms a frame with a
  software OpenGL, and the servos would answer late).

The child serves the three ptys from one thread (select, woken when the next status packet or board frame is due,
the board looked at no more often than every ``BOARD_POLL_S``), asks for real-time scheduling as the loop does (the servos it stands in for
never wait for a PC), and ends when the app closes the socket — or dies, which closes it too. A board pty that
nobody reads does not fill up: more than ``BOARD_BACKLOG_S`` (wall time) of unread frames are discarded, as a USB adapter does
for a closed port, so a reader that opens it late starts on fresh frames.

Linux and macOS (``os.openpty``): :func:`devices.factory.lab_process_wanted` says where it can run and why not.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import logging
import mmap
import os
import select
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
import serial

from devices import process_messages as messages
from devices.child import child_setup, release_shared, spawn
from devices.config import LabConfig
from devices.errors import LabProcessUnavailable
from devices.sim.clock import SimClock

log = logging.getLogger(__name__)

READY_TIMEOUT_S = 60.0  # a fresh interpreter imports numpy and MuJoCo and builds the world
CALL_TIMEOUT_S = 5.0
CLOSE_TIMEOUT_S = 5.0
BOARD_POLL_S = 0.004  # the board's pty is looked at no more often than this (a USB adapter's 1-16 ms latency)
BOARD_BACKLOG_S = 1.0  # wall seconds: unread board bytes older than this are discarded (nobody reads the port)
IDLE_WAIT_S = 0.05
READ_CHUNK = 4096
QPOS_RATE_HZ = 30.0
QPOS_HEADER = struct.Struct("<Qd")  # sequence (odd while being written), the world's time (s)
DEVICES = ("robot", "board", "rig")


# == the app's side ====================================================================================================
class _Remote:
    """A dotted name on the child's :class:`devices.sim.lab.SimLab`: calling it calls that method there
    (``lab.board.unplug()``, ``lab.chain.set_limp_position(3, 2348)``); its attributes are longer names
    (``lab.rig.chain.inject_overload(1)``). A plain value is read with :meth:`LabProcess.call`."""

    def __init__(self, lab: LabProcess, name: str) -> None:
        self._lab = lab
        self._name = name

    def __getattr__(self, part: str) -> _Remote:
        if part.startswith("_"):
            raise AttributeError(part)
        return _Remote(self._lab, f"{self._name}.{part}")

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._lab.call(self._name, *args, **kwargs)


class LabProcess:
    """A :class:`devices.sim.lab.SimLab` in a child process; see the module docstring. ``start()`` first."""

    def __init__(self, config: LabConfig | None = None, *, seed: int = 0, speed: float = 1.0) -> None:
        self.config = config or LabConfig()
        self.seed = int(seed)
        self.speed = float(speed)
        self.clock = SimClock(speed)  # replaced by the child's clock at start (same start time)
        self.chain = _Remote(self, "chain")  # the Teach tab's SimHand: set_limp_position, release_limp_hold
        self.board = _Remote(self, "board")  # fault injection, as on the in-process lab: board.unplug() …
        self.rig = _Remote(self, "rig")
        self.physics: MirrorPhysics | None = None
        self.physics_note = ""
        self.paths: dict[str, str] = {}
        self._process: subprocess.Popen | None = None
        self._conn: Connection | None = None
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._qpos_fd: int | None = None
        self._qpos: mmap.mmap | None = None
        self._closed = False
        self.died = ""  # why the child ended without being asked to ("" while it runs or after close())
        self._died_listeners: list[Callable[[str], None]] = []

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process is not None else None

    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def serial_path(self, device: str) -> str:
        """The pty a host opens for ``device`` (robot, board, rig)."""
        if device not in self.paths:
            raise ValueError(f"the simulated lab has no device {device!r}")
        return self.paths[device]

    def endpoint(self, device: str) -> Any:
        raise RuntimeError(f"the simulated lab runs in its own process: open its {device} at {self.paths.get(device)}")

    def start(self) -> LabProcess:
        if self._process is not None:
            raise RuntimeError("the lab process is already running")
        try:
            child = spawn("devices.sim.lab_process", 4, "sensnake-qpos-")
        except (OSError, ValueError) as exc:
            raise LabProcessUnavailable(f"cannot start {sys.executable}: {exc}") from exc
        self._process, self._conn = child.process, child.conn
        self._qpos_fd, self._qpos = child.shared_fd, child.shared
        try:
            self._conn.send(messages.LabStart(self.config, self.seed, self.speed))
            ready = self._wait_ready()
        except BaseException:
            self.close()
            raise
        self.paths, self.physics_note = dict(ready.paths), ready.physics_note
        # One monotonic clock for every process: the same simulated time.
        self.clock = SimClock(self.speed, wall0=ready.wall0)
        if ready.nq is not None:
            self.physics = MirrorPhysics(self.config, self._qpos, int(ready.nq), gone=lambda: self.died)
        threading.Thread(target=self._watch, name="lab-process-watcher", daemon=True).start()
        return self

    def add_died_listener(self, listener: Callable[[str], None]) -> None:
        """``listener(text)`` is called (on a watcher thread) if the child ends without being asked to; at once if
        it already has."""
        with self._lock:
            self._died_listeners.append(listener)
            died = self.died
        if died:
            listener(died)

    def remove_died_listener(self, listener: Callable[[str], None]) -> None:
        with self._lock, contextlib.suppress(ValueError):
            self._died_listeners.remove(listener)

    def _watch(self) -> None:
        process = self._process
        assert process is not None
        code = process.wait()
        if self._closed:
            return
        how = f"killed by {signal.Signals(-code).name}" if code < 0 and -code in signal.valid_signals() else \
            f"exit status {code}"
        # What to do first: the status bar shows the start of a long message.
        text = (f"simulated lab stopped: restart the app (what was recorded is kept) — the simulated lab's process "
                f"(pid {process.pid}) ended ({how}), taking the simulated robot, board and rig with it")
        log.error("%s", text)
        with self._lock:
            self.died = text
            listeners = list(self._died_listeners)
        for listener in listeners:
            listener(text)

    def _wait_ready(self) -> messages.LabReady:
        conn, process = self._conn, self._process
        assert conn is not None and process is not None
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            try:
                if not conn.poll(0.2):
                    if process.poll() is not None:
                        raise LabProcessUnavailable(f"the simulated lab's process exited at start "
                                                    f"(exit code {process.returncode})")
                    continue
                reply = conn.recv()
            except (EOFError, OSError) as exc:
                raise LabProcessUnavailable("the simulated lab's process exited at start") from exc
            reply = messages.expect(reply, messages.LabReady, messages.Failed)
            if isinstance(reply, messages.LabReady):
                return reply
            assert isinstance(reply, messages.Failed)
            raise LabProcessUnavailable(f"the simulated lab did not start: {reply.error.qualname}: "
                                        f"{reply.error.message}")
        raise LabProcessUnavailable(f"the simulated lab's process did not start within {READY_TIMEOUT_S:g} s")

    def call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """Call ``name`` (a dotted path on the lab: ``chain.set_limp_position``, ``board.unplug``) in the child and
        return its result; its exception is raised here as the same class (a builtin or the project's own)."""
        with self._lock:
            if self._conn is None or self._closed:
                raise RuntimeError("the simulated lab's process is closed")
            request = next(self._ids)
            try:
                self._conn.send(messages.Call(request, name, tuple(args), dict(kwargs)))
                if not self._conn.poll(CALL_TIMEOUT_S):
                    raise RuntimeError(f"the simulated lab did not answer {name} within {CALL_TIMEOUT_S:g} s")
                reply = messages.reply_for(self._conn.recv(), request)
            except (EOFError, OSError) as exc:
                raise RuntimeError(f"the simulated lab's process is gone ({name} not done)") from exc
        if reply.error is not None:
            raise reply.error.rebuild()
        return reply.value

    def close(self) -> None:
        """End the child (closing the socket asks it to; killed if it does not within ``CLOSE_TIMEOUT_S``)."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            if self._conn is not None:
                with contextlib.suppress(OSError):
                    self._conn.close()
                self._conn = None
        process = self._process
        if process is not None:
            try:
                process.wait(timeout=CLOSE_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=CLOSE_TIMEOUT_S)
        if self.physics is not None:
            self.physics.close()
        self._close_qpos()

    def _close_qpos(self) -> None:
        release_shared(self._qpos_fd, self._qpos)
        self._qpos_fd, self._qpos = None, None


def read_qpos(page: mmap.mmap, nq: int) -> tuple[float, np.ndarray] | None:
    """The newest joint positions in ``page`` (the world's time, qpos), or None before the first."""
    view = np.frombuffer(page, dtype=np.float64, count=nq, offset=QPOS_HEADER.size)
    for _ in range(100):
        seq0, t_s = QPOS_HEADER.unpack_from(page, 0)
        if seq0 == 0:
            return None
        if seq0 % 2:
            time.sleep(0.0001)
            continue
        qpos = view.copy()
        if QPOS_HEADER.unpack_from(page, 0)[0] == seq0:
            return t_s, qpos
    return None


class _PosedWorld:
    """What a :class:`devices.sim.physics.render.SceneRenderer` reads of a world (``model``, ``update_scene``), for
    a copy of the lab's world posed from the newest published ``qpos`` before each picture."""

    def __init__(self, world: Any, page: mmap.mmap, nq: int) -> None:
        self.world = world
        self.model = world.model
        self._page = page
        self._nq = nq
        self.shown_time_s: float | None = None

    def update_scene(self, renderer: Any, camera: Any) -> None:
        import mujoco

        newest = read_qpos(self._page, self._nq)
        if newest is not None:
            self.shown_time_s, qpos = newest
            self.world.data.qpos[:] = qpos
            mujoco.mj_kinematics(self.world.model, self.world.data)
        self.world.update_scene(renderer, camera)


class MirrorPhysics:
    """Pictures of the lab's physics world, drawn here: the same MuJoCo model, posed from the child's ``qpos``.

    Has the drawing half of :class:`devices.sim.physics.backend.PhysicsBackend` (``render_rgb``,
    ``release_renderer``), which is what the 3-D tab uses; one renderer per calling thread. Once the lab's process
    has ended (``gone()`` says why) it refuses to draw the last pose as if it were live: RuntimeError."""

    def __init__(self, config: LabConfig, page: mmap.mmap, nq: int, gone: Callable[[], str] = str) -> None:
        from devices.sim.physics.backend import scene_from_config
        from devices.sim.physics.world import PhysicsWorld

        world = PhysicsWorld(scene_from_config(config))
        if world.model.nq != nq:
            raise LabProcessUnavailable(f"the lab's world has {nq} positions, its copy here {world.model.nq}")
        self.posed = _PosedWorld(world, page, nq)
        self._gone = gone  # why the lab's process has ended ("" while it runs): no picture of a stale pose then
        self._renderers: Any = None  # devices.sim.physics.render.ThreadRenderers, made on the first picture

    @property
    def shown_time_s(self) -> float | None:
        """The lab world's time of the pose drawn last (None before the first)."""
        return self.posed.shown_time_s

    def render_rgb(self, width: int = 640, height: int = 480, marks: Sequence[Any] = ()) -> np.ndarray:
        from devices.sim.physics.render import ThreadRenderers

        why = self._gone()
        if why:
            raise RuntimeError(why)  # the 3-D tab says it and draws the 2-D body instead
        if self._renderers is None:
            self._renderers = ThreadRenderers(self.posed)  # type: ignore[arg-type]
        return self._renderers.render(width, height, marks)

    def release_renderer(self) -> None:
        if self._renderers is not None:
            self._renderers.release()

    def close(self) -> None:
        self.release_renderer()


# == the child ========================================================================================================
class _Pty:
    def __init__(self, endpoint: Any, baud: int) -> None:
        self.endpoint = endpoint
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.baud = baud
        self.pending = bytearray()  # device bytes the pty could not take yet (written on the next pass)
        endpoint.host_opened(baud)

    def host_baud(self) -> int:
        from devices.sim.pty_server import host_baud

        return host_baud(self.slave, self.baud)

    def unread_bytes(self) -> int:
        buf = fcntl.ioctl(self.slave, termios.FIONREAD, b"\0\0\0\0")
        return int(struct.unpack("i", buf)[0])

    def forward(self, now_s: float) -> None:
        """Hand the host's bytes to the device and the device's due bytes to the host."""
        while True:
            try:
                data = os.read(self.master, READ_CHUNK)
            except (BlockingIOError, OSError):
                break
            if not data:
                break
            rate = self.host_baud()
            if rate != self.baud:
                self.baud = rate
                self.endpoint.host_opened(rate)
            self.endpoint.host_write(data, now_s)
        self.pending += self.endpoint.host_read(time.monotonic())
        if self.pending:
            try:
                written = os.write(self.master, self.pending)
            except (BlockingIOError, OSError):  # full: the host is not reading; kept for the next pass
                written = 0
            del self.pending[:written]

    def discard_unread(self) -> None:
        """Drop what the host has not read and what waits to be written (nobody is reading)."""
        termios.tcflush(self.slave, termios.TCIFLUSH)
        self.pending.clear()

    def close(self) -> None:
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def _serve(lab: Any, ptys: dict[str, _Pty], stop: threading.Event) -> None:
    from devices.realtime import _raise_thread_priority

    _raise_thread_priority()  # the emulated servos answer on time, as the real ones do
    board = ptys["board"]
    config = lab.config.board
    frame_bytes = 16 + 2 * config.n_channels
    # Wall seconds of frames at the lab's speed: a busy app that reads a few hundred ms late (a GUI stall, a loaded
    # machine) is a reader, not nobody; at 15× real time a limit counted in simulated seconds was 17 ms of wall time, and a
    # calibration on the simulated rig lost whole seconds of frames on a busy machine.
    backlog_limit = max(4 * frame_bytes, int(BOARD_BACKLOG_S * lab.clock.speed * config.rate_hz * frame_bytes))
    chains = [ptys["robot"], ptys["rig"]]
    fds = [p.master for p in ptys.values()]
    next_board = time.monotonic()
    while not stop.is_set():
        now = time.monotonic()
        dues = [due for due in (p.endpoint.next_delivery_wall_s() for p in chains) if due is not None]
        if any(p.pending for p in chains):
            dues.append(now + 0.001)  # a reply the pty could not take at once
        wake = min([next_board, *dues])
        readable, _, _ = select.select(fds, [], [], max(0.0, min(wake - now, IDLE_WAIT_S)))
        now = time.monotonic()
        due_board = now >= next_board
        if due_board:
            # Woken when the board's next bytes are in (a frame at 30 Hz), polled every BOARD_POLL_S while bytes
            # wait or nobody listens.
            next_board = max(board.endpoint.next_delivery_wall_s(), now + BOARD_POLL_S)
        for pty in ptys.values():
            if pty is board and not due_board and board.master not in readable:
                continue
            try:
                pty.forward(now)
            except serial.SerialException as exc:  # a simulated unplug: the host hears nothing meanwhile
                log.debug("%s: %s", pty.path, exc)
            except Exception:  # noqa: BLE001 - the thread that serves every device must not end: say it, go on
                log.exception("the simulated lab's %s device failed a pass", pty.path)
        if due_board and board.unread_bytes() + len(board.pending) > backlog_limit:
            board.discard_unread()  # nobody reads: a reader that opens the port late starts on fresh frames


def _publish_qpos(lab: Any, page: mmap.mmap, stop: threading.Event) -> None:
    world = lab.physics.world
    view = np.frombuffer(page, dtype=np.float64, count=world.model.nq, offset=QPOS_HEADER.size)
    seq = 0
    while not stop.wait(1.0 / QPOS_RATE_HZ):
        t_s, qpos = world.pose_snapshot()
        QPOS_HEADER.pack_into(page, 0, seq + 1, t_s)
        view[:] = qpos
        seq += 2
        QPOS_HEADER.pack_into(page, 0, seq, t_s)


def _resolve(lab: Any, name: str) -> Any:
    target = lab
    for part in name.split("."):
        if not part or part.startswith("_"):
            raise AttributeError(f"{name!r} is not a public name of the simulated lab")
        target = getattr(target, part)
    return target


def child_main(conn: Connection, page: mmap.mmap | None) -> int:
    from devices.sim.lab import SimLab

    start = messages.expect(conn.recv(), messages.LabStart)
    config = start.config
    try:
        lab = SimLab(config, seed=start.seed, speed=start.speed)
        lab.realtime_threads = True  # the simulated motion capture's sender, raised as the threads below
        lab.start_background()
        ptys = {"robot": _Pty(lab.chain, config.robot.baud), "board": _Pty(lab.board, config.board.baud),
                "rig": _Pty(lab.rig.chain, config.rig.baud)}
    except Exception as exc:  # noqa: BLE001 - said to the app, which then keeps the lab in the app's process
        conn.send(messages.Failed(messages.ErrorPayload.of(exc, "lab")))
        return 1
    stop = threading.Event()
    threads = [threading.Thread(target=_serve, args=(lab, ptys, stop), name="lab-ptys", daemon=True)]
    nq = None
    if lab.physics is not None and page is not None:
        nq = int(lab.physics.world.model.nq)
        threads.append(threading.Thread(target=_publish_qpos, args=(lab, page, stop), name="lab-qpos", daemon=True))
    for thread in threads:
        thread.start()
    # This (the calls') thread and the qpos publisher get the servos' priority too (when permitted): one preempted
    # while it holds the interpreter lock would make the servos answer late. Not the physics world's stepping
    # thread: when it cannot keep up it steps without sleeping, and at real-time priority it would take a core from
    # the app.
    from devices.realtime import _raise_thread_priority, raise_thread_priority_of

    _raise_thread_priority()
    for thread in threads:
        if thread.native_id is not None:
            raise_thread_priority_of(thread.native_id)
    conn.send(messages.LabReady({name: p.path for name, p in ptys.items()}, lab.clock.wall0, nq, lab.physics_note))
    try:
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):
                return 0  # the app closed the socket (or died)
            call = messages.expect(message, messages.Call)
            try:
                target = _resolve(lab, call.name)
                value = target(*call.args, **call.kwargs) if callable(target) else target  # a property: its value
                answer = messages.Result(call.request_id or 0, value)
            except Exception as exc:  # noqa: BLE001 - handed back to the caller, raised there as itself
                answer = messages.Result(call.request_id or 0, error=messages.ErrorPayload.of(exc, "lab"))
            if call.request_id is not None:
                conn.send(answer)
    finally:
        stop.set()
        for thread in threads:
            thread.join(timeout=2.0)
        lab.close()
        for pty in ptys.values():
            pty.close()


def main(argv: Sequence[str] | None = None) -> int:
    conn, page = child_setup(argv, "python -m devices.sim.lab_process",
                             "The simulated lab's process (started by the app).",
                             "a file shared with the app: the world's joint positions", "lab process")
    from devices.realtime import _lower_switch_interval

    _lower_switch_interval()  # the pty thread waits at most this for the physics thread's lock
    return child_main(conn, page)


if __name__ == "__main__":
    sys.exit(main())
