"""``sensnake calibrate`` on the simulated lab: the rig, the board and the fit, unattended, at 60× real time.

The simulated sensor under the probe has documented parameters (``[lab] sensor_*`` of the lab config, times its
seeded spread, read back with ``SimLab.rig_sensor_truth``); a calibration on the rig must recover them. The board
runs at 12 Hz here (the protocol samples at 6 Hz) so that its frames keep up at 60× on a busy test machine.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from app.cli.main import main
from app.core import calibration_fit
from app.core.rig_protocol import ProtocolSettings, check_protocol, finished_trials, read_session
from devices.config import BoardConfig, RigConfig, load_config
from devices.sim.lab import SimLab

REPO = Path(__file__).resolve().parents[2]
# The scripted simulated lab (the app's default is the physics lab; tests pin the scripted one, tests/conftest.py).
LAB_TOML = "[board]\nrate_hz = 12.0\n[lab]\nphysics = \"scripted\"\n"
# The runs whose fit is checked use a sensor that creeps 5× faster than the lab's (τ 20 s instead of 100 s): holds
# and rests of 5 τ take a fifth of the time, so they can run at 60× (at 150× a run now and then lost enough board
# frames on a 2-core machine to leave a trial a "poor fit" or a drift unresolved: said and refused, as it should be,
# but a failed test). The fitter's accuracy on the paper protocol's own timescale is tests/models' to check.
FAST_SENSOR_TOML = LAB_TOML + "sensor_tau_s = 20.0\n"
FAST_HOLD = ["--hold", "100", "--rest", "100"]


@pytest.fixture
def lab_config(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text(LAB_TOML, encoding="utf-8")
    return path


@pytest.fixture
def fast_sensor_config(tmp_path):
    path = tmp_path / "fast_sensor_lab.toml"
    path.write_text(FAST_SENSOR_TOML, encoding="utf-8")
    return path


def test_a_short_protocol_recovers_the_simulated_sensor(tmp_path, fast_sensor_config, capsys):
    lab_config = fast_sensor_config
    out = tmp_path / "cal.json"
    code = main(["calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim",
                 "--forces", "1.75,3,4,5.25", "--trials", "1", *FAST_HOLD, "--time-scale", "60", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    truth = SimLab(load_config(lab_config), seed=0).rig_sensor_truth()
    entry = json.loads(out.read_text())["sensors"]["S06B"]
    for key in ("E0_Pa", "E1_Pa"):
        assert entry["sls"][key] == pytest.approx(truth[key], rel=0.05), (key, entry["sls"], truth)
    # μ1 (and τ) within 7 %: the 3 s loading ramp is 15 % of this sensor's τ, so the creep started during it is
    # resolved less finely than the lab sensor's (measured: μ1 1–3 % low, trials scattering ±6 %).
    assert entry["sls"]["mu1_Pa_s"] == pytest.approx(truth["mu1_Pa_s"], rel=0.07), (entry["sls"], truth)
    tau = entry["sls"]["mu1_Pa_s"] / entry["sls"]["E1_Pa"]
    assert tau == pytest.approx(truth["tau_s"], rel=0.07)
    assert entry["degenerate"] is False and entry["refusal_reasons"] == []
    # The SLS describes the simulated sensor: no trial is a "poor fit"; what misfit remains is the rig's reference
    # moving by encoder ticks (7.5 mN each), not the model.
    assert not [w for t in entry["trials"] for w in t["warnings"] if w.startswith("poor fit")], entry["trials"]
    assert all(0 < t["misfit_force_N"] < 0.005 * t["force_N"] + 0.015 for t in entry["trials"]), entry["trials"]
    # What the rig saw: the window means rise with force, the unloaded level is a small fraction of them.
    means = [t["mean_conductance_S"] for t in entry["trials"]]
    forces = [t["force_N"] for t in entry["trials"]]
    assert forces == sorted(forces) and np.all(np.diff(means) > 0), means
    assert 0 <= entry["unloaded_conductance_S"] < 0.05 * min(means)
    assert all(t["unloaded_conductance_S"] is not None for t in entry["trials"])
    # The trials are SPEC §3.1 CSVs in the session folder beside CAL.json, and the progress line said how long.
    sessions = [p for p in tmp_path.iterdir() if p.is_dir() and p.name.startswith("S06B_")]
    assert len(sessions) == 1 and len(finished_trials(sessions[0], read_session(sessions[0]))) == 4
    assert "left" in captured.err and "wrote S06B" in captured.out


def test_a_rig_thread_held_up_on_the_ramp_redoes_the_trial_and_held_up_elsewhere_costs_nothing(
        tmp_path, fast_sensor_config, capsys, monkeypatch):
    """A busy machine holds the rig's thread up now and then. Once on trial 1's ramp here, for 40 ms before a read
    (2.4 s of the lab at 60×: longer than the ramp): the servo kept ramping on its own (it paces the ramp), but the
    record missed the whole loading edge, so the trial is not kept and runs again, saying so. In the holds, every
    6th read waits 40 ms before or after it (the force stands still there, so when it was read does not matter):
    every kept trial fits and the moduli come back. Before, such stalls stalled the ramp with the thread and timed a
    read by the middle of the stall: a trial came out a 'poor fit' (seen in a CI run) or E0 and E1 5-12 % off."""
    from devices import rig as rig_module

    read = rig_module.CalibrationRig.applied_force_n
    held = {"ramp": 0, "hold": 0, "reads": 0}
    handed: list[float] = []  # the forces the runner was handed, newest last

    def held_up(self):
        # Where the runner is, judged by what it was handed: a hold is three reads above 1 N within 20 mN (the runner
        # has recorded it). The servo's own state would not do: it settles a moment before the record's first hold
        # read, and a stall on that read leaves the ramp's last stretch unrecorded, which must (and did) redo the trial.
        held["reads"] += 1
        last = handed[-3:]
        rising = len(last) >= 2 and last[-1] - last[-2] > 0.02
        holding = len(last) == 3 and min(last) > 1.0 and max(last) - min(last) < 0.02
        if held["ramp"] == 0 and rising and 0.2 < last[-1] < 1.2:
            held["ramp"] += 1
            # Deliberate: the rig's thread held up on trial 1's ramp (a busy machine); the servo goes on ramping.
            time.sleep(0.04)
        elif holding and held["reads"] % 6 == 0:
            held["hold"] += 1
            # Deliberate: the rig's thread held up in a hold, before its read.
            time.sleep(0.04)
        force = read(self)
        if holding and held["reads"] % 6 == 3:
            held["hold"] += 1
            # Deliberate: the rig's thread held up in a hold, between its read and the clock that times it.
            time.sleep(0.04)
        handed.append(force)
        return force

    monkeypatch.setattr(rig_module.CalibrationRig, "applied_force_n", held_up)
    out = tmp_path / "cal.json"
    code = main(["calibrate", "--config", str(fast_sensor_config), "--rig", "sim", "--daq", "sim",
                 "--forces", "1.75,3,4,5.25", "--trials", "1", *FAST_HOLD, "--time-scale", "60", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert held["ramp"] == 1 and held["hold"] > 20, held
    said = captured.out + captured.err
    assert "trial 1/4: 1.75 N, repeat 1: the rig's force was not read for" in said, said[-2000:]
    assert "over the loading edge" in said and "runs again after its rest" in said
    entry = json.loads(out.read_text())["sensors"]["S06B"]
    assert len(entry["trials"]) == 4
    assert not [w for t in entry["trials"] for w in t["warnings"] if w.startswith("poor fit")], entry["trials"]
    truth = SimLab(load_config(fast_sensor_config), seed=0).rig_sensor_truth()
    for key in ("E0_Pa", "E1_Pa"):
        assert entry["sls"][key] == pytest.approx(truth[key], rel=0.05), (key, entry["sls"], truth)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_kill_9_during_trial_3_then_resume_keeps_trials_1_2_and_redoes_3(tmp_path, fast_sensor_config):
    lab_config = fast_sensor_config
    out = tmp_path / "cal.json"
    command = [sys.executable, "-m", "app", "calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim",
               "--forces", "1.75,3,5.25", "--trials", "1", *FAST_HOLD, "--time-scale", "60", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    process = subprocess.Popen(command, cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                               text=True)
    seen = []
    try:
        assert process.stderr is not None
        for line in process.stderr:  # non-terminal stderr: a line at every phase change
            seen.append(line)
            if line.startswith("trial 3/3") and ": hold" in line:
                break
        else:
            pytest.fail("the run ended before trial 3's hold:\n" + "".join(seen))
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait(timeout=60)
        process.stderr.close()
    assert process.returncode == -signal.SIGKILL
    session = next(p for p in tmp_path.iterdir() if p.is_dir() and p.name.startswith("S06B_"))
    settings = read_session(session)
    kept = finished_trials(session, settings)
    assert sorted(kept) == [0, 1], sorted(kept)  # trial 3 was in progress: not on disk
    before = {i: _digest(p) for i, p in kept.items()}
    assert not out.exists()

    resumed = subprocess.run([sys.executable, "-m", "app", "calibrate", "--config", str(lab_config), "--rig", "sim",
                              "--daq", "sim", "--time-scale", "60", "--resume", str(session), "--out", str(out)],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "2 of 3 trial(s) kept" in resumed.stderr
    done = finished_trials(session, settings)
    assert sorted(done) == [0, 1, 2]
    assert {i: _digest(done[i]) for i in (0, 1)} == before  # trials 1-2 untouched
    entry = json.loads(out.read_text())["sensors"]["S06B"]
    assert [t["file"] for t in entry["trials"]] == [done[i].name for i in (0, 1, 2)]


def test_resume_takes_the_protocol_from_the_session(tmp_path, lab_config, capsys):
    folder = tmp_path / "S06B_x"
    folder.mkdir()
    (folder / "protocol.json").write_text(json.dumps({"format": "sensnake-calibration-protocol", "version": 1,
                                                      **ProtocolSettings().__dict__}), encoding="utf-8")
    code = main(["calibrate", "--rig", "sim", "--daq", "sim", "--resume", str(folder), "--hold", "10",
                 "--out", str(tmp_path / "c.json")])
    err = capsys.readouterr().err
    assert code == 1 and "--resume continues the session's own protocol: drop --hold" in err
    code = main(["calibrate", "--rig", "sim", "--daq", "sim", "--resume", str(tmp_path),
                 "--out", str(tmp_path / "c.json")])
    assert code == 1 and "is not a calibration session folder" in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["--hold", "1.7", "--ramp", "1", "--rate", "6"], "leaves 4 samples at full force; the fit needs at least 10"),
    (["--forces", "1.75,9"], "above the rig's maximum force 8 N"),
    (["--sensor", "S99Z"], "sensor S99Z is not a channel of the board"),
    (["--time-scale", "60", "--rig", "/dev/ttyUSB7"], "--time-scale only runs the simulated lab faster"),
    (["--condition", "3@9"], "conditioning at 9 N is above the rig's maximum force 8 N"),
    (["--condition", "three"], "--condition 'three': the number of cycles must be a whole number"),
    (["--condition", "3@x"], "'x' is not a force in N"),
    (["--condition", "-1"], "must be 0 (off) or more"),
    (["--sensors", "S02B,S99Z"], "--sensors: 'S99Z' is not a channel of the board"),
    (["--sensors", "S02B", "--sensor", "S03B"], "--sensor names one sensor, --sensors several"),
    (["--sensors", "S*B", "--forces", "1.75,9"], "protocol refused: 9 N is above the rig's maximum force 8 N"),
])
def test_protocol_refused_before_anything_moves(tmp_path, capsys, argv, message):
    base = ["calibrate", "--rig", "sim", "--daq", "sim", "--out", str(tmp_path / "c.json")]
    code = main(base + argv)
    err = capsys.readouterr().err
    assert code == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []  # no session folder, no file


def test_protocol_check_names_the_spring_travel_and_the_readout_range():
    settings = ProtocolSettings(forces_n=(1.75, 20.0), hold_s=30.0)
    check = check_protocol(settings, RigConfig(max_force_n=50.0), BoardConfig())
    assert any("spring's travel" in e for e in check.errors), check
    typical = check_protocol(ProtocolSettings(), RigConfig(), BoardConfig())
    assert typical.ok and any("readout's ceiling" in w for w in typical.warnings)


def _fake_cal(degenerate=(), e0=2e6):
    sls = SimpleNamespace(E0_Pa=e0, E1_Pa=4e6, mu1_Pa_s=4e8)
    return SimpleNamespace(degenerate=bool(degenerate), degenerate_reasons=tuple(degenerate), sls=sls)


def test_refusal_reasons_name_what_makes_a_fit_unusable():
    forces = [1.75, 3.0, 4.0, 5.25]
    rising = [3e-4, 3.6e-4, 4.2e-4, 4.9e-4]
    assert calibration_fit.refusal_reasons(_fake_cal(), forces, rising, 1e-7) == []
    reasons = calibration_fit.refusal_reasons(_fake_cal(("τ → 0",)), forces, rising, 1e-7)
    assert reasons == ["degenerate SLS fit: τ → 0"]
    assert "non-physical" in calibration_fit.refusal_reasons(_fake_cal(e0=-1.0), forces, rising, 1e-7)[0]
    falling = [3.2e-4, 2.9e-4, 3.5e-4, 3.6e-4]  # a reported run: the 1.75 N plateau below the 0 N baseline
    texts = calibration_fit.refusal_reasons(_fake_cal(), forces, falling, 3.1e-4)
    assert any("does not rise with force" in t for t in texts) and any("unloaded level" in t for t in texts)


def test_ctrl_c_keeps_the_finished_trials_and_says_how_to_continue(tmp_path, lab_config):
    out = tmp_path / "cal.json"
    command = [sys.executable, "-m", "app", "calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim",
               "--forces", "1.75,3", "--trials", "1", "--hold", "60", "--rest", "60", "--time-scale", "60",
               "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    process = subprocess.Popen(command, cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                               text=True)
    lines = []
    assert process.stderr is not None
    for line in process.stderr:
        lines.append(line)
        if line.startswith("trial 2/2") and ": hold" in line:
            process.send_signal(signal.SIGINT)
            break
    rest = process.communicate(timeout=120)[1]
    err = "".join(lines) + rest
    assert process.returncode == 130, err
    assert "interrupted (Ctrl-C)" in err and "load released" in err and "1 finished trial(s) are kept" in err
    assert "continue with: sensnake calibrate --resume" in err
    session = next(p for p in tmp_path.iterdir() if p.is_dir() and p.name.startswith("S06B_"))
    assert sorted(finished_trials(session, read_session(session))) == [0]
    assert not out.exists()


def test_ctrl_c_while_the_rig_is_still_releasing_waits_for_its_outcome(tmp_path):
    """Ctrl-C lands in the main thread while the rig thread runs and the load takes a while to come off (a busy
    machine). Before: on Python 3.11 the KeyboardInterrupt inside ``Thread.join(0.2)`` marked the rig thread as
    ended, the outcome was not waited for and the run ended "without an outcome" (exit 1, not 130)."""
    from app.cli.calibrate import run_until_done
    from app.core.rig_protocol import ABORTED, Outcome

    stopped = threading.Event()
    reasons: list[str] = []

    def abort(reason: str) -> None:
        reasons.append(reason)
        stopped.set()

    def work() -> Outcome:
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)  # the user's Ctrl-C, to the main thread
        assert stopped.wait(30), "Ctrl-C did not abort the run"
        # Deliberate: the rig releasing the load on a slow machine, the main thread waiting for it.
        time.sleep(1.0)
        return Outcome(ABORTED, reasons[0], tmp_path)

    before = signal.getsignal(signal.SIGINT)
    outcome, why = run_until_done(work, abort, "test-rig")
    assert why == "Ctrl-C" and reasons == ["interrupted (Ctrl-C)"]
    assert outcome is not None and outcome.status == ABORTED and outcome.message == "interrupted (Ctrl-C)"
    assert signal.getsignal(signal.SIGINT) is before  # the handlers are put back


def test_a_rejected_trial_is_kept_aside_and_the_session_is_unfinished_again(tmp_path):
    from app.core import calfiles
    from app.core.rig_protocol import reject_trial, trial_file_name, unfinished_sessions, write_session

    settings = ProtocolSettings(forces_n=(1.75, 3.0), trials_per_force=1)
    folder = tmp_path / "S06B_x"
    folder.mkdir()
    write_session(folder, settings)
    paths = []
    for index, (force, repeat) in enumerate(settings.plan):
        path = folder / trial_file_name(settings.sensor, index, force, repeat)
        calfiles.write_trial_csv(path, np.arange(3.0), np.full(3, force), np.full(3, 1e-4))
        paths.append(path)
    assert unfinished_sessions(tmp_path) == []
    moved = reject_trial(paths[1])
    assert moved == folder / "rejected" / paths[1].name and moved.is_file() and not paths[1].exists()
    assert [(f, done) for f, _s, done in unfinished_sessions(tmp_path)] == [(folder, 1)]
    with pytest.raises(ValueError, match="another protocol"):
        write_session(folder, ProtocolSettings(forces_n=(2.0,)))


def test_conditioning_runs_before_the_trials_is_logged_and_not_repeated_on_resume(tmp_path, lab_config, capsys):
    from app.core.rig_protocol import reject_trial

    out = tmp_path / "cal.json"
    code = main(["calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim", "--forces", "1.75,5.25",
                 "--trials", "1", "--hold", "120", "--rest", "60", "--condition", "2@4", "--time-scale", "60",
                 "--save-anyway", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "2 conditioning cycle(s) at 4 N, then 2 trial(s) of S06B" in err
    assert "conditioning cycle 1/2 at 4 N" in err and "conditioning cycle 2/2 at 4 N" in err
    assert err.index("conditioning cycle 2/2") < err.index("trial 1/2")
    session = next(p for p in tmp_path.iterdir() if p.is_dir() and p.name.startswith("S06B_"))
    settings = read_session(session)
    assert settings.condition_cycles == 2 and settings.condition_force_n == 4.0  # in protocol.json
    assert sorted(p.name for p in session.glob("*.csv")) == [p.name for p in finished_trials(session, settings).values()]
    log_bytes = (session / "conditioning.json").read_bytes()
    log = json.loads(log_bytes)
    assert log["finished"] is True and [c["cycle"] for c in log["cycle_log"]] == [1, 2]
    assert all(abs(c["force_N"] - 4.0) < 0.25 for c in log["cycle_log"])
    assert len(json.loads(out.read_text())["sensors"]["S06B"]["trials"]) == 2  # conditioning is not a trial

    reject_trial(finished_trials(session, settings)[1])
    code = main(["calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim", "--time-scale", "60",
                 "--resume", str(session), "--save-anyway", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "conditioning finished earlier (2 cycle(s) at 4 N): not repeated" in err
    assert "conditioning cycle" not in err
    assert (session / "conditioning.json").read_bytes() == log_bytes
    code = main(["calibrate", "--rig", "sim", "--daq", "sim", "--resume", str(session), "--condition", "2",
                 "--out", str(out)])
    assert code == 1 and "drop --condition" in capsys.readouterr().err


def test_the_time_left_counts_the_whole_remaining_protocol_and_never_jumps_back(tmp_path, lab_config, monkeypatch,
                                                                                   capsys):
    """Every progress report's time left (protocol seconds), from the contact search to the end: it starts at the
    whole protocol (conditioning included) and only goes down — no jump back up at a release or a rest."""
    from app.core import rig_protocol

    seen: list[rig_protocol.Progress] = []
    real = rig_protocol.Progress

    def record(*args, **kwargs):
        progress = real(*args, **kwargs)
        seen.append(progress)
        return progress

    monkeypatch.setattr(rig_protocol, "Progress", record)
    code = main(["calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim", "--forces", "2,4",
                 "--trials", "1", "--hold", "60", "--rest", "30", "--condition", "1@3", "--time-scale", "60",
                 "--save-anyway", "--out", str(tmp_path / "cal.json")])
    assert code == 0, capsys.readouterr().err
    settings = ProtocolSettings(forces_n=(2.0, 4.0), trials_per_force=1, hold_s=60.0, rest_s=30.0,
                                condition_cycles=1, condition_force_n=3.0)
    left = np.array([p.time_left_s for p in seen])
    phases = [p.phase for p in seen]
    assert phases[0] == "contact" and left[0] == pytest.approx(settings.total_duration_s(), rel=1e-6)
    rises = np.flatnonzero(np.diff(left) > 1.0)  # protocol seconds; reports are ≤ 1 s of protocol time apart
    assert rises.size == 0, [(phases[k], left[k], phases[k + 1], left[k + 1]) for k in rises]
    assert "release" in phases and phases[-1] == "done" and left[-1] == 0.0


def test_the_preflight_predicts_the_reading_from_the_sensor_itself_when_it_can():
    """The top force's reading: from the sensor's last calibration, else from a trial of this session, else a typical
    sensor (a warning that says so). The simulated sensor (E0 2 MPa, E1 4 MPa) reads far below the ceiling at 5.25 N,
    where the typical sensor would be near it."""
    from models.physics import PhysicsConstants
    from models.sls_model import SLSParams

    settings = ProtocolSettings()  # the paper's 1.75 … 5.25 N
    typical = check_protocol(settings, RigConfig(), BoardConfig())
    assert any("a typical sensor (no calibration or trial" in w for w in typical.warnings)
    own = check_protocol(settings, RigConfig(), BoardConfig(),
                         expected_sls=(SLSParams(E0_Pa=2e6, E1_Pa=4e6, mu1_Pa_s=4e8), 1.4e-3, PhysicsConstants()))
    assert own.ok and not any("readout's ceiling" in w for w in own.warnings), own
    # A trial of the session at 3 N read 400 µS: 700 µS at 5.25 N, well inside the 1111 µS ceiling.
    quiet = check_protocol(settings, RigConfig(), BoardConfig(), seen=(3.0, 400e-6))
    assert quiet.ok and not any("readout's ceiling" in w for w in quiet.warnings)
    # One that read 650 µS at 3 N would reach ~1140 µS: warned, naming where the number comes from.
    loud = check_protocol(settings, RigConfig(), BoardConfig(), seen=(3.0, 650e-6))
    assert any("scaling this session's trial at 3 N (650 µS)" in w for w in loud.warnings), loud


def test_simulated_truth_writes_every_sensor_of_the_apps_lab_and_never_over_a_file(tmp_path, capsys):
    """`calibrate --simulated-truth` gives the calibration the app's simulated lab (seed 0, physics lab) computes its
    sensors from — the way to drive force feedback on the simulated lab without 36 rig runs — and says what it is."""
    out = tmp_path / "truth.json"
    assert main(["calibrate", "--simulated-truth", "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    assert len(document["sensors"]) == 36 and "not a measurement" in document["source"]
    assert "not a measurement" in capsys.readouterr().out
    lab = SimLab()  # the app's lab: the physics lab by default, seed 0
    try:
        truth = lab.board.ground_truth_calibration()
    finally:
        lab.close()
    assert document["sensors"] == truth["sensors"] and document["physics"] == truth["physics"]
    before = out.read_bytes()
    assert main(["calibrate", "--simulated-truth", "--out", str(out)]) != 0
    assert out.read_bytes() == before
    assert "already exists" in capsys.readouterr().err


def test_sensors_are_expanded_in_the_order_given_patterns_in_the_boards_order():
    from app.cli.calibrate import expand_sensors
    from devices.config import default_sensor_names

    channels = tuple(default_sensor_names())
    assert expand_sensors("S*B", channels) == tuple(f"S{k:02d}B" for k in range(1, 13))
    assert expand_sensors("S03B, S02B,S03B", channels) == ("S03B", "S02B")
    assert expand_sensors("S01?,S12B", channels) == ("S01L", "S01R", "S01B", "S12B")
    with pytest.raises(ValueError, match="name at least one sensor"):
        expand_sensors(" , ", channels)


def test_several_sensors_in_one_run_the_simulated_probe_moving_to_each(tmp_path, fast_sensor_config, capsys):
    """``--sensors``: each sensor in turn on the rig — the simulated lab's probe moves onto it (before, a sensor other
    than the config's rig.sensor lay under the robot's weight and its fit was refused) — each saved into CAL.json as
    its fit is done, the batch's folder saying which were."""
    lab_config = fast_sensor_config
    out = tmp_path / "cal.json"
    code = main(["calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim", "--sensors", "S02B,S03B",
                 "--forces", "1.75,5.25", "--trials", "1", *FAST_HOLD, "--time-scale", "60", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "the probe moves onto S02B" in captured.err and "the probe moves onto S03B" in captured.err
    assert "S03B (2/2) trial 1/2" in captured.err and "wrote 2 of 2 sensor(s)" in captured.out
    sensors = json.loads(out.read_text())["sensors"]
    assert sorted(sensors) == ["S02B", "S03B"]
    lab = SimLab(load_config(lab_config), seed=0)
    for name in ("S02B", "S03B"):
        entry = sensors[name]
        assert entry["degenerate"] is False and entry["refusal_reasons"] == [], (name, entry["refusal_reasons"])
        lab.move_rig_to(name)
        truth = lab.rig_sensor_truth()
        # The probe presses the sensor's own area; the fit, given the rig's documented area, carries the ratio in its
        # moduli (as the robot's weight meets the same area: forces come out right either way).
        scale = truth["area_m2"] / entry["area_m2"]
        for key, rel in (("E0_Pa", 0.03), ("E1_Pa", 0.03), ("mu1_Pa_s", 0.07)):  # μ1: see the first test
            assert entry["sls"][key] == pytest.approx(truth[key] * scale, rel=rel), (name, key)
    batch = next(p for p in tmp_path.iterdir() if p.is_dir() and p.name.startswith("sensors_"))
    document = json.loads((batch / "batch.json").read_text())
    assert document["sensors"] == ["S02B", "S03B"] and document["outcomes"] == {"S02B": "saved", "S03B": "saved"}
    for name in ("S02B", "S03B"):
        assert len(finished_trials(batch / name, read_session(batch / name))) == 2


def test_a_batch_cut_short_resumes_where_it_stopped(tmp_path, fast_sensor_config):
    """Ctrl-C during the second sensor: the first stays saved, the second's finished trials stay; ``--resume`` of the
    batch folder skips the first, finishes the second's session and saves it."""
    lab_config = fast_sensor_config
    out = tmp_path / "cal.json"
    command = [sys.executable, "-m", "app", "calibrate", "--config", str(lab_config), "--rig", "sim", "--daq", "sim",
               "--sensors", "S02B,S03B", "--forces", "1.75,3", "--trials", "1", "--hold", "30", "--rest", "30",
               "--time-scale", "60", "--save-anyway", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    process = subprocess.Popen(command, cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                               text=True)
    lines = []
    assert process.stderr is not None
    for line in process.stderr:
        lines.append(line)
        if line.startswith("S03B (2/2) trial 2/2") and ": hold" in line:
            process.send_signal(signal.SIGINT)
            break
    err = "".join(lines) + process.communicate(timeout=120)[1]
    assert process.returncode == 130, err
    batch = next(p for p in tmp_path.iterdir() if p.is_dir() and p.name.startswith("sensors_"))
    assert f"continue with: sensnake calibrate --resume {batch} --out {out}" in err
    assert json.loads((batch / "batch.json").read_text())["outcomes"] == {"S02B": "saved"}
    assert sorted(json.loads(out.read_text())["sensors"]) == ["S02B"]
    kept = finished_trials(batch / "S03B", read_session(batch / "S03B"))
    assert sorted(kept) == [0]
    first = _digest(kept[0])
    resumed = subprocess.run([sys.executable, "-m", "app", "calibrate", "--config", str(lab_config), "--rig", "sim",
                              "--daq", "sim", "--time-scale", "60", "--save-anyway", "--resume", str(batch),
                              "--out", str(out)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "1 of 2 sensor(s) to do (S03B)" in resumed.stderr and "S02B (1/2)" not in resumed.stderr
    done = finished_trials(batch / "S03B", read_session(batch / "S03B"))
    assert sorted(done) == [0, 1] and _digest(done[0]) == first  # the finished trial untouched
    assert sorted(json.loads(out.read_text())["sensors"]) == ["S02B", "S03B"]
    assert json.loads((batch / "batch.json").read_text())["outcomes"] == {"S02B": "saved", "S03B": "saved"}
