"""The calibration wizard's state without Qt: its steps, what each step waits for, which controls are on.

The Calibration tab (:mod:`app.gui.tabs.calibration`) draws this model and forwards what happens to it: a click
becomes :meth:`CalibrationWizard.go_to`, a finished rig check :meth:`CalibrationWizard.check_finished`, and so on.
Whatever the tab shows about the wizard — the step's title, whether Back and Next are on, the line saying why Next is
off, which buttons a running fit or rig run disables — is read from here, so it can be tested without a display.

Two kinds of state meet here:

* **the wizard's own** (:class:`CalibrationWizard`'s fields): the step, and what the steps found (the sensor whose rig
  check passed, the sensor whose contact was found, whether a check or a contact search is going). Only the event
  methods change them; each change calls the listeners once.
* **facts the tab owns** (:class:`Facts`): the sensor typed in, how many trials are loaded, whether a fit or a rig run
  is going, whether a fit result is there. They are read fresh from the tab each time (never copied into the model,
  so they can never disagree with what the tab holds).

Adding a step is one entry in :data:`STEPS` (its title and what it waits for) and one page in the tab.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum


class Step(IntEnum):
    """The wizard's steps, in order (the tab's pages have the same order)."""

    SETUP = 0
    RIG_CHECK = 1
    CONTACT = 2
    PROTOCOL = 3
    REVIEW = 4
    SAVE = 5


@dataclass(frozen=True)
class Facts:
    """What the tab holds that the wizard's rules read (a snapshot taken when they are read)."""

    sensor: str  # the sensor's name as typed (stripped)
    channels: tuple[str, ...]  # the board's channel names (a sensor the rig can press is one of them)
    trials: int = 0  # trials in the list
    fitting: bool = False  # a fit is running
    rig_running: bool = False  # the rig session runs (a protocol run, or the contact search)
    fitted: bool = False  # a fit result is shown (and can be saved)
    session: bool = False  # the trials come from a rig session folder (redo/resume possible)


@dataclass(frozen=True)
class Controls:
    """Which of the tab's controls are on."""

    fit: bool
    add_trials: bool
    remove_trials: bool
    clear_trials: bool
    save: bool
    sensor: bool  # the sensor's name, its picker, the area
    run: bool
    resume: bool
    redo: bool
    rig_check: bool
    find_contact: bool


@dataclass(frozen=True)
class Nav:
    """The wizard's frame: the step line, Back, Next and the hint saying why Next is off."""

    step: Step
    title: str  # "Step 2 of 6 · Rig check"
    back: bool
    next: bool
    hint: str  # "" when Next is on (and on the last step)


@dataclass(frozen=True)
class StepSpec:
    """A step: its title, and why Next is off on it ("" when it is on)."""

    title: str
    waits_for: Callable[[CalibrationWizard, Facts], str]


def _setup_waits(_w: CalibrationWizard, facts: Facts) -> str:
    if facts.sensor not in facts.channels:
        return f"pick a sensor on the body ({facts.sensor or 'none'} is not a channel of the board)"
    return ""


def _check_waits(w: CalibrationWizard, facts: Facts) -> str:
    if w.checking:
        return "the rig check is running"
    return "" if w.rig_check_ok_for == facts.sensor else "run the rig check: Next needs every line to pass"


def _contact_waits(w: CalibrationWizard, facts: Facts) -> str:
    if w.contact_running:
        return "finding the contact…"
    return "" if w.contact_found_for == facts.sensor else "find the contact first"


def _protocol_waits(_w: CalibrationWizard, facts: Facts) -> str:
    if facts.rig_running:
        return "the run is going"
    return "" if facts.trials else "run the protocol (or resume a session)"


def _review_waits(_w: CalibrationWizard, facts: Facts) -> str:
    if facts.fitting:
        return "fitting…"
    return "" if facts.fitted else "fit the trials first"


