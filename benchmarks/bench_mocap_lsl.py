"""The live motion-capture path against the lab's acceptance numbers (docs/MOCAP.md, "Live: Lab Streaming Layer").

Three processes: a 480 Hz LSL MoCap sender (``tests/mocap_streams.py``'s: 4 markers on each of 12 segments, in mm,
with the channel metadata; the straight body sliding along x at 0.2 m/s), ``sensnake record --daq sim --seconds N
--mocap lsl:BenchMocap --lsl-out --out REC.h5``, and this one, reading ``SenSnake-forces`` as another program on the
network would. Then, from the recording and what the sender and the reader saw:

1. **Samples kept** (target ≥ 97 %): the sender's samples captured while the recording ran (its start to its last
   ``/daq`` frame) that ``/mocap`` holds. **Stamped at capture** (target: p99 − p1 ≤ 3 ms): each stored sample's
   ``time_s`` minus its true capture time on the recording's clock. The true capture time is known without trusting
   any time stamp: the sender publishes on a fixed schedule (sample i captured at ``start + i / 480`` on its LSL
   clock, pushed with that explicit stamp in 25 ms chunks, as a camera system's network sends them), and the body
   slides 0.42 mm between samples, so a stored sample's first marker says which i it is. The sender writes its
   start and rate to a file when it stops; LSL's clock is brought to the recording's through the wall clock (its
   ``started`` attribute, to the millisecond: the median offset printed is good to about that, the spread exactly).
2. **Every board frame on ``SenSnake-forces``** while the reader is connected (target: none missing): each sample
   the reader received matched to its ``/daq`` row by its values (conductance in µS, bit for bit), the rows from
   the first matched to the recording's last counted. **Stamped with ``/daq``'s spacing** (target: p99 ≤ 3 ms):
   the received time stamps minus their rows' ``time_s``, a constant removed (the median).

Prints each number against its target (OK / MISSED) and the machine's load average at the start and the end.
Timing is the point: run it plainly, not under ``nice``. LSL stays on this machine: unless ``LSLAPICFG`` is set, a
loopback-only configuration is written and set for this process and the two it starts.

    python -m benchmarks.bench_mocap_lsl [--quick] [--seconds N]

Default 60 s recorded; ``--quick`` 10 s. ``run(quick)`` is ``sensnake bench``'s entry.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STREAM = "BenchMocap"
RATE_HZ = 480.0
KEPT_TARGET = 0.97
SPREAD_TARGET_S = 0.003
FORCES_TARGET_S = 0.003
POLL_S = 0.005  # the forces' reader takes what has arrived this often
RESOLVE_TIMEOUT_S = 60.0  # the recorder's start-up (Python, numpy, h5py, the simulated lab) on a busy machine


# -- pure statistics (tests/benchmarks/test_bench_mocap_lsl.py) -------------------------------------------------
def capture_index(first_marker_x_m: np.ndarray, x0_m: float, speed_m_s: float, rate_hz: float) -> np.ndarray:
    """Which sample of the sender's schedule each stored sample is, from its first marker's x (m): the body slides
    ``speed_m_s`` from ``x0_m`` at sample 0."""
    return np.rint((np.asarray(first_marker_x_m, dtype=float) - x0_m) * rate_hz / speed_m_s).astype(np.int64)


def spread_s(values: np.ndarray) -> float:
    """p99 − p1 of ``values``."""
    low, high = np.percentile(np.asarray(values, dtype=float), [1.0, 99.0])
    return float(high - low)


def match_rows(rows: np.ndarray, received: np.ndarray) -> np.ndarray:
    """The row of ``rows`` (N, C) equal bit for bit to each of ``received`` (M, C), -1 where none; a value shared
    by several rows goes to the first after the previous match (rows are in time order, so are the received)."""
    where: dict[bytes, list[int]] = {}
    for i, row in enumerate(np.ascontiguousarray(rows, dtype=np.float64)):
        where.setdefault(row.tobytes(), []).append(i)
    matched = np.full(len(received), -1, dtype=np.int64)
    previous = -1
    for k, sample in enumerate(np.ascontiguousarray(received, dtype=np.float64)):
        candidates = where.get(sample.tobytes(), [])
        later = [i for i in candidates if i > previous]
        if later:
            matched[k] = previous = later[0]
    return matched


@dataclass(frozen=True)
class Verdict:
    what: str
    value: str
    target: str
    ok: bool

    def line(self) -> str:
        return f"  {self.what}: {self.value} (target {self.target}) {'OK' if self.ok else 'MISSED'}"


# -- the sender's process ---------------------------------------------------------------------------------------
def send(name: str, rate_hz: float, info: Path) -> None:
    """Publish until stdin closes, then write the schedule (start on the LSL clock, rate, speed, the first
    marker's x at the start, the wall clock minus the LSL clock) to ``info``."""
    import pylsl

    from tests.mocap_streams import MocapSender

    with MocapSender(name, rate_hz=rate_hz, gap=None) as sender:
        sys.stdin.read()  # the benchmark closes it
    before = pylsl.local_clock()
    wall = time.time()
    after = pylsl.local_clock()
    info.write_text(json.dumps({
        "start_lsl": sender.start_lsl, "rate_hz": rate_hz, "speed_m_s": sender.speed_m_s, "sent": sender.sent,
        "x0_m": float(sender.markers_mm(sender.start_lsl)[0]) / 1000.0,
        "wall_minus_lsl": wall - 0.5 * (before + after)}), encoding="utf-8")


# -- the reader of SenSnake-forces ------------------------------------------------------------------------------
class ForcesReader(threading.Thread):
    """``SenSnake-forces`` read until :attr:`done` is set and nothing more comes."""

    def __init__(self) -> None:
        super().__init__(name="bench-forces-reader", daemon=True)
        self.done = threading.Event()
        self.values: list[np.ndarray] = []
        self.stamps: list[np.ndarray] = []
        self.error = ""

    def run(self) -> None:
        import pylsl

        found = pylsl.resolve_byprop("name", "SenSnake-forces", 1, RESOLVE_TIMEOUT_S)
        if not found:
            self.error = f"SenSnake-forces did not answer within {RESOLVE_TIMEOUT_S:g} s"
            return
        inlet = pylsl.StreamInlet(found[0], max_buflen=600, recover=False)
        inlet.open_stream(RESOLVE_TIMEOUT_S)
        try:
            while True:
                # What has arrived, without waiting: a pull that waits gathers samples until its timeout, and when
                # the stream is withdrawn meanwhile (the recording's end) liblsl raises and they are lost with it.
                try:
                    values, stamps = inlet.pull_chunk(timeout=0.0, as_numpy=True)
                except pylsl.util.LostError:  # the recording ended and withdrew the stream
                    return
                if len(stamps):
                    self.values.append(np.asarray(values, dtype=np.float64))
                    self.stamps.append(np.asarray(stamps, dtype=np.float64))
                elif self.done.wait(POLL_S):
                    return
        finally:
            inlet.close_stream()


# -- the run ----------------------------------------------------------------------------------------------------
def measure(seconds: float, folder: Path) -> list[Verdict]:
    out = folder / "rec.h5"
    info = folder / "sender.json"
    sender = subprocess.Popen([sys.executable, "-m", "benchmarks.bench_mocap_lsl", "--send", str(info)],
                              cwd=ROOT, stdin=subprocess.PIPE)
    reader = ForcesReader()
    try:
        reader.start()
        done = subprocess.run([sys.executable, "-m", "app", "record", "--daq", "sim", "--seconds", str(seconds),
                               "--mocap", f"lsl:{STREAM}", "--lsl-out", "--out", str(out)],
                              cwd=ROOT, capture_output=True, text=True, timeout=seconds + 300)
    finally:
        assert sender.stdin is not None
        sender.stdin.close()
        sender.wait(timeout=60)
        reader.done.set()
        reader.join(timeout=60)
    print(done.stdout.strip())
    if done.returncode != 0:
        raise SystemExit(f"sensnake record exited {done.returncode}: {done.stderr[-2000:]}")
    schedule = json.loads(info.read_text(encoding="utf-8"))
    with h5py.File(out, "r") as f:
        started = _wall_s(str(f.attrs["started"]))
        daq_time = f["daq/time_s"][:]
        conductance_us = f["daq/conductance_S"][:] * 1e6
        mocap_time = f["mocap/time_s"][:]
        first_x = f["mocap/markers_m"][:, 0, 0]
    return [*_mocap_verdicts(schedule, started, daq_time, mocap_time, first_x),
            *_forces_verdicts(reader, daq_time, conductance_us)]


def _wall_s(iso: str) -> float:
    from datetime import datetime

    return datetime.fromisoformat(iso).timestamp()


def _mocap_verdicts(schedule: dict, started_wall_s: float, daq_time: np.ndarray, mocap_time: np.ndarray,
                    first_x: np.ndarray) -> list[Verdict]:
    rate = float(schedule["rate_hz"])
    index = capture_index(first_x, schedule["x0_m"], schedule["speed_m_s"], rate)
    # sample i's capture on the recording's clock: its LSL time, through the wall clock, minus the recording's start
    lsl_to_recording = schedule["wall_minus_lsl"] - started_wall_s
    capture = schedule["start_lsl"] + index / rate + lsl_to_recording
    end = float(daq_time[-1])
    first_i = int(np.ceil((0.0 - lsl_to_recording - schedule["start_lsl"]) * rate))
    last_i = int(np.floor((end - lsl_to_recording - schedule["start_lsl"]) * rate))
    due = last_i - first_i + 1
    inside = np.unique(index[(index >= first_i) & (index <= last_i)])
    offset = mocap_time - capture
    absent = np.setdiff1d(np.arange(first_i, last_i + 1), inside)
    where = (f"{int(np.sum(absent < inside[0]))} before the first stored, {int(np.sum(absent > inside[-1]))} after "
             f"the last, {int(np.sum((absent > inside[0]) & (absent < inside[-1])))} between") if len(inside) else ""
    repeated = len(index) - len(np.unique(index))
    print(f"motion capture: {len(mocap_time)} samples stored of {schedule['sent']} sent at {rate:g} Hz; "
          f"{len(inside)} of the {due} captured between the recording's start and its last frame ({end:.1f} s; missing: {where}); "
          f"{repeated} stored twice; stored time - capture time: median {1000 * np.median(offset):+.2f} ms "
          f"(the wall clock's millisecond), p1 {1000 * np.percentile(offset, 1):+.3f}, "
          f"p99 {1000 * np.percentile(offset, 99):+.3f}, max |.| {1000 * np.abs(offset - np.median(offset)).max():.3f}"
          " ms about the median")
    kept = len(inside) / max(due, 1)
    spread = spread_s(offset)
    return [Verdict("MoCap samples kept", f"{100 * kept:.2f} % ({len(inside)} of {due})",
                    f">= {100 * KEPT_TARGET:.0f} %", kept >= KEPT_TARGET and repeated == 0),
            Verdict("MoCap stored time - capture time, p99 - p1", f"{1000 * spread:.3f} ms",
                    f"<= {1000 * SPREAD_TARGET_S:g} ms", spread <= SPREAD_TARGET_S)]


def _forces_verdicts(reader: ForcesReader, daq_time: np.ndarray, conductance_us: np.ndarray) -> list[Verdict]:
    if reader.error or not reader.stamps:
        why = reader.error or "no sample received"
        return [Verdict("SenSnake-forces: board frames carried", why, "every one", False)]
    values, stamps = np.concatenate(reader.values), np.concatenate(reader.stamps)
    rows = match_rows(conductance_us, values)
    matched = rows >= 0
    first = int(rows[matched][0]) if matched.any() else len(daq_time)
    span = len(daq_time) - first  # the recording's frames from the first one received to its last
    carried = len(np.unique(rows[matched]))
    absent = np.setdiff1d(np.arange(first, len(daq_time)), rows[matched])
    offset = stamps[matched] - daq_time[rows[matched]]
    deviation = np.abs(offset - np.median(offset)) if len(offset) else np.array([np.inf])
    spacing = np.abs(np.diff(stamps[matched]) - np.diff(daq_time[rows[matched]]))
    print(f"SenSnake-forces: {len(stamps)} samples received, {int(matched.sum())} matched to /daq rows "
          f"({len(stamps) - int(matched.sum())} unmatched), from row {first} of {len(daq_time)} "
          f"({daq_time[min(first, len(daq_time) - 1)]:.2f} s): {carried} of the {span} frames carried"
          f"{f' (not: rows {absent[:10].tolist()})' if len(absent) else ''}; "
          f"stamps minus /daq time_s: p99 {1000 * np.percentile(deviation, 99):.4f} ms, "
          f"max {1000 * deviation.max():.4f} ms about the median; spacing differences p99 "
          f"{1000 * (np.percentile(spacing, 99) if len(spacing) else np.inf):.4f} ms")
    p99 = float(np.percentile(deviation, 99))
    return [Verdict("SenSnake-forces: board frames carried while connected", f"{carried} of {span}",
                    "every one", carried == span and span > 0),
            Verdict("SenSnake-forces stamps - /daq time_s (constant removed), p99", f"{1000 * p99:.4f} ms",
                    f"<= {1000 * FORCES_TARGET_S:g} ms", p99 <= FORCES_TARGET_S)]


def run(quick: bool = False, seconds: float | None = None) -> list[Verdict]:
    """``sensnake bench``'s entry: record ``seconds`` (60; 10 with ``quick``) and print the verdicts."""
    from app.core.lsl_link import keep_lsl_on_this_machine

    seconds = seconds if seconds is not None else (10.0 if quick else 60.0)
    keep_lsl_on_this_machine("bench-mocap-lsl-")  # before pylsl is first used here; the children inherit it
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-mocap-lsl-") as tmp:
        verdicts = measure(seconds, Path(tmp))
    load_after = os.getloadavg()
    print(f"{seconds:g} s recorded, MoCap at {RATE_HZ:g} Hz; load average (1, 5, 15 min) at the start "
          f"{', '.join(f'{v:.2f}' for v in load_before)}, at the end {', '.join(f'{v:.2f}' for v in load_after)} "
          f"on {os.cpu_count()} CPUs")
    for verdict in verdicts:
        print(verdict.line())
    return verdicts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="record 10 s")
    parser.add_argument("--seconds", type=float, default=None, help="seconds recorded (default 60)")
    parser.add_argument("--send", metavar="INFO", type=Path, help=argparse.SUPPRESS)  # the sender's process
    args = parser.parse_args()
    if args.send is not None:
        send(STREAM, RATE_HZ, args.send)
        return
    verdicts = run(quick=args.quick, seconds=args.seconds)
    sys.exit(0 if all(v.ok for v in verdicts) else 1)


if __name__ == "__main__":
    main()
