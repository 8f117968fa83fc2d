"""The Trials dock on a real X screen (Xvfb, Qt's xcb platform): a 3-trial series with the operator's prompts, Esc in
trial 2 (kept, marked aborted), the app killed while trial 3 records, and the series resumed in a new app to its end
— read back from the panel's widgets and from the X server's pixels (``trials_probe.py``)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from app.core.run_documents import read_documents
from tests.realdisplay.xserver import ROOT, probe_env, run_probe
from widgets import theme

pytestmark = pytest.mark.realdisplay

PROBE = "tests.realdisplay.trials_probe"
GREEN, AMBER, RED = (theme.STATUS_BACKGROUNDS[level].upper() for level in (theme.OK, theme.WARN, theme.ERROR))


def test_a_trial_series_on_x_prompts_a_stop_a_crash_and_a_resume(x_display, tmp_path):
    folder = tmp_path / "series"
    done = subprocess.run([sys.executable, "-m", PROBE, "crash", str(folder)], cwd=ROOT, env=probe_env(x_display),
                          capture_output=True, text=True, timeout=600)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert done.returncode == -signal.SIGKILL and lines, f"exit {done.returncode}:\n{done.stdout[-2000:]}\n" \
                                                         f"{done.stderr[-3000:]}"
    crash = json.loads(lines[-1])
    first = crash["first_prompt"]
    assert first["prompt"] == "Place the robot, then Start trial 1 of 3"
    assert first["buttons"]["start_trial"] == ["Start trial 1 of 3", True] and not first["buttons"]["outcomes"]
    assert GREEN in first["prompt_colours"]  # the prompt is drawn on the screen, on its green ("do this") ground
    marking = crash["marking"]
    assert marking["prompt"] == "Trial 1 of 3 recorded: mark its outcome" and marking["buttons"]["outcomes"]
    assert AMBER in marking["prompt_colours"]
    stopped = crash["after_stop"]
    assert stopped["prompt"] == "Go to the start pose for trial 3 of 3"
    assert "trial 2 stopped (STOP (button or Esc)): kept, marked aborted" in stopped["detail"]
    assert [row[1] for row in stopped["rows"]] == ["traversed", "aborted", ""]
    assert GREEN in stopped["outcome_colours"][0] and RED in stopped["outcome_colours"][1]
    assert stopped["buttons"]["go_start"] and not stopped["buttons"]["start_trial"][1]
    assert crash["recording"]["prompt"].startswith("Recording trial 3 of 3")
    assert RED in crash["recording"]["prompt_colours"]
    state = json.loads((folder / "series.json").read_text())
    assert [t["state"] for t in state["trials"]] == ["done", "done", "recording"]  # what the kill left

    result = run_probe(x_display, "resume", str(folder), module=PROBE, timeout_s=600)
    assert "trial 3 was cut short while recording" in result["resumed"]["detail"]
    assert result["resumed"]["prompt"] == "Go to the start pose for trial 3 of 3"
    assert result["waiting"]["prompt"] == "Place the robot, then Start trial 3 of 3"
    complete = result["complete"]
    assert complete["prompt"] == "Series complete: 3 of 3 trials finished (1 traversed, 1 failed, 1 aborted)"
    assert [row[1] for row in complete["rows"]] == ["traversed", "aborted", "failed"]
    assert AMBER in complete["outcome_colours"][2] and GREEN in complete["prompt_colours"]
    uids = {read_documents(folder / f"trial-{k:03d}.h5")[0]["series_uid"] for k in range(3)}
    assert len(uids) == 1 and (folder / "trial-002.cut-short.h5").exists()
    assert [read_documents(folder / f"trial-{k:03d}.h5")[1]["outcome"] for k in range(3)] == \
        ["traversed", "aborted", "failed"]
    assert Path(folder / "trials.csv").read_text().count("\n") == 4
