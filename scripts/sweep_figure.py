"""Draw a sweep's figure (what ``sensnake experiment sweep`` writes as ``summary.svg``) from its ``summary.csv`` as a
PNG, for the docs and the README:

    python scripts/sweep_figure.py benchmarks/results/feedback/feedback_heldout13_summary.csv docs/screenshots/feedback_heldout13.png

The figure is :func:`app.core.sweep.summary_svg` of the summary's rows, rasterised at twice its size on white with
Qt's SVG renderer, offscreen. An existing OUT is replaced only with ``--force`` (one line, exit 2, otherwise).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("summary", help="a sweep's summary.csv")
    parser.add_argument("out", help="the PNG to write")
    parser.add_argument("--force", action="store_true", help="replace OUT if it exists")
    args = parser.parse_args()
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        parser.error(f"{out}: the figure is written as a .png")
    if out.exists() and not args.force:
        sys.stderr.write(f"{out} exists; pass --force to replace it\n")
        return 2

    from PySide6.QtCore import QByteArray
    from PySide6.QtGui import QColor, QGuiApplication, QImage, QPainter
    from PySide6.QtSvg import QSvgRenderer

    from app.core.sweep import read_summary, summary_svg

    try:
        rows = read_summary(args.summary)
    except (OSError, KeyError, ValueError) as exc:
        sys.stderr.write(f"{args.summary}: not a sweep summary ({exc})\n")
        return 2
    if not rows:
        sys.stderr.write(f"{args.summary}: no runs in it\n")
        return 2
    _app = QGuiApplication.instance() or QGuiApplication([])
    renderer = QSvgRenderer(QByteArray(summary_svg(rows).encode("utf-8")))
    size = renderer.defaultSize() * 2
    image = QImage(size, QImage.Format.Format_ARGB32)
    image.fill(QColor("white"))
    painter = QPainter(image)
    renderer.render(painter)
    painter.end()
    if not image.save(str(out)):
        sys.stderr.write(f"{out}: could not be written\n")
        return 2
    sys.stdout.write(f"{out}: {size.width()} × {size.height()} px, {len(rows)} runs\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
