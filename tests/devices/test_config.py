"""Lab configuration: the packaged default loads, and every kind of mistake names its key."""

from __future__ import annotations

import os
import re
from dataclasses import replace

import pytest

from devices.config import (
    BoardConfig,
    LabConfig,
    RigConfig,
    RobotConfig,
    default_sensor_names,
    load_config,
    parse_config,
)
from devices.errors import ConfigError


def test_default_config_is_the_simulated_lab():
    config = load_config()
    assert config.robot.port == "sim" and config.board.port == "sim" and config.rig.port == "sim"
    assert config.robot.joint_ids == tuple(range(1, 13))
    assert config.robot.axes[:2] == ("pitch", "yaw")
    assert config.board.channel_names[:4] == ("S01L", "S01R", "S01B", "S02L")
    assert config.board.n_channels == 36
    assert config.rig.spring_k_n_per_m == 246.0
    assert "[robot]" in config.source_text
    assert config.lab.physics == "mujoco" and LabConfig().lab.physics == "mujoco"  # the physics lab by default


def test_sensor_names_follow_the_channel_rule():
    names = default_sensor_names()
    # channel k = 3·(segment−1) + {L:0, R:1, B:2}
    assert names[3 * (6 - 1) + 2] == "S06B"
    assert names[3 * (12 - 1) + 0] == "S12L"


def test_partial_file_keeps_defaults():
    config = parse_config('[robot]\nport = "/dev/ttyUSB0"\n')
    assert config.robot.port == "/dev/ttyUSB0"
    assert config.robot.baud == LabConfig().robot.baud
    assert config.board == LabConfig().board


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[robot]\nbaud = 'fast'\n", "robot.baud"),
        ("[robot]\njoint_ids = [1, 2, 2]\n", "robot.joint_ids"),
        ("[robot]\njoint_ids = [1, 2, 300]\nsigns=[1,1,1]\naxes=['pitch','yaw','pitch']\n"
         "zero_offsets_rad=[0.0,0.0,0.0]\njoint_min_rad=[-1.0,-1.0,-1.0]\njoint_max_rad=[1.0,1.0,1.0]\n",
         "robot.joint_ids[2]"),
        ("[robot]\naxes = ['pitch']\n", "robot.axes"),
        ("[robot]\nsigns = [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 2]\n", "robot.signs[11]"),
        ("[robot]\njoint_min_rad = [2.0, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1]\n", "robot.joint_min_rad[0]"),
        ("[robot]\nspeed = 3\n", "robot.speed"),
        ("[board]\nr_c_ohm = -900.0\n", "board.r_c_ohm"),
        ("[board]\nchannel_names = ['A', 'A']\n", "board.channel_names"),
        ("[rig]\nspring_k_n_per_m = 0\n", "rig.spring_k_n_per_m"),
        ("[rig]\nwheel_radius_m = nan\n", "rig.wheel_radius_m"),
        ("[robots]\n", "robots"),
    ],
)
def test_invalid_config_names_the_key(text, key):
    with pytest.raises(ConfigError) as info:
        parse_config(text, source="lab.toml")
    message = str(info.value)
    assert key in message
    assert message.startswith("lab.toml")


def test_broken_toml_and_missing_file_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        parse_config("[robot\n")
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(tmp_path / "missing.toml")


def test_config_error_is_a_value_error():
    assert issubclass(ConfigError, ValueError)


@pytest.mark.parametrize(("build", "key"), [
    (lambda: replace(RobotConfig(), control_rate_hz=5000.0), "robot.control_rate_hz"),
    (lambda: replace(RobotConfig(), joint_ids=(1, 2, 2) + tuple(range(4, 13))), "robot.joint_ids"),
    (lambda: replace(BoardConfig(), baud=-1), "board.baud"),
    (lambda: replace(BoardConfig(), channel_names=()), "board.channel_names"),
    (lambda: replace(RigConfig(), spring_k_n_per_m=0.0), "rig.spring_k_n_per_m"),
    (lambda: LabConfig().with_ports(board="   "), "board.port"),
    (lambda: RobotConfig(port=""), "robot.port"),
])
def test_a_config_built_without_a_file_is_validated_too(build, key):
    """dataclasses.replace (command-line overrides such as play --rate), with_ports and plain construction run the
    same checks as loading a file: there is no unchecked config."""
    with pytest.raises(ConfigError, match=re.escape(key)):
        build()


def test_a_file_error_still_names_the_file_and_the_key(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text('[board]\nport = ""\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: board\.port "):
        load_config(path)


def test_a_scene_named_relative_to_the_config_file_is_found_beside_it(tmp_path):
    from devices.config import load_config

    (tmp_path / "my_scene.toml").write_text("[ground]\nfriction = 0.5\n", encoding="utf-8")
    (tmp_path / "lab.toml").write_text('[lab]\nscene = "my_scene.toml"\n', encoding="utf-8")
    config = load_config(tmp_path / "lab.toml")
    assert config.lab.scene == str(tmp_path / "my_scene.toml")
    (tmp_path / "lab2.toml").write_text('[lab]\nscene = "step"\n', encoding="utf-8")
    assert load_config(tmp_path / "lab2.toml").lab.scene == "step"  # a built-in scene's name is kept


def test_a_servos_profile_that_would_cut_the_app_off_is_refused_with_the_reason(tmp_path):
    for value in (0, 1):
        with pytest.raises(ConfigError, match=f"servos.status_return_level = {value} would cut the app off"):
            parse_config(f"[servos]\nstatus_return_level = {value}\n", source="lab.toml")
    assert parse_config("[servos]\nstatus_return_level = 2\n").servos == (("Status Return Level", 2),)
    fifo = tmp_path / "lab.toml"
    os.mkfifo(fifo)  # never opened: reading it would block
    with pytest.raises(ConfigError, match="is a FIFO, not a lab configuration"):
        load_config(fifo)
