"""`sensnake mocap import|simulate`: a take of the physics lab's body (C3D, or XDF) placed on a recording's clock
from the motion alone, every segment's pose against the simulation's truth, and bad takes refused in one line."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import ezc3d
import h5py
import numpy as np
import pytest

pytest.importorskip("mujoco")

from app.cli.main import main  # noqa: E402
from app.core.mocap import sim_segment_poses, simulated_take  # noqa: E402
from devices.config import MocapConfig  # noqa: E402
from models.mocap import markers_from_poses, resample_poses  # noqa: E402
from tests.app.xdf_files import stream_xml, write_xdf  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
LEAD_S = 1.37  # the take starts this long before the recording
WAVE = [0.0, 0.3, 0.2, -0.3, -0.2, 0.3, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 4 s physics-lab run on flat ground, a wave of bends played follow-the-leader (the one physics run)."""
    from app.core.experiment import run_experiment
    from app.core.shapes import Shape

    folder = tmp_path_factory.mktemp("mocap")
    shape = Shape(name="wave", axes=("pitch", "yaw") * 6, angles_rad=tuple(WAVE))
    out = folder / "run.h5"
    run_experiment(out, scene="flat", shape=shape, speed_rad_s=0.3, seconds=4.0, settle_s=0.5, rest_cap_s=0.0)
    return out


def sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in "\n".join(err), err
    return errors[0]


