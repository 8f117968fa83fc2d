"""What the robot commands share (app/cli/_robot.py) against the independent XM430 emulator
(tests/emulators/xm430_emulator.py): the ports from ``--config`` when ``--robot``/``--daq`` are not given, a servo's
hardware error worded for when it was found (never "motion stopped" when nothing moved) with the command that clears
it, and ``play --strict`` on missed control ticks, with their measured cause."""

from __future__ import annotations

import json
import sys
import threading
from pathlib import Path

import pytest

from app.cli.main import main
from app.cli.play import BusTiming, describe_missed_ticks
from tests.emulators.xm430_emulator import EmulatorProcess

pytestmark = pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")), reason="needs os.openpty")

DEFAULT_LAB = Path(__file__).resolve().parents[2] / "resources" / "default_lab.toml"


@pytest.fixture
def emulator():
    process = EmulatorProcess()
    yield process
    assert process.close() == 0


def lab_with_port(folder: Path, port: str) -> Path:
    """The shipped config with its [robot] port set to ``port``."""
    text = DEFAULT_LAB.read_text()
    assert 'port = "sim"                 # U2D2' in text
    config = folder / "lab.toml"
    config.write_text(text.replace('port = "sim"                 # U2D2', f'port = "{port}"  # U2D2', 1))
    return config


def shape_file(folder: Path) -> Path:
    path = folder / "bump.json"
    path.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": "bump",
                                "axes": ["pitch", "yaw"] * 6, "angles_rad": [0.1] + [0.0] * 11}))
    return path


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "warning" not in line]
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


@pytest.mark.parametrize("argv", [["scan"], ["teach", "--out", "t.json"], ["play", "s.json"],
                                  ["record", "--seconds", "1", "--out", "r.h5"], ["servo", "get", "--id", "3"]])
def test_no_port_and_no_config_is_one_line_exit_2(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    line = one_error_line(capsys)
    option = "--daq" if argv[0] == "record" else "--robot"
    assert exit_info.value.code == 2 and f"no {'force-sensor board' if argv[0] == 'record' else 'robot'} port" in line
    assert option in line and "--config" in line
    silent = tmp_path / "lab.toml"
    silent.write_text("[lab]\nphysics = \"scripted\"\n")  # a config naming no port: never the simulator quietly
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, "--config", str(silent)])
    line = one_error_line(capsys)
    assert exit_info.value.code == 2 and str(silent) in line and ("[board]" if argv[0] == "record" else "[robot]") in line


def test_record_takes_the_board_port_from_the_config(tmp_path, capsys):
    config = tmp_path / "lab.toml"
    config.write_text(DEFAULT_LAB.read_text() + "")
    text = config.read_text()
    board_at = text.index("[board]")
    config.write_text(text[:board_at] + f'[board]\nport = "{tmp_path / "ttyNOPE"}"\n' +
                      text[board_at + len("[board]"):].replace('\nport = "sim"', "\n# port", 1))
    assert main(["record", "--config", str(config), "--seconds", "1", "--out", str(tmp_path / "r.h5")]) == 1
    assert "ttyNOPE" in one_error_line(capsys)  # the config's port was the one opened
    assert not (tmp_path / "r.h5").exists()


def test_a_servo_in_error_at_connect_is_refused_before_anything_moves(emulator, tmp_path, capsys):
    config = lab_with_port(tmp_path, emulator.path)  # and no --robot: the config's port
    emulator.command("overload 5")
    assert main(["play", str(shape_file(tmp_path)), "--config", str(config), "--speed", "1"]) == 1
    line = one_error_line(capsys)
    assert "servo 5 overload: found at connect, nothing moved" in line and "motion stopped" not in line
    assert "sensnake servo reboot --id 5" in line and "Hardware tab → Reboot" in line
    assert all(emulator.state(sid)["goal_writes"] == 0 for sid in (1, 5))  # nothing was sent to move
    assert main(["teach", "--config", str(config), "--after", "0", "--out", str(tmp_path / "t.json")]) == 1
    line = one_error_line(capsys)
    assert "found at connect, nothing moved" in line and "sensnake servo reboot --id 5" in line
    assert not (tmp_path / "t.json").exists()
    assert main(["servo", "reboot", "--config", str(config), "--id", "5"]) == 0  # and the fix it names works
    assert emulator.state(5)["hw_error"] == 0


