"""Output files and messages, through the CLI in-process (``main([...])``): output files get the user's usual
permissions (umask) or keep those of the file they replace; a binary shape or config names the file; a write error
names the user's path, not the hidden temporary file; ``fit --sensor`` refuses a sensor the board does not carry;
``forward`` refuses a negative force (or reads it as 0 N, saying so, with ``--clip-negative``)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from app.cli import main
from app.core import calfiles
from models.physics import PhysicsConstants
from models.synthetic import TYPICAL_TRUTH, Readout, paper_protocol

AREA = "1.4e-3"
BINARY = bytes(range(256)) * 4  # not UTF-8 from byte 128 on


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """Two synthetic trials fitted once into cal.json (S06B); returns (folder, trial paths, cal path)."""
    folder = tmp_path_factory.mktemp("files")
    trials = paper_protocol(TYPICAL_TRUTH, PhysicsConstants(), seed=5, repeats=1, noise_rel=0.001,
                            readout=Readout())[:2]
    paths = []
    for t in trials:
        path = folder / f"{t.name}.csv"
        calfiles.write_trial_csv(path, t.time_s, t.force_n, t.conductance_s)
        paths.append(str(path))
    cal = folder / "cal.json"
    assert main(["fit", *paths, "--sensor", "S06B", "--area", AREA, "--out", str(cal)]) == 0
    return folder, paths, cal


@pytest.fixture
def umask():
    """Set the process umask for one test (restored after)."""
    previous = os.umask(0o022)
    os.umask(previous)

    def set_umask(mask: int) -> None:
        os.umask(mask)

    yield set_umask
    os.umask(previous)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def _force_csv(path, force_n: np.ndarray) -> None:
    t = np.arange(force_n.size) / 6.0
    calfiles.write_series_csv(path, t, ("S06B",), force_n[:, None])


def test_fit_estimate_forward_write_with_the_umask_and_keep_a_replaced_files_mode(fitted, tmp_path, umask, capsys):
    _folder, paths, cal = fitted
    force = tmp_path / "force.csv"
    _force_csv(force, np.r_[np.zeros(30), np.full(60, 2.0)])
    outputs = {
        "fit": (tmp_path / "fit.json", lambda out: ["fit", paths[0], "--sensor", "S06B", "--area", AREA,
                                                     "--physics", str(cal), "--out", str(out)]),
        "forward": (tmp_path / "c.csv", lambda out: ["forward", str(force), "--cal", str(cal), "--out", str(out)]),
        "estimate": (tmp_path / "f.csv", lambda out: ["estimate", str(tmp_path / "c.csv"), "--cal", str(cal),
                                                      "--out", str(out)]),
    }
    for mask, expected in ((0o022, 0o644), (0o077, 0o600), (0o002, 0o664)):
        umask(mask)
        for name, (out, argv) in outputs.items():
            out.unlink(missing_ok=True)
            assert main(argv(out)) == 0, (name, capsys.readouterr().err)
            assert _mode(out) == expected, f"{name} with umask {mask:03o}: {_mode(out):03o}"
    umask(0o077)  # a replaced file keeps its mode, whatever the umask says
    for name, (out, argv) in outputs.items():
        os.chmod(out, 0o640)
        assert main(argv(out)) == 0, (name, capsys.readouterr().err)
        assert _mode(out) == 0o640, f"{name} replaced a 0640 file: {_mode(out):03o}"
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")], "temporary files left behind"


def test_a_binary_shape_or_config_is_named_in_one_line(tmp_path, capsys):
    shape = tmp_path / "walk.json"
    shape.write_bytes(BINARY)
    config = tmp_path / "lab.toml"
    config.write_bytes(BINARY)
    trial = tmp_path / "t.csv"
    calfiles.write_trial_csv(trial, np.arange(5.0), np.ones(5), np.full(5, 1e-4))
    for argv, path in ((["play", str(shape), "--robot", "sim"], shape),
                       (["fit", str(trial), "--sensor", "S06B", "--area", AREA, "--config", str(config),
                         "--out", str(tmp_path / "cal.json")], config)):
        code = main(argv)
        err = capsys.readouterr().err
        assert code != 0
        lines = err.strip().splitlines()
        assert len(lines) == 1 and str(path) in lines[0] and "codec can't decode" not in lines[0], err
        assert "Traceback" not in err


def test_a_write_error_names_the_users_path_not_the_temporary_file(fitted, tmp_path, capsys):
    _folder, _paths, cal = fitted
    force = tmp_path / "force.csv"
    _force_csv(force, np.full(20, 1.0))
    out = tmp_path / "out.csv"
    out.mkdir()  # the output path is a folder: refused before anything is written
    code = main(["forward", str(force), "--cal", str(cal), "--out", str(out)])
    err = capsys.readouterr().err
    assert code != 0 and str(out) in err and ".tmp" not in err and "[Errno" not in err, err
    assert "is a folder" in err  # refused before anything is written (app.core.outputs)
    assert len(err.strip().splitlines()) == 1
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")], "temporary file left behind"


def test_fit_refuses_a_sensor_that_is_not_on_the_board(fitted, tmp_path, capsys):
    _folder, paths, _cal = fitted
    out = tmp_path / "cal.json"
    code = main(["fit", paths[0], "--sensor", "S99Z", "--area", AREA, "--out", str(out)])
    err = capsys.readouterr().err
    assert code != 0 and "S99Z" in err and "not a channel" in err, err
    assert not out.exists()


def test_forward_refuses_a_negative_force_or_clips_it_saying_so(fitted, tmp_path, capsys):
    _folder, _paths, cal = fitted
    force = np.r_[np.zeros(30), np.full(60, 2.0)]
    force[40] = -0.25
    source = tmp_path / "force.csv"
    _force_csv(source, force)
    out = tmp_path / "c.csv"
    code = main(["forward", str(source), "--cal", str(cal), "--out", str(out)])
    err = capsys.readouterr().err
    assert code != 0 and "negative" in err and "S06B = -0.25 N" in err and "--clip-negative" in err, err
    assert not out.exists()

    assert main(["forward", str(source), "--cal", str(cal), "--out", str(out), "--clip-negative"]) == 0
    err = capsys.readouterr().err
    assert "1 negative force(s) read as 0 N" in err
    clipped = tmp_path / "clipped.csv"
    _force_csv(clipped, np.maximum(force, 0.0))
    assert main(["forward", str(clipped), "--cal", str(cal), "--out", str(tmp_path / "c0.csv")]) == 0
    np.testing.assert_array_equal(calfiles.read_series_csv(out, "conductance_S").values,
                                  calfiles.read_series_csv(tmp_path / "c0.csv", "conductance_S").values)
