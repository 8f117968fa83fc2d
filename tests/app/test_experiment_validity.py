"""A physics run checks itself and is judged at rest (app/core/experiment.py, app/cli/experiment.py, app/core/sweep.py).

- What no physics can honour is refused before the run (a tail load beyond friction), in one line with the formula.
- A run that blows up (a NaN injected into the world mid-run, as a solver blowing up leaves one) ends invalid: exit 3
  and one line naming what and when, the recording kept with ``/sim`` ``valid`` = 0 and ``invalid_reason``, a sweep's
  ``summary.csv`` row ``valid`` 0 with its measured columns empty, every statistic counting it apart; MuJoCo's log
  lands in the recording's events, never in a ``MUJOCO_LOG.TXT`` in the working folder.
- The outcome is judged once the body is at rest (synthetic body tracks: moving then resting; still moving at the
  cap: undecided).

Short simulated runs on flat ground (settle 0.5 s, about a second of play).
"""

from __future__ import annotations

import csv
import math

import h5py
import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from app.cli.main import main  # noqa: E402
from app.core.errors import (
    InvalidRecordingError,  # noqa: E402
    SweepError,  # noqa: E402
)
from app.core.experiment import REST_HOLD_S, judge_at_rest, outcome_from_recording  # noqa: E402
from app.core.physics_check import check_recording  # noqa: E402
from app.core.sweep import compare, read_sweep, run_sweep, summary_table  # noqa: E402
from devices.sim.physics import world as world_module  # noqa: E402

BLOW_UP_AT_S = 1.2  # world clock: 0.7 s after a 0.5 s settle's capture
SHORT_RUN = ["--scene", "flat", "--mode", "serpenoid", "--seconds", "1", "--settle", "0.5"]


@pytest.fixture
def blow_up(monkeypatch):
    """Every world made from here on blows up at BLOW_UP_AT_S: a NaN in a shell's velocity (DOF 29)."""
    step = world_module.PhysicsWorld.step

    def blowing_up(self: world_module.PhysicsWorld, n: int = 1) -> None:
        if self.time_s >= BLOW_UP_AT_S and not getattr(self, "_blown", False):
            self._blown = True  # type: ignore[attr-defined]
            self.data.qvel[29] = np.nan
        step(self, n)

    monkeypatch.setattr(world_module.PhysicsWorld, "step", blowing_up)


