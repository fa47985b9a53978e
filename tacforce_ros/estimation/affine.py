"""Shared machinery of the models that are affine in their parameters (M1, M2, M3, M3-lambda).

Each subclass defines its feature map phi(X); the fit is one (damped) least-squares solve.
Learned state: coef_ (3, p) and intercept_ (3,), plus whatever the feature map learns.
"""
from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.base import ForceModel, ModelNotFittedError, check_inputs
from tacforce_ros.estimation.least_squares import fit_affine

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray


class AffineModel(ForceModel):
    """f = coef_ phi(x) + intercept_, fitted by least squares with damping `self.damping`."""

    damping: float = 0.0

    def __init__(self, array: TaxelArray) -> None:
        super().__init__(array)
        self.coef_: np.ndarray | None = None
        self.intercept_: np.ndarray | None = None

    @abstractmethod
    def features(self, X: np.ndarray) -> np.ndarray:
        """(N, n, 3) standardised inputs -> (N, p) design."""

    def learn_features(self, X: np.ndarray) -> None:
        """Fit whatever the feature map learns from the training inputs (default: nothing)."""

    def fit(self, X: np.ndarray, F: np.ndarray) -> AffineModel:
        X = check_inputs(X, self.array.n_taxels, F)
        self.learn_features(X)
        self.coef_, self.intercept_ = fit_affine(self.features(X), F, self.damping)
        return self

    def _fitted(self) -> tuple[np.ndarray, np.ndarray]:
        if self.coef_ is None or self.intercept_ is None:
            raise ModelNotFittedError(f'{self.kind} model for {self.array.name} is not fitted')
        return self.coef_, self.intercept_

    def predict(self, X: np.ndarray) -> np.ndarray:
        coef, intercept = self._fitted()
        X = check_inputs(X, self.array.n_taxels)
        return self.features(X) @ coef.T + intercept

    def n_parameters(self) -> int:
        coef, intercept = self._fitted()
        return int(coef.size + intercept.size)

    def hyperparameters(self) -> dict:
        return {}

    def state_arrays(self) -> dict[str, np.ndarray]:
        coef, intercept = self._fitted()
        return {'coef_': coef, 'intercept_': intercept}

    @classmethod
    def from_state(cls, array: TaxelArray, hyper: dict,
                   arrays: dict[str, np.ndarray]) -> AffineModel:
        model = cls(array, **hyper)
        expected = set(model.state_names())
        if set(arrays) != expected:
            raise ValueError(f'{cls.kind} state needs arrays {sorted(expected)}, '
                             f'got {sorted(arrays)}')
        for name, value in arrays.items():
            setattr(model, name, np.asarray(value, dtype=np.float64))
        model.check_state()
        return model

    def state_names(self) -> tuple[str, ...]:
        return ('coef_', 'intercept_')

    def check_state(self) -> None:
        """Refuse loaded state whose shapes do not fit this array."""
        coef, intercept = self._fitted()
        n_features = self.features(np.zeros((1, self.array.n_taxels, 3))).shape[1]
        if coef.shape != (3, n_features) or intercept.shape != (3,):
            raise ValueError(f'{self.kind} state for {self.array.name}: coef_ {coef.shape} and '
                             f'intercept_ {intercept.shape}, expected (3, {n_features}) and (3,)')


class LinearInputModel(AffineModel):
    """Affine models whose features are linear in the taxel inputs (M1, M3): f = W x + b.

    They all batch the same way: one (k, 3, 3 n_max) weight stack and one matmul per tick.
    """

    @abstractmethod
    def input_weights(self) -> np.ndarray:
        """Effective weights on the taxel inputs, (3, n, 3)."""

    @classmethod
    def compile_batch(cls, models: Sequence[ForceModel]) -> Callable[[np.ndarray], np.ndarray]:
        n_max = max(m.array.n_taxels for m in models)
        weights = np.zeros((len(models), 3, n_max, 3))
        for k, model in enumerate(models):
            weights[k, :, :model.array.n_taxels] = model.input_weights()
        weights = weights.reshape(len(models), 3, 3 * n_max)
        bias = np.stack([m.intercept_ for m in models])
        rows = (len(models), 1, 3 * n_max)

        def predict_batch(X: np.ndarray) -> np.ndarray:
            X = X[:, :n_max]        # wider input: the extra columns are zero padding
            # vecdot: one batched dot per output row; measured faster than matmul at this size.
            return np.vecdot(weights, X.reshape(rows)) + bias

        return predict_batch
