"""Shape JSON (SPEC §3.4): round trip, clear errors, transforms, library folder."""

from __future__ import annotations

import json

import pytest

from app.core.errors import ShapeFormatError
from app.core.shapes import (
    Keyframe,
    Shape,
    ShapeLibrary,
    default_library_dir,
    mirror,
    read_shape,
    scale,
    shift,
    write_shape,
)

AXES = tuple("pitch" if i % 2 == 1 else "yaw" for i in range(1, 13))
ANGLES = tuple(0.01 * i for i in range(1, 13))


def make_shape(**kw):
    base = dict(name="conform-obstacle", axes=AXES, angles_rad=ANGLES,
                keyframes=(Keyframe(0.0, ANGLES, "a"), Keyframe(2.5, tuple(-a for a in ANGLES))))
    base.update(kw)
    return Shape(**base)


def test_round_trip_matches_spec_layout(tmp_path):
    shape = make_shape()
    path = write_shape(shape, tmp_path / "s.json")
    data = json.loads(path.read_text())
    assert data["format"] == "sensnake-shape" and data["version"] == 1
    assert data["axes"] == list(AXES) and len(data["angles_rad"]) == 12
    assert data["keyframes"][1] == {"t_s": 2.5, "angles_rad": [-a for a in ANGLES]}
    assert data["created"].endswith("Z")
    assert read_shape(path) == shape


def test_spec_example_without_keyframes_reads(tmp_path):
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": "n", "created": "c",
                                "axes": list(AXES), "angles_rad": list(ANGLES)}))
    shape = read_shape(path)
    assert shape.keyframes == () and shape.angles_rad == ANGLES


@pytest.mark.parametrize(("patch", "message"), [
    ({"format": "other"}, "format is 'other'"),
    ({"version": 2}, "version 2 is not supported"),
    ({"angles_rad": [0.0] * 11}, "angles_rad has 11 angles, expected 12"),
    ({"axes": ["pitch"] * 11 + ["roll"]}, r"axes\[11\] = 'roll'"),
    ({"keyframes": [{"t_s": "x", "angles_rad": list(ANGLES)}]}, r"keyframes\[0\].t_s"),
    ({"angles_rad": [0.0] * 5 + [None] + [0.0] * 6}, r"angles_rad\[5\] = None"),
])
def test_bad_files_name_the_key(tmp_path, patch, message):
    data = {"format": "sensnake-shape", "version": 1, "name": "n", "axes": list(AXES), "angles_rad": list(ANGLES)}
    data.update(patch)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ShapeFormatError, match=message) as info:
        read_shape(path)
    assert str(path) in str(info.value)


def test_not_json_and_missing_file(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{"format": ')
    with pytest.raises(ShapeFormatError, match=r"broken.json:1: not valid JSON"):
        read_shape(path)
    with pytest.raises(ShapeFormatError, match="cannot read shape file"):
        read_shape(tmp_path / "nope.json")


def test_mirror_scale_shift():
    shape = make_shape()
    m = mirror(shape)
    assert m.angles_rad[0] == ANGLES[0] and m.angles_rad[1] == -ANGLES[1]
    assert m.keyframes[1].angles_rad[1] == ANGLES[1]
    assert scale(shape, 2.0).angles_rad[5] == pytest.approx(2 * ANGLES[5])
    only_pitch = scale(shape, 0.0, axis="pitch")
    assert only_pitch.angles_rad[0] == 0.0 and only_pitch.angles_rad[1] == ANGLES[1]
    s = shift(shape, 1)  # one joint of each axis toward the tail
    assert s.angles_rad[0] == 0.0 and s.angles_rad[1] == 0.0
    assert s.angles_rad[2] == ANGLES[0] and s.angles_rad[3] == ANGLES[1]
    back = shift(shape, -1)
    assert back.angles_rad[0] == ANGLES[2] and back.angles_rad[-1] == 0.0


def test_library_save_list_load_delete(tmp_path, monkeypatch):
    monkeypatch.setenv("SENSNAKE_SHAPES_DIR", str(tmp_path / "lib"))
    assert default_library_dir() == tmp_path / "lib"
    lib = ShapeLibrary()
    lib.save(make_shape(name="my shape/1"))
    assert lib.names() == ["my-shape-1"]
    assert lib.load("my shape/1").name == "my shape/1"
    with pytest.raises(FileExistsError, match="already exists"):
        lib.save(make_shape(name="my shape/1"), overwrite=False)
    lib.delete("my shape/1")
    assert lib.names() == []
    with pytest.raises(FileNotFoundError, match="no shape named 'x'"):
        lib.load("x")
