"""`sensnake estimate` end to end, as a user runs it: process start, CSV in, estimate, CSV out.

Data: 36 sensors × 370 s × 100 Hz (37 001 rows, ~31 MB), forces 1–4 N as slow sines with random phases, the
typical sensor (contact term on), 0.1 % conductance noise; one calibration file with both a linear and an SLS
model per sensor. Printed: wall time of each model (best of ``--repeats``), the sls/linear ratio (target
≤ 1.5×), throughput in sensor-samples/s including I/O, the RMS force error against the applied force; then the CSV
reader and writer alone, numpy's loadtxt/savetxt against the Arrow path `app.core.calfiles` uses (target: the CSV
path ≥ 2× faster than numpy's).

Run: ``python -m benchmarks.bench_estimate_io [--repeats 3] [--seconds 370]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from app.core import calfiles
from models.physics import DEFAULT_PHYSICS
from models.sls import TYPICAL_AREA_M2, TYPICAL_SLS, conductance_from_force

SENSORS = [f"S{i // 3 + 1:02d}{'LRB'[i % 3]}" for i in range(36)]


def _write_inputs(folder: Path, seconds: float) -> tuple[Path, Path, np.ndarray]:
    rng = np.random.default_rng(29)
    t = np.arange(int(seconds * 100) + 1) / 100.0
    force = 2.5 + 1.5 * np.sin(2 * np.pi * t[:, None] / 60.0 + rng.uniform(0, 2 * np.pi, len(SENSORS)))
    cond = np.asarray(conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS))
    cond = cond + rng.normal(0.0, 1e-3 * float(np.mean(cond)), cond.shape)
    slope, offset = np.polyfit(force.ravel(), cond.ravel(), 1)
    entry = {"area_m2": TYPICAL_AREA_M2, "linear": {"m_S_per_N": float(slope), "d_S": float(offset)},
             "sls": {"E0_Pa": float(TYPICAL_SLS.E0_Pa), "E1_Pa": float(TYPICAL_SLS.E1_Pa),
                     "mu1_Pa_s": float(TYPICAL_SLS.mu1_Pa_s)}}
    cal = folder / "cal.json"
    cal.write_text(json.dumps({"format": "sensnake-calibration", "version": 1, "physics": DEFAULT_PHYSICS.to_dict(),
                               "sensors": dict.fromkeys(SENSORS, entry)}), encoding="utf-8")
    data = folder / "in.csv"
    calfiles.write_series_csv(data, t, SENSORS, cond)
    return cal, data, force


def _estimate(cal: Path, data: Path, model: str, out: Path) -> float:
    out.unlink(missing_ok=True)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from app.cli import main; main()", "estimate", str(data), "--cal", str(cal), "--model", model,
                    "--out", str(out)], check=True, capture_output=True)
    return time.perf_counter() - start


def run(repeats: int = 3, seconds: float = 370.0) -> None:
    with tempfile.TemporaryDirectory(prefix="bench_estimate_io_") as tmp:
        folder = Path(tmp)
        cal, data, force = _write_inputs(folder, seconds)
        n_rows = force.shape[0]
        size_mb = data.stat().st_size / 1e6
        print(f"sensnake estimate, {len(SENSORS)} sensors × {n_rows} rows ({size_mb:.0f} MB CSV), best of {repeats}")
        print(f"{'model':<8} {'wall s':>7} {'M sensor-samples/s':>19} {'RMS err N':>10}")
        walls = {}
        for model in ("linear", "sls"):
            out = folder / f"out_{model}.csv"
            walls[model] = min(_estimate(cal, data, model, out) for _ in range(repeats))
            estimated = calfiles.read_series_csv(out, "force_N", allow_gaps=True)
            err = float(np.sqrt(np.nanmean((estimated.values - force) ** 2)))
            rate = len(SENSORS) * n_rows / walls[model] / 1e6
            print(f"{model:<8} {walls[model]:>7.2f} {rate:>19.2f} {err:>10.4f}")
        ratio = walls["sls"] / walls["linear"]
        print(f"sls / linear: {ratio:.2f}× (target ≤ 1.5×: {'met' if ratio <= 1.5 else 'NOT met'})")

        header = calfiles._read_header(data)  # noqa: SLF001 - the benchmark times the two private paths
        indices = list(range(len(header)))
        arrow = calfiles._arrow_csv  # noqa: SLF001
        read = {"numpy": lambda: calfiles._read_columns_numpy(data, header, indices, 1, {}),  # noqa: SLF001
                "arrow": lambda: calfiles._read_numbers_fast(data, header, indices)}  # noqa: SLF001
        table = calfiles._read_columns_numpy(data, header, indices, 1, {})  # noqa: SLF001
        times: dict[str, list[float]] = {}
        for name, reader in read.items():
            if name == "arrow" and arrow is None:
                continue
            times[name] = [min(_timed(reader) for _ in range(repeats))]
        out = folder / "w.csv"

        def write_numpy() -> None:
            np.savetxt(out, table, delimiter=",", fmt="%.17g", header=",".join(header), comments="")

        def write_arrow() -> None:
            calfiles.write_series_csv(out, table[:, 0], header[1:], table[:, 1:])

        times["numpy"].append(min(_timed(write_numpy) for _ in range(repeats)))
        if "arrow" in times:
            times["arrow"].append(min(_timed(write_arrow) for _ in range(repeats)))
        print(f"\nCSV alone ({size_mb:.0f} MB): {'path':<6} {'read s':>7} {'write s':>8} {'total s':>8}")
        for name, (r, w) in times.items():
            print(f"{'':<21}{name:<6} {r:>7.3f} {w:>8.3f} {r + w:>8.3f}")
        if "arrow" in times:
            gain = sum(times["numpy"]) / sum(times["arrow"])
            print(f"Arrow over numpy: {gain:.1f}× (target ≥ 2×: {'met' if gain >= 2 else 'NOT met'})")


def _timed(fn) -> float:  # type: ignore[no-untyped-def]
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=370.0, help="record length at 100 Hz")
    args = parser.parse_args(argv)
    if args.repeats < 1 or not args.seconds > 0:
        parser.error("--repeats must be ≥ 1 and --seconds > 0")
    run(args.repeats, args.seconds)


if __name__ == "__main__":
    main()
