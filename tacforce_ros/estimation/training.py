"""Fit models on offset-corrected data: standardise, fit, wrap into ModelBundles."""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.model_io import ModelBundle
from tacforce_ros.estimation.preprocessing import (FORCE_STD_FLOOR, TAXEL_STD_FLOOR,
                                                   Standardiser)
from tacforce_ros.estimation.registry import model_class

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray


def fit_bundle(array: TaxelArray, kind: str, hyper: dict[str, Any], X: np.ndarray,
               F: np.ndarray, plates: np.ndarray, x_offset: np.ndarray | None = None,
               provenance: dict[str, Any] | None = None) -> ModelBundle:
    """X (N, n, 3) counts with offsets removed, F (N, 3) N in {S0} with offsets removed.

    Standardisation statistics come from these samples only, so in cross-validation the
    held-out plate never shapes them.
    """
    bundle, = fit_bundles(array, kind, hyper, [(X, F, plates)])
    return for_deployment(bundle, x_offset, provenance)


def for_deployment(bundle: ModelBundle, x_offset: np.ndarray | None,
                   provenance: dict[str, Any] | None) -> ModelBundle:
    """The bundle with the counts' offset it removes at run time and where it came from."""
    if x_offset is not None:
        bundle.x_offset = x_offset
    bundle.provenance.update(provenance or {})
    return bundle


def fit_bundles(array: TaxelArray, kind: str, hyper: dict[str, Any],
                data: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[ModelBundle]:
    """fit_bundle on each (X, F, plates) of `data` (e.g. the folds of a cross-validation), with
    the models fitted together by ForceModel.fit_many (M4 and M5 train as one network)."""
    scalers = [(Standardiser.fit(X, TAXEL_STD_FLOOR), Standardiser.fit(F, FORCE_STD_FLOOR))
               for X, F, _ in data]
    cls = model_class(kind)
    models = [cls(array, **hyper) for _ in data]
    cls.fit_many(models, [(x_scaler.transform(X), f_scaler.transform(F), np.asarray(plates))
                          for (X, F, plates), (x_scaler, f_scaler) in zip(data, scalers)])
    return [ModelBundle(model=model, x_scaler=x_scaler, f_scaler=f_scaler,
                        x_offset=np.zeros((array.n_taxels, 3)))
            for model, (x_scaler, f_scaler) in zip(models, scalers)]
