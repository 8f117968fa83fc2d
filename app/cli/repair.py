"""``sensnake repair REC.h5 [--out FIXED.h5]``: salvage a recording that was cut short (copy interrupted, disk full,
a failing USB stick) into a clean file.

Every row whose data lies wholly inside the bytes that survive is kept; nothing is guessed. Prints how much was
recovered. ``REC.h5`` is never changed; the default output is ``REC-repaired.h5`` beside it. A file that is not
damaged is copied as it is (and says so). Runs on the main thread.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.core.errors import RecordingFormatError
from app.core.recording import carry_groups, check_input, copy_recording, open_recording, repair_recording
from app.core.run_documents import carry_documents


def run(args: argparse.Namespace) -> int:
    path = check_input(args.recording)  # a link loop, a FIFO or a device is named as such, never "damaged"
    out = Path(args.out) if args.out else path.with_name(f"{path.stem}-repaired{path.suffix or '.h5'}")
    try:
        recording = open_recording(path)
    except RecordingFormatError:
        report = repair_recording(path, out)
        carry_documents(path, out, salvaged=report.text)  # the run it was, and that it was cut short
        carried, lost = carry_groups(path, out)  # the physics lab's /sim, /control, /mocap, … where they read whole
        said = (f"; also kept whole: {', '.join(carried)}" if carried else "") + \
            (f"; not salvaged (damaged): {', '.join(lost)}" if lost else "")
        print(f"{report.text}{said}; wrote {out}")
        return 0
    copy_recording(path, out)  # as it is: every group and attribute (a rewrite kept only the board's and robot's)
    print(f"{path.name} is not damaged: all {recording.n_samples} board samples ({recording.duration_s:.1f} s) "
          f"and everything else in it copied as it is to {out}")
    return 0
