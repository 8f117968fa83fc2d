"""The sample validator's one-row path (a live reader's block: one board frame) gives the general path's results, bit
for bit: every status, every conductance passed on and every piece of state carried to the next block."""

from __future__ import annotations

import numpy as np
import pytest

from models.sls import ForceStatus
from models.validation import DEFAULT_STEP_S, SampleValidator, ValidationRule

CEILING_S = 1.0 / 900.0


def _stream(seed: int, rows: int = 1200, sensors: int = 24) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, conductance, saturated) of a 30 Hz board whose sensors do everything the rule judges: noise of a few ADC
    steps or none (quiet sensors repeating themselves), loads ramping and creeping, lines freezing under load,
    releases and opens straight after a load, gaps (NaN, inf), negative and impossible readings, the ceiling."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.8, 1.2, rows)) / 30.0
    level = np.cumsum(rng.normal(0.0, 3e-6, (rows, sensors)), axis=0) + rng.uniform(5e-5, 8e-4, sensors)
    ramp = np.clip((t[:, None] - rng.uniform(5, 40, sensors)) / rng.uniform(0.5, 3.0, sensors), 0.0, 1.0)
    creep = 1.0 + 0.05 * (1.0 - np.exp(-t[:, None] / rng.uniform(20, 200, sensors)))
    noise = rng.normal(0.0, 1.0, (rows, sensors)) * rng.choice([0.0, 0.2, 0.5, 2.0], sensors) * DEFAULT_STEP_S
    cond = np.round((level * ramp * creep + noise) / DEFAULT_STEP_S) * DEFAULT_STEP_S
    for j in range(sensors):  # frozen lines: a stretch of one value, some short, some past flat_max_s
        start = rng.integers(0, rows - 10)
        cond[start:start + rng.integers(10, 900), j] = cond[start, j]
    events = rng.random((rows, sensors))
    cond[events < 0.004] = 0.0  # opens (after a load: under load)
    cond[(events >= 0.004) & (events < 0.006)] = np.nan
    cond[(events >= 0.006) & (events < 0.007)] = np.inf
    cond[(events >= 0.007) & (events < 0.008)] = -1e-4
    cond[(events >= 0.008) & (events < 0.009)] = 1e300
    cond[(events >= 0.009) & (events < 0.011)] = CEILING_S
    cond[:, 0] = 0.0  # a sensor never touched
    cond[100:400, 1] = 0.0  # a release lasting past open_release_s
    cond[:700, 2] = np.where(np.arange(700) < 5, 1e-4, 2e-4)  # one change, then a history too short to judge by
    saturated = rng.random((rows, sensors)) < 0.003
    return t, cond, saturated


STATE = ("_last_value", "_run_start_s", "_run_length", "_run_needs", "_last_informative", "_changes", "_compares",
         "_valid", "_ever", "_run_flat", "_tail_signed", "_tail_unusable", "_guard_mark", "_guard_row",
         "_last_reading", "_open_start_s")


def _same_state(a: SampleValidator, b: SampleValidator) -> None:
    for name in STATE:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name, strict=True)


@pytest.mark.parametrize("seed, rule", [
    (0, ValidationRule(ceiling_s=CEILING_S)),
    (1, ValidationRule(ceiling_s=CEILING_S, flat_s=3.0, flat_min_s=0.5, flat_max_s=8.0)),
    (2, ValidationRule(ceiling_s=None, step_s=None)),
    (3, ValidationRule(ceiling_s=CEILING_S, flat_s=0.0)),
])
def test_one_row_blocks_give_the_general_paths_results_bit_for_bit(seed, rule):
    t, cond, saturated = _stream(seed)
    fast = SampleValidator(cond.shape[1], rule)
    general = SampleValidator(cond.shape[1], rule)
    general.one_row_fast_path = False
    rng = np.random.default_rng(100 + seed)
    i = 0
    seen = set()
    while i < t.size:
        # mostly one row, as a live reader's, with blocks of other sizes between (the state crosses both ways)
        n = 1 if rng.random() < 0.8 else int(rng.integers(2, 40))
        block = slice(i, i + n)
        mask = saturated[block] if rng.random() < 0.5 else None
        got = fast.check(t[block], cond[block], mask)
        want = general.check(t[block], cond[block], mask)
        np.testing.assert_array_equal(got.status, want.status, strict=True)
        np.testing.assert_array_equal(got.conductance_s, want.conductance_s, strict=True)
        _same_state(fast, general)
        seen.update(np.unique(got.status).tolist())
        i += n
    # the stream reached the rule's branches (with flat_s 0 the stuck-channel rule is off)
    expected = {ForceStatus.OK, ForceStatus.NAN_INPUT, ForceStatus.NEGATIVE_CONDUCTANCE,
                ForceStatus.READOUT_SATURATED, ForceStatus.OPEN_UNDER_LOAD}
    if rule.flat_s > 0:
        expected.add(ForceStatus.FLAT)
    if rule.ceiling_s is not None:
        expected.add(ForceStatus.ABOVE_CEILING)
    assert expected <= seen, sorted(ForceStatus(code).name for code in expected - seen)
    if seed == 1:
        assert ForceStatus.UNCHANGED in seen


def test_one_row_path_is_taken_for_one_row_blocks(monkeypatch):
    calls = []
    validator = SampleValidator(3)
    original = validator._flat_one_row
    monkeypatch.setattr(validator, "_flat_one_row", lambda *a: calls.append(1) or original(*a))
    validator.check(np.array([0.0]), np.full((1, 3), 1e-4))
    validator.check(np.array([0.1, 0.2]), np.full((2, 3), 1e-4))
    assert calls == [1]
