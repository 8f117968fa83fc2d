"""The calibration history (``calibration_history.jsonl`` in the calibrations folder) is appended to a regular file
only: a symbolic link or a FIFO planted at its name is refused naming it, never followed or waited on."""

from __future__ import annotations

import os
import sys
from types import SimpleNamespace

import pytest

from app.core.calibration_fit import HISTORY_FILE, append_history, read_history
from app.core.errors import OutputPathError
from models.sls import TYPICAL_SLS


def _fit(sensor: str = "S06B") -> SimpleNamespace:
    calibration = SimpleNamespace(sls=TYPICAL_SLS, linear=None, force_range_n=(1.75, 5.25))
    return SimpleNamespace(sensor=sensor, calibration=calibration, trial_files=("t1.csv",),
                           unloaded_conductance_s=1e-6, problems=())


def test_two_saves_are_two_lines_of_the_sensors_history(tmp_path):
    append_history(tmp_path, _fit(), tmp_path / "cal.json")
    append_history(tmp_path, _fit(), tmp_path / "cal.json")
    append_history(tmp_path, _fit("S01L"), tmp_path / "cal.json")
    history = read_history(tmp_path, "S06B")
    assert len(history) == 2 and history[0]["sls"] == TYPICAL_SLS.to_dict()


def test_a_link_planted_at_the_history_is_refused_and_its_target_untouched(tmp_path):
    target = tmp_path / "someone_elses.txt"
    target.write_text("theirs\n", encoding="utf-8")
    (tmp_path / HISTORY_FILE).symlink_to(target)
    with pytest.raises(OutputPathError, match="symbolic link"):
        append_history(tmp_path, _fit(), tmp_path / "cal.json")
    assert target.read_text(encoding="utf-8") == "theirs\n"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="FIFOs (POSIX)")
@pytest.mark.timeout(10)  # the old open() waited for a reader for ever
def test_a_fifo_planted_at_the_history_is_refused_at_once(tmp_path):
    os.mkfifo(tmp_path / HISTORY_FILE)
    with pytest.raises(OutputPathError, match="FIFO"):
        append_history(tmp_path, _fit(), tmp_path / "cal.json")
