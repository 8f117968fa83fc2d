"""Save a plot (any widget) as a PNG or SVG image with a title line above it. GUI thread only.

The SVG is vector: traces, axes and text are drawn as paths and text, not a screenshot. Items that normally paint
from a pixmap cache (the force plots' axes and legends) are drawn directly for the export, so their text stays text.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import QPoint, QRect, QRectF, QSize, Qt
from PySide6.QtGui import QColor, QFont, QImage, QPainter, QRegion
from PySide6.QtWidgets import QGraphicsItem, QGraphicsView, QWidget

IMAGE_FORMATS = ("png", "svg")
TITLE_HEIGHT_PX = 20
PNG_SCALE = 2  # a PNG at twice the screen's pixels: sharp in a paper or a slide


def _uncached(widget: QWidget) -> list[tuple[QGraphicsItem, QGraphicsItem.CacheMode]]:
    """Turn off every graphics item's pixmap cache inside ``widget``; returns what to restore."""
    changed: list[tuple[QGraphicsItem, QGraphicsItem.CacheMode]] = []
    views = [widget] if isinstance(widget, QGraphicsView) else []
    views += widget.findChildren(QGraphicsView)
    for view in views:
        scene = view.scene()
        if scene is None:
            continue
        for item in scene.items():
            mode = item.cacheMode()
            if mode != QGraphicsItem.CacheMode.NoCache:
                changed.append((item, mode))
                item.setCacheMode(QGraphicsItem.CacheMode.NoCache)
    return changed


def _paint(painter: QPainter, widget: QWidget, title: str, width: int) -> None:
    painter.setRenderHint(QPainter.RenderHint.Antialiasing, True)
    painter.setRenderHint(QPainter.RenderHint.TextAntialiasing, True)
    if title:
        font = QFont(widget.font())
        font.setBold(True)
        painter.setFont(font)
        painter.setPen(QColor("#222222"))
        painter.drawText(QRectF(4, 0, width - 8, TITLE_HEIGHT_PX),
                         int(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignVCenter), title)
    # QWidget's render, not QGraphicsView's (which draws the scene only): the widget as shown, children included.
    QWidget.render(widget, painter, QPoint(0, TITLE_HEIGHT_PX if title else 0), QRegion(),
                   QWidget.RenderFlag.DrawChildren)


def image_kind(path: str | Path) -> str:
    """``"png"`` or ``"svg"``, by ``path``'s suffix; ValueError naming the file for another suffix."""
    path = Path(path)
    kind = path.suffix.lower().lstrip(".")
    if kind not in IMAGE_FORMATS:
        raise ValueError(f"{path.name}: an image is saved as .png or .svg, not {path.suffix or 'no suffix'}")
    return kind


def save_widget_image(widget: QWidget, path: str | Path, title: str = "", kind: str | None = None) -> Path:
    """Write ``widget`` as it looks now to ``path`` as ``kind`` (``"png"`` or ``"svg"``; by default by the suffix:
    a caller writing a temporary of another name says which), with ``title`` above it. Raises ValueError for another
    suffix, OSError naming ``path`` when it cannot be written."""
    path = Path(path)
    kind = image_kind(path) if kind is None else kind
    if kind not in IMAGE_FORMATS:
        raise ValueError(f"an image is saved as .png or .svg, not {kind}")
    width, height = widget.width(), widget.height() + (TITLE_HEIGHT_PX if title else 0)
    restore = _uncached(widget)
    try:
        if kind == "svg":
            from PySide6.QtSvg import QSvgGenerator

            generator = QSvgGenerator()
            generator.setFileName(str(path))
            generator.setSize(QSize(width, height))
            generator.setViewBox(QRect(0, 0, width, height))
            generator.setTitle(title or path.stem)
            painter = QPainter()
            if not painter.begin(generator):
                raise OSError(f"cannot write {path}")
            try:
                _paint(painter, widget, title, width)
            finally:
                painter.end()
            if not path.exists() or path.stat().st_size == 0:
                raise OSError(f"cannot write {path}")
        else:
            image = QImage(width * PNG_SCALE, height * PNG_SCALE, QImage.Format.Format_ARGB32)
            image.setDevicePixelRatio(PNG_SCALE)
            image.fill(QColor("white"))
            painter = QPainter(image)
            try:
                _paint(painter, widget, title, width)
            finally:
                painter.end()
            # The format named: a temporary's name says nothing of PNG. PySide6 takes it as str at run time (its
            # stubs say bytes, which it refuses).
            if not image.save(str(path), "PNG"):  # type: ignore[call-overload]
                raise OSError(f"cannot write {path}")
    finally:
        for item, mode in restore:
            item.setCacheMode(mode)
    return path
