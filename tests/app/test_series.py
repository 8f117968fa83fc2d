"""Series (Qt-free): what a recording and the live lab offer under one name each, a window of one (decimated, peaks
kept), bounded live rings, and plot layouts saved and reopened, never over a file unless asked."""

from __future__ import annotations

import json
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from app.core import series as sr
from app.core.errors import PlotLayoutError, RecordingFormatError

N_SEG = 12
CHANNELS = [f"S{s + 1:02d}{side}" for s in range(N_SEG) for side in "LRB"]


def write_recording(path, seconds=6.0, config_text=""):
    """A small recording with every group a series can come from: /daq + /forces (+ status) at 30 Hz, /robot at
    50 Hz, /control at 50 Hz, /mocap at 100 Hz (segment centres, joint angles, fit flags, residuals), /sim at 30 Hz
    (points, true forces, support) and /events with two health changes of S06B."""
    rng = np.random.default_rng(5)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "sensnake-recording"
        f.attrs["version"] = 1
        f.attrs["config"] = config_text
        t_daq = np.arange(0, seconds, 1 / 30)
        daq = f.create_group("daq")
        daq.attrs["channels"] = CHANNELS
        daq.create_dataset("time_s", data=t_daq)
        daq.create_dataset("conductance_S", data=1e-4 + 1e-5 * rng.standard_normal((t_daq.size, 36)))
        forces = f.create_group("forces")
        forces.create_dataset("force_N", data=2 + np.sin(t_daq[:, None] + np.arange(36)))
        forces.create_dataset("status", data=np.zeros((t_daq.size, 36), dtype=np.int8))
        t_rob = np.arange(0, seconds, 1 / 50)
        robot = f.create_group("robot")
        robot.create_dataset("time_s", data=t_rob)
        robot.create_dataset("goal_rad", data=0.3 * np.sin(t_rob[:, None] + np.arange(12)))
        robot.create_dataset("present_rad", data=0.29 * np.sin(t_rob[:, None] + np.arange(12)))
        robot.create_dataset("current_mA", data=100 * np.cos(t_rob[:, None] * (1 + np.arange(12))))
        control = f.create_group("control")
        control.create_dataset("time_s", data=t_rob)
        control.create_dataset("correction_rad", data=0.01 * np.sin(3 * t_rob[:, None] + np.arange(12)))
        t_m = np.arange(-0.5, seconds, 1 / 100)
        mocap = f.create_group("mocap")
        mocap.create_dataset("time_s", data=t_m)
        centers = np.stack([np.stack([0.08 * s + 0.1 * np.cos(t_m), 0.1 * np.sin(t_m), 0.03 + 0 * t_m], axis=1)
                            for s in range(12)], axis=1)
        mocap.create_dataset("segment_center_m", data=centers)
        mocap.create_dataset("segment_rotation", data=np.tile(np.eye(3), (t_m.size, 12, 1, 1)))
        mocap.create_dataset("joint_angle_rad", data=0.2 * np.sin(t_m[:, None] + np.arange(12)))
        mocap.create_dataset("fit_flag", data=np.zeros((t_m.size, 12), dtype=np.int8))
        mocap.create_dataset("residual_m", data=np.full((t_m.size, 12), 0.001))
        sim = f.create_group("sim")
        sim.create_dataset("time_s", data=t_daq)
        points = np.zeros((t_daq.size, 13, 3))
        points[:, :, 0] = -0.08 * np.arange(13)[None, :] + 0.01 * t_daq[:, None]
        sim.create_dataset("points_m", data=points)
        sim.create_dataset("sheet_true_N", data=rng.uniform(0, 3, (t_daq.size, 36)))
        sim.create_dataset("support_N", data=np.full(t_daq.size, 23.5))
        events = f.create_group("events")
        events.create_dataset("time_s", data=[1.0, 2.0, 4.0])
        events.create_dataset("kind", data=[b"health", b"gap", b"health"])
        events.create_dataset("text", data=[b"S06B: noisy (loose?), saturated", b"board gap", b"S06B: ok"])
    return path


