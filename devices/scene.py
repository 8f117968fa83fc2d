"""Scene files: the physics lab's terrain as data (SPEC §6), read from TOML and checked key by key.

A scene is the ground's friction, any number of obstacles that span the whole width (y) — ``half_cylinder``,
``box`` (a step) and ``wedge`` (a ramp rising toward +x) — and where and how the robot starts. The robot heads toward
+x. Every length is in metres, every friction a Coulomb coefficient of the pair (robot sleeve, that surface).

:func:`load_scene` refuses a bad file with one :class:`SceneError` line naming the file, the key and the problem
(unknown keys included). :func:`Scene.height_at` is the terrain's height profile, used to place the robot above it.

Pure Python (no MuJoCo): any thread.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from devices.errors import SceneError
from devices.toml_files import parse_toml_text, read_text_file

SIDES = ("B", "L", "R")  # a segment's sheets: row order of the physics lab's loads (the scripted ContactModel's too)
SHAPES = ("half_cylinder", "box", "wedge")
STARTS = ("settle", "flat")
# The depth the physics lab's contact model resolves (devices.sim.physics.validity, where a contact held deeper than
# this ends a run as invalid): a loaded shell sinks < 1 mm into what it rests on and a landing several mm for a few
# ms (MuJoCo's soft contact), the shell travels 3 mm before it bottoms out on its housing, and a shell at 2.5 m/s (a
# fall off the paper's obstacle) moves 5 mm in one 2 ms step. A feature thinner than this — a 1 mm plate — is inside
# what the contact model blurs: the shell sinks through it or steps over it, and a run on it would measure nothing.
RESOLVED_DEPTH_M = 0.005
RESOLVED_ONSETS = 3.0  # with [ground] contact_onset_m a shell sinks deeper by design: at least this many onsets
# What the robot weighs on the scene's surfaces (SceneParams.robot_mass_kg, model.GRAVITY_M_S2: the same numbers; this
# module does not load MuJoCo): friction can hold at most mass × g × the largest friction coefficient of the scene.
ROBOT_MASS_KG = 2.4
GRAVITY_M_S2 = 9.81
SHELL_RADIUS_M = 0.036  # the paper's segment radius (SceneParams.segment_radius_m)
# Half the width of a loaded shell's flattened contact patch, sqrt(2 R d) for the shell deflecting d = 1 mm under a
# segment's share of the weight (ShellParams' assumed stiffness; docs/PHYSICS_LAB.md): the ground's default roll
# resistance. An assumption derived from another; a rig measurement of the shell's contact width replaces it.
GROUND_ROLL_M = round(math.sqrt(2 * SHELL_RADIUS_M * 0.001), 4)  # 0.0085 m
MAX_ROLL_M = SHELL_RADIUS_M  # a lever arm longer than the shell's radius is no contact patch
# [ground] contact_onset_m: from 0.05 mm (a contact near rigid, as MuJoCo's default) to 5 mm (a soft cover)
MIN_ONSET_M, MAX_ONSET_M = 0.00005, 0.005
# The most obstacles a scene may hold: MuJoCo keeps a step's contacts in a fixed arena, which 100 boxes stacked under
# the whole body overflow (mj_stackAlloc); 64 stacked boxes, half cylinders or wedges run (measured). The built-in
# scenes hold at most 2.
MAX_OBSTACLES = 64
SCENES_DIR = Path(str(resources.files("resources").joinpath("scenes")))
PAPER_SCENE = SCENES_DIR / "paper_obstacle.toml"


@dataclass(frozen=True)
class Obstacle:
    """One obstacle across the whole width. ``x_m`` is its centre along x; ``radius_m`` for a half cylinder,
    ``length_m`` (along x) and ``height_m`` for a box or a wedge."""

    shape: str
    x_m: float
    friction: float
    radius_m: float = 0.0
    length_m: float = 0.0
    height_m: float = 0.0
    # Its resistance to a shell rolling about the path's heading (x) on it, as a lever arm (m): the same flattened
    # patch as on the ground (Scene.ground_roll_m, whose value a file's obstacle takes unless it names its own).
    roll_resistance_m: float = GROUND_ROLL_M

    @property
    def x_range_m(self) -> tuple[float, float]:
        """Where along x the obstacle stands on the ground (its footprint)."""
        half = self.radius_m if self.shape == "half_cylinder" else self.length_m / 2.0
        return self.x_m - half, self.x_m + half

    @property
    def top_m(self) -> float:
        return self.radius_m if self.shape == "half_cylinder" else self.height_m

    def height_at(self, x_m: float) -> float:
        """The obstacle's surface height (m) above the ground at ``x_m`` (0 off its footprint)."""
        lo, hi = self.x_range_m
        if not lo <= x_m <= hi:
            return 0.0
        if self.shape == "half_cylinder":
            return math.sqrt(max(self.radius_m**2 - (x_m - self.x_m) ** 2, 0.0))
        if self.shape == "box":
            return self.height_m
        return self.height_m * (x_m - lo) / self.length_m  # wedge: 0 at its back edge, height_m at its front


