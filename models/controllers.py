"""The controllers a physics-lab run, a sweep, an evaluation or a tuning can name, and the law's gains each one runs.

Every controller but ``feedforward`` is the force-feedback law of :mod:`models.force_feedback`; the variants differ
from it only in the node terms they leave out, so that they are compared on the same footing (same runner, same
conditions, same seeds). Fu & Li 2023 (Bioinspir. Biomim. 18:056002) separate the two things contact feedback does:
*conforming* (reaching for lost contact, yielding to an overload) and *pushing* (pressing harder where the body
already pushes forward):

==================  ==========================================================================================
``feedforward``     follow-the-leader as taught (SPEC §5): no law at all
``feedback``        the whole law with the given gains
``conform_only``    the law with ``push_gain`` and ``relieve_gain`` 0: nodes only reach for lost contact and yield
``push_only``       the law with ``conform_gain`` 0: nodes only press where they lean forward (no reach, no yield)
==================  ==========================================================================================

The lead and its tail guard (the front's own term, neither conforming nor pushing a node) stay as the gains say in
every variant. Pure: no clock, no I/O.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from models.force_feedback import FeedbackGains

FEEDFORWARD = "feedforward"
CONTROLLERS = (FEEDFORWARD, "feedback", "conform_only", "push_only")
# The gains each variant of the law sets to 0 (the rest are the gains it is given).
ZEROED_GAINS: dict[str, tuple[str, ...]] = {"feedback": (), "conform_only": ("push_gain", "relieve_gain"),
                                            "push_only": ("conform_gain",)}


def uses_law(controller: str) -> bool:
    """True for a controller that runs the force-feedback law (every one but feedforward)."""
    return controller != FEEDFORWARD


def law_gains(controller: str, gains: FeedbackGains) -> FeedbackGains:
    """The gains the law runs with for ``controller`` given ``gains``: those of :data:`ZEROED_GAINS` set to 0.
    ValueError for feedforward (no law) or an unknown name."""
    if controller not in ZEROED_GAINS:
        raise ValueError(f"controller must be one of {', '.join(ZEROED_GAINS)} to run the law, got {controller!r}")
    return replace(gains, **dict.fromkeys(ZEROED_GAINS[controller], 0.0))
