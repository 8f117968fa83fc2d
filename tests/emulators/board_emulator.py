"""An independent force-sensor board on a pseudo-terminal, written from SPEC §4 alone (not from ``devices/``).

Run it as its own process::

    python -m tests.emulators.board_emulator --link DIR/board [--channels 36] [--rate-hz 30] [--baud 2000000]
        [--garbage P] [--crc-flip P] [--drop P] [--over-range P] [--wrong-channels N --wrong-from-s T]
        [--unplug-at S] [--replug-at S] [--silent] [--t-us-start US] [--seed K] [--log FILE.json]
        [--version V] [--clock-back-at S [--clock-back-us US]] [--hold-first S] [--burst S]

It makes a pty, points the symlink ``--link`` at its slave (a host opens that path like ``/dev/ttyUSB0``) and prints
``READY <link>`` on stdout. Frames go out at the board's rate, each written as one burst the way a USB-serial adapter
delivers them; the frame rate must fit the baud rate (10 bits per byte). Counts follow :func:`expected_counts` so a
test can check every recorded value exactly.

Faults, drawn per frame from a seeded generator: ``--garbage P`` random bytes (1…40) before the frame; ``--crc-flip
P`` one bit flipped in the frame after the sync bytes (the host must reject it); ``--drop P`` the frame is never sent
(``seq`` still advances); ``--over-range P`` a count above 4095 with a *valid* CRC (impossible for a 12-bit ADC);
``--wrong-channels N`` sends N channels instead (from ``--wrong-from-s`` on); ``--version V`` sends protocol
version V (valid CRC); ``--repeat P`` sends a frame twice (same seq); ``--clock-back-at S`` steps ``t_us`` back by ``--clock-back-us`` once, seq going on. Delivery:
``--hold-first S`` keeps the frames of the first S seconds and writes them together at S (a board that blocks until
its host reads, then sends its backlog); ``--burst S`` writes the frames made in each S seconds together (an adapter
that holds them back); frames keep the board's pace and clock either way. ``--silent`` opens the pty and sends
nothing. Unplug closes the pty and removes the link (the host sees EIO); re-plug makes a new pty behind the same link
and the board restarts: ``seq`` and ``t_us`` from 0 (a new clock segment). Commands on stdin (one per line):
``unplug``, ``replug``, ``quit``; or ``--unplug-at``/``--replug-at`` seconds after start.

On exit (``quit``, SIGTERM, SIGINT, SIGHUP, or end of stdin — so an emulator never outlives its test) it writes ``--log``: JSON ``{"segments": [{"sent":
[seq…], "corrupt": [seq…], "dropped": [seq…], "unread": [seq…]}]}`` — ``sent`` are the good frames written whole,
``unread`` the frames the pty could not take (nobody reading, buffer full).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import faulthandler
import json
import os
import random
import signal
import struct
import sys
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

SYNC = b"\xa5\x5a"
VERSION = 1
BITS_PER_BYTE = 10
ADC_MAX = 4095


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE, bit by bit (poly 0x1021, init 0xFFFF, MSB first, no final xor) — SPEC §4."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def expected_counts(seq: int, n_channels: int, segment: int = 0) -> list[int]:
    """The counts the emulator sends in frame ``seq`` of plug segment ``segment``: 1 … 4095, all distinct per
    channel, so a swapped column or a shifted frame cannot match."""
    return [1 + (seq * 37 + k * 101 + segment * 997) % ADC_MAX for k in range(n_channels)]


def encode(seq: int, t_us: int, counts: list[int], flags: int = 0, version: int = VERSION) -> bytes:
    """One SPEC §4 frame (little-endian; CRC over version … last reading)."""
    body = struct.pack("<BBIIH", version, flags, seq & 0xFFFFFFFF, t_us & 0xFFFFFFFF, len(counts))
    body += struct.pack(f"<{len(counts)}H", *counts)
    return SYNC + body + struct.pack("<H", crc16_ccitt_false(body))


@dataclass
class Segment:
    sent: list[int] = field(default_factory=list)
    corrupt: list[int] = field(default_factory=list)
    dropped: list[int] = field(default_factory=list)
    unread: list[int] = field(default_factory=list)


class Board:
    """The emulated board; :meth:`run` paces frames until :meth:`quit`. Commands may come from any thread."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.link = Path(args.link)
        self.rng = random.Random(args.seed)
        self.segments: list[Segment] = []
        self._lock = threading.Lock()
        self._quit = threading.Event()
        # Set by the signal handler. Not the Event: Event.set() takes the lock Event.wait() holds around its check,
        # and a handler runs on the main thread inside that wait -- it would wait for itself forever (seen in CI:
        # SIGTERM ignored for 20 s). A plain attribute is atomic; the loop polls it at least every 50 ms.
        self.signalled = False
        self._master: int | None = None
        self._slave: int | None = None
        self._plugged_at = 0.0
        self._index = 0  # frames since the plug (seq and clock restart with each plug)
        self._held: list[tuple[bytes, int | None, str, Segment]] = []  # frames made, not yet written (see --burst)
        self._held_since = 0.0
        frame_bytes = 16 + 2 * args.channels
        if args.rate_hz * frame_bytes * BITS_PER_BYTE > args.baud:
            raise SystemExit(f"board emulator: {args.rate_hz} frames/s of {frame_bytes} bytes do not fit "
                             f"{args.baud} baud")

    # -- plug ---------------------------------------------------------------------------------------------------
    def plug(self) -> None:
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave)  # no line discipline: bytes pass untouched before the host sets its own mode
            os.set_blocking(master, False)
            tmp = self.link.with_name(self.link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(os.ttyname(slave))
            os.replace(tmp, self.link)
            self._master, self._slave = master, slave
            self._plugged_at = time.monotonic()
            self._index = 0
            self.segments.append(Segment())

    def unplug(self) -> None:
        with self._lock:
            if self._master is None:
                return
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
            os.close(self._master)
            if self._slave is not None:
                os.close(self._slave)
            self._master = self._slave = None

    def quit(self) -> None:
        self._quit.set()

    # -- streaming ----------------------------------------------------------------------------------------------
    def run(self) -> None:
        args = self.args
        start = time.monotonic()
        unplug_at = None if args.unplug_at is None else start + args.unplug_at
        replug_at = None if args.replug_at is None else start + args.replug_at
        period = 1.0 / args.rate_hz
        while not (self._quit.is_set() or self.signalled):
            now = time.monotonic()
            if unplug_at is not None and now >= unplug_at:
                unplug_at = None
                self.unplug()
            if replug_at is not None and now >= replug_at:
                replug_at = None
                self.plug()
            with self._lock:
                plugged = self._master is not None
                due = self._plugged_at + self._index * period if plugged else now + period
            if now < due:
                # The board's own pace: this process is the device, not a test waiting for a result.
                self._quit.wait(min(due - now, 0.05))
                continue
            if plugged and not args.silent:
                self._send_one(now - start)
            with self._lock:
                self._index += 1

    def _send_one(self, elapsed_s: float) -> None:
        args, rng = self.args, self.rng
        with self._lock:
            if self._master is None:
                return
            seq = self._index
            segment_no = len(self.segments) - 1
            segment = self.segments[-1]
            t_us = args.t_us_start + round(seq * 1e6 / args.rate_hz) if segment_no == 0 else \
                round(seq * 1e6 / args.rate_hz)
            if args.clock_back_at is not None and elapsed_s >= args.clock_back_at:
                t_us -= args.clock_back_us  # the board's clock steps back once; seq goes on
        n = args.channels
        if args.wrong_channels and elapsed_s >= args.wrong_from_s:
            n = args.wrong_channels
        counts = expected_counts(seq, n, segment_no)
        kind = "sent" if n == args.channels else "corrupt"
        data = b""
        if rng.random() < args.garbage:
            data += bytes(rng.randrange(256) for _ in range(rng.randint(1, 40)))
        if rng.random() < args.drop:
            segment.dropped.append(seq)
            frame = b""
        else:
            if rng.random() < args.over_range:
                counts = list(counts)
                counts[rng.randrange(n)] = rng.randint(ADC_MAX + 1, 0xFFFF)
                kind = "corrupt"
            frame = encode(seq, t_us, counts, version=args.version)
            if rng.random() < args.crc_flip:
                flipped = bytearray(frame)
                at = rng.randrange(2, len(flipped))
                flipped[at] ^= 1 << rng.randrange(8)
                frame = bytes(flipped)
                kind = "corrupt"
        data += frame
        if frame and args.repeat and rng.random() < args.repeat:
            data += frame  # the same frame (same seq) twice: a firmware that repeats itself
        self._held.append((data, seq if frame else None, kind, segment))
        hold_until = self._held_since + args.burst if args.burst else 0.0
        if args.hold_first is not None and elapsed_s < args.hold_first:
            return  # a board that blocks until its host reads: the frames wait in it and then go out together
        if args.burst and elapsed_s < hold_until:
            return  # an adapter that holds frames and hands them over in bursts
        self._flush_held(elapsed_s)

    def _flush_held(self, elapsed_s: float) -> None:
        held, self._held = self._held, []
        self._held_since = elapsed_s
        written = self._write(b"".join(data for data, *_ in held))
        end = 0
        for data, seq, kind, segment in held:
            end += len(data)
            if seq is None:
                continue
            if written < end:
                segment.unread.append(seq)
            elif kind == "sent":
                segment.sent.append(seq)
            else:
                segment.corrupt.append(seq)

    def _write(self, data: bytes) -> int:
        with self._lock:
            if self._master is None or not data:
                return 0
            try:
                return os.write(self._master, data)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EIO):
                    return 0  # nobody is reading and the pty is full: the bytes are lost, as on a real UART
                raise

    def write_log(self) -> None:
        if self.args.log:
            document = {"segments": [vars(s) for s in self.segments]}
            Path(self.args.log).write_text(json.dumps(document))


