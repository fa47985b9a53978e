"""M2: rotation-assisted quadratic model (paper eq. 5): f = A z' + b, p = 30.

z' = [z1, z2, z3, z1^2, z2^2, z3^2, z1 z2, z2 z3, z1 z3] with z = sum_i R_i^0 x_i. z is the sum of
n standardised inputs, so it is divided by its training std (z_scale_) before squaring: the
quadratic columns then stay O(1) on training data and the design stays well conditioned; large
inputs grow quadratically but finitely in float64. z_scale_ is a normalisation, not counted in p.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.affine import AffineModel
from tacforce_ros.estimation.base import ForceModel
from tacforce_ros.estimation.m1_rotation_linear import rotated_sum

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray


def quadratic_features(z: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 9) in the paper's order."""
    z1, z2, z3 = z[..., 0], z[..., 1], z[..., 2]
    return np.stack([z1, z2, z3, z1 * z1, z2 * z2, z3 * z3, z1 * z2, z2 * z3, z1 * z3], axis=-1)


class M2Quadratic(AffineModel):
    kind = 'M2'

    def __init__(self, array: TaxelArray) -> None:
        super().__init__(array)
        self.z_scale_: np.ndarray | None = None

    def learn_features(self, X: np.ndarray) -> None:
        std = rotated_sum(X, self.array.rotations).std(axis=0)
        self.z_scale_ = np.where(std > 1e-12, std, 1.0)

    def features(self, X: np.ndarray) -> np.ndarray:
        scale = np.ones(3) if self.z_scale_ is None else self.z_scale_
        return quadratic_features(rotated_sum(X, self.array.rotations) / scale)

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {**super().state_arrays(), 'z_scale_': self.z_scale_}

    def state_names(self) -> tuple[str, ...]:
        return ('coef_', 'intercept_', 'z_scale_')

    @classmethod
    def compile_batch(cls, models: Sequence[ForceModel]) -> Callable[[np.ndarray], np.ndarray]:
        k = len(models)
        n_max = max(m.array.n_taxels for m in models)
        # Rotations divided by z_scale_, stacked as one (k, 3, 3 n_max) map x -> z / z_scale.
        project = np.zeros((k, 3, n_max, 3))
        for i, model in enumerate(models):
            project[i, :, :model.array.n_taxels] = (
                model.array.rotations.transpose(1, 0, 2) / model.z_scale_[:, None, None])
        project = project.reshape(k, 3, 3 * n_max)
        coef = np.stack([m.coef_ for m in models])
        bias = np.stack([m.intercept_ for m in models])

        def predict_batch(X: np.ndarray) -> np.ndarray:
            X = X[:, :n_max]        # wider input: the extra columns are zero padding
            z = np.matmul(project, X.reshape(k, -1, 1))[..., 0]
            return np.matmul(coef, quadratic_features(z)[..., None])[..., 0] + bias

        return predict_batch
