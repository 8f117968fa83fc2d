"""The CLI entry point: contract of the parser, and one clear line (no traceback) for expected failures."""

from __future__ import annotations

import subprocess
import sys

import pytest

from app.cli import build_parser, main


def test_every_spec_command_is_in_the_parser():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) >= {"gui", "fit", "estimate", "forward", "scan", "teach", "play", "record", "export", "bench"}


def test_play_defaults_follow_the_spec():
    args = build_parser().parse_args(["play", "shape.json", "--robot", "sim"])
    assert (args.mode, args.speed, args.rate, args.time_scale, args.shifts) == ("follow", 0.034, 50.0, 1.0, None)


def test_fit_window_default_is_225_to_300():
    args = build_parser().parse_args(["fit", "t.csv", "--sensor", "S06B", "--area", "0.0014", "--out", "c.json"])
    assert tuple(args.window) == (225.0, 300.0)


def test_missing_file_is_one_line_not_a_traceback(tmp_path, capsys):
    code = main(["export", str(tmp_path / "nope.h5"), "--csv", str(tmp_path / "out.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    assert len(err) == 1 and "nope.h5" in err[0]
    assert "Traceback" not in err[0]


@pytest.mark.slow
def test_python_dash_m_app_shows_help():
    result = subprocess.run([sys.executable, "-m", "app", "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    assert "sensnake" in result.stdout and "record" in result.stdout


@pytest.mark.parametrize("command", ["scan", "teach", "play"])
def test_robot_commands_refuse_a_non_positive_baud_in_one_line(command, tmp_path, capsys):
    from app.core.shapes import Shape, write_shape
    from devices.config import RobotConfig

    shape = tmp_path / "s.json"
    write_shape(Shape("s", RobotConfig().axes, (0.0,) * 12), shape)
    argv = {"scan": ["scan"], "teach": ["teach", "--out", str(tmp_path / "t.json")], "play": ["play", str(shape)]}
    code = main([*argv[command], "--robot", "sim", "--baud", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err == [f"sensnake {command}: error: --baud must be a positive rate in bps, got 0"]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["bogus"], "sensnake: error: argument COMMAND: invalid choice: 'bogus'"),
        (["fit"], "sensnake fit: error: the following arguments are required: TRIAL.csv, --sensor, --area, --out"),
        (["play", "s.json", "--robot", "sim", "--speed", "abc"],
         "sensnake play: error: argument --speed: invalid float value: 'abc'"),
    ],
)
def test_usage_errors_are_one_line_with_exit_2(argv, expected, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2
    assert len(err) == 1 and err[0].startswith(expected) and err[0].endswith("--help')")
