"""Temperature: per-taxel readings (kelvin) that wander, and the count drift they cause."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect
from tacforce_ros.sim.taxel_response import CHIP_ZERO

BLOCK = 128   # frames of draws made at once


@dataclass
class TemperatureDrift(Effect):
    name = 'temperature_drift'
    # Slow Ornstein-Uhlenbeck wander per array around the warmed-up temperature (the paper
    # warms the hand 30 min before recording, section IV-A); magnitudes are our estimates.
    sigma: float = 0.5              # K, stationary std of each array's temperature
    time_constant: float = 60.0     # s
    taxel_offset_sigma: float = 0.2  # K, fixed per-taxel reading offset
    # NdFeB magnets lose ~0.12 %/K of remanence (reversible coefficient of Br, standard figure),
    # scaling the field the chip sees; the Hall chip offset drift is our estimate.
    remanence_coefficient: float = -0.0012   # 1/K
    offset_drift_sigma: float = 8.0          # counts/K

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        # Each taxel's thermistor offset and Hall-chip drift coefficient belong to the chip.
        self._offset = rng.normal(0.0, self.taxel_offset_sigma, ctx.n_taxels)
        self._drift = rng.normal(0.0, self.offset_drift_sigma, (ctx.n_taxels, 3))

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng
        self._decay = float(np.exp(-ctx.dt / self.time_constant))
        self._array_of = ctx.array_of_taxel
        n_arrays = int(self._array_of.max()) + 1
        self._wander = rng.normal(0.0, self.sigma, n_arrays)
        self._innovation = self.sigma * np.sqrt(1.0 - self._decay ** 2)
        self._next = BLOCK

    def on_counts(self, state) -> None:
        if self._next == BLOCK:     # the same draws, in order, as one frame's at a time
            self._block = self._rng.standard_normal((BLOCK, len(self._wander)))
            self._next = 0
        self._wander = (self._decay * self._wander + self._innovation * self._block[self._next])
        self._next += 1
        delta = self._wander[self._array_of] + self._offset
        state.temperatures = state.temperatures + delta
        change = state.counts - CHIP_ZERO      # the field, scaled in place into the change
        change *= self.remanence_coefficient
        change += self._drift
        change *= delta[:, None]
        state.counts += change


EFFECT = TemperatureDrift
