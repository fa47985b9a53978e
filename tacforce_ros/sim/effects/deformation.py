"""Elastomer deformation: under load a curved skin flattens, turning its taxels' frames.

Taxels near the contact rotate towards the contact normal, by a fraction that grows with the
indentation depth and fades with distance; on a flat array the normals already agree, so nothing
turns. Models that assume the unloaded R_i^0 (M1, M2 of the paper) then mis-project the taxel
readings, which is why they lose on the curved fingertip (paper, Table I and section V-A).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect
from tacforce_ros.sim.vector import cross


@dataclass
class Deformation(Effect):
    name = 'deformation'
    max_fraction: float = 1.0     # share of the taxel-to-contact-normal angle removed at most
    depth_scale: float = 0.0004   # m of indentation for ~63 % of that flattening
    reach: float = 0.010          # m, radius of the flattened patch (fingertip 13.5 mm radius)

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._positions = ctx.array.positions
        self._normals = ctx.array.rotations[:, :, 2]

    def on_rotations(self, state) -> None:
        contact = state.contact
        if state.depth <= 0.0:
            return
        dist2 = np.sum((self._positions - contact.point) ** 2, axis=1)
        fraction = (self.max_fraction * (1.0 - np.exp(-state.depth / self.depth_scale))
                    * np.exp(-0.5 * dist2 / self.reach ** 2))
        axis = cross(self._normals, contact.normal)
        sin_angle = np.linalg.norm(axis, axis=1)
        angle = np.arctan2(sin_angle, self._normals @ contact.normal)
        unit = axis / np.maximum(sin_angle, 1e-12)[:, None]
        theta = fraction * angle
        # Rodrigues' formula, batched: R = I + sin(t) K + (1 - cos(t)) K^2.
        k = np.zeros((len(unit), 3, 3))
        k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -unit[:, 2], unit[:, 1], -unit[:, 0]
        k -= k.transpose(0, 2, 1)
        turn = (np.eye(3) + np.sin(theta)[:, None, None] * k
                + (1.0 - np.cos(theta))[:, None, None] * (k @ k))
        state.rotations = turn @ state.rotations


EFFECT = Deformation
