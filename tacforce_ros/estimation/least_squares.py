"""Affine (damped) least squares via one SVD of the centred design.

min_W,b ||Phi W^T + b - F||^2 + lam ||W||^2. Centring the design and the targets makes the bias
exact and unpenalised; the SVD Phi_c = U S V^T gives every damping at the cost of one
decomposition: W^T = V diag(s / (s^2 + lam)) U^T F_c. No normal equations, no inverse.

The design is tall (10^5 samples, <= 10^2 features), so the SVD is taken of the triangular
factor of a QR of [Phi_c | F_c] instead: Phi_c = Q1 R11 and F_c = Q1 R12 + (orthogonal rest),
so Phi_c has R11's singular values and right vectors and U^T F_c = U11^T R12, with Q and the
tall U never formed. Same solution to rounding. On 160 000 x 90, each of two processes running
at once as the main job's workers do (2026-11-26): numpy's SVD of the tall matrix 3.0 s, one QR
1.5 s. A QR by blocks of 2048 rows (TSQR) was faster alone (0.32 against 0.76 s, one thread)
but 9.2 s there: each small LAPACK call makes OpenBLAS's threads meet, and two processes' threads
on two cores wait on each other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CentredSVD:
    """SVD of a centred design, kept to solve for many dampings and targets."""

    phi_mean: np.ndarray    # (p,)
    f_mean: np.ndarray      # (3,)
    s: np.ndarray           # (r,) singular values
    vt: np.ndarray          # (r, p)
    utf: np.ndarray         # (r, 3) U^T F_c

    @classmethod
    def of(cls, phi: np.ndarray, F: np.ndarray) -> CentredSVD:
        phi = np.asarray(phi, dtype=np.float64)
        F = np.asarray(F, dtype=np.float64)
        if phi.shape[0] == 0:
            raise ValueError('cannot fit on zero samples')
        if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(F))):
            raise ValueError('design or targets contain NaN or Inf')
        phi_mean = phi.mean(axis=0)
        f_mean = F.mean(axis=0)
        p = phi.shape[1]
        r = np.linalg.qr(np.hstack([phi - phi_mean, F - f_mean]), mode='r')[:p]
        u, s, vt = np.linalg.svd(r[:, :p], full_matrices=False)
        return cls(phi_mean=phi_mean, f_mean=f_mean, s=s, vt=vt, utf=u.T @ r[:, p:])

    def solve(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """(coef (3, p), intercept (3,)) for damping lam >= 0 (0: minimum-norm least squares)."""
        lam = float(lam)
        if not (lam >= 0.0 and np.isfinite(lam)):
            raise ValueError(f'damping must be finite and >= 0, got {lam}')
        s = self.s
        # Singular values below numerical rank carry no information: drop them (pseudo-inverse
        # cut-off as numpy.linalg.lstsq), damped or not, so rank-deficient designs stay finite.
        keep = s > (s[0] if s.size else 0.0) * max(len(self.phi_mean), 1) * np.finfo(float).eps
        gain = np.zeros_like(s)
        gain[keep] = s[keep] / (s[keep] ** 2 + lam)
        coef = (self.vt.T @ (gain[:, None] * self.utf)).T
        return coef, self.f_mean - coef @ self.phi_mean


def fit_affine(phi: np.ndarray, F: np.ndarray, lam: float = 0.0
               ) -> tuple[np.ndarray, np.ndarray]:
    """Affine least squares F ~ phi @ coef.T + intercept, damping lam on coef only."""
    return CentredSVD.of(phi, F).solve(lam)
