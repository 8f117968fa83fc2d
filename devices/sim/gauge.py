"""The simulated rig's dial gauge: what a digital indicator on the probe would show.

The reading is the simulated probe's travel (:meth:`devices.sim.rig.VirtualRig.probe_travel_m`) plus the gauge's
repeatability (Gaussian, ``noise_m`` s.d.; 3 µm by default, an assumption: a 0.01 mm indicator repeats within its
digit) rounded to its digit (``resolution_m``, 0.01 mm), from a seeded generator. Its zero is where the probe rested
when the gauge was set (an arbitrary offset, as on the bench). Its accuracy over the stroke (a slow scale error, up to
±0.02 mm on the usual 12.7 mm indicators) is not modelled: that error scales the fitted stiffness by well under 1 %.
"""

from __future__ import annotations

import numpy as np

from devices.sim.rig import VirtualRig

DEFAULT_NOISE_M = 3e-6


class SimDialGauge:
    """A dial gauge on the simulated rig's probe (:class:`devices.gauge.TravelGauge`)."""

    def __init__(self, rig: VirtualRig, resolution_m: float = 1e-5, noise_m: float = DEFAULT_NOISE_M,
                 seed: int = 0, zero_m: float = 0.00123) -> None:
        self.resolution_m = resolution_m
        self._rig = rig
        self._noise_m = noise_m
        self._zero_m = zero_m
        self._rng = np.random.default_rng(seed)

    def read_m(self, what: str) -> float:
        true_m = self._rig.probe_travel_m() + self._zero_m
        noisy = true_m + float(self._rng.normal(0.0, self._noise_m))
        return float(np.round(noisy / self.resolution_m) * self.resolution_m)
