"""devices.toml_files: a TOML file a user names can neither hang, exhaust nor crash its reader."""

from __future__ import annotations

import os

import pytest

from devices.errors import SceneError
from devices.scene import MAX_OBSTACLES, load_scene
from devices.toml_files import MAX_TOML_BYTES, read_toml_file


@pytest.mark.parametrize(("text", "words"), [
    (f"[ground]\nfriction = {'9' * 400}\n", "'ground.friction' is a 400-digit integer"),  # was an OverflowError
    (f"[ground]\nfriction = {'9' * 5000}\n", "more than 4300 digits"),  # was Python's words without the file
    ("x = " + "[" * 200_000 + "]" * 200_000 + "\n", "nested too deeply"),  # was a RecursionError
    ("[ground\n", "not valid TOML"),
    ("[ground]\nfriction = 0.3\n" + "".join(f'[[obstacle]]\nshape = "box"\nx_m = {k * 0.0002:.4f}\nlength_m = 0.01\n'
                                            f"height_m = 0.01\n" for k in range(10_000)), f"at most {MAX_OBSTACLES}"),
])
def test_a_hostile_scene_is_one_error_naming_the_file(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SceneError) as raised:
        load_scene(path)
    assert str(raised.value).startswith(f"{path}:") and words in str(raised.value), raised.value


def test_only_a_regular_file_of_at_most_1_mb_is_read(tmp_path):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)  # its open would wait for a writer for ever
    zero = tmp_path / "zero.toml"
    zero.symlink_to("/dev/zero")  # reads for ever
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * MAX_TOML_BYTES + "\n", encoding="utf-8")
    for path, words in ((fifo, "is a FIFO (named pipe), not a scene file"),
                        (zero, "is a character device, not a scene file"), (big, "larger than 1 MB"),
                        (tmp_path, "is a folder")):
        with pytest.raises(SceneError, match=words.replace("(", r"\(").replace(")", r"\)")):
            load_scene(path)


def test_a_gains_file_with_gains_at_the_top_and_in_feedback_is_refused_naming_both(tmp_path):
    from app.core.experiment import read_gains
    from models.errors import GainsError

    path = tmp_path / "gains.toml"
    path.write_text("push_gain = 0.3\n[feedback]\ntarget_n = 6.0\n", encoding="utf-8")
    with pytest.raises(GainsError, match=r"gains.toml: gains both at the top level \(push_gain\) and in \[feedback\]"):
        read_gains(path)
    path.write_text("[feedback]\ntarget_n = 6.0\n", encoding="utf-8")
    assert read_gains(path).target_n == 6.0


def test_a_valid_file_reads_as_its_text_and_table(tmp_path):
    path = tmp_path / "ok.toml"
    path.write_text("a = 1\n[b]\nc = [1.5, 2]\n", encoding="utf-8")
    assert read_toml_file(path, "test file") == ("a = 1\n[b]\nc = [1.5, 2]\n", {"a": 1, "b": {"c": [1.5, 2]}})
