"""The live motion-capture benchmark's statistics (the benchmark itself is run by hand, never by the tests)."""

from __future__ import annotations

import numpy as np

from benchmarks.bench_mocap_lsl import capture_index, match_rows, spread_s


def test_a_stored_sample_is_placed_on_the_senders_schedule_by_its_position() -> None:
    rate_hz, speed_m_s, x0_m = 480.0, 0.2, 0.0123
    index = np.array([0, 1, 2, 479, 28_800, 60_000])
    x = (x0_m + index / rate_hz * speed_m_s) * 1000.0
    stored_m = x.astype(np.float32).astype(float) / 1000.0  # sent in float32 mm, as the stream's channels
    np.testing.assert_array_equal(capture_index(stored_m, x0_m, speed_m_s, rate_hz), index)


def test_the_spread_is_p99_minus_p1_and_ignores_a_constant() -> None:
    values = np.linspace(0.0, 1.0, 10_001)
    assert abs(spread_s(values) - 0.98) < 1e-12
    assert abs(spread_s(values + 5.0) - spread_s(values)) < 1e-9


def test_received_samples_are_matched_to_their_rows_bit_for_bit_in_order() -> None:
    rows = np.array([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0], [5.0, 6.0]])
    received = np.array([[3.0, 4.0], [1.0, 2.0], [5.0, 6.0], [5.0, 6.0 + 1e-12]])
    # the repeated value goes to the row after the previous match; a value one ulp away matches nothing
    np.testing.assert_array_equal(match_rows(rows, received), [1, 2, 3, -1])
