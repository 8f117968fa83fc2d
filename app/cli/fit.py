"""``sensnake fit TRIAL.csv... --sensor NAME --area M2 [--physics FILE.json] [--window 225 300] --out CAL.json
[--config FILE] [--fit-rate HZ] [--solver NAME]``.

Fits the linear and SLS models of one sensor to its calibration trials (models.calibration), writes them into the
calibration file (created, or updated with other sensors kept) and prints a per-trial table. Samples at the readout's
ceiling ``1/R_C`` (``board.r_c_ohm`` of ``--config``, else the default circuit) are saturated and not fitted. Runs
on the CLI's main thread. ``--solver`` (or ``SENSNAKE_FIT_SOLVER``) ``scipy|gauss-newton|ipopt|sqpmethod`` picks the joint-fit solver (default scipy, the
fastest at the same error; CasADi is the cross-check). ``--fit-rate`` (default 5 Hz) block-averages faster trials before the
fit (models.calibration.decimate_trial): a 1 kHz calibration costs about what a 5 Hz one does.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
from pathlib import Path

from app.core import calfiles
from devices.config import BoardConfig, load_config
from models.calibration import (
    DEFAULT_FIT_RATE_HZ,
    DEFAULT_SOLVER,
    SensorCalibration,
    TrialInput,
    calibrate_sensor,
    calibrate_with_drift,
)
from models.physics import PhysicsConstants

# The joint-fit solvers; --solver or SENSNAKE_FIT_SOLVER picks one (default models.calibration.DEFAULT_SOLVER).
SOLVERS = ("scipy", "gauss-newton", "ipopt", "sqpmethod")


def _physics(args: argparse.Namespace) -> PhysicsConstants:
    """--physics, else the constants already in --out, else the paper's values — written into the new file and
    announced on stderr, so the constants used are never hidden (SPEC §5 note: K_contact is a placeholder until the
    lab measures ρ1, ρ2 and H; refit with --physics once it has)."""
    if args.physics:
        return calfiles.read_physics(args.physics)
    out = Path(args.out)
    if out.exists():
        document = calfiles.read_calibration(out)
        if "physics" in document:
            return calfiles.physics_from_calibration(document, str(out))
    paper = PhysicsConstants()
    print(f"sensnake fit: note: no --physics given and {out} has none; using the paper's constants "
          f"{json.dumps(paper.to_dict())} (K_contact is a placeholder) and storing them in {out}",
          file=sys.stderr)
    return paper


def _short_tags(warnings: tuple[str, ...]) -> str:
    tags = []
    for text in warnings:
        if "saturated" in text:
            tags.append("saturated")
        elif text.startswith("no loading ramp"):
            tags.append("no-ramp")
        elif text.startswith("poor fit"):
            tags.append("poor-fit")
        elif text.startswith("paper LS"):
            tags.append("paper-LS-refused")
        elif text.startswith("per-trial fit refused"):
            tags.append("REFUSED")
        else:
            tags.append("see-below")
    return ",".join(dict.fromkeys(tags)) or "-"


def print_report(sensor: str, cal: SensorCalibration, out: str) -> None:
    """The per-trial table and the sensor summary, on stdout."""
    header = (f"{'file':<24} {'force_N':>8} {'c1_S':>11} {'c2_S':>11} {'c3_1/s':>10} {'E0_Pa':>11} {'E1_Pa':>11} "
              f"{'mu1_Pa_s':>11} {'rmse_S':>10}  warnings")
    print(header)
    print("-" * len(header))
    for t in cal.trials:
        name = t.name if len(t.name) <= 24 else "…" + t.name[-23:]
        values = (f"{'refused':>11} {'-':>11} {'-':>11}" if t.refused else
                  f"{float(t.params.E0_Pa):11.4e} {float(t.params.E1_Pa):11.4e} {float(t.params.mu1_Pa_s):11.4e}")
        print(f"{name:<24} {t.force_n:8.3f} {t.exp_fit.c1:11.4e} {t.exp_fit.c2:11.4e} {t.exp_fit.c3:10.4e} "
              f"{values} {t.rmse_s:10.3e}  {_short_tags(t.warnings)}")
    print()
    s = cal.sls
    print(f"sensor {sensor}: area {cal.area_m2:g} m², forces {cal.force_range_n[0]:g}–{cal.force_range_n[1]:g} N, "
          f"solver {cal.solver}")
    for key, value in (("E0_Pa", s.E0_Pa), ("E1_Pa", s.E1_Pa), ("mu1_Pa_s", s.mu1_Pa_s)):
        lo, hi = cal.sls_ci95[key]
        print(f"  sls {key:<9} {float(value):12.5e}   95% [{lo:.5e}, {hi:.5e}]")
    tau_lo, tau_hi = cal.tau_ci95
    print(f"  sls tau_s     {float(s.tau_s):12.5g}   95% [{tau_lo:.5g}, {tau_hi:.5g}] (profile)   "
          f"joint rmse {cal.rmse_s:.3e} S")
    if cal.drift_s_per_s is not None:
        print(f"  baseline drift {cal.drift_s_per_s * 1e6:+.4g} µS/s" + (" (separated from the creep: see warnings)"
                                                                      if cal.drift_s_per_s else " (none found)"))
    arm = cal.second_arm
    if arm is not None:
        if not arm.resolved:
            print(f"  second creep arm: none resolved (likelihood ratio {arm.lr:.1f})")
        else:
            slow = f"tau2 {arm.tau2_s:.4g} s, {100 * arm.share:.0f} % of the creep" if arm.tau2_resolved else \
                "tau2 beyond the records"
            print(f"  second creep arm: {slow}; ignoring it costs {arm.record_rms_n:.3g} N RMS here, "
                  f"{arm.long_hold_error_n:+.3g} N after {arm.long_hold_s / 60:.0f} min (see warnings)")
    if cal.sls_trend is not None:
        for key, (intercept, slope) in cal.sls_trend.items():
            print(f"  sls_trend {key:<9} {intercept:12.5e} + {slope:12.5e}·F")
    if cal.degenerate:
        print(f"  DEGENERATE SLS fit (stored with \"degenerate\": true; 'sensnake estimate' refuses it unless "
              f"--allow-degenerate): {'; '.join(cal.degenerate_reasons)}")
    if cal.linear is not None:
        r2 = cal.linear.r_squared
        print(f"  linear m {cal.linear.model.m_S_per_N:.5e} S/N, d {cal.linear.model.d_S:.5e} S, "
              + (f"R² {r2:.5f}" if math.isfinite(r2) else "R² undefined"))
    # The same warning on many trials is printed once with the list of trials (the paper's LS refuses every hold).
    grouped: dict[str, list[str]] = {}
    for t in cal.trials:
        for text in t.warnings:
            key = re.sub(r" \(±[^)]*\)", "", text)  # per-trial figures differ; the advice is the same
            grouped.setdefault(key, []).append(t.name)
    if grouped or cal.warnings:
        print("warnings:")
        for text, names in grouped.items():
            where = names[0] if len(names) == 1 else f"{len(names)} trials ({', '.join(names)})"
            print(f"  {where}: {text}")
        for text in cal.warnings:
            print(f"  sensor: {text}")
    print(f"wrote {sensor} to {out}")


def _check_sensor_on_board(sensor: str, board: BoardConfig, config_path: str | None) -> None:
    """A calibration for a sensor the board does not carry would never be used (and hides a typo): refuse it."""
    if sensor in board.channel_names:
        return
    names = board.channel_names
    where = (f"the board of {config_path}" if config_path else
             "the default board (pass --config FILE for a board with other channels)")
    raise ValueError(f"--sensor {sensor} is not a channel of {where}: its {len(names)} channels are "
                     f"{names[0]} … {names[-1]}")


def run(args: argparse.Namespace) -> int:
    if not args.sensor.strip():
        raise ValueError("--sensor must name the sensor, e.g. S06B")
    if not (args.area > 0 and math.isfinite(args.area)):
        raise ValueError(f"--area must be a positive area in m², got {args.area!r}")
    window = (float(args.window[0]), float(args.window[1]))
    if not window[0] < window[1]:
        raise ValueError(f"--window start must be before its end, got {window[0]:g} {window[1]:g}")
    if Path(args.out).exists():
        calfiles.read_calibration(args.out)  # refuse an unknown format/version before spending time fitting
    folder = Path(args.out).parent
    if not folder.is_dir():  # said before the fit, not after it
        what = "is not a folder" if folder.exists() else "does not exist"
        raise ValueError(f"--out {args.out}: the folder {folder} {what}")
    trials = []
    for path in args.trials:
        trial = calfiles.read_trial_csv(path)
        trials.append(TrialInput(Path(path).name, trial.time_s, trial.force_n, trial.conductance_s))
    board = load_config(args.config).board if getattr(args, "config", None) else BoardConfig()
    _check_sensor_on_board(args.sensor, board, getattr(args, "config", None))
    physics = _physics(args)
    # The readout's ceiling (SPEC §4: counts = 0 reads 1/R_C): such samples are censored, not fitted.
    saturation_s = 1.0 / board.r_c_ohm
    solver = getattr(args, "solver", None) or os.environ.get("SENSNAKE_FIT_SOLVER", DEFAULT_SOLVER)
    if solver not in SOLVERS:
        raise ValueError(f"SENSNAKE_FIT_SOLVER={solver!r} is not one of {', '.join(SOLVERS)}")
    fit_rate = getattr(args, "fit_rate", None)
    if fit_rate is None:
        fit_rate = DEFAULT_FIT_RATE_HZ
    if not (math.isfinite(fit_rate) and fit_rate >= 0):
        raise ValueError(f"--fit-rate must be a rate in Hz ≥ 0 (0: every sample), got {fit_rate:g}")
    fitter = calibrate_with_drift if getattr(args, "drift", "fit") == "fit" else calibrate_sensor
    cal = fitter(trials, args.area, physics, window_s=window, saturation_s=saturation_s, solver=solver,
                 fit_rate_hz=fit_rate or None)
    calfiles.update_calibration(args.out, args.sensor, cal.to_dict(), physics, calfiles.readout_of(board))
    print_report(args.sensor, cal, args.out)
    return 0
