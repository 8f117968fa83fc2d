"""Truncated recordings are salvaged (``sensnake repair`` and recovery on open), saying how much was recovered;
nothing past the cut is guessed."""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest

from app.cli import main
from app.core.errors import RecordingFormatError
from app.core.recording import RecordingWriter, open_recording, recover_recording
from devices.board import SampleBlock, conductance_from_counts
from devices.config import BoardConfig, default_sensor_names
from models.sls import ForceStatus

CHANNELS = default_sensor_names()


def counts_for(seq: np.ndarray) -> np.ndarray:
    return ((seq[:, None] * 7 + np.arange(len(CHANNELS))) % 4095 + 1).astype(np.uint16)


def status_for(seq: np.ndarray) -> np.ndarray:
    """Every 7th sample's S01L flagged at the readout's ceiling."""
    status = np.zeros((len(seq), len(CHANNELS)), np.int8)
    status[seq % 7 == 0, 0] = ForceStatus.READOUT_SATURATED
    return status


def write_recording(path, blocks: int = 100, rows: int = 30) -> None:
    t0 = time.monotonic()
    with RecordingWriter(path, "[board]\n", CHANNELS, calibration_json="{}", flush_interval_s=0.0,
                         t0_monotonic_s=t0) as writer:
        for k in range(blocks):
            seq = (np.arange(rows) + rows * k).astype(np.uint32)
            counts = counts_for(seq)
            writer.append_daq(SampleBlock(counts, conductance_from_counts(counts, BoardConfig()), seq / 30.0,
                                          t0 + seq / 30.0, seq, counts == 0))
            writer.append_forces(np.full((rows, len(CHANNELS)), float(k)), status_for(seq))
            if k % 10 == 0:
                writer.log_event(f"block {k}")


@pytest.fixture(scope="module")
def good_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "good.h5"
    write_recording(path)
    return path


def truncate(good, tmp_path, fraction: float):
    data = good.read_bytes()
    cut = tmp_path / f"cut{fraction}.h5"
    cut.write_bytes(data[: int(len(data) * fraction)])
    return cut


@pytest.mark.parametrize("fraction", [0.999, 0.9, 0.5])
def test_truncated_file_is_salvaged_with_only_intact_rows(good_file, tmp_path, fraction):
    cut = truncate(good_file, tmp_path, fraction)
    with pytest.raises(RecordingFormatError, match="sensnake repair"):
        open_recording(cut)  # strict by default: a command never reads a damaged file without saying so
    rec, report = recover_recording(cut)
    got, claimed = report.rows["daq"]
    assert claimed == 3000 and 0 < got <= 3000
    if fraction >= 0.999:
        assert got >= 2900
    assert rec.n_samples == got
    # What is recovered is exact: nothing from the zero-padded tail.
    np.testing.assert_array_equal(rec.seq, np.arange(got))
    np.testing.assert_array_equal(rec.counts, counts_for(rec.seq.astype(np.int64)))
    assert "recovered" in report.text and f"{got} of 3000" in report.text
    if rec.forces_status is not None:  # the status column is kept with the forces it flags, or dropped, never cut
        np.testing.assert_array_equal(rec.forces_status, status_for(rec.seq[:len(rec.forces_status)].astype(np.int64)))
    assert open_recording(cut, recover=True).recovery == report.text


