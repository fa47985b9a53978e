"""Elastomer deformation: under load a curved skin flattens, turning its taxels' frames.

Taxels near the contact turn towards the contact normal, by a fraction that grows with the
indentation depth and fades with distance; on a flat array the normals already agree, so nothing
turns. A taxel frame turned by Q reads R_i^T Q^T f_i, so the effect turns each taxel's force by
Q^T (Rodrigues' formula on vectors, batched). Models that assume the unloaded R_i^0 (M1, M2 of
the paper) then mis-project the readings, as on the curved fingertip (paper, Table I).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect
from tacforce_ros.sim.vector import cross


@dataclass
class Deformation(Effect):
    name = 'deformation'
    # Our estimates for a ~4-5 mm silicone layer on the 13.5 mm radius uSkin fingertip.
    max_fraction: float = 1.0     # share of the taxel-to-contact-normal angle removed at most
    depth_scale: float = 0.0004   # m of indentation for ~63 % of that flattening
    reach: float = 0.010          # m, radius of the flattened patch

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._positions = ctx.array.positions
        self._normals = ctx.array.rotations[:, :, 2]

    def on_taxel_force(self, state) -> None:
        contact = state.contact
        if state.depth <= 0.0:
            return
        dist2 = np.sum((self._positions - contact.point) ** 2, axis=1)
        fraction = (self.max_fraction * (1.0 - np.exp(-state.depth / self.depth_scale))
                    * np.exp(-0.5 * dist2 / self.reach ** 2))
        axis = cross(self._normals, contact.normal)
        sin_angle = np.sqrt(np.sum(axis * axis, axis=1))
        angle = np.arctan2(sin_angle, self._normals @ contact.normal)
        unit = axis / np.maximum(sin_angle, 1e-12)[:, None]
        theta = (fraction * angle)[:, None]
        force = state.taxel_force
        # Q^T f = f cos(t) - (k x f) sin(t) + k (k . f)(1 - cos(t))
        along = np.sum(unit * force, axis=1, keepdims=True)
        state.taxel_force = (force * np.cos(theta) - cross(unit, force) * np.sin(theta)
                             + unit * along * (1.0 - np.cos(theta)))


EFFECT = Deformation
