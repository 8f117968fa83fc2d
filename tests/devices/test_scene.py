"""Scene files (SPEC §6, devices/scene.py): read key by key, refused with the file, the key and the problem named."""

from __future__ import annotations

import math

import pytest

from devices.errors import SceneError
from devices.scene import SCENES_DIR, load_scene, parse_scene

GOOD = """
[ground]
friction = 0.25
[[obstacle]]
shape = "half_cylinder"
x_m = 0.0
radius_m = 0.27
friction = 0.1
[[obstacle]]
shape = "box"
x_m = 0.8
length_m = 0.3
height_m = 0.08
[[obstacle]]
shape = "wedge"
x_m = -0.6
length_m = 0.4
height_m = 0.1
friction = 0.2
[robot]
head_x_m = -0.2
start = "flat"
"""


def test_a_scene_reads_every_shape_and_the_robot_start():
    scene = parse_scene(GOOD, "good.toml")
    assert scene.ground_friction == 0.25
    cylinder, box, wedge = scene.obstacles
    assert (cylinder.shape, cylinder.radius_m, cylinder.friction) == ("half_cylinder", 0.27, 0.1)
    assert box.friction == 0.25  # an obstacle without its own friction takes the ground's
    assert (wedge.length_m, wedge.height_m) == (0.4, 0.1)
    assert scene.head_x_m == -0.2 and scene.start == "flat"
    assert scene.far_edge_m == pytest.approx(0.95)


def test_the_grounds_roll_resistance_defaults_to_the_shells_contact_patch_and_survives_a_round_trip():
    from devices.scene import GROUND_ROLL_M, scene_to_toml
    assert abs(GROUND_ROLL_M - math.sqrt(2 * 0.036 * 0.001)) < 1e-4  # sqrt(2 R d), d = 1 mm
    assert parse_scene(GOOD).ground_roll_m == GROUND_ROLL_M
    free = parse_scene("[ground]\nfriction = 0.3\nroll_resistance_m = 0\n")  # round shells rolling freely
    assert free.ground_roll_m == 0.0
    assert parse_scene(scene_to_toml(free)).ground_roll_m == 0.0
    assert parse_scene(scene_to_toml(parse_scene(GOOD))).ground_roll_m == GROUND_ROLL_M


def test_an_obstacles_roll_resistance_is_the_grounds_unless_it_names_its_own_and_survives_a_round_trip():
    from devices.scene import GROUND_ROLL_M, scene_to_toml
    assert {o.roll_resistance_m for o in parse_scene(GOOD).obstacles} == {GROUND_ROLL_M}
    text = ("[ground]\nroll_resistance_m = 0\n[[obstacle]]\nshape = 'box'\nx_m = 0\nlength_m = 0.3\nheight_m = 0.1\n"
            "[[obstacle]]\nshape = 'half_cylinder'\nx_m = 1\nradius_m = 0.2\nroll_resistance_m = 0.004\n")
    free_box, cylinder = parse_scene(text).obstacles
    assert free_box.roll_resistance_m == 0.0 and cylinder.roll_resistance_m == 0.004  # the ground's, its own
    again = parse_scene(scene_to_toml(parse_scene(text))).obstacles
    assert [o.roll_resistance_m for o in again] == [0.0, 0.004]


def test_the_contact_onset_is_mujocos_default_unless_named_refused_out_of_range_and_survives_a_round_trip():
    import mujoco

    from devices.scene import scene_to_toml
    from devices.sim.physics.model import SceneParams, build_mjcf
    assert parse_scene(GOOD).contact_onset_m is None
    soft = parse_scene("[ground]\ncontact_onset_m = 0.0003\n" + GOOD.split("[ground]")[1].split("\n", 1)[1], "s.toml")
    assert soft.contact_onset_m == 0.0003
    assert parse_scene(scene_to_toml(soft)).contact_onset_m == 0.0003
    with pytest.raises(SceneError, match=r"s\.toml \[ground\].*contact_onset_m.*outside"):
        parse_scene("[ground]\ncontact_onset_m = 0.1\n", "s.toml")
    with pytest.raises(SceneError, match=r"s\.toml \[ground\]: 'contact_onset_m' needs 'roll_resistance_m' > 0"):
        parse_scene("[ground]\ncontact_onset_m = 0.0003\nroll_resistance_m = 0\n", "s.toml")
    with pytest.raises(SceneError, match=r"s\.toml \[\[obstacle\]\] #1: 'roll_resistance_m' = 0 leaves it"):
        parse_scene("[ground]\ncontact_onset_m = 0.0003\n[[obstacle]]\nshape = 'box'\nx_m = 0\nlength_m = 0.3\n"
                    "height_m = 0.1\nroll_resistance_m = 0\n", "s.toml")
    model = mujoco.MjModel.from_xml_string(build_mjcf(SceneParams(terrain_scene=soft)))
    impedance = {model.geom(int(g)).name: tuple(model.pair_solimp[k, :3])
                 for k, g in enumerate(model.pair_geom1)}
    assert impedance["ground"] == impedance["obstacle1"] == impedance["obstacle2"] == (0.0, 0.95, 0.0003)
    assert impedance["obstacle3"] == (0.9, 0.95, 0.001)  # the wedge, a mesh, keeps MuJoCo's default


