"""The shell's bench test on the calibration rig: force against deflection of a segment's compliant shell, fitted to
the ``[lab.physics]`` shell values.

The plan (docs/PHYSICS_LAB.md, "The shell on the rig"): the segment lies on the rig's beam with the sensor under the
probe and a dial gauge on the probe. The rig finds the contact from its servo's current
(:meth:`devices.rig.CalibrationRig.find_contact`), unwinds to slack, then steps: a few slack steps before the contact
(the gauge's rest), then ``steps`` steps of nominal force ``F = k·r·(θ − θ_c)`` up to ``max_force_n`` (the force the
spring would give on a rigid sensor; on the shell it gives less, so the rig's limit holds), reading the servo's
settled angle and the gauge at each; then back to slack and one more reading (the probe must come back to its rest).
:func:`models.shell_fit.fit_shell` turns the windings and readings into the stiffness and travel with intervals.
Runs on the calling thread (it owns the rig); nothing here is Qt.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from devices.config import LabConfig
from devices.gauge import TravelGauge
from devices.rig import CalibrationRig
from models.shell_fit import ShellFit, fit_shell

SLACK_OFFSETS_RAD = (-0.15, -0.10, -0.05)  # readings before the contact the current found (it is known to ±0.03 rad)
RETURN_DIGITS = 3  # the probe back at rest within this many gauge digits of where it started
TICK_RAD = 2 * math.pi / 4096  # one encoder tick of the XM430
STEP_READ_TRIES = 3  # a step whose wheel crept during the reading is read again, at most this many times in all


@dataclass(frozen=True)
class ShellBenchSettings:
    """What the bench test does and what its gauge is (SI units)."""

    max_force_n: float = 8.0  # nominal (rigid-sensor) force of the last step; the rig's max_force_n caps it
    steps: int = 16  # loaded steps
    gauge_resolution_m: float = 1e-5
    gauge_force_n: float = 0.0  # the plunger's measuring force at the slack reading (N)
    gauge_rate_n_per_m: float = 0.0  # how much it falls per metre the probe goes in (N/m)
    # Seconds waited once the wheel is at rest before the gauge is read: the shell follows the probe with
    # c/(k + k_shell), tens of ms, and a person reads a gauge after it has stopped changing.
    read_delay_s: float = 1.0
    # Seconds the probe is held at the ramp's middle step and the gauge read again (0: no hold): a shell that
    # creeps (a viscoelastic TPU) goes on in; the lab's shell, a spring and a damper, does not.
    hold_s: float = 0.0
    # The rig's seconds per wall second: 1 on a real rig, X on the simulated rig at X× real time (its waits are the
    # same rig seconds, 1/X as long on the wall).
    clock_scale: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_force_n) and self.max_force_n > 0):
            raise ValueError(f"--max-force must be a positive force in N, got {self.max_force_n}")
        if self.steps < 4:
            raise ValueError(f"--steps must be 4 or more (the slope needs them), got {self.steps}")
        if not (math.isfinite(self.gauge_resolution_m) and 0 < self.gauge_resolution_m <= 1e-3):
            raise ValueError(f"--gauge-resolution must be above 0 and at most 1 mm, got {self.gauge_resolution_m * 1e3} mm")
        if not (math.isfinite(self.gauge_force_n) and self.gauge_force_n >= 0):
            raise ValueError(f"--gauge-force must be 0 N or more, got {self.gauge_force_n}")
        if not (math.isfinite(self.gauge_rate_n_per_m) and self.gauge_rate_n_per_m >= 0):
            raise ValueError(f"--gauge-rate must be 0 N/m or more, got {self.gauge_rate_n_per_m}")
        if not (math.isfinite(self.read_delay_s) and self.read_delay_s >= 0):
            raise ValueError(f"the read delay must be 0 s or more, got {self.read_delay_s}")
        if not (math.isfinite(self.hold_s) and 0 <= self.hold_s <= 3600):
            raise ValueError(f"--hold must be 0-3600 s, got {self.hold_s}")
        if not (math.isfinite(self.clock_scale) and self.clock_scale > 0):
            raise ValueError(f"the clock scale must be above 0, got {self.clock_scale}")

    def wait(self, seconds: float) -> None:
        """Wait ``seconds`` of the rig's time."""
        time.sleep(seconds / self.clock_scale)


