"""The app's motion capture and its Lab Streaming Layer streams: the GUI's face of :class:`app.core.lsl_link.LslLinks`
(the same core ``sensnake record --mocap lsl:NAME --lsl-out`` runs).

One :class:`MocapLink` per lab (``lab.mocap``). The Forces tab's picker (:func:`install_mocap_picker`, beside Record)
chooses its source — none, the simulated lab's (the physics lab publishes its body's markers at 960 Hz,
:mod:`devices.sim.mocap_stream`; ``[lab] mocap = true`` picks it at start) or an LSL stream by name, found as the
user's own LSL configuration says (this computer or the lab's network: the app leaves that to the user) — and
switches the app's own streams on and off (``SenSnake-forces`` from the Forces tab's live session, ``SenSnake-joints``
from the control loop's states at its rate, ``SenSnake-events``). A stream is resolved on a worker thread (up to
5 s); its reader fits a few poses a second for the 3-D tab (:meth:`MocapLink.live_snapshot`, any thread). A
recording started while a source is followed gets every sample written into it as ``/mocap`` as it arrives
(:meth:`MocapLink.recording_started`, :meth:`MocapLink.recording_stopping`; nothing of the take is kept), and
:meth:`MocapLink.write_take` (on :class:`app.gui.recording_session.RecordingSession`'s worker) says what it holds.

Signals (GUI thread): ``source_changed(str)``, ``status_changed(str, str)`` (text, level), ``publishing_changed(bool)``.
Public methods are for the GUI thread unless they say otherwise.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, QTimer, Signal

from app.core.errors import MocapFileError
from app.core.lsl_link import LiveSnapshot, LiveTake, LslLinks, MocapInlet
from app.core.recorder import Recorder
from app.gui.thread_bridge import ThreadBridge
from devices.config import SIM_MOCAP, mocap_stream_spec
from devices.factory import installed_sim_lab, is_sim
from widgets import theme
from widgets.mocap_picker import MocapSourceButton

LIVE_RATE_HZ = 30.0  # poses fitted a second for the live views
STATUS_REFRESH_MS = 1000
SILENT_S = 1.0  # a followed stream quiet this long is said to be silent


def start_sim_stream() -> str:
    """Ask the simulated lab (in this process or its own) to publish its motion capture; its stream's name.
    ValueError when there is no simulated lab or it cannot film (the scripted lab). Any thread."""
    lab = installed_sim_lab()
    if lab is None:
        raise ValueError("no simulated lab is running: the simulated motion capture films the physics lab's robot "
                         "(port sim)")
    call = getattr(lab, "call", None)  # the lab's own process
    if callable(call):
        return str(call("start_mocap_stream"))
    start = getattr(lab, "start_mocap_stream", None)
    if not callable(start):
        raise ValueError("this simulated lab has no motion capture")
    return str(start())


class MocapLink(QObject):
    """See the module docstring. ``MocapLink(lab)``; :meth:`close` when the lab closes."""

    source_changed = Signal(str)
    status_changed = Signal(str, str)
    publishing_changed = Signal(bool)

    def __init__(self, lab: Any, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.lab = lab
        config = lab.config
        self.config = config
        self.links = LslLinks(None, config.mocap, config.robot.axes, joint_rate_hz=config.robot.control_rate_hz)
        self.source = ""
        self.status = "no motion capture"
        self.level = theme.IDLE
        self._bridge = ThreadBridge(self)
        self._request = 0
        self._resolvers: list[threading.Thread] = []
        self._closed = False
        self._received = (0, time.monotonic())
        self._timer = QTimer(self)
        self._timer.setInterval(STATUS_REFRESH_MS)
        self._timer.timeout.connect(self._refresh_status)
        robot = getattr(lab, "robot", None)
        if robot is not None and hasattr(robot, "state_block"):
            robot.state_block.connect(self.links.push_robot_states)
        if config.lab.mocap:
            self.set_source(config.lab.mocap)

    # -- what the views read ---------------------------------------------------------------------------------------
    @property
    def inlet(self) -> MocapInlet | None:
        return self.links.inlet

    @property
    def publishing(self) -> bool:
        return self.links.publisher is not None

    def live_snapshot(self) -> LiveSnapshot | None:
        """The newest poses the reader fitted (None without a source or before the first). Any thread."""
        inlet = self.links.inlet
        live = inlet.live if inlet is not None else None
        return live.snapshot() if live is not None else None

    def sim_available(self) -> tuple[bool, str]:
        """Whether the simulated lab can film its body here, and why not."""
        if not is_sim(self.config.robot.port):
            return False, "the simulated motion capture films the simulated robot: this robot is real"
        lab = installed_sim_lab()
        if lab is None or getattr(lab, "physics", None) is None:
            note = getattr(lab, "physics_note", "")
            return False, (f"the scripted simulated lab has no body to film ([lab] physics = \"mujoco\")"
                           f"{'; ' + note if note else ''}")
        return True, ""

    # -- the source --------------------------------------------------------------------------------------------------
    def set_source(self, source: str) -> None:
        """Follow ``source`` ("" none, ``sim`` the simulated lab's, ``lsl:NAME``): the one followed so far is let
        go at once, the new one resolved on a worker (``status_changed`` says how it went)."""
        if self._closed:
            return
        source = source.strip()
        if self.links.recording and source != self.source:  # the take would lose what it has kept so far
            self.source_changed.emit(self.source)
            self.status_changed.emit(f"the source stays {self.source or 'none'} while a recording runs: stop it "
                                     "first", theme.WARN)
            return
        self._request += 1
        self.source = source
        self.links.adopt(None)
        self._timer.stop()
        self.source_changed.emit(source)
        if not source:
            self._set_status("no motion capture", theme.IDLE)
            return
        spec = mocap_stream_spec(source)
        self._set_status(f"looking for LSL stream {spec.removeprefix('lsl:')!r}…", theme.WARN)
        thread = threading.Thread(target=self._resolve, args=(self._request, source, spec), name="mocap-resolve",
                                  daemon=True)
        self._resolvers = [t for t in self._resolvers if t.is_alive()] + [thread]
        thread.start()

    def _resolve(self, request: int, source: str, spec: str) -> None:  # worker thread
        try:
            if source == SIM_MOCAP:
                start_sim_stream()
            inlet = self.links.open_inlet(spec, collect=False, live_rate_hz=LIVE_RATE_HZ)
        except (ConnectionError, MocapFileError, ValueError, RuntimeError, OSError) as exc:
            self._bridge.post(self._failed, request, str(exc))
            return
        self._bridge.post(self._adopt, request, inlet)

    def _adopt(self, request: int, inlet: MocapInlet) -> None:
        if request != self._request or self._closed:  # another source was asked for meanwhile
            inlet.close()
            return
        self.links.adopt(inlet)
        self._received = (inlet.received, time.monotonic())
        self._set_status(f"following LSL stream {inlet.stream_name!r} ({len(inlet.channels)} channels, "
                         f"{inlet.rate_hz:g} Hz, {inlet.unit})", theme.OK)
        self._timer.start()

    def _failed(self, request: int, message: str) -> None:
        if request == self._request and not self._closed:
            self._set_status(f"not following: {message}", theme.ERROR)

    def _refresh_status(self) -> None:
        inlet = self.links.inlet
        if inlet is None:
            return
        now = time.monotonic()
        count, since = self._received
        rate = (inlet.received - count) / max(now - since, 1e-3)
        self._received = (inlet.received, now)
        silent = now - inlet.last_host_s  # NaN before the first sample
        where = f"LSL stream {inlet.stream_name!r}"
        if math.isnan(silent) or silent >= SILENT_S:
            quiet = "since it was found" if math.isnan(silent) else f"for {silent:.0f} s"
            self._set_status(f"{where} silent {quiet} ({inlet.dropouts} dropout(s) so far)", theme.ERROR)
        else:
            level = theme.WARN if inlet.dropouts else theme.OK
            self._set_status(f"following {where}: {rate:.0f} samples/s of {inlet.rate_hz:g} Hz, {inlet.dropouts} "
                             f"dropout(s), {inlet.missing} sample(s) missing", level)

    def _set_status(self, text: str, level: str) -> None:
        if (text, level) != (self.status, self.level):
            self.status, self.level = text, level
            self.status_changed.emit(text, level)

    # -- publishing --------------------------------------------------------------------------------------------------
    def bind_live(self, live: Any) -> None:
        """The live board session whose forces ``SenSnake-forces`` carries (the Forces tab's)."""
        self.links.live = live

    def set_publishing(self, on: bool) -> bool:
        """Publish the app's streams (True) or withdraw them; returns whether they are published."""
        if on and self.links.live is None:
            self._set_status("open the Forces tab to publish its forces on LSL", theme.ERROR)
        else:
            try:
                self.links.publish(on)
            except (OSError, RuntimeError) as exc:
                self._set_status(f"LSL streams not published: {exc}", theme.ERROR)
        self.publishing_changed.emit(self.publishing)
        return self.publishing

    # -- recordings --------------------------------------------------------------------------------------------------
    def recording_started(self, recorder: Recorder) -> None:
        """A recording starts: the samples from now on are kept for it."""
        self.links.start(recorder)

    def recording_stopping(self, recorder: Recorder) -> LiveTake | None:
        """The recording is about to close: its samples (None without a source)."""
        return self.links.stop(recorder)

    def write_take(self, take: LiveTake, path: str | Path, t0_monotonic_s: float) -> str:
        """Finish ``take``'s ``/mocap`` in the closed recording at ``path`` (written into it as it came; see
        :meth:`app.core.lsl_link.LiveTake.write`); one line saying what was written. Any thread (the recording
        session's worker)."""
        result = take.write(path, t0_monotonic_s, self.config.mocap, self.config.robot.axes)
        return take.summary(result, Path(path).name)

    # -- life cycle --------------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Let go of the stream and the outlets; joins the workers still resolving (each ends within its resolve
        timeout). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._timer.stop()
        self._bridge.close()
        for thread in self._resolvers:
            thread.join()
        self._resolvers = []
        self.links.close()


def install_mocap_picker(tab: Any) -> MocapSourceButton | None:
    """The Forces tab's motion-capture source and LSL switch, beside its Record button, wired to ``tab.lab.mocap``
    (None when the lab has none: a test's stand-in lab)."""
    link = getattr(tab.lab, "mocap", None)
    if not isinstance(link, MocapLink):
        return None
    link.bind_live(tab.live)
    button = MocapSourceButton(tab.controls)
    button.set_sim_available(*link.sim_available())
    button.show_source(link.source, link.status, link.level)
    button.set_publishing(link.publishing)
    button.source_requested.connect(link.set_source)
    button.publish_toggled.connect(link.set_publishing)
    link.status_changed.connect(lambda text, level: button.show_source(link.source, text, level))
    link.publishing_changed.connect(button.set_publishing)
    tab.controls.add_beside_record(button)
    return button
