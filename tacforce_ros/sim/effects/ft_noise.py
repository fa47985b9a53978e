"""F/T sensor noise and bias (ATI Mini45 behind a Net F/T box)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect

BLOCK = 256   # steps of draws made at once


@dataclass
class FTNoise(Effect):
    name = 'ft_noise'
    # Noise about half the Mini45 SI-145-5 resolution (1/16 N, 1/752 N m per ATI's catalogue);
    # an un-zeroed bias of a few tenths of a newton with a slow drift, our estimate.
    force_sigma: float = 0.03        # N
    torque_sigma: float = 0.0007     # N m
    force_bias_sigma: float = 0.15   # N
    torque_bias_sigma: float = 0.003  # N m
    drift_per_sqrt_s: float = 0.002  # N/sqrt(s), random walk of the force bias

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng
        self._sigma = np.array([self.force_sigma] * 3 + [self.torque_sigma] * 3)
        self._bias = rng.normal(0.0, 1.0, 6) * np.array(
            [self.force_bias_sigma] * 3 + [self.torque_bias_sigma] * 3)
        self._step = self.drift_per_sqrt_s * np.sqrt(ctx.physics_dt)
        self._next = BLOCK

    def on_wrench(self, state) -> None:
        if self._next == BLOCK:
            # A block of steps' draws at once, scaled at once: the same numbers, in the same
            # order, as three and six per step, at a fraction of the calls. The force bias's
            # walk over the block is summed in step order (add.accumulate adds row after row).
            draws = self._rng.standard_normal((BLOCK, 9))
            walk = np.vstack([self._bias[:3], self._step * draws[:, :3]])
            self._biases = np.empty((BLOCK, 6))
            self._biases[:, :3] = np.add.accumulate(walk)[1:]
            self._biases[:, 3:] = self._bias[3:]
            self._bias = self._biases[-1].copy()
            self._offsets = self._biases + self._sigma * draws[:, 3:]   # bias and noise
            self._next = 0
        state.wrench = state.wrench + self._offsets[self._next]
        self._next += 1


EFFECT = FTNoise
