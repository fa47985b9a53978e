"""Mechanics and magnetics of a magnetic tactile taxel: the pieces a uSkin reading is made of.

A uSkin taxel is a small magnet in a silicone layer over a 3-axis Hall chip (Tomo et al. 2018).
An indenter presses the layer; the pressure under it (Hertz) displaces the elastomer around the
magnet (point loads summed over the contact patch, each displacing a layer bonded to the chip's
board: sim/elastic_layer.py); the column under the magnet stiffens as it is squeezed; the chip
reads the displaced magnet's field (the elastomer's creep and hysteresis:
sim/elastomer_memory.py). Formulas: K. L. Johnson, Contact Mechanics (1985), chapter 4 (Hertz,
the approximate ellipse ratio); J. D. Jackson, Classical Electrodynamics (1999), sec. 5.5 and
5.8 (a circular current loop's field, the equivalent surface current of a uniformly magnetised
body). Parameter values live with their sources in docs/SKIN_PHYSICS.md and in
sim/effects/magnetic_skin.py; this module holds no numbers of the hardware.
"""
from __future__ import annotations

import numpy as np
from scipy.special import ellipe, ellipk

MU0 = 4e-7 * np.pi   # T m / A
# Gauss-Legendre loops along a magnet's length: 8 reproduce the closed-form axial field to
# 1e-9 from one magnet length beyond its face outwards (test_sim_skin_physics.py); nearer, the
# chip reads beyond its range on this skin.
CYLINDER_LOOPS = 8
# Within this fraction of a loop's radius from its axis, B_rho is its axial series: the closed
# form's bracket cancels there (it vanishes as rho^2, so its rounding grows as (radius / rho)^2),
# while the series is exact to (rho / radius)^2; at 1e-4 both are within 1e-8 of B_rho.
NEAR_AXIS = 1e-4
_LOOP_NODES, _LOOP_WEIGHTS = np.polynomial.legendre.leggauss(CYLINDER_LOOPS)


