"""``sensnake export REC.h5 --csv OUT.csv`` (SPEC §1, §3.5): a recording to CSV.

Columns: ``time_s`` (seconds since the recording started) then one per channel — forces in newtons when the
recording stored live forces (a calibration was in use), otherwise conductance in siemens; ``--units suffixed`` names
each column's unit (``<name>_N``, ``<name>_uS`` in µS). Runs on the main thread.
"""

from __future__ import annotations

import argparse

from app.core.recording import export_csv, open_recording


def run(args: argparse.Namespace) -> int:
    recording = open_recording(args.recording)
    suffixed = getattr(args, "units", "bare") == "suffixed"
    out = export_csv(recording, args.csv, unit_suffixes=suffixed)
    forces = recording.forces_n is not None and not recording.forces_from_defaults
    what = "forces (N)" if forces else ("conductance (µS)" if suffixed else "conductance (S)")
    print(f"wrote {recording.n_samples} rows × {len(recording.channels)} channels of {what} to {out}")
    if recording.forces_from_defaults:
        print("note: this recording's forces were estimated without a calibration (typical-sensor defaults of an "
              "older version): conductance exported instead")
    return 0