def test_missed_ticks_are_measured_said_and_fail_only_with_strict(emulator, tmp_path, capsys):
    shape = shape_file(tmp_path)

    played = threading.Event()

    def stall_once_moving(goals_before: int) -> None:  # the bus's far end held up once, 150 ms: ~7 ticks at 50 Hz
        while emulator.counts()["sync_write"] < goals_before + 10:
            if played.wait(0.01):
                return
        emulator.command("stall 0.15")

    for strict, expected in (([], 0), (["--strict"], 1)):
        played.clear()
        staller = threading.Thread(target=stall_once_moving, args=(emulator.counts()["sync_write"],),
                                   name="test-stall")
        staller.start()
        try:
            code = main(["play", str(shape), "--robot", emulator.path, "--speed", "0.3", "--shifts", "1", *strict])
        finally:
            played.set()
            staller.join()
        captured = capsys.readouterr()
        assert code == expected, captured.err
        assert "finished" in captured.out  # the motion itself finished either way (SPEC: exit 0 without --strict)
        (line,) = [line for line in captured.err.splitlines() if "control ticks missed" in line]
        assert line.startswith("sensnake play: error:" if strict else "sensnake play: warning:"), line
        # the causes measured on this bus: the factory Return Delay Time (12 × 500 µs) and one very long tick
        assert "Return Delay Time up to 500 µs" in line and "6.0 ms" in line
        assert "longest time between two ticks' readings" in line
        # a stalled far end: ticks kept their slots and ran on the last angles read, or were missed; said either way
        assert "missed" in line and ("without feedback" in line or "run without" not in line)
        assert "fix:" in line


def test_the_latency_timer_is_named_with_its_fix():
    fix = "fix with `echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer`"
    slow = BusTiming(cycle_s=0.019, latency_timer_ms=16, latency_fix=fix, return_delays_s={})
    line = describe_missed_ticks(9, 200, 50.0, slow, 0.04, "normal scheduling")
    assert line.startswith("9 of 200 control ticks missed (4.5%") and "latency timer is 16 ms" in line
    assert "needs 1 ms" in line and fix in line and "--rate 26" in line  # 0.5 / 19 ms
    quiet = BusTiming(cycle_s=0.004, latency_timer_ms=1, latency_fix=None, return_delays_s={1: 0.0})
    line = describe_missed_ticks(3, 200, 50.0, quiet, 0.03, "normal scheduling")
    assert "latency" not in line and "Return Delay" not in line and "no single cause" in line


def test_teach_with_a_servo_failing_while_posed_never_says_motion_stopped(emulator, tmp_path, capsys):
    writes_before = emulator.counts()["write"]
    posed = threading.Event()

    def overload_once_limp() -> None:  # after teach's 12 torque-off writes: while the robot is posed by hand
        while emulator.counts()["write"] < writes_before + 12:
            if posed.wait(0.01):
                return
        emulator.command("overload 3")

    trip = threading.Thread(target=overload_once_limp, name="test-overload")
    trip.start()
    try:
        code = main(["teach", "--robot", emulator.path, "--after", "1", "--out", str(tmp_path / "t.json")])
    finally:
        posed.set()
        trip.join()
    line = one_error_line(capsys)
    assert code == 1 and "servo 3 overload" in line and "motion" not in line, line
    assert "sensnake servo reboot --id 3" in line and not (tmp_path / "t.json").exists()


def test_ticks_whose_replies_came_too_late_are_said_as_run_without_feedback():
    quiet = BusTiming(cycle_s=0.004, latency_timer_ms=1, latency_fix=None, return_delays_s={1: 0.0})
    line = describe_missed_ticks(2, 200, 50.0, quiet, 0.03, "normal scheduling", blind=7)
    assert line.startswith("9 of 200 control ticks missed or run without feedback (2 missed, 7 whose servo replies")
    assert "(4.5%, more than 1%)" in line