def test_repair_command_writes_a_clean_file_and_says_how_much(good_file, tmp_path, capsys):
    cut = truncate(good_file, tmp_path, 0.95)
    before = cut.read_bytes()
    fixed = tmp_path / "fixed.h5"
    assert main(["repair", str(cut), "--out", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "recovered" in out and "board samples" in out and str(fixed) in out
    assert cut.read_bytes() == before  # the damaged original is never changed
    with h5py.File(fixed, "r") as f:  # a plain reader opens the repaired file
        n = f["daq/seq"].shape[0]
        assert f["daq/counts"].shape == (n, 36) and f.attrs["format"] == "sensnake-recording"
    rec = open_recording(fixed)
    assert rec.n_samples == n > 0 and rec.recovery is None
    assert rec.forces_status is not None  # the flags survive the repair with the forces
    np.testing.assert_array_equal(rec.forces_status, status_for(rec.seq[:len(rec.forces_n)].astype(np.int64)))
    assert main(["export", str(fixed), "--csv", str(tmp_path / "fixed.csv")]) == 0


def test_repair_of_an_intact_file_copies_it_and_says_so(good_file, tmp_path, capsys):
    out = tmp_path / "copy.h5"
    assert main(["repair", str(good_file), "--out", str(out)]) == 0
    assert "not damaged" in capsys.readouterr().out
    assert open_recording(out).n_samples == 3000


def test_repair_of_a_non_hdf5_file_is_one_line(tmp_path, capsys):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"\x00" * 1000)
    assert main(["repair", str(junk)]) == 1
    err = capsys.readouterr().err
    assert "junk.h5" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def killed_mid_flush(good, tmp_path):
    """``good`` as a writer killed in the middle of a flush leaves it (seen in CI: kill -9 of ``sensnake record``):
    the chunk index already points at the last data chunk of /daq/counts, but the superblock's end-of-allocation
    was not moved past it (HDF5: "addr overflow, addr = …, eoa = …"). The file opens; that chunk does not read."""
    with h5py.File(good, "r") as f:
        counts = f["daq/counts"].id
        last = max(counts.get_chunk_info(i).byte_offset for i in range(counts.get_num_chunks()))
    data = bytearray(good.read_bytes())
    assert data[8] == 0  # superblock version 0 (no checksum): its end-of-allocation address is at 24 + 2 offsets
    size = data[13]
    data[24 + 2 * size:24 + 3 * size] = last.to_bytes(size, "little")
    bad = tmp_path / "killed.h5"
    bad.write_bytes(bytes(data))
    return bad


def test_a_file_killed_in_the_middle_of_a_flush_is_refused_with_the_repair_hint_and_salvaged_exactly(good_file,
                                                                                                      tmp_path):
    bad = killed_mid_flush(good_file, tmp_path)
    with h5py.File(bad, "r") as f:  # plain h5py opens it ...
        assert f["daq/seq"].shape[0] == 3000
        with pytest.raises(OSError):
            f["daq/counts"][:]  # ... but its last chunk lies past the end the superblock claims
    with pytest.raises(RecordingFormatError, match="sensnake repair"):
        open_recording(bad)  # strict: a command names the damage and the way out (it said neither)
    rec = open_recording(bad, recover=True)  # what the GUI does: it used to refuse this file
    assert 2500 < rec.n_samples < 3000 and "cut off in the middle of a write" in rec.recovery
    np.testing.assert_array_equal(rec.seq, np.arange(rec.n_samples))  # whole chunks only, nothing guessed
    assert main(["repair", str(bad), "--out", str(tmp_path / "fixed.h5")]) == 0
    assert open_recording(tmp_path / "fixed.h5").n_samples == rec.n_samples


@pytest.mark.usefixtures("sim_lab_fast")
def test_the_forces_tab_opens_a_truncated_recording_saying_how_much_was_recovered(good_file, tmp_path, qtbot,
                                                                                   monkeypatch):
    """The GUI face of the salvage: Open recording… shows the intact rows, says how much survived, points at
    ``sensnake repair``; the damaged file is not changed."""
    from app.gui.lab import LabContext
    from app.gui.tabs.forces import create_tab
    from devices.config import LabConfig

    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    cut = truncate(good_file, tmp_path, 0.9)
    before = cut.read_bytes()
    _rec, report = recover_recording(cut)
    lab = LabContext(LabConfig())
    tab = create_tab(lab)
    qtbot.addWidget(tab)
    try:
        shown = tab.open_recording_file(cut)
        assert shown is not None and tab.viewed is shown
        assert shown.n_samples == report.rows["daq"][0] < 3000
        np.testing.assert_array_equal(shown.counts, counts_for(shown.seq.astype(np.int64)))
        message = tab.controls.message.text()
        assert report.text in message and "sensnake repair" in message, message
        assert len(tab.plots.history) == shown.n_samples
    finally:
        tab.shutdown()
        lab.close()
    assert cut.read_bytes() == before


def test_repair_keeps_what_it_does_not_model_the_physics_labs_sim_and_control(good_file, tmp_path, capsys):
    """An intact recording was rewritten from what the reader models (board, robot, forces, events): the physics
    lab's /sim, /control and /mocap were dropped while it said "not damaged ... copied". Now it is copied as it is;
    a salvaged copy is given the source's other groups that read whole, and says which."""
    from app.core.recording import carry_groups

    source = tmp_path / "with_sim.h5"
    source.write_bytes(good_file.read_bytes())
    with h5py.File(source, "a") as f:
        f.create_group("sim").create_dataset("time_s", data=np.arange(10.0))
        f.create_group("control").attrs["controller"] = "feedback"
    out = tmp_path / "copy.h5"
    assert main(["repair", str(source), "--out", str(out)]) == 0
    assert "everything else in it copied as it is" in capsys.readouterr().out
    assert out.read_bytes() == source.read_bytes()
    salvaged = tmp_path / "salvaged.h5"
    assert main(["repair", str(truncate(good_file, tmp_path, 0.95)), "--out", str(salvaged)]) == 0
    assert carry_groups(source, salvaged) == (["/control", "/sim"], [])
    with h5py.File(salvaged, "r") as f:
        np.testing.assert_array_equal(f["sim/time_s"][:], np.arange(10.0))
        assert f["control"].attrs["controller"] == "feedback"
