"""Elastomer hysteresis: a play (backlash) operator on each taxel's load, per axis.

The loop's half-width grows with the load (viscoelastic silicone loses a share of the stored
energy), plus a small constant part for static friction between magnet and chip housing."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect
from tacforce_ros.sim.elastomer_memory import Play


@dataclass
class Hysteresis(Effect):
    name = 'hysteresis'
    # Our estimates for silicone skins (the paper neglects hysteresis, section III; this
    # effect tests that assumption).
    relative: float = 0.05   # share of the load
    width: float = 0.003     # N

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._play = Play(self.relative, self.width)
        self._play.reset((ctx.array.n_taxels, 3))

    def on_local_force(self, state) -> None:
        state.local_force = self._play(state.local_force)


EFFECT = Hysteresis
