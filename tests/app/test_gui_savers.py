"""The GUI's savers of a file the user names: bad input is one line on the tab, an existing file is replaced only
when the user confirmed it in the save dialog, and nothing half-written is ever left (no hidden temporary either)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from app.core import event_log
from app.core.outputs import write_new_file
from app.gui.lab import LabContext
from app.gui.tabs import forces
from app.gui.tabs.forces import create_tab
from devices.config import LabConfig
from tests.app.test_view_export import make_recording

pytestmark = pytest.mark.usefixtures("sim_lab_fast")


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture
def tab(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    lab = LabContext(LabConfig())
    tab = create_tab(lab)
    qtbot.addWidget(tab)
    tab.resize(1200, 900)
    tab.show()
    tab.viewed = make_recording(with_robot=False)  # a 2-joint robot would not fit this lab's body map
    yield tab
    tab.shutdown()
    lab.close()


@pytest.fixture
def targets(tmp_path: Path) -> dict[str, Path]:
    """Paths no export may write through: name → path (each a .png; the CSV test renames them)."""
    folder = tmp_path / "out"
    folder.mkdir()
    fifo = folder / "pipe.png"
    os.mkfifo(fifo)  # Qt's open of it would wait for a reader for ever
    (folder / "dir.png").mkdir()
    return {"fifo": fifo, "folder": folder / "dir.png", "missing folder": folder / "nowhere" / "x.png"}


def message(tab) -> str:
    return tab.controls.message.text()


@pytest.mark.parametrize("suffix", ["png", "svg"])
def test_an_image_export_never_replaces_a_file_unconfirmed_and_replaces_one_confirmed(tab, tmp_path, suffix):
    out = tmp_path / f"seg.{suffix}"
    out.write_text("someone's figure")
    assert tab.export_plot_image(5, out) is None
    assert "exists" in message(tab) and str(out) in message(tab)
    assert out.read_text() == "someone's figure"
    assert tab.export_plot_image(5, out, replace=True) == out
    assert out.stat().st_size > 100 and out.read_bytes() != b"someone's figure"
    assert hidden(tmp_path) == []


def test_an_image_export_through_a_link_replaces_the_link_never_the_file_it_leads_to(tab, tmp_path):
    other = tmp_path / "notes.txt"
    other.write_text("keep me")
    link = tmp_path / "fig.png"
    link.symlink_to(other)
    assert tab.export_plot_image(-1, link) is None and "exists" in message(tab)
    assert tab.export_plot_image(-1, link, replace=True) == link
    assert not link.is_symlink() and link.read_bytes().startswith(b"\x89PNG")
    assert other.read_text() == "keep me"


def test_an_image_export_to_a_fifo_a_folder_or_a_missing_folder_is_one_line(tab, targets, tmp_path):
    for name, path in targets.items():
        for replace in (False, True):
            assert tab.export_plot_image(5, path, replace=replace) is None, name
            line = message(tab)
            assert line.startswith("image not saved: ") and str(path) in line and "\n" not in line, (name, line)
            assert ".partial" not in line, line  # the user's file named, never the temporary
    assert tab.export_plot_image(5, targets["fifo"], replace=True) is None and "FIFO" in message(tab)
    assert hidden(tmp_path / "out") == []


def test_a_failed_image_write_leaves_the_old_file_and_no_temporary(tab, tmp_path, monkeypatch):
    out = tmp_path / "body.png"
    out.write_text("the old figure")

    def fail_midway(_widget, path, *_args):
        Path(path).write_bytes(b"\x89PNG half")  # Qt's writer stopped part way (a full disk)
        raise OSError(f"cannot write {path}")  # what the widget then says

    monkeypatch.setattr(forces, "save_widget_image", fail_midway)
    assert tab.export_plot_image(-1, out, replace=True) is None
    assert f"cannot write {out}" in message(tab)
    assert out.read_text() == "the old figure" and hidden(tmp_path) == []


def test_the_image_dialog_replaces_what_it_confirmed_and_keeps_a_file_it_never_showed(tab, tmp_path, monkeypatch):
    shown = tmp_path / "fig.png"
    shown.write_text("old")
    monkeypatch.setattr(forces.QFileDialog, "getSaveFileName", lambda *a, **k: (str(shown), ""))
    tab._choose_image(5, "png")  # the dialog asked "replace?" and the user said yes
    assert shown.read_bytes().startswith(b"\x89PNG")
    shown.write_text("old")
    # Typed without a suffix: the dialog checked "fig", not "fig.png", so fig.png is kept.
    monkeypatch.setattr(forces.QFileDialog, "getSaveFileName", lambda *a, **k: (str(tmp_path / "fig"), ""))
    tab._choose_image(5, "png")
    assert shown.read_text() == "old" and "exists" in message(tab)


def test_a_csv_export_never_replaces_a_file_unconfirmed_and_refuses_what_is_no_file(tab, targets, tmp_path,
                                                                                     monkeypatch):
    out = tmp_path / "view.csv"
    out.write_text("someone's table")
    assert tab.export_viewed_csv(out) is None
    assert "exists" in message(tab) and out.read_text() == "someone's table"
    monkeypatch.setattr(forces.QFileDialog, "getSaveFileName", lambda *a, **k: (str(out), ""))
    tab._choose_export()  # confirmed in the dialog
    assert out.read_text().startswith("time_s,")
    for name, path in targets.items():
        csv_path = path.with_suffix(".csv")
        if name == "fifo":
            os.mkfifo(csv_path)
        elif name == "folder":
            csv_path.mkdir()
        for replace in (False, True):
            assert tab.export_viewed_csv(csv_path, replace=replace) is None, name
            line = message(tab)
            assert line.startswith("not exported: ") and str(csv_path) in line and "\n" not in line, (name, line)
    assert hidden(tmp_path) == [] and hidden(tmp_path / "out") == []


def test_a_new_file_is_written_whole_or_not_at_all_and_never_over_anything(tmp_path, monkeypatch):
    out = tmp_path / "events.csv"
    assert write_new_file(out, b"a,b\n", "kept") == out and out.read_bytes() == b"a,b\n"
    with pytest.raises(FileExistsError, match=f"{out} exists: kept"):
        write_new_file(out, b"other", "kept")
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    dangling = tmp_path / "link.csv"
    dangling.symlink_to(tmp_path / "elsewhere.csv")  # writing through it would create a file elsewhere
    for path, words in ((fifo, "is a FIFO"), (tmp_path, "is a folder"), (dangling, "exists"),
                        (tmp_path / "no" / "x.csv", "the folder")):
        with pytest.raises(OSError) as raised:
            write_new_file(path, b"x", "kept")
        assert str(path) in str(raised.value) and words in str(raised.value), raised.value
    assert not (tmp_path / "elsewhere.csv").exists()

    def full_disk(_fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match=f"cannot write {tmp_path / 'new.csv'}: No space left"):
        event_log.write_csv([], tmp_path / "new.csv")
    assert not (tmp_path / "new.csv").exists() and hidden(tmp_path) == []
    assert out.read_bytes() == b"a,b\n"
