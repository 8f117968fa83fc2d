"""The lab's bad days, tried against independent emulators: prints every case and "cases tried / handled cleanly".

    python scripts/fault_matrix.py [--only WORD] [--list]

Each case runs ``sensnake`` as a user would (a separate process) against the independent board emulator
(``tests/emulators/board_emulator.py``) or servo chain emulator (``tests/emulators/xm430_emulator.py``), both on
pseudo-terminals and written from SPEC §4 / the XM430 e-manual, and judges the outcome by what a user can see:

- "handled cleanly" = the expected exit code; no Python traceback; a failure is one line on stderr naming the cause;
  an existing output file is never clobbered by a failed command; every recorded value is exactly what the board
  sent (no corrupt frame kept, no good frame lost between the first and the last one recorded); a file left by a
  crash or a signal opens in plain ``h5py.File(path, "r")`` in another process.

Run from the repository root (the emulators are started as ``python -m tests.emulators.…``). Takes about two minutes
on an idle machine (the recordings run in real time). Linux only (pseudo-terminals).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.emulators.board_emulator import EmulatedBoard, expected_counts  # noqa: E402

RATE_HZ = 200.0
N_CHANNELS = 36


@dataclass
class Outcome:
    ok: bool
    note: str


@dataclass
class Run:
    code: int
    out: str
    err: str

    @property
    def traceback(self) -> bool:
        return "Traceback" in self.err or "Traceback" in self.out

    def error_lines(self) -> list[str]:
        return [line for line in self.err.replace("\r", "\n").splitlines() if line.startswith("sensnake ")
                and ": error:" in line]


def sensnake(*args: str, timeout_s: float = 60.0) -> Run:
    done = subprocess.run([sys.executable, "-m", "app", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout_s, env={**os.environ, "PYTHONPATH": str(REPO)})
    return Run(done.returncode, done.stdout, done.stderr)


def plain_h5py(path: Path) -> tuple[bool, str]:
    """Open with plain h5py in a fresh process; (ok, rows or the error)."""
    done = subprocess.run([sys.executable, "-c", "import sys, h5py\nwith h5py.File(sys.argv[1], 'r') as f:\n"
                           "    print(f['daq/seq'].shape[0])", str(path)], capture_output=True, text=True,
                          timeout=60)
    if done.returncode == 0:
        return True, done.stdout.strip()
    lines = done.stderr.strip().splitlines()
    return False, lines[-1] if lines else f"exit {done.returncode}"


def check_exact(path: Path, log: dict) -> tuple[bool, str]:
    """Every recorded frame is a good one the emulator sent, with its exact counts, and none between the first and
    the last recorded one of each clock segment is missing."""
    import h5py
    import numpy as np

    with h5py.File(path, "r") as f:
        n = min(f["daq/seq"].shape[0], f["daq/counts"].shape[0])
        seq = f["daq/seq"][:n].astype(np.int64)
        counts = f["daq/counts"][:n]
        segments = f["daq/clock_segment"][:n] if "clock_segment" in f["daq"] else np.zeros(n, dtype=int)
    if n == 0:
        return False, "no frames"
    for segment in sorted(set(segments.tolist())):
        mine = segments == segment
        s = seq[mine]
        sent = np.array(log["segments"][segment]["sent"], dtype=np.int64)
        window = sent[(sent >= s[0]) & (sent <= s[-1])]
        if s.size != window.size or np.any(s != window):
            return False, f"segment {segment}: {s.size} frames recorded, {window.size} good ones sent in that span"
        expected = np.array([expected_counts(int(k), N_CHANNELS, segment) for k in s], dtype=np.uint16)
        if not np.array_equal(counts[mine], expected):
            return False, f"segment {segment}: counts differ from what was sent"
    return True, f"{n} frames exact"


def clean_failure(run: Run, code: int = 1, *words: str) -> tuple[bool, str]:
    lines = run.error_lines()
    if run.traceback:
        return False, "traceback"
    if run.code != code:
        return False, f"exit {run.code}, expected {code}: {run.err.strip()[-200:]}"
    if len(lines) != 1:
        return False, f"{len(lines)} error lines"
    missing = [w for w in words if w not in lines[0]]
    if missing:
        return False, f"message lacks {missing}: {lines[0]}"
    return True, lines[0][:110]


# -- board cases ---------------------------------------------------------------------------------------------------
def record_case(seconds: float = 1.5, expect_code: int = 0, words: tuple[str, ...] = (),
                actions: tuple[tuple[str, str], ...] = (), **faults: object) -> Callable[[Path], Outcome]:
    """Record from the emulator with ``faults``; ``actions`` are (trigger, emulator command) pairs run in order:
    the trigger is a number of recorded frames or a word on the recorder's stderr (``disconnected``)."""
    def case(folder: Path) -> Outcome:
        config = folder / "lab.toml"
        config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
        out = folder / "rec.h5"
        with EmulatedBoard(folder, rate_hz=RATE_HZ, **faults) as emu:
            child = subprocess.Popen([sys.executable, "-m", "app", "record", "--daq", emu.path, "--seconds",
                                      str(seconds), "--out", str(out), "--config", str(config)], cwd=REPO,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            seen = _drive(child, emu, list(actions))
            stdout, err = child.communicate(timeout=60)
            log = emu.stop()
        run = Run(child.returncode, stdout, seen + err)
        if expect_code:
            ok, note = clean_failure(run, expect_code, *words)
            if not ok:
                return Outcome(False, note)
        elif run.code != 0 or run.traceback:
            return Outcome(False, f"exit {run.code}: {run.err.strip()[-200:]}")
        if not out.exists():
            return Outcome(expect_code != 0, "no file (nothing recorded)")
        opened, rows = plain_h5py(out)
        if not opened:
            return Outcome(False, f"plain h5py cannot open the file: {rows}")
        exact, note = check_exact(out, log)
        return Outcome(exact, note + (f"; {run.error_lines()[0][:90]}" if expect_code else ""))
    return case


def _drive(child: subprocess.Popen, emu: EmulatedBoard, actions: list[tuple[str, str]]) -> str:
    """Read the recorder's stderr until every action ran (or it exited); returns what was read."""
    assert child.stderr is not None
    seen = ""
    while actions:
        chunk = child.stderr.read(32)
        if not chunk:
            break
        seen += chunk
        trigger, command = actions[0]
        if trigger.isdigit():
            counts = [int(w) for w, nxt in zip(seen.split(), seen.split()[1:]) if nxt == "frames" and w.isdigit()]
            fired = bool(counts) and counts[-1] >= int(trigger)
        else:
            fired = trigger in seen
        if fired:
            emu.command(command)
            actions.pop(0)
    return seen


def record_over_existing_silent(folder: Path) -> Outcome:
    config = folder / "lab.toml"
    config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
    out = folder / "precious.h5"
    out.write_bytes(b"an earlier recording" * 1000)
    before = out.read_bytes()
    with EmulatedBoard(folder, rate_hz=RATE_HZ, silent=True) as emu:
        run = sensnake("record", "--daq", emu.path, "--seconds", "5", "--out", str(out), "--config", str(config))
    ok, note = clean_failure(run, 1, "no frames")
    if ok and out.read_bytes() != before:
        return Outcome(False, "the existing --out was changed")
    return Outcome(ok, note)


def record_signal(signum: int, expect_code: int | None) -> Callable[[Path], Outcome]:
    def case(folder: Path) -> Outcome:
        config = folder / "lab.toml"
        config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
        out = folder / "signalled.h5"
        with EmulatedBoard(folder, rate_hz=RATE_HZ) as emu:
            child = subprocess.Popen([sys.executable, "-m", "app", "record", "--daq", emu.path, "--seconds", "60",
                                      "--out", str(out), "--config", str(config)], cwd=REPO,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            assert child.stderr is not None
            seen = ""
            while "frames" not in seen or int(seen.replace("\r", "\n").split("frames")[-2].split()[-1]) < 300:
                chunk = child.stderr.read(64)
                if not chunk:
                    break
                seen += chunk
            child.send_signal(signum)
            _, err = child.communicate(timeout=30)
            log = emu.stop()
        err = seen + err
        if expect_code is not None and child.returncode != expect_code:
            return Outcome(False, f"exit {child.returncode}, expected {expect_code}")
        if "Traceback" in err:
            return Outcome(False, "traceback")
        opened, rows = plain_h5py(out)
        if not opened:
            return Outcome(False, f"plain h5py cannot open it: {rows}")
        exact, note = check_exact(out, log)
        return Outcome(exact, f"plain h5py opens it ({rows} rows); {note}")
    return case


def one_line(args: Callable[[Path], list[str]], code: int = 1, *words: str) -> Callable[[Path], Outcome]:
    def case(folder: Path) -> Outcome:
        return Outcome(*clean_failure(sensnake(*args(folder)), code, *words))
    return case


def good_recording(folder: Path) -> Path:
    config = folder / "lab.toml"
    config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
    out = folder / "good.h5"
    with EmulatedBoard(folder, rate_hz=RATE_HZ) as emu:
        run = sensnake("record", "--daq", emu.path, "--seconds", "2", "--out", str(out), "--config", str(config))
    if run.code != 0:
        raise RuntimeError(f"could not make a recording: {run.err}")
    return out


def truncated(fraction: float, min_recovered: float) -> Callable[[Path], Outcome]:
    def case(folder: Path) -> Outcome:
        good = good_recording(folder)
        data = good.read_bytes()
        cut = folder / "cut.h5"
        cut.write_bytes(data[: int(len(data) * fraction)])
        export = sensnake("export", str(cut), "--csv", str(folder / "cut.csv"))
        ok, note = clean_failure(export, 1, "cut.h5", "repair")
        if not ok:
            return Outcome(False, f"export: {note}")
        fixed = folder / "fixed.h5"
        repair = sensnake("repair", str(cut), "--out", str(fixed))
        if repair.code != 0 or repair.traceback:
            return Outcome(False, f"repair exit {repair.code}: {repair.err.strip()[-160:]}")
        opened, rows = plain_h5py(fixed)
        with_rows = int(rows) if opened else 0
        import h5py

        with h5py.File(good, "r") as f:
            total = f["daq/seq"].shape[0]
        share = with_rows / total
        return Outcome(opened and share >= min_recovered and "recovered" in repair.out,
                       f"recovered {with_rows}/{total} rows ({share:.1%}); {repair.out.strip()[:80]}")
    return case


def not_hdf5_export(folder: Path) -> Outcome:
    bad = folder / "notes.h5"
    bad.write_text("not a recording")
    return Outcome(*clean_failure(sensnake("export", str(bad), "--csv", str(folder / "x.csv")), 1, "notes.h5"))


def export_unwritable(folder: Path) -> Outcome:
    good = good_recording(folder)
    blocker = folder / "file"
    blocker.write_text("x")
    return Outcome(*clean_failure(sensnake("export", str(good), "--csv", str(blocker / "out.csv")), 1, "out.csv"))


CASES: dict[str, Callable[[Path], Outcome]] = {
    "board: clean stream": record_case(),
    "board: 5% garbage": record_case(garbage=0.05),
    "board: 5% CRC flips": record_case(crc_flip=0.05),
    "board: 2% dropped frames": record_case(drop=0.02),
    "board: 5% garbage + 5% CRC flips + 2% drops (issue 14)": record_case(seconds=3.0, garbage=0.05, crc_flip=0.05,
                                                                           drop=0.02, seed=14),
    "board: 30% garbage": record_case(garbage=0.3, seed=2),
    "board: 30% CRC flips (a storm: warn, keep going)": record_case(crc_flip=0.3, seed=3),
    "board: counts > 4095 with a valid CRC (10%)": record_case(over_range=0.1, seed=4),
    "board: 48 channels, config 36": record_case(expect_code=1, words=("48 channels", "36"), wrong_channels=48),
    "board: 12 channels, config 36": record_case(expect_code=1, words=("12 channels", "36"), wrong_channels=12),
    "board: re-plugged (new clock segment)": record_case(seconds=3.0, actions=(("150", "unplug"),
                                                                               ("disconnected", "replug"))),
    "board: cable pulled for good": record_case(seconds=2.5, expect_code=1, words=("missing",),
                                                actions=(("150", "unplug"),)),
    "board: 2^32 µs clock wrap": record_case(t_us_start=2**32 - 400_000),
    "board: silent, existing --out": record_over_existing_silent,
    "board: no such port": one_line(lambda d: ["record", "--daq", str(d / "ttyNOPE"), "--seconds", "1", "--out",
                                               str(d / "r.h5")], 1, "ttyNOPE"),
    "record: --seconds 0": one_line(lambda d: ["record", "--daq", "sim", "--seconds", "0", "--out",
                                               str(d / "r.h5")], 1, "--seconds"),
    "record: --out in a missing folder": one_line(lambda d: ["record", "--daq", "sim", "--seconds", "1", "--out",
                                                            str(d / "nope" / "r.h5")], 1, "r.h5"),
    "record: SIGTERM": record_signal(signal.SIGTERM, 128 + signal.SIGTERM),
    "record: SIGHUP": record_signal(signal.SIGHUP, 128 + signal.SIGHUP),
    "record: Ctrl-C": record_signal(signal.SIGINT, 130),
    "record: kill -9": record_signal(signal.SIGKILL, -signal.SIGKILL),
    "file: truncated at 99.9%": truncated(0.999, 0.95),
    "file: truncated at 90%": truncated(0.9, 0.5),
    "file: truncated at 50%": truncated(0.5, 0.1),
    "file: not HDF5": not_hdf5_export,
    "file: export to an unwritable path": export_unwritable,
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default="", help="run the cases whose name contains this word")
    parser.add_argument("--list", action="store_true")
    args = parser.parse_args(argv)
    cases = {name: case for name, case in CASES.items() if args.only.lower() in name.lower()}
    if args.list:
        print("\n".join(cases))  # noqa: T201 - a command-line script
        return 0
    handled = 0
    start = time.perf_counter()
    results = []
    for name, case in cases.items():
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="fault-") as folder:
            try:
                outcome = case(Path(folder))
            except Exception as exc:  # noqa: BLE001 - a case that breaks is a case not handled, reported in one line
                outcome = Outcome(False, f"case failed: {type(exc).__name__}: {exc}")
        handled += outcome.ok
        mark = "ok  " if outcome.ok else "FAIL"
        print(f"{mark} {name:<58} {time.perf_counter() - t0:5.1f} s  {outcome.note}", flush=True)  # noqa: T201
        results.append({"case": name, "ok": outcome.ok, "note": outcome.note})
    print(f"\ncases tried / handled cleanly: {len(cases)} / {handled}  ({time.perf_counter() - start:.0f} s; "  # noqa: T201
          "timings are wall time on a shared machine)")
    if os.environ.get("FAULT_MATRIX_JSON"):
        Path(os.environ["FAULT_MATRIX_JSON"]).write_text(json.dumps(results, indent=1))
    return 0 if handled == len(cases) else 1


if __name__ == "__main__":
    sys.exit(main())
