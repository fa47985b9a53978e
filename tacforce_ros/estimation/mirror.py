"""The mirror hand's recordings read in this hand's layout, so a kind's shared model learns from
both hands' arrays.

A left hand's module is the right hand's reflected across its {S0} x-z plane, with the same
taxel numbering (config/hand/allegro_left_uskin.yaml): taxel k sits at M p_k, its frame is
M R_k M, M = diag(1, -1, 1). The magnets keep their polarity along z, which M leaves alone, so
the field of a reflected press at a reflected magnet is the reflected field (a dipole's field is
B(M r) = M B(r) when M m = m). The reflected taxel frame's axes are M x, -M y and M z, so its
reading of M B is the other hand's reading of B with the y component negated; the force in {S0}
is M F. A left array's recording with every y component negated (the raw counts too: each
session's offsets are removed before any fit) is what the right hand's array of the module reads
under the mirrored press, and it joins that kind's pool.

Why pool them: a kind of three arrays (the palm pads) shares a model learnt from two; the
mirror hand's three cut the palm pads' error at 100 s per array by almost half in simulation, and
reflected they beat the same recordings unreflected (docs/MEASUREMENT_HISTORY.md,
2026-11-29 evening).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from tacforce_ros.estimation.dataset import CalibrationDataset
    from tacforce_ros.hand.description import TaxelArray

REFLECTION = np.diag([1.0, -1.0, 1.0])     # across the x-z plane of {S0}
LAYOUT_TOL = 1e-9                           # m and rotation entries: the descriptions' rounding


class MirrorError(ValueError):
    """Two arrays that are not each other's mirror image, so one's data cannot join the other's."""


def check_mirror(source: TaxelArray, target: TaxelArray) -> None:
    """Refuse unless `source` is `target` reflected: the other hand, the same kind and taxel
    count, each taxel at the reflected place with the reflected frame."""
    if source.hand_side == target.hand_side:
        raise MirrorError(f'{source.name} and {target.name} are both of the {source.hand_side} '
                          'hand: nothing to reflect')
    if (source.kind, source.n_taxels) != (target.kind, target.n_taxels):
        raise MirrorError(f'{source.hand_side} {source.name} ({source.kind}, {source.n_taxels} '
                          f'taxels) is not of the kind of {target.hand_side} {target.name} '
                          f'({target.kind}, {target.n_taxels} taxels)')
    place = np.abs(source.positions - target.positions @ REFLECTION).max()
    frame = np.abs(source.rotations - REFLECTION @ target.rotations @ REFLECTION).max()
    if not (place <= LAYOUT_TOL and frame <= LAYOUT_TOL):
        raise MirrorError(f'{source.hand_side} {source.name} is not {target.hand_side} '
                          f'{target.name} reflected (taxels off by {place:.3g} m, frames by '
                          f'{frame:.3g}): its hand description does not mirror the module')


def reflect(X: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Readings (N, n, 3) and forces (N, 3) with their y components negated (new arrays)."""
    X = np.array(X, dtype=np.float64)
    F = np.array(F, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3 or F.shape != (len(X), 3):
        raise ValueError(f'readings (N, n, 3) and forces (N, 3) expected, got {X.shape} and '
                         f'{F.shape}')
    X[:, :, 1] *= -1.0
    F[:, 1] *= -1.0
    return X, F


def mirrored(dataset: CalibrationDataset, source: TaxelArray, target: TaxelArray
             ) -> CalibrationDataset:
    """`dataset`, recorded on `source`, as `target` (its mirror image) would read it."""
    import dataclasses

    if dataset.array != source.name or dataset.hand_side != source.hand_side:
        raise MirrorError(f'the recording is of the {dataset.hand_side} hand\'s {dataset.array}, '
                          f'not of the {source.hand_side} hand\'s {source.name}')
    check_mirror(source, target)
    X, F = reflect(dataset.X, dataset.F)
    return dataclasses.replace(dataset, array=target.name, X=X, F=F,
                               hand_side=target.hand_side)


def to_layout(dataset: CalibrationDataset, source: TaxelArray, target: TaxelArray
              ) -> CalibrationDataset:
    """`dataset`, recorded on `source` of another hand, in `target`'s layout: reflected when the
    hands are mirror images (`mirrored`), as it is when `source` has `target`'s layout (a second
    hand of the same side). Refused (MirrorError) otherwise."""
    import dataclasses

    if source.hand_side != target.hand_side:
        return mirrored(dataset, source, target)
    if (source.kind, source.n_taxels) != (target.kind, target.n_taxels) or not (
            np.abs(source.positions - target.positions).max() <= LAYOUT_TOL
            and np.abs(source.rotations - target.rotations).max() <= LAYOUT_TOL):
        raise MirrorError(f'{source.name} does not have the layout of {target.name}')
    return dataclasses.replace(dataset, array=target.name)