def test_a_tail_load_no_friction_can_hold_is_refused_before_the_run(tmp_path, capsys):
    out = tmp_path / "r.h5"
    assert main(["experiment", "run", "--scene", "paper_obstacle", "--tail-load", "30", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--tail-load 30 N is more than friction can hold on scene paper_obstacle" in err
    assert "2.4 kg × 9.81 m/s² × μ 0.3" in err and "= 7.06 N" in err
    assert not out.exists()


def test_a_run_that_blows_up_exits_3_with_one_line_and_its_recording_marked_invalid(tmp_path, monkeypatch, capsys,
                                                                                   blow_up):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its MUJOCO_LOG.TXT into the working folder unless told otherwise
    out = tmp_path / "blown.h5"
    assert main(["experiment", "run", *SHORT_RUN, "--out", str(out)]) == 3
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err  # one line: what and when, nothing of MuJoCo's own log
    assert err.startswith("sensnake experiment: invalid run: MuJoCo: bad QVEL (NaN, Inf or huge velocity) at DOF 29")
    assert "at t=0.6" in err and "marked invalid (/sim valid = 0)" in err  # 1.2 s − the capture at 0.512 s
    assert "advanced" not in captured.out  # no figure of a run that is not physics
    with h5py.File(out, "r") as f:
        sim = f["sim"]
        assert int(sim.attrs["valid"]) == 0 and "bad QVEL" in sim.attrs["invalid_reason"]
        assert sim.attrs["outcome"] == "invalid"
        assert sim["time_s"][-1] < BLOW_UP_AT_S - 0.5  # recorded up to the last good tick
        assert np.all(np.isfinite(sim["points_m"][:]))
        events = [t.decode() if isinstance(t, bytes) else str(t) for t in f["events/text"][:]]
    assert any("Nan, Inf or huge value in QVEL at DOF 29" in e for e in events)  # MuJoCo's log, in the file
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    with pytest.raises(InvalidRecordingError, match="marked invalid"):
        check_recording(out)
    assert outcome_from_recording(out)[:2] == (False, sim_reason(out))


def sim_reason(path: object) -> str:
    with h5py.File(path, "r") as f:  # type: ignore[arg-type]
        return str(f["sim"].attrs["invalid_reason"])


def test_a_sweeps_invalid_run_is_a_row_marked_invalid_and_counted_apart(tmp_path, capsys, blow_up):
    plan = tmp_path / "sweep.toml"
    plan.write_text('scenes = ["flat"]\ncontrollers = ["feedforward"]\nseconds = 1.0\nsettle_s = 0.5\n'
                    'mode = "serpenoid"\n', encoding="utf-8")
    rows = run_sweep(read_sweep(plan), tmp_path / "out", jobs=1)  # the worker is forked: it blows up too
    with open(tmp_path / "out" / "summary.csv", newline="", encoding="utf-8") as f:
        written = list(csv.DictReader(f))
    assert written[0]["valid"] == "0" and "bad QVEL" in written[0]["invalid_reason"]
    assert written[0]["outcome"] == "invalid"
    assert written[0]["advance_m"] == written[0]["traversed"] == ""  # nothing it measured is data
    valid = {**rows[0], "run": 1, "valid": 1, "invalid_reason": "", "traversed": 1, "traverse_s": 5.0,
             "advance_m": 0.4, "overloads": 0, "outcome": "traversed"}
    undecided = {**valid, "run": 2, "outcome": "undecided"}
    for controller in ("feedforward", "feedback"):  # the same runs under both, paired, for compare
        rows_both = [{**r, "controller": controller, "gains_index": -1 if controller == "feedforward" else 0}
                     for r in (rows[0], valid, undecided)]
        rows_both[2]["seed"] = 1
        if controller == "feedforward":
            table_rows = rows_both
        else:
            pairs = table_rows + rows_both
    entry = summary_table(table_rows)[0]
    assert (entry["runs"], entry["invalid"], entry["undecided"]) == (2, 1, 1)  # invalid apart, never data
    assert entry["success"] == 1.0 and entry["median_advance_m"] == 0.4
    assert entry["at_rest_success"] == 1.0  # over the one decided run
    assert compare(pairs, 0).invalid_runs == 2 and compare(pairs, 0).pairs == 2


def test_the_sweep_command_prints_invalid_runs_apart_and_exits_3(tmp_path, monkeypatch, capsys):
    plan = tmp_path / "sweep.toml"
    plan.write_text('scenes = ["flat"]\ncontrollers = ["feedforward"]\n', encoding="utf-8")
    rows = [{"run": 0, "scene": "flat", "controller": "feedforward", "gains_index": -1, "tail_load_N": 0.0,
             "seed": 0, "traversed": "", "advance_m": "", "overloads": "", "file": "a.h5", "valid": 0,
             "invalid_reason": "invalid run: MuJoCo: bad QACC at DOF 29 at t=12.34 s", "outcome": "invalid"},
            {"run": 1, "scene": "flat", "controller": "feedforward", "gains_index": -1, "tail_load_N": 0.0,
             "seed": 1, "traversed": 0, "advance_m": 0.2, "overloads": 0, "file": "b.h5", "valid": 1,
             "invalid_reason": "", "outcome": "not traversed"}]
    monkeypatch.setattr("app.cli.experiment.run_sweep", lambda *args, **kwargs: rows)
    assert main(["experiment", "sweep", str(plan), "--out", str(tmp_path / "out")]) == 3
    captured = capsys.readouterr()
    line = next(x for x in captured.out.splitlines() if x.startswith("flat"))
    assert line.split()[3:5] == ["1", "0%"] and line.split()[-1] == "1"  # 1 valid run, 0 % traversed; 1 invalid
    assert "run 0 (flat, feedforward, 0.0 N, seed 0) invalid run: MuJoCo: bad QACC at DOF 29 at t=12.34 s" in \
        captured.err


def test_a_sweep_with_a_tail_load_a_scene_cannot_hold_is_refused_before_any_run(tmp_path):
    plan = tmp_path / "sweep.toml"
    plan.write_text('scenes = ["flat", "paper_obstacle"]\ntail_loads_n = [1.0, 8.0]\nseeds = [0, 1]\n',
                    encoding="utf-8")
    with pytest.raises(SweepError, match=r"'tail_loads_n' 8 N is more than friction can hold on scene flat: 2.4 kg "
                                         r"× 9.81 m/s² × μ 0.3 .* = 7.06 N"):
        read_sweep(plan)
    plan.write_text('scenes = ["paper_obstacle"]\ntail_loads_n = [7.0]\nseeds = [0, 1, 4]\n', encoding="utf-8")
    with pytest.raises(SweepError, match=r"\(seed 4\) 7 N is more than friction can hold .* μ 0.29"):
        read_sweep(plan)  # 7 N is within the written μ 0.3 (7.06 N), not within seed 4's 0.29 (6.83 N)


def _track(x_of_t: np.ndarray, dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """A straight body (13 points 8 cm apart, head first) whose head tip is at ``x_of_t`` at each tick."""
    times = np.arange(len(x_of_t)) * dt
    points = np.zeros((len(x_of_t), 13, 3))
    points[:, :, 0] = x_of_t[:, None] - 0.08 * np.arange(13)[None, :]
    return times, points


def test_the_outcome_is_judged_once_the_body_rests_with_the_margin_past_the_far_edge():
    # moving at 2 cm/s until 10 s (the motion ends at 8 s), then resting 4 s with its tail 5 cm past the edge at 0.5
    moving = 0.35 + 0.02 * np.arange(0, 10.0, 0.02)
    x = np.concatenate([moving, np.full(200, moving[-1])])
    times, points = _track(x)
    far_edge = moving[-1] - 0.96 - 0.05
    judged = judge_at_rest(times, points, motion_end_s=8.0, far_edge_m=far_edge)
    assert judged.outcome == "traversed"
    assert judged.at_rest_s == pytest.approx(10.0 + REST_HOLD_S, abs=0.05)  # 2 s still, after the motion
    assert judged.margin_m == pytest.approx(0.05, abs=1e-9)  # the rearmost point's margin past the edge
    assert judged.advance_m == pytest.approx(moving[-1] - moving[0])
    assert judged.slide_back_m == pytest.approx(0.0)
    # the same body resting short of an edge 10 cm farther on: not traversed, 5 cm short
    short = judge_at_rest(times, points, motion_end_s=8.0, far_edge_m=far_edge + 0.1)
    assert short.outcome == "not traversed" and short.margin_m == pytest.approx(-0.05, abs=1e-9)


def test_a_tail_passing_the_edge_by_millimetres_then_sliding_back_is_no_traversal():
    # the tail passes the edge by 3 mm at 6 s, then the body slides back 4 cm and rests: judged where it rests
    x = np.concatenate([0.5 + 0.01 * np.arange(0, 6.0, 0.02), 0.56 - 0.01 * np.arange(0, 4.0, 0.02),
                        np.full(150, 0.52)])
    times, points = _track(x)
    judged = judge_at_rest(times, points, motion_end_s=6.0, far_edge_m=0.56 - 0.96 - 0.003)
    assert judged.outcome == "not traversed" and judged.margin_m == pytest.approx(-0.037, abs=1e-3)
    assert judged.slide_back_m == pytest.approx(0.04, abs=1e-3)


def test_a_body_still_moving_at_the_cap_is_undecided():
    times, points = _track(0.1 + 0.005 * np.arange(0, 20.0, 0.02))  # creeping at 5 mm/s to the end
    judged = judge_at_rest(times, points, motion_end_s=5.0, far_edge_m=0.0)
    assert judged.outcome == "undecided"
    assert all(math.isnan(v) for v in (judged.at_rest_s, judged.margin_m, judged.advance_m, judged.slide_back_m))
    # resting less than REST_HOLD_S before the recording ends: not yet at rest either
    times, points = _track(np.concatenate([0.1 + 0.01 * np.arange(0, 10.0, 0.02), np.full(90, 0.2)]))
    assert judge_at_rest(times, points, motion_end_s=5.0, far_edge_m=0.0).outcome == "undecided"
