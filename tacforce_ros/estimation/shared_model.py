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

from tacforce_ros.estimation.cross_validation import CrossValidation, Fold
from tacforce_ros.estimation.least_squares import CentredSVD, augmented_factor
from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.estimation.model_io import ModelBundle
from tacforce_ros.estimation.preprocessing import FORCE_STD_FLOOR, TAXEL_STD_FLOOR, Standardiser
from tacforce_ros.estimation.registry import model_class

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray

Data = tuple[np.ndarray, np.ndarray, np.ndarray]        # X counts (offsets removed), F N, plates
# The prior's weight against the array's own data; inf keeps the shared model as it is.
ADAPT_WEIGHTS = (0.0, 1e-3, 1e-2, 0.1, 1.0, float('inf'))
# The kinds whose features are the standardised inputs themselves: a union of blocks fits them
# exactly from the blocks' factors (KindBlocks).
BLOCK_KINDS = ('M3', 'M3-lambda')


class KindBlocks:
    """The data of a kind's arrays as one block per (array, plate): its sample count, means and
    centred sums of squares, and the triangular factor of [1 | x | F] in a reference
    standardisation (least_squares.augmented_factor). The shared model of any union of blocks,
    with the standardisation training.fit_bundles would fit on its rows, follows from these
    without another pass over the rows: the leave-one-array-out choice of the weight needs a
    pooled fit per other array and plate (55 for a flat pad among eleven; 2-4 s each on the
    rows)."""

    def __init__(self, array: TaxelArray, kind: str, hyper: dict[str, Any],
                 data: Mapping[str, Data]) -> None:
        self.model = model_class(kind)(array, **hyper)
        if kind not in BLOCK_KINDS or getattr(self.model, 'lambda_grid', None) is not None:
            raise ValueError(f'{kind} {hyper}: only {BLOCK_KINDS} with a fixed damping are '
                             'shared and adapted here')
        self.array, self.kind, self.hyper = array, kind, hyper
        blocks = {}
        for name, (X, F, plates) in data.items():
            x = np.asarray(X, np.float64).reshape(len(X), -1)
            F = np.asarray(F, np.float64)
            plates = np.asarray(plates)
            for plate in dict.fromkeys(plates.tolist()):
                on = plates == plate
                blocks[name, str(plate)] = (x[on], F[on])
        self.names = list(data)
        self._stats = {key: _moments(np.hstack(parts)) for key, parts in blocks.items()}
        self._mean0, self._std0 = _combine(list(self._stats.values()))
        self._std0 = np.where(self._std0 > 0.0, self._std0, 1.0)
        self._factors = {key: augmented_factor(*np.hsplit(
            (np.hstack(parts) - self._mean0) / self._std0, [-3]))
            for key, parts in blocks.items()}

    def plates(self, name: str) -> list[str]:
        return [plate for n, plate in self._factors if n == name]

    def fit(self, names: Sequence[str], without: str | None = None,
            array: TaxelArray | None = None) -> ModelBundle:
        """The shared model of `names`' data, all plates but `without`: fit_bundles' on their
        pooled rows, to rounding; for `array` (default: the one the blocks were made with), of
        the kind."""
        keys = [key for key in self._factors if key[0] in names and key[1] != without]
        if not keys:
            raise ValueError(f'{self.array.name}: a shared model needs the data of another array')
        mean, std = _combine([self._stats[key] for key in keys])
        p = mean.size - 3
        floors = np.r_[np.full(p, TAXEL_STD_FLOOR), np.full(3, FORCE_STD_FLOOR)]
        dead = ~(std > floors)
        std = np.where(dead, 1.0, std)
        # [1 | z] of the reference standardisation -> [1 | (x - mean) / std] of this union's.
        to_union = np.diag(np.r_[1.0, self._std0 / std])
        to_union[0, 1:] = (self._mean0 - mean) / std
        stacked = np.vstack([self._factors[key] for key in keys]) @ to_union
        coef, intercept = CentredSVD.of_factor(np.linalg.qr(stacked, mode='r')).solve(
            self.model.damping)
        array = self.array if array is None else array
        if array.n_taxels != self.array.n_taxels:
            raise ValueError(f'{array.name} has {array.n_taxels} taxels, the kind '
                             f'{self.array.n_taxels}')
        model = model_class(self.kind)(array, **self.hyper)
        model.coef_, model.intercept_ = coef, intercept
        n = array.n_taxels
        return ModelBundle(
            model=model, x_scaler=Standardiser(mean=mean[:p].reshape(n, 3),
                                               std=std[:p].reshape(n, 3),
                                               dead=dead[:p].reshape(n, 3)),
            f_scaler=Standardiser(mean=mean[p:], std=std[p:], dead=dead[p:]),
            x_offset=np.zeros((n, 3)))


