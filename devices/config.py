"""Lab configuration: frozen dataclasses loaded from TOML and validated whenever one is built.

Every quantity carries its unit in its name. An invalid file raises :class:`ConfigError` naming the key
(``robot.joint_ids[3]``) and the problem, so a lab user can fix the TOML without reading code. Validation runs in
each dataclass's ``__post_init__``, so a config built any other way — ``dataclasses.replace`` with a command-line
override (``play --rate``), :meth:`LabConfig.with_ports`, a test — is checked by the same rules; there is no way to
hold an unchecked config.
Any thread may call these functions; the objects are immutable.
"""

from __future__ import annotations

import math
import stat
import sys
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from devices.errors import ConfigError
from devices.toml_files import MAX_TOML_BYTES, parse_toml_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

N_JOINTS = 12
SENSOR_SIDES = ("L", "R", "B")
SIM_PORT = "sim"


def default_sensor_names(n_segments: int = N_JOINTS) -> tuple[str, ...]:
    """``S01L S01R S01B S02L … S12B`` (SPEC §2)."""
    return tuple(f"S{seg:02d}{side}" for seg in range(1, n_segments + 1) for side in SENSOR_SIDES)


@dataclass(frozen=True)
class RobotConfig:
    """The servo chain on one Dynamixel Protocol 2.0 bus."""

    port: str = SIM_PORT
    baud: int = 1_000_000
    joint_ids: tuple[int, ...] = tuple(range(1, N_JOINTS + 1))
    axes: tuple[str, ...] = tuple("pitch" if i % 2 == 1 else "yaw" for i in range(1, N_JOINTS + 1))
    signs: tuple[int, ...] = (1,) * N_JOINTS
    zero_offsets_rad: tuple[float, ...] = (0.0,) * N_JOINTS
    joint_min_rad: tuple[float, ...] = (-1.57,) * N_JOINTS
    joint_max_rad: tuple[float, ...] = (1.57,) * N_JOINTS
    max_joint_speed_rad_s: float = 1.0
    control_rate_hz: float = 50.0
    status_rate_hz: float = 5.0
    segment_length_m: float = 0.08

    def __post_init__(self) -> None:
        _validate_robot(self, "")

    @property
    def n_joints(self) -> int:
        return len(self.joint_ids)


@dataclass(frozen=True)
class BoardConfig:
    """The multiplexing force-sensor board (SPEC §4) and its readout circuit."""

    port: str = SIM_PORT
    baud: int = 2_000_000
    rate_hz: float = 30.0
    channel_names: tuple[str, ...] = field(default_factory=default_sensor_names)
    v_ref_v: float = 2.5
    v_supply_v: float = 3.3
    r_c_ohm: float = 900.0
    adc_max_counts: int = 4095

    def __post_init__(self) -> None:
        _validate_board(self, "")

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)


@dataclass(frozen=True)
class RigConfig:
    """The calibration rig: a servo winding a cable through a spring onto a probe."""

    port: str = SIM_PORT
    baud: int = 1_000_000
    servo_id: int = 1
    wheel_radius_m: float = 0.02
    spring_k_n_per_m: float = 246.0
    sensor: str = "S06B"
    area_m2: float = 1.4e-3  # the sensor's active area under the probe (the large flat probe: the whole sensor)
    max_force_n: float = 8.0  # the rig never commands more (protects the sensor and the spring)

    def __post_init__(self) -> None:
        _validate_rig(self, "")


PHYSICS_KINDS = ("scripted", "mujoco")
SENSING_KINDS = ("robot", "ideal")  # [lab] sensing (app.core.sensing)
# [lab] mocap = true: the physics lab publishes a simulated motion-capture stream of this name (Lab Streaming Layer,
# type MoCap; devices.sim.mocap_stream) and recordings follow it. Kept in the config as SIM_MOCAP.
SIM_MOCAP = "sim"
SIM_MOCAP_STREAM = "SenSnake-lab-mocap"


MAX_BAUD = 12_000_000  # no USB-serial adapter here runs faster (the U2D2 tops out at 6 Mbps)


def _param(default: float, source: str) -> Any:
    """A physical parameter's default and where it comes from (a datasheet, a measurement, an assumption): the
    source goes into docs/CONFIG.md (scripts/config_doc.py) beside the key."""
    return field(default=default, metadata={"source": source})


