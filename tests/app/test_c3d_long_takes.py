"""C3D takes longer than the header's 65,535 frames (68 s at 960 Hz: shorter than one of the paper's runs). ezc3d
1.7 stops reading there without a word; the import read 65,535 frames of a 70,000-frame take and lost the rest."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from app.core.errors import MocapFileError
from app.core.mocap import layout_labels, read_c3d
from devices.config import MocapConfig

FRAMES = 70_000
RATE_HZ = 960.0


def write_take(path, frames: int = FRAMES, stated: str = "trial") -> None:
    """Marker SEG01_1 at x = frame × 0.01 mm, every marker's y its index; marker SEG01_4 unseen (negative residual)
    in frames 100–199 and 69,000–69,099."""
    labels = tuple(label for row in layout_labels(MocapConfig(), 12) for label in row)
    n = len(labels)
    points = np.ones((4, n, frames))
    points[0] = np.arange(frames)[None, :] * 0.01
    points[1] = np.arange(n)[:, None]
    points[2] = 36.0
    residuals = np.zeros((1, n, frames))
    residuals[0, 3, 100:200] = -1.0
    residuals[0, 3, 69_000:69_100] = -1.0
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [RATE_HZ]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d.add_parameter("POINT", "UNITS", "mm")
    if stated == "trial":
        c3d.add_parameter("TRIAL", "ACTUAL_START_FIELD", [1, 0])
        c3d.add_parameter("TRIAL", "ACTUAL_END_FIELD", [frames & 0xFFFF, frames >> 16])
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals, "camera_masks": np.zeros((7, n, frames), dtype=bool)}
    c3d.write(str(path))


@pytest.fixture(scope="module")
def long_take(tmp_path_factory):
    path = tmp_path_factory.mktemp("c3d") / "long.c3d"
    write_take(path)
    return path


@pytest.mark.parametrize("stated", ["trial", "size"])
def test_every_frame_of_a_take_longer_than_65535_frames_is_read(tmp_path, long_take, stated):
    path = long_take
    if stated == "size":  # as ezc3d writes one: 65,535 frames stated, every frame written
        path = tmp_path / "long.c3d"
        write_take(path, stated=stated)
    take = read_c3d(path, MocapConfig(), 12)
    markers = take.markers_m
    assert markers.shape == (FRAMES, 12, 4, 3)
    np.testing.assert_allclose(markers[:, 0, 0, 0], np.arange(FRAMES) * 1e-5, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(markers[-1, 1, 2, 1], 6 * 1e-3)  # SEG02_3: the file's 7th point, y = its index (mm)
    assert take.time_s[-1] == pytest.approx((FRAMES - 1) / RATE_HZ)
    unseen = np.isnan(markers[:, 0, 3, 0])
    assert unseen[100:200].all() and unseen[69_000:69_100].all() and unseen.sum() == 200
    assert str(FRAMES) in take.source and ("TRIAL" in take.source if stated == "trial" else "size" in take.source)


def test_a_long_take_cut_short_is_refused_naming_both_counts(tmp_path, long_take):
    path = tmp_path / "cut.c3d"
    shutil.copyfile(long_take, path)
    os.truncate(path, os.path.getsize(path) - 2_000 * 48 * 16)
    with pytest.raises(MocapFileError, match=r"70000 frames but the file holds 6\d{4}.*cut short"):
        read_c3d(path, MocapConfig(), 12)


def test_a_take_within_65535_frames_reads_as_before(tmp_path):
    path = tmp_path / "short.c3d"
    write_take(path, frames=3_000, stated="size")
    take = read_c3d(path, MocapConfig(), 12)
    assert take.markers_m.shape[0] == 3_000 and take.source == "C3D short.c3d"
    assert np.isnan(take.markers_m[150, 0, 3, 0]) and not np.isnan(take.markers_m[250, 0, 3, 0])


def test_the_header_and_parameters_read_without_the_frames_are_ezc3ds(tmp_path: Path) -> None:
    """read_head parses the parameter section itself (ezc3d would read every frame to give them): every parameter
    ezc3d reads is there with the same values, and the frames read from the data section (interleaved with analog
    samples here) are ezc3d's."""
    from app.core.c3d_frames import point_layout, read_frames, read_head

    labels = tuple(label for row in layout_labels(MocapConfig(), 12) for label in row)
    frames, analog_per_frame = 500, 4
    rng = np.random.default_rng(2)
    points = np.ones((4, len(labels), frames))
    points[:3] = rng.normal(0, 500, (3, len(labels), frames))
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [RATE_HZ]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["ANALOG"]["RATE"]["value"] = [RATE_HZ * analog_per_frame]
    c3d["parameters"]["ANALOG"]["LABELS"]["value"] = ("EMG1", "EMG2", "SYNC")
    c3d.add_parameter("POINT", "UNITS", "mm")
    c3d.add_parameter("SUBJECTS", "NAMES", ["Snake", "Rig"])
    c3d["data"]["points"] = points
    c3d["data"]["analogs"] = rng.normal(0, 1, (1, 3, frames * analog_per_frame))
    path = tmp_path / "analog.c3d"
    c3d.write(str(path))
    theirs = ezc3d.c3d(str(path))
    head = read_head(path)
    assert head is not None
    for key in ("size", "first_frame", "last_frame", "frame_rate"):
        assert head["header"]["points"][key] == theirs["header"]["points"][key], key
    compared = 0
    for group, entries in theirs["parameters"].items():
        for name, entry in entries.items():
            if not isinstance(entry, dict) or "value" not in entry:
                continue
            ours = head["parameters"][group][name]["value"]
            expected = [str(x) if isinstance(x, str) else float(x) for x in np.ravel(entry["value"])]
            assert [str(x) if isinstance(x, str) else float(x) for x in ours] == expected, f"{group}:{name}"
            compared += 1
    assert compared > 20 and head["parameters"]["SUBJECTS"]["NAMES"]["value"] == ["Snake", "Rig"]
    xyz = read_frames(path, point_layout(path, head), 0, frames)
    assert np.array_equal(xyz, np.transpose(theirs["data"]["points"][:3], (2, 1, 0)))


