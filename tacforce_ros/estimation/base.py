"""Contract shared by every force model (M1-M5, M3-lambda).

A model maps the standardised taxel inputs of ONE array, X (N, n, 3), to the standardised force in
the array frame {S0}, F (N, 3). Offsets, standardisation and de-standardisation live outside the
model (pipeline, model file, runtime estimator), so every model sees the same well-scaled numbers.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, ClassVar

import numpy as np

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray


class ForceModel(ABC):
    """Per-array force model; subclasses take explicit keyword hyper-parameters."""

    kind: ClassVar[str]     # 'M1' | 'M2' | 'M3' | 'M3-lambda' | 'M4' | 'M5'
    # True for models whose fit() also takes `groups` (plate label per sample), e.g. M3-lambda
    # selecting its damping by cross-validation nested inside the training plates.
    needs_groups: ClassVar[bool] = False

    def __init__(self, array: TaxelArray, **hyper) -> None:
        self.array = array

    @abstractmethod
    def fit(self, X: np.ndarray, F: np.ndarray) -> ForceModel:
        """X (N, n, 3) float64 standardised taxel inputs; F (N, 3) float64 standardised force."""

    @classmethod
    def fit_many(cls, models: Sequence[ForceModel],
                 data: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        """Fit models[i] on data[i] = (X, F, groups), each as fit() would.

        This default fits them one by one; kinds that can train several models as one (M4, M5:
        torch_batched) override it.
        """
        for model, (X, F, groups) in zip(models, data, strict=True):
            if model.needs_groups:
                model.fit(X, F, groups=groups)
            else:
                model.fit(X, F)

    @abstractmethod
    def predict(self, X: np.ndarray) -> np.ndarray:
        """(N, n, 3) -> (N, 3), numpy only."""

    @abstractmethod
    def n_parameters(self) -> int:
        """Number of learned scalars."""

    @abstractmethod
    def hyperparameters(self) -> dict:
        """JSON-serialisable keyword arguments that rebuild an unfitted model."""

    @abstractmethod
    def state_arrays(self) -> dict[str, np.ndarray]:
        """Learned state; attribute names end with '_'."""

    @classmethod
    @abstractmethod
    def from_state(cls, array: TaxelArray, hyper: dict,
                   arrays: dict[str, np.ndarray]) -> ForceModel:
        """Rebuild a fitted model from hyperparameters() and state_arrays()."""

    @classmethod
    @abstractmethod
    def compile_batch(cls, models: Sequence[ForceModel]) -> Callable[[np.ndarray], np.ndarray]:
        """One batched numpy pass for k models of this kind.

        The callable takes (k, n_max, 3) standardised inputs zero-padded to n_max taxels and
        returns (k, 3). Weights are stacked (zero-padded) once here, so the callable does only
        the math.
        """


class ModelNotFittedError(RuntimeError):
    """predict/state_arrays called on a model that has not been fitted."""


def check_inputs(X: np.ndarray, n_taxels: int, F: np.ndarray | None = None) -> np.ndarray:
    """Validate shapes (and finiteness) of a model's inputs; returns X as float64."""
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (n_taxels, 3):
        raise ValueError(f'X must have shape (N, {n_taxels}, 3), got {X.shape}')
    if F is not None:
        if X.shape[0] == 0:
            raise ValueError('cannot fit on zero samples')
        F = np.asarray(F)
        if F.shape != (X.shape[0], 3):
            raise ValueError(f'F must have shape ({X.shape[0]}, 3), got {F.shape}')
        if not np.all(np.isfinite(F)):
            raise ValueError('F contains NaN or Inf')
        if not np.all(np.isfinite(X)):
            raise ValueError('X contains NaN or Inf')
    return X
