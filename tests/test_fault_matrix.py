"""scripts/fault_matrix.py: its judge can fail a case, it covers every fault docs/RELIABILITY.md lists, and one real case runs
end to end (the whole matrix takes minutes of real-time recordings; the tests it mirrors are in tests/app and
tests/devices)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux pseudo-terminals")


@pytest.fixture(scope="module")
def matrix():
    spec = importlib.util.spec_from_file_location("fault_matrix", ROOT / "scripts" / "fault_matrix.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["fault_matrix"] = module  # its dataclasses look their module up
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop("fault_matrix", None)


def test_the_judge_fails_tracebacks_extra_lines_wrong_codes_and_leaked_internals(matrix):
    run = matrix.Run
    good = run(1, "", "sensnake record: error: cannot create recording /x/r.h5: the folder /x does not exist\n")
    assert matrix.clean_failure(good, 1, "/x/r.h5") == (True, good.err.strip())
    hdf5 = ("sensnake record: error: cannot create recording /x/r.h5: Unable to synchronously create file (unable to "
            "open file: name = '/x/.r.h5.1.partial', errno = 2, error message = 'No such file', flags = 13, "
            "o_flags = 242)\n")
    for bad, why in ((run(1, "", hdf5), "internals"),
                     (run(1, "", "Traceback (most recent call last):\n" + good.err), "traceback"),
                     (run(1, "", good.err * 2), "2 error lines"),
                     (run(0, "", good.err), "exit 0"),
                     (run(1, "", "sensnake fit: error: 'utf-8' codec can't decode byte 0x80\n"), "internals")):
        ok, note = matrix.clean_failure(bad, 1)
        assert not ok and why in note, note
    assert not matrix.clean_failure(good, 1, "S99Z")[0]  # a message that does not name the cause


def test_every_item_of_issue_15_has_cases(matrix):
    names = " | ".join(matrix.CASES)
    for words in (["re-plugged"],  # 1 a re-plugged board is a new clock segment
                  ["silent, existing --out", "wrong channel count, existing --out"],  # 2 a failed record
                  ["kill -9", "SIGTERM", "SIGHUP"],  # 3 signals leave a plain-h5py file
                  ["truncated at 99.9%"],  # 4 salvage
                  ["reboots mid-play"],  # 5
                  ["beyond the joint limits"],  # 6
                  ["cable pulled for good"],  # 7
                  ["bus killed mid-play"],  # 8
                  ["counts > 4095", "48 channels"],  # 9
                  ["umask"],  # 10
                  ["binary shape", "binary config", "write error", "S99Z", "negative force",
                   "--out in a missing folder"],  # 11
                  ["5% garbage + 5% CRC flips + 2% drops"]):
        for word in words:
            assert word in names, word


def test_every_item_of_issue_25_has_cases(matrix):
    names = " | ".join(matrix.CASES)
    for word in ("onto its input", "two recorders on one --out", "ulimit -f", "2 GB sparse CSV", "NUL byte",
                 "symlink loop", "sent twice (same seq)", "clock steps back", "protocol version 2", "SIGSTOP",
                 "two servos on ID 1", "--baud 99999999999", "mu1 < 0"):
        assert word in names, word
    assert len(matrix.CASES) >= 46 + 13  # the board, recording, file and servo faults' 46 kept
    for word in ("restore checked whole", "restore refused midway"):  # servo settings checked against the servos
        assert word in names, word


def test_a_case_runs_end_to_end_and_the_figure_is_printed():
    done = subprocess.run([sys.executable, "scripts/fault_matrix.py", "--only", "--out in a missing folder"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stdout + done.stderr
    assert "cases tried / handled cleanly: 1 / 1" in done.stdout
    assert done.stdout.startswith("ok ") and "cannot create recording" in done.stdout


HOSTILE_WORDS = ("FIFO or a link to one, a socket, a device node", "killed writer's temporary", "full disk", "TOML",
                 "wrong shape or type", "200 flipped bytes", "symlink loop", "ulimit -v", "6000 digits",
                 "play --log onto its shape")


def test_every_hostile_input_case_is_handled_cleanly(matrix, tmp_path):
    """The hostile-input cases (outputs that are no regular file, stale temporaries, a full disk, TOML and HDF5
    files no reader should trust, a symlink loop as input, fit under address-space limits) run here in full: they
    call the command in this process where they can, ~20 s in all."""
    names = [name for name in matrix.CASES if name.startswith("hostile:")]
    for words in HOSTILE_WORDS:
        assert any(words in name for name in names), words
    failures = []
    for k, name in enumerate(names):
        folder = tmp_path / f"case{k}"
        folder.mkdir()
        outcome = matrix.CASES[name](folder)
        if not outcome.ok:
            failures.append(f"{name}: {outcome.note}")
    assert not failures, "\n".join(failures)
