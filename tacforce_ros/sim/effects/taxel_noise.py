"""White noise on the raw tactile counts of every taxel."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect

BLOCK = 128   # frames of noise drawn per call: one large draw is far cheaper than many small


@dataclass
class TaxelNoise(Effect):
    name = 'taxel_noise'
    # A few counts rms: our estimate for uSkin raw readings at rest (no datasheet figure).
    sigma: tuple[float, float, float] = (5.0, 5.0, 8.0)   # counts, X Y Z

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng
        self._sigma = np.asarray(self.sigma, np.float64)
        self._shape = (BLOCK, ctx.n_taxels, 3)
        self._next = BLOCK

    def on_counts(self, state) -> None:
        if self._next == BLOCK:
            # float32 draws: half the cost, and ample for noise of a few counts.
            self._block = self._rng.standard_normal(self._shape, np.float32) * self._sigma
            self._next = 0
        state.counts += self._block[self._next]
        self._next += 1


EFFECT = TaxelNoise