@dataclass(frozen=True)
class Scene:
    """The terrain and the robot's start. ``name`` is the file's stem; ``text`` its TOML (stored in recordings)."""

    ground_friction: float = 0.3
    obstacles: tuple[Obstacle, ...] = ()
    # The ground's resistance to a shell rolling about its own axis, as a lever arm (m): a torque up to N times this
    # (a tipping box's half width). Default: half the width of the shell's flattened contact patch (GROUND_ROLL_M);
    # 0: round shells roll freely.
    ground_roll_m: float = GROUND_ROLL_M
    # The penetration (m) over which a terrain contact's force grows from zero to full, on the ground, half cylinders
    # and boxes (devices.sim.physics.model.soft_onset_solimp); None: MuJoCo's default impedance, 90 % at touching.
    contact_onset_m: float | None = None
    head_x_m: float | None = None  # None: the default start (see PhysicsWorld.place)
    start: str = "settle"
    name: str = "flat"
    text: str = field(default="", repr=False, compare=False)

    def height_at(self, x_m: float) -> float:
        """The terrain's height (m) at ``x_m``: the highest obstacle surface there, 0 on bare ground."""
        return max((o.height_at(x_m) for o in self.obstacles), default=0.0)

    def max_height_between(self, x0_m: float, x1_m: float, step_m: float = 0.005) -> float:
        lo, hi = min(x0_m, x1_m), max(x0_m, x1_m)
        n = max(2, int(math.ceil((hi - lo) / step_m)) + 1)
        return max(self.height_at(lo + (hi - lo) * k / (n - 1)) for k in range(n))

    @property
    def max_friction(self) -> tuple[float, str]:
        """The largest friction coefficient of the scene's surfaces and which surface has it."""
        best = (self.ground_friction, "the ground's")
        for k, o in enumerate(self.obstacles, start=1):
            if o.friction > best[0]:
                best = (o.friction, f"obstacle #{k}'s")
        return best

    def holdable_load_n(self, mass_kg: float = ROBOT_MASS_KG) -> float:
        """The largest backward pull (N) friction can hold the robot against on this scene: mass × g × the largest
        friction coefficient (the whole weight on the grippiest surface; a tail load beyond it drags the robot
        backward whatever it does)."""
        return mass_kg * GRAVITY_M_S2 * self.max_friction[0]

    def refuse_unholdable_load(self, load_n: float, what: str, mass_kg: float = ROBOT_MASS_KG) -> None:
        """Raise :class:`SceneError` (a ValueError) when ``load_n`` is more than :meth:`holdable_load_n`, naming
        ``what`` (the option or key), the scene and the formula."""
        limit = self.holdable_load_n(mass_kg)
        if load_n > limit:
            mu, surface = self.max_friction
            raise SceneError(
                f"{what} {load_n:g} N is more than friction can hold on scene {self.name}: {mass_kg:g} kg × "
                f"{GRAVITY_M_S2:g} m/s² × μ {mu:g} (the largest friction coefficient of the scene, {surface}) = "
                f"{limit:.2f} N; beyond it the robot is dragged backward whatever it does")

    @property
    def far_edge_m(self) -> float:
        """The x of the far (+x) edge of the last obstacle (what a traversal must pass); −inf on flat ground."""
        return max((o.x_range_m[1] for o in self.obstacles), default=-math.inf)


def scene_to_toml(scene: Scene) -> str:
    """The scene file that reads back as ``scene`` (SPEC §6)."""
    lines = ["[ground]", f"friction = {scene.ground_friction!r}"]
    lines.append(f"roll_resistance_m = {scene.ground_roll_m!r}")
    if scene.contact_onset_m is not None:
        lines.append(f"contact_onset_m = {scene.contact_onset_m!r}")
    for o in scene.obstacles:
        lines += ["", "[[obstacle]]", f'shape = "{o.shape}"', f"x_m = {o.x_m!r}"]
        if o.shape == "half_cylinder":
            lines.append(f"radius_m = {o.radius_m!r}")
        else:
            lines += [f"length_m = {o.length_m!r}", f"height_m = {o.height_m!r}"]
        lines.append(f"friction = {o.friction!r}")
        lines.append(f"roll_resistance_m = {o.roll_resistance_m!r}")
    lines += ["", "[robot]", f'start = "{scene.start}"']
    if scene.head_x_m is not None:
        lines.append(f"head_x_m = {scene.head_x_m!r}")
    return "\n".join(lines) + "\n"