@dataclass(frozen=True)
class LabPhysicsConfig:
    """The physics lab's physical parameters (``[lab.physics]``): the robot's compliant shell, its contact with the
    terrain, the servos' loop and passive terms. Friction per surface lives in the scene files (SPEC §6), where each
    surface names its own. Every default is the value the lab used before these were data; each key says where it
    comes from. A ``[lab.physics]`` table selects the MuJoCo lab (``[lab] physics`` is then that table, not a kind)."""

    timestep_s: float = _param(
        0.002, "assumption, measured stable: a 2 ms implicit-fast step keeps the 60 g shell on 2000 N/m from "
               "chattering (docs/PHYSICS_LAB.md)")
    shell_stiffness_n_per_m: float = _param(
        2000.0, "assumption: the hollow TPU shell deflects ~1 mm under a segment's share of the weight (2 N); not "
                "measured. Measure it: `sensnake lab shell` on the calibration rig (force against a dial gauge's "
                "deflection; docs/PHYSICS_LAB.md, 'The shell on the rig'), or `sensnake lab identify` on recordings")
    shell_damping_n_s_per_m: float = _param(
        30.0, "assumption: near-critical damping of a segment bouncing on the shell; `sensnake lab shell` cannot "
              "measure it (a gauge read at rest sees the static deflection only) and says so")
    shell_mass_kg: float = _param(
        0.06, "assumption: shell, sheets, rubber covers and holders of the 196 g segment (an XM430 alone is 82 g)")
    shell_travel_m: float = _param(
        0.003, "assumption: the shell's travel before it bottoms out on the servo's housing; `sensnake lab shell` "
               "measures it when its force ramp bottoms the shell out (shell_stiffness_n_per_m × travel below the "
               "rig's force), else says it is more than the deflection reached")
    roll_resistance_m: float = _param(
        0.0085, "assumption derived from the shell's stiffness: half the width of the loaded shell's flattened "
                "contact patch, sqrt(2 R d) for R 36 mm, d 1 mm; the lever of the terrain's resistance to a shell's "
                "roll wherever a scene names no roll_resistance_m of its own")
    contact_time_constant_s: float = _param(
        0.01, "assumption: near-rigid contacts (MuJoCo solref), the compliance being the shell's")
    contact_damping_ratio: float = _param(
        1.0, "assumption: critically damped contacts (MuJoCo solref)")
    servo_position_gain_nm_per_rad: float = _param(
        21.0, "published MuJoCo models of the XM430-W350; not measured on our servos")
    servo_damping_nm_s_per_rad: float = _param(
        1.08, "published MuJoCo models of the XM430-W350; not measured on our servos")
    servo_armature_kg_m2: float = _param(
        0.045, "published MuJoCo models of the XM430-W350 (the rotor's inertia through the 353.5:1 gear); not "
               "measured on our servos")
    servo_friction_loss_nm: float = _param(
        0.03, "published MuJoCo models of the XM430-W350; not measured on our servos")
    servo_stall_torque_nm: float = _param(
        4.1, "datasheet: ROBOTIS e-manual, XM430-W350 at 12 V (4.1 N·m at 2.3 A)")
    servo_no_load_speed_rad_s: float = _param(
        46.0 * 2.0 * math.pi / 60.0, "datasheet: ROBOTIS e-manual, XM430-W350 at 12 V (46 rev/min)")

    def __post_init__(self) -> None:
        _validate_lab_physics(self, "")

    def to_dict(self) -> dict[str, float]:
        """The values in force, key by key (a recording's ``/sim`` stores them as JSON)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


# [lab.physics] key → (lowest, highest) it may take (both inclusive; a lowest of 0 with the flag: above 0)
LAB_PHYSICS_RANGES: dict[str, tuple[float, float, bool]] = {
    "timestep_s": (1e-4, 0.01, False),
    "shell_stiffness_n_per_m": (0.0, 1e6, True),
    "shell_damping_n_s_per_m": (0.0, 1e4, False),
    "shell_mass_kg": (0.0, 0.19, True),
    "shell_travel_m": (0.0, 0.018, True),
    "roll_resistance_m": (0.0, 0.036, False),
    "contact_time_constant_s": (0.002, 1.0, False),
    "contact_damping_ratio": (0.0, 10.0, True),
    "servo_position_gain_nm_per_rad": (0.0, 1e4, True),
    "servo_damping_nm_s_per_rad": (0.0, 100.0, False),
    "servo_armature_kg_m2": (0.0, 10.0, False),
    "servo_friction_loss_nm": (0.0, 10.0, False),
    "servo_stall_torque_nm": (0.0, 100.0, True),
    "servo_no_load_speed_rad_s": (0.0, 100.0, True),
}


@dataclass(frozen=True)
class SimLabConfig:
    """What the simulated lab (port ``sim``) simulates. ``physics = "mujoco"`` (the default): the robot, the ground
    and the paper's half-cylindrical obstacle in MuJoCo (needs the ``mujoco`` package; without it the lab falls back
    to the scripted one and says why, ``SimLab.physics_note``); ``"scripted"``: the cheap contact model. The obstacle's height is a fraction of the body length (paper: 0.28; 0 = flat ground); friction
    coefficients are Coulomb's μ (the paper's obstacle is covered with PTFE).

    The simulated sensors (paper Sec. IV-A): standard linear solid creep (Eq. 2) with ``sensor_E0_Pa``,
    ``sensor_E1_Pa`` and the retardation time ``sensor_tau_s`` = μ1/E1, each sensor's values drawn around these by
    ``sensor_spread`` (relative s.d., clipped to ±4 s.d.; seeded), the resistance–strain law with the contact term
    (Eq. 3, :class:`models.physics.PhysicsConstants`), and the readout's noise ``noise_counts`` (s.d., ADC counts)
    before 12-bit quantisation. The sensor on the calibration rig (``rig.sensor``) is pressed over
    ``sensor_area_m2`` (the large flat probe covers the whole sensor) and, while the rig servo holds torque, its
    segment lies on the rig's beam: the probe alone loads it, not the robot's weight."""

    physics: str = "mujoco"
    # A scene file (SPEC §6; a path, relative to the config file's folder, or a built-in scene's name such as
    # "step"); "" = the paper's half cylinder built from obstacle_height_ratio/obstacle_friction/ground_friction.
    scene: str = ""
    obstacle_height_ratio: float = 0.28
    obstacle_friction: float = 0.1
    ground_friction: float = 0.3
    sensor_E0_Pa: float = 2.0e6
    sensor_E1_Pa: float = 4.0e6
    sensor_tau_s: float = 100.0
    sensor_area_m2: float = 1.4e-3
    sensor_spread: float = 0.05
    noise_counts: float = 0.5
    # the motion-capture stream a recording follows: "lsl:NAME", "sim" (TOML true: the physics lab's own simulated
    # stream, SIM_MOCAP_STREAM) or "" (none): docs/MOCAP.md
    mocap: str = ""
    # What a physics-lab run's controller senses (app.core.sensing): "robot", the forces through a rig calibration's
    # errors, the board's noise and the sensors' creep; "ideal", through the sensors' true calibration
    sensing: str = "robot"
    # [lab.physics]: the physics lab's physical parameters (a TOML table where [lab] physics would name the kind)
    physical: LabPhysicsConfig = field(default_factory=LabPhysicsConfig)

    def __post_init__(self) -> None:
        _validate_lab(self, "")


MOCAP_LABEL_FIELDS = ("segment", "marker")


@dataclass(frozen=True)
class MocapConfig:
    """Motion capture (docs/MOCAP.md): how the take's markers are labelled and where they sit on a segment.
    ``labels`` is a Python format pattern with ``{segment}`` (1 = head … 12) and ``{marker}`` (1 … K);
    ``marker_layout_m`` gives each marker's [x, y, z] (m) in its segment's frame (origin at the segment's centre on
    its long axis, x toward the head, z up when the body lies straight and upright, y = z × x), the same for every
    segment (the default: :func:`models.mocap.default_marker_layout_m`). A fit further than ``max_residual_m`` (RMS)
    from the layout is not taken as the segment's pose."""

    labels: str = "SEG{segment:02d}_{marker}"
    marker_layout_m: tuple[tuple[float, ...], ...] = field(default_factory=lambda: _default_layout())
    max_residual_m: float = 0.004

    def __post_init__(self) -> None:
        _validate_mocap(self, "")

    def label(self, segment: int, marker: int) -> str:
        """The label of ``marker`` (1-based) of ``segment`` (1-based)."""
        return self.labels.format(segment=segment, marker=marker)


