"""M3-lambda: M3 fitted by damped least squares (paper Sec. IV-A, lambda = 33).

With `lambda_grid` the damping is instead chosen by leave-one-plate-out cross-validation over the
plates given to fit() (the training plates only), so a held-out test plate never influences it.
One SVD per inner fold serves the whole grid (least_squares.CentredSVD), and one QR per plate
serves every inner fold and the final fit (least_squares.GroupFactors).

The damping multiplies ||W||^2 next to the residual SUM of squares (not the mean), as in the
paper's damped least squares, so its effect shrinks as the number of samples grows.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.base import check_inputs
from tacforce_ros.estimation.least_squares import GroupFactors
from tacforce_ros.estimation.m3_linear import M3Linear

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray

PAPER_LAMBDA = 33.0
DEFAULT_GRID = tuple(float(v) for v in np.logspace(-3, 5, 17))


def select_damping(phi: np.ndarray, F: np.ndarray, groups: np.ndarray,
                   grid: Sequence[float], factors: GroupFactors | None = None
                   ) -> tuple[float, np.ndarray]:
    """Damping with the lowest mean leave-one-group-out MAE; returns (lambda, MAE per lambda).
    `factors`: GroupFactors of (phi, F, groups), when the caller has them."""
    groups = np.asarray(groups)
    factors = GroupFactors(phi, F, groups) if factors is None else factors
    if len(factors.labels) < 2:
        raise ValueError(f'nested damping selection needs >= 2 plates in the training data, '
                         f'got {factors.labels}')
    scores = np.zeros(len(grid))
    for label in factors.labels:
        held = groups == label
        svd = factors.svd([other for other in factors.labels if other != label])
        for j, lam in enumerate(grid):
            coef, intercept = svd.solve(lam)
            scores[j] += np.abs(phi[held] @ coef.T + intercept - F[held]).mean()
    scores /= len(factors.labels)
    return float(grid[int(np.argmin(scores))]), scores


class M3Lambda(M3Linear):
    kind = 'M3-lambda'
    needs_groups = True

    def __init__(self, array: TaxelArray, lam: float = PAPER_LAMBDA,
                 lambda_grid: Sequence[float] | None = None) -> None:
        super().__init__(array)
        if not (np.isfinite(lam) and lam >= 0.0):
            raise ValueError(f'lam must be finite and >= 0, got {lam}')
        self.damping = float(lam)
        self.lambda_grid = None if lambda_grid is None else tuple(float(v) for v in lambda_grid)
        self.lambda_scores_: np.ndarray | None = None

    def fit(self, X: np.ndarray, F: np.ndarray, groups: np.ndarray | None = None) -> M3Lambda:
        if self.lambda_grid is not None:
            if groups is None or len(groups) != len(X):
                raise ValueError('M3-lambda with lambda_grid needs groups (plate per sample)')
            X = check_inputs(X, self.array.n_taxels, F)
            self.learn_features(X)
            phi, F = self.features(X), np.asarray(F, dtype=np.float64)
            factors = GroupFactors(phi, F, groups)
            self.damping, self.lambda_scores_ = select_damping(phi, F, groups,
                                                               self.lambda_grid, factors)
            # The fit on every training plate: their factors together, no pass over the rows.
            self.coef_, self.intercept_ = factors.svd(factors.labels).solve(self.damping)
            return self
        return super().fit(X, F)

    def hyperparameters(self) -> dict:
        return {'lam': self.damping, 'lambda_grid': None if self.lambda_grid is None
                else list(self.lambda_grid)}