def loop_field(radius: float, current: float | np.ndarray, rho: np.ndarray,
               z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B_rho, B_z) T of a circular loop of `radius` (m) carrying `current` (A) about the z axis
    in the plane z = 0, at distance `rho` from the axis and height `z` (m), off the wire: the
    closed form in complete elliptic integrals (Jackson 1999, sec. 5.5; in the form of Simpson et
    al., NASA/TP-2001-210605: r^2 = rho^2 + z^2, alpha^2 = a^2 + r^2 - 2 a rho,
    beta^2 = a^2 + r^2 + 2 a rho, k^2 = 1 - alpha^2 / beta^2). Near the axis B_rho is
    -rho / 2 dB_z/dz of the axial field B_z = mu0 I a^2 / (2 (a^2 + z^2)^(3/2)) (div B = 0)."""
    rho, z = np.asarray(rho, np.float64), np.asarray(z, np.float64)
    r2 = rho * rho + z * z
    alpha2 = radius * radius + r2 - 2.0 * radius * rho
    beta2 = radius * radius + r2 + 2.0 * radius * rho
    beta = np.sqrt(beta2)
    m = 1.0 - alpha2 / beta2
    big_k, big_e = ellipk(m), ellipe(m)
    scale = MU0 * current / (2.0 * np.pi * alpha2 * beta)
    b_z = scale * ((radius * radius - r2) * big_e + alpha2 * big_k)
    near_axis = rho < NEAR_AXIS * radius
    if not near_axis.any():
        return scale * z / rho * ((radius * radius + r2) * big_e - alpha2 * big_k), b_z
    closed = scale * z / np.where(near_axis, 1.0, rho) * (
        (radius * radius + r2) * big_e - alpha2 * big_k)
    series = 0.75 * MU0 * current * radius * radius * z * rho / (
        radius * radius + z * z) ** 2.5
    return np.where(near_axis, series, closed), b_z


def cylinder_field(remanence: float, diameter: float, length: float,
                   offset: np.ndarray) -> np.ndarray:
    """(..., 3) T: field of a cylinder magnet uniformly magnetised along +z (remanence T,
    diameter and length m) at `offset` (m) from its centre, in the magnet's frame. Uniform
    magnetisation M = B_r / mu0 is a surface current M per unit length on the side (Jackson
    1999, sec. 5.8): loops summed by Gauss-Legendre along the length. Far away it is the point
    dipole of moment M x volume."""
    offset = np.asarray(offset, np.float64)
    rho = np.hypot(offset[..., 0], offset[..., 1])
    # The current loops along a last axis, summed.
    radial, axial = loop_field(0.5 * diameter, remanence / MU0 * 0.5 * length * _LOOP_WEIGHTS,
                               rho[..., None], offset[..., 2, None] - 0.5 * length * _LOOP_NODES)
    b_rho, b_z = radial.sum(axis=-1), axial.sum(axis=-1)
    lateral = np.where(rho > 0.0, b_rho / np.where(rho > 0.0, rho, 1.0), 0.0)
    return np.stack([lateral * offset[..., 0], lateral * offset[..., 1], b_z], axis=-1)


def neo_hookean_stretch(linear_strain: np.ndarray) -> np.ndarray:
    """Stretch (current over rest length) of an incompressible neo-Hookean column under the
    uniaxial nominal stress that would strain it by `linear_strain` (negative: compressed) in
    linear elasticity of the same Young's modulus E: mu (lam - lam^-2) = E e with mu = E / 3
    (Ogden, Non-Linear Elastic Deformations, 1984, the uniaxial load of an incompressible
    neo-Hookean solid), i.e. lam^3 - 3 e lam^2 - 1 = 0. It equals 1 + e to first order, stiffens
    in compression (lam > 0 under any load; at half its length it carries 7/3 of the linear
    stress) and softens in tension.

    The cubic's one positive root in closed form (with lam = e + y it is y^3 - 3 e^2 y -
    (2 e^3 + 1) = 0): for e^3 >= -1/4 Cardano's, lam = e + u + e^2 / u with
    u^3 = e^3 + 1/2 + sqrt(e^3 + 1/4), which has no cancelling difference; squeezed harder,
    three real roots and the trigonometric form, written with asin so that it stays exact as
    e^3 grows (lam = -e (sqrt(3) sin phi - 2 sin^2(phi / 2)), phi = 2/3 asin(sqrt(-1 / (4 e^3)))).
    The Newton iteration it replaced agreed to 8e-16 relative over |e| <= 1000 and took 2.6x
    as long on a fingertip's 30 taxels (the magnetic skin calls it every frame)."""
    strain = np.asarray(linear_strain, np.float64)
    cube = strain * strain * strain
    one_root = cube >= -0.25
    u = np.cbrt(cube + 0.5 + np.sqrt(np.where(one_root, cube + 0.25, 0.0)))
    cardano = strain + u + strain * strain / np.where(one_root, u, 1.0)
    if one_root.all():
        return cardano
    sine = np.sqrt(np.where(one_root, 1.0, -0.25 / np.where(one_root, -1.0, cube)))
    phi = (2.0 / 3.0) * np.arcsin(np.minimum(sine, 1.0))
    trig = -strain * (np.sqrt(3.0) * np.sin(phi) - 2.0 * np.sin(0.5 * phi) ** 2)
    return np.where(one_root, cardano, trig)


def hertz_semi_axes(normal_force: float, curvatures: tuple[float, float],
                    contact_modulus: float) -> tuple[float, float]:
    """(a, b) m: semi-axes of the Hertz contact ellipse along the two principal directions of
    relative curvature (1/m, both > 0) for a rigid indenter on a body of contact modulus
    E* = E / (1 - nu^2). Equivalent radius R_e = 1 / sqrt(k1 k2), sqrt(a b) = (3 P R_e /
    (4 E*))^(1/3), and the ratio from Johnson's approximation b / a = (k1 / k2)^(2/3)
    (1985, eq. 4.33b): the ellipse is longer along the direction of smaller curvature."""
    k1, k2 = curvatures
    if k1 <= 0.0 or k2 <= 0.0:
        raise ValueError(f'Hertz contact needs both curvatures > 0, got {k1}, {k2}')
    mean = (3.0 * normal_force / (4.0 * contact_modulus * np.sqrt(k1 * k2))) ** (1.0 / 3.0)
    ratio = (k1 / k2) ** (1.0 / 3.0)      # sqrt of b / a
    return mean / ratio, mean * ratio


