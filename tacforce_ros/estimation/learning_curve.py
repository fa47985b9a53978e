"""Learning curves: how a model's held-out error falls with the labelled seconds it was trained
on, which is what calibration costs its users (the paper pressed each array 2000 s, five plates
of 4 x 100 s, and never measured how much its models need).

A point of the curve is a recording an operator stops after `seconds` in all, spread evenly over
the plates: on each plate its sessions in the order they were recorded, cut after seconds / plates
(first_seconds). Offsets are each session's, from its rest wherever it falls: the operator's
rest is not pressing, and one before the first press costs no labelled time (a simulated session
may press from its first second and rest later: offsets from a 5 s cut of it would not exist).
The error is the paper's leave-one-plate-out e_hat: each fold trains on the cut of the other
plates and is tested on all of the held-out plate's data, so a small cut is judged on as much
data as a large one. At the full recording the point is Table I's.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.cross_validation import CrossValidation, cross_validate
from tacforce_ros.estimation.dataset import CalibrationDataset
from tacforce_ros.estimation.shared_model import Data, KindBlocks, shared_folds

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
    return _rows_of(dataset, cut_rows(dataset, per_plate))


def _rows_of(dataset: CalibrationDataset, keep: np.ndarray) -> CalibrationDataset:
    return CalibrationDataset(array=dataset.array, X=dataset.X[keep], F=dataset.F[keep],
                              plates=dataset.plates[keep], sessions=dataset.sessions[keep],
                              time=dataset.time[keep], source=dataset.source,
                              hand_side=dataset.hand_side)


def cut_rows(dataset: CalibrationDataset, per_plate: float) -> np.ndarray:
    """The rows first_seconds keeps (bool, one per sample)."""
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
    return keep


def learning_curve(array: TaxelArray, dataset: CalibrationDataset,
                   models: Mapping[str, tuple[str, dict[str, Any]]],
                   seconds: Sequence[float] = SECONDS, **static_kw: Any
                   ) -> list[dict[str, Any]]:
    """One row per point and model (models: label -> (kind, hyperparameters)): `seconds` asked,
    `recorded_s` (the cut: less where the recording is shorter), `e_hat_n` and `e_r` (means over
    the folds), `samples`. static_kw: how offsets find rest (CalibrationDataset.without_offsets);
    StaticSegmentError when a session has none."""
    plates = dataset.plate_names()
    if len(plates) < 2:
        raise ValueError(f'{dataset.array}: a learning curve needs >= 2 plates, got {plates}')
    X_all, F_all, _ = dataset.without_offsets(**static_kw)
    held_out = (X_all, F_all, dataset.plates)
    rows = []
    for total in seconds:
        keep = cut_rows(dataset, total / len(plates))
        cut = _rows_of(dataset, keep)
        point = {'array': dataset.array, 'seconds': float(total),
                 'recorded_s': recorded_seconds(cut), 'samples': int(keep.sum())}
        for label, (kind, hyper) in models.items():
            summary = cross_validate(array, kind, hyper, X_all[keep], F_all[keep],
                                     dataset.plates[keep], held_out=held_out).summary()
            rows.append({**point, 'model': label, 'way': 'own', 'e_hat_n': summary['e_hat_mean'],
                         'e_r': summary['e_r_mean']})
    return rows


def shared_learning_curve(array: TaxelArray, dataset: CalibrationDataset, label: str, kind: str,
                          hyper: dict[str, Any], others: Mapping[str, tuple[np.ndarray, ...]],
                          seconds: Sequence[float] = SECONDS, **static_kw: Any
                          ) -> list[dict[str, Any]]:
    """learning_curve's points for the model shared by the kind's other arrays (`others`:
    name -> (X offsets removed, F, plates)) and adapted to the array's cut (shared_model.py):
    the same cuts, folds and held-out data as the array's own model. Rows as learning_curve's,
    `way` 'shared', with each fold's adaptation weight (None: unadapted)."""
    plates = dataset.plate_names()
    if len(plates) < 2:
        raise ValueError(f'{dataset.array}: a learning curve needs >= 2 plates, got {plates}')
    X_all, F_all, _ = dataset.without_offsets(**static_kw)
    keeps = [cut_rows(dataset, total / len(plates)) for total in seconds]
    results = shared_folds(array, kind, hyper, (X_all, F_all, dataset.plates), keeps, others)
    rows = []
    for total, keep, result in zip(seconds, keeps, results):
        summary = result.summary()
        rows.append({'array': dataset.array, 'seconds': float(total),
                     'recorded_s': recorded_seconds(_rows_of(dataset, keep)),
                     'samples': int(keep.sum()), 'model': label, 'way': 'shared',
                     'e_hat_n': summary['e_hat_mean'], 'e_r': summary['e_r_mean'],
                     'adapt_weights': [f['hyperparameters']['adapt_weight']
                                       for f in summary['per_fold']]})
    return rows


