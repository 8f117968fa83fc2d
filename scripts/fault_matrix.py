"""The lab's bad days, tried against independent emulators: prints every case and "cases tried / handled cleanly".

    python scripts/fault_matrix.py [--only WORD] [--list]

Each case runs ``sensnake`` as a user would (a separate process) against the independent board emulator
(``tests/emulators/board_emulator.py``) or servo chain emulator (``tests/emulators/xm430_emulator.py``), both on
pseudo-terminals and written from SPEC §4 / the XM430 e-manual, and judges the outcome by what a user can see:

- "handled cleanly" = the expected exit code; no Python traceback; a failure is one line on stderr naming the cause
  (the user's path, never HDF5's report — ``errno = …, o_flags = …`` —, a hidden work file or a codec's complaint);
  an existing output file is never clobbered by a failed command; output files get the user's umask, a replaced
  file keeps its mode; every recorded value is exactly what the board
  sent (no corrupt frame kept, no good frame lost between the first and the last one recorded); a file left by a
  crash or a signal opens in plain ``h5py.File(path, "r")`` in another process.

The cases cover every fault docs/RELIABILITY.md lists (board, recording, file, output-file and message faults; the servo chain's
reboots, limits and a killed bus) and every way a user could lose data (an output onto an input, two writers on one file, a file-size limit
mid-recording, a 2 GB sparse CSV, NUL bytes and endless lines, a symlink-loop ``--out``, a board repeating frames,
its clock stepping back, another protocol version, a stopped recorder, two servos on one ID, messages naming the
file, sensor and key). Run from the repository root (the emulators are started as
``python -m tests.emulators.…``). Takes about three minutes on an idle machine (the recordings run in real time).
Linux only (pseudo-terminals).
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
# Words that must never reach a user's error line: HDF5's report, a hidden work file, a codec's complaint.
INTERNALS = ("errno =", "[Errno", "o_flags", "flags =", "Unable to synchronously", ".partial", ".tmp", "codec can't",
             "Traceback")


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


def sensnake(*args: str, timeout_s: float = 60.0, umask: int | None = None) -> Run:
    done = subprocess.run([sys.executable, "-m", "app", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout_s, env={**os.environ, "PYTHONPATH": str(REPO)},
                          preexec_fn=None if umask is None else (lambda: os.umask(umask)))  # noqa: PLW1509
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
    leaked = [w for w in INTERNALS if w in lines[0]]
    if leaked:
        return False, f"internals {leaked} in: {lines[0][:120]}"
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


def kill_at_random_moments(trials: int) -> Callable[[Path], Outcome]:
    """``kill -9`` the recorder at random moments (not just after a flush): the file must open in plain h5py with
    exact values every time. The writer's flush (open, append, close) is the only window where it could not."""
    def case(folder: Path) -> Outcome:
        import random

        rng = random.Random(9)
        config = folder / "lab.toml"
        config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
        failures = []
        for trial in range(trials):
            out = folder / f"killed{trial}.h5"
            with EmulatedBoard(folder, rate_hz=RATE_HZ, seed=trial) as emu:
                child = subprocess.Popen([sys.executable, "-m", "app", "record", "--daq", emu.path, "--seconds",
                                          "60", "--out", str(out), "--config", str(config)], cwd=REPO,
                                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                _drive(child, emu, [("120", "noop")])
                deadline = time.monotonic() + 10.0  # the first flush put the file in place (a kill before it
                while not out.exists() and time.monotonic() < deadline:  # leaves no file: another case)
                    time.sleep(0.01)
                time.sleep(rng.uniform(0.0, 1.0))  # a random moment relative to the 0.5 s flushes
                child.kill()
                child.communicate(timeout=30)
                log = emu.stop()
            opened, rows = plain_h5py(out)
            exact, note = check_exact(out, log) if opened else (False, rows)
            if not (opened and exact):
                failures.append(f"trial {trial}: {note}")
        return Outcome(not failures, f"{trials - len(failures)}/{trials} killed files open in plain h5py, exact"
                       + (f"; {failures[0]}" if failures else ""))
    return case


def _touch(path: Path) -> Path:
    path.write_text("x")
    return path


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
    return Outcome(*clean_failure(sensnake("export", str(good), "--csv", str(blocker / "out.csv")), 1, "out.csv",
                                  "not a folder"))


def record_over_existing_wrong_board(folder: Path) -> Outcome:
    """A board of another channel count must not cost the user the recording already at ``--out``."""
    config = folder / "lab.toml"
    config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
    out = folder / "precious.h5"
    out.write_bytes(b"an earlier recording" * 1000)
    before = out.read_bytes()
    with EmulatedBoard(folder, rate_hz=RATE_HZ, wrong_channels=48) as emu:
        run = sensnake("record", "--daq", emu.path, "--seconds", "5", "--out", str(out), "--config", str(config))
    ok, note = clean_failure(run, 1, "48 channels")
    if ok and out.read_bytes() != before:
        return Outcome(False, "the existing --out was changed")
    return Outcome(ok and not _hidden(folder), note)


def damaged_recording_export(folder: Path) -> Outcome:
    """An HDF5 file that says it is a recording but has no board data."""
    import h5py

    bad = folder / "nodaq.h5"
    with h5py.File(bad, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["version"] = 1
    return Outcome(*clean_failure(sensnake("export", str(bad), "--csv", str(folder / "x.csv")), 1, "nodaq.h5"))


def _hidden(folder: Path) -> list[str]:
    """Hidden work files left behind (a temporary the user never asked for)."""
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


# -- output files and messages ----------------------------------------------------------------------------------------
AREA = "1.4e-3"
BINARY = bytes(range(256)) * 4  # not UTF-8 from byte 128 on


def _fitted(folder: Path) -> tuple[list[str], Path]:
    """Two synthetic calibration trials and ``sensnake fit`` of them (S06B): (trial paths, cal.json)."""
    from app.core import calfiles
    from models.physics import PhysicsConstants
    from models.synthetic import TYPICAL_TRUTH, Readout, paper_protocol

    trials = paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=5, repeats=1, noise_rel=0.001,
                            readout=Readout())[:2]
    paths = []
    for trial in trials:
        path = folder / f"{trial.name}.csv"
        calfiles.write_trial_csv(path, trial.time_s, trial.force_n, trial.conductance_s)
        paths.append(str(path))
    cal = folder / "cal.json"
    run = sensnake("fit", *paths, "--sensor", "S06B", "--area", AREA, "--out", str(cal))
    if run.code != 0:
        raise RuntimeError(f"could not fit: {run.err.strip()[-200:]}")
    return paths, cal


def _force_csv(path: Path, force_n: list[float]) -> Path:
    import numpy as np

    from app.core import calfiles

    values = np.asarray(force_n, dtype=float)
    calfiles.write_series_csv(path, np.arange(values.size) / 6.0, ("S06B",), values[:, None])
    return path


def output_modes(folder: Path) -> Outcome:
    """fit, forward and estimate write with the user's umask and keep the mode of a file they replace."""
    import stat

    paths, cal = _fitted(folder)
    force = _force_csv(folder / "force.csv", [0.0] * 30 + [2.0] * 60)
    commands = {
        "fit": (folder / "fit.json", lambda out: ["fit", paths[0], "--sensor", "S06B", "--area", AREA,
                                                   "--physics", str(cal), "--out", str(out)]),
        "forward": (folder / "c.csv", lambda out: ["forward", str(force), "--cal", str(cal), "--out", str(out)]),
        "estimate": (folder / "f.csv", lambda out: ["estimate", str(folder / "c.csv"), "--cal", str(cal),
                                                    "--out", str(out)]),
    }
    problems = []
    for mask, expected in ((0o022, 0o644), (0o077, 0o600)):
        for name, (out, argv) in commands.items():
            out.unlink(missing_ok=True)
            run = sensnake(*argv(out), umask=mask)
            mode = stat.S_IMODE(out.stat().st_mode) if out.exists() else -1
            if run.code != 0 or mode != expected:
                problems.append(f"{name} with umask {mask:03o}: exit {run.code}, mode {mode:03o}")
    for name, (out, argv) in commands.items():
        os.chmod(out, 0o640)
        run = sensnake(*argv(out), umask=0o077)
        mode = stat.S_IMODE(out.stat().st_mode)
        if run.code != 0 or mode != 0o640:
            problems.append(f"{name} replacing a 640 file: exit {run.code}, mode {mode:03o}")
    problems += [f"left behind: {name}" for name in _hidden(folder)]
    return Outcome(not problems, problems[0] if problems else
                   "fit/forward/estimate: umask 022 → 644, 077 → 600; a replaced 640 file stays 640")


def binary_input(kind: str) -> Callable[[Path], Outcome]:
    """A binary file given as a shape (play) or as a config (fit): one line naming the file."""
    def case(folder: Path) -> Outcome:
        bad = folder / ("walk.json" if kind == "shape" else "lab.toml")
        bad.write_bytes(BINARY)
        if kind == "shape":
            run = sensnake("play", str(bad), "--robot", "sim")
        else:
            import numpy as np

            from app.core import calfiles

            trial = folder / "trial.csv"
            calfiles.write_trial_csv(trial, np.arange(3.0), np.array([0.0, 1.0, 1.0]), np.array([1e-4, 2e-4, 2e-4]))
            run = sensnake("fit", str(trial), "--sensor", "S06B", "--area", AREA, "--config", str(bad),
                           "--out", str(folder / "cal.json"))
        return Outcome(*clean_failure(run, run.code if run.code else 1, str(bad)))
    return case


def write_error_names_users_path(folder: Path) -> Outcome:
    _paths, cal = _fitted(folder)
    force = _force_csv(folder / "force.csv", [1.0] * 20)
    out = folder / "out.csv"
    out.mkdir()  # the output path is a folder: the final move fails
    run = sensnake("forward", str(force), "--cal", str(cal), "--out", str(out))
    ok, note = clean_failure(run, run.code if run.code else 1, str(out))
    return Outcome(ok and not _hidden(folder), note)


def fit_unknown_sensor(folder: Path) -> Outcome:
    paths, _cal = _fitted(folder)
    out = folder / "new.json"
    run = sensnake("fit", paths[0], "--sensor", "S99Z", "--area", AREA, "--out", str(out))
    ok, note = clean_failure(run, run.code if run.code else 1, "S99Z")
    return Outcome(ok and not out.exists(), note)


def forward_negative_force(folder: Path) -> Outcome:
    _paths, cal = _fitted(folder)
    force = _force_csv(folder / "force.csv", [0.0] * 30 + [2.0] * 10 + [-0.25] + [2.0] * 49)
    out = folder / "c.csv"
    run = sensnake("forward", str(force), "--cal", str(cal), "--out", str(out))
    ok, note = clean_failure(run, run.code if run.code else 1, "negative", "-0.25", "--clip-negative")
    if ok and out.exists():
        return Outcome(False, "a refused forward wrote its output")
    clipped = sensnake("forward", str(force), "--cal", str(cal), "--out", str(out), "--clip-negative")
    if clipped.code != 0 or "read as 0 N" not in clipped.err:
        return Outcome(False, f"--clip-negative: exit {clipped.code}: {clipped.err.strip()[:100]}")
    return Outcome(ok, note)


# -- servo cases (tests/emulators/xm430_emulator.py) ---------------------------------------------------------------
def _servo_emulator(*args: str):
    from tests.emulators.xm430_emulator import EmulatorProcess

    return EmulatorProcess(*args)


def _shape(path: Path, angles: list[float]) -> Path:
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": path.stem,
                                "axes": ["pitch", "yaw"] * 6, "angles_rad": angles}))
    return path