def mocap_stream_spec(mocap: str) -> str:
    """``[lab] mocap`` as the stream a recording follows: ``lsl:NAME`` as it is, the simulated lab's
    (:data:`SIM_MOCAP`) as ``lsl:`` + :data:`SIM_MOCAP_STREAM`, "" for none."""
    return f"lsl:{SIM_MOCAP_STREAM}" if mocap == SIM_MOCAP else mocap


def _default_layout() -> tuple[tuple[float, ...], ...]:
    from models.mocap import DEFAULT_MARKER_LAYOUT_M

    return tuple(tuple(float(v) for v in row) for row in DEFAULT_MARKER_LAYOUT_M)


@dataclass(frozen=True)
class LabConfig:
    robot: RobotConfig = field(default_factory=RobotConfig)
    board: BoardConfig = field(default_factory=BoardConfig)
    rig: RigConfig = field(default_factory=RigConfig)
    lab: SimLabConfig = field(default_factory=SimLabConfig)
    mocap: MocapConfig = field(default_factory=MocapConfig)
    source_text: str = ""  # the TOML text this was loaded from, stored in recordings
    # [servos]: control-table items (name, raw value) every joint servo should hold; applied on connect where a
    # servo differs (app.core.servo_settings.apply_profile). Empty: the servos are left as they are.
    servos: tuple[tuple[str, int], ...] = ()

    def with_ports(self, robot: str | None = None, board: str | None = None, rig: str | None = None) -> LabConfig:
        """A copy with the given ports replaced (``None`` keeps the configured one)."""
        return replace(
            self,
            robot=replace(self.robot, port=robot) if robot else self.robot,
            board=replace(self.board, port=board) if board else self.board,
            rig=replace(self.rig, port=rig) if rig else self.rig,
        )


