"""Draw the README figure from a ``sensnake experiment obstacle`` recording: estimated force versus time for every
bottom sensor, one strip per segment (head on top), as the paper's Fig. 6E, plus the body's side view at a few times.

    python scripts/obstacle_figure.py REC.h5 docs/obstacle_forces.png

Uses pyqtgraph's image exporter offscreen (no extra dependency).
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

import h5py  # noqa: E402
import numpy as np  # noqa: E402
import pyqtgraph as pg  # noqa: E402
import pyqtgraph.exporters  # noqa: E402,F401
from PySide6.QtWidgets import QApplication  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from app.core.recording import open_recording  # noqa: E402


def main(recording_path: str, png_path: str) -> None:
    app = QApplication.instance() or QApplication([])
    pg.setConfigOptions(antialias=True, background="w", foreground="k")
    recording = open_recording(recording_path)
    if recording.forces_n is None:
        raise SystemExit(f"{recording_path} has no estimated forces (/forces): record it with a calibration")
    bottom = [i for i, name in enumerate(recording.channels) if name.endswith("B")]
    forces = np.nan_to_num(recording.forces_n[:, bottom])
    with h5py.File(recording_path) as f:
        sim_t = f["sim/time_s"][:]
        points = f["sim/points_m"][:]
        height = float(f["sim"].attrs["obstacle_height_m"])
    layout = pg.GraphicsLayoutWidget()
    layout.resize(1100, 900)
    side = layout.addPlot(row=0, col=0, title="side view (simulated body; obstacle in grey)")
    arc = np.linspace(0, np.pi, 100)
    side.plot(height * np.cos(arc), height * np.sin(arc), pen=pg.mkPen((150, 150, 150), width=2))
    side.plot([-0.8, 0.8], [0, 0], pen=pg.mkPen((150, 150, 150), width=1))
    picks = np.linspace(0, len(sim_t) - 1, 4).astype(int)
    for colour, index in zip(((30, 30, 200), (0, 150, 0), (220, 130, 0), (200, 0, 0)), picks):
        side.plot(points[index, :, 0], points[index, :, 2], pen=pg.mkPen(colour, width=3),
                  name=f"t = {sim_t[index]:.0f} s")
    side.setAspectLocked(True)
    side.setLabel("bottom", "x (m)")
    side.setLabel("left", "z (m)")
    spacing = max(5.0, float(np.ceil(np.percentile(forces, 99))))
    strips = layout.addPlot(row=1, col=0, title=f"estimated force on each bottom sensor, head on top "
                                                f"(strips {spacing:.0f} N apart)")
    for k in range(forces.shape[1]):
        offset = (forces.shape[1] - 1 - k) * spacing
        strips.plot(recording.time_s, forces[:, k] + offset, pen=pg.mkPen((20, 20, 20), width=1))
        label = pg.TextItem(f"S{k + 1:02d}B", color=(80, 80, 80), anchor=(1, 0.5))
        label.setPos(recording.time_s[0], offset)
        strips.addItem(label)
    strips.setLabel("bottom", "time since capture (s)")
    strips.hideAxis("left")
    layout.ci.layout.setRowStretchFactor(1, 3)
    layout.show()
    app.processEvents()
    exporter = pg.exporters.ImageExporter(layout.scene())
    exporter.parameters()["width"] = 1100
    exporter.export(png_path)
    print(f"wrote {png_path}")  # noqa: T201 - a script reporting what it wrote


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
