"""``[lab.physics]``: the physics lab's physical parameters as data, validated at load, routed into the MuJoCo model
with the defaults the lab had as constants, and stored in a recording's ``/sim``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from devices.config import LabConfig, LabPhysicsConfig, parse_config
from devices.errors import ConfigError

mujoco = pytest.importorskip("mujoco")


def test_the_defaults_are_the_constants_the_model_had() -> None:
    from devices.scene import GROUND_ROLL_M
    from devices.sim.physics.model import SceneParams, ServoParams, ShellParams

    physical = LabPhysicsConfig()
    servo, shell, scene = ServoParams(), ShellParams(), SceneParams()
    assert physical.servo_position_gain_nm_per_rad == servo.position_gain_nm_per_rad
    assert physical.servo_damping_nm_s_per_rad == servo.damping_nm_s_per_rad
    assert physical.servo_armature_kg_m2 == servo.armature_kg_m2
    assert physical.servo_friction_loss_nm == servo.friction_loss_nm
    assert physical.servo_stall_torque_nm == servo.stall_torque_nm
    assert physical.servo_no_load_speed_rad_s == servo.no_load_speed_rad_s
    assert (physical.shell_stiffness_n_per_m, physical.shell_damping_n_s_per_m, physical.shell_mass_kg,
            physical.shell_travel_m) == (shell.stiffness_n_per_m, shell.damping_n_s_per_m, shell.mass_kg,
                                         shell.travel_m)
    assert physical.timestep_s == scene.timestep_s
    assert (physical.contact_time_constant_s, physical.contact_damping_ratio) == scene.contact_solref
    assert physical.roll_resistance_m == GROUND_ROLL_M


def test_the_default_config_builds_the_model_it_built_before() -> None:
    from devices.sim.physics.backend import scene_from_config
    from devices.sim.physics.model import SceneParams, build_mjcf

    assert build_mjcf(scene_from_config(LabConfig())) == build_mjcf(SceneParams())


def test_a_table_sets_the_values_and_selects_the_mujoco_lab() -> None:
    config = parse_config("[lab.physics]\nshell_stiffness_n_per_m = 3000\nservo_position_gain_nm_per_rad = 15\n"
                          "roll_resistance_m = 0.004\n")
    assert config.lab.physics == "mujoco"
    assert config.lab.physical.shell_stiffness_n_per_m == 3000.0
    assert config.lab.physical.shell_damping_n_s_per_m == 30.0  # left out: its default

    from devices.sim.physics.backend import scene_from_config
    from devices.sim.physics.world import PhysicsWorld

    scene = scene_from_config(config)
    world = PhysicsWorld(scene)
    shell_joint = world.model.joint("seg01_sz")
    assert float(world.model.jnt_stiffness[shell_joint.id]) == 3000.0
    assert world._kp == 15.0
    terrain = scene.terrain  # the legacy half cylinder takes the configured roll resistance
    assert terrain.ground_roll_m == 0.004 and terrain.obstacles[0].roll_resistance_m == 0.004


def test_a_scene_file_naming_its_own_roll_resistance_keeps_it(tmp_path: Path) -> None:
    from devices.sim.physics.backend import scene_from_config

    path = tmp_path / "s.toml"
    path.write_text("[ground]\nfriction = 0.4\nroll_resistance_m = 0.002\n[[obstacle]]\nshape = \"box\"\n"
                    "x_m = 0.3\nlength_m = 0.2\nheight_m = 0.05\n", encoding="utf-8")
    config = parse_config(f"[lab]\nscene = \"{path}\"\n[lab.physics]\nroll_resistance_m = 0.006\n")
    terrain = scene_from_config(config).terrain
    assert terrain.ground_roll_m == 0.002 and terrain.obstacles[0].roll_resistance_m == 0.002
    path.write_text("[ground]\nfriction = 0.4\n", encoding="utf-8")
    assert scene_from_config(config).terrain.ground_roll_m == 0.006


@pytest.mark.parametrize(("text", "named"), [
    ("[lab.physics]\nshell_stiffness_n_per_m = -1\n", "lab.physics.shell_stiffness_n_per_m"),
    ("[lab.physics]\ntimestep_s = 0.5\n", "lab.physics.timestep_s"),
    ("[lab.physics]\nservo_gain = 3\n", "lab.physics.servo_gain"),
    ("[lab.physics]\nshell_mass_kg = \"heavy\"\n", "lab.physics.shell_mass_kg"),
    ("[lab]\nphysical = 3\n", "lab.physical"),
])
def test_a_bad_value_is_refused_naming_its_key(text: str, named: str) -> None:
    with pytest.raises(ConfigError, match=named.replace(".", r"\.")):
        parse_config(text, "lab.toml")


def test_a_config_built_in_code_is_checked_too() -> None:
    with pytest.raises(ConfigError, match="lab.physics.servo_stall_torque_nm"):
        dataclasses.replace(LabPhysicsConfig(), servo_stall_torque_nm=0.0)
