"""Joint friction of the simulated hand: Coulomb friction loss and viscous damping per joint."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class JointFriction(Effect):
    name = 'joint_friction'
    # Geared Allegro joints: our estimate of a few hundredths of a N m of static friction.
    coulomb: float = 0.02     # N m
    viscous: float = 0.003    # N m s/rad

    def on_model(self, world) -> None:
        for joint in world.hand_joints():
            joint.frictionloss = self.coulomb
            joint.damping = np.asarray(joint.damping) + np.eye(len(joint.damping))[0] * self.viscous


EFFECT = JointFriction