def scan_case(emulator_args: tuple[str, ...] = (), commands: tuple[str, ...] = (), baud: str = "1000000",
              expect_ids: int = 12) -> Callable[[Path], Outcome]:
    def case(folder: Path) -> Outcome:
        emu = _servo_emulator(*emulator_args)
        try:
            for command in commands:
                emu.command(command)
            run = sensnake("scan", "--robot", emu.path, "--baud", baud)
        finally:
            emu.close()
        if run.traceback:
            return Outcome(False, "traceback")
        if expect_ids:
            found = [line for line in run.out.splitlines() if "XM430" in line]
            return Outcome(run.code == 0 and len(found) == expect_ids, f"exit {run.code}, {len(found)} servos")
        ok = run.code == 0 and "no servo" in (run.out + run.err).lower() or run.code == 1 and len(
            run.error_lines()) == 1
        return Outcome(ok, f"exit {run.code}: {(run.out + run.err).strip()[:100]}")
    return case


def play_case(fault: str | None, angles: list[float], words: tuple[str, ...]) -> Callable[[Path], Outcome]:
    """``sensnake play`` (slow) with ``fault`` sent to the emulator once goals flow; expects exit 1, one line."""
    def case(folder: Path) -> Outcome:
        emu = _servo_emulator()
        shape = _shape(folder / "shape.json", angles)
        try:
            child = subprocess.Popen([sys.executable, "-m", "app", "play", str(shape), "--robot", emu.path,
                                      "--speed", "0.05"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
            if fault is not None:
                deadline = time.monotonic() + 30
                while emu.counts()["sync_write"] < 15 and child.poll() is None and time.monotonic() < deadline:
                    time.sleep(0.05)  # a script polling the emulator's counters, not a test
                emu.command(fault)
            out, err = child.communicate(timeout=60)
            goals = emu.counts()["sync_write"] if fault is None else 0  # after "kill" the emulator is gone
        finally:
            emu.close()
        ok, note = clean_failure(Run(child.returncode, out, err), 1, *words)
        if ok and fault is None and goals:
            return Outcome(False, f"{goals} goal writes before the refusal")
        return Outcome(ok, note)
    return case


def teach_silent_servo(folder: Path) -> Outcome:
    emu = _servo_emulator()
    try:
        emu.command("silent 7")
        run = sensnake("teach", "--robot", emu.path, "--after", "0", "--out", str(folder / "t.json"))
    finally:
        emu.close()
    ok, note = clean_failure(run, 1, "7")
    return Outcome(ok and not (folder / "t.json").exists(), note)


# -- nothing a user does loses, mixes or invents data ---------------------------------------------------------------
def _calibration(folder: Path) -> Path:
    from tests.calibration_files import write_typical_calibration

    return write_typical_calibration(folder / "cal.json", ["S06B"])


def _series(folder: Path) -> Path:
    path = folder / "in.csv"
    path.write_text("time_s,S06B\n" + "".join(f"{k / 30:.6f},{1e-4 * (1 + k % 7)}\n" for k in range(300)))
    return path


def output_onto_input(folder: Path) -> Outcome:
    data = _series(folder)
    before = data.read_bytes()
    run = sensnake("estimate", str(data), "--cal", str(_calibration(folder)), "--out", str(data))
    ok, note = clean_failure(run, 1, "in.csv", "also an input")
    if ok and data.read_bytes() != before:
        return Outcome(False, "the input was changed")
    return Outcome(ok, note)


def two_writers_one_file(folder: Path) -> Outcome:
    out = folder / "same.h5"
    first = subprocess.Popen([sys.executable, "-m", "app", "record", "--daq", "sim", "--seconds", "4", "--out",
                              str(out)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert first.stderr is not None
        seen = ""
        while "frames" not in seen:  # the first writer holds the file
            chunk = first.stderr.read(16)
            if not chunk:
                break
            seen += chunk
        second = sensnake("record", "--daq", "sim", "--seconds", "1", "--out", str(out))
        first.communicate(timeout=60)
    finally:
        first.kill()
        first.wait()
    ok, note = clean_failure(second, 1, "same.h5", str(first.pid))
    if not ok:
        return Outcome(False, f"second writer: {note}")
    opened, rows = plain_h5py(out)
    return Outcome(first.returncode == 0 and opened, f"refused naming pid {first.pid}; the first kept {rows} rows")


def file_size_limit(folder: Path) -> Outcome:
    import resource

    out = folder / "limited.h5"
    done = subprocess.run([sys.executable, "-m", "app", "record", "--daq", "sim", "--seconds", "60", "--out",
                           str(out)], cwd=REPO, capture_output=True, text=True, timeout=120,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (600_000, 600_000)))  # noqa: PLW1509
    run = Run(done.returncode, done.stdout, done.stderr)
    ok, note = clean_failure(run, 1, "limited.h5", "File too large")
    if not ok:
        return Outcome(False, note)
    opened, rows = plain_h5py(out)
    leftovers = _hidden(folder)
    if not opened or leftovers:
        return Outcome(False, f"plain h5py: {rows}; left behind: {leftovers}")
    return Outcome(True, f"one line; plain h5py opens it ({rows} rows)")


def sparse_csv(folder: Path) -> Outcome:
    big = folder / "big.csv"
    big.write_text("time_s,S06B\n")
    with big.open("r+b") as handle:
        handle.truncate(2 << 30)
    # Measured from a small fresh python: a child forked from this process would report this process's RSS too.
    measure = ("import os, subprocess, sys, time\nstart = time.monotonic()\n"
               "child = subprocess.Popen([sys.executable, '-m', 'app', *sys.argv[1:]], stdout=subprocess.DEVNULL)\n"
               "_pid, status, usage = os.wait4(child.pid, 0)\n"
               "print(os.waitstatus_to_exitcode(status), usage.ru_maxrss, time.monotonic() - start)")
    done = subprocess.run([sys.executable, "-c", measure, "estimate", str(big), "--cal", str(_calibration(folder)),
                           "--out", str(folder / "f.csv")], cwd=REPO, capture_output=True, text=True, timeout=120)
    code, peak_kb, wall = done.stdout.split()
    run = Run(int(code), "", done.stderr)
    seconds = float(wall)
    ok, note = clean_failure(run, 1, "big.csv", "not a text CSV")
    peak_mb = int(peak_kb) / 1024
    return Outcome(ok and peak_mb <= 500 and seconds <= 10, f"{note[:60]}; peak {peak_mb:.0f} MB, {seconds:.1f} s")


def csv_nul_and_long_line(folder: Path) -> Outcome:
    cal = _calibration(folder)
    nul = folder / "nul.csv"
    nul.write_bytes(b"time_s,S06B\n0,1e-4\n\x001,1e-4\n")
    long_line = folder / "long.csv"
    long_line.write_text("time_s,S06B\n0," + "9" * (2 << 20) + "\n")
    notes = []
    for path, words in ((nul, ("nul.csv", "NUL byte")), (long_line, ("long.csv", "longer than"))):
        ok, note = clean_failure(sensnake("estimate", str(path), "--cal", str(cal), "--out", str(folder / "o.csv")),
                                 1, *words)
        if not ok:
            return Outcome(False, note)
        notes.append(note[:50])
    return Outcome(True, " | ".join(notes))


def board_case_exact(**faults: object) -> Callable[[Path], Outcome]:
    """Record from the emulator with ``faults``: exit 0, every frame once and exact, no gap marked."""
    def case(folder: Path) -> Outcome:
        import h5py

        config = folder / "lab.toml"
        config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
        out = folder / "rec.h5"
        with EmulatedBoard(folder, rate_hz=RATE_HZ, **faults) as emu:
            run = sensnake("record", "--daq", emu.path, "--seconds", "2", "--out", str(out), "--config", str(config))
            log = emu.stop()
        if run.code != 0 or run.traceback:
            return Outcome(False, f"exit {run.code}: {run.err.strip()[-160:]}")
        exact, note = check_exact(out, log)
        with h5py.File(out, "r") as f:
            kinds = [k.decode() for k in f["events/kind"][:]]
            attrs = {k: int(v) for k, v in f["daq"].attrs.items() if k in ("duplicate_frames", "clock_backsteps")}
        if "gap" in kinds:
            return Outcome(False, f"a false gap was marked ({note})")
        return Outcome(exact, f"{note}; {attrs}")
    return case


def protocol_version_2(folder: Path) -> Outcome:
    config = folder / "lab.toml"
    config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
    with EmulatedBoard(folder, rate_hz=RATE_HZ, version=2) as emu:
        run = sensnake("record", "--daq", emu.path, "--seconds", "2", "--out", str(folder / "r.h5"), "--config",
                       str(config))
    return Outcome(*clean_failure(run, 1, "protocol version 2", "version 1"))


def stopped_recorder(folder: Path) -> Outcome:
    import h5py
    import numpy as np

    config = folder / "lab.toml"
    config.write_text("[board]\nrate_hz = 30.0\n")
    out = folder / "stalled.h5"
    with EmulatedBoard(folder, rate_hz=30.0) as emu:
        child = subprocess.Popen([sys.executable, "-m", "app", "record", "--daq", emu.path, "--seconds", "60",
                                  "--out", str(out), "--config", str(config)], cwd=REPO, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        _drive(child, emu, [("30", "noop")])
        os.kill(child.pid, signal.SIGSTOP)
        time.sleep(2.0)  # the recorder stopped: nobody reads the board meanwhile
        os.kill(child.pid, signal.SIGCONT)
        time.sleep(1.5)  # it catches up and records on
        child.send_signal(signal.SIGTERM)
        child.communicate(timeout=30)
        emu.stop()
    with h5py.File(out, "r") as f:
        steps = np.diff(f["daq/time_s"][:])
        kinds = [k.decode() for k in f["events/kind"][:]]
    ok = steps.max() < 0.25 and "stall" in kinds
    return Outcome(ok, f"largest time step {steps.max() * 1e3:.0f} ms; events {sorted(set(kinds))}")


def board_holds_frames(folder: Path, **delivery: float) -> Outcome:
    """A board that holds its frames (``hold_first``: until it is read; ``burst``: an adapter handing them over in
    bursts): every frame kept, at the board's spacing, ``--seconds`` of them, and no host stall counted."""
    import h5py
    import numpy as np

    config = folder / "lab.toml"
    config.write_text("[board]\nrate_hz = 30.0\n")
    out = folder / "held.h5"
    with EmulatedBoard(folder, rate_hz=30.0, **delivery) as emu:
        run = sensnake("record", "--daq", emu.path, "--seconds", "2.5", "--out", str(out), "--config", str(config))
    if run.code != 0 or "Traceback" in run.err:
        return Outcome(False, f"exit {run.code}: {run.err.strip()[-200:]}")
    with h5py.File(out, "r") as f:
        time_s = f["daq/time_s"][:]
        stalls = int(f["daq"].attrs["host_stalls"])
    steps = np.diff(time_s)
    ok = steps.min() > 0.8 / 30 and time_s[-1] - time_s[0] >= 2.4 and stalls == 0
    return Outcome(ok, f"steps {steps.min() * 1e3:.1f}–{steps.max() * 1e3:.1f} ms over {time_s[-1] - time_s[0]:.2f} s; "
                       f"host stalls {stalls}")


def duplicate_servo_id(folder: Path) -> Outcome:
    emu = _servo_emulator("--ids", "1,1,3-12")
    shape = _shape(folder / "shape.json", [0.1 * (-1) ** i for i in range(12)])
    try:
        scan = sensnake("scan", "--robot", emu.path)
        play = sensnake("play", str(shape), "--robot", emu.path, "--speed", "1", "--shifts", "1")
    finally:
        emu.close()
    ok, note = clean_failure(scan, 1, "servo ID 1", "same ID", "2")
    if not ok:
        return Outcome(False, f"scan: {note}")
    ok, note = clean_failure(play, 1, "same ID")
    if not ok or "wiring" in play.err:
        return Outcome(False, f"play: {note}")
    return Outcome(True, "scan and play name ID 1 shared and ID 2 missing")


def calibration_messages(folder: Path) -> Outcome:
    from tests.calibration_files import typical_sensor_entry, write_calibration

    entry = typical_sensor_entry()
    entry["sls"]["mu1_Pa_s"] = -1.0
    bad = write_calibration(folder / "bad.json", {"S06B": entry})
    deep = folder / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    semi = folder / "semi.csv"
    semi.write_text("time_s;S06B\n0;1e-4\n")
    good_cal = _calibration(folder)
    data = _series(folder)
    checks = [(sensnake("estimate", str(data), "--cal", str(bad), "--out", str(folder / "o.csv")),
               ("bad.json", "S06B", "mu1_Pa_s")),
              (sensnake("estimate", str(data), "--cal", str(deep), "--out", str(folder / "o.csv")), ("deep.json",)),
              (sensnake("estimate", str(semi), "--cal", str(good_cal), "--out", str(folder / "o.csv")),
               ("semi.csv", "semicolons"))]
    for run, words in checks:
        ok, note = clean_failure(run, 1, *words)
        if not ok:
            return Outcome(False, note)
    return Outcome(True, "each names the file (and sensor, key)")


def symlink_loop_out(folder: Path) -> Outcome:
    (folder / "a.h5").symlink_to(folder / "b.h5")
    (folder / "b.h5").symlink_to(folder / "a.h5")
    run = sensnake("record", "--daq", "sim", "--seconds", "1", "--out", str(folder / "a.h5"))
    ok, note = clean_failure(run, 1, "a.h5")
    leftovers = _hidden(folder)
    return Outcome(ok and not leftovers, note if not leftovers else f"left behind: {leftovers}")


def servo_reboot_clears_overload(folder: Path) -> Outcome:
    emu = _servo_emulator()
    try:
        emu.command("overload 5")
        run = sensnake("servo", "reboot", "--robot", emu.path, "--id", "5")
        hw_error = emu.state(5)["hw_error"]
    finally:
        emu.close()
    ok = run.code == 0 and not run.traceback and "32 (overload) → 0 (no error)" in run.out and hw_error == 0
    return Outcome(ok, f"exit {run.code}: {(run.out + run.err).strip()[:110]}")


def play_with_a_servo_in_error(folder: Path) -> Outcome:
    emu = _servo_emulator()
    shape = _shape(folder / "shape.json", [0.1] + [0.0] * 11)
    try:
        emu.command("overload 5")
        run = sensnake("play", str(shape), "--robot", emu.path, "--speed", "1")
        goals = emu.state(5)["goal_writes"]
    finally:
        emu.close()
    ok, note = clean_failure(run, 1, "servo 5 overload", "nothing moved", "sensnake servo reboot --id 5")
    if ok and ("motion stopped" in run.err or goals):
        return Outcome(False, f"said 'motion stopped' or moved ({goals} goal writes): {note}")
    return Outcome(ok, note)


def restore_a_file_keyed_254(folder: Path) -> Outcome:
    emu = _servo_emulator()
    saved = folder / "servos.json"
    try:
        dump = sensnake("servo", "dump", "--robot", emu.path, "--id", "3", "--out", str(saved))
        document = json.loads(saved.read_text()) if dump.code == 0 else {"servos": {}}
        document["servos"] = {"254": document["servos"].get("3", {})}
        saved.write_text(json.dumps(document))
        writes = emu.counts()["write"]
        run = sensnake("servo", "restore", str(saved), "--robot", emu.path)
        writes = emu.counts()["write"] - writes
    finally:
        emu.close()
    ok, note = clean_failure(run, 1, "'254'", "not a servo ID")
    if ok and ("TxRxResult" in run.err or writes):
        return Outcome(False, f"{writes} writes or the SDK's words: {note}")
    return Outcome(ok, note)


def dump_onto_a_fifo(folder: Path) -> Outcome:
    fifo = folder / "servos.json"
    os.mkfifo(fifo)
    run = sensnake("servo", "dump", "--robot", "sim", "--out", str(fifo), timeout_s=30)
    ok, note = clean_failure(run, 1, str(fifo), "FIFO")
    return Outcome(ok and fifo.is_fifo(), note)


CASES: dict[str, Callable[[Path], Outcome]] = {
    "board: clean stream": record_case(),
    "board: 5% garbage": record_case(garbage=0.05),
    "board: 5% CRC flips": record_case(crc_flip=0.05),
    "board: 2% dropped frames": record_case(drop=0.02),
    "board: 5% garbage + 5% CRC flips + 2% drops": record_case(seconds=3.0, garbage=0.05, crc_flip=0.05,
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
    "board: wrong channel count, existing --out": record_over_existing_wrong_board,
    "record: --out in a missing folder": one_line(lambda d: ["record", "--daq", "sim", "--seconds", "1", "--out",
                                                            str(d / "nope" / "r.h5")], 1, "nope/r.h5",
                                                  "does not exist"),
    "record: --out inside a file": one_line(lambda d: ["record", "--daq", "sim", "--seconds", "1", "--out",
                                                      str(_touch(d / "file") / "r.h5")], 1, "file/r.h5",
                                            "not a folder"),
    "record: --out is a folder": one_line(lambda d: ["record", "--daq", "sim", "--seconds", "1", "--out", str(d)],
                                          1, "is a folder"),
    "record: SIGTERM": record_signal(signal.SIGTERM, 128 + signal.SIGTERM),
    "record: SIGHUP": record_signal(signal.SIGHUP, 128 + signal.SIGHUP),
    "record: Ctrl-C": record_signal(signal.SIGINT, 130),
    "record: kill -9": record_signal(signal.SIGKILL, -signal.SIGKILL),
    "record: kill -9 at 12 random moments": kill_at_random_moments(12),
    "file: truncated at 99.9%": truncated(0.999, 0.95),
    "file: truncated at 90%": truncated(0.9, 0.5),
    "file: truncated at 50%": truncated(0.5, 0.1),
    "file: not HDF5": not_hdf5_export,
    "file: export to an unwritable path": export_unwritable,
    "file: a recording without board data": damaged_recording_export,
    "files: fit/forward/estimate keep the umask and a replaced file's mode": output_modes,
    "message: a binary shape given to play": binary_input("shape"),
    "message: a binary config given to fit": binary_input("config"),
    "message: a write error names the user's path": write_error_names_users_path,
    "message: fit --sensor S99Z (not on the board)": fit_unknown_sensor,
    "message: forward with a negative force": forward_negative_force,
    "servo: scan a clean chain": scan_case(),
    "servo: scan with servo 4 silent": scan_case(commands=("silent 4",), expect_ids=11),
    "servo: scan at the wrong baud": scan_case(baud="57600", expect_ids=0),
    "servo: teach with servo 7 silent": teach_silent_servo,
    "servo: play a shape beyond the joint limits": play_case(None, [0.0, 0.0, 10.0] + [0.0] * 9,
                                                             ("joint 3", "10.000", "limit")),
    "servo: servo 5 reboots mid-play (sags)": play_case("reboot 5 0.05 700", [0.5 * (-1) ** i for i in range(12)],
                                                        ("servo 5",)),
    "servo: servo 5 reboots mid-play (torque off only)": play_case("reboot 5 0.05 0",
                                                                   [0.5 * (-1) ** i for i in range(12)],
                                                                   ("servo 5",)),
    "servo: servo 3 overload mid-play": play_case("overload 3", [0.5 * (-1) ** i for i in range(12)],
                                                  ("servo 3",)),
    "servo: bus killed mid-play": play_case("kill", [0.5 * (-1) ** i for i in range(12)], ("servo bus",)),
    # nothing a user does loses, mixes or invents data
    "data: estimate --out onto its input": output_onto_input,
    "data: two recorders on one --out": two_writers_one_file,
    "data: a file-size limit mid-recording (ulimit -f)": file_size_limit,
    "data: a 2 GB sparse CSV to estimate": sparse_csv,
    "data: a CSV with a NUL byte / a 2 MB line": csv_nul_and_long_line,
    "data: --out is a symlink loop": symlink_loop_out,
    "board: every frame sent twice (same seq)": board_case_exact(repeat=1.0),
    "board: its clock steps back 0.5 s (seq goes on)": board_case_exact(clock_back_at=0.8),
    "board: speaks protocol version 2": protocol_version_2,
    "record: SIGSTOP 2 s, then SIGCONT": stopped_recorder,
    "record: a board that holds its first 1.5 s until read": lambda d: board_holds_frames(d, hold_first=1.5),
    "record: an adapter handing frames over every 0.8 s": lambda d: board_holds_frames(d, burst=0.8),
    "servo: two servos on ID 1 (none on 2)": duplicate_servo_id,
    "record: --baud 99999999999": one_line(lambda d: ["record", "--daq", "sim", "--seconds", "1", "--out",
                                                      str(d / "r.h5"), "--baud", "99999999999"], 1, "--baud"),
    "message: a calibration with mu1 < 0, a 100 000-deep JSON, a ;-CSV": calibration_messages,
    "servo: reboot clears servo 5's latched overload": servo_reboot_clears_overload,
    "servo: play with servo 5 in error at connect (nothing moves)": play_with_a_servo_in_error,
    "servo: restore a settings file keyed 254 (the broadcast ID)": restore_a_file_keyed_254,
    "servo: dump onto a FIFO": dump_onto_a_fifo,
    "robot: play with neither --robot nor --config": one_line(lambda d: ["play", str(_shape(d / "s.json", [0.0] * 12))],
                                                             2, "no robot port", "--config"),
}


# -- hostile inputs: outputs that are no regular file, stale temporaries, TOML, HDF5, memory limits -----------------
# These run the command in this process (app.cli.main.main), as tests/app does: fast enough for tests/test_fault_matrix.py
# to run every one of them; only the memory limits need a process of their own.
def in_process(*args: str) -> Run:
    """``sensnake ARGS`` called in this process: (exit code, stdout, stderr)."""
    import contextlib
    import io

    from app.cli.main import main as sensnake_main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = sensnake_main(list(args))
        except SystemExit as exc:  # argparse's usage errors
            code = int(exc.code or 0)
        except Exception:  # noqa: BLE001 - an escaped exception is what a user would see as a traceback
            import traceback

            err.write(traceback.format_exc())
            code = 1
    return Run(code, out.getvalue(), err.getvalue())


def _small_recording(path: Path, n: int = 40) -> Path:
    """A valid recording of 36 channels (S06B among them) written in this process, no board needed."""
    import numpy as np

    from app.core.recording import RecordingWriter
    from devices.config import BoardConfig

    names = BoardConfig().channel_names
    with RecordingWriter(path, "", names, flush_interval_s=0.0, min_free_bytes=0) as writer:
        counts = np.full((n, len(names)), 2000, dtype=np.uint16)

        class Block:
            seq = np.arange(n, dtype=np.uint32)
            host_time_s = writer.t0_monotonic_s + np.arange(n) / 30.0
            conductance_s = np.full((n, len(names)), 1e-4)

        Block.counts = counts  # type: ignore[attr-defined]
        writer.append_daq(Block())  # type: ignore[arg-type]
    return path


def outputs_that_are_no_regular_file(folder: Path) -> Outcome:
    """A FIFO, a symbolic link to one, a socket and (as root) a character device node of its own (``mknod c 1 3``,
    what /dev/null is; never the real one) as every writer's output: refused in one line naming it, each left what
    it was."""
    import socket
    import stat

    rec = _small_recording(folder / "rec.h5")
    data, cal = _series(folder), _calibration(folder)
    trial = folder / "trial.csv"
    trial.write_text("time_s,force_N,conductance_S\n" + "".join(f"{k / 100:.2f},{k / 50:.3f},{1e-5 * (1 + k / 40):.6g}\n"
                                                                   for k in range(200)))
    fifo = folder / "pipe"
    os.mkfifo(fifo)
    link = folder / "link.out"
    link.symlink_to(fifo)
    targets = {fifo: "FIFO", link: "FIFO"}
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(folder / "sock"))
    targets[folder / "sock"] = "socket"
    if hasattr(os, "geteuid") and os.geteuid() == 0:  # root: a device node of our own, never /dev/null itself
        os.mknod(folder / "devnull", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        targets[folder / "devnull"] = "character device"
    kinds = {target: stat.S_IFMT(os.lstat(target).st_mode) for target in targets}
    commands = {"estimate CSV": ["estimate", str(data), "--cal", str(cal), "--out"],
                "estimate --flags": ["estimate", str(data), "--cal", str(cal), "--out", str(folder / "f.csv"),
                                     "--flags"],
                "estimate REC.h5": ["estimate", str(rec), "--cal", str(cal), "--out"],
                "export": ["export", str(rec), "--csv"], "repair": ["repair", str(rec), "--out"],
                "fit": ["fit", str(trial), "--sensor", "S06B", "--area", AREA, "--out"],
                "forward": ["forward", str(_force_csv(folder / "force.csv", [0.5, 1.5])), "--cal", str(cal),
                            "--out"],
                "record": ["record", "--daq", "sim", "--seconds", "1", "--out"],
                "experiment run": ["experiment", "run", "--seconds", "0.1", "--out"],
                "play --log": ["play", str(_shape(folder / "shape.json", [0.0] * 12)), "--robot", "sim", "--log"],
                "servo dump": ["servo", "dump", "--robot", "sim", "--out"]}
    try:
        for name, argv in commands.items():
            for target, kind in targets.items():
                ok, note = clean_failure(in_process(*argv, str(target)), 1, str(target), kind)
                if not ok:
                    return Outcome(False, f"{name} {target.name}: {note}")
                changed = [t.name for t in targets if stat.S_IFMT(os.lstat(t).st_mode) != kinds[t]]
                if changed:
                    return Outcome(False, f"{name} replaced {changed}")
    finally:
        listener.close()
    leftovers = _hidden(folder)
    return Outcome(not leftovers, f"left behind: {leftovers}" if leftovers else
                   f"{len(commands)} writers × ({', '.join(t.name for t in targets)}): one line each, each left what it "
                   "was")


def stale_temporaries_removed(folder: Path) -> Outcome:
    """A writer killed (kill -9) with its temporary open leaves it; the next writer of that output removes it (its
    pid is dead), and keeps a live writer's."""
    rec = _small_recording(folder / "rec.h5")
    out = folder / "new.h5"
    killed = subprocess.run([sys.executable, "-c", "import os, sys\nfrom app.core.outputs import create_temporary\n"
                             "create_temporary(sys.argv[1])\nos.kill(os.getpid(), 9)", str(out)], cwd=REPO,
                            env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, timeout=60)
    stale = _hidden(folder)
    if killed.returncode != -signal.SIGKILL or len(stale) != 1:
        return Outcome(False, f"the killed writer left {stale} (exit {killed.returncode})")
    live = folder / f".{out.name}.{os.getpid()}.0123abcd.partial"  # this process: alive
    live.write_bytes(b"")
    run = in_process("estimate", str(rec), "--cal", str(_calibration(folder)), "--out", str(out))
    left = _hidden(folder)
    ok = run.code == 0 and left == [live.name]
    if not ok:
        return Outcome(False, f"exit {run.code}; left {left}")
    live.unlink()
    settings = folder / "servos.json"  # a servo dump killed while writing its settings file
    killed = subprocess.run([sys.executable, "-c", "import os, sys\nfrom app.core.outputs import create_temporary\n"
                             "create_temporary(sys.argv[1], '.tmp')\nos.kill(os.getpid(), 9)", str(settings)],
                            cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, timeout=60)
    stale_dump = _hidden(folder)
    run = in_process("servo", "dump", "--robot", "sim", "--id", "2", "--out", str(settings))
    ok = killed.returncode == -signal.SIGKILL and len(stale_dump) == 1 and run.code == 0 and not _hidden(folder)
    return Outcome(ok, f"removed {stale[0]} (estimate) and {stale_dump[0]} (servo dump), kept the live one" if ok
                   else f"servo dump: exit {run.code}; left {_hidden(folder)} (before: {stale_dump})")


def full_disk_record(folder: Path) -> Outcome:
    """A disk too full for the first flush: one line that says the old file was left as it was (not "keeps the
    first 0 board samples"), the old file untouched, no lock file or temporary left."""
    import shutil
    from unittest import mock

    out = folder / "old.h5"
    out.write_bytes(b"an earlier recording" * 100)
    before = out.read_bytes()
    real = shutil.disk_usage(folder)
    full = type(real)(real.total, real.total, 1000)  # 1 kB free
    with mock.patch.object(shutil, "disk_usage", return_value=full):
        run = in_process("record", "--daq", "sim", "--seconds", "2", "--out", str(out))
    ok, note = clean_failure(run, 1, "old.h5", "almost full", "left as it was")
    if ok and ("first 0" in note or out.read_bytes() != before or _hidden(folder)):
        return Outcome(False, f"{note}; file changed or left behind: {_hidden(folder)}")
    return Outcome(ok, note)


def hostile_toml(folder: Path) -> Outcome:
    """Scene, sweep and gains files no reader should trust: one line each naming the file."""
    huge = "9" * 400
    files = {"int400.toml": f"[ground]\nfriction = {huge}\n", "int5000.toml": f"[ground]\nfriction = {'9' * 5000}\n",
             "deep.toml": "x = " + "[" * 200_000 + "]" * 200_000 + "\n",
             "crowd.toml": "[ground]\nfriction = 0.3\n" + "".join(
                 f'[[obstacle]]\nshape = "box"\nx_m = {k * 0.0002:.4f}\nlength_m = 0.01\nheight_m = 0.01\n'
                 for k in range(10_000)),
             "both.toml": "push_gain = 0.3\n[feedback]\ntarget_n = 6.0\n",
             "sweep.toml": f'scenes = ["flat"]\nseconds = {huge}\n'}
    for name, text in files.items():
        (folder / name).write_text(text, encoding="utf-8")
    os.mkfifo(folder / "fifo.toml")
    (folder / "zero.toml").symlink_to("/dev/zero")
    out = str(folder / "r.h5")
    checks: list[tuple[list[str], tuple[str, ...]]] = [
        (["experiment", "run", "--scene", str(folder / name), "--out", out], (name, words))
        for name, words in (("int400.toml", "400-digit"), ("int5000.toml", "digits"), ("deep.toml", "nested"),
                            ("crowd.toml", "at most 64"), ("fifo.toml", "FIFO"), ("zero.toml", "character device"))]
    checks += [(["experiment", "run", "--controller", "feedback", "--gains", str(folder / "both.toml"), "--out", out],
                ("both.toml", "top level", "[feedback]")),
               (["experiment", "run", "--controller", "feedback", "--gains", str(folder / "int400.toml"), "--out",
                 out], ("int400.toml", "400-digit")),
               (["experiment", "sweep", str(folder / "sweep.toml"), "--out", str(folder / "sweep")],
                ("sweep.toml", "400-digit")),
               (["experiment", "sweep", str(folder / "fifo.toml"), "--out", str(folder / "sweep")],
                ("fifo.toml", "FIFO"))]
    for argv, words in checks:
        ok, note = clean_failure(in_process(*argv), 1, *words)
        if not ok:
            return Outcome(False, f"{' '.join(argv[:2])} {words[0]}: {note}")
    return Outcome(True, f"{len(checks)} files, one line each naming the file and the cause")


def _hostile_recordings(folder: Path) -> dict[str, tuple[Path, tuple[str, ...]]]:
    """Recordings a reader must refuse: name → (file, words the message must hold)."""
    import shutil

    import h5py
    import numpy as np

    good = _small_recording(folder / "good.h5")
    n = 40

    def variant(name: str, change: Callable[[h5py.File], None], *words: str) -> tuple[Path, tuple[str, ...]]:
        path = folder / f"{name}.h5"
        shutil.copy(good, path)
        with h5py.File(path, "r+") as f:
            change(f)
        return path, (path.name, *words)

    def dataset(where: str, data: object) -> Callable[[h5py.File], None]:
        def change(f: h5py.File) -> None:
            del f[where]
            f[where] = data
        return change

    def loop(f: h5py.File) -> None:
        del f["daq/conductance_S"]
        f["daq/conductance_S"] = h5py.SoftLink("/daq/loop")
        f["daq/loop"] = h5py.SoftLink("/daq/conductance_S")

    def version(f: h5py.File) -> None:
        f.attrs["version"] = "abc"

    def hollow(f: h5py.File) -> None:  # 10⁸ rows declared (29 GB), none written: read whole, they would fill memory
        del f["daq/conductance_S"]
        f.create_dataset("daq/conductance_S", shape=(10**8, 36), dtype="f8", chunks=(1024, 36))

    cond = "/daq/conductance_S"
    return {
        "compound dtype": variant("compound", dataset("daq/conductance_S", np.zeros(
            (n, 36), dtype=[("a", "f8"), ("b", "i4")])), cond, "compound"),
        "1-D": variant("oned", dataset("daq/conductance_S", np.zeros(n)), cond, "36 columns"),
        "5 columns": variant("five", dataset("daq/conductance_S", np.zeros((n, 5))), cond, "36 columns"),
        "scalar": variant("scalar", dataset("daq/conductance_S", 1.0), cond, "single value"),
        "strings": variant("strings", dataset("daq/conductance_S", np.array([b"abc"] * n)), cond, "text"),
        "complex": variant("complex", dataset("daq/conductance_S", np.full((n, 36), 1e-4 + 1e-5j)), cond, "complex"),
        "soft-link loop": variant("loop", loop, cond, "loops back"),
        "2-D time": variant("time2d", dataset("daq/time_s", np.zeros((n, 2))), "/daq/time_s", "one value per row"),
        'version "abc"': variant("version", version, "version", "'abc'"),
        "hollow (10⁸ rows declared, none stored)": variant("hollow", hollow, cond, "declares 100,000,000 rows"),
    }


def hostile_recordings(folder: Path) -> Outcome:
    """estimate REC.h5, export and repair on recordings of the wrong shape or type: one line naming the file, the dataset
    and what was expected; never a traceback, a numpy warning or a silent exit 0."""
    import warnings

    cal = _calibration(folder)
    for name, (path, words) in _hostile_recordings(folder).items():
        for argv in (["estimate", str(path), "--cal", str(cal), "--out", str(folder / "o.h5")],
                     ["export", str(path), "--csv", str(folder / "o.csv")],
                     ["repair", str(path), "--out", str(folder / "fixed.h5")]):
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # a leaked numpy warning fails the case
                run = in_process(*argv)
            ok, note = clean_failure(run, 1, *words)
            if not ok:
                return Outcome(False, f"{argv[0]} on {name}: {note}")
    return Outcome(True, "10 hostile recordings × (estimate, export, repair): each one line naming the file and the "
                         "cause")


def repair_flipped_bytes(folder: Path) -> Outcome:
    """200 flipped bytes at five random places: repair either salvages or says in one line why not (never a codec's
    complaint or HDF5's report)."""
    import numpy as np

    data = _small_recording(folder / "good.h5").read_bytes()
    notes = []
    for seed in range(5):
        damaged = bytearray(data)
        rng = np.random.default_rng(seed)
        for k in rng.choice(len(damaged), 200, replace=False):
            damaged[k] ^= 0xFF
        path = folder / f"flipped{seed}.h5"
        path.write_bytes(bytes(damaged))
        run = in_process("repair", str(path), "--out", str(folder / f"fixed{seed}.h5"))
        if run.code == 0 and not run.traceback:
            notes.append("salvaged")
            continue
        ok, note = clean_failure(run, 1, path.name)
        if not ok:
            return Outcome(False, f"seed {seed}: {note}")
        notes.append("refused")
    return Outcome(not _hidden(folder), f"{', '.join(notes)}; left behind: {_hidden(folder)}" if _hidden(folder)
                   else ", ".join(notes))


def symlink_loop_inputs(folder: Path) -> Outcome:
    (folder / "a.h5").symlink_to(folder / "b.h5")
    (folder / "b.h5").symlink_to(folder / "a.h5")
    for argv in (["export", str(folder / "a.h5"), "--csv", str(folder / "o.csv")],
                 ["repair", str(folder / "a.h5"), "--out", str(folder / "o.h5")],
                 ["estimate", str(folder / "a.h5"), "--cal", str(_calibration(folder)), "--out", str(folder / "o.h5")]):
        ok, note = clean_failure(in_process(*argv), 1, "a.h5", "symbolic link loop")
        if not ok:
            return Outcome(False, f"{argv[0]}: {note}")
    return Outcome(True, "export, repair, estimate: 'symbolic link loop', not 'does not exist'")


def fifo_as_every_recording_input(folder: Path) -> Outcome:
    """A FIFO given where a recording is read (its open would wait for a writer for ever): every reader names it
    for what it is, never 'no such recording' or a hang."""
    fifo = folder / "take.h5"
    os.mkfifo(fifo)
    rec = _small_recording(folder / "rec.h5")
    readers = {"export": ["export", str(fifo), "--csv", str(folder / "o.csv")],
               "repair": ["repair", str(fifo), "--out", str(folder / "o.h5")],
               "estimate": ["estimate", str(fifo), "--cal", str(_calibration(folder)), "--out", str(folder / "o.h5")],
               "report": ["report", "repeatability", str(fifo), str(rec), "--out", str(folder / "report")],
               "runs show": ["runs", "show", str(fifo)],
               "mocap import": ["mocap", "import", "--xdf", str(folder / "none.xdf"), "--rec", str(fifo), "--out",
                                str(folder / "m.h5")],
               "lab identify": ["lab", "identify", str(fifo), "--out", str(folder / "fitted.toml")]}
    for name, argv in readers.items():
        ok, note = clean_failure(in_process(*argv), 1, "take.h5", "FIFO")
        if not ok:
            return Outcome(False, f"{name}: {note}")
    return Outcome(True, f"{len(readers)} readers: one line naming the FIFO")


def longest_legal_output_names(folder: Path) -> Outcome:
    """An output named with 255 bytes (the longest name a file may have): written (its hidden temporary and lock
    file carry a shortened name), nothing left beside it; 'File name too long' was said of legal names."""
    rec = _small_recording(folder / "rec.h5")
    data, cal = _series(folder), _calibration(folder)
    def named(tag: str, suffix: str) -> str:  # exactly 255 bytes
        return tag + "ü" * ((255 - len(tag) - len(suffix)) // 2) + "x" * ((255 - len(tag) - len(suffix)) % 2) + suffix

    runs = {"estimate": (["estimate", str(data), "--cal", str(cal), "--out"], named("a", ".csv")),
            "export": (["export", str(rec), "--csv"], named("b", ".csv")),
            "estimate REC.h5": (["estimate", str(rec), "--cal", str(cal), "--out"], named("c", ".h5")),
            "record": (["record", "--daq", "sim", "--seconds", "0.3", "--out"], named("d", ".h5"))}
    for what, (argv, out) in runs.items():
        run = in_process(*argv, str(folder / out))
        if run.code != 0 or run.traceback or not (folder / out).is_file():
            return Outcome(False, f"{what} ({len(out.encode())}-byte name): exit {run.code}: {run.err.strip()[-120:]}")
    left = _hidden(folder)
    return Outcome(not left, f"left behind: {left}" if left else f"{len(runs)} writers, 255-byte names: written")


def fit_under_address_limits(folder: Path) -> Outcome:
    """``fit`` under ``ulimit -v`` 150 MB, 300 MB and 2 GB: done, or one line naming the limit, within seconds —
    never minutes of silence (OpenBLAS threads, or its allocator spinning while a library loads)."""
    import resource

    from app.core import calfiles
    from models.physics import PhysicsConstants
    from models.synthetic import TYPICAL_TRUTH, Readout, paper_protocol

    trial = paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=5, repeats=1, noise_rel=0.001,
                           readout=Readout())[0]
    paths = [str(folder / "trial.csv")]
    calfiles.write_trial_csv(paths[0], trial.time_s, trial.force_n, trial.conductance_s)
    notes = []
    for limit_mb in (150, 300, 2048):
        limit = limit_mb << 20

        def address_limit(limit: int = limit) -> None:
            resource.setrlimit(resource.RLIMIT_AS, (limit, resource.RLIM_INFINITY))

        started = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "app", "fit", paths[0], "--sensor", "S06B", "--area", AREA,
                               "--out", str(folder / f"cal{limit_mb}.json")], cwd=REPO, capture_output=True,
                              text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO),
                                                           "SENSNAKE_IMPORT_WATCHDOG_S": "3"},
                              preexec_fn=address_limit)  # noqa: PLW1509
        seconds = time.monotonic() - started
        run = Run(done.returncode, done.stdout, done.stderr)
        if run.traceback or seconds > 60:
            return Outcome(False, f"{limit_mb} MB: {'traceback' if run.traceback else f'{seconds:.0f} s'}")
        if run.code != 0:
            lines = run.error_lines()
            if len(lines) != 1 or "ulimit -v" not in lines[0]:
                return Outcome(False, f"{limit_mb} MB: exit {run.code}: {run.err.strip()[-160:]}")
        notes.append(f"{limit_mb} MB: {'fitted' if run.code == 0 else 'one line'} in {seconds:.1f} s")
    return Outcome(True, "; ".join(notes))


def hostile_json_inputs(folder: Path) -> Outcome:
    """A shape (play), a servo settings file (servo restore) and a calibration (estimate --cal) that is a FIFO, a
    link to /dev/zero, 20 MB of blanks, a 6000-digit number or 150 000-deep nesting: one line naming the file and
    the cause, at once (a FIFO's read would block for ever, /dev/zero's never end)."""
    data = _series(folder)
    fifo = folder / "fifo.json"
    os.mkfifo(fifo)
    zero = folder / "zero.json"
    zero.symlink_to("/dev/zero")
    files = {fifo: "FIFO", zero: "character device"}
    for name, text, words in (("digits.json", '{"format": 1, "x": [' + "3" * 6000 + "]}", "digits"),
                              ("deep.json", "[" * 150_000 + "]" * 150_000, "nested too deeply")):
        (folder / name).write_text(text)
        files[folder / name] = words
    blank = folder / "blank.json"
    with blank.open("wb") as handle:
        handle.truncate(20_000_000)  # sparse: no disk used
    readers = {"play": lambda p: ["play", str(p), "--robot", "sim"],
               "servo restore": lambda p: ["servo", "restore", str(p), "--robot", "sim"],
               "estimate --cal": lambda p: ["estimate", str(data), "--cal", str(p), "--out", str(folder / "o.csv")]}
    for reader, argv in readers.items():
        for path, words in files.items():
            ok, note = clean_failure(in_process(*argv(path)), 1, path.name, words)
            if not ok:
                return Outcome(False, f"{reader} {path.name}: {note}")
        if reader != "estimate --cal":  # a calibration refuses the NUL bytes as binary; these two say the size cap
            ok, note = clean_failure(in_process(*argv(blank)), 1, blank.name, "larger than")
            if not ok:
                return Outcome(False, f"{reader} {blank.name}: {note}")
    twice = folder / "twice.json"  # json would keep the second "4" silently
    twice.write_text('{"format": "sensnake-servos", "version": 1, "servos": {"4": {"items": {}}, "4": {"items": {}}}}')
    ok, note = clean_failure(in_process("servo", "restore", str(twice), "--robot", "sim"), 1, "twice.json",
                             "given twice")
    if not ok:
        return Outcome(False, f"a servo given twice: {note}")
    config = folder / "huge.toml"
    with config.open("wb") as handle:
        handle.truncate(5_000_000)
    ok, note = clean_failure(in_process("estimate", str(data), "--cal", str(_calibration(folder)), "--config",
                                        str(config), "--out", str(folder / "o.csv")), 1, "huge.toml", "larger than")
    if not ok:
        return Outcome(False, f"a 5 MB lab config: {note}")
    return Outcome(True, f"{len(readers)} readers × (FIFO, /dev/zero, 6000 digits, 150 000 deep, 20 MB), a servo "
                         "given twice, a 5 MB lab config: one line each")


def play_log_never_clobbers(folder: Path) -> Outcome:
    """play --log: onto its own shape, into a missing folder, onto a FIFO: refused before the bus opens; a log from
    a play that never started leaves an old log as it was; a finished one replaces it whole, nothing left behind."""
    shape = _shape(folder / "walk.json", [0.0] * 12)
    before = shape.read_bytes()
    ok, note = clean_failure(in_process("play", str(shape), "--robot", "sim", "--log", str(shape)), 1,
                             "walk.json", "also an input")
    if not ok or shape.read_bytes() != before:
        return Outcome(False, f"onto its shape: {note}" if not ok else "the shape was overwritten")
    ok, note = clean_failure(in_process("play", str(shape), "--robot", "sim", "--log",
                                        str(folder / "nowhere" / "log.csv")), 1, "nowhere/log.csv")
    if not ok:
        return Outcome(False, f"missing folder: {note}")
    old = folder / "log.csv"
    old.write_text("an earlier play's log\n")
    failed = in_process("play", str(shape), "--robot", str(folder / "no-such-port"), "--log", str(old))
    if failed.code == 0 or failed.traceback or old.read_text() != "an earlier play's log\n" or _hidden(folder):
        return Outcome(False, f"a play that never started: exit {failed.code}, log {old.read_text()[:40]!r}, "
                              f"left {_hidden(folder)}")
    run = in_process("play", str(shape), "--robot", "sim", "--speed", "1.0", "--log", str(old))
    rows = old.read_text().splitlines()
    ok = run.code == 0 and rows[0].startswith("time_s,goal_rad_1") and len(rows) >= 2 and not _hidden(folder)
    return Outcome(ok, f"refused onto its shape and into a missing folder; old log kept after a failed connect, "
                       f"replaced by {len(rows) - 1} rows after a play" if ok else
                   f"exit {run.code}: {run.err.strip()[-120:]}; {len(rows)} rows; left {_hidden(folder)}")


def restore_checked_whole(folder: Path) -> Outcome:
    """servo restore against the XM430 emulator: a file for another model, a misspelt item, Min above Max Position
    Limit, a servo that is not on the bus, Status Return Level 0: one line each naming the servo and the cause, and
    no write at all (the change the file would restore on the first servo stays unwritten); servo set and a lab's
    [servos] refuse Status Return Level 0 with the reason."""
    emu = _servo_emulator()
    try:
        saved = folder / "servos.json"
        if sensnake("servo", "dump", "--robot", emu.path, "--out", str(saved)).code != 0:
            return Outcome(False, "servo dump failed")
        document = json.loads(saved.read_text())
        if sensnake("servo", "set", "--robot", emu.path, "--id", "1", "Position D Gain", "40").code != 0:
            return Outcome(False, "servo set failed")

        def variant(name: str, sid: str, **items: int) -> Path:
            copy = json.loads(json.dumps(document))
            copy["servos"][sid]["items"].update(items)
            if name == "model":
                copy["servos"][sid]["model_number"] = items["Model Number"]
            if name == "missing":
                copy["servos"]["19"] = copy["servos"][sid]
            path = folder / f"{name}.json"
            path.write_text(json.dumps(copy))
            return path

        cases = [(variant("model", "7", **{"Model Number": 1200}), ("servo 7", "model 1200", "nothing written")),
                 (variant("misspelt", "8", **{"Profile Acceleraton": 20}), ("servo 8", "Profile Acceleraton")),
                 (variant("limits", "9", **{"Min Position Limit": 3900, "Max Position Limit": 150}),
                  ("servo 9", "Min Position Limit = 3900 is above Max Position Limit = 150")),
                 (variant("missing", "10"), ("servo 19", "does not answer", "nothing written")),
                 (variant("silent", "11", **{"Status Return Level": 0}), ("servo 11", "cut the app off"))]
        writes = emu.counts()["write"]
        for path, words in cases:
            ok, note = clean_failure(sensnake("servo", "restore", str(path), "--robot", emu.path), 1, path.name,
                                     *words)
            if not ok:
                return Outcome(False, f"{path.name}: {note}")
        if emu.counts()["write"] != writes:
            return Outcome(False, f"{emu.counts()['write'] - writes} writes by refused restores")
        ok, note = clean_failure(sensnake("servo", "set", "--robot", emu.path, "--id", "5", "Status Return Level",
                                          "0"), 1, "Status Return Level = 0", "cut the app off")
        if not ok:
            return Outcome(False, f"servo set: {note}")
        config = folder / "lab.toml"
        config.write_text((REPO / "resources" / "default_lab.toml").read_text(encoding="utf-8")
                          + "\n[servos]\nstatus_return_level = 0\n", encoding="utf-8")
        ok, note = clean_failure(sensnake("play", str(_shape(folder / "s.json", [0.0] * 12)), "--robot", emu.path,
                                          "--config", str(config)), 1, "lab.toml", "status_return_level = 0")
        if not ok:
            return Outcome(False, f"[servos]: {note}")
        if emu.counts()["write"] != writes:
            return Outcome(False, f"{emu.counts()['write'] - writes} writes by refused settings")
    finally:
        emu.close()
    return Outcome(True, f"{len(cases)} settings files, servo set and [servos]: one line each, nothing written")


def restore_refused_midway(folder: Path) -> Outcome:
    """A servo whose firmware refuses a value midway through a restore (in this process: a write refused with
    the Data Limit error on servo 6): the line names the write, what was written and what was not; the servos hold
    what it says."""
    from unittest import mock

    from devices.errors import ERRNUM_DATA_LIMIT, ServoCommandError
    from devices.servo_chain import ServoChain

    emu = _servo_emulator()
    try:
        saved = folder / "servos.json"
        if in_process("servo", "dump", "--robot", emu.path, "--out", str(saved)).code != 0:
            return Outcome(False, "servo dump failed")
        for sid, item, value in ((2, "Position I Gain", "5"), (6, "Moving Threshold", "20"),
                                 (6, "Position I Gain", "5"), (11, "Position I Gain", "5")):
            if in_process("servo", "set", "--robot", emu.path, "--id", str(sid), item, value).code != 0:
                return Outcome(False, f"servo set {sid} {item} failed")
        write_item = ServoChain.write_item

        def refusing(self: ServoChain, servo_id: int, name: str, value: int, **kwargs: object) -> None:
            if (servo_id, name) == (6, "Moving Threshold"):
                raise ServoCommandError(servo_id, ERRNUM_DATA_LIMIT, f"writing {name} = {value}")
            write_item(self, servo_id, name, value, **kwargs)  # type: ignore[arg-type]

        with mock.patch.object(ServoChain, "write_item", refusing):
            run = in_process("servo", "restore", str(saved), "--robot", emu.path)
        ok, note = clean_failure(run, 1, "servos.json", "restore stopped at servo 6, Moving Threshold", "Written: servo 2 "
                                 "(Position I Gain)", "Not written: servo 6 (Moving Threshold, Position I Gain); "
                                 "servo 11 (Position I Gain)")
        held = [in_process("servo", "get", "--robot", emu.path, "--id", str(sid), "Position I Gain").out
                for sid in (2, 6, 11)]
    finally:
        emu.close()
    values = [text.split("Position I Gain")[-1].split()[0] if "Position I Gain" in text else "?" for text in held]
    if ok and values != ["0", "5", "5"]:
        return Outcome(False, f"Position I Gain of servos 2, 6, 11 reads {values}, not as the line said")
    return Outcome(ok, note)


def planted_in_a_sweep_folder(folder: Path) -> Outcome:
    """A sweep (tune, evaluation) folder where a link to someone else's file is planted at summary.csv and at the
    old predictable temporary's name, and a FIFO at failures.csv: the links are replaced, never written through,
    the FIFO refused in words, never opened (its open would hang)."""
    import stat

    from app.core.errors import OutputPathError
    from app.core.sweep import write_summary

    victim = folder / "someone-elses.csv"
    victim.write_text("theirs")
    out = folder / "sweep"
    out.mkdir()
    for name in ("summary.csv", "summary.csv.partial"):
        (out / name).symlink_to(victim)
    write_summary(out, [], {})
    os.mkfifo(out / "failures.csv")
    try:
        write_summary(out, [], {2: "a failed run"})
        return Outcome(False, "failures.csv: a FIFO was written (or the write hung)")
    except OutputPathError as exc:
        words = str(exc)
    plan = folder / "plan.toml"
    plan.write_text('scenes = ["flat"]\nseconds = 0.1\n')
    resumed = folder / "resumed"
    resumed.mkdir()
    os.mkfifo(resumed / "sweep.json")  # a resumed sweep reads its record first: the read would hang
    fifo_ok, fifo_note = clean_failure(in_process("experiment", "sweep", str(plan), "--out", str(resumed)), 1,
                                       "sweep.json", "FIFO")
    if not fifo_ok:
        return Outcome(False, f"a FIFO at sweep.json: {fifo_note}")
    ok = (victim.read_text() == "theirs" and not (out / "summary.csv").is_symlink()
          and stat.S_ISFIFO(os.lstat(out / "failures.csv").st_mode) and "FIFO" in words)
    return Outcome(ok, f"links replaced, FIFOs refused: {words[:90]}" if ok else f"victim {victim.read_text()!r}; "
                   f"{words}")


def planted_lock_files(folder: Path) -> Outcome:
    """A link to someone else's file planted at a recording's lock (``.NAME.lock``) and at a sweep folder's
    (``DIR/.lock``), a FIFO at another recording's: refused naming the lock file; the file the link leads to keeps
    its content (the lock's pid used to be written over it)."""
    victim = folder / "notes.txt"
    victim.write_text("theirs")
    (folder / ".a.h5.lock").symlink_to(victim)
    os.mkfifo(folder / ".b.h5.lock")
    for name, kind in (("a.h5", "symbolic link"), ("b.h5", "FIFO")):
        ok, note = clean_failure(in_process("record", "--daq", "sim", "--seconds", "0.2", "--out", str(folder / name)),
                                 1, f".{name}.lock (the lock file)", kind)
        if not ok:
            return Outcome(False, f"record {name}: {note}")
    sweep = folder / "sweep"
    sweep.mkdir()
    (sweep / ".lock").symlink_to(victim)
    plan = folder / "plan.toml"
    plan.write_text('scenes = ["flat"]\nseconds = 0.1\n')
    ok, note = clean_failure(in_process("experiment", "sweep", str(plan), "--out", str(sweep)), 1,
                             ".lock (the lock file)", "symbolic link")
    if not ok:
        return Outcome(False, f"experiment sweep: {note}")
    return Outcome(victim.read_text() == "theirs", "record × (link, FIFO), sweep × link: refused naming the lock file"
                   if victim.read_text() == "theirs" else "the linked file was written over")


CASES.update({
    "hostile: a FIFO or a link to one, a socket, a device node as every writer's output":
        outputs_that_are_no_regular_file,
    "hostile: a shape, settings or calibration file that is a FIFO, /dev/zero, 20 MB, 6000 digits, 150 000 deep; "
    "a servo given twice, a 5 MB lab config":
        hostile_json_inputs,
    "hostile: play --log onto its shape, a missing folder, an old log (never clobbered)": play_log_never_clobbers,
    "hostile: a link and a FIFO planted in a sweep's folder (its files, its record)": planted_in_a_sweep_folder,
    "hostile: a link or a FIFO planted at a recording's or a folder's lock file": planted_lock_files,
    "hostile: a killed writer's temporary is removed by the next run": stale_temporaries_removed,
    "hostile: record onto a full disk (old file untouched, no lock left)": full_disk_record,
    "hostile: TOML (400/5000 digits, deep nesting, 10 000 obstacles, FIFO, /dev/zero, gains twice)": hostile_toml,
    "hostile: recordings of the wrong shape or type (compound, 1-D, complex, loops, hollow, …)": hostile_recordings,
    "hostile: repair with 200 flipped bytes": repair_flipped_bytes,
    "hostile: export/repair/estimate of a symlink loop": symlink_loop_inputs,
    "hostile: a FIFO given as a recording to every reader": fifo_as_every_recording_input,
    "hostile: outputs with 255-byte names": longest_legal_output_names,
    "hostile: fit under ulimit -v 150 MB, 300 MB, 2 GB": fit_under_address_limits,
    "servo: restore checked whole (another model, a misspelt item, Min > Max, a missing servo, Status Return "
    "Level 0), set and [servos] refuse Status Return Level 0": restore_checked_whole,
    "servo: a restore refused midway names what was and was not written": restore_refused_midway,
})


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
