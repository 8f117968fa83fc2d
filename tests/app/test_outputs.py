"""app.core.outputs: an output only ever replaces a regular file; temporaries are created exclusively and a killed
writer's are removed by the next writer of that output."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from app.core import calfiles
from app.core.errors import OutputPathError
from app.core.outputs import check_output, create_temporary, move_into_place, remove_stale_temporaries

ROOT = Path(__file__).resolve().parents[2]


def test_a_fifo_a_link_to_one_a_folder_and_a_link_loop_are_refused_naming_what_they_are(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    link = tmp_path / "link.csv"
    link.symlink_to(fifo)
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    for path, words in ((fifo, "is a FIFO (named pipe), not a regular file"),
                        (link, f"is a symbolic link to {fifo}, a FIFO (named pipe)"),
                        (tmp_path, "is a folder"), (tmp_path / "a", "symbolic link loop")):
        with pytest.raises(OutputPathError, match=words.replace("(", r"\(").replace(")", r"\)")):
            check_output(path)
    assert check_output(tmp_path / "new.csv") == tmp_path / "new.csv"  # missing: fine
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    check_output(tmp_path / "dangling")  # a dangling link: a new file takes its place


def test_a_writer_never_replaces_a_fifo_even_one_made_while_it_wrote(tmp_path):
    fifo = tmp_path / "out.csv"
    os.mkfifo(fifo)
    with pytest.raises(OutputPathError, match="FIFO"):
        calfiles.write_atomically(fifo, lambda handle: handle.write("x\n"))
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    target = tmp_path / "late.csv"
    fd, work = create_temporary(target)
    os.close(fd)
    os.mkfifo(target)  # appears between the start of the work and its move into place
    with pytest.raises(OutputPathError):
        move_into_place(work, target)
    assert stat.S_ISFIFO(os.stat(target).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == [work.name]


def test_temporaries_are_exclusive_and_a_killed_writers_are_removed_by_the_next_writer(tmp_path):
    out = tmp_path / "rec.h5"
    killed = subprocess.run([sys.executable, "-c", "import os, sys\nfrom app.core.outputs import create_temporary\n"
                             "create_temporary(sys.argv[1])\nos.kill(os.getpid(), 9)", str(out)], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=60)
    assert killed.returncode == -9
    (stale,) = tmp_path.iterdir()
    assert stale.name.startswith(".rec.h5.") and stale.name.endswith(".partial")
    live = tmp_path / f".rec.h5.{os.getpid()}.00aa11bb.partial"  # this process's: alive
    live.write_bytes(b"")
    other = tmp_path / f".other.h5.{2**31 - 1}.00aa11bb.partial"  # a dead pid, but another output's: not ours
    other.write_bytes(b"")
    fd, work = create_temporary(out)
    os.close(fd)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert stale.name not in names and live.name in names and other.name in names and work.name in names
    assert work.name.startswith(f".rec.h5.{os.getpid()}.")
    assert remove_stale_temporaries(out) == []  # nothing stale left: ours and the live one stay
