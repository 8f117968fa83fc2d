"""A dial gauge (dial indicator) on the calibration rig's probe: the probe's travel, read by a person.

The rig's servo knows how far it has wound the cable, not how far the probe went: on a compliant specimen (a segment's
shell) the probe follows the shell in, and only an independent measure of that travel turns the winding into a force
(``F = k·(r·(θ − θ_c) − d)``). A dial gauge is what any lab has: a plunger resting on the probe, read to its
resolution (0.01 mm on the usual digital indicators) once the rig has settled at each step. :class:`TypedGauge` asks
for each reading on a line of text (the person types what the display shows, in millimetres); the simulated rig's
gauge (``devices.sim.gauge``, through :func:`devices.factory.travel_gauge`) answers the same question from the
simulated probe. Either is called on the thread that runs the rig.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from devices.errors import GaugeReadError

DEFAULT_RESOLUTION_M = 1e-5  # 0.01 mm: the common digital indicator's digit
TYPED_TRIES = 3  # a line that is not a number is asked again this many times in all


class TravelGauge(Protocol):
    """Reads the probe's position (m) along its push, positive toward the specimen; any zero."""

    resolution_m: float

    def read_m(self, what: str) -> float:
        """One reading (m) taken now; ``what`` says which step it is (for a person reading it)."""
        ...


class TypedGauge:
    """A dial gauge read by a person: ``ask`` shows a prompt and returns the line typed (``input`` by default)."""

    def __init__(self, resolution_m: float = DEFAULT_RESOLUTION_M, ask: Callable[[str], str] = input) -> None:
        self.resolution_m = resolution_m
        self._ask = ask

    def read_m(self, what: str) -> float:
        for _ in range(TYPED_TRIES):
            try:
                line = self._ask(f"{what}: the dial gauge reads (mm)? ")
            except EOFError:
                raise GaugeReadError(f"no dial gauge reading for {what}: the input ended") from None
            try:
                value = float(line.strip().replace(",", "."))
            except ValueError:
                continue
            if math.isfinite(value):
                return value / 1000.0
        raise GaugeReadError(f"no dial gauge reading for {what}: {TYPED_TRIES} lines were not a number of "
                             "millimetres")
