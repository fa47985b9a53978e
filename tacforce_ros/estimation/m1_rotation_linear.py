"""M1: rotation-assisted linear model (paper eq. 1, 4): f = A z + b, z = sum_i R_i^0 x_i, p = 12."""
from __future__ import annotations

import numpy as np

from tacforce_ros.estimation.affine import LinearInputModel


def rotated_sum(X: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """z = sum_i R_i^0 x_i: (N, n, 3) taxel inputs -> (N, 3) total activity in {S0}."""
    return np.einsum('nij,Nnj->Ni', rotations, X)


NORMAL_INPUT_NOTE = ('The slope of the taxels\' counts summed in {S0} (z) over the normal force '
                     '(|F_z| >= 0.3 N), counts / N: M1 maps that sum to the force linearly, so '
                     'it needs these alike across plates.')


def normal_input_per_newton(X: np.ndarray, F: np.ndarray, plates: np.ndarray,
                            rotations: np.ndarray, min_force: float = 0.3) -> dict:
    """{plate: counts per N or None}: per plate, the least-squares slope through the origin of
    M1's normal input (z of rotated_sum of the counts X (N, n, 3)) over the normal force
    F[:, 2], on the samples with |F_z| >= min_force (N); None where a plate has none. Why it
    matters: NORMAL_INPUT_NOTE."""
    z = rotated_sum(X, rotations)[:, 2]
    plates = np.asarray(plates)
    gains = {}
    for plate in dict.fromkeys(plates.tolist()):
        pressed = (plates == plate) & (np.abs(F[:, 2]) >= min_force)
        force = F[pressed, 2]
        gains[str(plate)] = float(z[pressed] @ force / (force @ force)) if force.size else None
    return gains


class M1Linear(LinearInputModel):
    kind = 'M1'

    def features(self, X: np.ndarray) -> np.ndarray:
        return rotated_sum(X, self.array.rotations)

    def input_weights(self) -> np.ndarray:
        coef, _ = self._fitted()
        # A z = A sum_i R_i x_i = sum_i (A R_i) x_i
        return np.einsum('ab,nbc->anc', coef, self.array.rotations)
