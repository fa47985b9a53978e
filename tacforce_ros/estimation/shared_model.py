"""A model shared by the arrays of a kind, adapted to one array from a little of its own data.

The 18 arrays of a hand are three kinds of one module design (curved fingertips, square phalanx
pads, palm pads), read in the taxel order and sensor frame the kind shares; what one array's
calibration teaches, another of its kind need not be pressed to learn again. The shared model is
a linear model (M1-M3, M3-lambda) fitted on the pooled data of the kind's other arrays, each with
its own offsets removed. Adapting it to an array is damped least squares centred on it instead
of on zero, in the shared model's standardised units:

    W = argmin ||F - phi W - b||^2 + damping ||W - W_shared||^2,    damping = weight * n,

the fit of a Gaussian prior around the shared model (multi-task ridge), n the array's own
samples. The weight says how much the prior counts against the array's data, whatever its
size; it is chosen from ADAPT_WEIGHTS by leave-one-array-out: each other array of the kind in
turn plays the new one, with as much of its own data as the array has, and the weight that gave
the lowest mean e_hat on its held-out plate wins. Two simpler dampings failed on the main job's
training sets (docs/CALIBRATION.md has the figures): the prior's own estimate (sigma^2 / tau^2
from the other arrays' fits) was far too weak, as the arrays' fits spread most where the data
barely constrain them; one chosen by leave-one-plate-out on the array's own few seconds was
erratic between folds. It is the paper's model and solver, with no epochs; a network fine-tuned
per array was not tried.
"""
from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.affine import AffineModel
from tacforce_ros.estimation.cross_validation import CrossValidation, Fold
from tacforce_ros.estimation.least_squares import fit_affine
from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.estimation.registry import model_class
from tacforce_ros.estimation.training import fit_bundles

if TYPE_CHECKING:
    from tacforce_ros.estimation.model_io import ModelBundle
    from tacforce_ros.hand.description import TaxelArray

Data = tuple[np.ndarray, np.ndarray, np.ndarray]        # X counts (offsets removed), F N, plates
# The prior's weight against the array's own data; inf keeps the shared model as it is.
ADAPT_WEIGHTS = (0.0, 1e-3, 1e-2, 0.1, 1.0, float('inf'))


def fit_shared(array: TaxelArray, kind: str, hyper: dict[str, Any],
               others: Sequence[Data]) -> ModelBundle:
    """The kind's model on the pooled data of `others` (arrays of `array`'s kind)."""
    if not issubclass(model_class(kind), AffineModel):
        raise ValueError(f'{kind}: only the linear models (M1-M3, M3-lambda) are shared and '
                         'adapted here')
    if not others:
        raise ValueError(f'{array.name}: a shared model needs the data of another array')
    pooled = tuple(np.concatenate([np.asarray(d[i]) for d in others]) for i in range(3))
    (bundle,) = fit_bundles(array, kind, hyper, [pooled])
    return bundle


def adapt(shared: ModelBundle, weight: float, X: np.ndarray, F: np.ndarray) -> ModelBundle:
    """The shared model moved toward the array's own (X, F): damped least squares centred on it,
    damping weight * len(X), the intercept free as in every affine fit here. weight inf (or no
    data) returns the shared model unchanged."""
    if not weight >= 0.0:
        raise ValueError(f'adapt weight {weight!r}: must be >= 0 (inf: unadapted)')
    adapted = copy.deepcopy(shared)
    if np.isinf(weight) or len(X) == 0:
        return adapted
    model = shared.model
    xs = shared.x_scaler.transform(X)
    delta, offset = fit_affine(model.features(xs),
                               shared.f_scaler.transform(F) - model.predict(xs),
                               weight * len(X))
    adapted.model.coef_ = model.coef_ + delta
    adapted.model.intercept_ = model.intercept_ + offset
    return adapted


