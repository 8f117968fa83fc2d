"""Draw the kinematics beside the forces, as the paper's Fig. 6D/7A with 6E/7B: every segment's position along x (or
y, or its height z) against time on the left, the bottom sensors' forces against time on the right, one colour per segment
(head dark, tail light), one clock.

    python scripts/kinematics_figure.py REC.h5 OUT.png [--coord x|y|z] [--source mocap|sim]

Positions come from the recording's motion capture (``/mocap/segment_center_m``, added by ``sensnake mocap
import``), or else from the physics lab's simulated body (``/sim``, the truth; ``--source`` chooses). A segment
without a pose in a frame (fewer than 3 markers seen) is a gap in its line, never filled. Of a take longer than a few
thousand frames (``app.core.mocap.PLOT_FRAMES``) one frame in k is drawn, read so from the file (a 30-minute take
is never held whole), and the left panel's title says so. Forces are the estimated
``/forces/force_N`` of the bottom sensors. Uses pyqtgraph's image exporter offscreen (no extra dependency); never
writes over an existing file.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# The segments' colours are those of the app's kinematics panel (widgets.kinematics_view.segment_colour); the
# positions are read as the app reads them (app.core.mocap.segment_positions, at most PLOT_FRAMES of them).
WIDTH_PX = 1400
HEIGHT_PX = 760


def read_bottom_forces(path: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    from app.core.recording import open_recording

    recording = open_recording(path)
    bottom = [i for i, name in enumerate(recording.channels) if name.endswith("B")]
    if recording.forces_n is None or not bottom:
        raise ValueError("no estimated bottom-sensor forces (/forces/force_N)")
    n = min(len(recording.forces_n), recording.n_samples)
    return recording.time_s[:n], recording.forces_n[:n, bottom], [recording.channels[i] for i in bottom]


def draw(path: str, out: str, coord: str, source: str) -> str:
    import pyqtgraph as pg
    import pyqtgraph.exporters  # noqa: F401
    from PySide6.QtWidgets import QApplication

    from app.core.mocap import segment_positions
    from widgets.kinematics_view import segment_colour
    from widgets.theme import no_si_prefix

    time_s, centers, what = segment_positions(path, source)
    force_t, forces, names = read_bottom_forces(path)
    app = QApplication.instance() or QApplication([])
    pg.setConfigOptions(antialias=True, background="w", foreground="k")
    layout = pg.GraphicsLayoutWidget()
    layout.resize(WIDTH_PX, HEIGHT_PX)
    axis = "xyz".index(coord)
    n = centers.shape[1]
    word = {"x": "forward position x", "y": "lateral position y", "z": "height z"}[coord]
    # what was thinned goes on a line of its own: one long title would widen this panel and crop the forces'
    left = layout.addPlot(row=0, col=0, title=f"each segment's {word} — from {what}".replace("; ", "<br>"))
    t0 = float(min(time_s[0], force_t[0]))
    t1 = float(max(time_s[-1], force_t[-1]))
    finite_c = centers[..., axis][np.isfinite(centers[..., axis])]
    gap = 0.03 * float(np.ptp(finite_c)) if finite_c.size else 0.0  # labels closer than this would overlap
    labelled: list[float] = []
    for k in range(n):
        colour = segment_colour(k, n)
        curve = left.plot(time_s, centers[:, k, axis], pen=pg.mkPen(colour, width=2), connect="finite")
        curve.setDownsampling(auto=True, method="peak")
        curve.setClipToView(True)
        seen = np.flatnonzero(np.isfinite(centers[:, k, axis]))
        start = float(centers[seen[0], k, axis]) if seen.size else np.nan
        if seen.size and all(abs(start - y) > gap for y in labelled):  # the segment's number where its line begins
            labelled.append(start)
            text = pg.TextItem(f"{k + 1}" + (" head" if k == 0 else " tail" if k == n - 1 else ""), color=colour,
                               anchor=(1, 0.5))
            text.setPos(float(time_s[seen[0]]), float(centers[seen[0], k, axis]))
            left.addItem(text)
    left.setLabel("bottom", "time on the recording's clock (s)")
    left.setLabel("left", f"segment centre {coord} (m)")
    for side in ("bottom", "left"):
        no_si_prefix(left.getAxis(side))
    finite = forces[np.isfinite(forces)]
    spacing = max(5.0, float(np.ceil(np.percentile(finite, 99.5) / 5.0) * 5.0)) if finite.size else 5.0
    right = layout.addPlot(row=0, col=1, title=f"estimated force on each bottom sensor, head on top "
                                               f"(strips {spacing:.0f} N apart)")
    for k in range(forces.shape[1]):
        offset = (forces.shape[1] - 1 - k) * spacing
        right.plot([t0, t1], [offset, offset], pen=pg.mkPen((215, 215, 215), width=1))
        right.plot(force_t, forces[:, k] + offset, pen=pg.mkPen(segment_colour(k, forces.shape[1]), width=1.6),
                   connect="finite")
        text = pg.TextItem(names[k], color=(60, 60, 60), anchor=(1, 0.5))
        text.setPos(t0, offset + 0.3 * spacing)
        right.addItem(text)
    bar_x = t1 + 0.01 * (t1 - t0)
    right.plot([bar_x, bar_x], [0, spacing], pen=pg.mkPen((0, 0, 0), width=3))
    scale = pg.TextItem(f"{spacing:.0f} N", color=(0, 0, 0), anchor=(0, 0.5))
    scale.setPos(bar_x, 0.5 * spacing)
    right.addItem(scale)
    right.hideAxis("left")
    right.setLabel("bottom", "time on the recording's clock (s)")
    for plot in (left, right):
        plot.setXRange(t0 - 0.1 * (t1 - t0), t1 + 0.08 * (t1 - t0), padding=0)
    layout.show()
    app.processEvents()
    exporter = pg.exporters.ImageExporter(layout.scene())
    exporter.parameters()["width"] = WIDTH_PX
    work = Path(out).with_name(f".{Path(out).name}.{os.getpid()}.partial.png")
    exporter.export(str(work))
    try:
        os.link(work, out)  # never over an existing file
    finally:
        work.unlink(missing_ok=True)
    layout.close()
    return what


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", metavar="REC.h5", help="a recording with /mocap (or a physics-lab run's /sim)")
    parser.add_argument("png", metavar="OUT.png", help="the figure to write (a new file)")
    parser.add_argument("--coord", choices=("x", "y", "z"), default="x",
                        help="x: forward position (the paper's Fig. 7A, default); y: lateral position (a serpenoid's "
                             "sway); z: height (the side view's other axis)")
    parser.add_argument("--source", choices=("auto", "mocap", "sim"), default="auto",
                        help="where the positions come from (default: /mocap if there, else /sim)")
    args = parser.parse_args()
    if os.path.lexists(args.png):
        print(f"kinematics_figure: {args.png} exists: give a new file", file=sys.stderr)  # noqa: T201
        return 1
    try:
        what = draw(args.recording, args.png, args.coord, args.source)
    except (OSError, KeyError, ValueError) as exc:
        print(f"kinematics_figure: {args.recording}: {exc}", file=sys.stderr)  # noqa: T201
        return 1
    print(f"wrote {args.png}: segment positions from {what} beside the bottom sensors' forces")  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
