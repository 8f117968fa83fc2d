"""A bounded, multi-resolution time-series history for live plots: pure numpy (no Qt), preallocated rings.

Level 0 holds every sample of the last ``capacity`` samples. Each coarser level ``k`` holds the min and max of buckets
of ``factor**k`` samples, so the whole session stays browsable at a resolution that coarsens with age while memory
stays fixed. A query asks for a time range and a point budget and is answered from the finest level that covers the
range within that budget, then peak-decimated, so drawing cost depends on the plot's width, not on how long the
session has run.

Thread use: one writer and its readers on the same thread (the GUI thread in the Forces tab); the memory is
committed by a thread of its own (:func:`commit_memory`), which never touches the data.
"""

from __future__ import annotations

import ctypes
import mmap
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MADV_POPULATE_WRITE = 23  # Linux ≥ 5.14: fault pages in as if written, without writing them
# One madvise call over a 96 MB history kept the GUI thread waiting 80-400 ms at a time while the Forces tab was built,
# off the CPU and not for the interpreter lock (its constructor: 173-435 ms of wall for 35-42 ms of CPU; 33-40 ms of
# wall with no commit; a 2-core VM with transparent huge pages). Most likely the kernel's memory-map lock, which the
# call holds throughout and which the GUI thread's allocations (numpy arrays, Qt's pixmaps) need. Committed a huge
# page a call with a pause between, one call takes ≤ 1 ms alone (≤ 5 ms seen in the app at load 3-5).
# A 2 MB call took up to 16-23 ms in the app when the kernel was short of free huge pages (other programs' memory), and
# the GUI thread's allocations queued behind each such call: after a call the thread rests four times as long as the
# call took (the lock is held at most a fifth of the time), at least COMMIT_PAUSE_S, and no more than
# COMMIT_REST_BUDGET_S in all: a commit lasts at most ~0.6 s longer than its calls (every LabContext commits the
# board's history, and a test fails on a thread still running 3 s after it).
COMMIT_CHUNK_BYTES = 2 * 1024 * 1024
COMMIT_PAUSE_S = 0.001
COMMIT_REST_PER_BUSY = 4.0
COMMIT_REST_BUDGET_S = 0.5


def _populate_writable(arrays: Sequence[np.ndarray], chunk_bytes: int | None = None, pause_s: float = 0.0,
                       rest_per_busy: float = 0.0, rest_budget_s: float = 0.0) -> bool:
    """Ask the kernel to commit the arrays' pages (MADV_POPULATE_WRITE), ``chunk_bytes`` per call (all of an array in
    one call when None) with a rest between calls of ``rest_per_busy`` times the call's own time (while the rests add
    up to less than ``rest_budget_s``), at least ``pause_s``; False where it cannot (not Linux, an older kernel).
    ctypes lets go of the GIL meanwhile; the data are not touched, so another thread may write them."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        madvise = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):
        return False
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    page = mmap.PAGESIZE
    for array in arrays:
        start = array.ctypes.data & ~(page - 1)
        end = array.ctypes.data + array.nbytes
        step = end - start if chunk_bytes is None else max(page, chunk_bytes - chunk_bytes % page)
        for offset in range(start, end, step):
            began = time.perf_counter()
            if madvise(offset, min(step, end - offset), MADV_POPULATE_WRITE) != 0:
                return False
            rest_s = pause_s
            if rest_budget_s > 0.0:
                rest_s = max(pause_s, min(rest_budget_s, rest_per_busy * (time.perf_counter() - began)))
                rest_budget_s -= rest_s
            if rest_s > 0.0:
                time.sleep(rest_s)
    return True


def commit_memory(arrays: Sequence[np.ndarray]) -> threading.Thread | None:
    """Make the arrays' memory the process's now, not as they fill: np.empty maps pages lazily, and the process's
    memory then grew for hours as a history filled (170 → 312 MB seen in a long session, read as a leak). On Linux
    a daemon thread asks the kernel to commit them (returned), ``COMMIT_CHUNK_BYTES`` at a time, resting between
    calls (``COMMIT_REST_PER_BUSY``), so the GUI thread — which does not wait for it — is never held up for long by the
    kernel's lock (see ``COMMIT_CHUNK_BYTES``); elsewhere they are written once here."""
    probe = np.empty(1, dtype=np.uint8)
    if _populate_writable([probe]):
        thread = threading.Thread(target=_populate_writable,
                                  args=(list(arrays), COMMIT_CHUNK_BYTES, COMMIT_PAUSE_S, COMMIT_REST_PER_BUSY,
                                        COMMIT_REST_BUDGET_S),
                                  name="history-commit", daemon=True)
        thread.start()
        return thread
    for array in arrays:
        array.fill(0)
    return None