def test_the_height_profile_follows_each_shape():
    scene = parse_scene(GOOD)
    assert scene.height_at(0.0) == pytest.approx(0.27)  # the cylinder's top
    assert scene.height_at(0.27 * math.sqrt(0.5)) == pytest.approx(0.27 * math.sqrt(0.5))
    assert scene.height_at(0.8) == pytest.approx(0.08)  # on the step
    assert scene.height_at(-0.8) == pytest.approx(0.0)  # the wedge's back edge: it rises toward +x …
    assert scene.height_at(-0.6) == pytest.approx(0.05)
    assert scene.height_at(-0.4001) == pytest.approx(0.1, abs=1e-3)  # … to its height at its front edge
    assert scene.height_at(2.0) == 0.0
    assert scene.max_height_between(-1.0, 1.0) == pytest.approx(0.27, abs=1e-3)


@pytest.mark.parametrize(("text", "words"), [
    ("[ground]\nfriction = 0.3\ncolour = 1\n", ["bad.toml", "[ground]", "unknown key 'colour'"]),
    ("[[obstacle]]\nshape = 'box'\nx_m = 0\nlength_m = 0.3\nheight_m = 0.1\nradius_m = 2\n",
     ["[[obstacle]] #1", "unknown key 'radius_m'"]),
    ("[[obstacle]]\nshape = 'cone'\nx_m = 0\n", ["'shape' must be one of", "'cone'"]),
    ("[[obstacle]]\nshape = 'box'\nx_m = 0\nheight_m = 0.1\n", ["missing key 'length_m'"]),
    ("[[obstacle]]\nshape = 'half_cylinder'\nx_m = 0\nradius_m = -1\n", ["'radius_m' = -1 is outside"]),
    # a size that rounds to 0 in the model's text made MuJoCo fail with "size 0 must be positive in geom"; a plate
    # thinner than the contact model resolves is no terrain a run can measure on (devices.scene.RESOLVED_DEPTH_M)
    ("[[obstacle]]\nshape = 'box'\nx_m = 0\nlength_m = 1e-9\nheight_m = 5\n",
     ["'length_m' = 1e-09 m is thinner than the physics lab's contact model resolves (at least 0.005 m"]),
    ("[[obstacle]]\nshape = 'box'\nx_m = 0.3\nlength_m = 0.5\nheight_m = 0.001\n",
     ["'height_m' = 0.001 m is thinner than the physics lab's contact model resolves (at least 0.005 m"]),
    ("[ground]\ncontact_onset_m = 0.003\n[[obstacle]]\nshape = 'half_cylinder'\nx_m = 0\nradius_m = 0.008\n",
     ["'radius_m' = 0.008 m is thinner", "(at least 0.009 m"]),  # 3 × the onset a shell sinks by design
    ("[[obstacle]]\nshape = 'wedge'\nx_m = 0\nlength_m = 0.3\nheight_m = 0\n", ["'height_m' = 0 is outside"]),
    ("[[obstacle]]\nshape = 'half_cylinder'\nx_m = 'left'\nradius_m = 1\n", ["'x_m' must be a number"]),
    ("[ground]\nfriction = nan\n", ["'friction' = nan is outside"]),
    ("[ground]\nroll_resistance_m = 0.05\n", ["'roll_resistance_m' = 0.05 is outside [0, 0.036]"]),
    ("[[obstacle]]\nshape = 'wedge'\nx_m = 0\nlength_m = 0.3\nheight_m = 0.1\nroll_resistance_m = -0.001\n",
     ["[[obstacle]] #1", "'roll_resistance_m' = -0.001 is outside [0, 0.036]"]),
    ("[robot]\nstart = 'fly'\n", ["'start' must be one of"]),
    ("[terrain]\n", ["unknown key 'terrain'"]),
    ("[ground\n", ["bad.toml", "not valid TOML"]),
])
def test_a_bad_scene_is_refused_in_one_line_naming_the_file_and_the_key(text, words):
    with pytest.raises(SceneError) as refused:
        parse_scene(text, "bad.toml")
    message = str(refused.value)
    assert "\n" not in message
    for word in words:
        assert word in message


def test_files_that_are_not_scenes_are_refused_by_name(tmp_path):
    with pytest.raises(SceneError, match="scene file not found.*built-in scenes: .*paper_obstacle"):
        load_scene(tmp_path / "missing.toml")
    with pytest.raises(SceneError, match="is a folder"):
        load_scene(tmp_path)
    binary = tmp_path / "x.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SceneError, match="x.toml: not a UTF-8 text file"):
        load_scene(binary)


def test_the_built_in_scenes_load_by_name_and_the_paper_obstacle_is_the_legacy_default():
    names = sorted(p.stem for p in SCENES_DIR.glob("*.toml"))
    assert {"paper_obstacle", "flat", "step", "wedge", "two_obstacles"} <= set(names)
    for name in names:
        assert load_scene(name).name == name
    paper = load_scene("paper_obstacle")
    (cylinder,) = paper.obstacles
    assert cylinder.radius_m == pytest.approx(0.28 * 0.96)  # the lab config's obstacle_height_ratio default
    assert cylinder.friction == 0.1 and paper.ground_friction == 0.3