def half_cylinder_scene(radius_m: float, friction: float, ground_friction: float, name: str = "",
                        roll_m: float = GROUND_ROLL_M) -> Scene:
    """The paper's terrain (one half cylinder at x = 0) from the lab config's legacy keys; flat if ``radius_m`` is 0.
    ``roll_m``: the ground's and the obstacle's roll resistance (``[lab.physics] roll_resistance_m``)."""
    obstacles = (Obstacle("half_cylinder", 0.0, friction, radius_m=radius_m, roll_resistance_m=roll_m),) \
        if radius_m > 0 else ()
    return Scene(ground_friction=ground_friction, obstacles=obstacles, ground_roll_m=roll_m,
                 name=name or (f"half cylinder r = {radius_m:.3f} m" if obstacles else "flat ground"))


# -- reading a file ----------------------------------------------------------------------------------------------------
_EVERY_OBSTACLE_KEYS = {"shape", "x_m", "friction", "roll_resistance_m"}
_OBSTACLE_KEYS = {"half_cylinder": _EVERY_OBSTACLE_KEYS | {"radius_m"},
                  "box": _EVERY_OBSTACLE_KEYS | {"length_m", "height_m"},
                  "wedge": _EVERY_OBSTACLE_KEYS | {"length_m", "height_m"}}


def _number(where: str, table: dict[str, Any], key: str, *, low: float, high: float, default: float | None = None,
            low_open: bool = False) -> float:
    if key not in table:
        if default is None:
            raise SceneError(f"{where}: missing key '{key}'")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SceneError(f"{where}: '{key}' must be a number, got {value!r}")
    value = float(value)
    bad_low = value <= low if low_open else value < low
    if not math.isfinite(value) or bad_low or value > high:
        bracket = "(" if low_open else "["
        raise SceneError(f"{where}: '{key}' = {value:g} is outside {bracket}{low:g}, {high:g}]")
    return value


def _size(where: str, table: dict[str, Any], key: str, high: float, thinnest: float) -> float:
    """An obstacle's size (m): positive, at most ``high``, and no thinner than the contact model resolves."""
    value = _number(where, table, key, low=0.0, high=high, low_open=True)
    if value < thinnest:
        raise SceneError(f"{where}: '{key}' = {value:g} m is thinner than the physics lab's contact model resolves "
                         f"(at least {thinnest:g} m: a shell sinks, travels or steps that deep into what it meets)")
    return value


def _only(where: str, table: dict[str, Any], allowed: set[str]) -> None:
    for key in table:
        if key not in allowed:
            raise SceneError(f"{where}: unknown key '{key}' (known: {', '.join(sorted(allowed))})")


