"""SceneView: a 3-D picture of the simulated lab, or the 2-D body drawing when there is none.

A passive view. :meth:`SceneView.set_frame` shows an RGB picture (``(h, w, 3)`` uint8, e.g. an offscreen MuJoCo
render) scaled to fit; :meth:`SceneView.show_fallback` switches to the 2-D :class:`widgets.body_view.BodyView`
(reachable as :attr:`SceneView.body`, fed with ``set_angles`` by its owner) with a one-line reason above it, for a
real robot, the scripted simulated lab or a machine without OpenGL. GUI thread only.
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

    def __init__(self, axes: Sequence[str], segment_length_m: float, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.frames_shown = 0
        self.reason = QLabel("")
        self.reason.setWordWrap(True)
        self.picture = QLabel()
        self.picture.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.picture.setMinimumSize(160, 120)
        self.picture.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.picture.setStyleSheet("background: black;")
        self.body = BodyView(axes, segment_length_m)
        self._stack = QStackedWidget()
        self._stack.addWidget(self.picture)
        self._stack.addWidget(self.body)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.reason)
        layout.addWidget(self._stack, 1)
        self._pixmap: QPixmap | None = None
        self.show_fallback("")

    @property
    def showing_picture(self) -> bool:
        return self._stack.currentWidget() is self.picture

    def set_frame(self, rgb: np.ndarray) -> None:
        """Show ``rgb`` ((h, w, 3) uint8) scaled to the view, keeping its aspect ratio."""
        frame = np.ascontiguousarray(rgb, dtype=np.uint8)
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"a frame must be (height, width, 3) RGB, got shape {frame.shape}")
        height, width = frame.shape[:2]
        image = QImage(frame.data, width, height, 3 * width, QImage.Format.Format_RGB888).copy()  # own the pixels
        self._pixmap = QPixmap.fromImage(image)
        self._show_scaled()
        if not self.showing_picture:
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
