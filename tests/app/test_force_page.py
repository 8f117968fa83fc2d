"""The shared force page between the app and the control loop's process: a reader never waits on the writer, never
raises, never sees half a publication and never goes back to an older one — also while the writer is descheduled
half-way through a write (SIGSTOP) and while the machine is busy."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from app.core.force_control import ForcePage
from models.force_feedback import FeedbackGains

N_CHANNELS = 1024  # the board scales to ~1024 channels: the largest page, the longest write

# A writer that publishes as fast as it can; every publication is self-consistent (each force equals the arrival
# time, the trusted flags alternate with its parity), so a torn read shows.
WRITER = """
import sys, numpy as np
from app.core.force_control import ForcePage
page = ForcePage(sys.argv[1])
n = page.n_channels
k = 0
sys.stdout.write("ready\\n"); sys.stdout.flush()
while True:
    k += 1
    page.publish(float(k), np.full(n, float(k)), np.full(n, k % 2 == 0))
"""

LOAD = "while True: pass"


def _start(code: str, *args: str, talks: bool = True) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE if talks else None,
                            text=True, env=env)


def _end(*processes: subprocess.Popen) -> None:
    for process in processes:
        process.kill()
        process.wait(timeout=10)
        if process.stdout is not None:
            process.stdout.close()


def _check_whole(arrival: float, forces: np.ndarray, trusted: np.ndarray) -> None:
    assert np.all(forces == arrival), "a read mixed two publications"
    assert np.all(trusted == (int(arrival) % 2 == 0)), "a read mixed two publications"


def test_a_page_publishes_and_reads_back_in_one_process(tmp_path: Path) -> None:
    page = ForcePage.create(36, folder=tmp_path)
    try:
        assert page.read()[0] == -math.inf and page.gains() == (0, None)
        for k in range(1, 11):  # more publications than the ring has slots
            page.publish(k * 0.1, np.full(36, float(k)), np.arange(36) % 2 == 0)
            arrival, forces, trusted = page.read()
            assert arrival == pytest.approx(k * 0.1) and np.all(forces == k) and trusted.sum() == 18
        assert page.publication == 10 and not page.being_written
        page.set_gains(FeedbackGains(target_n=6.0))
        page.set_gains(FeedbackGains(target_n=7.0))
        version, gains = page.gains()
        assert version == 2 and gains is not None and gains.target_n == 7.0
        with pytest.raises(ValueError, match="channels"):
            ForcePage(page.path, 12)
    finally:
        page.close()
    assert page.read()[0] == -math.inf  # closed: nothing, no error


def test_a_file_that_is_not_a_force_page_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "junk.page"
    path.write_bytes(os.urandom(256))
    with pytest.raises(ValueError, match="not a force page"):
        ForcePage(path)


@pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs SIGSTOP")
def test_a_writer_stopped_mid_write_never_stops_the_reader(tmp_path: Path) -> None:
    """The writer is stopped (SIGSTOP) at random moments until it has been caught half-way through a publication at
    least 20 times; while it is stopped the reader keeps reading. No read raises, waits, mixes two publications or
    goes back to an older one; a stop mid-write gives the publication before it."""
    page = ForcePage.create(N_CHANNELS, folder=tmp_path)
    reader = ForcePage(page.path)
    writer = _start(WRITER, str(page.path))
    rng = np.random.default_rng(7)
    try:
        assert writer.stdout is not None and writer.stdout.readline().strip() == "ready"
        mid_write = stops = reads = 0
        last = -math.inf
        deadline = time.monotonic() + 60.0
        while mid_write < 20 and time.monotonic() < deadline:
            # Deliberate: the writer runs for a random moment, so the stop lands anywhere in its loop
            time.sleep(float(rng.uniform(0.0, 0.002)))
            os.kill(writer.pid, signal.SIGSTOP)
            # wait until the kernel has really stopped it (state T), so what we read is a frozen page
            while _state(writer.pid) not in ("T", "t"):
                # Deliberate: a short poll of /proc until the kernel has stopped the writer
                time.sleep(0.0005)
            stops += 1
            caught = reader.being_written
            mid_write += caught
            for _ in range(10):
                arrival, forces, trusted = reader.read()
                reads += 1
                assert arrival >= last, "a read returned an older publication than the read before"
                if arrival > 0:
                    _check_whole(arrival, forces, trusted)
                last = arrival
            if caught:
                assert reader.being_written  # frozen mid-write, and the reads above still succeeded
            os.kill(writer.pid, signal.SIGCONT)
        assert mid_write >= 20, f"the writer was caught mid-write only {mid_write} times in {stops} stops"
        assert last > 0 and reads == 10 * stops
    finally:
        _end(writer)
        reader.close()
        page.close()


def _state(pid: int) -> str:
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0]


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc")
def test_reads_under_cpu_load_never_fail(tmp_path: Path) -> None:
    """Writer and reader at normal priority beside four busy processes on this machine's cores: 2 s of reads as fast
    as the reader can, every one whole and none older than the one before (the longer soak is
    benchmarks/bench_force_page_soak.py)."""
    page = ForcePage.create(N_CHANNELS, folder=tmp_path)
    reader = ForcePage(page.path)
    load = [_start(LOAD, talks=False) for _ in range(4)]
    writer = _start(WRITER, str(page.path))
    try:
        assert writer.stdout is not None and writer.stdout.readline().strip() == "ready"
        last, distinct, end = -math.inf, set(), time.monotonic() + 2.0
        while time.monotonic() < end:
            arrival, forces, trusted = reader.read()
            assert arrival >= last
            if arrival > 0:
                _check_whole(arrival, forces, trusted)
                distinct.add(arrival)
            last = arrival
        assert len(distinct) > 10  # the reader did follow the writer
    finally:
        _end(writer, *load)
        reader.close()
        page.close()
