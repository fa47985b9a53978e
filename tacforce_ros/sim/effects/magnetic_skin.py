"""The magnetic skin: each taxel's counts from its physics instead of the empirical response.

Per frame: the Hertz pressure of the plate on the skin (relative curvature of plate and skin at
the contact, the skin's from the hand description's taxels), sampled as point loads carrying the
contact force (shear in proportion to pressure); the displacement of each magnet relative to
its chip from those loads (the exact solution for a layer bonded to the chip's board); the
elastomer's creep and hysteresis; the field of the displaced magnet (a uniformly magnetised
cylinder) at the chip, converted to counts by the chip's sensitivity. Pieces:
sim/skin_physics.py, sim/elastic_layer.py. Parameter sources: docs/SKIN_PHYSICS.md.

A hand's arrays differ as modules do: each magnet its own remanence within its grade and its own
place (from its drawn rest reading), each array its own layer thickness and elastomer modulus,
drawn once per hand (sensor seed).

It supersedes what the empirical chain stood in for: the foundation-spring pressure weights
and the tanh response (sim/contact.py, sim/taxel_response.py), `taxel_variation` (here the
spread of rest readings and gains comes from where each magnet sits), `deformation` (the
displacement field turns and shifts what each taxel reads on a curved skin) and `hysteresis`
(its own creep and play). A scene naming one of those beside it is refused. The chip's noise
and temperature effects (`taxel_noise`, `temperature_drift`) and `crosstalk` act on its counts
as before.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from tacforce_ros.sim import skin_physics as phys
from tacforce_ros.sim.effects import Effect
from tacforce_ros.sim.elastic_layer import BondedLayer
from tacforce_ros.sim.elastomer_memory import Creep, Play
from tacforce_ros.sim.taxel_response import CHIP_ZERO

# The chip reads +/- 22000 counts about its zero at most (MLX90393 datasheet, Table 21, RES_XYZ 2).
CHIP_RANGE = 22000.0
# A principal relative curvature below this counts as flat: a 1 N Hertz contact on this
# elastomer would be wider than an array (semi-axis ~9 mm at 10 /m). The fingertip is 74 /m.
FLAT_CURVATURE = 10.0         # 1/m
# A line contact's pressure along its line is tabulated once per location over these offsets
# across it (m); the half-width of the edge and fillet plates stays inside at the operator's forces.
LINE_REACH = 0.003
LINE_TABLE_STEP = 0.00005
LINE_PROFILE = (np.arange(8) + 0.5) / 4.0 - 1.0   # across-line sample points, in half-widths
# Newton steps placing a magnet where its field reads the rest value (5 on the shipped hand).
PLACEMENT_ITERATIONS = 20
# The parameters without a source (docs/SKIN_PHYSICS.md): skin_sensitivity varies these. The
# field scales with the remanence as with 1 / the chip's sensitivities, which stand for it.
ESTIMATES = ('magnet_diameter', 'magnet_thickness', 'layer_thickness', 'youngs_modulus', 'poisson',
             'sensitivity_xy', 'sensitivity_z', 'play_relative', 'play_width',
             'creep_share', 'creep_time_constant', 'module_layer_spread', 'module_modulus_spread')


@functools.lru_cache(maxsize=64)
def bonded_layer(thickness: float, shear_modulus: float, poisson: float,
                 depths: bytes) -> BondedLayer:
    """The layer of an array, by its magnets' depths (float64 bytes): tabulated once per
    process (0.2-0.4 s each), not again with every simulator of a main job's worker."""
    return BondedLayer(thickness, shear_modulus, poisson, np.frombuffer(depths, np.float64))


class SkinPlacementError(ValueError):
    """The parameters put a magnet outside its layer."""


