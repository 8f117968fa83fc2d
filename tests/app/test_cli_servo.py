"""``sensnake servo get|set|dump|restore`` against the independent XM430 emulator (a separate process on a pty,
written from the e-manual; tests/emulators/xm430_emulator.py): one read per servo, read before write, torque off
around an EEPROM write and back on, range checks, read-back, and a settings file that restores only what differs."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from pathlib import Path

import pytest

from app.cli.main import main
from devices.config import RobotConfig
from devices.errors import StatusReturnLevelError
from devices.servo_chain import ServoChain
from tests.emulators.xm430_emulator import EmulatorProcess

pytestmark = pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")), reason="needs os.openpty")


@pytest.fixture
def emulator():
    process = EmulatorProcess()
    yield process
    assert process.close() == 0


def test_get_reads_every_item_of_a_servo_in_one_request(emulator, capsys):
    before = emulator.counts()["read"]
    assert main(["servo", "get", "--robot", emulator.path, "--id", "3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert emulator.counts()["read"] == before + 1  # the whole table in one read
    rows = {line[18:42].strip(): line for line in out}
    assert len(rows) == 53 and "Position P Gain" in rows and "Present Temperature" in rows
    assert rows["Return Delay Time"].split()[-6:] == ["250", "2", "µs", "0", "…", "254"], rows["Return Delay Time"]
    assert "EEPROM" in rows["Return Delay Time"] and "RAM" in rows["Position P Gain"]
    assert main(["servo", "get", "--robot", emulator.path, "--id", "3", "position p gain"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert "Position P Gain" in line and " 800 " in line and "0 … 16383" in line


def test_set_an_eeprom_item_with_torque_on_turns_it_off_for_the_write_and_back_on(emulator, capsys):
    with ServoChain(dataclasses.replace(RobotConfig(), port=emulator.path)) as chain:
        chain.set_torque(True, [5])
    assert emulator.state(5)["torque"] == 1
    capsys.readouterr()
    assert main(["servo", "set", "--robot", emulator.path, "--id", "5", "Return Delay Time", "0"]) == 0
    assert "Return Delay Time 250 → 0 (read back)" in capsys.readouterr().out
    state = emulator.state(5)
    assert state["rdt"] == 0 and state["torque"] == 1  # written with torque off, torque restored


def test_set_reads_before_writing_and_refuses_bad_values_in_one_line(emulator, capsys):
    writes = emulator.counts()["write"]
    assert main(["servo", "set", "--robot", emulator.path, "--id", "2", "Position P Gain", "800"]) == 0
    assert "already 800: not written" in capsys.readouterr().out
    assert emulator.counts()["write"] == writes  # nothing written: it already held the value
    for argv, words in ((["Position P Gain", "20000"], "out of its range 0 … 16383"),
                        (["Present Temperature", "20"], "read-only"),
                        (["Position Gain", "1"], "did you mean"),):
        assert main(["servo", "set", "--robot", emulator.path, "--id", "2", *argv]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
    assert emulator.counts()["write"] == writes
    assert main(["servo", "set", "--robot", emulator.path, "Position P Gain", "10"]) == 1  # which servo?
    assert "needs one --id" in capsys.readouterr().err


def test_dump_then_restore_writes_back_only_what_changed(emulator, capsys, tmp_path):
    out = tmp_path / "servos.json"
    assert main(["servo", "dump", "--robot", emulator.path, "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["format"] == "sensnake-servos" and set(document["servos"]) == {str(i) for i in range(1, 13)}
    assert document["servos"]["7"]["items"]["Position P Gain"] == 800
    assert main(["servo", "set", "--robot", emulator.path, "--id", "7", "Position P Gain", "300"]) == 0
    assert main(["servo", "set", "--robot", emulator.path, "--id", "9", "Temperature Limit", "70"]) == 0
    capsys.readouterr()
    writes = emulator.counts()["write"]
    assert main(["servo", "restore", str(out), "--robot", emulator.path]) == 0
    captured = capsys.readouterr()
    assert "servo 7: Position P Gain 300 → 800" in captured.out and "servo 9: Temperature Limit 70 → 80" in captured.out
    assert "2 item(s) written" in captured.err
    # Two items written (EEPROM: torque was off here, so no torque writes).
    assert emulator.counts()["write"] == writes + 2
    assert emulator.state(7)["goal"] == 2048  # goals and torque are the moment's state: never restored


def test_a_bad_settings_file_is_one_line_naming_it(emulator, capsys, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "sensnake-servos", "version": 1,
                               "servos": {"3": {"items": {"Position P Gain": 99999}}}}))
    assert main(["servo", "restore", str(bad), "--robot", emulator.path]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.json" in err[0] and "servo 3" in err[0] and "out of its range" in err[0]
    good = tmp_path / "good.json"
    assert main(["servo", "dump", "--robot", emulator.path, "--out", str(good)]) == 0
    assert main(["servo", "restore", str(good), "--robot", emulator.path]) == 0


def test_zero_makes_the_present_pose_read_zero_and_keeps_the_old_config(emulator, capsys, tmp_path):
    from devices.config import load_config

    config = tmp_path / "lab.toml"
    original = (Path(__file__).resolve().parents[2] / "resources" / "default_lab.toml").read_text()
    config.write_text(original.replace('port = "sim"                 # U2D2', f'port = "{emulator.path}"  # U2D2', 1))
    emulator.command("push 3 200")  # the robot laid "straight" by hand, joint 3 off by 200 ticks (0.307 rad)
    emulator.command("push 8 -100")
    assert main(["servo", "zero", "--robot", emulator.path, "--config", str(config), "--dry-run"]) == 0
    assert capsys.readouterr().out.count("\n") == 13 and config.read_text() == original.replace(
        'port = "sim"                 # U2D2', f'port = "{emulator.path}"  # U2D2', 1)  # a dry run writes nothing
    assert main(["servo", "zero", "--robot", emulator.path, "--config", str(config)]) == 0
    err = capsys.readouterr().err
    backup = tmp_path / "lab.toml.bak-1"
    assert backup.exists() and "kept as" in err and str(backup) in err
    robot = load_config(config).robot
    assert robot.zero_offsets_rad[2] == pytest.approx(-200 * 2 * 3.141592653589793 / 4096, abs=2e-3)
    assert robot.zero_offsets_rad[7] == pytest.approx(100 * 2 * 3.141592653589793 / 4096, abs=2e-3)
    assert "# U2D2" in config.read_text() and "# head first" in config.read_text()  # the other lines kept
    with ServoChain(robot) as chain:  # the pose now reads 0 on every joint
        assert max(abs(a) for a in chain.read_state().position_rad) < 2e-3
    assert main(["servo", "zero", "--robot", emulator.path, "--config", str(config)]) == 0
    assert (tmp_path / "lab.toml.bak-2").exists() and backup.exists()  # a second backup, never over the first
    assert main(["servo", "zero", "--robot", emulator.path]) == 1
    assert "needs --config" in capsys.readouterr().err
    emulator.command("overload 4")  # found while nothing moves: never "motion stopped"
    assert main(["servo", "zero", "--robot", emulator.path, "--config", str(config)]) == 1
    err = capsys.readouterr().err
    assert "servo 4 overload: found while reading the pose" in err and "motion" not in err
    assert not (tmp_path / "lab.toml.bak-3").exists()


def test_an_id_change_refuses_an_id_already_on_the_bus_and_moves_the_servo_otherwise(emulator, capsys):
    assert main(["servo", "set", "--robot", emulator.path, "--id", "12", "ID", "11"]) == 1
    assert "ID 11 is already on the bus" in capsys.readouterr().err
    assert main(["servo", "set", "--robot", emulator.path, "--id", "12", "ID", "20"]) == 0
    assert "ID 12 → 20 (read back)" in capsys.readouterr().out
    assert main(["scan", "--robot", emulator.path]) == 0
    out = capsys.readouterr()
    assert "ID  20" in out.out and "ID(s) 12 did not answer" in out.err


def test_a_factory_reset_asks_for_yes_and_keeps_the_id_and_baud(emulator, capsys):
    assert main(["servo", "set", "--robot", emulator.path, "--id", "5", "Position P Gain", "300"]) == 0
    assert main(["servo", "set", "--robot", emulator.path, "--id", "5", "Return Delay Time", "0"]) == 0
    capsys.readouterr()
    resets = emulator.counts()["reset"]
    assert main(["servo", "reset", "--robot", emulator.path, "--id", "5"]) == 1  # not without --yes
    assert "add --yes" in capsys.readouterr().err and emulator.counts()["reset"] == resets
    assert main(["servo", "reset", "--robot", emulator.path, "--id", "5", "--yes"]) == 0
    assert emulator.counts()["reset"] == resets + 1
    capsys.readouterr()
    assert main(["servo", "get", "--robot", emulator.path, "--id", "5", "Position P Gain"]) == 0
    assert " 800 " in capsys.readouterr().out  # back at the factory value, at the same ID and baud rate
    assert emulator.state(5)["rdt"] == 250


def test_a_labs_servo_profile_writes_only_what_differs_on_the_emulator(emulator):
    """The [servos] profile the app applies on connect (app.core.servo_settings.apply_profile), on the emulator: one
    table read per servo, a write only where a servo differs, EEPROM items with torque off and back on."""
    from app.core import servo_settings

    profile = [("Position P Gain", 640), ("Return Delay Time", 0)]
    with ServoChain(dataclasses.replace(RobotConfig(), port=emulator.path)) as chain:
        chain.set_torque(True, [4])
        reads, writes = emulator.counts()["read"], emulator.counts()["write"]
        changes = servo_settings.apply_profile(chain, [3, 4], profile)
        written = {(c.servo_id, c.item) for c in changes if c.written}
        assert emulator.counts()["read"] >= reads + 2  # at least the one table read per servo
        assert ("Position P Gain" in {item for _, item in written}) and emulator.state(4)["torque"] == 1
        again = servo_settings.apply_profile(chain, [3, 4], profile)
        assert not any(c.written for c in again)
        writes_after = emulator.counts()["write"]
        servo_settings.apply_profile(chain, [3, 4], profile)
        assert emulator.counts()["write"] == writes_after  # read-compare: nothing differs, nothing sent
    assert writes_after > writes
    assert "written on servo(s) 3, 4" in servo_settings.describe_changes(changes)


def test_a_baud_rate_change_finds_the_servo_at_its_new_rate_and_says_what_to_do(emulator, capsys):
    """Wizard's "change baud": the servo is written (torque off), found at its new rate and read back there; the bus
    keeps its own rate, so the servo no longer answers on it until the host switches too."""
    with ServoChain(dataclasses.replace(RobotConfig(), port=emulator.path)) as chain:
        chain.set_torque(True, [6])
    capsys.readouterr()
    assert main(["servo", "set", "--robot", emulator.path, "--id", "6", "Baud Rate", "1"]) == 0
    out, err = capsys.readouterr()
    assert "Baud Rate 3 → 1" in out and "now talks at 57600 bps" in err and "--baud 57600" in err
    assert emulator.state(6)["torque"] == 0
    # At the bus's 1 Mbps servo 6 is silent; at 57600 it is the only one that answers.
    assert main(["scan", "--robot", emulator.path, "--baud", "1000000"]) == 0
    found = [line.split()[1] for line in capsys.readouterr().out.splitlines() if line.startswith("ID")]
    assert found == [str(i) for i in range(1, 13) if i != 6]
    assert main(["scan", "--robot", emulator.path, "--baud", "57600"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("ID")]
    assert [line.split()[1] for line in lines] == ["6"] and "57600 bps" in lines[0]
    # And back, from its new rate.
    assert main(["servo", "set", "--robot", emulator.path, "--baud", "57600", "--id", "6", "Baud Rate", "3"]) == 0
    with ServoChain(dataclasses.replace(RobotConfig(), port=emulator.path)) as chain:
        assert chain.read_item(6, "Baud Rate") == 3


TWO_JOINTS = """[robot]
port = "{port}"
joint_ids = [1, 2]
axes = ["pitch", "yaw"]
signs = [1, 1]
zero_offsets_rad = [0.0, 0.0]
joint_min_rad = [-1.57, -1.57]
joint_max_rad = [1.57, 1.57]
"""


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_reboot_torque_and_led_with_the_port_from_the_config(tmp_path, capsys):
    process = EmulatorProcess("--ids", "1-2")
    try:
        config = tmp_path / "lab.toml"
        config.write_text(TWO_JOINTS.format(port=process.path))  # no --robot below: the config's port
        assert main(["scan", "--config", str(config)]) == 0
        scanned = capsys.readouterr()
        assert [line.split()[:2] for line in scanned.out.splitlines()] == [["ID", "1"], ["ID", "2"]], scanned
        assert scanned.err == ""
        process.command("overload 2")
        reboots = process.counts()["reboot"]
        assert main(["servo", "reboot", "--all", "--config", str(config)]) == 0
        out = capsys.readouterr().out
        assert "servo 2: rebooted (torque off); Hardware Error Status 32 (overload) → 0 (no error)" in out
        assert "servo 1: rebooted" in out and process.counts()["reboot"] == reboots + 2
        assert process.state(2)["hw_error"] == 0  # the latched overload is cleared
        with pytest.raises(SystemExit) as exit_info:  # which servos? a reboot drops them: never implied
            main(["servo", "reboot", "--config", str(config)])
        assert exit_info.value.code == 2 and "--id N" in one_error_line(capsys)

        assert main(["servo", "torque", "on", "--config", str(config)]) == 0
        assert process.state(1)["torque"] == 1 and process.state(2)["torque"] == 1
        assert main(["servo", "torque", "off", "--config", str(config), "--id", "2"]) == 0
        assert process.state(1)["torque"] == 1 and process.state(2)["torque"] == 0
        assert main(["servo", "led", "on", "--config", str(config), "--id", "2"]) == 0
        assert main(["servo", "get", "--config", str(config), "--id", "2", "LED"]) == 0
        assert capsys.readouterr().out.split("\n")[-2].split()[5] == "1"  # the LED item reads 1

        process.command("overload 1")  # an error found while idle: never "motion stopped"
        assert main(["servo", "torque", "on", "--config", str(config), "--id", "1"]) == 1
        line = one_error_line(capsys)
        assert "servo 1 overload" in line and "sensnake servo reboot --id 1" in line and "motion" not in line
        assert main(["servo", "get", "--config", str(config), "--id", "254"]) == 1
        assert "not a servo ID" in one_error_line(capsys)
    finally:
        assert process.close() == 0


def test_a_servo_answering_only_pings_is_brought_back_by_reset_and_never_set_so(emulator, capsys):
    writes = emulator.counts()["write"]
    for item, value in (("Status Return Level", "0"), ("Status Return Level", "1"), ("Protocol Type", "1")):
        assert main(["servo", "set", "--robot", emulator.path, "--id", "4", item, value]) == 1
        assert "would cut the app off" in one_error_line(capsys)
    assert emulator.counts()["write"] == writes
    with ServoChain(dataclasses.replace(RobotConfig(), port=emulator.path)) as chain:
        chain.write_item(4, "Status Return Level", 0)  # as another tool could leave it: it answers pings only
    assert main(["servo", "get", "--robot", emulator.path, "--id", "4", "ID"]) == 1
    capsys.readouterr()
    assert main(["servo", "reset", "--robot", emulator.path, "--id", "4", "--yes"]) == 0  # no status packet: fine
    assert main(["servo", "get", "--robot", emulator.path, "--id", "4", "Status Return Level"]) == 0
    assert " 2 " in capsys.readouterr().out


def test_scan_finds_a_servo_answering_only_pings_and_says_what_its_level_means(emulator, capsys):
    robot = dataclasses.replace(RobotConfig(), port=emulator.path)
    with ServoChain(robot) as chain:  # as another tool could leave them
        chain.write_item(4, "Status Return Level", 0)  # answers PING only
        chain.write_item(6, "Status Return Level", 1)  # PING and READ
    assert main(["scan", "--robot", emulator.path]) == 0  # a broadcast ping, then each servo found on its own
    out = capsys.readouterr()
    lines = {int(line.split()[1]): line for line in out.out.splitlines() if line.startswith("ID")}
    assert sorted(lines) == list(range(1, 13))  # none hidden
    assert lines[4].endswith("Status Return Level 0: pings only") and "firmware 48" in lines[4]
    assert lines[6].endswith("Status Return Level 1: pings and reads only")
    assert "Status Return Level" not in lines[5]
    warnings = out.err.splitlines()
    assert len(warnings) == 2, warnings
    assert "servo 4 has Status Return Level 0: it answers pings only" in warnings[0]
    assert "sensnake servo reboot --id 4" in warnings[0] and "refuses to connect" in warnings[0]
    assert "servo 6 has Status Return Level 1" in warnings[1]
    with ServoChain(robot) as chain:
        found = chain.scan(ids=range(1, 13))  # the short list: a ping per ID
        assert [(i.servo_id, i.status_return_level) for i in found] == [
            (i, {4: 0, 6: 1}.get(i, 2)) for i in range(1, 13)]
        with pytest.raises(StatusReturnLevelError) as refused:  # connecting: the level, never "check its cable"
            chain.check_models()
    assert "servo 4 has Status Return Level 0" in str(refused.value) and "cable" not in str(refused.value)
    for sid in (4, 6):  # the level lives in RAM: a restart brings 2 back
        assert main(["servo", "reboot", "--robot", emulator.path, "--id", str(sid)]) == 0
    capsys.readouterr()
    assert main(["scan", "--robot", emulator.path]) == 0
    out = capsys.readouterr()
    assert "Status Return Level" not in out.out + out.err and len(out.out.splitlines()) == 12


def changed(document: dict, sid: str = "3", **items: int) -> dict:
    copy = json.loads(json.dumps(document))
    copy["servos"][sid]["items"].update(items)
    return copy


def test_restore_checks_the_whole_file_against_the_servos_before_writing(emulator, capsys, tmp_path):
    saved = tmp_path / "servos.json"
    assert main(["servo", "dump", "--robot", emulator.path, "--out", str(saved)]) == 0
    document = json.loads(saved.read_text())
    assert main(["servo", "set", "--robot", emulator.path, "--id", "3", "Position P Gain", "300"]) == 0
    other_model = changed(document, "12")
    other_model["servos"]["12"]["model_number"] = other_model["servos"]["12"]["items"]["Model Number"] = 1200
    with_13 = json.loads(json.dumps(document))
    with_13["servos"]["13"] = document["servos"]["12"]
    broadcast = json.loads(json.dumps(document))
    broadcast["servos"]["254"] = broadcast["servos"].pop("12")
    misspelt = changed(document, "12")
    misspelt["servos"]["12"]["items"]["Positon P Gain"] = 700
    cases = {
        "model.json": (other_model, ("servo 12", "model 1200", "model 1020", "nothing written")),
        "with13.json": (with_13, ("servo 13", "does not answer", "nothing written")),
        "broadcast.json": (broadcast, ("'254'", "not a servo ID", "broadcast")),
        "misspelt.json": (misspelt, ("servo 12", "'Positon P Gain'", "did you mean 'Position P Gain'")),
        "range.json": (changed(document, "12", **{"Velocity Limit": 5000}), ("servo 12", "Velocity Limit", "range")),
        "limits.json": (changed(document, "12", **{"Min Position Limit": 3000, "Max Position Limit": 1000}),
                        ("servo 12", "Min Position Limit = 3000 is above Max Position Limit = 1000")),
        "silent.json": (changed(document, "12", **{"Status Return Level": 0}), ("servo 12", "cut the app off")),
    }
    capsys.readouterr()
    writes = emulator.counts()["write"]
    for name, (content, words) in cases.items():
        (tmp_path / name).write_text(json.dumps(content))
        assert main(["servo", "restore", str(tmp_path / name), "--robot", emulator.path]) == 1, name
        line = one_error_line(capsys)
        assert all(word in line for word in words), (name, line)
    # servo 3 comes first in every file, its change was never written: the checks ran before any write
    assert emulator.counts()["write"] == writes and emulator.state(3)["goal_writes"] == 0
    capsys.readouterr()
    assert main(["servo", "restore", str(tmp_path / "with13.json"), "--robot", emulator.path, "--id", "3"]) == 0
    assert "servo 3: Position P Gain 300 → 800" in capsys.readouterr().out  # the servos chosen are checked


def test_a_servo_refusing_midway_names_what_was_and_was_not_written(emulator, capsys, tmp_path, monkeypatch):
    from devices.errors import ERRNUM_DATA_LIMIT, ServoCommandError

    saved = tmp_path / "servos.json"
    assert main(["servo", "dump", "--robot", emulator.path, "--out", str(saved)]) == 0
    for sid, item, value in ((3, "Position P Gain", "300"), (5, "Velocity Limit", "100"),
                             (5, "Position P Gain", "300"), (7, "Position P Gain", "300")):
        assert main(["servo", "set", "--robot", emulator.path, "--id", str(sid), item, value]) == 0
    capsys.readouterr()
    write_item = ServoChain.write_item

    def refusing(self, servo_id, name, value, **kwargs):  # a servo whose firmware refuses this value
        if (servo_id, name) == (5, "Velocity Limit"):
            raise ServoCommandError(servo_id, ERRNUM_DATA_LIMIT, f"writing {name} = {value}")
        return write_item(self, servo_id, name, value, **kwargs)

    monkeypatch.setattr(ServoChain, "write_item", refusing)
    assert main(["servo", "restore", str(saved), "--robot", emulator.path]) == 1
    line = one_error_line(capsys)
    assert "restore stopped at servo 5, Velocity Limit = 200" in line and "data limit error" in line
    assert "Written: servo 3 (Position P Gain)." in line
    assert "Not written: servo 5 (Velocity Limit, Position P Gain); servo 7 (Position P Gain)" in line
    monkeypatch.undo()
    with ServoChain(dataclasses.replace(RobotConfig(), port=emulator.path)) as chain:
        assert [chain.read_item(s, "Position P Gain") for s in (3, 5, 7)] == [800, 300, 300]  # as the line says


def test_settings_and_config_writers_never_clobber_nor_follow_links(emulator, capsys, tmp_path):
    existing = tmp_path / "servos.json"
    existing.write_text("keep")
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    dangling = tmp_path / "link.json"
    dangling.symlink_to(tmp_path / "nowhere.json")
    for out, words in ((existing, "never written over"), (fifo, "is a FIFO"), (dangling, "exists")):
        assert main(["servo", "dump", "--robot", emulator.path, "--out", str(out)]) == 1
        line = one_error_line(capsys)
        assert str(out) in line and words in line, line
    assert existing.read_text() == "keep" and not (tmp_path / "nowhere.json").exists()

    real = tmp_path / "real.toml"
    original = (Path(__file__).resolve().parents[2] / "resources" / "default_lab.toml").read_text()
    real.write_text(original)
    config = tmp_path / "lab.toml"
    config.symlink_to(real)  # the lab keeps its config behind a link: it is rewritten where it lives
    planted = tmp_path / "planted.txt"
    (tmp_path / "real.toml.bak-1").symlink_to(planted)  # a dangling link where a backup would go
    emulator.command("push 3 100")
    assert main(["servo", "zero", "--robot", emulator.path, "--config", str(config)]) == 0
    assert config.is_symlink() and "zero_offsets_rad = [0.0, 0.0, -0.1534" in real.read_text()
    assert not planted.exists() and (tmp_path / "real.toml.bak-2").read_text() == original
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")], "temporary left behind"
    capsys.readouterr()
    assert main(["servo", "zero", "--robot", emulator.path, "--config", str(fifo)]) == 1  # never read (blocks)
    assert "is a FIFO" in one_error_line(capsys)
