"""Per-taxel gains, baselines and cross-axis coupling (no two uSkin taxels read alike)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect
from tacforce_ros.sim.taxel_response import CHIP_ZERO


@dataclass
class TaxelVariation(Effect):
    name = 'taxel_variation'
    # Rest spread: X/Y within about +/-1350 counts of mid-scale, Z between ~33,600 and ~37,600
    # (docs/PROTOCOLS.md section 1). Gain spread and coupling are our estimates (magnet placement,
    # elastomer thickness tolerances).
    baseline_xy_spread: float = 1350.0   # counts, uniform +/-
    baseline_z_range: tuple[float, float] = (33600.0, 37600.0)
    gain_sigma: float = 0.2              # relative, lognormal
    coupling_sigma: float = 0.08         # off-diagonal load mixing

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        n = ctx.n_taxels
        self._baseline = np.column_stack([
            CHIP_ZERO + rng.uniform(-self.baseline_xy_spread, self.baseline_xy_spread, (n, 2)),
            rng.uniform(*self.baseline_z_range, n)])
        self._gain = np.exp(rng.normal(0.0, self.gain_sigma, (n, 3)))
        self._coupling = np.eye(3) + rng.normal(0.0, self.coupling_sigma, (n, 3, 3)) * (
            1.0 - np.eye(3))

    def on_response(self, ctx) -> None:
        params = ctx.params
        params.baseline = self._baseline
        params.slope = params.slope * self._gain
        params.coupling = self._coupling


EFFECT = TaxelVariation