def kind_folds(arrays: Mapping[str, TaxelArray], kind: str, hyper: dict[str, Any],
               recorded: Mapping[str, Data], held_out: Mapping[str, Data],
               pool: Mapping[str, Data] | None = None) -> dict[str, CrossValidation]:
    """Leave-one-plate-out of each array's model in a campaign where every array of a kind
    recorded `recorded` (name -> (X offsets removed, F, plates); three or more arrays with the
    pool): the model the other arrays' recordings share, adapted to its own (shared_model.py,
    the weight chosen on the recordings alone, as the campaign would have it), tested on
    `held_out[name]`'s rows of each plate. `pool`: recordings of the kind made before (the
    mirror hand's, in this hand's layout: estimation/mirror.py), shared by every array's model
    and in the weight's choice like the others', and not judged."""
    pool = dict(pool or {})
    clash = sorted(set(pool) & set(recorded))
    if clash:
        raise ValueError(f'pool names {clash} are also arrays of the campaign')
    if not arrays or len(arrays) + len(pool) < 3:
        raise ValueError(f'a kind of three or more arrays is needed, got {sorted(arrays)}'
                         + (f' and the pool {sorted(pool)}' if pool else ''))
    shared = {**recorded, **pool}
    blocks = KindBlocks(next(iter(arrays.values())), kind, hyper, shared)
    results = {}
    for name, array in arrays.items():
        others = {o: data for o, data in shared.items() if o != name}
        (results[name],) = shared_folds(array, kind, hyper, recorded[name],
                                        [np.ones(len(recorded[name][1]), bool)], others,
                                        blocks=blocks, held_out=held_out[name])
    return results


def kind_curve(arrays: Mapping[str, tuple[TaxelArray, CalibrationDataset]], label: str,
               kind: str, hyper: dict[str, Any], seconds: Sequence[float] = SECONDS,
               pool: Mapping[str, CalibrationDataset] | None = None,
               **static_kw: Any) -> list[dict[str, Any]]:
    """The curve a campaign with a budget plans on: every array of a kind (`arrays`: name ->
    (array, its recording), three or more) cut to the same `seconds`, judged by kind_folds on
    all of its held-out plate's data. `pool`: kind_folds', whole recordings (the mirror hand's
    calibration, made before). Rows as learning_curve's, `way` 'shared-kind' ('shared-kind+pool'
    with a pool), with the array's `kind`."""
    pool = dict(pool or {})
    plates = {name: tuple(dataset.plate_names()) for name, (_, dataset) in arrays.items()}
    plates.update({name: tuple(dataset.plate_names()) for name, dataset in pool.items()})
    if len(set(plates.values())) != 1 or len(next(iter(plates.values()))) < 2:
        raise ValueError(f'the arrays of a kind curve need the same two or more plates: {plates}')
    per_plate = len(next(iter(plates.values())))
    full = {name: dataset.without_offsets(**static_kw)[:2] + (dataset.plates,)
            for name, (_, dataset) in arrays.items()}
    pooled = {name: dataset.without_offsets(**static_kw)[:2] + (dataset.plates,)
              for name, dataset in pool.items()}
    rows = []
    for total in seconds:
        keeps = {name: cut_rows(dataset, total / per_plate)
                 for name, (_, dataset) in arrays.items()}
        cut = {name: tuple(part[keeps[name]] for part in full[name]) for name in arrays}
        results = kind_folds({n: a for n, (a, _) in arrays.items()}, kind, hyper, cut, full,
                             pooled)
        for name, (array, dataset) in arrays.items():
            summary = results[name].summary()
            rows.append({'array': name, 'kind': array.kind, 'seconds': float(total),
                         'recorded_s': recorded_seconds(_rows_of(dataset, keeps[name])),
                         'samples': int(keeps[name].sum()), 'model': label,
                         'way': 'shared-kind+pool' if pool else 'shared-kind',
                         'e_hat_n': summary['e_hat_mean'],
                         'e_r': summary['e_r_mean']})
    return rows


def curve_table(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown: a row per array and model, a column per point (e_hat in N; '-' where the cut
    could not train; the seconds actually recorded where less than asked)."""
    points = sorted({r['seconds'] for r in rows})
    lines = ['| array | model | way | ' + ' | '.join(f'{s:g} s' for s in points) + ' |',
             '|---|---|---|' + '---|' * len(points)]
    groups = dict.fromkeys((r['array'], r['model'], r.get('way', 'own')) for r in rows)
    for array, model, way in groups:
        cells = []
        for s in points:
            row = next((r for r in rows if (r['array'], r['model'], r.get('way', 'own'), r[
                'seconds']) == (array, model, way, s)), None)
            if row is None or row['e_hat_n'] is None:
                cells.append('-')
                continue
            short = row['recorded_s'] < 0.99 * s
            cells.append(f"{row['e_hat_n']:.3f}" + (f" ({row['recorded_s']:.0f} s)" if short
                                                     else ''))
        lines.append(f'| {array} | {model} | {way} | ' + ' | '.join(cells) + ' |')
    return lines


def plot_curves(rows: list[dict[str, Any]], path: Path, title: str, panel: str = 'array'
                ) -> Path:
    """e_hat against labelled seconds (log axis), a panel per array (or per `panel` key: 'kind'
    for kind curves, a line per array), a line per model and way."""
    import matplotlib.pyplot as plt
    panels = list(dict.fromkeys(r[panel] for r in rows))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.0 * len(panels), 3.8), squeeze=False)

    def line_of(r: dict[str, Any]) -> tuple[str, ...]:
        return (r['model'], r.get('way', 'own')) + ((r['array'],) if panel != 'array' else ())

    for ax, name in zip(axes[0], panels):
        mine = [r for r in rows if r[panel] == name and r['e_hat_n'] is not None]
        for key in dict.fromkeys(line_of(r) for r in mine):
            line = sorted((r['recorded_s'], r['e_hat_n']) for r in mine if line_of(r) == key)
            label = f'{key[0]} ({key[1]})' + (f' {key[2]}' if len(key) > 2 else '')
            ax.plot(*zip(*line), marker='o', label=label)
        ax.set_xscale('log')
        ax.set_xlabel('labelled seconds on the array')
        ax.set_ylabel('held-out e_hat [N]')
        ax.set_title(name)
        ax.grid(True, which='both', alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