@dataclass
class ShellBenchData:
    """What the bench test measured: each step's settled servo angle (rad) and gauge reading (m), the contact the
    current found (rad) and the gauge back at rest after the ramp (m)."""

    angles_rad: list[float] = field(default_factory=list)
    readings_m: list[float] = field(default_factory=list)
    contact_rad: float = math.nan
    rest_after_m: float = math.nan
    hold_step: int = -1  # the step held (index into the lists), -1 without a hold
    hold_after_m: float = math.nan  # the gauge at its end
    hold_s: float = 0.0


@dataclass(frozen=True)
class ShellBenchResult:
    data: ShellBenchData
    fit: ShellFit
    config: LabConfig
    settings: ShellBenchSettings

    def fixed_values(self) -> dict[str, float]:
        """The ``[lab.physics]`` values the data fixes (SI units)."""
        values = {"shell_stiffness_n_per_m": self.fit.stiffness_n_per_m, "shell_travel_m": self.fit.travel_m}
        return {key: value for key, value in values.items() if key not in self.fit.not_fixed}

    def calibration_bias(self) -> float:
        """The fraction by which the rig's ``F = k·r·(θ − θ_c)`` overstates the force on a sensor on this shell
        (below bottoming) in a calibration, with no gauge on the probe: ``k/(k + k_shell)``."""
        k = self.config.rig.spring_k_n_per_m
        return k / (k + self.fit.stiffness_n_per_m)


def run_bench(rig: CalibrationRig, gauge: TravelGauge, settings: ShellBenchSettings,
              progress: Callable[[str], None] = lambda line: None) -> ShellBenchData:
    """Run the plan on an open rig with the gauge on its probe; returns what was measured. Leaves the cable slack.
    Raises what the rig raises (no contact found, a move that does not settle, a refused force)."""
    data = ShellBenchData()
    contact = rig.find_contact()
    data.contact_rad = contact
    progress(f"contact (servo current) at {contact:+.3f} rad")
    top = min(settings.max_force_n, rig.max_force_n)
    forces = np.linspace(top / settings.steps, top, settings.steps)
    n_all = len(SLACK_OFFSETS_RAD) + len(forces)
    try:
        for i, offset in enumerate(SLACK_OFFSETS_RAD):
            rig.move_to(contact + offset)
            _read_step(rig, gauge, data, f"step {i + 1}/{n_all} (slack)", settings, progress)
        held = len(forces) // 2 if settings.hold_s > 0 else -1
        for j, force in enumerate(forces):
            rig.command_force(float(force))
            _read_step(rig, gauge, data, f"step {len(SLACK_OFFSETS_RAD) + j + 1}/{n_all} ({force:.2f} N nominal)",
                       settings, progress)
            if j == held:
                progress(f"holding {settings.hold_s:g} s (creep check)")
                settings.wait(settings.hold_s)
                data.hold_step, data.hold_s = len(data.readings_m) - 1, settings.hold_s
                data.hold_after_m = gauge.read_m(f"step {len(SLACK_OFFSETS_RAD) + j + 1} again, after "
                                                 f"{settings.hold_s:g} s held")
                progress(f"after the hold: gauge {data.hold_after_m * 1e3:.3f} mm")
    finally:
        rig.release()
    rig.position_at_rest_rad()
    settings.wait(settings.read_delay_s)
    data.rest_after_m = gauge.read_m("back at rest (cable slack)")
    progress(f"back at rest: gauge {data.rest_after_m * 1e3:.3f} mm")
    return data


def _read_step(rig: CalibrationRig, gauge: TravelGauge, data: ShellBenchData, what: str,
               settings: ShellBenchSettings, progress: Callable[[str], None]) -> None:
    """One step's angle and gauge reading, the angle read at rest before and after the reading: a wheel that crept
    meanwhile (more than a tick) is read again, so the pair belongs together."""
    for _ in range(STEP_READ_TRIES):
        rig.position_at_rest_rad()
        settings.wait(settings.read_delay_s)
        before = rig.position_at_rest_rad()
        reading = gauge.read_m(f"{what} at {before:+.3f} rad")
        after = rig.position_at_rest_rad()
        if abs(after - before) <= TICK_RAD:
            break
    data.angles_rad.append(after)
    data.readings_m.append(reading)
    progress(f"{what} at {after:+.4f} rad: gauge {reading * 1e3:.3f} mm")