def choose_weight(array: TaxelArray, kind: str, hyper: dict[str, Any], plate: str,
                  rows_per_plate: Mapping[str, int], pooled_without: Mapping[str, ModelBundle],
                  others: Mapping[str, Data], weights: Sequence[float] = ADAPT_WEIGHTS
                  ) -> tuple[float, list[float]]:
    """Leave-one-array-out over `others`: each in turn adapts the shared model of the rest
    (`pooled_without[name]`, fitted without `plate`) from its first rows_per_plate rows of each
    other plate and is tested on all of its rows of `plate`. Returns (the weight of the lowest
    mean e_hat, the mean e_hat per weight)."""
    scores = np.zeros(len(weights))
    for name, data in others.items():
        X, F, plates = data
        own = _first_rows(_without(data, plate), rows_per_plate)
        on = np.asarray(plates) == plate
        for j, weight in enumerate(weights):
            bundle = adapt(pooled_without[name], weight, own[0], own[1])
            scores[j] += error_stats(F[on], bundle.predict(X[on])).e_hat_mean
    scores /= len(others)
    return float(weights[int(np.argmin(scores))]), scores.tolist()


def shared_folds(array: TaxelArray, kind: str, hyper: dict[str, Any], own: Data,
                 cuts: Sequence[np.ndarray], others: Mapping[str, Data],
                 weights: Sequence[float] = ADAPT_WEIGHTS) -> list[CrossValidation]:
    """Leave-one-plate-out of the shared model adapted to each cut of `own` (bool rows), judged
    as a learning curve judges the array's own model: for each plate of `own` the shared model
    is fitted on the other arrays' data of the other plates (the held-out plate is new to it as
    to the array's own model), adapted on the cut's rows of the other plates with the weight
    choose_weight picks, and tested on all of `own`'s rows of the held-out plate. The pooled fits
    of a plate serve every cut. One CrossValidation per cut; each fold's hyperparameters hold
    the weight (None: unadapted) and the damping."""
    if len(others) < 2:
        raise ValueError(f'{array.name}: choosing the adaptation needs two other arrays of its '
                         f'kind, got {sorted(others)}')
    X, F, plates = own
    plates = np.asarray(plates)
    for name, data in others.items():
        missing = set(plates.tolist()) - set(np.asarray(data[2]).tolist())
        if missing:
            raise ValueError(f'{name} has no data on the plates {sorted(missing)}')
    results = [CrossValidation(kind=kind) for _ in cuts]
    for plate in dict.fromkeys(plates.tolist()):
        rest = {name: _without(data, plate) for name, data in others.items()}
        shared = fit_shared(array, kind, hyper, list(rest.values()))
        pooled_without = {name: fit_shared(array, kind, hyper,
                                           [d for other, d in rest.items() if other != name])
                          for name in others}
        on = plates == plate
        for cut, result in zip(cuts, results):
            train = np.asarray(cut, bool) & ~on
            rows_per_plate = {str(p): int(np.sum(train & (plates == p)))
                              for p in dict.fromkeys(plates[train].tolist())}
            weight, _ = choose_weight(array, kind, hyper, plate, rows_per_plate,
                                      pooled_without, others, weights)
            bundle = adapt(shared, weight, X[train], F[train])
            result.folds.append(Fold(
                test_plate=str(plate), stats=error_stats(F[on], bundle.predict(X[on])),
                train_seconds=0.0, hyperparameters={
                    'adapt_weight': None if np.isinf(weight) else weight,
                    'damping': None if np.isinf(weight) else weight * int(train.sum())}))
            result.n_parameters = bundle.model.n_parameters()
    return results


def _without(data: Data, plate: str) -> Data:
    X, F, plates = data
    keep = np.asarray(plates) != plate
    return X[keep], F[keep], np.asarray(plates)[keep]


def _first_rows(data: Data, rows_per_plate: Mapping[str, int]) -> Data:
    """Each plate's first rows (as recorded), as many as rows_per_plate asks (or all it has)."""
    X, F, plates = data
    plates = np.asarray(plates)
    keep = np.zeros(len(plates), bool)
    for plate, n in rows_per_plate.items():
        keep[np.flatnonzero(plates == plate)[:n]] = True
    return X[keep], F[keep], plates[keep]