def sets_port(config: LabConfig, section: str) -> bool:
    """Whether the config's own text sets ``[<section>] port``, rather than leaving it at its default (the
    simulator): a command taking its port from a config that forgot it must not quietly drive the simulator."""
    if not config.source_text:
        return False
    table = tomllib.loads(config.source_text).get(section, {})
    return isinstance(table, dict) and "port" in table


def default_config_path() -> Path:
    """The packaged default config (simulated lab)."""
    return Path(str(resources.files("resources").joinpath("default_lab.toml")))


def load_config(path: str | Path | None = None) -> LabConfig:
    """Load and validate a lab config; ``None`` loads the packaged default (simulated lab)."""
    path = Path(path) if path is not None else default_config_path()
    try:
        # A FIFO or a device would block the read or never end it: only a regular file is read.
        status = path.stat()
        mode = status.st_mode
        if not stat.S_ISREG(mode):
            kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else \
                "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a regular file"
            raise ConfigError(f"{path} is {kind}, not a lab configuration: the config is a TOML text file like "
                              "resources/default_lab.toml")
        if status.st_size > MAX_TOML_BYTES:  # a few kB; read whole, so a huge file is refused first
            raise ConfigError(f"{path}: larger than {MAX_TOML_BYTES / 1e6:g} MB, too large for a lab configuration")
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a lab configuration: byte {exc.start} is not UTF-8 text (a binary file?); "
                          "the config is a TOML text file like resources/default_lab.toml") from None
    return resolve_relative_scene(parse_config(text, source=str(path)), path)


def parse_config(text: str, source: str = "<config>") -> LabConfig:
    # Invalid TOML, nesting deeper than the parser goes or an integer no float holds: one line naming the file.
    data = parse_toml_text(text, source, "lab configuration", ConfigError)
    unknown = set(data) - {"robot", "board", "rig", "lab", "servos", "mocap"}
    if unknown:
        raise ConfigError(f"{source}: unknown section [{sorted(unknown)[0]}] (expected robot, board, rig, lab, "
                          "servos, mocap)")
    # Each section is validated as it is built (__post_init__); _build prefixes the file's name to any error.
    robot = _build(RobotConfig, data.get("robot", {}), "robot", source)
    board = _build(BoardConfig, data.get("board", {}), "board", source)
    rig = _build(RigConfig, data.get("rig", {}), "rig", source)
    lab = _build_lab(data.get("lab", {}), source)
    servos = _servo_profile(data.get("servos", {}), source)
    mocap = _build(MocapConfig, data.get("mocap", {}), "mocap", source)
    return LabConfig(robot=robot, board=board, rig=rig, lab=lab, source_text=text, servos=servos, mocap=mocap)


