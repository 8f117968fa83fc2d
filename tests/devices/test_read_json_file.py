"""devices.toml_files.read_json_file: a JSON file a user names can neither hang, exhaust nor crash its reader; each
refusal is one line naming the file."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from devices.toml_files import read_json_file


class _Refused(ValueError):
    """The caller's own error class: the reader raises it, never another."""


def _hostile(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name → (path, the words its one line must hold)."""
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)  # its open would wait for a writer for ever
    zero = tmp_path / "zero.json"
    zero.symlink_to("/dev/zero")  # reads for ever
    folder = tmp_path / "folder.json"
    folder.mkdir()
    binary = tmp_path / "binary.json"
    binary.write_bytes(b'{"a": "\xff\xfe"}')
    twice = tmp_path / "twice.json"
    twice.write_text('{"servos": {"3": 1, "3": 2}}')
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 10_000 + "]" * 10_000)
    digits = tmp_path / "digits.json"
    digits.write_text('{"a": ' + "7" * 5_000 + "}")
    big = tmp_path / "big.json"
    big.write_text('"' + "x" * 200_000 + '"')
    broken = tmp_path / "broken.json"
    broken.write_text('{\n  "a": 1,\n}\n')
    return {"fifo": (fifo, "is a FIFO (named pipe), not a test file"),
            "device": (zero, "is a character device, not a test file"),
            "folder": (folder, "is a folder, not a test file"),
            "invalid UTF-8": (binary, "not a UTF-8 text file"),
            "repeated key": (twice, "'3' is given twice in one object"),
            "deep": (deep, "nested too deeply to be a test file"),
            "digits": (digits, "holds an integer of more than 4300 digits: not a test file"),
            "over the cap": (big, "larger than 0.1 MB, too large for a test file"),
            "invalid JSON": (broken, ":3: not valid JSON (")}  # the parser's words vary with Python's version


@pytest.mark.parametrize("name", ["fifo", "device", "folder", "invalid UTF-8", "repeated key", "deep", "digits",
                                  "over the cap", "invalid JSON"])
def test_a_hostile_file_is_one_line_naming_it(tmp_path: Path, name: str) -> None:
    path, words = _hostile(tmp_path)[name]
    with pytest.raises(_Refused) as raised:
        read_json_file(path, "test file", _Refused, max_bytes=100_000, refuse_repeated_keys=True)
    line = str(raised.value)
    assert line.startswith(str(path)) and words in line and "\n" not in line, line


def test_a_missing_file_is_named_with_the_callers_hint(tmp_path: Path) -> None:
    path = tmp_path / "nope.json"
    with pytest.raises(_Refused, match=r"nope.json: test file not found: make one first$"):
        read_json_file(path, "test file", _Refused, not_found=": make one first")


def test_a_repeated_key_is_kept_last_unless_refused(tmp_path: Path) -> None:
    path = tmp_path / "twice.json"
    path.write_text('{"a": 1, "a": 2}')
    assert read_json_file(path, "test file", _Refused) == {"a": 2}  # plain JSON's rule, for files that allow it
    with pytest.raises(_Refused, match="'a' is given twice"):
        read_json_file(path, "test file", _Refused, refuse_repeated_keys=True)


def test_a_valid_file_reads_whole_up_to_its_cap(tmp_path: Path) -> None:
    path = tmp_path / "ok.json"
    path.write_text('{"a": [1, 2.5, {"b": null}], "c": "é"}', encoding="utf-8")
    size = path.stat().st_size
    expected = {"a": [1, 2.5, {"b": None}], "c": "é"}
    assert read_json_file(path, "test file", _Refused, max_bytes=size, refuse_repeated_keys=True) == expected
    with pytest.raises(_Refused, match="too large"):
        read_json_file(path, "test file", _Refused, max_bytes=size - 1)