def parse_scene(text: str, source: str = "<scene>", name: str = "scene", default_roll_m: float = GROUND_ROLL_M) -> Scene:
    """A :class:`Scene` from TOML ``text``; ``source`` names the file in every error. ``default_roll_m``: the
    ground's roll resistance when the file names none (the lab config's ``[lab.physics] roll_resistance_m``)."""
    data = parse_toml_text(text, source, "scene file", SceneError)
    _only(source, data, {"ground", "obstacle", "robot"})
    ground = data.get("ground", {})
    if not isinstance(ground, dict):
        raise SceneError(f"{source}: [ground] must be a table")
    _only(f"{source} [ground]", ground, {"friction", "roll_resistance_m", "contact_onset_m"})
    ground_friction = _number(f"{source} [ground]", ground, "friction", low=0.0, high=5.0, default=0.3)
    ground_roll = _number(f"{source} [ground]", ground, "roll_resistance_m", low=0.0, high=MAX_ROLL_M,
                          default=default_roll_m)
    onset = _number(f"{source} [ground]", ground, "contact_onset_m", low=MIN_ONSET_M, high=MAX_ONSET_M) \
        if "contact_onset_m" in ground else None
    if onset is not None and ground_roll == 0.0:  # it acts through the roll resistance's contact pairs
        raise SceneError(f"{source} [ground]: 'contact_onset_m' needs 'roll_resistance_m' > 0")
    raw = data.get("obstacle", [])
    if not isinstance(raw, list):
        raise SceneError(f"{source}: obstacles are written [[obstacle]] (an array of tables)")
    if len(raw) > MAX_OBSTACLES:
        raise SceneError(f"{source}: {len(raw)} obstacles; a scene holds at most {MAX_OBSTACLES} (the physics lab "
                         "keeps every contact of a step in a fixed arena)")
    obstacles = []
    for k, table in enumerate(raw, start=1):
        where = f"{source} [[obstacle]] #{k}"
        if not isinstance(table, dict):
            raise SceneError(f"{where}: must be a table")
        shape = table.get("shape")
        if shape not in SHAPES:
            raise SceneError(f"{where}: 'shape' must be one of {', '.join(SHAPES)}, got {shape!r}")
        _only(where, table, _OBSTACLE_KEYS[shape])
        x_m = _number(where, table, "x_m", low=-50.0, high=50.0)
        friction = _number(where, table, "friction", low=0.0, high=5.0, default=ground_friction)
        roll = _number(where, table, "roll_resistance_m", low=0.0, high=MAX_ROLL_M, default=ground_roll)
        if onset is not None and roll == 0.0 and shape != "wedge":
            raise SceneError(f"{where}: 'roll_resistance_m' = 0 leaves it without the ground's 'contact_onset_m'")
        thinnest = max(RESOLVED_DEPTH_M, RESOLVED_ONSETS * (onset or 0.0))
        if shape == "half_cylinder":
            radius = _size(where, table, "radius_m", 5.0, thinnest)
            obstacles.append(Obstacle(shape, x_m, friction, radius_m=radius, roll_resistance_m=roll))
        else:
            length = _size(where, table, "length_m", 50.0, thinnest)
            height = _size(where, table, "height_m", 5.0, thinnest)
            obstacles.append(Obstacle(shape, x_m, friction, length_m=length, height_m=height,
                                      roll_resistance_m=roll))
    robot = data.get("robot", {})
    if not isinstance(robot, dict):
        raise SceneError(f"{source}: [robot] must be a table")
    _only(f"{source} [robot]", robot, {"head_x_m", "start"})
    head_x = _number(f"{source} [robot]", robot, "head_x_m", low=-50.0, high=50.0) if "head_x_m" in robot else None
    start = robot.get("start", "settle")
    if start not in STARTS:
        raise SceneError(f"{source} [robot]: 'start' must be one of {', '.join(STARTS)}, got {start!r}")
    return Scene(ground_friction=ground_friction, obstacles=tuple(obstacles), head_x_m=head_x, start=start,
                 name=name, text=text, ground_roll_m=ground_roll, contact_onset_m=onset)


def resolve_scene_path(value: str | Path) -> Path:
    """A scene given as a path, or as the name of a built-in scene (``paper_obstacle``, ``step``, …)."""
    path = Path(value).expanduser()
    if not path.exists() and path.suffix == "" and (SCENES_DIR / f"{path.name}.toml").exists():
        return SCENES_DIR / f"{path.name}.toml"
    return path


def load_scene(value: str | Path, default_roll_m: float = GROUND_ROLL_M) -> Scene:
    """Read a scene file (a path or a built-in scene's name); :class:`SceneError` names what is wrong.
    ``default_roll_m``: as :func:`parse_scene`'s."""
    path = resolve_scene_path(value)
    builtin = ", ".join(sorted(p.stem for p in SCENES_DIR.glob("*.toml")))
    # Only a regular file of at most 1 MB: a FIFO would hang the read, /dev/zero would fill the memory.
    text = read_text_file(path, "scene file", SceneError, not_found=f" (built-in scenes: {builtin})")
    return parse_scene(text, str(path), name=path.stem, default_roll_m=default_roll_m)


def channel_map(channel_names: Sequence[str], n_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """For SPEC §2 names (``S06B``): per channel the row in ``SIDES`` and the segment index (−1, −1: not a sensor
    the robot carries, which then reads no force)."""
    pattern = re.compile(r"^S(\d+)([LRB])$")
    rows = np.full(len(channel_names), -1)
    segments = np.full(len(channel_names), -1)
    for channel, name in enumerate(channel_names):
        match = pattern.match(name)
        if match and 1 <= int(match.group(1)) <= n_segments:
            rows[channel] = SIDES.index(match.group(2))
            segments[channel] = int(match.group(1)) - 1
    return rows, segments