def test_a_recording_offers_every_series_it_holds_under_the_live_names(tmp_path):
    rec = sr.RecordingSeries(write_recording(tmp_path / "run.h5"))
    keys = {i.key for i in rec.catalog()}
    for key in ("robot/J5/current_mA", "robot/J5/goal_rad", "robot/J5/present_rad", "forces/S06B/force_N",
                "daq/S06B/conductance_uS", "forces/S06B/status", "health/S06B/flags", "control/J3/correction_rad",
                "mocap/seg03/x_m", "mocap/seg03/fit_flag", "mocap/J4/angle_rad", "sim/S06B/true_N",
                "sim/seg02/z_m", "sim/body/support_N"):
        assert key in keys, key
    assert "robot/J5/velocity_rad_s" not in keys  # recordings hold no velocity: not offered
    live = sr.LiveSeries(CHANNELS, range(1, 13), 0.0)
    shared = keys & {i.key for i in live.catalog()}
    assert {"robot/J5/current_mA", "forces/S06B/force_N", "control/J5/correction_rad", "health/S06B/flags"} <= shared
    info = rec.info("robot/J5/current_mA")
    assert info is not None and (info.group, info.item, info.name, info.unit) == ("Joints", "J5", "current", "mA")
    assert info.text == "J5 current (mA)"
    assert rec.span() == pytest.approx((-0.5, 6.0 - 1 / 100), abs=0.02)


def test_a_series_read_is_the_file_column_and_a_window_keeps_every_peak(tmp_path):
    path = write_recording(tmp_path / "run.h5")
    rec = sr.RecordingSeries(path)
    with h5py.File(path) as f:
        t_rob, current = f["robot/time_s"][:], f["robot/current_mA"][:, 4]
        t_daq, force = f["daq/time_s"][:], f["forces/force_N"][:, CHANNELS.index("S06B")]
        centers = f["mocap/segment_center_m"][:, 2, 0]
        points = f["sim/points_m"][:, 1:3, 2].mean(axis=1)
        conductance = f["daq/conductance_S"][:, 17]
    t, v = rec.read("robot/J5/current_mA")
    np.testing.assert_array_equal(t, t_rob)
    np.testing.assert_array_equal(v, current)
    np.testing.assert_array_equal(rec.read("forces/S06B/force_N")[1], force)
    np.testing.assert_array_equal(rec.read("mocap/seg03/x_m")[1], centers)
    np.testing.assert_allclose(rec.read("sim/seg02/z_m")[1], points)
    np.testing.assert_allclose(rec.read("daq/S06B/conductance_uS")[1], conductance * 1e6)
    assert rec.value_at("forces/S06B/force_N", 1.01) == force[np.flatnonzero(t_daq <= 1.01)[-1]]
    # the health events are a step series of the flags
    from models.health import SensorHealth

    _t, flags = rec.read("health/S06B/flags")
    assert rec.value_at("health/S06B/flags", 0.5) == 0
    assert rec.value_at("health/S06B/flags", 3.0) == int(SensorHealth.NOISY | SensorHealth.SATURATED)
    assert rec.value_at("health/S06B/flags", 5.0) == 0
    # a window of 300 points of a long series keeps the single-sample spike
    t_long = np.arange(200_000) * 1e-3
    v_long = np.sin(t_long)
    v_long[123_457] = 50.0
    x, y = sr.decimate(t_long, v_long, 0.0, t_long[-1], 300)
    assert x.size <= 2 * 300 + 2 and y.max() == 50.0 and np.all(np.diff(x) >= 0)
    x, y = sr.decimate(t_long, v_long, 10.0, 10.5, 300)  # a zoomed window: every sample, one either side
    assert x[0] < 10.0 < 10.5 < x[-1] and x.size == 503
    rec.keep_only(["forces/S06B/force_N"])
    assert set(rec._cache) == {"forces/S06B/force_N"}


def test_a_recording_that_is_not_one_is_refused_naming_it(tmp_path):
    bad = tmp_path / "other.h5"
    with h5py.File(bad, "w") as f:
        f.attrs["format"] = "someone-else"
    with pytest.raises(RecordingFormatError, match="other.h5"):
        sr.RecordingSeries(bad)
    (tmp_path / "text.h5").write_text("not hdf5")
    with pytest.raises(RecordingFormatError, match="text.h5"):
        sr.RecordingSeries(tmp_path / "text.h5")


def test_joint_names_follow_the_recorded_config(tmp_path):
    config = "[robot]\njoint_ids = [21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32]\n"
    rec = sr.RecordingSeries(write_recording(tmp_path / "ids.h5", config_text=config))
    keys = {i.key for i in rec.catalog()}
    assert "robot/J25/current_mA" in keys and "robot/J5/current_mA" not in keys


