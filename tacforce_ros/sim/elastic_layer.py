"""Point loads on an elastic layer bonded to a rigid base: the exact (Burmister) solution.

A silicone layer on a circuit board is a layer of thickness h whose base neither moves nor
slides. For a nearly incompressible elastomer this matters: the material under a load cannot
shrink, so it flows sideways towards the free surface beside the load, and a wide load meets a
stiffer layer than a narrow one. Steinbrenner's approximation (the half-space displacement at a
depth less the one at the base) ignores the base's grip and misses most of that flow.

The solution, per surface wavenumber k (Burmister 1945, J. Appl. Phys. 16:89; the same Love
strain function in Timoshenko & Goodier, Theory of Elasticity, 1970, sec. 140):
phi = (A + B z) e^{-kz} + (C + D z) e^{k(z - h)} with free surface tractions at z = 0 and zero
displacement at z = h; the in-plane shear (SH) part is G (u'' - k^2 u) = 0 with the same
boundaries. The displacement of a point load is the inverse Hankel transform over k (orders 0,
1, 2 for the load's normal, radial and shear parts), integrated numerically: at a depth z the
kernels fall as e^{-kz}, and unlike the half space's the layer's are finite at k = 0, so the
integrals converge at both ends and the response vanishes far from the load. Frame: z INTO the
material, as in skin_physics.
"""
from __future__ import annotations

import numpy as np
from scipy.special import j0, j1

# Quadrature and table resolution: the kernels at the shallowest depth z have fallen to e^-40
# at k = 40 / z; the Bessel factors oscillate with period 2 pi / r in k; the bonded layer's
# response decays exponentially with distance (at 12 h, 1e-6 of its peak).
K_MAX = 40.0              # x 1 / (shallowest depth)
K_PER_PERIOD = 16         # quadrature points per Bessel period at the table's farthest radius
R_MAX = 12.0              # x h
R_STEPS_PER_DEPTH = 10    # table points per depth of the shallowest field point
R_CHUNK = 64              # radii per block of Bessel factors (bounds the memory)
_PARTS = ('a', 'b', 'c', 'nz', 'nr')
# The response to unit loads from sums of a table times a direction factor (row: table * 5 +
# factor, factors 1, cos, sin, cos 2t, sin 2t; column: force axis * 3 + displacement axis), as
# `displacement` writes it: Fx -> (a - b cos2, -b sin2, c cos), Fy -> (-b sin2, a + b cos2,
# c sin), Fz -> (nr cos, nr sin, nz).
_RESPONSE = np.zeros((25, 9))
for _row, _column, _sign in ((0, 0, 1), (8, 0, -1), (9, 1, -1), (11, 2, 1),
                             (9, 3, -1), (0, 4, 1), (8, 4, 1), (12, 5, 1),
                             (21, 6, 1), (22, 7, 1), (15, 8, 1)):
    _RESPONSE[_row, _column] = _sign


def _love_terms(k: np.ndarray, z: np.ndarray, h: float, poisson: float,
                shear_modulus: float) -> dict[str, np.ndarray]:
    """(..., 4) rows of the Love function's terms at depth z for wavenumbers k: what each of the
    coefficients (A, B, C, D) contributes to the Hankel transforms of u_z (order 0), u_r
    (order 1), sigma_z (order 0) and tau_rz (order 1)."""
    em = np.exp(-k * z)
    ep = np.exp(k * (z - h))
    kz = k * z
    phi = np.stack([em, z * em, ep, z * ep], axis=-1)
    d1 = np.stack([-k * em, (1 - kz) * em, k * ep, (1 + kz) * ep], axis=-1)
    d2 = np.stack([k * k * em, k * (kz - 2) * em, k * k * ep, k * (kz + 2) * ep], axis=-1)
    d3 = np.stack([-k ** 3 * em, k * k * (3 - kz) * em, k ** 3 * ep, k * k * (kz + 3) * ep],
                  axis=-1)
    kk = (k * k)[..., None]
    laplacian = d2 - kk * phi
    return {'u_z': (2 * (1 - poisson) * laplacian - d2) / (2 * shear_modulus),
            'u_r': k[..., None] * d1 / (2 * shear_modulus),
            'sigma_z': (2 - poisson) * (d3 - kk * d1) - d3,
            'tau_rz': -k[..., None] * ((1 - poisson) * laplacian - d2)}


