"""The record a tuning or an evaluation keeps in its --out folder, read back on a resume: anything but the JSON object
it wrote is one line naming the file and saying to choose another folder (a list or a deep nesting was a traceback)."""

from __future__ import annotations

import os
import sys

import pytest

from app.core.engines import read_folder_record
from app.core.errors import EvaluationError, TuneError


@pytest.mark.parametrize("text", ["[1, 2]", "[" * 100_000, '{"sha256": ' + "7" * 5000 + "}", "{not json", "\udcff"])
@pytest.mark.parametrize("error", [TuneError, EvaluationError])
def test_anything_but_the_object_written_is_one_line_naming_the_file(tmp_path, text, error):
    record = tmp_path / "tune.json"
    record.write_bytes(text.encode("utf-8", "surrogateescape"))
    with pytest.raises(error) as refused:
        read_folder_record(record, "tuning folder's record", error)
    message = str(refused.value)
    assert str(record) in message and message.endswith("choose another --out folder") and "\n" not in message


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="FIFOs (POSIX)")
@pytest.mark.timeout(10)
def test_a_fifo_at_the_record_is_refused_at_once(tmp_path):
    record = tmp_path / "evaluation.json"
    os.mkfifo(record)
    with pytest.raises(EvaluationError, match="choose another --out folder"):
        read_folder_record(record, "evaluation folder's record", EvaluationError)


def test_the_object_written_reads_back(tmp_path):
    record = tmp_path / "tune.json"
    record.write_text('{"kind": "tune", "sha256": "ab"}', encoding="utf-8")
    assert read_folder_record(record, "tuning folder's record", TuneError) == {"kind": "tune", "sha256": "ab"}
