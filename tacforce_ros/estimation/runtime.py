"""Whole-hand force estimation at 100 Hz: one batched numpy pass per tactile frame.

Per tick: standardise the flat (368, 3) counts into a buffer whose last row stays zero (one
subtract that also casts to float64, one multiply by 1/std), optionally low-pass it in place
(`set_lowpass`: a causal filter per input channel, estimation/causal_filter.py; the models were
trained on low-passed data, and the controller then sees the filter's delay), gather it with one
precomputed index into an (arrays, 1, 3 n_max) block, one zero-padded row per array (padding
points at the zero row), take the OOD score from the block, and run one callable per model kind
that returns forces in newtons. Arrays whose input or output is not finite are flagged invalid
and report zero force, not garbage.

Linear models (M1, M3, M3-lambda) are folded at load time: the output de-standardisation
f = f_std (W z + b) + f_mean goes into the stacked weights and bias, so their part of the tick is
one vecdot and one add. The input standardisation z stays explicit: the OOD score and the
validity flag are defined on z, so it is computed anyway, and folding 1/std into W as well would
only move work, not remove it.

dtype: float64 throughout. The work per tick is ~18 x 3 x 90 multiply-adds, so the pass is bound by
numpy call overhead, not arithmetic: float32 would save nothing measurable and would make online
predictions differ from the offline (float64) evaluation.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from math import isfinite
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.affine import LinearInputModel
from tacforce_ros.estimation.causal_filter import BatchLowPass
from tacforce_ros.estimation.model_io import ModelBundle

if TYPE_CHECKING:
    from tacforce_ros.hand.description import HandDescription

STATUS_OK = 'ok'
STATUS_NOT_FINITE = 'model output is NaN or Inf'

# (k, 1, 3 n_max) standardised inputs, one row per array (taxel-major, zero-padded) -> (k, 3) N
BatchPredict = Callable[[np.ndarray], np.ndarray]


@dataclass(slots=True)
class HandEstimate:
    force: np.ndarray       # (arrays, 3) N in each array frame {S0}; zero where not valid
    valid: np.ndarray       # (arrays,) bool
    status: tuple[str, ...]  # 'ok' or why the estimate is not valid
    ood_score: np.ndarray   # (arrays,) max |standardised input| over the array's channels


def folded_linear_batch(bundles: Sequence[ModelBundle], n_max: int) -> BatchPredict:
    """Linear bundles (W z + b on standardised z) as one callable returning newtons.

    f = f_std (W z + b) + f_mean = (f_std W) z + (f_std b + f_mean): exact, folded once here.
    """
    k = len(bundles)
    weights = np.zeros((k, 3, n_max, 3))
    bias = np.empty((k, 3))
    for i, bundle in enumerate(bundles):
        model, f_std = bundle.model, bundle.f_scaler.std
        weights[i, :, :model.array.n_taxels] = f_std[:, None, None] * model.input_weights()
        bias[i] = f_std * model.intercept_ + bundle.f_scaler.mean
    weights = weights.reshape(k, 3, 3 * n_max)

    def predict_newtons(X: np.ndarray) -> np.ndarray:
        # vecdot: one batched dot per output row; measured faster than matmul and einsum here.
        force = np.vecdot(weights, X)
        return np.add(force, bias, out=force)

    return predict_newtons


def destandardised_batch(bundles: Sequence[ModelBundle], n_max: int) -> BatchPredict:
    """Any model kind: its own compiled batch, then f_std * y + f_mean."""
    predict = type(bundles[0].model).compile_batch([b.model for b in bundles])
    width = max(b.array.n_taxels for b in bundles)   # the group's own n_max
    block = (len(bundles), n_max, 3)
    f_std = np.stack([b.f_scaler.std for b in bundles])
    f_mean = np.stack([b.f_scaler.mean for b in bundles])

    def predict_newtons(X: np.ndarray) -> np.ndarray:
        # multiply allocates: the callable may reuse its output buffer between calls
        force = np.multiply(predict(X.reshape(block)[:, :width]), f_std)
        return np.add(force, f_mean, out=force)

    return predict_newtons


class RuntimeEstimator:
    """One model bundle per array of the hand (mixed kinds allowed)."""

    def __init__(self, hand: HandDescription, bundles: Sequence[ModelBundle]) -> None:
        by_name = {b.array.name: b for b in bundles}
        missing = [a.name for a in hand.arrays if a.name not in by_name]
        extra = sorted(set(by_name) - {a.name for a in hand.arrays})
        if missing or extra or len(bundles) != len(hand.arrays):
            raise ValueError(f'need exactly one model per hand array; missing {missing}, '
                             f'unknown {extra}, got {len(bundles)} for {len(hand.arrays)} arrays')
        for array in hand.arrays:
            if by_name[array.name].array.n_taxels != array.n_taxels:
                raise ValueError(f'model for {array.name} has {by_name[array.name].array.n_taxels}'
                                 f' taxels, the hand description {array.n_taxels}')
        self.hand = hand
        self.bundles = [by_name[a.name] for a in hand.arrays]
        self.names = tuple(a.name for a in hand.arrays)
        self.kinds = tuple(b.model.kind for b in self.bundles)
        n_arrays, n_max = len(hand.arrays), max(a.n_taxels for a in hand.arrays)
        self.n_taxels = hand.n_taxels
        self._n_arrays = n_arrays
        self._shape = (self.n_taxels, 3)

        flat = np.concatenate([a.flat_indices for a in hand.arrays])
        if np.unique(flat).size != flat.size or flat.min() < 0 or flat.max() >= self.n_taxels:
            raise ValueError('hand arrays must partition the flat taxel indices 0..'
                             f'{self.n_taxels - 1} (each taxel in exactly one array)')
        # Standardisation happens on the flat frame (each taxel belongs to one array), then one
        # gather builds the padded block; the flat buffer has one extra row, never written, that
        # stays zero and feeds the padding.
        self._mean = np.zeros((self.n_taxels, 3))
        self._inv_std = np.zeros((self.n_taxels, 3))
        self._tare = np.zeros((self.n_taxels, 3))
        gather = np.full((n_arrays, n_max), self.n_taxels, dtype=np.intp)
        for k, (array, bundle) in enumerate(zip(hand.arrays, self.bundles)):
            gather[k, :array.n_taxels] = array.flat_indices
            self._mean[array.flat_indices] = bundle.x_scaler.mean
            self._inv_std[array.flat_indices] = 1.0 / bundle.x_scaler.std
            self._tare[array.flat_indices] = bundle.x_offset
        self._centre = self._tare + self._mean
        # Element indices into the raveled buffer (a 1-D take is the cheapest gather in numpy),
        # shaped as the models' (arrays, 1, 3 n_max) rows so the block needs no reshape.
        self._gather = (gather[..., None] * 3 + np.arange(3)).reshape(n_arrays, 1, 3 * n_max)
        self._segments = np.arange(n_arrays) * n_max * 3
        self._groups = self._compile(n_max)
        self._flat = np.zeros((self.n_taxels + 1, 3))
        self._x = np.zeros(self._gather.shape)
        self._abs = np.zeros(self._x.size)
        # views and bound methods, made once: the tick is bound by per-call overhead
        self._frame = self._flat[:-1]
        self._take = self._flat.reshape(-1).take
        self._x_1d = self._x.reshape(-1)
        self._all_ok = (STATUS_OK,) * n_arrays
        self._sum = np.add.reduce
        self._frame_1d = self._frame.reshape(-1)
        taxel_array = np.empty(self.n_taxels, dtype=np.intp)
        for k, array in enumerate(hand.arrays):
            taxel_array[array.flat_indices] = k
        self._channel_array = np.repeat(taxel_array, 3)     # array of each flat input channel
        self.lowpass: BatchLowPass | None = None

    def _compile(self, n_max: int) -> list[tuple[np.ndarray, BatchPredict]]:
        """(rows, callable) per model kind, in the order the kinds first appear."""
        groups = []
        for kind in dict.fromkeys(self.kinds):
            rows = np.flatnonzero(np.array(self.kinds) == kind)
            bundles = [self.bundles[k] for k in rows]
            linear = all(isinstance(b.model, LinearInputModel) for b in bundles)
            batch = folded_linear_batch if linear else destandardised_batch
            groups.append((rows, batch(bundles, n_max)))
        return groups

    def set_lowpass(self, cutoff_hz: float | None, rate_hz: float, order: int = 2) -> None:
        """Low-pass every input channel at `cutoff_hz` (Butterworth of `order`) for frames at
        `rate_hz`; None or 0 switches filtering off. Raises FilterDesignError on a bad cut-off."""
        self.lowpass = (BatchLowPass(self._frame_1d.size, cutoff_hz, rate_hz, order)
                        if cutoff_hz else None)

    # --- tare --------------------------------------------------------------------------------

    def set_tare(self, frames: np.ndarray, names: Sequence[str] | None = None) -> None:
        """Tare from a window of no-contact whole-hand frames (T, 368, 3): mean per taxel.

        `names` limits the tare to some arrays (others keep theirs).
        """
        frames = np.asarray(frames, dtype=np.float64)
        if frames.ndim != 3 or frames.shape[1:] != (self.n_taxels, 3) or frames.shape[0] < 1:
            raise ValueError(f'tare needs frames (T >= 1, {self.n_taxels}, 3), got {frames.shape}')
        if not np.all(np.isfinite(frames)):
            raise ValueError('tare frames contain NaN or Inf; refusing to tare on them')
        rows = range(len(self.names)) if names is None else [self.names.index(n) for n in names]
        for k in rows:
            taxels = self.hand.arrays[k].flat_indices
            self._tare[taxels] = frames[:, taxels].mean(axis=0)
        self._centre = self._tare + self._mean
        if self.lowpass is not None:      # the input steps with the tare: start over from it
            self.lowpass.restart(np.isin(self._channel_array, rows))

    def tare(self, name: str) -> np.ndarray:
        """Current tare (n, 3) [counts] of one array."""
        return self._tare[self.hand.array(name).flat_indices].copy()

    # --- tick ------------------------------------------------------------------------------

    def worst_taxel(self, k: int) -> int:
        """The taxel (index within array `k`) with the largest standardised input |z| of the
        last estimate(): the one its OOD score comes from."""
        rows = self.hand.arrays[k].flat_indices
        return int(np.abs(self._frame[rows]).max(axis=1).argmax())

    def estimate(self, counts: np.ndarray) -> HandEstimate:
        """Whole-hand flat counts (368, 3) -> per-array forces, validity and OOD scores."""
        counts = np.asarray(counts)
        n_arrays = self._n_arrays
        if counts.shape != self._shape:
            reason = f'input has shape {counts.shape}, expected ({self.n_taxels}, 3)'
            return HandEstimate(force=np.zeros((n_arrays, 3)), valid=np.zeros(n_arrays, bool),
                                status=(reason,) * n_arrays, ood_score=np.zeros(n_arrays))
        x, frame = self._x, self._frame
        np.subtract(counts, self._centre, out=frame)    # copies and casts to float64 too
        np.multiply(frame, self._inv_std, out=frame)
        if self.lowpass is not None:
            self.lowpass(self._frame_1d)
        # mode='clip' skips per-element bounds errors (the indices are built valid): ~1 us less
        self._take(self._gather, out=x, mode='clip')
        # NaN/Inf stay inside their own array's rows, so the OOD score doubles as the check.
        ood = np.maximum.reduceat(np.abs(self._x_1d, out=self._abs), self._segments)
        valid = np.isfinite(ood)
        status = self._all_ok
        if np.count_nonzero(valid) < n_arrays:     # cheaper than valid.all() on 18 flags
            x[~valid] = 0.0
            ood[~valid] = np.inf     # no finite input: as far out of distribution as it gets
            status = tuple(STATUS_OK if ok else 'input contains NaN or Inf' for ok in valid)
            if self.lowpass is not None:      # not carried into the next frames
                self.lowpass.restart(~valid[self._channel_array])
        if len(self._groups) == 1:
            force = self._groups[0][1](x)
        else:
            force = np.empty((n_arrays, 3))
            for rows, predict in self._groups:
                force[rows] = predict(x[rows])
        if status is not self._all_ok:
            force[~valid] = 0.0
        if not isfinite(self._sum(force, None)):    # one reduction; NaN and Inf propagate
            bad = ~np.isfinite(force).all(axis=1)
            valid = valid & ~bad
            force[bad] = 0.0
            status = tuple(STATUS_NOT_FINITE if b else s for b, s in zip(bad, status))
        return HandEstimate(force=force, valid=valid, status=status, ood_score=ood)
