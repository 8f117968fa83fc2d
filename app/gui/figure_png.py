"""A figure's SVG text rasterised to a PNG with Qt's SVG renderer, offscreen (the command line's reports: the
figure itself is drawn Qt-free in ``app.core``; only its pixels come from Qt); and :func:`write_beside`, how any
image Qt writes by its name reaches a user's file whole or not at all.

Any thread that may create a ``QGuiApplication`` (the main thread of a command); in the GUI, the GUI thread.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from pathlib import Path

from app.core.errors import OutputPathError
from app.core.outputs import check_output, move_into_place, temporary_beside


def svg_to_png(svg_text: str, out: str | os.PathLike[str], scale: float = 1.5) -> Path:
    """Write ``svg_text`` as a PNG at ``out`` (``scale`` × its size, on white), whole or not at all; OSError naming
    ``out`` when it cannot be written."""
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")  # a report needs no display
    from PySide6.QtCore import QByteArray
    from PySide6.QtGui import QColor, QGuiApplication, QImage, QPainter
    from PySide6.QtSvg import QSvgRenderer
    from PySide6.QtWidgets import QApplication

    out = check_output(out)
    # A QApplication (not the lighter QGuiApplication): the process's one application may later be asked for
    # widgets (a test run, the GUI) and Qt allows one application object per process.
    _app = QGuiApplication.instance() or QApplication([])
    renderer = QSvgRenderer(QByteArray(svg_text.encode("utf-8")))
    if not renderer.isValid():
        raise ValueError(f"{out}: the figure's SVG did not parse")
    size = renderer.defaultSize() * scale
    image = QImage(size, QImage.Format.Format_RGB32)
    image.fill(QColor("white"))
    painter = QPainter(image)
    painter.setRenderHint(QPainter.RenderHint.Antialiasing)
    renderer.render(painter)
    painter.end()
    # The temporary's name says nothing of PNG, so the format is named; PySide6 takes it as str at run time (its
    # stubs say bytes, which it refuses).
    write_beside(out, lambda work: image.save(str(work), "PNG"))  # type: ignore[call-overload]
    return out


def write_beside(out: Path, write: Callable[[Path], bool]) -> None:
    """``write(work)`` (Qt writing a file by its name; False when it could not) into a hidden temporary beside
    ``out``, then moved onto ``out`` (:mod:`app.core.outputs`): whole or not at all, only ever over a regular file.
    OSError naming ``out``, never the temporary."""
    try:
        with temporary_beside(out) as (fd, work):
            os.close(fd)
            if not write(work):
                raise OSError(errno.EIO, "Qt could not write it")
            move_into_place(work, out)
    except OutputPathError:
        raise
    except OSError as exc:  # Qt's own failures carry no errno, and name the temporary
        raise OSError(exc.errno or errno.EIO, f"cannot write {out}: {exc.strerror or 'Qt could not write it'}") \
            from None
