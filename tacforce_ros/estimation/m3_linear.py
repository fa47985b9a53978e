"""M3: raw-input linear model (paper eq. 6): f = A x + b over all 3n taxel inputs, p = 9n + 3."""
from __future__ import annotations

import numpy as np

from tacforce_ros.estimation.affine import LinearInputModel


class M3Linear(LinearInputModel):
    kind = 'M3'

    def features(self, X: np.ndarray) -> np.ndarray:
        return X.reshape(X.shape[0], -1)

    def input_weights(self) -> np.ndarray:
        coef, _ = self._fitted()
        return coef.reshape(3, self.array.n_taxels, 3)
