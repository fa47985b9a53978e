"""Affine (damped) least squares via one SVD of the centred design.

min_W,b ||Phi W^T + b - F||^2 + lam ||W||^2. Centring the design and the targets makes the bias
exact and unpenalised; the SVD Phi_c = U S V^T gives every damping at the cost of one
decomposition: W^T = V diag(s / (s^2 + lam)) U^T F_c. No normal equations, no inverse.

The design is tall (10^5 samples, <= 10^2 features), so the SVD is taken of a triangular factor
instead: R of a QR of [1 | Phi | F]. Its first row holds sqrt(N) times the means (the ones
column's), and below it sits the factor of the centred [Phi_c | F_c]: Phi_c = Q1 R11 and
F_c = Q1 R12 + (orthogonal rest), so Phi_c has R11's singular values and right vectors and
U^T F_c = U11^T R12, with Q and the tall U never formed. Same solution to rounding. On
160 000 x 90, each of two processes running at once as the main job's workers do (2026-11-26):
numpy's SVD of the tall matrix 3.0 s, one QR 1.5 s. A QR by blocks of 2048 rows (TSQR) was
faster alone (0.32 against 0.76 s, one thread) but 9.2 s there: each small LAPACK call makes
OpenBLAS's threads meet, and two processes' threads on two cores wait on each other.

The factors of disjoint sets of rows, stacked and factorised again, give the factor of their
union. So leave-one-group-out folds over the same design (M3-lambda's damping selection) take one
QR per group, a few large calls, and each fold's factor from its groups' (`GroupFactors`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def augmented_factor(phi: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Upper-triangular R of a QR of [1 | phi | F], (min(N, p + 4), p + 4)."""
    phi = np.asarray(phi, dtype=np.float64)
    F = np.asarray(F, dtype=np.float64)
    if phi.shape[0] == 0:
        raise ValueError('cannot fit on zero samples')
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(F))):
        raise ValueError('design or targets contain NaN or Inf')
    return np.linalg.qr(np.hstack([np.ones((len(phi), 1)), phi, F]), mode='r')


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
        return cls.of_factor(augmented_factor(phi, F))

    @classmethod
    def of_factor(cls, r: np.ndarray) -> CentredSVD:
        """From augmented_factor's triangular R of [1 | phi | F]."""
        p = r.shape[1] - 4
        means = r[0, 1:] / r[0, 0]       # the ones column's row: sqrt(N) times the means
        centred = r[1:, 1:]              # the factor of [phi_c | F_c]
        u, s, vt = np.linalg.svd(centred[:p, :p], full_matrices=False)
        return cls(phi_mean=means[:p], f_mean=means[p:], s=s, vt=vt,
                   utf=u.T @ centred[:p, p:])

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


class GroupFactors:
    """One augmented factor per group of rows (e.g. per plate): the SVD of any union of
    groups from their factors, without another pass over the rows."""

    def __init__(self, phi: np.ndarray, F: np.ndarray, groups: np.ndarray) -> None:
        groups = np.asarray(groups)
        self.labels = list(dict.fromkeys(groups.tolist()))
        self._factors = {label: augmented_factor(phi[groups == label], F[groups == label])
                         for label in self.labels}

    def svd(self, labels) -> CentredSVD:
        stacked = np.vstack([self._factors[label] for label in labels])
        return CentredSVD.of_factor(np.linalg.qr(stacked, mode='r'))
