"""M1: rotation-assisted linear model (paper eq. 1, 4): f = A z + b, z = sum_i R_i^0 x_i, p = 12."""
from __future__ import annotations

import numpy as np

from tacforce_ros.estimation.affine import LinearInputModel


def rotated_sum(X: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """z = sum_i R_i^0 x_i: (N, n, 3) taxel inputs -> (N, 3) total activity in {S0}."""
    return np.einsum('nij,Nnj->Ni', rotations, X)


class M1Linear(LinearInputModel):
    kind = 'M1'

    def features(self, X: np.ndarray) -> np.ndarray:
        return rotated_sum(X, self.array.rotations)

    def input_weights(self) -> np.ndarray:
        coef, _ = self._fitted()
        # A z = A sum_i R_i x_i = sum_i (A R_i) x_i
        return np.einsum('ab,nbc->anc', coef, self.array.rotations)
