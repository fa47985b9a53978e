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
        self._key = b''

    def _geometry(self, point: np.ndarray, normal: np.ndarray) -> None:
        """Turn axes and full angles times the distance fall-off for one contact location
        (cached: the operator holds a location through a press)."""
        key = point.tobytes() + normal.tobytes()
        if key == self._key:
            return
        self._key = key
        # np.add.reduce is np.sum without its Python wrapper: the contact moves every frame of
        # a closed loop, so this runs once per frame there.
        dist2 = np.add.reduce((self._positions - point) ** 2, axis=1)
        falloff = self.max_fraction * np.exp(-0.5 * dist2 / self.reach ** 2)
        # n_i x c for every taxel normal n_i: one product with the cross-product matrix of c
        nx, ny, nz = normal.tolist()
        axis = self._normals @ np.array([[0.0, -nz, ny], [nz, 0.0, -nx], [-ny, nx, 0.0]])
        sin_angle = np.sqrt(np.add.reduce(axis * axis, axis=1))
        self._turn = falloff * np.arctan2(sin_angle, self._normals @ normal)
        self._unit = axis / np.maximum(sin_angle, 1e-12)[:, None]

    def on_taxel_force(self, state) -> None:
        if state.depth <= 0.0:
            return
        self._geometry(state.contact.point, state.contact.normal)
        theta = (self._turn * (1.0 - np.exp(-state.depth / self.depth_scale)))[:, None]
        force, unit = state.taxel_force, self._unit
        # Q^T f = f cos(t) - (k x f) sin(t) + k (k . f)(1 - cos(t))
        along = np.add.reduce(unit * force, axis=1, keepdims=True)
        cos = np.cos(theta)
        state.taxel_force = (force * cos - cross(unit, force) * np.sin(theta)
                             + unit * along * (1.0 - cos))

EFFECT = Deformation