def _as_mips(intel: bytes) -> bytes:
    """An Intel C3D file as a MIPS (big-endian) one: processor byte 86, every 16-bit word and float swapped."""
    out = bytearray(intel)

    def signed(i: int) -> int:
        return (out[i] ^ 0x80) - 0x80

    for offset, width in ((2, 2), (4, 2), (6, 2), (8, 2), (10, 2), (12, 4), (16, 2), (18, 2), (20, 4)):
        out[offset:offset + width] = out[offset:offset + width][::-1]
    start = (out[0] - 1) * 512
    out[start + 3] = 86
    position = start + 4
    while out[position]:
        name_end = position + 2 + abs(signed(position))
        jump = int(np.frombuffer(bytes(out[name_end:name_end + 2]), "<i2")[0])
        out[name_end:name_end + 2] = out[name_end:name_end + 2][::-1]
        if signed(position + 1) > 0:
            kind, n_dims = signed(name_end + 2), out[name_end + 3]
            cursor = name_end + 4 + n_dims
            width = abs(kind)
            for i in range(int(np.prod(list(out[name_end + 4:cursor]))) if width in (2, 4) else 0):
                out[cursor + i * width:cursor + (i + 1) * width] = out[cursor + i * width:cursor + (i + 1) * width][::-1]
        if jump <= 0:
            break
        position = name_end + jump
    data = (int(np.frombuffer(bytes(out[16:18]), ">u2")[0]) - 1) * 512
    out[data:] = np.frombuffer(bytes(out[data:len(out) - (len(out) - data) % 4]), "<f4").astype(">f4").tobytes() + \
        bytes(out[len(out) - (len(out) - data) % 4:])
    return bytes(out)


def test_a_mips_take_reads_as_the_same_take_written_for_intel(tmp_path: Path) -> None:
    """ezc3d 1.7 refuses MIPS files ("not supported yet"); this reader reads them in their byte order."""
    intel = tmp_path / "intel.c3d"
    write_take(intel, frames=300, stated="size")
    mips = tmp_path / "mips.c3d"
    mips.write_bytes(_as_mips(intel.read_bytes()))
    ours, theirs = read_c3d(mips, MocapConfig(), 12), read_c3d(intel, MocapConfig(), 12)
    assert np.array_equal(ours.markers_m, theirs.markers_m, equal_nan=True) and np.isnan(ours.markers_m[150, 0, 3, 0])
    assert (ours.rate_hz, ours.units, ours.labels) == (theirs.rate_hz, theirs.units, theirs.labels)


def test_a_parameter_section_longer_than_its_stated_block_count_is_read_to_the_data(tmp_path: Path) -> None:
    """Some writers leave the parameter section's block count (its third byte) short: the labels past it count."""
    whole = tmp_path / "whole.c3d"
    write_take(whole, frames=300, stated="size")
    raw = bytearray(whole.read_bytes())
    start = (raw[0] - 1) * 512
    assert raw[start + 2] > 1  # 48 labels take more than one block
    raw[start + 2] = 1
    short = tmp_path / "short.c3d"
    short.write_bytes(bytes(raw))
    assert read_c3d(short, MocapConfig(), 12).labels == read_c3d(whole, MocapConfig(), 12).labels