def _moments(rows: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    mean = rows.mean(axis=0)
    return len(rows), mean, ((rows - mean) ** 2).sum(axis=0)


def _combine(stats: Sequence[tuple[int, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Mean and (population) std of the union of blocks, from their moments (Chan et al.'s
    pairwise update, no sums of squares about zero)."""
    n = sum(k for k, _, _ in stats)
    mean = sum(k * m for k, m, _ in stats) / n
    m2 = sum(s2 + k * (m - mean) ** 2 for k, m, s2 in stats)
    return mean, np.sqrt(m2 / n)


def adapt(shared: ModelBundle, weight: float, X: np.ndarray, F: np.ndarray) -> ModelBundle:
    """The shared model moved toward the array's own (X, F): damped least squares centred on it,
    damping weight * len(X), the intercept free as in every affine fit here. weight inf (or no
    data) returns the shared model unchanged."""
    return Adaptation(shared, X, F)(weight)


class Adaptation:
    """`adapt` of one shared model to one array's (X, F) at any weight, the data's factor taken
    once: the weight's choice adapts each other array at every weight, and the factor was 30 of
    a flat-pad kind curve point's 53 s when taken per weight. Each weight's model is the one
    `adapt` gave, to the bit (the same factor, solved at its damping)."""

    def __init__(self, shared: ModelBundle, X: np.ndarray, F: np.ndarray) -> None:
        self.shared, self.X, self.F = shared, X, F
        self._svd: CentredSVD | None = None

    def __call__(self, weight: float) -> ModelBundle:
        if not weight >= 0.0:
            raise ValueError(f'adapt weight {weight!r}: must be >= 0 (inf: unadapted)')
        adapted = copy.deepcopy(self.shared)
        if np.isinf(weight) or len(self.X) == 0:
            return adapted
        model = self.shared.model
        if self._svd is None:
            xs = self.shared.x_scaler.transform(self.X)
            self._svd = CentredSVD.of(model.features(xs),
                                      self.shared.f_scaler.transform(self.F) - model.predict(xs))
        delta, offset = self._svd.solve(weight * len(self.X))
        adapted.model.coef_ = model.coef_ + delta
        adapted.model.intercept_ = model.intercept_ + offset
        return adapted


def choose_weight(plate: str, rows_per_plate: Mapping[str, int],
                  pooled_without: Mapping[str, ModelBundle], others: Mapping[str, Data],
                  weights: Sequence[float] = ADAPT_WEIGHTS) -> tuple[float, list[float]]:
    """Leave-one-array-out over `others`: each in turn adapts the shared model of the rest
    (`pooled_without[name]`, fitted without `plate`) from its first rows_per_plate rows of each
    other plate and is tested on all of its rows of `plate`. Returns (the weight of the lowest
    mean e_hat, the mean e_hat per weight)."""
    scores = np.zeros(len(weights))
    for name, data in others.items():
        X, F, plates = data
        own = _first_rows(_without(data, plate), rows_per_plate)
        on = np.asarray(plates) == plate
        adaptation = Adaptation(pooled_without[name], own[0], own[1])
        for j, weight in enumerate(weights):
            bundle = adaptation(weight)
            scores[j] += error_stats(F[on], bundle.predict(X[on])).e_hat_mean
    scores /= len(others)
    return float(weights[int(np.argmin(scores))]), scores.tolist()


def shared_folds(array: TaxelArray, kind: str, hyper: dict[str, Any], own: Data,
                 cuts: Sequence[np.ndarray], others: Mapping[str, Data],
                 weights: Sequence[float] = ADAPT_WEIGHTS,
                 blocks: KindBlocks | None = None,
                 held_out: Data | None = None) -> list[CrossValidation]:
    """Leave-one-plate-out of the shared model adapted to each cut of `own` (bool rows), judged
    as a learning curve judges the array's own model: for each plate of `own` the shared model
    is fitted on the other arrays' data of the other plates (the held-out plate is new to it as
    to the array's own model), adapted on the cut's rows of the other plates with the weight
    choose_weight picks, and tested on all of `own`'s rows of the held-out plate. `blocks`: the
    KindBlocks of (at least) `others`, when the caller has them. `held_out`: the data each fold
    is tested on, plate by plate, when not `own` (a simulated campaign judged on more of the
    array's data than it recorded). One CrossValidation per cut;
    each fold's hyperparameters hold the weight (None: unadapted), the damping and the mean
    e_hat of each of `weights` in the choice."""
    if len(others) < 2:
        raise ValueError(f'{array.name}: choosing the adaptation needs two other arrays of its '
                         f'kind, got {sorted(others)}')
    X, F, plates = own
    plates = np.asarray(plates)
    for name, data in others.items():
        missing = set(plates.tolist()) - set(np.asarray(data[2]).tolist())
        if missing:
            raise ValueError(f'{name} has no data on the plates {sorted(missing)}')
    blocks = KindBlocks(array, kind, hyper, others) if blocks is None else blocks
    X_test, F_test, test_plates = own if held_out is None else held_out
    test_plates = np.asarray(test_plates)
    untested = set(plates.tolist()) - set(test_plates.tolist())
    if untested:
        raise ValueError(f'{array.name}: the held-out data has no rows on {sorted(untested)}')
    results = [CrossValidation(kind=kind) for _ in cuts]
    for plate in dict.fromkeys(plates.tolist()):
        shared = blocks.fit(list(others), without=plate, array=array)
        pooled_without = {name: blocks.fit([o for o in others if o != name], without=plate)
                          for name in others}
        on = plates == plate
        tested = test_plates == plate
        for cut, result in zip(cuts, results):
            train = np.asarray(cut, bool) & ~on
            rows_per_plate = {str(p): int(np.sum(train & (plates == p)))
                              for p in dict.fromkeys(plates[train].tolist())}
            weight, scores = choose_weight(plate, rows_per_plate, pooled_without, others,
                                           weights)
            bundle = adapt(shared, weight, X[train], F[train])
            result.folds.append(Fold(
                test_plate=str(plate), stats=error_stats(F_test[tested],
                                                         bundle.predict(X_test[tested])),
                train_seconds=0.0, hyperparameters={
                    'adapt_weight': None if np.isinf(weight) else weight,
                    'damping': None if np.isinf(weight) else weight * int(train.sum()),
                    'weight_scores': scores}))
            result.n_parameters = bundle.model.n_parameters()
    return results


def fit_adapted(array: TaxelArray, kind: str, hyper: dict[str, Any], own: Data,
                others: Mapping[str, Data], weights: Sequence[float] = ADAPT_WEIGHTS,
                blocks: KindBlocks | None = None
                ) -> tuple[ModelBundle, float, CrossValidation]:
    """The model to ship: the shared model of every other array's data adapted to all of
    `own`, with the weight whose leave-one-array-out e_hat, averaged over the held-out plates,
    is lowest; and its leave-one-plate-out (shared_folds on all of `own`), which those scores
    come from. Returns (bundle, weight (inf: unadapted), cross-validation)."""
    blocks = KindBlocks(array, kind, hyper, others) if blocks is None else blocks
    (cv,) = shared_folds(array, kind, hyper, own, [np.ones(len(own[1]), bool)], others,
                         weights, blocks)
    scores = np.mean([f.hyperparameters['weight_scores'] for f in cv.folds], axis=0)
    weight = float(weights[int(np.argmin(scores))])
    return adapt(blocks.fit(list(others), array=array), weight, own[0], own[1]), weight, cv


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
