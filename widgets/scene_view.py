"""SceneView: a 3-D picture of the simulated lab, or the 2-D body drawing when there is none.

A passive view. :meth:`SceneView.set_frame` shows an RGB picture (``(h, w, 3)`` uint8, e.g. an offscreen MuJoCo
render) scaled to fit; :meth:`SceneView.show_fallback` switches to the 2-D :class:`widgets.body_view.BodyView`
(reachable as :attr:`SceneView.body`, fed with ``set_angles`` by its owner) with a one-line reason above it, for a
real robot, the scripted simulated lab or a machine without OpenGL. Until the first picture or the fallback, it shows
``waiting_text`` on a black picture. The 2-D drawing is made only when first shown or asked for (two pyqtgraph views,
~20-30 ms of the GUI thread, which the 3-D lab's first opening does not need). GUI thread only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtGui import QImage, QPixmap
from PySide6.QtWidgets import QLabel, QSizePolicy, QStackedWidget, QVBoxLayout, QWidget

from widgets.body_view import BodyView


class SceneView(QWidget):
    """See the module docstring."""

    def __init__(self, axes: Sequence[str], segment_length_m: float, parent: QWidget | None = None,
                 waiting_text: str = "") -> None:
        super().__init__(parent)
        self._axes = tuple(axes)
        self._segment_length_m = segment_length_m
        self.frames_shown = 0
        self.reason = QLabel("")
        self.reason.setWordWrap(True)
        self.picture = QLabel()
        self.picture.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.picture.setMinimumSize(160, 120)
        self.picture.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.picture.setStyleSheet("background: black;")
        self._body: BodyView | None = None
        self._stack = QStackedWidget()
        self._stack.addWidget(self.picture)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.reason)
        layout.addWidget(self._stack, 1)
        self._pixmap: QPixmap | None = None
        self.reason.setText(waiting_text)
        self.reason.setVisible(bool(waiting_text))

    @property
    def body(self) -> BodyView:
        """The 2-D body drawing (made now if it was not)."""
        if self._body is None:
            self._body = BodyView(self._axes, self._segment_length_m)
            self._stack.addWidget(self._body)
        return self._body

    @property
    def has_body(self) -> bool:
        """The 2-D drawing has been made (shown as the fallback, or asked for)."""
        return self._body is not None

    @property
    def showing_picture(self) -> bool:
        """A rendered picture is shown (not the fallback, nor the black picture before the first frame)."""
        return self._stack.currentWidget() is self.picture and self._pixmap is not None

    def set_frame(self, rgb: np.ndarray) -> None:
        """Show ``rgb`` ((h, w, 3) uint8) scaled to the view, keeping its aspect ratio."""
        frame = np.ascontiguousarray(rgb, dtype=np.uint8)
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"a frame must be (height, width, 3) RGB, got shape {frame.shape}")
        height, width = frame.shape[:2]
        image = QImage(frame.data, width, height, 3 * width, QImage.Format.Format_RGB888).copy()  # own the pixels
        self._pixmap = QPixmap.fromImage(image)
        self._show_scaled()
        if self._stack.currentWidget() is not self.picture or self.reason.isVisible():
            self._stack.setCurrentWidget(self.picture)
            self.reason.setVisible(False)
        self.frames_shown += 1

    def show_fallback(self, reason: str) -> None:
        """Show the 2-D body drawing, with ``reason`` (why there is no 3-D picture) above it when not empty."""
        self._stack.setCurrentWidget(self.body)
        self.reason.setText(reason)
        self.reason.setVisible(bool(reason))

    def resizeEvent(self, event) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(event)
        self._show_scaled()

    def _show_scaled(self) -> None:
        if self._pixmap is not None:
            self.picture.setPixmap(self._pixmap.scaled(self.picture.size(), Qt.AspectRatioMode.KeepAspectRatio,
                                                       Qt.TransformationMode.SmoothTransformation))