def _save_waits(_w: CalibrationWizard, _facts: Facts) -> str:
    return "the last step"


STEPS: dict[Step, StepSpec] = {
    Step.SETUP: StepSpec("Setup: the sensor, its area, the readout", _setup_waits),
    Step.RIG_CHECK: StepSpec("Rig check", _check_waits),
    Step.CONTACT: StepSpec("Find contact · conditioning", _contact_waits),
    Step.PROTOCOL: StepSpec("Protocol run", _protocol_waits),
    Step.REVIEW: StepSpec("Review", _review_waits),
    Step.SAVE: StepSpec("Save", _save_waits),
}


class CalibrationWizard:
    """The wizard's step and what its steps found; see the module docstring. Not thread-safe: one thread (the GUI's)
    calls it."""

    def __init__(self) -> None:
        self.step = Step.SETUP
        self.rig_check_ok_for: str | None = None  # the sensor whose rig check passed
        self.checking = False  # a rig check is running
        self.checking_sensor = ""  # the sensor it checks
        self.contact_running = False  # the contact search is running
        self.contact_found_for: str | None = None  # the sensor whose contact was found
        self._listeners: list[Callable[[], None]] = []

    # -- listening ---------------------------------------------------------------------------------------------------
    def subscribe(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` after every change of the wizard's state."""
        self._listeners.append(listener)

    def _changed(self) -> None:
        for listener in list(self._listeners):
            listener()

    # -- events ------------------------------------------------------------------------------------------------------
    def go_to(self, step: int) -> Step:
        """Go to ``step`` (clamped to the first … last); returns the step now shown. Going is always allowed: the
        wizard guides, it does not lock (Next is off until a step is done; Back, the files route and a run's own
        progress may jump)."""
        target = Step(max(min(Step), min(max(Step), int(step))))
        if target != self.step:
            self.step = target
            self._changed()
        return self.step

    def check_started(self, sensor: str) -> bool:
        """A rig check of ``sensor`` starts (False, nothing changed, if one is already running). A new check forgets
        the last verdict."""
        if self.checking:
            return False
        self.checking, self.checking_sensor, self.rig_check_ok_for = True, sensor, None
        self._changed()
        return True

    def check_finished(self, passed: bool) -> None:
        """The rig check ended: passed only if every line passed."""
        self.checking = False
        self.rig_check_ok_for = self.checking_sensor if passed else None
        self._changed()

    def contact_started(self) -> None:
        self.contact_running, self.contact_found_for = True, None
        self._changed()

    def contact_finished(self, found: bool, sensor: str) -> None:
        self.contact_running = False
        self.contact_found_for = sensor if found else None
        self._changed()

    # -- what the tab shows ------------------------------------------------------------------------------------------
    def next_blocked(self, facts: Facts) -> str:
        """Why Next is off on the current step ("" when it is on)."""
        return STEPS[self.step].waits_for(self, facts)

    def nav(self, facts: Facts) -> Nav:
        blocked = self.next_blocked(facts)
        title = f"Step {int(self.step) + 1} of {len(STEPS)} · {STEPS[self.step].title}"
        last = self.step == max(Step)
        return Nav(self.step, title, back=self.step > min(Step), next=not blocked,
                   hint="" if not blocked or last else f"Next: {blocked}")

    def controls(self, facts: Facts) -> Controls:
        """Which controls are on: nothing that changes the trials or starts rig work while a fit or a run is going;
        the sensor stays fixed while the rig runs (the run reads its channel)."""
        busy = facts.fitting or facts.rig_running
        has = facts.trials > 0
        return Controls(
            fit=has and not busy, add_trials=not busy, remove_trials=has and not busy, clear_trials=has and not busy,
            save=facts.fitted and not busy, sensor=not facts.rig_running, run=not busy, resume=not busy,
            redo=not busy and facts.session and has, rig_check=not facts.rig_running and not self.checking,
            find_contact=not busy)