@dataclass(frozen=True)
class TraceWindow:
    """Samples for drawing: ``t_s`` (M,), ``low``/``high`` (M×C) per-bucket extremes (equal at level 0)."""

    t_s: np.ndarray
    low: np.ndarray
    high: np.ndarray
    level: int

    def peak_interleaved(self, channel: int) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) with each bucket's low then high, for a line that shows every peak."""
        if self.level == 0:
            return self.t_s, self.low[:, channel]
        x = np.repeat(self.t_s, 2)
        y = np.empty(x.size, dtype=self.low.dtype)
        y[0::2] = self.low[:, channel]
        y[1::2] = self.high[:, channel]
        return x, y


class _Ring:
    """A fixed-capacity ring of (t, low, high) rows, oldest overwritten first."""

    def __init__(self, capacity: int, n_channels: int, dtype, with_high: bool) -> None:
        self.capacity = capacity
        # np.empty: rows are read only once written (below ``count``). The memory is committed by the history
        # (commit_memory), so it is fixed from the start and stays flat (benchmarks/bench_soak.py). Not np.zeros:
        # numpy asks the kernel for huge pages on a large np.empty array (not on np.zeros' calloc), and writing
        # 96 MB of np.zeros in 4 kB page faults held the GUI thread ~0.5 s (a tab's first opening froze on it).
        self.t = np.empty(capacity)
        self.low = np.empty((capacity, n_channels), dtype=dtype)
        self.high = np.empty((capacity, n_channels), dtype=dtype) if with_high else self.low
        self.write = 0
        self.count = 0

    def push(self, t: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
        n = t.shape[0]
        if n > self.capacity:
            t, low, high = t[-self.capacity:], low[-self.capacity:], high[-self.capacity:]
            n = self.capacity
        first = min(n, self.capacity - self.write)
        self.t[self.write:self.write + first] = t[:first]
        self.low[self.write:self.write + first] = low[:first]
        if self.high is not self.low:
            self.high[self.write:self.write + first] = high[:first]
        rest = n - first
        if rest:
            self.t[:rest] = t[first:]
            self.low[:rest] = low[first:]
            if self.high is not self.low:
                self.high[:rest] = high[first:]
        self.write = (self.write + n) % self.capacity
        self.count = min(self.capacity, self.count + n)

    def _segments(self) -> list[slice]:
        if self.count < self.capacity:
            return [slice(0, self.count)]
        return [slice(self.write, self.capacity), slice(0, self.write)]

    def arrays(self) -> list[np.ndarray]:
        return [self.t, self.low] if self.high is self.low else [self.t, self.low, self.high]

    def oldest_first(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (t, low) of every row held, oldest first."""
        segments = self._segments()
        return np.concatenate([self.t[s] for s in segments]), np.concatenate([self.low[s] for s in segments])

    def oldest_t(self) -> float:
        if self.count == 0:
            return np.inf
        return float(self.t[0] if self.count < self.capacity else self.t[self.write])

    def newest_t(self) -> float:
        return float(self.t[(self.write - 1) % self.capacity]) if self.count else -np.inf

    def count_between(self, t0: float, t1: float) -> int:
        return sum(int(np.searchsorted(self.t[s], t1, "right") - np.searchsorted(self.t[s], t0, "left"))
                   for s in self._segments())

    def between(self, t0: float, t1: float, channels: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows with t0 ≤ t ≤ t1 (plus one either side so a line reaches the edges), oldest first; only
        ``channels`` (column indices) when given, so a plot showing 3 of 1024 channels copies only those."""
        parts_t, parts_lo, parts_hi = [], [], []
        for seg in self._segments():
            ts = self.t[seg]
            i0 = max(0, int(np.searchsorted(ts, t0, "left")) - 1)
            i1 = min(ts.size, int(np.searchsorted(ts, t1, "right")) + 1)
            if i1 > i0:
                sub = slice(seg.start + i0, seg.start + i1)
                parts_t.append(self.t[sub])
                if channels is None:
                    parts_lo.append(self.low[sub])
                    parts_hi.append(self.high[sub])
                else:
                    parts_lo.append(self.low[sub][:, channels])
                    parts_hi.append(parts_lo[-1] if self.high is self.low else self.high[sub][:, channels])
        if not parts_t:
            empty = self.low[:0] if channels is None else self.low[:0][:, channels]
            return self.t[:0], empty, empty
        if len(parts_t) == 1:
            return parts_t[0], parts_lo[0], parts_hi[0]
        return np.concatenate(parts_t), np.concatenate(parts_lo), np.concatenate(parts_hi)


class _Level:
    """A coarse level: accumulates ``factor`` rows of the finer level into one min/max bucket."""

    def __init__(self, capacity: int, n_channels: int, factor: int, dtype) -> None:
        self.ring = _Ring(capacity, n_channels, dtype, with_high=True)
        self.factor = factor
        self.pending_t: float | None = None
        self.pending_lo = np.full(n_channels, np.inf, dtype=dtype)
        self.pending_hi = np.full(n_channels, -np.inf, dtype=dtype)
        self.pending_n = 0

    def push(self, t: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fold finer rows in; returns the buckets completed by this call (for the next level)."""
        out_t, out_lo, out_hi = [], [], []
        i = 0
        n = t.shape[0]
        if self.pending_n:
            take = min(n, self.factor - self.pending_n)
            np.minimum(self.pending_lo, lo[:take].min(axis=0), out=self.pending_lo)
            np.maximum(self.pending_hi, hi[:take].max(axis=0), out=self.pending_hi)
            self.pending_n += take
            i = take
            if self.pending_n == self.factor:
                out_t.append(np.array([self.pending_t]))
                out_lo.append(self.pending_lo[None].copy())
                out_hi.append(self.pending_hi[None].copy())
                self.pending_n = 0
        whole = (n - i) // self.factor
        if whole:
            j = i + whole * self.factor
            shape = (whole, self.factor, lo.shape[1])
            out_t.append(t[i:j:self.factor])
            out_lo.append(lo[i:j].reshape(shape).min(axis=1))
            out_hi.append(hi[i:j].reshape(shape).max(axis=1))
            i = j
        if i < n:
            self.pending_t = float(t[i])
            self.pending_lo[:] = lo[i:].min(axis=0)
            self.pending_hi[:] = hi[i:].max(axis=0)
            self.pending_n = n - i
        if not out_t:
            return t[:0], lo[:0], hi[:0]
        bt, blo, bhi = (np.concatenate(out_t), np.concatenate(out_lo), np.concatenate(out_hi))
        self.ring.push(bt, blo, bhi)
        return bt, blo, bhi


class TraceHistory:
    """Bounded history of ``n_channels`` traces; memory is fixed at construction.

    ``capacity`` samples at full rate; ``levels`` coarser levels each holding ``capacity // 4`` buckets of
    ``factor**k`` samples. ``dtype`` float32 halves memory and is ample for display.
    """

    def __init__(self, n_channels: int, capacity: int, levels: int = 3, factor: int = 16,
                 dtype=np.float32) -> None:
        if n_channels < 1 or capacity < 16:
            raise ValueError(f"need n_channels ≥ 1 and capacity ≥ 16, got {n_channels}, {capacity}")
        self.n_channels = n_channels
        self.dtype = np.dtype(dtype)
        self._factor = factor
        self._allocate(capacity, levels)

    def _allocate(self, capacity: int, levels: int) -> None:
        self._level0 = _Ring(capacity, self.n_channels, self.dtype, with_high=False)
        self._levels = [_Level(max(16, capacity // 4), self.n_channels, self._factor, self.dtype)
                        for _ in range(levels)]
        self.total_samples = 0
        rings = [self._level0] + [level.ring for level in self._levels]
        commit_memory([array for ring in rings for array in ring.arrays()])

    @classmethod
    def for_budget(cls, n_channels: int, budget_bytes: int, levels: int = 3, factor: int = 16) -> TraceHistory:
        """A float32 history whose arrays take about ``budget_bytes`` in all."""
        per_sample = n_channels * 4 + 8
        # level 0 stores one row per sample; each coarse level a quarter as many rows of twice the width.
        capacity = int(budget_bytes / (per_sample * (1 + levels * 2 / 4)))
        return cls(n_channels, max(16, capacity), levels=levels, factor=factor)

    @property
    def nbytes(self) -> int:
        rings = [self._level0] + [lv.ring for lv in self._levels]
        return sum(r.t.nbytes + r.low.nbytes + (r.high.nbytes if r.high is not r.low else 0) for r in rings)

    @property
    def capacity(self) -> int:
        return self._level0.capacity

    def clear(self) -> None:
        self._allocate(self._level0.capacity, len(self._levels))

    def append(self, t_s: np.ndarray, values: np.ndarray) -> None:
        """Append samples: ``t_s`` (N,) non-decreasing seconds, ``values`` (N×C)."""
        values = np.asarray(values, dtype=self.dtype)
        t_s = np.asarray(t_s, dtype=float)
        if values.ndim != 2 or values.shape != (t_s.shape[0], self.n_channels):
            raise ValueError(f"expected t (N,) and values (N×{self.n_channels}), got {t_s.shape}, {values.shape}")
        if t_s.size == 0:
            return
        self._level0.push(t_s, values, values)
        self.total_samples += t_s.size
        t, lo, hi = t_s, values, values
        for level in self._levels:
            t, lo, hi = level.push(t, lo, hi)
            if t.size == 0:
                break

    def __len__(self) -> int:
        return self._level0.count

    def span(self) -> tuple[float, float]:
        """(oldest, newest) time still held at any resolution; (nan, nan) when empty."""
        if self._level0.count == 0:
            return (np.nan, np.nan)
        oldest = min([self._level0.oldest_t()] + [lv.ring.oldest_t() for lv in self._levels])
        return (oldest, self._level0.newest_t())

    def full_rate(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of every sample still held at full rate (level 0), oldest first: (t (N,), values (N×C)); what is
        older is held only as min/max buckets."""
        return self._level0.oldest_first()

    def latest(self) -> tuple[float, np.ndarray] | None:
        """(t, values (C,)) of the newest sample."""
        if self._level0.count == 0:
            return None
        i = (self._level0.write - 1) % self._level0.capacity
        return float(self._level0.t[i]), self._level0.low[i]

    def value_at(self, t_s: float) -> tuple[float, np.ndarray] | None:
        """The sample nearest ``t_s`` at the finest resolution that holds it: (t, values (C,))."""
        rings = [self._level0] + [lv.ring for lv in self._levels]
        for ring in rings:
            if ring.count and ring.oldest_t() <= t_s:
                t, lo, hi = ring.between(t_s, t_s)
                if t.size == 0:
                    continue
                i = int(np.argmin(np.abs(t - t_s)))
                value = lo[i] if ring is self._level0 else (lo[i] + hi[i]) / 2
                return float(t[i]), value
        return None

    def _with_unfinished_buckets(self, level: int, t, lo, hi, channels=None):
        """Append what finer levels hold but level ``level`` has not bucketed yet, so a live edge never lags."""
        pending = [lv for lv in self._levels[:level] if lv.pending_n]
        newest = self.latest()
        if newest is None:
            return t, lo, hi
        cols = slice(None) if channels is None else channels
        rows_t, rows_lo, rows_hi = [t], [lo], [hi]
        if pending:
            rows_t.append(np.array([min(lv.pending_t for lv in pending if lv.pending_t is not None)]))
            rows_lo.append(np.min([lv.pending_lo[cols] for lv in pending], axis=0)[None])
            rows_hi.append(np.max([lv.pending_hi[cols] for lv in pending], axis=0)[None])
        rows_t.append(np.array([newest[0]]))
        rows_lo.append(newest[1][cols][None])
        rows_hi.append(newest[1][cols][None])
        return np.concatenate(rows_t), np.concatenate(rows_lo), np.concatenate(rows_hi)

    def window(self, t0_s: float, t1_s: float, max_points: int,
               channels: np.ndarray | None = None) -> TraceWindow:
        """Samples in [t0, t1] for a plot ``max_points`` buckets wide (peak-decimated when denser); columns are
        ``channels`` (indices into the history's channels) when given, else all."""
        max_points = max(2, int(max_points))
        candidates = [(0, self._level0)] + [(k + 1, lv.ring) for k, lv in enumerate(self._levels)]
        chosen = candidates[-1]
        for k, ring in candidates:
            if ring.count == 0:
                continue
            covers = ring.oldest_t() <= t0_s or k == len(candidates) - 1 or not any(
                r.count and r.oldest_t() < ring.oldest_t() for _, r in candidates[k + 1:])
            if covers and ring.count_between(t0_s, t1_s) <= 4 * max_points:
                chosen = (k, ring)
                break
        level, ring = chosen
        t, lo, hi = ring.between(t0_s, t1_s, channels)
        if level > 0 and t1_s >= ring.newest_t():
            t, lo, hi = self._with_unfinished_buckets(level, t, lo, hi, channels)
        if level == 0 and t.size <= 2 * max_points:
            return TraceWindow(t, lo, lo, 0)
        if t.size > max_points:
            step = int(np.ceil(t.size / max_points))
            whole = t.size // step * step
            shape = (whole // step, step, lo.shape[1])
            t_parts = [t[:whole:step]]
            lo_parts = [lo[:whole].reshape(shape).min(axis=1)]
            hi_parts = [hi[:whole].reshape(shape).max(axis=1)]
            if whole < t.size:
                t_parts.append(t[whole:whole + 1])
                lo_parts.append(lo[whole:].min(axis=0, keepdims=True))
                hi_parts.append(hi[whole:].max(axis=0, keepdims=True))
            # The newest row again as its own point: a live plot's right edge must not lag by a bucket.
            t_parts.append(t[-1:])
            lo_parts.append(lo[-1:])
            hi_parts.append(hi[-1:])
            t, lo, hi = np.concatenate(t_parts), np.concatenate(lo_parts), np.concatenate(hi_parts)
            level = max(level, 1)
        return TraceWindow(t, lo, hi, level)


def append_with_gaps(history: TraceHistory, t_s: np.ndarray, values: np.ndarray,
                     gap_before: np.ndarray | None) -> None:
    """Append samples, with a NaN row just before every sample flagged in ``gap_before`` (N,) so the plotted line
    breaks where data is missing (a pulled cable, dropped frames) instead of bridging the hole."""
    if gap_before is None or not np.any(gap_before):
        history.append(t_s, values)
        return
    cuts = np.flatnonzero(gap_before)
    start = 0
    for cut in cuts.tolist():
        if cut > start:
            history.append(t_s[start:cut], values[start:cut])
        gap_t = t_s[cut] if cut == 0 else (t_s[cut - 1] + t_s[cut]) / 2
        history.append(np.array([gap_t]), np.full((1, values.shape[1]), np.nan))
        start = cut
    history.append(t_s[start:], values[start:])