def _state(t, j5_current, correction=None):
    n = 12
    current = np.zeros(n)
    current[4] = j5_current
    return SimpleNamespace(host_time_s=t, position_rad=np.full(n, 0.1), velocity_rad_s=np.zeros(n),
                           current_ma=current, goal_rad=np.full(n, 0.2),
                           correction_rad=None if correction is None else np.full(n, correction))



class _Block(SimpleNamespace):
    def __len__(self):
        return len(self.host_time_s)


def test_live_rings_hold_a_fixed_size_and_answer_a_window():
    live = sr.LiveSeries(CHANNELS, range(1, 13), t0_monotonic_s=100.0, robot_rate_hz=50.0, board_rate_hz=30.0,
                         history_s=2.0)
    assert live.nbytes == 0  # nothing allocated before the first sample
    for k in range(400):  # 8 s of states at 50 Hz into a ring made for about 2.5 s
        live.add_states([_state(100.0 + k / 50, j5_current=k, correction=0.01 if k >= 200 else None)])
    capacity = live.capacity(sr.ROBOT)
    held = live.nbytes
    t, v = live.read("robot/J5/current_mA")
    assert t.size == capacity < 400 and v[-1] == 399 and t[-1] == pytest.approx(399 / 50)
    for k in range(400, 800):
        live.add_states([_state(100.0 + k / 50, j5_current=k)])
    assert live.nbytes == held  # memory fixed
    x, y = live.window("robot/J5/current_mA", 15.0, 15.5, 500)
    assert x[0] <= 15.0 and x[-1] >= 15.5 and set(np.round(y[1:-1])) <= set(range(750, 776))
    assert np.isnan(live.value_at("control/J5/correction_rad", 15.0))  # no correction in those states
    assert live.value_at("robot/J5/goal_rad", 15.0) == pytest.approx(0.2)
    # board blocks: conductance in µS, a NaN row before a gap; a backfill skips what is held
    live.add_block(_Block(host_time_s=100.0 + np.arange(3) / 30, conductance_s=np.full((3, 36), 2e-4),
                          gap_before=None))
    live.add_block(_Block(host_time_s=101.0 + np.arange(3) / 30, conductance_s=np.full((3, 36), 3e-4),
                          gap_before=np.array([True, False, False])))
    t, v = live.read("daq/S06B/conductance_uS")
    assert t.size == 7 and np.isnan(v[3]) and v[0] == pytest.approx(200.0) and v[-1] == pytest.approx(300.0)
    live.add_block(_Block(host_time_s=101.0 + np.arange(5) / 30, conductance_s=np.full((5, 36), 4e-4),
                          gap_before=None), after_s=live.newest_s(["daq/S06B/conductance_uS"]))
    t, v = live.read("daq/S06B/conductance_uS")
    assert t.size == 9 and np.all(np.diff(t) >= 0) and t[-1] == pytest.approx(1 + 4 / 30)  # the two new ones
    # forces, status and health flags (kept on change)
    forces = np.full((2, 36), np.nan)
    forces[:, 17] = [1.5, 1.6]
    live.add_forces(np.array([102.0, 102.1]), forces, np.zeros((2, 36), dtype=np.int8))
    assert live.value_at("forces/S06B/force_N", 2.2) == pytest.approx(1.6)
    assert np.isnan(live.value_at("forces/S01L/force_N", 2.2))
    version = live.version
    live.add_health(102.1, np.zeros(36, dtype=np.uint8))
    live.add_health(102.2, np.zeros(36, dtype=np.uint8))  # unchanged and soon after: not kept
    assert live.version == version + 1
    flags = np.zeros(36, dtype=np.uint8)
    flags[17] = 2
    live.add_health(102.3, flags)
    assert live.value_at("health/S06B/flags", 2.35) == 2
    live.add_servo_health(102.4, [SimpleNamespace(servo_id=5, hardware_error=32, temperature_c=41.0,
                                                  voltage_v=12.1)])
    assert live.value_at("servo/J5/hardware_error", 2.5) == 32
    assert live.value_at("servo/J5/temperature_C", 2.5) == 41.0
    assert np.isnan(live.value_at("servo/J6/voltage_V", 2.5))


