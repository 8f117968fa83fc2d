"""Draw the README figure from a ``sensnake experiment obstacle`` recording: estimated force versus time for every
bottom sensor, one strip per segment (head on top), as the paper's Fig. 6E, plus the body's side view at a few times
(as its Fig. 6D), and print the figures the README compares with the paper's.

    python scripts/obstacle_figure.py REC.h5 docs/screenshots/obstacle_forces.png

On each strip a dot marks the moment that sensor is pressed hardest; read from head to tail, the dots move later in
time: the force pattern travels backward along the body. Uses pyqtgraph's image exporter offscreen (no extra
dependency).
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
from widgets.theme import no_si_prefix  # noqa: E402

SNAPSHOT_COLOURS = ((30, 30, 200), (0, 150, 0), (220, 130, 0), (200, 0, 0))
PRESSING_FRACTION_OF_WEIGHT = 0.15  # a sensor "presses" when it carries more than this share of the weight


def summary(recording, forces: np.ndarray, sim_t: np.ndarray, points: np.ndarray, weight_n: float) -> dict:
    """The numbers the README sets beside the paper's Fig. 6E (all from the recording, nothing assumed)."""
    t = recording.time_s
    total = forces.sum(axis=1)
    peaks = forces.max(axis=0)
    peak_times = t[np.argmax(forces, axis=0)]
    moving = t >= 1.0  # from the first shift on (before it the limp drape's load is spread evenly)
    loaded = forces[moving].max(axis=1) > PRESSING_FRACTION_OF_WEIGHT * weight_n
    most = (np.argmax(forces[moving], axis=1) + 1).astype(float)  # the segment pressed hardest, 1 = head
    most[~loaded] = np.nan
    ok = np.isfinite(most)
    slope = float(np.polyfit(t[moving][ok], most[ok], 1)[0]) if ok.sum() > 2 else float("nan")
    centroid = points[:, :, 0].mean(axis=1)
    window = max(1, int(np.searchsorted(sim_t, sim_t[0] + 1.0)))  # samples in 1 s
    speed = (centroid[window:] - centroid[:-window]) / (sim_t[window:] - sim_t[:-window])
    fastest = int(np.argmax(speed)) if speed.size else 0
    return {
        "played_s": float(t[-1] - t[0]),
        "median_total_N": float(np.median(total)), "weight_N": weight_n,
        "advance_centroid_m": float(centroid[-1] - centroid[0]), "advance_head_m": float(points[-1, 0, 0] - points[0, 0, 0]),
        "max_force_N": float(peaks.max()), "max_force_sensor": f"S{int(np.argmax(peaks)) + 1:02d}B",
        "max_force_pct_weight": float(100 * peaks.max() / weight_n),
        "most_loaded_segment_per_s": slope,
        "most_loaded_segment_first_last_5s": (float(np.nanmedian(most[t[moving] < t[moving][0] + 5])),
                                              float(np.nanmedian(most[t[moving] > t[-1] - 5]))),
        "median_advance_cm_s": float(100 * np.median(speed)) if speed.size else float("nan"),
        "fastest_1s_advance_cm_s": (float(100 * speed[fastest]), float(sim_t[fastest])) if speed.size else None,
        "peak_time_s_per_sensor": [round(float(x), 1) for x in peak_times],
        "peak_N_per_sensor": [round(float(x), 1) for x in peaks],
        "sim_span_s": float(sim_t[-1] - sim_t[0]),
    }