# Items a [servos] profile may not set: the moment's state, and what would lose the servo on the bus.
PROFILE_REFUSED = frozenset({"Torque Enable", "LED", "Goal PWM", "Goal Current", "Goal Velocity", "Goal Position",
                             "ID", "Baud Rate", "Registered Instruction", "Homing Offset", "Operating Mode",
                             "Protocol Type"})


def profile_key(item_name: str) -> str:
    """The [servos] key of a control-table item: "Return Delay Time" → ``return_delay_time``."""
    return item_name.lower().replace(" ", "_").replace("-", "_")


def _why_refused(name: str) -> str:
    if name in ("ID", "Baud Rate", "Protocol Type"):
        return "it would lose the servo on the bus"
    if name == "Operating Mode":
        return "the app drives every joint in position control mode"
    if name == "Homing Offset":
        return "the joints' zero is [robot] zero_offsets_rad, set by 'Set zero pose'"
    return "it is the servo's state of the moment"


def _servo_profile(table: Any, source: str) -> tuple[tuple[str, int], ...]:
    """``[servos]`` → (item name, raw value) pairs, each item writable, allowed in a profile and in its range."""
    from devices import control_table as ct

    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [servos] must be a table of control-table items")
    by_key = {profile_key(item.name): item for item in ct.XM430_W350_ITEMS}
    profile = []
    for key, value in table.items():
        item = by_key.get(key)
        if item is None or not item.writable:
            allowed = sorted(k for k, i in by_key.items() if i.writable and i.name not in PROFILE_REFUSED)
            what = "a read-only item" if item is not None else "not a control-table item of the XM430-W350"
            raise ConfigError(f"{source}: servos.{key} is {what} (items a profile can set: {', '.join(allowed)})")
        if item.name in PROFILE_REFUSED:
            raise ConfigError(f"{source}: servos.{key} cannot be in a profile applied on every connect ("
                              + _why_refused(item.name) + ")")
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: servos.{key} = {value!r} must be a whole number in the servo's raw units")
        if not item.minimum <= value <= item.maximum:
            raise ConfigError(f"{source}: servos.{key} = {value} is out of its range {item.minimum} … {item.maximum}")
        cut_off = ct.cut_off_reason(item.name, value)
        if cut_off:
            raise ConfigError(f"{source}: servos.{key} = {value} would cut the app off from every joint: {cut_off}")
        profile.append((item.name, int(value)))
    return tuple(profile)


def resolve_relative_scene(config: LabConfig, config_path: str | Path) -> LabConfig:
    """``[lab] scene`` given relative to the config file's folder, made absolute (a built-in name is kept)."""
    scene = config.lab.scene
    if not scene or Path(scene).is_absolute():
        return config
    beside = Path(config_path).resolve().parent / scene
    return replace(config, lab=replace(config.lab, scene=str(beside))) if beside.exists() else config


def _build_lab(table: Any, source: str) -> SimLabConfig:
    """``[lab]``, whose ``physics`` is either the kind (``"mujoco"``, ``"scripted"``) or the ``[lab.physics]`` table
    of physical parameters (which selects the MuJoCo lab)."""
    if isinstance(table, dict) and isinstance(table.get("physics"), dict):
        rest = {key: value for key, value in table.items() if key != "physics"}
        physical = _build(LabPhysicsConfig, table["physics"], "lab.physics", source)
        lab = _build(SimLabConfig, rest, "lab", source)
        return replace(lab, physics="mujoco", physical=physical)
    if isinstance(table, dict) and isinstance(table.get("mocap"), bool):  # mocap = true: the lab's simulated stream
        table = {**table, "mocap": SIM_MOCAP if table["mocap"] else ""}
    return _build(SimLabConfig, table, "lab", source)


