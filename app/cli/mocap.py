"""``sensnake mocap import TAKE.c3d|--xdf FILE.xdf --rec REC.h5 [--config LAB.toml] [--offset S] --out NEW.h5``:
a motion-capture take added to a recording on the recording's clock (``/mocap``, docs/MOCAP.md).

The take's markers are matched by ``[mocap] labels``, each segment's pose fitted to ``[mocap] marker_layout_m`` and
the take placed at ``--offset`` (the recording time of its first frame) or where its joint angles line up with the
recording's ``/robot/present_rad`` — printed with its confidence, or refused with the reason. A C3D take is read,
fitted and written a block of frames at a time (``app.core.mocap.import_take``); an XDF file is loaded whole (pyxdf). The lab config is
``--config``, else the one stored in the recording, else the default. REC.h5 is only read; NEW.h5 must not exist.

``sensnake mocap simulate REC.h5 --out TAKE.c3d [--lead S] [--seed K] [--config LAB.toml]``: a C3D take of a
physics-lab recording's simulated body (``/sim``), with noise, dropouts and a hidden segment, to try the import on.
Runs on the CLI's main thread.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from app.core.errors import MocapFileError
from app.core.mocap import (
    frames_of,
    import_take,
    open_c3d,
    read_xdf,
    refuse_existing,
    simulated_take,
    summary_lines,
)
from app.core.recording import Recording, open_recording
from devices.config import LabConfig, load_config, parse_config
from devices.errors import ConfigError
from models.errors import OffsetRefusedError


def run(args: argparse.Namespace) -> int:
    if args.mocap_command == "simulate":
        return _simulate(args)
    return _import(args)


def _lab_config(args: argparse.Namespace, recording: Recording | None) -> LabConfig:
    """``--config``, else the config stored in the recording, else the default; said on stderr."""
    if args.config:
        return load_config(args.config)
    if recording is not None and recording.config_text.strip():
        try:
            config = parse_config(recording.config_text, source=f"{recording.path} (its stored config)")
        except ConfigError as exc:
            print(f"sensnake mocap: note: the recording's stored config does not load ({exc}); using the default "
                  "(give --config)", file=sys.stderr)
            return LabConfig()
        print(f"sensnake mocap: note: joint axes and [mocap] from the config stored in {recording.path.name}",
              file=sys.stderr)
        return config
    return LabConfig()


def _import(args: argparse.Namespace) -> int:
    if bool(args.take) == bool(args.xdf):
        raise ValueError("give one take: TAKE.c3d, or --xdf FILE.xdf (a LabRecorder file with a MoCap stream)")
    out, rec = Path(args.out), Path(args.rec)
    refuse_existing(out, rec)  # before any work
    if args.offset is not None and not np.isfinite(args.offset):
        raise ValueError(f"--offset {args.offset}: give the recording time (s) of the take's first frame")
    recording = open_recording(rec)
    config = _lab_config(args, recording)
    n_segments = config.robot.n_joints
    take = frames_of(read_xdf(args.xdf, config.mocap, n_segments)) if args.xdf else \
        open_c3d(args.take, config.mocap, n_segments)
    robot = recording.robot
    if robot is not None and robot.present_rad.shape[1] != n_segments:
        raise MocapFileError(f"{rec}: /robot has {robot.present_rad.shape[1]} joints, the config {n_segments}")
    if args.offset is not None:
        _refuse_an_offset_off_the_recording(args.offset, take.time_s, [recording.time_s,
                                                                       robot.time_s if robot else None])
    shown = [0.0]

    def progress(done: int, total: int) -> None:
        """One line on a terminal, redrawn at most once a second (a 30-minute take takes minutes)."""
        now = time.monotonic()
        if sys.stderr.isatty() and (now - shown[0] >= 1.0 or done == total):
            shown[0] = now
            print(f"\rimporting {take.path.name}: {done:,} of {total:,} frames fitted and written"
                  + ("; finding the clock offset" if done == total and args.offset is None else "") + "\x1b[K",
                  end="" if done < total else "\n", file=sys.stderr, flush=True)

    try:
        imported = import_take(take, rec, out, config.mocap, config.robot.axes, robot.time_s if robot else None,
                               robot.present_rad if robot else None, take_start_s=args.offset, progress=progress)
    except OffsetRefusedError as exc:
        raise ValueError(f"{take.path.name} on {rec.name}: the motion cannot place the take on the recording's clock: "
                         f"{exc}; give --offset S (the recording time of the take's first frame)") from None
    print(f"take start on the recording's clock: {imported.take_start_s:+.4f} s ({imported.how})")
    for line in summary_lines(imported):
        print(f"  {line}")
    print(f"wrote {out}: {rec.name} with /mocap ({take.source})")
    return 0


def _refuse_an_offset_off_the_recording(offset_s: float, take_time_s: np.ndarray,
                                        clocks: list[np.ndarray | None]) -> None:
    """A given ``--offset`` that puts the take beside the recording, not on it (``--offset 500`` on a 2.4 s run; 1e300
    wrote every frame at the same time): refused, naming both spans. Only where both have times."""
    recorded = [np.asarray(t, dtype=float) for t in clocks if t is not None and len(t)]
    recorded = [t[np.isfinite(t)] for t in recorded]
    recorded = [t for t in recorded if t.size]
    if not recorded or not len(take_time_s):
        return
    span = float(take_time_s[-1] - take_time_s[0])
    first, last = min(float(t[0]) for t in recorded), max(float(t[-1]) for t in recorded)
    if offset_s > last or offset_s + span < first:
        raise ValueError(f"--offset {offset_s:g}: the take ({span:.2f} s) would lie at {offset_s:.6g} … "
                         f"{offset_s + span:.6g} s, the recording at {first:.3f} … {last:.3f} s: they do not "
                         "overlap; give the recording time (s) of the take's first frame")


def _simulate(args: argparse.Namespace) -> int:
    config = load_config(args.config) if args.config else LabConfig()
    made = simulated_take(args.recording, args.out, lead_s=args.lead, mocap=config.mocap, seed=args.seed)
    print(f"wrote {made.path}: {made.n_frames} frames at 960 Hz in mm, starting {made.take_start_s:+.4f} s on the "
          f"recording's clock; segment {made.hidden_segment + 1} hidden {made.hidden_s[0]:.2f} … "
          f"{made.hidden_s[1]:.2f} s; {made.dropped_fraction:.1%} of marker-frames unseen")
    return 0
