"""The calibration wizard's model without Qt: steps, what each waits for, which controls are on."""

from __future__ import annotations

import subprocess
import sys

import pytest

from app.core.calibration_wizard import STEPS, CalibrationWizard, Facts, Step

CHANNELS = ("S01L", "S01R", "S01B", "S06B")


def facts(**changes: object) -> Facts:
    base: dict[str, object] = {"sensor": "S06B", "channels": CHANNELS}
    base.update(changes)
    return Facts(**base)  # type: ignore[arg-type]


def test_the_model_imports_without_qt() -> None:
    code = ("import sys; import app.core.calibration_wizard; "
            "assert not [m for m in sys.modules if m.startswith(('PySide6', 'pyqtgraph'))], 'Qt was imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_every_step_has_an_entry_and_the_last_says_so() -> None:
    assert list(STEPS) == list(Step)
    wizard = CalibrationWizard()
    for step in Step:
        wizard.go_to(step)
        nav = wizard.nav(facts())
        assert nav.title.startswith(f"Step {int(step) + 1} of {len(Step)} · ")
        assert nav.back == (step != Step.SETUP)
    assert wizard.nav(facts()).hint == ""  # the last step: Next off, no hint asking for more
    assert not wizard.nav(facts()).next


def test_a_walk_through_the_steps_with_what_each_waits_for() -> None:
    wizard = CalibrationWizard()
    assert wizard.next_blocked(facts(sensor="S99Z")).startswith("pick a sensor on the body (S99Z")
    assert wizard.next_blocked(facts(sensor="")).startswith("pick a sensor on the body (none")
    assert wizard.next_blocked(facts()) == ""

    wizard.go_to(Step.RIG_CHECK)
    assert "run the rig check" in wizard.next_blocked(facts())
    assert wizard.check_started("S06B")
    assert not wizard.check_started("S06B")  # one check at a time
    assert wizard.next_blocked(facts()) == "the rig check is running"
    assert not wizard.controls(facts()).rig_check
    wizard.check_finished(passed=False)
    assert "run the rig check" in wizard.next_blocked(facts())
    assert wizard.check_started("S06B")
    wizard.check_finished(passed=True)
    assert wizard.next_blocked(facts()) == ""
    # The verdict belongs to the sensor checked: another sensor needs its own check.
    assert "run the rig check" in wizard.next_blocked(facts(sensor="S01B"))

    wizard.go_to(Step.CONTACT)
    assert wizard.next_blocked(facts()) == "find the contact first"
    wizard.contact_started()
    assert wizard.next_blocked(facts(rig_running=True)) == "finding the contact…"
    wizard.contact_finished(found=False, sensor="S06B")
    assert wizard.next_blocked(facts()) == "find the contact first"
    wizard.contact_started()
    wizard.contact_finished(found=True, sensor="S06B")
    assert wizard.next_blocked(facts()) == ""
    assert wizard.next_blocked(facts(sensor="S01B")) == "find the contact first"

    wizard.go_to(Step.PROTOCOL)
    assert "run the protocol" in wizard.next_blocked(facts())
    assert wizard.next_blocked(facts(rig_running=True, trials=3)) == "the run is going"
    assert wizard.next_blocked(facts(trials=12)) == ""

    wizard.go_to(Step.REVIEW)
    assert wizard.next_blocked(facts(trials=12)) == "fit the trials first"
    assert wizard.next_blocked(facts(trials=12, fitting=True, fitted=True)) == "fitting…"
    nav = wizard.nav(facts(trials=12, fitted=True))
    assert nav.next and nav.hint == ""
    assert wizard.nav(facts(trials=12)).hint == "Next: fit the trials first"


@pytest.mark.parametrize("step", [-5, -1, 6, 99])
def test_going_past_either_end_is_clamped(step: int) -> None:
    wizard = CalibrationWizard()
    wizard.go_to(Step.REVIEW)
    assert wizard.go_to(step) == (Step.SETUP if step < 0 else Step.SAVE)


def test_listeners_hear_each_change_once_and_nothing_else() -> None:
    wizard = CalibrationWizard()
    heard: list[Step] = []
    wizard.subscribe(lambda: heard.append(wizard.step))
    wizard.go_to(Step.SETUP)  # already there: no change
    assert heard == []
    wizard.go_to(Step.RIG_CHECK)
    wizard.check_started("S06B")
    wizard.check_started("S06B")  # refused: no change
    wizard.check_finished(True)
    assert heard == [Step.RIG_CHECK] * 3


def test_controls_while_busy() -> None:
    wizard = CalibrationWizard()
    idle = wizard.controls(facts(trials=3, fitted=True, session=True))
    assert all(vars(idle).values())
    for busy in (facts(trials=3, fitted=True, session=True, fitting=True),
                 facts(trials=3, fitted=True, session=True, rig_running=True)):
        on = wizard.controls(busy)
        assert not (on.fit or on.add_trials or on.remove_trials or on.clear_trials or on.save or on.run
                    or on.resume or on.redo or on.find_contact)
    # A fit does not lock the sensor or the rig check; a rig run does.
    assert wizard.controls(facts(fitting=True)).sensor and wizard.controls(facts(fitting=True)).rig_check
    assert not wizard.controls(facts(rig_running=True)).sensor
    assert not wizard.controls(facts(rig_running=True)).rig_check
    # Nothing to fit, remove or redo without trials; redo needs a session.
    empty = wizard.controls(facts())
    assert not (empty.fit or empty.remove_trials or empty.clear_trials or empty.redo or empty.save)
    assert not wizard.controls(facts(trials=3)).redo
