"""Run documents (bluesky-shaped ``run_start``/``run_stop`` root attributes) on every recording written."""

from __future__ import annotations

import json
import time

import h5py
import numpy as np
import pytest

from app.core.recorder import Recorder
from app.core.run_documents import (
    condition,
    condition_differences,
    read_documents,
    run_start_document,
    run_stop_document,
    text_hash,
)
from devices.board import SampleBlock, conductance_from_counts
from devices.config import BoardConfig, default_sensor_names

CHANNELS = default_sensor_names()


def _block(n: int, host_t0: float) -> SampleBlock:
    counts = np.full((n, len(CHANNELS)), 2000, np.uint16)
    seq = np.arange(n, dtype=np.uint32)
    return SampleBlock(counts=counts, conductance_s=conductance_from_counts(counts, BoardConfig()),
                       board_time_s=seq / 30.0, host_time_s=host_t0 + seq / 30.0, seq=seq, saturated=counts == 0)


@pytest.mark.parametrize(("how", "status"), [((), "success"), (("abort", "interrupted"), "abort")])
def test_a_live_recording_starts_with_its_run_start_and_ends_with_its_run_stop(tmp_path, how, status):
    path = tmp_path / "live.h5"
    t0 = time.monotonic()
    recorder = Recorder(path, "[board]\nrate_hz = 30\n", CHANNELS, calibration_json='{"sensors": {}}',
                        t0_monotonic_s=t0)
    recorder.start()
    recorder.add_block(_block(10, t0 + 0.01))
    recorder.stop(*how)
    start, stop = read_documents(path)
    assert start is not None and stop is not None
    assert start["plan_name"] == "record" and start["uid"] == stop["run_start"]
    assert start["condition"]["config_hash"] == text_hash("[board]\nrate_hz = 30\n")
    assert start["condition"]["calibration_hash"] == text_hash('{"sensors": {}}')
    assert start["condition"]["scene"] is None  # a live recording does not guess what was played
    assert stop["exit_status"] == status
    assert stop["reason"] == ("interrupted" if how else "")
    with h5py.File(path) as f:  # plain JSON text, readable by any tool
        assert json.loads(f.attrs["run_start"])["app_version"]


def test_a_recording_cut_short_has_its_run_start_and_no_run_stop(tmp_path):
    from app.core.recording import RecordingWriter

    start = run_start_document("record", condition(config_text="x"))
    writer = RecordingWriter(tmp_path / "cut.h5", "x", CHANNELS, run_start=start)
    writer.append_daq(_block(5, writer.t0_monotonic_s))
    writer.flush()  # on disk as a crash would leave it: the writer never closed
    got_start, got_stop = read_documents(tmp_path / "cut.h5")
    assert got_start == start and got_stop is None
    writer.close()


def test_documents_hold_no_nan_and_conditions_name_their_differences():
    first = condition(scene="paper_obstacle", speed_rad_s=0.034, tail_load_n=float("nan"), calibration_json="a")
    other = condition(scene="paper_obstacle", speed_rad_s=0.05, calibration_json="b")
    assert first["tail_load_n"] is None  # NaN is unknown: JSON has no NaN
    assert "NaN" not in json.dumps(run_start_document("p", first), allow_nan=False)
    # the calibration is not the condition (each simulated trial has its own sensors)
    assert condition_differences(first, other) == ["speed_rad_s 0.034 ≠ 0.05"]
    assert condition_differences(first, None) == []
    with pytest.raises(ValueError, match="exit_status"):
        run_stop_document(None, "ok")


def test_a_repaired_copy_keeps_the_run_it_was(tmp_path):
    from app.cli.main import main
    from app.core.recording import RecordingWriter

    start = run_start_document("record", condition(config_text="x"), note="kept")
    writer = RecordingWriter(tmp_path / "cut.h5", "x", CHANNELS, run_start=start)
    writer.append_daq(_block(5, writer.t0_monotonic_s))
    writer.flush()  # cut short: no run_stop
    assert main(["repair", str(tmp_path / "cut.h5"), "--out", str(tmp_path / "fixed.h5")]) == 0
    assert read_documents(tmp_path / "fixed.h5") == (start, None)
    writer.close()


def test_sensnake_record_keeps_the_operators_note(install_sim_device, tmp_path):
    from app.cli.main import main
    from devices.config import LabConfig
    from devices.sim.board import VirtualBoard
    from devices.sim.clock import SimClock
    from devices.sim.contact import ContactModel

    config = LabConfig()
    install_sim_device("board", VirtualBoard(config.board, SimClock(20.0), ContactModel(config, None, seed=5).forces_n,
                                             seed=6))
    out = tmp_path / "noted.h5"
    assert main(["record", "--daq", "sim", "--seconds", "1", "--note", "S10B re-taped", "--out", str(out)]) == 0
    start, stop = read_documents(out)
    assert start["note"] == "S10B re-taped" and start["plan_name"] == "record"
    assert stop["exit_status"] == "success"
