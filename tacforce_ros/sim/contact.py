"""Contact pressure distribution over an array's taxels for a push-plate indenter.

Elastic-foundation (Winkler) model: each taxel is a spring of stiffness `k` under the elastomer.
The indenter surface (sphere, cylinder or plane) touches the array's surface at the contact
point; a taxel is loaded by how far the indenter, pushed in by depth d, reaches past the gap
between the two surfaces above it. d follows from the normal force; the taxel loads are then
spread by the elastomer (a Gaussian kernel over taxel distance). So the contact area grows with
force and depends on both the indenter's and the array's curvature, vectorised over taxels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.scene import Plate
from tacforce_ros.sim.vector import cross

# Foundation stiffness per taxel and elastomer spreading width: our estimates for a ~4-5 mm
# silicone layer over a 4.7 mm taxel pitch (uSkin; Tomo et al. 2018), not datasheet values.
FOUNDATION_STIFFNESS = 2000.0   # N/m per taxel
SPREAD_SIGMA = 0.0025           # m


# Width over which taxel normals are blended into the skin's surface normal at a point: about
# the 4.7 mm taxel pitch (uSkin), so the normal turns smoothly from taxel to taxel.
SURFACE_BLEND = 0.003   # m


def skin_surface(positions: np.ndarray, normals: np.ndarray, point: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(point on the skin, unit outward normal there), {S0}, for a point near the array.

    The skin is described by its taxels only; near `point` it is the plane through the taxels'
    blended centre with their blended normal, so a contact placed by the operator or by the
    fingertip dynamics sits on the same surface, with the normal the sensor chain assumes.
    """
    # np.add.reduce: np.sum without its Python wrapper (this runs on every closed-loop frame)
    dist2 = np.add.reduce((positions - point) ** 2, axis=1)
    weight = np.exp(-0.5 * dist2 / SURFACE_BLEND ** 2)
    total = np.add.reduce(weight)
    if total < 1e-12:   # far from every taxel: the nearest one decides
        weight = np.zeros(len(positions))
        weight[np.argmin(dist2)] = 1.0
        total = 1.0
    normal = weight @ normals
    normal /= np.sqrt(normal @ normal)
    anchor = weight @ positions / total
    return point - ((point - anchor) @ normal) * normal, normal


@dataclass
class Contact:
    """One contact on the array, all in {S0}: the force the array applies to the indenter."""
    force: np.ndarray       # (3,) N
    point: np.ndarray       # (3,) m, on the array surface
    normal: np.ndarray      # (3,) unit outward surface normal at the point
    axis: np.ndarray        # (3,) unit, cylinder axis in the tangent plane
    active: bool


class PressureModel:
    """Taxel load fractions of a plate pressed on one array."""

    def __init__(self, positions: np.ndarray, plate: Plate,
                 stiffness: float = FOUNDATION_STIFFNESS, spread: float = SPREAD_SIGMA) -> None:
        self.positions = np.asarray(positions, np.float64)
        self.plate = plate
        self.stiffness = float(stiffness)
        dist2 = np.sum((self.positions[:, None] - self.positions[None]) ** 2, axis=-1)
        kernel = np.exp(-0.5 * dist2 / spread ** 2)
        self.kernel = kernel / kernel.sum(axis=0, keepdims=True)   # columns conserve load
        self._active_counts = np.arange(1, len(self.positions) + 1)   # m = 1 .. n
        self.depth = 0.0

    def gaps(self, contact: Contact) -> np.ndarray:
        """(n,) m: gap between the indenter and the array surface above each taxel."""
        d = self.positions - contact.point
        height = d @ contact.normal                 # <= 0 where the array curves away
        tangent = d - height[:, None] * contact.normal
        if self.plate.shape == 'sphere':
            surface = np.add.reduce(tangent ** 2, axis=1) / (2.0 * self.plate.radius)
        elif self.plate.shape == 'cylinder':
            across = tangent @ cross(contact.normal, contact.axis)
            surface = across ** 2 / (2.0 * self.plate.radius)
        else:
            surface = np.zeros(len(d))
        return surface - height

    def weights(self, contact: Contact) -> np.ndarray:
        """(n,) load fractions (sum 1) for the contact's normal force; zeros when inactive."""
        normal_force = float(contact.force @ contact.normal)
        if not contact.active or normal_force <= 0.0:
            self.depth = 0.0
            return np.zeros(len(self.positions))
        gap = self.gaps(contact)
        gap = gap - np.minimum.reduce(gap)
        order = np.sort(gap)
        # With the m smallest gaps active: depth_m = (F/k + sum of those gaps) / m; the right m
        # is the largest whose m-th gap lies below its depth. (add.accumulate is np.cumsum, and
        # add.reduce np.sum, without their Python wrappers: this runs on every tactile frame.)
        depth = (normal_force / self.stiffness + np.add.accumulate(order)) / self._active_counts
        count = int(np.count_nonzero(order < depth))
        self.depth = float(depth[max(count, 1) - 1])
        load = self.kernel @ np.maximum(self.depth - gap, 0.0)
        return load / np.add.reduce(load)