def _coefficients(k: np.ndarray, h: float, poisson: float, shear_modulus: float) -> np.ndarray:
    """(n_k, 4, 2): Love coefficients (A, B, C, D) for a unit surface pressure (column 0) and a
    unit radial shear traction (column 1), both of Hankel transform 1 / 2 pi; the base at
    depth h neither moves nor slides."""
    surface = _love_terms(k, np.zeros_like(k), h, poisson, shear_modulus)
    rhs = np.zeros((k.size, 4, 2))
    rhs[:, 0, 0] = rhs[:, 1, 1] = -1.0 / (2 * np.pi)       # traction on the body: -sigma
    base = _love_terms(k, np.full_like(k, h), h, poisson, shear_modulus)
    matrix = np.stack([surface['sigma_z'], surface['tau_rz'], base['u_z'], base['u_r']], axis=1)
    return np.linalg.solve(matrix, rhs)


def _kernels(k: np.ndarray, z: np.ndarray, h: float, poisson: float,
             shear_modulus: float) -> dict[str, np.ndarray]:
    """(n_k, n_z) Hankel-space displacements at depths z, per unit point load:
    normal load: 'nz' (u_z, order 0), 'nr' (u_r, order 1); shear load along the wave: 'sz'
    (order 1, sign folded in), 'sr' (order 0 and 2); shear across it (SH): 'sh'."""
    coeff = _coefficients(k, h, poisson, shear_modulus)                    # (n_k, 4, 2)
    terms = _love_terms(k[:, None], np.broadcast_to(z, (k.size, z.size)), h, poisson,
                        shear_modulus)
    along = {name: np.einsum('kzc,kcl->kzl', terms[name], coeff) for name in ('u_z', 'u_r')}
    # SH: sinh(k (h - z)) / (G k cosh(k h)), written to stay finite at large k h.
    kz, kh = k[:, None] * z[None], (k * h)[:, None]
    sh = (np.exp(-kz) - np.exp(kz - 2 * kh)) / ((1 + np.exp(-2 * kh)) * shear_modulus
                                                  * k[:, None])
    # A plane wave of unit shear traction is the order-1 Hankel solution of column 1 times
    # 2 pi i (a plane wave's horizontal part is -i 2 pi times its Hankel radial part): its
    # horizontal part is 2 pi u_r, its vertical part 2 pi i u_z, of which i u_z enters u_z.
    return {'nz': along['u_z'][..., 0], 'nr': along['u_r'][..., 0],
            'sz': -along['u_z'][..., 1], 'sr': 2 * np.pi * along['u_r'][..., 1], 'sh': sh}


