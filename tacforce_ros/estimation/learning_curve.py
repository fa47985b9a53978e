"""Learning curves: how a model's held-out error falls with the labelled seconds it was trained
on, which is what calibration costs its users (the paper pressed each array 2000 s, five plates
of 4 x 100 s, and never measured how much its models need).

A point of the curve is a recording an operator stops after `seconds` in all, spread evenly over
the plates: on each plate its sessions in the order they were recorded, cut after seconds / plates
(first_seconds). Offsets come from that cut alone, as the operator has nothing else. The error is
the paper's leave-one-plate-out e_hat: each fold trains on the cut of the other plates and is
tested on all of the held-out plate's data (offsets from its full sessions), so a small cut is
judged on as much data as a large one. At the full recording the point is Table I's.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.dataset import CalibrationDataset
from tacforce_ros.estimation.preprocessing import StaticSegmentError

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray

# Labelled seconds per array (the points; 2000 s is the paper's campaign).
SECONDS = (25.0, 50.0, 100.0, 200.0, 400.0, 800.0, 2000.0)


def recorded_seconds(dataset: CalibrationDataset) -> float:
    """Seconds recorded: each session's span plus one sample period."""
    total = 0.0
    for session in np.unique(dataset.sessions):
        t = dataset.time[dataset.sessions == session]
        total += float(t[-1] - t[0] + (np.median(np.diff(t)) if t.size > 1 else 0.0))
    return total


def first_seconds(dataset: CalibrationDataset, per_plate: float) -> CalibrationDataset:
    """The recording cut after `per_plate` seconds on each plate: its sessions in the order they
    were recorded, whole until the budget runs out, then the start of the next."""
    if not per_plate > 0:
        raise ValueError(f'per_plate {per_plate!r}: must be > 0 s')
    keep = np.zeros(dataset.F.shape[0], bool)
    for plate in dataset.plate_names():
        left = per_plate
        on_plate = dataset.plates == plate
        for session in dict.fromkeys(dataset.sessions[on_plate].tolist()):
            rows = np.flatnonzero(on_plate & (dataset.sessions == session))
            t = dataset.time[rows] - dataset.time[rows[0]]
            period = float(np.median(np.diff(t))) if t.size > 1 else 0.0
            keep[rows[t < left - 0.5 * period]] = True
            left -= float(t[-1]) + period
            if left <= 0:
                break
    return CalibrationDataset(array=dataset.array, X=dataset.X[keep], F=dataset.F[keep],
                              plates=dataset.plates[keep], sessions=dataset.sessions[keep],
                              time=dataset.time[keep], source=dataset.source,
                              hand_side=dataset.hand_side)


def learning_curve(array: TaxelArray, dataset: CalibrationDataset,
                   models: Mapping[str, tuple[str, dict[str, Any]]],
                   seconds: Sequence[float] = SECONDS, **static_kw: Any
                   ) -> list[dict[str, Any]]:
    """One row per point and model (models: label -> (kind, hyperparameters)): `seconds` asked,
    `recorded_s` (the cut: less where the recording is shorter), `e_hat_n` and `e_r` (means over
    the folds), `samples`; `e_hat_n` None with a `reason` where the cut cannot train (no rest to
    take offsets from). static_kw: how offsets find rest (CalibrationDataset.without_offsets)."""
    plates = dataset.plate_names()
    if len(plates) < 2:
        raise ValueError(f'{dataset.array}: a learning curve needs >= 2 plates, got {plates}')
    X_all, F_all, _ = dataset.without_offsets(**static_kw)
    held_out = (X_all, F_all, dataset.plates)
    rows = []
    for total in seconds:
        cut = first_seconds(dataset, total / len(plates))
        point = {'array': dataset.array, 'seconds': float(total),
                 'recorded_s': recorded_seconds(cut), 'samples': int(cut.F.shape[0])}
        try:
            X, F, _ = cut.without_offsets(**static_kw)
        except StaticSegmentError as exc:
            rows += [{**point, 'model': label, 'e_hat_n': None, 'e_r': None,
                      'reason': f'no offsets from the cut: {exc}'} for label in models]
            continue
        for label, (kind, hyper) in models.items():
            summary = cross_validate(array, kind, hyper, X, F, cut.plates,
                                     held_out=held_out).summary()
            rows.append({**point, 'model': label, 'e_hat_n': summary['e_hat_mean'],
                         'e_r': summary['e_r_mean']})
    return rows
