"""MocapSourceButton: the Forces tab's motion-capture source, beside Record, and the switch that publishes the app's
own streams on Lab Streaming Layer.

One compact button whose menu offers: no motion capture; the simulated lab's (when the physics lab can film its body);
an LSL stream by name (asked for, and remembered for the session); and, checkable, publishing SenSnake-forces,
SenSnake-joints and SenSnake-events. A passive view: it emits what the user picked (:attr:`source_requested` with
"", ``SIM_SOURCE`` or ``lsl:NAME``; :attr:`publish_toggled`) and shows what it is told (:meth:`show_source`,
:meth:`set_publishing`). GUI thread only.
"""

from __future__ import annotations

from PySide6.QtCore import Signal
from PySide6.QtGui import QAction, QActionGroup
from PySide6.QtWidgets import QInputDialog, QMenu, QToolButton, QWidget

from widgets import theme

SIM_SOURCE = "sim"  # the app's word for the simulated lab's own motion capture
NONE_TEXT = "No motion capture"
SIM_TEXT = "Simulated lab's motion capture (960 Hz)"
PUBLISH_TEXT = "Publish SenSnake streams on LSL (forces, joints, events)"


def source_words(source: str) -> str:
    """A source as the button names it."""
    if not source:
        return "off"
    if source == SIM_SOURCE:
        return "simulated"
    return source[4:] if source.startswith("lsl:") else source


class MocapSourceButton(QToolButton):
    """See the module docstring."""

    source_requested = Signal(str)
    publish_toggled = Signal(bool)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setPopupMode(QToolButton.ToolButtonPopupMode.InstantPopup)
        self.menu_ = QMenu(self)
        self._group = QActionGroup(self)
        self._group.setExclusive(True)
        self.none_action = self._source_action(NONE_TEXT, "")
        self.sim_action = self._source_action(SIM_TEXT, SIM_SOURCE)
        self._named: dict[str, QAction] = {}
        self._named_anchor = self.menu_.addSeparator()
        self.ask_action = self.menu_.addAction("LSL stream by name…")
        self.ask_action.setToolTip("Follow a Lab Streaming Layer stream of this name (else the first of type MoCap), "
                                   "found on this computer or the lab's network as your LSL configuration says")
        self.ask_action.triggered.connect(self.ask_for_stream)
        self.menu_.addSeparator()
        self.publish_action = self.menu_.addAction(PUBLISH_TEXT)
        self.publish_action.setCheckable(True)
        self.publish_action.setToolTip("Publish the forces (N where calibrated, else µS), the present joint angles "
                                       "(rad) and the events on LSL, each sample stamped when it was measured: "
                                       "LabRecorder records them beside the motion capture")
        self.publish_action.toggled.connect(self.publish_toggled)
        self.setMenu(self.menu_)
        self.none_action.setChecked(True)
        self._source = ""
        self.show_source("", "no motion capture: pick a source to record one with the forces", theme.IDLE)

    def _source_action(self, text: str, source: str) -> QAction:
        action = QAction(text, self)
        action.setCheckable(True)
        action.setData(source)
        action.triggered.connect(lambda _checked=False, s=source: self.source_requested.emit(s))
        self._group.addAction(action)
        self.menu_.addAction(action)
        return action

    def set_sim_available(self, available: bool, why_not: str = "") -> None:
        """Whether the simulated lab can film its body (a physics lab on port sim); ``why_not`` as the tooltip."""
        self.sim_action.setEnabled(available)
        self.sim_action.setToolTip("" if available else why_not)

    def ask_for_stream(self) -> None:
        """Ask for a stream's name; a name given becomes the source asked for."""
        name, ok = QInputDialog.getText(self, "Motion capture over LSL", "Stream name (its type MoCap is taken "
                                        "when no stream has this name):", text=self._last_name())
        if ok and name.strip():
            self.source_requested.emit(f"lsl:{name.strip()}")

    def _last_name(self) -> str:
        return next(reversed(self._named), "") if self._named else ""

    def _named_action(self, source: str) -> QAction:
        action = self._named.get(source)
        if action is None:
            action = QAction(f"LSL stream {source[4:]!r}", self)
            action.setCheckable(True)
            action.setData(source)
            action.triggered.connect(lambda _checked=False, s=source: self.source_requested.emit(s))
            self._group.addAction(action)
            self.menu_.insertAction(self._named_anchor, action)
            self._named[source] = action
        return action

    @property
    def source(self) -> str:
        return self._source

    def show_source(self, source: str, status: str, level: str) -> None:
        """The source followed ("" none) and how it fares, as the button's text, colour and tooltip."""
        self._source = source
        action = {"": self.none_action, SIM_SOURCE: self.sim_action}.get(source) or self._named_action(source)
        action.setChecked(True)
        publishing = " · LSL out" if self.publish_action.isChecked() else ""
        text = f"Mocap: {source_words(source)}{publishing}"
        if self.text() != text:
            self.setText(text)
        tip = f"Motion capture: {status}\nRecord stores it as /mocap beside the forces (docs/MOCAP.md)."
        if self.toolTip() != tip:
            self.setToolTip(tip)
        style = theme.status_style(level)
        if self.styleSheet() != style:
            self.setStyleSheet(style)

    def set_publishing(self, on: bool) -> None:
        """Reflect the LSL switch without re-emitting."""
        self.publish_action.blockSignals(True)
        self.publish_action.setChecked(on)
        self.publish_action.blockSignals(False)
        self.setText(f"Mocap: {source_words(self._source)}{' · LSL out' if on else ''}")