def test_a_wide_fast_board_is_held_within_the_budget():
    names = [f"C{i:04d}" for i in range(1024)]
    live = sr.LiveSeries(names, range(1, 13), 0.0, board_rate_hz=100.0)
    rows = live.capacity(sr.BOARD)
    assert rows * (8 + 4 * 1024) <= sr.TABLE_BUDGET_BYTES and rows >= 100 * 30  # still half a minute or more


def test_layouts_are_edited_saved_and_reopened_and_never_written_over_unasked(tmp_path):
    layout = sr.PlotLayout()
    layout = layout.adding("robot/J5/current_mA")
    layout = layout.adding("forces/S06B/force_N")
    layout = layout.adding("robot/J5/present_rad", plot=0)
    layout = layout.adding("robot/J5/present_rad", plot=0)  # already there: unchanged
    layout = layout.adding_plot(sr.XY).adding("mocap/seg03/x_m", 2).adding("mocap/seg03/y_m", 2)
    assert [p.series for p in layout.plots] == [("robot/J5/current_mA", "robot/J5/present_rad"),
                                                ("forces/S06B/force_N",), ("mocap/seg03/x_m", "mocap/seg03/y_m")]
    assert layout.plots[2].kind == sr.XY
    assert layout.removing(0, "robot/J5/current_mA").plots[0].series == ("robot/J5/present_rad",)
    assert len(layout.removing(1).plots) == 2
    beside = sr.layout_beside(tmp_path / "run.h5")
    assert beside.name == "run.plots.json"
    written = sr.write_layout(layout, beside)
    assert sr.read_layout(written) == layout
    document = json.loads(written.read_text())
    assert document["format"] == "sensnake-plot-layout" and document["version"] == 1
    other = sr.PlotLayout().adding("robot/J1/goal_rad")
    with pytest.raises(FileExistsError, match="only when you choose"):
        sr.write_layout(other, beside)
    assert sr.read_layout(beside) == layout  # untouched
    assert sr.free_path(beside).name == "run-2.plots.json"
    sr.write_layout(other, beside, replace_existing=True)
    assert sr.read_layout(beside) == other
    (tmp_path / "folder.plots.json").mkdir()
    with pytest.raises(OSError, match="folder"):
        sr.write_layout(other, tmp_path / "folder.plots.json", replace_existing=True)


@pytest.mark.parametrize(("text", "match"), [
    ("not json", "not valid JSON"),
    ('{"format": "other", "version": 1, "plots": []}', "format must be"),
    ('{"format": "sensnake-plot-layout", "version": 9, "plots": []}', "version 9"),
    ('{"format": "sensnake-plot-layout", "version": 1, "plots": [{"kind": "pie"}]}', r"plots\[0\]\.kind"),
    ('{"format": "sensnake-plot-layout", "version": 1, "plots": [{"series": [3]}]}', r"plots\[0\]\.series"),
    ('{"format": "sensnake-plot-layout", "version": 1, "window_s": 0, "plots": []}', "window_s"),
])
def test_a_bad_layout_file_is_refused_naming_the_file_and_the_key(tmp_path, text, match):
    path = tmp_path / "bad.plots.json"
    path.write_text(text)
    with pytest.raises(PlotLayoutError, match=match) as info:
        sr.read_layout(path)
    assert "bad.plots.json" in str(info.value)


def test_resampling_for_an_xy_plot_and_steps_for_flags():
    t = np.array([0.0, 1.0, 2.0])
    assert np.allclose(sr.resample(t, np.array([0.0, 10.0, 20.0]), np.array([0.5, 1.5])), [5.0, 15.0])
    assert np.isnan(sr.resample(t, np.array([0.0, 10.0, 20.0]), np.array([3.0]))[0])
    x, y = sr.as_steps(t, np.array([0.0, 2.0, 0.0]))
    assert list(x) == [0.0, 1.0, 1.0, 2.0, 2.0] and list(y) == [0.0, 0.0, 2.0, 2.0, 0.0]


@pytest.mark.parametrize(("text", "words"), [
    ("[" * 100_000, "nested too deeply"),
    ('{"format": ' + "9" * 5000 + "}", "digits"),
    ('{"format": "x",\n "plots": [}', "mine.json:2: not valid JSON"),
])
def test_a_hostile_layout_file_is_one_line_naming_it(text, words):
    with pytest.raises(PlotLayoutError, match="mine.json") as refused:
        sr.parse_layout(text, "mine.json")
    assert words in str(refused.value) and "\n" not in str(refused.value)