def creep_line(result: ShellBenchResult) -> str:
    """What the hold says ("" without one): the shell crept beyond 3 gauge digits, or not."""
    data, settings = result.data, result.settings
    if data.hold_step < 0:
        return ""
    drift = data.hold_after_m - data.readings_m[data.hold_step]
    force = result.fit.force_n[data.hold_step]
    if abs(drift) > RETURN_DIGITS * settings.gauge_resolution_m:
        return (f"CREEP: held {data.hold_s:g} s at {force:.2f} N the probe went {drift * 1e3:+.3f} mm further: the "
                "shell is viscoelastic; the lab's shell (a spring and a damper) does not creep, and the stiffness "
                f"above is the one {settings.read_delay_s:g} s after each step")
    return (f"creep check: held {data.hold_s:g} s at {force:.2f} N the probe moved {drift * 1e3:+.3f} mm, within "
            f"{RETURN_DIGITS} gauge digits: no creep the gauge sees")


def damping_reason(config: LabConfig, stiffness_n_per_m: float) -> str:
    """Why a gauge read at rest cannot fix the shell's damping, with the time it settles in at the config's value."""
    physical = config.lab.physical
    k = config.rig.spring_k_n_per_m
    tau_ms = 1e3 * physical.shell_damping_n_s_per_m / (k + max(stiffness_n_per_m, 0.0))
    return (f"a dial gauge read at rest sees only the static deflection; at the config's "
            f"{physical.shell_damping_n_s_per_m:g} N·s/m the probe settles in c/(k + k_shell) ≈ {tau_ms:.0f} ms, "
            "far quicker than anyone reads a gauge (a probe position sampled at a kilohertz through a step would see it)")


def fit_bench(data: ShellBenchData, config: LabConfig, settings: ShellBenchSettings) -> ShellBenchResult:
    """Fit the measured steps (:func:`models.shell_fit.fit_shell`) after checking the probe came back to rest.
    Raises :class:`models.errors.ShellFitError` (a ValueError) with the reason when the data gives nothing."""
    from models.errors import ShellFitError

    readings = np.asarray(data.readings_m)
    if math.isfinite(data.rest_after_m) and len(readings):
        moved = abs(data.rest_after_m - readings[0])
        if moved > RETURN_DIGITS * settings.gauge_resolution_m:
            raise ShellFitError(
                f"the probe did not come back to its rest: the gauge read {readings[0] * 1e3:.3f} mm before the ramp "
                f"and {data.rest_after_m * 1e3:.3f} mm after it, cable slack both times: the segment moved on the "
                "beam, the gauge slipped, or the shell took a set; fix it and run again")
    rig = config.rig
    cable = rig.wheel_radius_m * (np.asarray(data.angles_rad) - data.angles_rad[0])
    fit = fit_shell(cable, readings, spring_k_n_per_m=rig.spring_k_n_per_m,
                    resolution_m=settings.gauge_resolution_m, gauge_force_n=settings.gauge_force_n,
                    gauge_rate_n_per_m=settings.gauge_rate_n_per_m, damping_reason="")
    fit.not_fixed["shell_damping_n_s_per_m"] = damping_reason(config, fit.stiffness_n_per_m)
    return ShellBenchResult(data, fit, config, settings)