@dataclass
class MagneticSkin(Effect):
    name = 'magnetic_skin'
    supersedes: ClassVar[tuple[str, ...]] = ('taxel_variation', 'deformation', 'hysteresis')
    # Values and sources: docs/SKIN_PHYSICS.md, which marks each as sourced or an estimate.
    magnet_diameter: float = 0.002          # m, estimate
    magnet_thickness: float = 0.0005        # m, estimate
    remanence: float = 1.345                # T, N45 sintered NdFeB (grade an estimate)
    # Each magnet's remanence anywhere in its grade's window, 1.32-1.37 T (uniform: estimate).
    remanence_spread: float = 0.025         # T, +/- about `remanence`
    layer_thickness: float = 0.005          # m, skin surface to the chip's board, estimate
    youngs_modulus: float = 87e3            # Pa, Ecoflex 00-50 (grade an estimate)
    poisson: float = 0.49                   # estimate (near-incompressible silicone)
    sensitivity_xy: float = 3.004e-6        # T per count, MLX90393 RES 2, GAIN_SEL 0 (estimate)
    sensitivity_z: float = 4.840e-6         # T per count, same setting
    rest_z_range: tuple[float, float] = (33600.0, 37600.0)   # counts at rest (docs/PROTOCOLS.md)
    rest_xy_spread: float = 1350.0          # counts, +/- mid-scale at rest (docs/PROTOCOLS.md)
    # Counts the readout adds to X and Y, the same on every taxel: 0 as XELA's recordings of
    # the Allegro skin rest (docs/PROTOCOLS.md); the public 4x4 modules of imanlab's recordings
    # rest near +16,032 / -16,368 (docs/SKIN_PHYSICS.md). Readings still clip at 0 and 65,535.
    readout_offset_xy: tuple[float, float] = (0.0, 0.0)
    # Play on the displacement: uSkin's loop is 10 % of its normal force range (Tomo 2018); a
    # half-width of 5 % of the displacement is our estimate of what gives it, beside creep.
    play_relative: float = 0.05
    play_width: float = 1e-6                # m, estimate
    creep_share: float = 0.1                # estimate
    creep_time_constant: float = 1.0        # s, estimate
    # No two modules are cast alike: each array's layer thickness and elastomer modulus are
    # its own, lognormal about the values above with these relative spreads (estimates: a cast
    # 5 mm layer within +/- 0.25 mm, a silicone's batch and cure within +/- 10 %).
    module_layer_spread: float = 0.05
    module_modulus_spread: float = 0.1

    def __post_init__(self) -> None:
        if not 0.0 <= self.remanence_spread < self.remanence:
            raise ValueError('magnetic_skin: remanence_spread must lie in [0, remanence)')
        if self.module_layer_spread < 0.0 or self.module_modulus_spread < 0.0:
            raise ValueError('magnetic_skin: module spreads must be >= 0')
        self._sensitivity = np.array([self.sensitivity_xy, self.sensitivity_xy,
                                      self.sensitivity_z])
        self._zero = CHIP_ZERO + np.array([*self.readout_offset_xy, 0.0])
        self.creep = Creep(self.creep_share, self.creep_time_constant)
        self.play = Play(self.play_relative, self.play_width)
        self._patch = phys.elliptic_patch()

    # -- the hand: where each magnet sits ------------------------------------------------------

    def field(self, position: np.ndarray, rows=slice(None)) -> np.ndarray:
        """(n, 3) T at the chips of the magnets `rows` (of the hand's taxels) centred at
        `position` (n, 3) m from them; each magnet's remanence is its own."""
        return phys.cylinder_field(self.remanence, self.magnet_diameter, self.magnet_thickness,
                                   -position) * self._remanence_scale[rows, None]

    def placement(self, rest: np.ndarray, rows=slice(None)
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(lateral (n, 2), height (n,)) m of the magnets `rows` whose fields read `rest`
        (n, 3) counts at their chips. Newton's method from where a point dipole of the same
        moment would read them: with the offset d = c h, B_xy / B_z = 3 c_xy / (2 - |c|^2) and
        B_z = mu0 m (2 - |c|^2) / (4 pi h^3 (1 + |c|^2)^(5/2)). Near its chip a disc as thin as
        this one reads less than its dipole at the same place, so it sits a little closer.
        Done when the field reads the rest value to 1e-12 of it."""
        target = (np.asarray(rest, np.float64) - CHIP_ZERO) * self._sensitivity
        if np.any(target[:, 2] <= 0.0):
            raise ValueError('rest Z counts must lie above the chip zero (the magnet above it)')
        ratio = target[:, :2] / target[:, 2:]
        # |c| solves |r| |c|^2 + 3 |c| - 2 |r| = 0, taken in its cancellation-free form.
        r2 = np.sum(ratio * ratio, axis=1, keepdims=True)
        c = ratio * 4.0 / (3.0 + np.sqrt(9.0 + 8.0 * r2))
        c2 = np.sum(c * c, axis=1)
        moment = self.remanence * self._remanence_scale[rows] * np.pi \
            * (0.5 * self.magnet_diameter) ** 2 * self.magnet_thickness / phys.MU0
        height = (phys.MU0 * moment * (2.0 - c2)
                  / (4.0 * np.pi * target[:, 2] * (1.0 + c2) ** 2.5)) ** (1.0 / 3.0)
        position = np.column_stack([c * height[:, None], height])
        # Central differences for the Jacobian: their error is (step / distance)^2, ~1e-12.
        step = 1e-6 * self.magnet_diameter
        tolerance = 1e-12 * np.linalg.norm(target, axis=1)
        for _ in range(PLACEMENT_ITERATIONS):
            residual = target - self.field(position, rows)
            if np.all(np.linalg.norm(residual, axis=1) <= tolerance):
                return position[:, :2], position[:, 2]
            jacobian = np.stack([(self.field(position + step * axis, rows)
                                  - self.field(position - step * axis, rows)) / (2.0 * step)
                                 for axis in np.eye(3)], axis=-1)
            try:
                position = position + np.linalg.solve(jacobian, residual[..., None])[..., 0]
            except np.linalg.LinAlgError:
                break
        raise SkinPlacementError(
            f'magnetic_skin: no magnet place reads the rest values within '
            f'{PLACEMENT_ITERATIONS} Newton steps: these magnet and chip parameters do not fit '
            'the measured rest readings')

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        """Each module's layer and elastomer, each magnet's remanence, and where each magnet
        sits: at the place whose field reads a rest value drawn from the measured ranges
        (docs/PROTOCOLS.md), so a taxel's gain follows from its height and magnet as on the
        real skin, and an array's from its module."""
        n = ctx.n_taxels
        rest = np.column_stack([
            CHIP_ZERO + rng.uniform(-self.rest_xy_spread, self.rest_xy_spread, (n, 2)),
            rng.uniform(*self.rest_z_range, n)])
        # Drawn after the rest readings, which then stay those of a hand without these spreads.
        self._remanence_scale = 1.0 + rng.uniform(-1.0, 1.0, n) * (self.remanence_spread
                                                                    / self.remanence)
        modules = len(ctx.hand.arrays)
        self.module_layer = self.layer_thickness * np.exp(
            rng.normal(0.0, self.module_layer_spread, modules))
        self.module_modulus = self.youngs_modulus * np.exp(
            rng.normal(0.0, self.module_modulus_spread, modules))
        self._module_of = np.asarray(ctx.array_of_taxel)
        self.lateral, self.height = self.placement(rest)
        top = self.height + 0.5 * self.magnet_thickness
        over = np.argmax(top - self.module_layer[self._module_of])
        if top[over] >= self.module_layer[self._module_of[over]]:
            raise SkinPlacementError(
                f'magnetic_skin: a magnet must reach {top[over] * 1e3:.2f} mm above its chip to '
                f'read the rest values, above its module\'s '
                f'{self.module_layer[self._module_of[over]] * 1e3:.2f} mm layer: these magnet, '
                'chip and layer parameters do not fit the measured rest readings')
        bottom = self.height.min() - 0.5 * self.magnet_thickness
        if bottom <= 0.0:
            raise SkinPlacementError(
                f'magnetic_skin: a magnet\'s lower face must sit {bottom * 1e3:.2f} mm above its '
                'chip to read the rest values, not above it: these magnet and chip parameters '
                'do not fit the measured rest readings')
        self.rest_counts = self.counts_at(np.zeros((n, 3)), slice(None))

    def counts_at(self, displacement: np.ndarray, rows) -> np.ndarray:
        """(n, 3) float counts of the taxels `rows` with their magnets displaced by
        `displacement` (n, 3) m in the taxel frames (z out of the skin) as linear elasticity
        gives it. The elastomer under the magnet, a column from the board to the magnet's lower
        face, stiffens as it is squeezed (neo-Hookean; the linear solution is its small-strain
        limit), so a magnet never reaches its chip."""
        column = self.height[rows] - 0.5 * self.magnet_thickness
        squeezed = column * phys.neo_hookean_stretch(displacement[:, 2] / column)
        position = np.column_stack([self.lateral[rows] + displacement[:, :2],
                                    squeezed + 0.5 * self.magnet_thickness])
        counts = self.field(position, rows) / self._sensitivity
        return self._zero + np.minimum(np.maximum(counts, -CHIP_RANGE), CHIP_RANGE)   # np.clip

    # -- a session -------------------------------------------------------------------------------

    def reset(self, rng: np.random.Generator, ctx) -> None:
        array = ctx.array
        self._rows = ctx.rows
        self._positions = array.positions
        self._normals = array.rotations[:, :, 2]
        self._rotations = array.rotations
        self._pitch = float(np.min(np.sqrt(np.sum(
            (self._positions[:, None] - self._positions[None]) ** 2, axis=-1))
            + np.eye(array.n_taxels)))
        module = int(self._module_of[self._rows][0])
        thickness, modulus = float(self.module_layer[module]), float(self.module_modulus[module])
        self.contact_modulus = modulus / (1.0 - self.poisson ** 2)
        depth = thickness - self.height[self._rows]
        self._layer = bonded_layer(thickness, modulus / (2.0 * (1.0 + self.poisson)),
                                   self.poisson, depth.tobytes())
        self.creep.reset((array.n_taxels, 3), ctx.dt)
        self.play.reset((array.n_taxels, 3))
        self._location_key, self._location_plate = b'', None
        ctx.idle_counts = self.rest_counts

    def _location(self, contact, plate) -> None:
        """Per contact location (the operator holds one through a press): the principal
        relative curvatures and their directions, and the array's footprint along them."""
        key = (contact.point.tobytes() + contact.normal.tobytes() + contact.axis.tobytes())
        if key == self._location_key and plate is self._location_plate:
            return
        self._location_key, self._location_plate = key, plate
        t1, t2 = phys.tangent_basis(contact.normal)
        basis = np.stack([t1, t2])
        skin = phys.skin_curvature(self._positions, self._normals, contact.point,
                                   contact.normal, reach=self._pitch, basis=basis)
        if plate.shape == 'sphere':
            indenter = np.eye(2) / plate.radius
        elif plate.shape == 'cylinder':
            across = np.cross(contact.normal, contact.axis)
            direction = np.array([across @ t1, across @ t2])
            length = float(np.sqrt(direction @ direction))
            if length < 1e-6:
                raise ValueError('magnetic_skin: a cylinder plate with its axis along the '
                                 'contact normal')
            direction /= length
            indenter = np.outer(direction, direction) / plate.radius
        else:
            indenter = np.zeros((2, 2))
        curvature, axes = np.linalg.eigh(skin + indenter)
        # How far the contact can reach along each principal direction: a sphere's radius
        # both ways, a cylinder's across its axis (eigh orders the larger curvature last).
        self._plate_reach = {'sphere': (plate.radius, plate.radius),
                             'cylinder': (np.inf, plate.radius)}.get(plate.shape,
                                                                     (np.inf, np.inf))
        self._curvatures = np.maximum(curvature, 0.0)
        self._axes = axes.T @ basis                                 # (2, 3) principal directions
        # Footprint of the array along the principal directions, half a pitch beyond its taxels.
        along = (self._positions - contact.point) @ self._axes.T
        self._footprint = (along.min(axis=0) - 0.5 * self._pitch,
                           along.max(axis=0) + 0.5 * self._pitch)
        # Contact point and principal directions in each taxel's frame (_unit_influence).
        self._local_offset = np.einsum('nji,nj->ni', self._rotations,
                                       self._positions - contact.point)       # (n, 3)
        self._local_axes = np.einsum('nji,dj->ndi', self._rotations, self._axes)   # (n, 2, 3)
        self._layouts()

    def _unit_influence(self, points: np.ndarray, shares: np.ndarray) -> np.ndarray:
        """(n, 3, 3): magnet displacements relative to their chips (half-space frame, z into
        the skin) per unit load (force axis, then displacement axis) spread over `points` (k, 2)
        about the contact point by `shares` (k,). Each taxel sees the skin about it as a flat
        layer: a load point sits at its 3-D distance, in the direction it has in the taxel's
        tangent plane (a press at the fingertip's apex loads a taxel on its side partly in
        shear, and from as far as it is)."""
        # From each load point to each taxel, in the taxel's frame: R_n^T (p_n - c - P_k axes).
        offset = self._local_offset[:, None, :] - points @ self._local_axes   # (n, k, 3)
        ox, oy, oz = offset[..., 0], offset[..., 1], offset[..., 2]
        planar2 = ox * ox + oy * oy
        distance = np.sqrt(planar2 + oz * oz)
        planar = np.sqrt(planar2)
        ahead = planar > 1e-12
        inverse = np.where(ahead, -1.0 / np.where(ahead, planar, 1.0), 0.0)
        return self._layer.unit_response_at(distance, np.where(ahead, ox * inverse, 1.0),
                                            oy * inverse, shares)

    def _layouts(self) -> None:
        """Per location, the loads that do not change with the force, integrated once: a flat
        plate's uniform pressure, and a line contact's pressure along its line (a table over the
        offset across it). Points lie at most half the shallowest magnet's depth apart, so the
        sum over them stands for the integral."""
        low, high = self._footprint
        step = 0.5 * float(self._layer.depths.min())
        curved = self._curvatures > FLAT_CURVATURE
        self._flat_influence = self._line_table = None
        if curved.all():
            return
        if not curved.any():
            u, v = (np.arange(lo + 0.5 * step, hi, step) for lo, hi in zip(low, high))
            points = np.stack(np.meshgrid(u, v, indexing='ij'), axis=-1).reshape(-1, 2)
            self._flat_influence = self._unit_influence(points, np.full(len(points),
                                                                        1.0 / len(points)))
            return
        line = 0 if curved[1] else 1
        self._line_along = np.arange(low[line] + 0.5 * step, high[line], step)
        self._line = line
        self._line_across = np.arange(-LINE_REACH, LINE_REACH + 1e-12, LINE_TABLE_STEP)
        # The table's rows are filled as the contact's width reaches them: a press held at one
        # place fills a few, and a contact that moves every frame (a grasp, the closed loop)
        # computes the 16 it reads, not all 121.
        self._line_table = {}                       # offset index -> (n, 3, 3)
        self._line_length = high[line] - low[line]
        self._line_curvature = self._curvatures[1 - line]

    def _line_rows(self, indices: np.ndarray) -> np.ndarray:
        """(n, len(indices), 3, 3): the line contact's table at these offsets across the line,
        each row a line of loads at that offset (computed once per location)."""
        along, line = self._line_along, self._line
        for index in dict.fromkeys(indices.tolist()):
            if index not in self._line_table:
                points = np.zeros((len(along), 2))
                points[:, line], points[:, 1 - line] = along, self._line_across[index]
                self._line_table[index] = self._unit_influence(
                    points, np.full(len(along), 1.0 / len(along)))
        return np.stack([self._line_table[index] for index in indices.tolist()], axis=1)

    def _unit_displacement(self, normal_force: float) -> np.ndarray:
        """(n, 3, 3) for this frame's force: Hertz ellipse, line contact or flat punch."""
        if self._flat_influence is not None:
            return self._flat_influence
        if self._line_table is None:
            a, b = phys.hertz_semi_axes(normal_force, tuple(self._curvatures),
                                        self.contact_modulus)
            # Hertz needs the contact small against the plate; pressed deeper, the plate's
            # edge bounds it (the button's 2 mm radius is reached near 1 N on this elastomer).
            a, b = np.minimum((a, b), self._plate_reach)
            return self._unit_influence(self._patch[0] * (a, b), self._patch[1])
        half = min(phys.line_contact_half_width(normal_force, self._line_length,
                                                self._line_curvature, self.contact_modulus),
                   self._plate_reach[1], LINE_REACH)
        across = half * LINE_PROFILE
        shares = np.sqrt(1.0 - LINE_PROFILE ** 2)
        shares /= shares.sum()
        position = np.interp(across, self._line_across, np.arange(len(self._line_across)))
        below = np.minimum(position.astype(np.int64), len(self._line_across) - 2)
        frac = (position - below)[None, :, None, None]
        rows = (1.0 - frac) * self._line_rows(below) + frac * self._line_rows(below + 1)
        return np.einsum('j,njfd->nfd', shares, rows)

    def displacement(self, contact, plate) -> np.ndarray:
        """(n, 3) m: each magnet's displacement relative to its chip, in its taxel frame, before
        creep; zeros without a compressive contact. Shear traction follows the pressure, so
        every load point carries the same share of the contact force."""
        normal_force = float(contact.force @ contact.normal)
        if not contact.active or normal_force <= 0.0:
            return np.zeros((len(self._positions), 3))
        self._location(contact, plate)
        # contact.force is what the skin applies to the plate; the plate loads the skin with
        # its opposite. Taxel frames have z out of the skin, the half-space's z points in.
        flip = np.array([1.0, 1.0, -1.0])
        loads = -np.einsum('nji,j->ni', self._rotations, contact.force) * flip   # (n, 3)
        moved = np.einsum('nf,nfd->nd', loads, self._unit_displacement(normal_force)) * flip
        return moved

    def counts(self, contact, plate) -> np.ndarray:
        """(n, 3) float counts of the pressed array for this frame."""
        return self.counts_at(self.play(self.creep(self.displacement(contact, plate))),
                              self._rows)


EFFECT = MagneticSkin


def with_magnetic_skin(effects: dict[str, dict], **params) -> dict[str, dict]:
    """A scene's effects with the magnetic skin in place of the effects it supersedes."""
    return {MagneticSkin.name: dict(params),
            **{name: value for name, value in effects.items()
               if name not in MagneticSkin.supersedes and name != MagneticSkin.name}}


def magnetic_skin_overlay(**params) -> dict[str, dict | None]:
    """The `effects` of a scene file that extends another to put it on the magnetic skin: the
    skin, and null for each effect it supersedes (null removes an inherited entry)."""
    return {MagneticSkin.name: dict(params), **dict.fromkeys(MagneticSkin.supersedes)}
