"""Recording files: write throughput of RecordingWriter and read-back time.

Each flush opens the file, appends, closes and fsyncs it (no HDF5 handle stays open, so a killed recorder leaves a
file plain h5py opens). Prints, for 36 channels (the robot) and 1024 channels (a full board), the rate at which board
frames can be appended in the blocks the GUI hands over (a block per 1/30 s) and flushed every 0.5 s, as frames/s,
MB/s of sample data, the CPU share that recording in real time would take and the flush time (median / max, the
window in which a ``kill -9`` could catch the file mid-write); then the time to open the file again.
Run: ``python -m benchmarks.bench_recording [--quick]``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from app.core.recording import RecordingWriter, open_recording
from devices.board import SampleBlock, conductance_from_counts
from devices.config import BoardConfig


def _blocks(n_channels: int, frames_per_block: int, n_blocks: int, seed: int = 0) -> list[SampleBlock]:
    rng = np.random.default_rng(seed)
    board = BoardConfig()
    blocks = []
    t0 = time.monotonic()
    for b in range(n_blocks):
        counts = rng.integers(1, 4096, (frames_per_block, n_channels)).astype(np.uint16)
        seq = (b * frames_per_block + np.arange(frames_per_block)).astype(np.uint32)
        blocks.append(SampleBlock(counts=counts, conductance_s=conductance_from_counts(counts, board),
                                  board_time_s=seq * 0.01, host_time_s=t0 + seq * 0.01, seq=seq,
                                  saturated=counts == 0))
    return blocks


def run(quick: bool) -> None:
    print(f"{'channels':>8} {'rate':>6} {'frames':>7} {'frames/s':>10} {'MB/s':>7} {'CPU @rate':>10} "
          f"{'flush ms p50/max':>16} {'file MB':>8} {'open+read s':>11}")
    cases = ((36, 30, 3000 if quick else 30_000), (1024, 100, 500 if quick else 6000))
    with tempfile.TemporaryDirectory() as tmp:
        for n_channels, rate_hz, n_frames in cases:
            per_block = max(1, rate_hz // 30)  # the GUI drains the reader at ≤ 60 Hz; ~30 Hz blocks here
            blocks = _blocks(n_channels, per_block, n_frames // per_block)
            path = Path(tmp) / f"bench_{n_channels}.h5"
            names = [f"C{k:04d}" for k in range(n_channels)]
            wall0, cpu0 = time.perf_counter(), time.process_time()
            # flush_interval 0.5 s of *recorded* time: flush every rate/2 frames, as a real-time recording would.
            with RecordingWriter(path, "", names, flush_interval_s=3600.0) as writer:
                since_flush = 0
                flush_s = []
                for block in blocks:
                    writer.append_daq(block)
                    since_flush += len(block)
                    if since_flush >= rate_hz // 2:
                        f0 = time.perf_counter()
                        writer.flush()
                        flush_s.append(time.perf_counter() - f0)
                        since_flush = 0
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
            frames = sum(len(b) for b in blocks)
            data_mb = frames * n_channels * (2 + 8) / 1e6
            t0 = time.perf_counter()
            rec = open_recording(path)
            read_s = time.perf_counter() - t0
            assert rec.n_samples == frames
            print(f"{n_channels:8d} {rate_hz:6d} {frames:7d} {frames / wall:10,.0f} {data_mb / wall:7.1f} "
                  f"{cpu / frames * rate_hz * 100:9.2f}% "
                  f"{1e3 * np.median(flush_s):7.1f}/{1e3 * max(flush_s):<8.1f} "
                  f"{path.stat().st_size / 1e6:8.1f} {read_s:11.3f}")
    print("CPU @rate = CPU seconds per frame × frame rate: the share of one core a real-time recording takes")


if __name__ == "__main__":
    run(quick="--quick" in sys.argv[1:])