def _build(cls: type, table: Any, section: str, source: str) -> Any:
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{section}] must be a table")
    defaults = cls()
    # a nested table (a field whose default is a dataclass: [lab.physics]) is read by its section's own builder
    known = {f.name: f for f in fields(cls) if not hasattr(getattr(defaults, f.name), "__dataclass_fields__")}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in known:
            raise ConfigError(f"{source}: unknown key {section}.{key} (known: {', '.join(sorted(known))})")
        kwargs[key] = _coerce(value, getattr(defaults, key), f"{section}.{key}", source)
    try:
        return cls(**kwargs)  # __post_init__ validates
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def _coerce(value: Any, default: Any, key: str, source: str) -> Any:
    """Coerce a TOML value to the type of the default, or name the key and the problem."""
    if isinstance(default, tuple):
        if not isinstance(value, list):
            raise ConfigError(f"{source}: {key} must be a list, got {type(value).__name__}")
        element = default[0] if default else value[0] if value else 0
        return tuple(_coerce(v, element, f"{key}[{i}]", source) for i, v in enumerate(value))
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {key} must be true or false")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key} must be an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{source}: {key} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{source}: {key} must be finite, got {value!r}")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"{source}: {key} must be a string, got {value!r}")
        return value
    return value


def _require(ok: bool, source: str, key: str, problem: str) -> None:
    if not ok:
        raise ConfigError(f"{source}: {key} {problem}" if source else f"{key} {problem}")


def _require_port(port: object, key: str) -> None:
    _require(isinstance(port, str) and bool(port.strip()), "", key,
             f"= {port!r} must name a serial port (/dev/ttyUSB0, COM3) or '{SIM_PORT}'")


def _validate_robot(robot: RobotConfig, source: str) -> None:
    _require_port(robot.port, "robot.port")
    n = robot.n_joints
    _require(n >= 1, source, "robot.joint_ids", "must list at least one servo ID")
    _require(len(set(robot.joint_ids)) == n, source, "robot.joint_ids", "has duplicate IDs")
    for i, sid in enumerate(robot.joint_ids):
        _require(0 <= sid <= 252, source, f"robot.joint_ids[{i}]", f"= {sid} is not a Dynamixel ID (0…252)")
    for name in ("axes", "signs", "zero_offsets_rad", "joint_min_rad", "joint_max_rad"):
        _require(len(getattr(robot, name)) == n, source, f"robot.{name}",
                 f"has {len(getattr(robot, name))} entries but robot.joint_ids has {n}")
    for i, axis in enumerate(robot.axes):
        _require(axis in ("pitch", "yaw"), source, f"robot.axes[{i}]", f"= {axis!r} must be 'pitch' or 'yaw'")
    for i, sign in enumerate(robot.signs):
        _require(sign in (1, -1), source, f"robot.signs[{i}]", f"= {sign} must be 1 or -1")
    for i, (lo, hi) in enumerate(zip(robot.joint_min_rad, robot.joint_max_rad)):
        _require(lo < hi, source, f"robot.joint_min_rad[{i}]", f"= {lo} must be below robot.joint_max_rad[{i}] = {hi}")
        _require(-math.pi <= lo and hi <= math.pi, source, f"robot.joint_max_rad[{i}]", "limits must lie within ±π")
    _require(robot.baud > 0, source, "robot.baud", "must be positive")
    _require(robot.max_joint_speed_rad_s > 0, source, "robot.max_joint_speed_rad_s", "must be positive")
    _require(0 < robot.control_rate_hz <= 1000, source, "robot.control_rate_hz", "must be in (0, 1000]")
    _require(0 < robot.status_rate_hz <= 100, source, "robot.status_rate_hz", "must be in (0, 100]")
    _require(robot.segment_length_m > 0, source, "robot.segment_length_m", "must be positive")


def _validate_board(board: BoardConfig, source: str) -> None:
    _require_port(board.port, "board.port")
    n = board.n_channels
    _require(1 <= n <= 1024, source, "board.channel_names", f"has {n} channels; the board carries 1…1024")
    _require(len(set(board.channel_names)) == n, source, "board.channel_names", "has duplicate names")
    _require(board.baud > 0, source, "board.baud", "must be positive")
    _require(0 < board.rate_hz <= 10_000, source, "board.rate_hz", "must be in (0, 10000]")
    _require(board.r_c_ohm > 0, source, "board.r_c_ohm", "must be positive")
    _require(board.v_ref_v > 0, source, "board.v_ref_v", "must be positive")
    _require(board.v_supply_v > 0, source, "board.v_supply_v", "must be positive")
    _require(board.adc_max_counts > 0, source, "board.adc_max_counts", "must be positive")