def main(recording_path: str, png_path: str) -> None:
    app = QApplication.instance() or QApplication([])
    pg.setConfigOptions(antialias=True, background="w", foreground="k")
    recording = open_recording(recording_path)
    bottom = [i for i, name in enumerate(recording.channels) if name.endswith("B")]
    names = [recording.channels[i] for i in bottom]
    if recording.forces_n is None or not bottom:
        raise SystemExit(f"{recording_path}: no estimated bottom-sensor forces (/forces); record it with "
                         "sensnake experiment obstacle")
    forces = np.nan_to_num(recording.forces_n[:, bottom])
    t = recording.time_s
    with h5py.File(recording_path) as f:
        if "sim" not in f:
            raise SystemExit(f"{recording_path}: no simulated body (/sim); record it with sensnake experiment obstacle")
        sim_t = f["sim/time_s"][:]
        points = f["sim/points_m"][:]
        height = float(f["sim"].attrs["obstacle_height_m"])
        if "weight_N" in f["sim"].attrs:
            weight_n = float(f["sim"].attrs["weight_N"])
        else:  # recordings made before the attribute: SenSnake v2's 2.4 kg, said so
            weight_n = 2.4 * 9.81
            print(f"{recording_path}: no /sim weight_N attribute; taking the paper's 2.4 kg robot")  # noqa: T201
    layout = pg.GraphicsLayoutWidget()
    layout.resize(1100, 1000)
    side = layout.addPlot(row=0, col=0, title="side view of the simulated body (head at the right end; obstacle in "
                                              "grey) — cf. the paper's Fig. 6D")
    side.addLegend(offset=(10, 5))
    arc = np.linspace(0, np.pi, 100)
    side.plot(height * np.cos(arc), height * np.sin(arc), pen=pg.mkPen((150, 150, 150), width=2))
    side.plot([-0.9, 0.9], [0, 0], pen=pg.mkPen((150, 150, 150), width=1))
    picks = np.linspace(0, len(sim_t) - 1, len(SNAPSHOT_COLOURS)).astype(int)
    for colour, index in zip(SNAPSHOT_COLOURS, picks, strict=True):
        side.plot(points[index, :, 0], points[index, :, 2], pen=pg.mkPen(colour, width=3),
                  symbol="o", symbolSize=4, symbolBrush=colour, symbolPen=None, name=f"t = {sim_t[index]:.0f} s")
    side.setAspectLocked(True)
    side.setXRange(-0.8, 0.9, padding=0)
    for axis, label in (("bottom", "x (m), obstacle axis at 0"), ("left", "z (m)")):
        no_si_prefix(side.getAxis(axis))
        side.setLabel(axis, label)
    spacing = max(5.0, float(np.ceil(np.percentile(forces, 99.5) / 5.0) * 5.0))
    strips = layout.addPlot(row=1, col=0, title="estimated force on each bottom sensor, head on top — cf. the paper's "
                                                f"Fig. 6E (strips {spacing:.0f} N apart; ● = that sensor's peak)")
    t0, t1 = float(t[0]), float(t[-1])
    label_x = t0 - 0.07 * (t1 - t0)
    peak_x, peak_y = [], []
    for k in range(forces.shape[1]):
        offset = (forces.shape[1] - 1 - k) * spacing
        strips.plot([t0, t1], [offset, offset], pen=pg.mkPen((210, 210, 210), width=1))
        strips.plot(t, forces[:, k] + offset, pen=pg.mkPen((20, 20, 20), width=1.2))
        label = pg.TextItem(names[k], color=(60, 60, 60), anchor=(0, 0.5))
        label.setPos(label_x, offset + 0.25 * spacing)
        strips.addItem(label)
        peak = int(np.argmax(forces[:, k]))
        if forces[peak, k] > PRESSING_FRACTION_OF_WEIGHT * weight_n:
            peak_x.append(t[peak])
            peak_y.append(forces[peak, k] + offset)
    strips.plot(peak_x, peak_y, pen=None, symbol="o", symbolSize=7, symbolBrush=(200, 0, 0), symbolPen=None)
    # Force scale: a bar of `spacing` newtons at the right end.
    bar_x = t1 + 0.02 * (t1 - t0)
    strips.plot([bar_x, bar_x], [0, spacing], pen=pg.mkPen((0, 0, 0), width=3))
    scale = pg.TextItem(f"{spacing:.0f} N", color=(0, 0, 0), anchor=(0, 0.5))
    scale.setPos(bar_x, 0.5 * spacing)
    strips.addItem(scale)
    strips.setXRange(label_x, t1 + 0.08 * (t1 - t0), padding=0)
    strips.setLabel("bottom", "time since the shape was captured and play began (s)")
    strips.hideAxis("left")
    layout.ci.layout.setRowStretchFactor(0, 1)
    layout.ci.layout.setRowStretchFactor(1, 3)
    layout.show()
    app.processEvents()
    exporter = pg.exporters.ImageExporter(layout.scene())
    exporter.parameters()["width"] = 1100
    exporter.export(png_path)
    print(f"wrote {png_path}")  # noqa: T201 - a script reporting what it wrote
    for key, value in summary(recording, forces, sim_t, points, weight_n).items():
        print(f"  {key}: {value}")  # noqa: T201


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", metavar="REC.h5", help="a recording of sensnake experiment obstacle (or run)")
    parser.add_argument("png", metavar="OUT.png", help="the figure to write")
    args = parser.parse_args()
    try:
        main(args.recording, args.png)
    except (OSError, KeyError, ValueError) as exc:
        sys.exit(f"obstacle_figure: {args.recording}: {exc}")