def test_a_simulated_take_lands_on_the_recordings_clock_and_its_poses_on_the_simulations(run, tmp_path, capsys):
    take = simulated_take(run, tmp_path / "take.c3d", lead_s=LEAD_S, seed=3)
    before = sha256(run)
    out = tmp_path / "new.h5"
    assert main(["mocap", "import", str(take.path), "--rec", str(run), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "take start on the recording's clock: -1.37" in printed and "confidence 1.00" in printed
    assert sha256(run) == before  # the input is only read
    with h5py.File(out, "r") as f:
        group = f["mocap"]
        time_s, centers = group["time_s"][:], group["segment_center_m"][:]
        markers, residual = group["markers_m"][:], group["residual_m"][:]
        attrs = dict(group.attrs)
        assert "daq" in f and "robot" in f and "sim" in f  # the rest of the recording is kept
    assert abs(time_s[0] - take.take_start_s) < 0.005  # the take's start, from the motion alone
    assert attrs["clock_offset_s"] == pytest.approx(time_s[0]) and attrs["rate_hz"] == 960.0
    assert attrs["clock_offset_confidence"] > 0.9 and list(attrs["labels"][:2]) == ["SEG01_1", "SEG01_2"]
    assert attrs["marker_layout_m"].shape == (12, 4, 3) and "C3D take.c3d" in attrs["source"]
    # every pose against the truth at the frame's true time (the simulated take's own clock)
    sim_t, sim_c, sim_r = sim_segment_poses(run)
    true_t = take.take_start_s + np.arange(len(time_s)) / 960.0
    truth, _ = resample_poses(sim_t, sim_c, sim_r, true_t)
    seen = np.isfinite(markers[..., 0]).reshape(len(time_s), 12, 4).sum(axis=-1)
    posed = np.isfinite(centers[..., 0])
    assert np.array_equal(posed, seen >= 3)  # a pose exactly where 3 or more markers were seen, NaN elsewhere
    assert (seen < 3).any() and np.isnan(residual[seen < 3]).all()
    error = np.linalg.norm(centers[posed] - truth[posed], axis=-1)
    assert np.sqrt(np.mean(error ** 2)) < 0.002
    hidden = (true_t >= take.hidden_s[0] + 0.001) & (true_t < take.hidden_s[1] - 0.001)
    assert hidden.sum() > 400 and not posed[hidden, take.hidden_segment].any()
    # the paper's Fig. 7A beside 7B from it: drawn, and never over a file
    figure = tmp_path / "kinematics.png"
    script = [sys.executable, str(ROOT / "scripts" / "kinematics_figure.py"), str(out), str(figure)]
    drawn = subprocess.run(script, capture_output=True, text=True, timeout=120)
    assert drawn.returncode == 0 and "from motion capture" in drawn.stdout, drawn.stderr
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    again = subprocess.run(script, capture_output=True, text=True, timeout=120)
    assert again.returncode == 1 and "exists" in again.stderr


def test_an_xdf_mocap_stream_on_the_lsl_clock_is_placed_too(run, tmp_path, capsys):
    """The same body as a LabRecorder file: one MoCap stream, channels SEGxx_k_X/Y/Z in metres, LSL time stamps."""
    sim_t, sim_c, sim_r = sim_segment_poses(run)
    mocap = MocapConfig()
    frames = np.arange(-LEAD_S, sim_t[-1], 1 / 960.0)
    c, r = resample_poses(sim_t, sim_c, sim_r, frames)
    markers = markers_from_poses(c, r, np.array([mocap.marker_layout_m] * 12)).reshape(len(frames), 48, 3)
    markers[100:300, 5] = np.nan
    channels = [{"label": f"{mocap.label(s, k)}_{axis}", "unit": "m", "type": f"Position{axis}"}
                for s in range(1, 13) for k in range(1, 5) for axis in "XYZ"]
    lsl_t = 5021.25 + np.arange(len(frames)) / 960.0
    events = stream_xml("Markers", "Markers", [{"label": "event"}], 0.0)
    xdf = write_xdf(tmp_path / "take.xdf", [(events, np.array([5021.0, 5022.0]), np.zeros((2, 1))),
                                            (stream_xml("PhaseSpace", "MoCap", channels, 960.0), lsl_t,
                                             markers.reshape(len(frames), -1))])
    out = tmp_path / "xdf.h5"
    assert main(["mocap", "import", "--xdf", str(xdf), "--rec", str(run), "--out", str(out)]) == 0
    with h5py.File(out, "r") as f:
        attrs = dict(f["mocap"].attrs)
        time_s = f["mocap/time_s"][:]
    assert attrs["clock_offset_s"] == pytest.approx(-LEAD_S - 5021.25, abs=0.005)
    assert abs(time_s[0] + LEAD_S) < 0.005 and "XDF take.xdf" in attrs["source"] and attrs["units"] == "m"


def test_a_given_offset_places_the_take_there(run, tmp_path, capsys):
    take = simulated_take(run, tmp_path / "take.c3d", lead_s=1.0, seed=1)
    out = tmp_path / "given.h5"
    assert main(["mocap", "import", str(take.path), "--rec", str(run), "--offset", "-0.25", "--out", str(out)]) == 0
    with h5py.File(out, "r") as f:
        assert f["mocap/time_s"][0] == pytest.approx(-0.25)
        assert f["mocap"].attrs["clock_offset_how"].startswith("given")
        assert np.isnan(f["mocap"].attrs["clock_offset_confidence"])
    assert "given" in capsys.readouterr().out
    # an offset that puts the take beside the recording, not on it, is refused naming both spans (1e300 wrote every
    # frame at one time)
    for offset in ("500", "1e300", "-1e17"):
        bad = tmp_path / f"off{offset}.h5"
        assert main(["mocap", "import", str(take.path), "--rec", str(run), f"--offset={offset}", "--out", str(bad)]) == 1
        line = capsys.readouterr().err.strip().splitlines()[-1]
        assert "do not overlap" in line and f"--offset {float(offset):g}" in line, line
        assert not bad.exists()


def _c3d(path, labels, units="mm", frames=5):
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [960.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c3d.add_parameter("POINT", "UNITS", units)
    points = np.ones((4, len(labels), frames))
    points[:3] = np.random.default_rng(0).normal(0, 100, (3, len(labels), frames))
    c3d["data"]["points"] = points
    c3d.write(str(path))
    return path


ALL = [f"SEG{s:02d}_{k}" for s in range(1, 13) for k in range(1, 5)]


@pytest.mark.parametrize(("make", "words"), [
    (lambda p: _c3d(p / "t.c3d", ["LFHD", "RFHD", "C7"]), ["t.c3d", "none of the layout's marker labels", "LFHD"]),
    (lambda p: _c3d(p / "t.c3d", ALL, units="in"), ["t.c3d", "POINT:UNITS = 'in'"]),
    (lambda p: _c3d(p / "t.c3d", [x for x in ALL if x[-1] in "12"]), ["t.c3d", "segment 1 has 2 of its 4 markers"]),
    (lambda p: write_xdf(p / "t.xdf", [(stream_xml("EEG", "EEG", [{"label": "Fz"}], 100.0), np.arange(3.0),
                                        np.zeros((3, 1)))]), ["t.xdf", "no stream of type MoCap", "EEG"]),
    (lambda p: (p / "t.c3d").write_bytes(b"not a c3d at all"), ["t.c3d", "not a readable C3D"]),
])
def test_a_take_that_cannot_be_imported_is_refused_in_one_line_naming_the_file(run, tmp_path, capsys, make, words):
    made = make(tmp_path)
    take = tmp_path / ("t.xdf" if str(made).endswith(".xdf") else "t.c3d")
    source = ["--xdf", str(take)] if take.suffix == ".xdf" else [str(take)]
    out = tmp_path / "out.h5"
    assert main(["mocap", "import", *source, "--rec", str(run), "--out", str(out)]) == 1
    line = one_line_error(capsys)
    for word in words:
        assert word in line
    assert not out.exists()


def test_a_layout_of_two_markers_a_segment_is_refused_naming_the_key(run, tmp_path, capsys):
    config = tmp_path / "lab.toml"
    config.write_text("[mocap]\nmarker_layout_m = [[0.03, 0.0, 0.05], [-0.03, 0.0, 0.05]]\n", encoding="utf-8")
    take = _c3d(tmp_path / "t.c3d", ALL)
    assert main(["mocap", "import", str(take), "--rec", str(run), "--config", str(config), "--out",
                 str(tmp_path / "o.h5")]) == 1
    line = one_line_error(capsys)
    assert "lab.toml" in line and "mocap.marker_layout_m has 2 marker(s) a segment" in line


def test_an_existing_output_or_the_input_is_never_written(run, tmp_path, capsys):
    take = _c3d(tmp_path / "t.c3d", ALL)
    existing = tmp_path / "there.h5"
    existing.write_bytes(b"keep me")
    before = sha256(run)
    assert main(["mocap", "import", str(take), "--rec", str(run), "--out", str(existing)]) == 1
    assert "exists" in one_line_error(capsys) and existing.read_bytes() == b"keep me"
    assert main(["mocap", "import", str(take), "--rec", str(run), "--out", str(run)]) == 1
    assert "input" in one_line_error(capsys) and sha256(run) == before
    assert not list(tmp_path.glob(".*partial*"))


def test_a_take_whose_motion_cannot_place_it_is_refused_with_the_reason(run, tmp_path, capsys):
    """A take of the body lying still (its first pose held): no motion in the take to line up on."""
    sim_t, sim_c, sim_r = sim_segment_poses(run)
    layout = np.array([MocapConfig().marker_layout_m] * 12)
    still = markers_from_poses(np.repeat(sim_c[:1], 3000, 0), np.repeat(sim_r[:1], 3000, 0), layout)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [960.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(ALL)
    c3d.add_parameter("POINT", "UNITS", "m")
    points = np.ones((4, 48, 3000))
    points[:3] = np.transpose(still.reshape(3000, 48, 3), (2, 1, 0))
    c3d["data"]["points"] = points
    c3d.write(str(tmp_path / "still.c3d"))
    assert main(["mocap", "import", str(tmp_path / "still.c3d"), "--rec", str(run), "--out",
                 str(tmp_path / "o.h5")]) == 1
    line = one_line_error(capsys)
    assert "cannot place the take" in line and "--offset" in line
    assert json.dumps(line)  # one plain line


@pytest.mark.parametrize("content", [None, b"not an HDF5 file"], ids=["missing", "not-hdf5"])
def test_simulate_from_a_recording_that_is_missing_or_not_hdf5_is_one_line(tmp_path, capsys, content):
    rec = tmp_path / "rec.h5"
    if content is not None:
        rec.write_bytes(content)
    assert main(["mocap", "simulate", str(rec), "--out", str(tmp_path / "take.c3d")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(rec) in err and "synchronously" not in err
    assert ("does not exist" in err) == (content is None)
    assert not (tmp_path / "take.c3d").exists()
