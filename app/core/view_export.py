"""The Forces tab's CSV export of a recording: every column's unit in its header, the robot beside the forces, and
optionally only a time range (what the plots show).

Columns: ``time_s``; one per sensor, ``<name>_N`` (force estimated live) or ``<name>_uS`` (conductance, for a sensor
with no force in the file: uncalibrated, or no calibration recorded); then per joint ``J<k>_present_rad``,
``J<k>_goal_rad`` and ``J<k>_current_mA`` when the recording has the robot. A force column never falls back to
conductance for some rows: a row whose force is missing (NaN in the file) is left empty. Robot values are those of the
newest robot sample at or before the row's time (the robot is sampled on its own clock; nothing is interpolated);
rows before the first robot sample leave them empty.

``sensnake export`` (SPEC §3.5, ``time_s`` then one column per channel) is unchanged: :func:`app.core.recording.
export_csv`. Qt-free; any thread.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path
from typing import TextIO

import numpy as np

from app.core import calfiles
from app.core.recording import Recording

MICRO = 1e6
_NAN_FIELD = re.compile(r"(?<![^,\n])[-+]?nan(?![^,\n])", re.IGNORECASE)


def export_view_csv(recording: Recording, out: str | Path, t0_s: float | None = None,
                    t1_s: float | None = None, joint_ids: list[int] | None = None) -> tuple[Path, int]:
    """Write ``recording`` (rows with ``t0_s <= time_s <= t1_s`` when given) to ``out``; returns (path, rows).

    ``joint_ids`` names the joint columns (``J<id>``); by default 1…J. Raises OSError naming ``out`` when it cannot
    be written, ValueError for an empty range.
    """
    out = Path(out)
    time_s = np.asarray(recording.time_s, dtype=float)
    n_rows = time_s.shape[0]
    keep = np.ones(n_rows, dtype=bool)
    if t0_s is not None:
        keep &= time_s >= t0_s
    if t1_s is not None:
        keep &= time_s <= t1_s
    rows = np.flatnonzero(keep)
    if t0_s is not None and t1_s is not None and not rows.size:
        raise ValueError(f"no samples between {t0_s:.3f} s and {t1_s:.3f} s")

    header = ["time_s"]
    columns: list[np.ndarray] = [time_s[rows]]
    forces = recording.forces_n
    in_newtons = recording.force_channels
    for c, name in enumerate(recording.channels):
        if forces is not None and in_newtons[c]:
            column = np.full(n_rows, np.nan)
            n = min(forces.shape[0], n_rows)
            column[:n] = forces[:n, c]
            header.append(f"{name}_N")
            columns.append(column[rows])
        else:
            header.append(f"{name}_uS")
            columns.append(np.asarray(recording.conductance_s[:, c], dtype=float)[rows] * MICRO)

    robot = recording.robot
    if robot is not None and robot.time_s.size:
        n_joints = robot.present_rad.shape[1]
        ids = list(joint_ids) if joint_ids is not None and len(joint_ids) == n_joints else list(range(1, n_joints + 1))
        # The newest robot sample at or before each row: index -1 (before the first) stays empty.
        index = np.searchsorted(robot.time_s, time_s[rows], side="right") - 1
        valid = index >= 0
        safe = np.where(valid, index, 0)
        for label, table in (("present_rad", robot.present_rad), ("goal_rad", robot.goal_rad),
                             ("current_mA", robot.current_ma)):
            for j, joint in enumerate(ids):
                header.append(f"J{joint}_{label}")
                columns.append(np.where(valid, np.asarray(table, dtype=float)[safe, j], np.nan))
        # Joint columns grouped per joint reads better: J1 present, goal, current, J2 …
        first = 1 + len(recording.channels)
        robot_header, robot_columns = header[first:], columns[first:]
        order = [k * n_joints + j for j in range(n_joints) for k in range(3)]
        header[first:] = [robot_header[i] for i in order]
        columns[first:] = [robot_columns[i] for i in order]

    table = np.column_stack(columns)
    buffer = io.StringIO()
    np.savetxt(buffer, table, delimiter=",", fmt="%.10g")
    body = _NAN_FIELD.sub("", buffer.getvalue())  # a missing value is an empty field, never a number
    def write(handle: TextIO) -> None:
        csv.writer(handle, lineterminator="\n").writerow(header)
        handle.write(body)

    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"cannot write {out}: the folder {folder} "
                                f"{'is not a folder' if folder.exists() else 'does not exist'}")
    # All or nothing, and only ever over a regular file (app.core.outputs): a device or FIFO is refused.
    calfiles.write_atomically(out, write)
    return out, int(rows.size)
