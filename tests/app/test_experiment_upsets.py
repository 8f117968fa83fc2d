"""Telling a traversal from a fall: when a physics-lab body lost the ground or rolled onto its side, from its true
sheet forces (app.core.experiment.body_upsets), on series with a known answer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.core.experiment import ExperimentResult, body_upsets, crawl_m
from devices.scene import SIDES, channel_map

NAMES = tuple(f"S{s:02d}{side}" for s in range(1, 13) for side in "LRB")
ROWS, _ = channel_map(NAMES, 12)
WEIGHT = 23.5
T = np.arange(0, 10, 0.02)


def _lying(on: str = "B") -> np.ndarray:
    """Every segment's share of the weight on its ``on`` sheets, for the whole of T."""
    sheets = np.zeros((len(T), len(NAMES)))
    sheets[:, np.asarray(ROWS) == SIDES.index(on)] = WEIGHT / 12
    return sheets


def test_a_body_on_its_bottom_sheets_has_no_upset():
    assert all(math.isnan(t) for t in body_upsets(T, _lying("B"), ROWS, WEIGHT))


def test_a_fall_is_the_sheets_carrying_almost_nothing_for_a_tenth_of_a_second_and_a_blip_is_not():
    sheets = _lying("B")
    sheets[(T >= 3.0) & (T < 3.04)] = 0.0  # two ticks (40 ms): a contact's hop, not a fall
    sheets[(T >= 5.0) & (T < 5.2)] *= 0.2  # 0.2 s at a fifth of the weight: off the ground
    lost, rolled = body_upsets(T, sheets, ROWS, WEIGHT)
    assert lost == pytest.approx(5.0)
    assert math.isnan(rolled)


def test_a_body_that_rolled_carries_its_weight_on_its_side_sheets():
    sheets = _lying("B")
    sheets[T >= 6.0] = _lying("R")[T >= 6.0]
    sheets[(T >= 2.0) & (T < 2.3)] = _lying("L")[(T >= 2.0) & (T < 2.3)]  # 0.3 s on its side: a wobble, not a roll
    lost, rolled = body_upsets(T, sheets, ROWS, WEIGHT)
    assert math.isnan(lost)
    assert rolled == pytest.approx(6.0)


def test_a_traversal_is_a_crawl_only_if_the_body_advanced_before_its_first_upset():
    def result(crawl: float, traversed: bool = True) -> ExperimentResult:
        return ExperimentResult(path=None, shape_rad=np.zeros(12), simulated_s=1.0, wall_s=1.0, advance_m=0.8,
                                median_bottom_force_n=23.5, median_vertical_support_n=23.5, weight_n=23.5,
                                overloads=(), traversed=traversed, crawl_m=crawl)

    assert result(0.55).crawled_traverse  # crawled on until the tail tipped over the crest
    assert not result(0.06).crawled_traverse  # balanced on the crest, then fell off it forward
    assert not result(0.55, traversed=False).crawled_traverse
    assert not result(math.nan).crawled_traverse  # not known is not a crawl


def test_the_crawl_is_the_advance_until_the_first_upset():
    points = np.zeros((len(T), 13, 3))
    points[:, :, 0] = (0.05 * T)[:, None] - np.arange(13) * 0.08  # crawling at 5 cm/s
    assert crawl_m(T, points, (math.nan, math.nan)) == pytest.approx(0.05 * T[-1])
    assert crawl_m(T, points, (6.0, 4.0)) == pytest.approx(0.20)  # rolled at 4 s, lost the ground at 6 s
    assert crawl_m(T, points, (math.nan, 1.0)) == pytest.approx(0.05)
