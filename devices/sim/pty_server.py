"""Serve a simulated servo chain on a pseudo-terminal, so any program can open it as a serial port.

    python -m devices.sim.pty_server --device robot [--seed N] [--speed X] [--config FILE]

Opens a pty in raw mode, prints the slave path (``/dev/pts/N``) as the first line on stdout, and serves a
:class:`devices.sim.dxl_chain.VirtualChain` on it until killed or until stdin closes. The host's baud rate is read
from the pty's termios settings, so a servo is only heard when the host uses its rate, as on a real bus.

Faults can be injected by writing lines on stdin (each answered by ``ok`` or ``error: …`` on stdout)::

    overload ID | no_reply ID | reply ID | corrupt N [ID] | load ID NM | limp ID TICKS | temperature ID C |
    voltage V

Linux and macOS only (``os.openpty``). A sim module: it may import ``devices.sim.*`` directly.
"""

from __future__ import annotations

import argparse
import os
import select
import sys
import termios
import time
import tty
from collections.abc import Sequence

from devices.config import LabConfig, load_config
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import VirtualChain

IDLE_WAIT_S = 0.05
READ_CHUNK = 4096
_BAUD_FROM_TERMIOS = {
    getattr(termios, f"B{rate}"): rate
    for rate in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000,
                 2000000, 2500000, 3000000, 3500000, 4000000)
    if hasattr(termios, f"B{rate}")
}


def build_chain(config: LabConfig, device: str, seed: int, speed: float) -> VirtualChain:
    clock = SimClock(speed)
    if device == "robot":
        return VirtualChain(ids=config.robot.joint_ids, baud=config.robot.baud, clock=clock, seed=seed)
    if device == "rig":
        return VirtualChain(ids=(config.rig.servo_id,), baud=config.rig.baud, clock=clock, seed=seed)
    raise ValueError(f"the pty server serves a servo bus: device must be 'robot' or 'rig', not {device!r}")


def host_baud(slave_fd: int, fallback: int) -> int:
    """The baud rate the host set on the pty (termios output speed); ``fallback`` for a custom rate."""
    speed = termios.tcgetattr(slave_fd)[5]
    return _BAUD_FROM_TERMIOS.get(speed, fallback)


def handle_command(chain: VirtualChain, line: str) -> str:
    """Apply one fault/hand command from stdin; returns the reply line."""
    words = line.split()
    if not words:
        return "ok"
    verb, args = words[0], words[1:]
    try:
        if verb == "overload":
            chain.inject_overload(int(args[0]))
        elif verb == "no_reply":
            chain.set_no_reply(int(args[0]), True)
        elif verb == "reply":
            chain.set_no_reply(int(args[0]), False)
        elif verb == "corrupt":
            chain.corrupt_next_replies(int(args[0]), int(args[1]) if len(args) > 1 else None)
        elif verb == "load":
            chain.set_load(int(args[0]), float(args[1]))
        elif verb == "limp":
            chain.set_limp_position(int(args[0]), float(args[1]))
        elif verb == "temperature":
            chain.set_temperature(int(args[0]), float(args[1]))
        elif verb == "voltage":
            chain.set_supply_voltage(float(args[0]))
        else:
            return f"error: unknown command {verb!r}"
    except (IndexError, KeyError, ValueError) as exc:
        return f"error: {exc}"
    return "ok"


def _say(out, text: str) -> None:
    out.write(text + "\n")
    out.flush()


def serve(chain: VirtualChain, baud: int, out=sys.stdout) -> None:
    """Run until stdin closes. Prints the slave path first."""
    master_fd, slave_fd = os.openpty()
    tty.setraw(master_fd)
    tty.setraw(slave_fd)
    _say(out, os.ttyname(slave_fd))
    chain.host_opened(baud)
    stdin_fd = sys.stdin.fileno()
    stdin_buf = b""
    watch = [master_fd, stdin_fd]
    try:
        while True:
            now = time.monotonic()
            due = chain.next_delivery_wall_s()
            timeout = IDLE_WAIT_S if due is None else max(0.0, due - now)
            readable, _, _ = select.select(watch, [], [], timeout)
            if master_fd in readable:
                try:
                    data = os.read(master_fd, READ_CHUNK)
                except OSError:  # EIO on Linux while no process has the slave open
                    data = b""
                if data:
                    rate = host_baud(slave_fd, baud)
                    if rate != chain.host_baud:
                        chain.host_opened(rate)
                    chain.host_write(data, time.monotonic())
            if stdin_fd in readable:
                chunk = os.read(stdin_fd, READ_CHUNK)
                if not chunk:
                    return
                stdin_buf += chunk
                while b"\n" in stdin_buf:
                    line, stdin_buf = stdin_buf.split(b"\n", 1)
                    _say(out, handle_command(chain, line.decode(errors="replace")))
            reply = chain.host_read(time.monotonic())
            if reply:
                os.write(master_fd, reply)
    finally:
        os.close(master_fd)
        os.close(slave_fd)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m devices.sim.pty_server", description=__doc__.split("\n")[0])
    parser.add_argument("--device", choices=("robot", "rig"), default="robot")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--speed", type=float, default=1.0, help="simulated clock speed (1 = real time)")
    parser.add_argument("--config", metavar="FILE", help="lab config (joint IDs, baud); default: the built-in one")
    args = parser.parse_args(argv)
    if not hasattr(os, "openpty"):
        _say(sys.stderr, "pty_server: pseudo-terminals need Linux or macOS")
        return 2
    config = load_config(args.config) if args.config else LabConfig()
    chain = build_chain(config, args.device, args.seed, args.speed)
    baud = config.robot.baud if args.device == "robot" else config.rig.baud
    try:
        serve(chain, baud)
    except KeyboardInterrupt:
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
