"""The run catalog: runs list/show/reindex over synthetic recordings; the files stay the truth."""

from __future__ import annotations

import csv
import io
import json
import os
import time

import h5py

from app.cli.main import main
from app.core.catalog import Catalog, catalog_path
from app.core.recorder import Recorder
from tests.app.synthetic_trials import CHANNELS, write_trial


def _csv(capsys):
    return list(csv.DictReader(io.StringIO(capsys.readouterr().out)))


def test_where_lists_exactly_the_matching_recordings_as_csv(tmp_path, capsys):
    folder = tmp_path / "runs"
    (folder / "sub").mkdir(parents=True)
    write_trial(folder / "a.h5", scene="paper_obstacle", duration_s=3)
    write_trial(folder / "sub" / "b.h5", scene="paper_obstacle", outcome="not traversed", duration_s=3)
    write_trial(folder / "c.h5", scene="step", duration_s=3)
    write_trial(folder / ".hidden.h5.123.partial.h5", scene="paper_obstacle", duration_s=3)  # a writer's temporary
    assert main(["runs", "list", "--dir", str(folder), "--where", "scene=paper_obstacle", "--format", "csv"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert len(lines) == 3 and lines[0].startswith("file,started,plan_name,scene")
    rows = list(csv.DictReader(io.StringIO(out)))
    assert sorted(os.path.basename(r["file"]) for r in rows) == ["a.h5", "b.h5"]
    assert main(["runs", "list", "--dir", str(folder), "--where", "scene=paper_obstacle", "--where",
                 "outcome=not traversed", "--format", "csv"]) == 0
    assert [os.path.basename(r["file"]) for r in _csv(capsys)] == ["b.h5"]
    # the files are the truth: a file removed or added is seen by the next listing
    (folder / "a.h5").unlink()
    write_trial(folder / "d.h5", scene="paper_obstacle", duration_s=3)
    assert main(["runs", "list", "--dir", str(folder), "--where", "scene=paper_obstacle", "--format", "json"]) == 0
    assert sorted(os.path.basename(r["file"]) for r in json.loads(capsys.readouterr().out)) == ["b.h5", "d.h5"]
    assert main(["runs", "list", "--dir", str(folder), "--where", "colour=red"]) != 0
    assert "colour" in capsys.readouterr().err


def test_a_corrupt_catalog_is_rebuilt_and_old_recordings_are_indexed_with_what_they_say(tmp_path, capsys):
    folder = tmp_path / "runs"
    folder.mkdir()
    write_trial(folder / "new.h5", duration_s=3)
    old = write_trial(folder / "old.h5", duration_s=3, with_documents=False)  # before run documents
    with h5py.File(old, "a") as f:
        f.attrs["config"] = "# sensnake experiment obstacle: height_ratio = 0.28\n[board]\n"
        f["sim"].attrs["scene_name"] = "paper_obstacle (seed 3)"
    (folder / "junk.h5").write_bytes(b"not a recording")
    catalog_path().parent.mkdir(parents=True, exist_ok=True)
    catalog_path().write_bytes(b"this is not an SQLite database" * 100)
    assert main(["runs", "list", "--dir", str(folder), "--where", "scene=paper_obstacle", "--format", "csv"]) == 0
    captured = capsys.readouterr()
    assert "rebuilt" in captured.err
    rows = list(csv.DictReader(io.StringIO(captured.out)))
    assert sorted(os.path.basename(r["file"]) for r in rows) == ["new.h5", "old.h5"]
    old_row = next(r for r in rows if r["file"].endswith("old.h5"))
    assert old_row["plan_name"] == "experiment obstacle" and old_row["outcome"] == "traversed"
    assert main(["runs", "show", str(folder / "junk.h5")]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "junk.h5" in err
    assert main(["runs", "show", str(old)]) == 0
    assert "run_start: none" in capsys.readouterr().out


def test_a_recording_is_indexed_when_its_writer_closes_it(tmp_path, capsys):
    path = tmp_path / "live.h5"
    recorder = Recorder(path, "[board]\n", CHANNELS)
    recorder.start()
    from tests.app.test_run_documents import _block

    recorder.add_block(_block(5, recorder.t0_monotonic_s + 0.01))
    recorder.stop()
    with Catalog() as catalog:
        entry = catalog.get(path)
    assert entry is not None and entry["plan_name"] == "record" and entry["exit_status"] == "success"
    assert main(["runs", "list", "--where", "plan=record", "--format", "csv"]) == 0  # no --dir: all the app wrote
    assert str(path.resolve()) in [r["file"] for r in _csv(capsys)]


def test_since_and_numbers_filter(tmp_path, capsys):
    folder = tmp_path / "runs"
    folder.mkdir()
    write_trial(folder / "slow.h5", duration_s=2, speed_rad_s=0.034)
    write_trial(folder / "fast.h5", duration_s=2, speed_rad_s=0.05)
    assert main(["runs", "list", "--dir", str(folder), "--where", "speed=0.05", "--format", "csv"]) == 0
    assert [os.path.basename(r["file"]) for r in _csv(capsys)] == ["fast.h5"]
    tomorrow = time.strftime("%Y-%m-%d", time.localtime(time.time() + 86400))
    assert main(["runs", "list", "--dir", str(folder), "--since", tomorrow, "--format", "csv"]) == 0
    assert _csv(capsys) == []
    # a date no local clock may hold (year 1) is a time or a refusal naming --since, never another error's words
    code = main(["runs", "list", "--dir", str(folder), "--since", "0001-01-01", "--format", "csv"])
    err = capsys.readouterr().err
    assert code == 0 or "--since '0001-01-01'" in err, err
    # inf (or 1e400) matched every run (|x − inf| ≤ 1e-9·inf): refused, naming the key
    for bad in ("speed=inf", "seed=1e400", "tail_load=-inf"):
        assert main(["runs", "list", "--dir", str(folder), "--where", bad]) != 0
        assert "is a finite number" in capsys.readouterr().err
    # --since compares with the start the listing shows (the file's "started", to the millisecond), not the run
    # document's time, written up to a second before it: a --since copied from the listing kept the run
    with h5py.File(folder / "fast.h5", "r+") as f:
        f.attrs["started"] = "2026-12-06T04:11:56.356+00:00"
        start = json.loads(f.attrs["run_start"])
        start["time"] = 1796530316.05  # 2026-12-06T04:11:56.050+00:00
        f.attrs["run_start"] = json.dumps(start)
    for since, listed in (("2026-12-06T04:11:56.356+00:00", ["fast.h5"]), ("2026-12-06T04:11:56.3+00:00", ["fast.h5"]),
                          ("2026-12-06T04:11:56.357+00:00", [])):
        assert main(["runs", "list", "--dir", str(folder), "--since", since, "--where", "speed=0.05",
                     "--format", "csv"]) == 0
        assert [os.path.basename(r["file"]) for r in _csv(capsys)] == listed, since


def test_a_sync_says_how_far_it_got_and_a_cancelled_one_stops_between_files(tmp_path):
    folder = tmp_path / "runs"
    folder.mkdir()
    for index in range(5):
        write_trial(folder / f"t{index}.h5", scene="step", duration_s=1)
    told: list[tuple[int, int]] = []
    with Catalog(tmp_path / "catalog.sqlite") as catalog:
        assert catalog.sync(folder, progress=lambda done, total: told.append((done, total))) == (5, 0)
        assert told == [(0, 5), (1, 5), (2, 5), (3, 5), (4, 5), (5, 5)]  # before each file, then once at the end
        told.clear()
        assert catalog.sync(folder, progress=lambda done, total: told.append((done, total))) == (0, 0)
        assert told == []  # nothing new or changed: nothing to say
        asked = []

        def cancelled() -> bool:
            asked.append(1)
            return len(asked) > 2  # stop before the third file

        told.clear()
        assert catalog.sync(folder, force=True, cancelled=cancelled,
                            progress=lambda done, total: told.append((done, total))) == (2, 0)
        assert told == [(0, 5), (1, 5)]  # a stopped reading does not claim to have finished


def test_runs_list_on_a_terminal_shows_its_reading_then_wipes_it(tmp_path, capsys, monkeypatch):
    from app.cli import runs

    folder = tmp_path / "runs"
    folder.mkdir()
    for index in range(3):
        write_trial(folder / f"t{index}.h5", scene="step", duration_s=1)
    monkeypatch.setenv("SENSNAKE_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setattr(runs.sys.stderr, "isatty", lambda: True)
    monkeypatch.setattr(runs, "PROGRESS_EVERY_S", 0.0)
    assert main(["runs", "list", "--dir", str(folder), "--format", "csv"]) == 0
    captured = capsys.readouterr()
    assert len(list(csv.DictReader(io.StringIO(captured.out)))) == 3  # the listing itself is untouched
    assert "reading recordings: 2 of 3" in captured.err and "reading recordings: 3 of 3" in captured.err
    assert captured.err.endswith("\r") and captured.err.rstrip("\r").split("\r")[-1].strip() == ""  # wiped


def test_a_folder_that_cannot_be_read_is_said_and_its_recordings_are_not_forgotten(tmp_path, capsys, monkeypatch):
    """An unreadable folder listed as empty, silently ("0 run(s)"), and its recordings left the catalog."""
    from app.core import catalog as catalog_module

    folder = tmp_path / "runs"
    (folder / "locked").mkdir(parents=True)
    write_trial(folder / "open.h5", scene="step", duration_s=1)
    write_trial(folder / "locked" / "hidden.h5", scene="flat", duration_s=1)
    monkeypatch.setenv("SENSNAKE_DATA_DIR", str(tmp_path / "data"))
    assert main(["runs", "list", "--dir", str(folder), "--format", "csv"]) == 0
    assert len(_csv(capsys)) == 2
    scandir = os.scandir

    def refusing(path):  # what a folder without read permission does (root bypasses chmod, so it is pretended)
        if os.fspath(path).endswith("locked"):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return scandir(path)

    monkeypatch.setattr(catalog_module.os, "scandir", refusing)
    assert main(["runs", "list", "--dir", str(folder), "--format", "csv"]) == 0
    captured = capsys.readouterr()
    # the catalog still holds what the folder hid (the file is there); the note says the folder was not read
    assert sorted(os.path.basename(r["file"]) for r in csv.DictReader(io.StringIO(captured.out))) == \
        ["hidden.h5", "open.h5"]
    assert "1 folder(s) could not be read" in captured.err and "locked (Permission denied)" in captured.err
    (folder / "open.h5").unlink()
    assert main(["runs", "list", "--dir", str(folder), "--format", "csv"]) == 0
    assert [os.path.basename(r["file"]) for r in _csv(capsys)] == ["hidden.h5"]  # a file really gone is forgotten
