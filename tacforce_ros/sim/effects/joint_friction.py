"""Joint friction of the simulated hand: Coulomb friction loss and viscous damping per joint."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class JointFriction(Effect):
    name = 'joint_friction'
    # Geared Allegro joints (our estimates, no datasheet figure): motor brush and bearing
    # friction of ~0.1 mN m times a gear ratio of a few hundred, through a gear train that loses
    # part of it again, gives a few hundredths of a N m at the joint: 0.03 N m is 0.3 N at the
    # ~0.1 m lever of the index fingertip, i.e. the force band in which the open loop can stick.
    # Viscous: back-EMF and gear drag, small beside the controller's K_d.
    coulomb: float = 0.03     # N m
    viscous: float = 0.003    # N m s/rad

    def on_model(self, world) -> None:
        if not world.hand_wide:
            return
        for joint in world.hand_joints():
            joint.frictionloss = self.coulomb
            joint.damping = np.asarray(joint.damping) + np.eye(len(joint.damping))[0] * self.viscous


EFFECT = JointFriction
