"""Kinematic mismatch: the simulated finger differs from the controller's nominal URDF.

The sensorised fingertip is thicker than the bare Allegro tip, and link lengths carry assembly
tolerances; the controller's Jacobian, built from the nominal URDF, no longer matches the hand.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class KinematicMismatch(Effect):
    name = 'kinematic_mismatch'
    # uSkin fingertip adds a few millimetres over the 14 mm Allegro tip radius (our estimate);
    # link length tolerance +/- 0.5 mm rms.
    tip_thickness: float = 0.004   # m, added to the fingertip contact radius
    link_sigma: float = 0.0005     # m, per link origin

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng

    def on_model(self, world) -> None:
        world.tip_radius_extra += self.tip_thickness
        for body in world.finger_bodies()[1:]:
            body.pos = np.asarray(body.pos) + self._rng.normal(0.0, self.link_sigma, 3)


EFFECT = KinematicMismatch