def summary_lines(result: ShellBenchResult) -> list[str]:
    """The fit as a person reads it: a table of the steps, each value with its interval and verdict, the residual."""
    fit, data = result.fit, result.data
    lines = [f"{'step':>4} {'angle rad':>10} {'gauge mm':>9} {'travel mm':>10} {'force N':>8}"]
    for i, (angle, reading) in enumerate(zip(data.angles_rad, data.readings_m, strict=True)):
        lines.append(f"{i + 1:>4} {angle:+10.4f} {reading * 1e3:9.3f} {fit.travel_from_rest_m[i] * 1e3:10.3f} "
                     f"{fit.force_n[i]:8.3f}")
    r = result.config.rig.wheel_radius_m
    contact_fit = data.angles_rad[0] + fit.contact_cable_m / r
    lines.append(f"contact: {contact_fit:+.3f} rad from the gauge, {data.contact_rad:+.3f} rad from the servo's "
                 f"current; {fit.n_slack} slack, {fit.n_loaded} loaded, {fit.n_bottomed} bottomed-out steps")
    low, high = fit.stiffness_interval
    verdict = _verdict(fit, "shell_stiffness_n_per_m")
    lines.append(f"shell_stiffness_n_per_m  {fit.stiffness_n_per_m:9.1f}  95 %: {low:.1f} to {high:.1f}  {verdict}")
    if math.isnan(fit.travel_m):
        lines.append(f"shell_travel_m           {'—':>9}  {_verdict(fit, 'shell_travel_m')}")
    else:
        low, high = fit.travel_interval
        lines.append(f"shell_travel_m           {fit.travel_m:9.5f}  95 %: {low:.5f} to {high:.5f}  "
                     f"{_verdict(fit, 'shell_travel_m')}")
    lines.append(f"shell_damping_n_s_per_m  {'—':>9}  {_verdict(fit, 'shell_damping_n_s_per_m')}")
    lines.append(f"residual RMS {fit.residual_rms_m * 1e3:.4f} mm of gauge (its digit alone explains "
                 f"{fit.noise_floor_m * 1e3:.4f} mm); largest force {fit.largest_force_n:.2f} N at "
                 f"{fit.largest_travel_m * 1e3:.3f} mm")
    if creep_line(result):
        lines.append(creep_line(result))
    lines.append(f"the interval holds the gauge's scatter only: the stiffness scales with the rig's spring "
                 f"({result.config.rig.spring_k_n_per_m:g} N/m, rig.spring_k_n_per_m): a spring off by x % moves it "
                 "by x %")
    lines.append(f"a sensor calibrated through this shell with F = k·r·(θ − θ_c) has every force overstated by "
                 f"{100 * result.calibration_bias():.1f} % of the rig's value (k/(k + k_shell)), below bottoming out")
    return lines


def _verdict(fit: ShellFit, key: str) -> str:
    return f"NOT FIXED: {fit.not_fixed[key]}" if key in fit.not_fixed else "fixed"


def shell_toml(result: ShellBenchResult) -> str:
    """The fixed values as a lab-config fragment (``[lab.physics]``) that ``--config`` accepts, with the intervals,
    the residual, the steps and what the data could not fix in comments."""
    fit, config, settings = result.fit, result.config, result.settings
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# sensnake lab shell ({when}): force against deflection of a segment's shell on the calibration rig",
             f"# (spring {config.rig.spring_k_n_per_m:g} N/m, wheel {config.rig.wheel_radius_m * 1e3:g} mm; dial "
             f"gauge digit {settings.gauge_resolution_m * 1e3:g} mm, measuring force {settings.gauge_force_n:g} N "
             f"falling {settings.gauge_rate_n_per_m:g} N/m).",
             f"# {len(result.data.angles_rad)} steps; residual RMS {fit.residual_rms_m * 1e3:.4f} mm of gauge; "
             f"largest force {fit.largest_force_n:.2f} N. Intervals: 95 %, the gauge's scatter only (the stiffness "
             "scales with the spring's k).",
             "# steps (angle rad, gauge mm): " + "; ".join(
                 f"{a:.4f} {g * 1e3:.3f}" for a, g in zip(result.data.angles_rad, result.data.readings_m,
                                                            strict=True))]
    if creep_line(result):
        lines.append(f"# {creep_line(result)}")
    for key, why in fit.not_fixed.items():
        lines.append(f"# NOT FIXED, not written: {key}: {why}")
    lines += ["", "[lab.physics]"]
    low, high = fit.stiffness_interval
    if "shell_stiffness_n_per_m" not in fit.not_fixed:
        lines.append(f"shell_stiffness_n_per_m = {fit.stiffness_n_per_m:.6g}  # 95 %: {low:.5g} to {high:.5g}")
    if "shell_travel_m" not in fit.not_fixed:
        low, high = fit.travel_interval
        lines.append(f"shell_travel_m = {fit.travel_m:.6g}  # 95 %: {low:.5g} to {high:.5g}")
    return "\n".join(lines) + "\n"


def write_shell_toml(result: ShellBenchResult, out: str | Path) -> Path:
    """Write :func:`shell_toml` to ``out``, a new file (an existing one is never replaced)."""
    out = Path(out)
    with open(out, "x", encoding="utf-8") as handle:
        handle.write(shell_toml(result))
    return out
