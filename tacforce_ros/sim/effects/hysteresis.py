"""Elastomer hysteresis: a play (backlash) operator on each taxel's load, per axis."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class Hysteresis(Effect):
    name = 'hysteresis'
    # Half-width of the loop: ~2 % of a 3 N per-cell range, our estimate for silicone skins
    # (the paper neglects hysteresis, section III; this effect tests that assumption).
    width: float = 0.03   # N

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._output = np.zeros((ctx.array.n_taxels, 3))

    def on_local_force(self, state) -> None:
        np.clip(self._output, state.local_force - self.width, state.local_force + self.width,
                out=self._output)
        state.local_force = self._output.copy()


EFFECT = Hysteresis
