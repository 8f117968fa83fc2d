"""The GUI's Forces tab records the independent board emulator's noisy link (5 % garbage, 5 % CRC flips, 2 % drops)
to the end with every good frame exact — through the same core code as ``sensnake record``
(:meth:`app.core.live_session.LiveSession.process_block` → :class:`app.core.recorder.Recorder`)."""

from __future__ import annotations

import sys
from dataclasses import replace

import pytest

from app.core.live_session import LiveSession
from app.core.recorder import Recorder
from app.core.recording import open_recording
from app.gui.lab import LabContext
from app.gui.tabs.forces import create_tab
from devices.config import LabConfig
from tests.app.test_record_emulated import assert_exact_and_complete
from tests.emulators.board_emulator import EmulatedBoard

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux pseudo-terminals"),
              pytest.mark.usefixtures("sim_lab_fast")]

RATE_HZ = 200.0


@pytest.fixture
def core_calls(monkeypatch):
    """Counts the core's data-path calls, whichever face makes them."""
    calls = {"process_block": 0, "add_block": 0}
    process, add = LiveSession.process_block, Recorder.add_block

    def counted_process(self, block):
        calls["process_block"] += 1
        return process(self, block)

    def counted_add(self, block, force_n=None):
        calls["add_block"] += 1
        return add(self, block, force_n)

    monkeypatch.setattr(LiveSession, "process_block", counted_process)
    monkeypatch.setattr(Recorder, "add_block", counted_add)
    return calls


def test_gui_records_a_noisy_link_with_every_good_frame_exact(qtbot, tmp_path, monkeypatch, core_calls):
    monkeypatch.setenv("SENSNAKE_RECORDINGS_DIR", str(tmp_path / "recordings"))
    out = tmp_path / "gui.h5"
    with EmulatedBoard(tmp_path, rate_hz=RATE_HZ, garbage=0.05, crc_flip=0.05, drop=0.02, seed=7) as emu:
        defaults = LabConfig()
        lab = LabContext(replace(defaults, board=replace(defaults.board, port=emu.path, rate_hz=RATE_HZ)))
        tab = create_tab(lab)
        qtbot.addWidget(tab)
        try:
            with qtbot.waitSignal(lab.board.connected, timeout=10_000):
                lab.board.start()
            session = tab.start_recording(out)
            assert session is not None and tab.live.recorder is session.recorder
            qtbot.waitUntil(lambda: session.n_daq_samples >= 2 * RATE_HZ, timeout=20_000)
            qtbot.waitUntil(lambda: lab.board.stats.crc_errors > 0, timeout=10_000)
            tab.stop_recording()
            assert not session.error
        finally:
            tab.shutdown()
            lab.close()
        log = emu.stop()
    rec = open_recording(out)
    seqs = assert_exact_and_complete(rec, log)
    assert seqs.size >= 1.8 * RATE_HZ
    assert rec.crc_errors > 0 and rec.resyncs > 0
    assert rec.forces_n is None  # no calibration loaded: the recording keeps conductance, never made-up newtons
    # The GUI went through the core's data path, block by block.
    assert core_calls["process_block"] >= 1 and core_calls["add_block"] >= 1


def test_cli_records_through_the_same_core_calls(tmp_path, core_calls, capsys):
    from app.cli import main

    config = tmp_path / "lab.toml"
    config.write_text(f"[board]\nrate_hz = {RATE_HZ}\n")
    with EmulatedBoard(tmp_path, rate_hz=RATE_HZ, garbage=0.05, crc_flip=0.05, drop=0.02, seed=8) as emu:
        assert main(["record", "--daq", emu.path, "--seconds", "1", "--out", str(tmp_path / "cli.h5"),
                     "--config", str(config)]) == 0
    capsys.readouterr()
    assert core_calls["process_block"] >= 1 and core_calls["add_block"] == core_calls["process_block"]
