"""White noise on the raw tactile counts of every taxel, each taxel at its own level.

The levels come from public recordings of uSkin 4x4 modules at rest (150 recordings of two
modules, 16 taxels each, raw counts: imanlab/tactile_prediction_flat_dataset): the rms over a
rest stretch, per taxel and recording, has a median of 1.0 / 0.9 / 3.1 counts on X / Y / Z and
a 90th percentile of 1.9 / 1.7 / 7.6. Each simulated taxel draws its level once per hand from a
lognormal with that median and 90th percentile (the lognormal shape is our estimate). Those
figures are of whole counts: the simulator's rounding to whole counts adds 1/12 count^2 itself,
so the noise added before it is that much smaller.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect

BLOCK = 128   # frames of noise drawn per call: one large draw is far cheaper than many small
ROUNDING_VARIANCE = 1.0 / 12.0   # count^2: uniform rounding error of a whole-count reading
Z90 = 1.2815515655446004         # the standard normal's 90th percentile


@dataclass
class TaxelNoise(Effect):
    name = 'taxel_noise'
    median: tuple[float, float, float] = (1.0, 0.9, 3.1)   # counts rms, X Y Z (module docstring)
    p90: tuple[float, float, float] = (1.9, 1.7, 7.6)      # counts rms, X Y Z
    scale: float = 1.0          # times both: a what-if (skin_sensitivity varies it)

    def __post_init__(self) -> None:
        median, p90 = np.asarray(self.median, np.float64), np.asarray(self.p90, np.float64)
        if median.shape != (3,) or p90.shape != (3,) or not np.all(median > 0.0) \
                or not np.all(p90 >= median) or not self.scale >= 0.0:
            raise ValueError('taxel_noise: median and p90 take three positive counts (X, Y, Z) '
                             f'with p90 >= median, scale >= 0; got {self.median}, {self.p90}, '
                             f'{self.scale}')
        self._log_median, self._log_spread = np.log(median), np.log(p90 / median) / Z90

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        level = self.scale * np.exp(self._log_median
                                    + self._log_spread * rng.standard_normal((ctx.n_taxels, 3)))
        self.sigma = np.sqrt(np.maximum(level * level - ROUNDING_VARIANCE, 0.0))

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng
        self._sigma = self.sigma.astype(np.float32)
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