class BondedLayer:
    """Displacements in a layer of `thickness` (m) bonded to a rigid base, at the depths
    `depths` (m, one per field point: a magnet under the surface), per surface point load.

    Tabulated over the distance from the load at construction (one to two seconds for a few dozen
    depths); `displacement` interpolates linearly."""

    def __init__(self, thickness: float, shear_modulus: float, poisson: float,
                 depths: np.ndarray) -> None:
        depths = np.asarray(depths, np.float64).ravel()
        if not (depths.size and np.all(depths > 0.0) and np.all(depths < thickness)):
            raise ValueError(f'BondedLayer: field points must lie inside the '
                             f'{thickness * 1e3:.3f} mm layer (depths {depths * 1e3} mm)')
        if not (0.0 <= poisson < 0.5 and shear_modulus > 0.0):
            raise ValueError(f'BondedLayer: Poisson ratio {poisson} outside [0, 0.5) or shear '
                             f'modulus {shear_modulus} Pa not positive')
        h = float(thickness)
        self.depths = depths
        self.r_step = float(depths.min()) / R_STEPS_PER_DEPTH
        self.radii = np.arange(0.0, R_MAX * h + self.r_step, self.r_step)
        dk = 2 * np.pi / self.radii[-1] / K_PER_PERIOD
        k = np.arange(0.5 * dk, K_MAX / depths.min(), dk)          # midpoint rule from 0
        kernel = _kernels(k, depths, h, poisson, shear_modulus)
        # Point-load displacement about the load, per unit force (see `displacement`):
        # normal: u_z = nz(r), u_r = nr(r); tangential F along x at angle theta:
        # u_x = a(r) - b(r) cos 2 theta, u_y = -b(r) sin 2 theta, u_z = c(r) cos theta.
        integrands = {'nz': (0, kernel['nz']), 'nr': (1, kernel['nr']),
                      'a': (0, (kernel['sr'] + kernel['sh']) / (4 * np.pi)),
                      'b': (2, (kernel['sr'] - kernel['sh']) / (4 * np.pi)),
                      'c': (1, kernel['sz'])}
        weights = (dk * k)[:, None]
        self.tables = {name: np.empty((depths.size, self.radii.size)) for name in integrands}
        for first in range(0, self.radii.size, R_CHUNK):
            block = slice(first, first + R_CHUNK)
            x = np.outer(self.radii[block], k)
            bessel = {0: j0(x), 1: j1(x)}
            bessel[2] = np.where(x > 0, 2 * bessel[1] / np.maximum(x, 1e-300) - bessel[0],
                                 0.0)                          # J2 by recurrence
            for name, (order, integrand) in integrands.items():
                self.tables[name][:, block] = (bessel[order] @ (weights * integrand)).T
        # For interpolation by one gather (np.take, 3x faster than fancy indexing here): per
        # table the values and the step to the next radius, over (depth, radius) pairs.
        stacked = np.stack([self.tables[name] for name in _PARTS])        # (5, depths, radii)
        step = np.zeros_like(stacked)
        step[..., :-1] = np.diff(stacked, axis=-1)
        self._knots = np.concatenate([stacked, step]).reshape(2 * len(_PARTS), -1)

    def _lookup(self, lateral: np.ndarray) -> tuple[np.ndarray, ...]:
        """From surface points at `lateral` (n, ..., 2) m off each field point's foot: the
        tables at their distances (`_tables_at`) and cos, sin of the direction from the load to
        the field point."""
        if lateral.shape[0] != self.depths.size:
            raise ValueError(f'BondedLayer: {lateral.shape[0]} field points given, '
                             f'{self.depths.size} tabulated')
        dx, dy = -lateral[..., 0], -lateral[..., 1]
        r = np.sqrt(dx * dx + dy * dy)
        safe = np.maximum(r, 1e-300)
        return (self._tables_at(r), np.where(r > 0, dx / safe, 1.0),
                np.where(r > 0, dy / safe, 0.0))

    def _tables_at(self, r: np.ndarray) -> np.ndarray:
        """(5, n, ...): the tables (a, b, c, nz, nr) of each of the n depths interpolated at the
        distances r (n, ...) m; zero beyond the table's reach."""
        position = r / self.r_step
        index = np.minimum(position.astype(np.intp), self.radii.size - 2)
        frac = position - index       # beyond the last radius, zeroed below
        flat = index + (self.radii.size * np.arange(self.depths.size)).reshape(
            (-1,) + (1,) * (r.ndim - 1))
        knots = np.take(self._knots, flat, axis=1)
        values = knots[:len(_PARTS)] + frac * knots[len(_PARTS):]
        if r.max(initial=0.0) > self.radii[-1]:
            values *= r <= self.radii[-1]
        return values

    def displacement(self, lateral: np.ndarray, force: np.ndarray) -> np.ndarray:
        """(n, ..., 3) m: displacement relative to the base at each of the n depths, from surface
        point loads `force` (..., 3) N (broadcast to (n, ..., 3)) at `lateral` (n, ..., 2) m from
        the field point's foot (both in the frame with z into the material); zero beyond the
        table's reach."""
        values, cos, sin = self._lookup(np.asarray(lateral, np.float64))
        force = np.asarray(force, np.float64)
        cos2, sin2 = cos * cos - sin * sin, 2 * sin * cos
        a, b, c, nz, nr = values
        fx, fy, fz = force[..., 0], force[..., 1], force[..., 2]
        ux = fx * (a - b * cos2) - fy * b * sin2 + fz * nr * cos
        uy = -fx * b * sin2 + fy * (a + b * cos2) + fz * nr * sin
        uz = (fx * cos + fy * sin) * c + fz * nz
        return np.stack([ux, uy, uz], axis=-1)

    def unit_response_at(self, distance: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                         shares: np.ndarray) -> np.ndarray:
        """(n, 3, 3) m/N: displacement at each depth (last axis) per unit force along each axis
        (middle axis) spread by `shares` (k,) over surface points at `distance` (n, k) m from
        each field point's foot, seen from the load in the direction (cos, sin) (n, k):
        `displacement` with a unit load along each axis, summed over the points, in one pass
        (the magnetic skin's step computes this every frame)."""
        if distance.shape[0] != self.depths.size:
            raise ValueError(f'BondedLayer: {distance.shape[0]} field points given, '
                             f'{self.depths.size} tabulated')
        return self._unit_response(self._tables_at(distance), cos, sin,
                                   np.asarray(shares, np.float64))

    def _unit_response(self, values: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                       shares: np.ndarray) -> np.ndarray:
        # Per depth, the tables times [1, cos, sin, cos 2t, sin 2t] summed over the points
        # with their shares: one (5, k) @ (k, 5) product, of which 8 entries make the response.
        n, k = cos.shape
        trig = np.empty((n, k, 5))
        trig[..., 0] = 1.0
        trig[..., 1], trig[..., 2] = cos, sin
        trig[..., 3] = cos * cos - sin * sin
        trig[..., 4] = 2.0 * sin * cos
        sums = np.matmul((values * shares).transpose(1, 0, 2), trig).reshape(n, 25)
        return (sums @ _RESPONSE).reshape(n, 3, 3)