def _commands(board: Board) -> None:
    for line in sys.stdin:
        word = line.strip()
        if word == "unplug":
            board.unplug()
        elif word == "replug":
            board.plug()
        elif word == "quit":
            break
        print(f"OK {word}", flush=True)
    # The test said quit or went away (stdin closed): stop streaming either way.
    board.quit()


class EmulatedBoard:
    """The emulator as a child process, for tests and the fault matrix. Any thread (one at a time).

    ``EmulatedBoard(tmp_dir, rate_hz=200, garbage=0.05, …)`` starts it with those options (underscores become
    dashes; ``True`` becomes a bare flag) and returns once the link exists; :meth:`command` sends ``unplug`` /
    ``replug``; :meth:`stop` ends it and returns the log.
    """

    def __init__(self, folder: str | os.PathLike[str], **options: object) -> None:
        import subprocess

        self.link = Path(folder) / "board"
        self.log_path = Path(folder) / "board-log.json"
        argv = [sys.executable, "-m", "tests.emulators.board_emulator", "--link", str(self.link),
                "--log", str(self.log_path)]
        for key, value in options.items():
            flag = "--" + key.replace("_", "-")
            if value is True:
                argv.append(flag)
            elif value is not None and value is not False:
                argv += [flag, str(value)]
        repo = Path(__file__).resolve().parents[2]
        self.process = subprocess.Popen(argv, cwd=repo, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.process.stdout is not None
        line = self.process.stdout.readline()  # blocks until the pty exists (or the emulator failed)
        if not line.startswith("READY"):
            self.process.kill()
            self.process.wait()
            raise RuntimeError(f"board emulator did not start: {line!r}")

    @property
    def path(self) -> str:
        return str(self.link)

    def command(self, word: str) -> None:
        """``unplug`` or ``replug``; returns once the emulator did it."""
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(word + "\n")
        self.process.stdin.flush()
        reply = self.process.stdout.readline()
        if reply.strip() != f"OK {word}":
            raise RuntimeError(f"board emulator answered {reply!r} to {word!r}")

    def stop(self, timeout_s: float = 20.0) -> dict:
        """End the emulator (the pty goes away) and return its log (see the module docstring). An emulator that
        does not end within ``timeout_s`` prints its threads' stacks (faulthandler, to the test's stderr), is
        killed, and this raises: a hung emulator never outlives its test nor hides why it hung."""
        import subprocess

        if self.process.stdin is not None:
            with contextlib.suppress(OSError):
                self.process.stdin.close()  # end of stdin: a second way to say quit
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            # wait(), not communicate(): the end of the process, not the end of its stdout (a pipe another process
            # may share by inheritance), is what is waited for.
            self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.send_signal(signal.SIGUSR1)  # faulthandler: dump every thread's stack
            time.sleep(1.0)
            self.process.kill()
            self.process.wait()
            raise RuntimeError(f"board emulator ignored SIGTERM for {timeout_s:.0f} s (stacks above); killed") from None
        finally:
            for stream in (self.process.stdin, self.process.stdout):
                if stream is not None:
                    with contextlib.suppress(OSError):
                        stream.close()
        return json.loads(self.log_path.read_text()) if self.log_path.exists() else {"segments": []}

    def __enter__(self) -> EmulatedBoard:
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self.process.poll() is None:
            self.stop()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="board_emulator", description=__doc__.split("\n\n")[0])
    p.add_argument("--link", required=True, help="symlink to create for the host to open")
    p.add_argument("--channels", type=int, default=36)
    p.add_argument("--rate-hz", type=float, default=30.0)
    p.add_argument("--baud", type=int, default=2_000_000)
    p.add_argument("--garbage", type=float, default=0.0)
    p.add_argument("--crc-flip", type=float, default=0.0)
    p.add_argument("--drop", type=float, default=0.0)
    p.add_argument("--over-range", type=float, default=0.0)
    p.add_argument("--wrong-channels", type=int, default=0)
    p.add_argument("--wrong-from-s", type=float, default=0.0)
    p.add_argument("--unplug-at", type=float, default=None)
    p.add_argument("--repeat", type=float, default=0.0, help="probability a frame is sent twice (same seq)")
    p.add_argument("--version", type=int, default=VERSION, help="protocol version byte to send (SPEC §4 is 1)")
    p.add_argument("--clock-back-at", type=float, default=None,
                   help="from this many seconds on, t_us is --clock-back-us lower (seq goes on)")
    p.add_argument("--clock-back-us", type=int, default=500_000)
    p.add_argument("--replug-at", type=float, default=None)
    p.add_argument("--hold-first", type=float, default=None,
                   help="keep the frames of the first S seconds and send them together at S (a board that blocks "
                        "until its host reads)")
    p.add_argument("--burst", type=float, default=0.0,
                   help="hand the frames over together every S seconds (an adapter that holds them back)")
    p.add_argument("--silent", action="store_true")
    p.add_argument("--t-us-start", type=int, default=0, help="board clock at the first frame (test the 2³² wrap)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--log", default=None)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # EmulatedBoard.stop asks for stacks if we hang
    board = Board(args)
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, lambda *_: setattr(board, "signalled", True))
    board.plug()
    print(f"READY {board.link}", flush=True)
    threading.Thread(target=_commands, args=(board,), name="commands", daemon=True).start()
    try:
        board.run()
    finally:
        board.unplug()
        board.write_log()
    return 0


if __name__ == "__main__":
    sys.exit(main())
