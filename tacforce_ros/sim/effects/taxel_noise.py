"""White noise on the raw tactile counts of every taxel."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class TaxelNoise(Effect):
    name = 'taxel_noise'
    # A few counts rms: our estimate for uSkin raw readings at rest (no datasheet figure).
    sigma: tuple[float, float, float] = (5.0, 5.0, 8.0)   # counts, X Y Z

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng
        self._sigma = np.asarray(self.sigma, np.float64)

    def on_counts(self, state) -> None:
        state.counts += self._rng.standard_normal(state.counts.shape) * self._sigma


EFFECT = TaxelNoise
