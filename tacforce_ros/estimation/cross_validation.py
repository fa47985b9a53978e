"""Leave-one-plate-out cross-validation (paper Sec. IV-A, V-A): train on 4 plates, test on the
5th."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.metrics import ErrorStats, average_folds, error_stats
from tacforce_ros.estimation.training import fit_bundles

if TYPE_CHECKING:
    from tacforce_ros.estimation.model_io import ModelBundle
    from tacforce_ros.hand.description import TaxelArray


@dataclass
class Fold:
    test_plate: str
    stats: ErrorStats
    train_seconds: float
    hyperparameters: dict[str, Any]     # as fitted (e.g. the damping M3-lambda selected)


@dataclass
class CrossValidation:
    kind: str
    folds: list[Fold] = field(default_factory=list)
    n_parameters: int = 0
    final: ModelBundle | None = None    # fitted on every plate (cross_validate(final=True))

    def summary(self) -> dict[str, Any]:
        return {**average_folds([f.stats for f in self.folds]),
                'train_seconds': float(np.mean([f.train_seconds for f in self.folds])),
                'n_parameters': self.n_parameters,
                'per_fold': [{'test_plate': f.test_plate, **f.stats.as_dict(),
                              'train_seconds': f.train_seconds,
                              'hyperparameters': f.hyperparameters} for f in self.folds]}


def cross_validate(array: TaxelArray, kind: str, hyper: dict[str, Any], X: np.ndarray,
                   F: np.ndarray, plates: np.ndarray, together: bool = True,
                   final: bool = False,
                   held_out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                   ) -> CrossValidation:
    """X counts and F newtons with offsets removed; one fold per distinct plate.

    held_out: (X, F, plates) each fold is tested on instead, its rows of the fold's plate (a
    learning curve trains on a cut of the data and tests on all of the held-out plate's).

    together: fit the folds' models in one fit_bundles call (M4 and M5 then train as one
    network, and each fold's train_seconds is the call's time over the models); False fits them
    one at a time, each timed alone (bench_train compares the two).
    final: also fit the model on every plate (CrossValidation.final), in the same call as the
    folds: the model to ship is one more member of the stacked network, not a training alone.
    """
    plates = np.asarray(plates)
    folds, bundles, seconds = fold_models(array, kind, hyper, X, F, plates, together, final)
    result = CrossValidation(kind=kind)
    for (plate, test), bundle, fold_seconds in zip(folds, bundles, seconds):
        X_test, F_test = (X[test], F[test]) if held_out is None else \
            (held_out[0][held_out[2] == plate], held_out[1][held_out[2] == plate])
        pred = bundle.predict(X_test)
        result.folds.append(Fold(test_plate=str(plate), stats=error_stats(F_test, pred),
                                 train_seconds=fold_seconds,
                                 hyperparameters=bundle.model.hyperparameters()))
        result.n_parameters = bundle.model.n_parameters()
    if final:
        result.final = bundles[-1]
    return result


def fold_models(array: TaxelArray, kind: str, hyper: dict[str, Any], X: np.ndarray,
                F: np.ndarray, plates: np.ndarray, together: bool = True, final: bool = False
                ) -> tuple[list[tuple[str, np.ndarray]], list[ModelBundle], list[float]]:
    """The folds (plate, its rows), a model per fold trained on the other plates (with `final`
    one more, on every plate) and each fit's seconds (cross_validate's `together`)."""
    labels = list(dict.fromkeys(plates.tolist()))
    if len(labels) < 2:
        raise ValueError(f'cross-validation needs >= 2 plates, got {labels}')
    folds = [(plate, plates == plate) for plate in labels]
    data = [(X[~test], F[~test], plates[~test]) for _, test in folds]
    if final:
        data.append((X, F, plates))
    if together:
        started = time.perf_counter()
        bundles = fit_bundles(array, kind, hyper, data)
        seconds = [(time.perf_counter() - started) / len(data)] * len(data)
    else:
        bundles, seconds = [], []
        for fold in data:
            started = time.perf_counter()
            bundles += fit_bundles(array, kind, hyper, [fold])
            seconds.append(time.perf_counter() - started)
    return folds, bundles, seconds


def transfer(array: TaxelArray, kind: str, hyper: dict[str, Any], X: np.ndarray, F: np.ndarray,
             plates: np.ndarray, targets: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
             ) -> dict[str, CrossValidation]:
    """This array's model applied unadapted to other arrays of its kind (the same taxel layout,
    each with its own offsets removed): each fold's model, trained on this array's other plates,
    is tested on each target's (X, F, plates) rows of the held-out plate, as cross_validate
    tests it on this array's own. The folds are fitted once for all targets."""
    plates = np.asarray(plates)
    folds, bundles, seconds = fold_models(array, kind, hyper, X, F, plates)
    results = {}
    for name, (X_t, F_t, plates_t) in targets.items():
        result = CrossValidation(kind=kind)
        for (plate, _), bundle, fold_seconds in zip(folds, bundles, seconds):
            rows = np.asarray(plates_t) == plate
            if not rows.any():
                raise ValueError(f'transfer: {name} has no data on the plate {plate}')
            result.folds.append(Fold(test_plate=str(plate),
                                     stats=error_stats(F_t[rows], bundle.predict(X_t[rows])),
                                     train_seconds=fold_seconds,
                                     hyperparameters=bundle.model.hyperparameters()))
            result.n_parameters = bundle.model.n_parameters()
        results[name] = result
    return results
