"""models/health.py on synthetic signals: each fault is detected on its sensor and nowhere else."""

from __future__ import annotations

import numpy as np
import pytest

from models.health import HealthMonitor, HealthThresholds, SensorHealth, describe

RATE_HZ = 30.0
N_SENSORS = 36
LSB_S = 3.3 / 4095 / (2.5 * 900.0)  # one ADC step of the default readout, in siemens


def healthy_signals(seconds: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Quantised resting conductance with sensor noise and a slow contact wave on some sensors."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    base = rng.uniform(3.5e-4, 4.5e-4, N_SENSORS)
    wave = 5e-5 * np.clip(np.sin(2 * np.pi * 0.2 * t[:, None] + np.arange(N_SENSORS)), 0, None)
    noisy = base + wave + rng.normal(0, 0.8 * LSB_S, (t.size, N_SENSORS))
    return t, np.round(noisy / LSB_S) * LSB_S


def run(monitor: HealthMonitor, t: np.ndarray, values: np.ndarray, saturated=None, block: int = 4) -> np.ndarray:
    for start in range(0, t.size, block):
        sl = slice(start, start + block)
        monitor.update(t[sl], values[sl], None if saturated is None else saturated[sl])
    return monitor.flags


def test_healthy_sensors_are_all_ok():
    t, values = healthy_signals(8.0)
    flags = run(HealthMonitor(N_SENSORS, RATE_HZ), t, values)
    assert flags.tolist() == [0] * N_SENSORS, [describe(f) for f in flags]


@pytest.mark.parametrize(
    ("fault", "expected"),
    [("flat", SensorHealth.FLAT), ("noisy", SensorHealth.NOISY), ("dropout", SensorHealth.DROPOUT),
     ("disconnected", SensorHealth.DISCONNECTED), ("below", SensorHealth.BELOW_BASELINE)],
)
def test_each_fault_flags_only_its_sensor(fault, expected):
    t, values = healthy_signals(10.0, seed=3)
    bad = 9  # the paper's loose sensor 10 (index 9)
    late = t >= 5.0
    rng = np.random.default_rng(7)
    if fault == "flat":
        values[late, bad] = values[np.argmax(late), bad]
    elif fault == "noisy":
        values[late, bad] += rng.normal(0, 4e-5, late.sum())
    elif fault == "dropout":
        values[late & (rng.random(t.size) < 0.2), bad] = 0.0
    elif fault == "disconnected":
        values[late, bad] = 0.0
    elif fault == "below":
        values[late, bad] *= 0.6
    monitor = HealthMonitor(N_SENSORS, RATE_HZ, HealthThresholds(baseline_s=3.0))
    flags = run(monitor, t, values)
    assert flags[bad] & expected, describe(flags[bad])
    others = np.delete(flags, bad)
    assert not others.any(), [describe(f) for f in others if f]


def test_saturation_flag_follows_the_board_flag_and_clears():
    t, values = healthy_signals(6.0)
    saturated = np.zeros(values.shape, dtype=bool)
    saturated[60:62, 4] = True
    monitor = HealthMonitor(N_SENSORS, RATE_HZ)
    run(monitor, t[:70], values[:70], saturated[:70])
    assert monitor.flags[4] & SensorHealth.SATURATED
    assert not (np.delete(monitor.flags, 4) & SensorHealth.SATURATED).any()
    run(monitor, t[70:], values[70:], saturated[70:])  # > 2 s later the window no longer holds it
    assert not monitor.flags[4] & SensorHealth.SATURATED


def test_report_lists_changed_sensors_once():
    t, values = healthy_signals(10.0)
    values[t >= 5.0, 2] = 0.0
    monitor = HealthMonitor(N_SENSORS, RATE_HZ, HealthThresholds(baseline_s=3.0))
    changes = []
    for start in range(0, t.size, 4):
        report = monitor.update(t[start:start + 4], values[start:start + 4])
        if report is not None:
            changes.extend(int(i) for i in report.changed)
    assert changes == [2]  # flagged once (disconnected), no flapping, nobody else
    assert monitor.flags[2] == SensorHealth.DISCONNECTED


def test_baseline_can_be_set_and_shape_is_checked():
    monitor = HealthMonitor(3, RATE_HZ, HealthThresholds(window_s=1.0))
    with pytest.raises(ValueError, match="shape"):
        monitor.set_baseline(np.ones(4))
    monitor.set_baseline(np.full(3, 4e-4))
    t = np.arange(60) / RATE_HZ
    values = np.full((60, 3), 4e-4) + np.arange(60)[:, None] % 2 * LSB_S
    values[:, 1] = 2e-4
    run(monitor, t, values)
    assert monitor.flags[1] & SensorHealth.BELOW_BASELINE
    assert not monitor.flags[0]


def test_bad_input_shapes_raise():
    monitor = HealthMonitor(4, RATE_HZ)
    with pytest.raises(ValueError, match="N×4"):
        monitor.update(np.zeros(3), np.zeros((3, 5)))
    with pytest.raises(ValueError):
        HealthMonitor(0, RATE_HZ)


def test_describe_words():
    assert describe(0) == "ok"
    assert describe(SensorHealth.NOISY | SensorHealth.SATURATED) == "noisy (loose?), saturated"


def test_unloaded_sensors_reading_open_are_not_flagged_without_a_baseline():
    """An unloaded sensor reads open (≈ 0 S); so does a contact that lifts off. Neither is a fault."""
    t, values = healthy_signals(8.0)
    values[:, :12] = np.round(np.random.default_rng(1).uniform(0, 4e-7, (t.size, 12)) / LSB_S) * LSB_S
    values[t >= 4.0, 20] = 0.0  # a segment lifts off the ground and stays up
    flags = run(HealthMonitor(N_SENSORS, RATE_HZ), t, values)
    assert not flags.any(), [describe(f) for f in flags]


def test_a_released_contact_is_not_a_dropout():
    t, values = healthy_signals(8.0)
    release = t >= 5.0
    values[release, 7] *= np.exp(-(t[release] - 5.0) / 0.1)  # decays over a few samples
    values[values[:, 7] < 1e-6, 7] = 0.0
    flags = run(HealthMonitor(N_SENSORS, RATE_HZ), t, values)
    assert not flags[7] & SensorHealth.DROPOUT


def test_one_open_sample_is_a_grazing_touch_two_in_the_window_a_dropout():
    t, values = healthy_signals(8.0)
    values[t >= 0.0, 7] = np.maximum(values[:, 7], 7e-5)  # sensor 7 clearly loaded throughout
    once = values.copy()
    once[np.searchsorted(t, 6.0), 7] = 0.0  # lets go for one frame
    flags = run(HealthMonitor(N_SENSORS, RATE_HZ), t, once)
    assert not flags[7] & SensorHealth.DROPOUT, describe(flags[7])
    twice = once.copy()
    twice[np.searchsorted(t, 6.5), 7] = 0.0  # and again within the 2 s window
    flags = run(HealthMonitor(N_SENSORS, RATE_HZ), t, twice)
    assert flags[7] & SensorHealth.DROPOUT, describe(flags[7])