def line_contact_half_width(normal_force: float, length: float, curvature: float,
                            contact_modulus: float) -> float:
    """m: half-width of the Hertz line contact of a cylinder (curvature 1/m across it) pressed
    over `length` m: a = sqrt(4 P R / (pi L E*)) (Johnson 1985, eq. 4.43)."""
    return float(np.sqrt(4.0 * normal_force / (np.pi * length * curvature * contact_modulus)))


def elliptic_patch(n_rings: int = 6, n_spokes: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Points (k, 2) in the unit disk and weights (k,) summing to 1 that sample the Hertz
    pressure sqrt(1 - r^2): scaled by the semi-axes they sample an elliptic contact, and with
    one axis collapsed onto a line they sample a line contact. Midpoint rings of equal width."""
    edges = np.linspace(0.0, 1.0, n_rings + 1)
    radii = 0.5 * (edges[1:] + edges[:-1])
    angles = (np.arange(n_spokes) + 0.5) * 2.0 * np.pi / n_spokes
    points = np.stack([np.outer(radii, np.cos(angles)).ravel(),
                       np.outer(radii, np.sin(angles)).ravel()], axis=-1)
    ring_load = radii * np.sqrt(1.0 - radii ** 2) * np.diff(edges)
    weights = np.repeat(ring_load / n_spokes, n_spokes)
    return points, weights / weights.sum()


def tangent_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (t1, t2) with t1 x t2 = normal (unit)."""
    normal = np.asarray(normal, np.float64)
    seed = np.eye(3)[np.argmin(np.abs(normal))]     # the axis least along the normal
    t1 = seed - (seed @ normal) * normal
    t1 /= np.sqrt(t1 @ t1)
    # normal x t1 written out: np.cross costs 50 us on one pair, and this runs every frame.
    (nx, ny, nz), (ax, ay, az) = normal.tolist(), t1.tolist()
    return t1, np.array([ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax])


def skin_curvature(positions: np.ndarray, normals: np.ndarray, point: np.ndarray,
                   normal: np.ndarray, reach: float,
                   basis: np.ndarray | None = None) -> np.ndarray:
    """(2, 2) 1/m: curvature tensor of the skin at `point` in the basis tangent_basis(normal)
    (or `basis`, (2, 3), when the caller has it), from its taxels (positions (n, 3), unit
    outward normals (n, 3)) within about `reach`: the shape operator S with dn = S dp, fitted by
    weighted least squares over the taxels' offsets and symmetrised. A sphere of radius R gives
    I / R, a plane 0, a cylinder 1/R across its axis only."""
    if basis is None:
        basis = np.stack(tangent_basis(normal))
    offset = (np.asarray(positions, np.float64) - point) @ basis.T          # (n, 2)
    turn = (np.asarray(normals, np.float64) - normal) @ basis.T             # (n, 2)
    weight = np.sqrt(np.exp(-0.5 * np.sum(offset ** 2, axis=1) / reach ** 2))[:, None]
    if np.count_nonzero(weight > 1e-3) < 3:
        return np.zeros((2, 2))
    design, target = weight * offset, weight * turn
    # Two unknowns per column: the normal equations, solved in closed form, unless the taxels
    # about the point lie nearly on a line (then least squares takes the minimum-norm fit).
    (g00, g01), (_, g11) = (design.T @ design).tolist()
    det = g00 * g11 - g01 * g01
    if det > 1e-8 * (g00 + g11) ** 2:
        solution = np.array([[g11, -g01], [-g01, g00]]) @ (design.T @ target) / det
    else:
        solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    return 0.5 * (solution + solution.T)
