"""Contact away from the controller's assumed end-effector point on the fingertip."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class ContactOffset(Effect):
    name = 'contact_offset'
    # The pad touches a few millimetres proximal of the tip point the controller assumes
    # (our estimate; the paper uses the fingertip as end effector, section IV-C).
    offset: tuple[float, float, float] = (0.0, 0.0, -0.006)   # m, in the fingertip link frame

    def on_model(self, world) -> None:
        world.contact_offset = world.contact_offset + np.asarray(self.offset, np.float64)


EFFECT = ContactOffset
