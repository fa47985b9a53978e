"""Fit one model on offset-corrected data: standardise, fit, wrap into a ModelBundle."""
from __future__ import annotations

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
    x_scaler = Standardiser.fit(X, TAXEL_STD_FLOOR)
    f_scaler = Standardiser.fit(F, FORCE_STD_FLOOR)
    model = model_class(kind)(array, **hyper)
    Xs, Fs = x_scaler.transform(X), f_scaler.transform(F)
    if model.needs_groups:
        model.fit(Xs, Fs, groups=np.asarray(plates))
    else:
        model.fit(Xs, Fs)
    return ModelBundle(model=model, x_scaler=x_scaler, f_scaler=f_scaler,
                       x_offset=np.zeros((array.n_taxels, 3)) if x_offset is None else x_offset,
                       provenance=dict(provenance or {}))