def _validate_rig(rig: RigConfig, source: str) -> None:
    _require_port(rig.port, "rig.port")
    _require(0 <= rig.servo_id <= 252, source, "rig.servo_id", f"= {rig.servo_id} is not a Dynamixel ID (0…252)")
    _require(rig.wheel_radius_m > 0, source, "rig.wheel_radius_m", "must be positive")
    _require(rig.spring_k_n_per_m > 0, source, "rig.spring_k_n_per_m", "must be positive")
    _require(rig.baud > 0, source, "rig.baud", "must be positive")
    _require(math.isfinite(rig.area_m2) and rig.area_m2 > 0, source, "rig.area_m2", "must be a positive area (m²)")
    _require(math.isfinite(rig.max_force_n) and rig.max_force_n > 0, source, "rig.max_force_n",
             "must be a positive force (N)")


def _validate_lab(lab: SimLabConfig, source: str) -> None:
    _require(lab.physics in PHYSICS_KINDS, source, "lab.physics", f"= {lab.physics!r} must be one of {PHYSICS_KINDS}")
    _require(0.0 <= lab.obstacle_height_ratio <= 1.0, source, "lab.obstacle_height_ratio", "must be in [0, 1]")
    _require(0.0 <= lab.obstacle_friction <= 2.0, source, "lab.obstacle_friction", "must be in [0, 2]")
    _require(0.0 <= lab.ground_friction <= 2.0, source, "lab.ground_friction", "must be in [0, 2]")
    for key in ("sensor_E0_Pa", "sensor_E1_Pa", "sensor_tau_s", "sensor_area_m2"):
        value = getattr(lab, key)
        _require(math.isfinite(value) and value > 0, source, f"lab.{key}", f"= {value!r} must be a positive number")
    _require(0.0 <= lab.sensor_spread <= 0.2, source, "lab.sensor_spread", "must be in [0, 0.2]")
    _require(math.isfinite(lab.noise_counts) and lab.noise_counts >= 0, source, "lab.noise_counts",
             "must be 0 or more (ADC counts)")
    _require(lab.sensing in SENSING_KINDS, source, "lab.sensing", f"= {lab.sensing!r} must be one of {SENSING_KINDS}")
    _require(isinstance(lab.physical, LabPhysicsConfig), source, "lab.physics",
             "must be a table of physical parameters ([lab.physics])")
    _require(lab.mocap in ("", SIM_MOCAP) or (lab.mocap.startswith("lsl:") and bool(lab.mocap[4:].strip())), source,
             "lab.mocap", f"= {lab.mocap!r} must be 'lsl:NAME' (a Lab Streaming Layer stream), true (the physics "
             "lab's simulated motion capture) or empty")


def _validate_lab_physics(physical: LabPhysicsConfig, source: str) -> None:
    for key, (low, high, above) in LAB_PHYSICS_RANGES.items():
        value = getattr(physical, key)
        ok = isinstance(value, int | float) and math.isfinite(value) and (value > low if above else value >= low) \
            and value <= high
        _require(ok, source, f"lab.physics.{key}", f"= {value!r} must be in {'(' if above else '['}{low:g}, {high:g}]")


def _validate_mocap(mocap: MocapConfig, source: str) -> None:
    from models.errors import MocapLayoutError
    from models.mocap import check_layout

    try:
        first, second = mocap.label(1, 1), mocap.label(2, 2)
    except (KeyError, IndexError, ValueError) as exc:
        raise ConfigError(f"mocap.labels = {mocap.labels!r} is not a label pattern with {{segment}} and {{marker}} "
                          f"({type(exc).__name__}: {exc})") from None
    _require(first != second and all(f"{{{name}" in mocap.labels for name in MOCAP_LABEL_FIELDS), source,
             "mocap.labels", f"= {mocap.labels!r} must name both {{segment}} and {{marker}}, e.g. "
             "'SEG{segment:02d}_{marker}'")
    rows = mocap.marker_layout_m
    for i, row in enumerate(rows):
        _require(len(row) == 3, source, f"mocap.marker_layout_m[{i}]", f"has {len(row)} numbers; give [x, y, z] (m)")
    try:
        check_layout(rows)
    except MocapLayoutError as exc:
        raise ConfigError(f"mocap.{exc}" if not source else f"{source}: mocap.{exc}") from None
    _require(math.isfinite(mocap.max_residual_m) and 0 < mocap.max_residual_m <= 0.05, source, "mocap.max_residual_m",
             "must be in (0, 0.05] m")
