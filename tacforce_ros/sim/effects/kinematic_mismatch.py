"""Kinematic mismatch: the simulated finger differs from the controller's nominal URDF.

The sensorised fingertip is thicker than the bare Allegro tip, and link lengths carry assembly
tolerances; the controller's Jacobian, built from the nominal URDF, no longer matches the hand.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.rig import FINGERS
from tacforce_ros.sim.effects import Effect


@dataclass
class KinematicMismatch(Effect):
    name = 'kinematic_mismatch'
    # The mounted uSkin tip (elastomer, cover, tape) is a few millimetres thicker than the
    # 13.5 mm tip sphere of the controller's URDF (our estimate); link tolerance 0.5 mm rms.
    tip_thickness: float = 0.004   # m, added to the fingertip contact radius
    link_sigma: float = 0.0005     # m, per link origin

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        # Origins of each finger's links after its base link (3 links and the tip), in the
        # hand's finger order: the tolerances of this hand's assembly (the index finger's drawn
        # first, as when only it was drawn).
        self._link_errors = rng.normal(0.0, self.link_sigma, (len(FINGERS), 4, 3))

    def on_model(self, world) -> None:
        world.tip_radius_extra += self.tip_thickness
        errors = self._link_errors[FINGERS.index(world.finger)]
        for body, error in zip(world.finger_bodies()[1:], errors, strict=True):
            body.pos = np.asarray(body.pos) + error


EFFECT = KinematicMismatch
