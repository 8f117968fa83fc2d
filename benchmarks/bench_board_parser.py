"""Force-sensor board: frame parser throughput and the reader's CPU cost (SPEC §4).

Target: 1024 channels × 100 frames/s using < 10% of one core. Prints
(a) the CRC alone (binascii's C loop vs the pure-Python table reference),
(b) FrameParser.feed throughput in channel·frames/s and the CPU share that 1024 ch × 100 fps and 36 ch × 30 fps
    would take, for clean streams and for streams with 1% corrupted frames and garbage,
(c) end to end: VirtualBoard → SimSerial → BoardReader thread → read_block, process CPU while streaming in real
    time (this includes the simulated board's own work, so it is an upper bound for the reader).

Run: ``python -m benchmarks.bench_board_parser [--quick]``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from devices import factory
from devices.board import BoardReader, FrameParser, crc16_ccitt_false, crc16_ccitt_false_table, encode_frame
from devices.config import BoardConfig, LabConfig
from devices.sim.board import VirtualBoard
from devices.sim.clock import SimClock
from devices.sim.contact import ContactModel

READ_CHUNK_BYTES = 4096  # what a USB-serial read typically returns at these rates


def _stream(n_channels: int, n_frames: int, corrupt_fraction: float = 0.0, seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed)
    parts = []
    for seq in range(n_frames):
        frame = bytearray(encode_frame(seq, seq * 10_000, rng.integers(0, 4096, n_channels)))
        if corrupt_fraction and rng.random() < corrupt_fraction:
            frame[20] ^= 0x04
            parts.append(rng.integers(0, 256, 37, dtype=np.uint8).tobytes())
        parts.append(bytes(frame))
    return b"".join(parts)


def _time_feed(stream: bytes, repeats: int) -> tuple[float, float, FrameParser]:
    best_wall = best_cpu = float("inf")
    parser = FrameParser()
    for _ in range(repeats):
        parser = FrameParser()
        wall0, cpu0 = time.perf_counter(), time.process_time()
        for start in range(0, len(stream), READ_CHUNK_BYTES):
            parser.feed(stream[start:start + READ_CHUNK_BYTES])
        best_wall = min(best_wall, time.perf_counter() - wall0)
        best_cpu = min(best_cpu, time.process_time() - cpu0)
    return best_wall, best_cpu, parser


def bench_crc(quick: bool) -> None:
    frame_body = _stream(1024, 1)[2:-2]
    n = 20 if quick else 100
    t0 = time.perf_counter()
    for _ in range(n):
        crc16_ccitt_false_table(frame_body)
    table_s = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for _ in range(n * 100):
        crc16_ccitt_false(frame_body)
    fast_s = (time.perf_counter() - t0) / (n * 100)
    print(f"(a) CRC of one 1024-channel frame ({len(frame_body)} bytes): binascii {fast_s * 1e6:8.2f} µs, "
          f"pure-Python table {table_s * 1e6:8.1f} µs ({table_s / fast_s:,.0f}× slower)")


def bench_parser(quick: bool) -> None:
    print("(b) FrameParser.feed, 4 KiB reads")
    print(f"    {'channels':>8} {'stream':>12} {'frames':>7} {'ch·frames/s':>14} {'µs/frame':>9} "
          f"{'CPU @100 fps':>13} {'CPU @30 fps':>12}")
    n_frames = 300 if quick else 2000
    repeats = 2 if quick else 5
    for n_channels in (36, 256, 1024):
        for label, corrupt in (("clean", 0.0), ("1% corrupt", 0.01)):
            stream = _stream(n_channels, n_frames, corrupt)
            wall, cpu, parser = _time_feed(stream, repeats)
            per_frame = cpu / max(parser.frames, 1)
            print(f"    {n_channels:8d} {label:>12} {parser.frames:7d} {n_channels * parser.frames / wall:14,.0f} "
                  f"{per_frame * 1e6:9.1f} {per_frame * 100 * 100:12.2f}% {per_frame * 30 * 100:11.3f}%")
    print("    CPU @N fps = CPU seconds per frame × N, as a share of one core (target at 1024 ch × 100 fps: < 10%)")


class _BoardOnlyLab:
    def __init__(self, board: VirtualBoard) -> None:
        self.board = board

    def endpoint(self, device: str) -> VirtualBoard:
        return self.board


def bench_end_to_end(quick: bool) -> None:
    print("(c) VirtualBoard → BoardReader, streaming in real time")
    print(f"    {'channels':>8} {'rate':>6} {'baud':>9} {'seconds':>7} {'frames':>7} {'lost':>5} {'CPU (sim+reader)':>17}")
    seconds = 1.5 if quick else 5.0
    for n_channels, rate_hz, baud in ((36, 30.0, 2_000_000), (1024, 100.0, 4_000_000)):
        names = tuple(f"C{k:04d}" for k in range(n_channels))
        board_cfg = replace(BoardConfig(), channel_names=names, rate_hz=rate_hz, baud=baud)
        config = replace(LabConfig(), board=board_cfg)
        clock = SimClock(1.0)
        board = VirtualBoard(board_cfg, clock, ContactModel(config, None, seed=1).forces_n, seed=2)
        previous = factory.install_sim_lab(_BoardOnlyLab(board))
        try:
            with BoardReader(board_cfg) as reader:
                reader.wait_for_frames(1, 5.0)
                reader.read_block()
                wall0, cpu0 = time.perf_counter(), time.process_time()
                frames = 0
                while time.perf_counter() - wall0 < seconds:
                    if reader.wait_for_frames(1, 0.1):
                        block = reader.read_block()
                        frames += 0 if block is None else len(block)
                wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
                stats = reader.stats
        finally:
            factory.install_sim_lab(previous)
        print(f"    {n_channels:8d} {rate_hz:5.0f}  {baud:9d} {wall:7.1f} {frames:7d} {stats.dropped_frames:5d} "
              f"{cpu / wall * 100:16.1f}%")
    print("    (includes the simulated board: 1024 sensors of SLS physics, readout and framing at 100 Hz; the parser"
          " alone is in (b))")


def run(quick: bool) -> None:
    bench_crc(quick)
    bench_parser(quick)
    bench_end_to_end(quick)


if __name__ == "__main__":
    run(quick="--quick" in sys.argv[1:])
