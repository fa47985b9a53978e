"""bench: accuracy against inference cost of M1, M2, M3, M3-lambda, M4, M5 (paper Table I + cost).

Every model goes through the leave-one-plate-out protocol on one array's dataset; then its cost is
timed: one `predict` on one sample, the compiled batch of one, and a full-hand tick of the runtime
estimator (18 arrays of that kind, one batched pass), without and with the estimator's causal
input low-pass (`--lowpass-hz`; its group delay is in the JSON), all timed round-robin so every
model sees the same machine load. Writes bench.json, bench.md and bench.png.

Full-hand models are fitted on short synthetic recordings of every array: the cost of a tick does
not depend on the weights' values, only on the shapes. `--model-sets` also times the tick of
model lists as the estimator node loads them (e.g. the shipped config/models/default.yaml), in
the same round-robin.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tacforce_ros.estimation.causal_filter import BatchLowPass
from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.dataset import CalibrationDataset, DatasetError
from tacforce_ros.estimation.preprocessing import CUTOFF_HZ, SAMPLE_RATE_HZ
from tacforce_ros.estimation.registry import PAPER_LABELS, paper_configurations
from tacforce_ros.estimation.runtime import RuntimeEstimator
from tacforce_ros.estimation.synthetic import synthetic_dataset, synthetic_hand_estimator
from tacforce_ros.estimation.training import fit_bundle
from tacforce_ros.paths import output_folder
from tacforce_ros.timing import time_interleaved


def bench_model(array, hand, label: str, kind: str, hyper: dict, dataset: CalibrationDataset,
                X: np.ndarray, F: np.ndarray, offset: np.ndarray, seed: int,
                lowpass: tuple[float, int] | None) -> tuple[dict, dict[str, Callable[[], object]]]:
    """Cross-validated accuracy row of one model, and the calls whose cost is to be timed;
    `lowpass` = (cut-off Hz, order) adds the full-hand tick with the input low-pass on."""
    cv = cross_validate(array, kind, hyper, X, F, dataset.plates).summary()
    bundle = fit_bundle(array, kind, hyper, X, F, dataset.plates, x_offset=offset)
    one = bundle.x_scaler.transform(X[:1])
    batch_one = type(bundle.model).compile_batch([bundle.model])
    estimator = synthetic_hand_estimator(hand, kind, hyper, seed)
    frame = np.clip(np.round(hand.merge([b.x_offset for b in estimator.bundles])), 0, 65535
                    ).astype(np.uint16)
    calls = {'predict_one': lambda: bundle.model.predict(one),
             'batch_one': lambda: batch_one(one),
             'full_hand_tick': lambda: estimator.estimate(frame)}
    if lowpass is not None:
        filtered = RuntimeEstimator(hand, estimator.bundles)
        filtered.set_lowpass(lowpass[0], SAMPLE_RATE_HZ, lowpass[1])
        calls['full_hand_tick_lowpass'] = lambda: filtered.estimate(frame)
    return {'label': label, 'kind': kind, 'hyperparameters': hyper, **cv}, calls


def table(rows: list[dict], title: str) -> str:
    lines = [f'## {title}', '',
             '| model | e_r [%] | e_hat [N] | MAE x / y / z [N] | p | train [s/fold] '
             '| predict 1 [us] | batch of 1 [us] | full hand [us] median (p99) '
             '| with low-pass [us] (ratio) |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        e_r = '-' if r['e_r_mean'] is None else \
            f"{100 * r['e_r_mean']:.1f} ± {100 * r['e_r_std']:.1f}"
        lines.append(
            f"| {r['label']} | {e_r} | {r['e_hat_mean']:.3f} ± {r['e_hat_std']:.3f} | "
            + ' / '.join(f'{v:.3f}' for v in r['mae_axis'])
            + f" | {r['n_parameters']} | {r['train_seconds']:.2f} | "
            f"{r['predict_one']['median_us']:.1f} | {r['batch_one']['median_us']:.1f} | "
            f"{r['full_hand_tick']['median_us']:.1f} ({r['full_hand_tick']['p99_us']:.1f}) | "
            + (lowpass_cell(r) if 'full_hand_tick_lowpass' in r else '-') + ' |')
    return '\n'.join(lines) + '\n'


def model_set_call(path: Path, hand) -> tuple[dict, Callable[[], object]]:
    """A models YAML as the estimator node loads it: its row, and its full-hand tick on a frame
    at every modelled array's rest reading."""
    from tacforce_ros.estimation.model_set import load_model_set
    models = load_model_set(path, hand)
    frame = np.zeros((hand.n_taxels, 3))
    for array, bundle in zip(models.arrays, models.estimator.bundles):
        frame[array.flat_indices] = bundle.x_offset
    frame = np.clip(np.round(frame), 1, 65534).astype(np.uint16)
    # As the node runs it: the taxel check on, and frames that differ (a live skin's noise),
    # so the tick timed is the healthy one.
    models.check_taxels()
    frames = itertools.cycle((frame, frame + 1))
    kinds = sorted(set(models.kinds))
    row = {'file': str(path), 'arrays': len(models.arrays), 'skipped': list(models.skipped),
           'kinds': kinds}
    return row, lambda: models.estimate(next(frames))


def model_set_table(rows: list[dict]) -> str:
    lines = ['## Model lists as the estimator loads them', '',
             '| file | arrays | kinds | full hand [us] median (p99) |', '|---|---|---|---|']
    for r in rows:
        tick = r['full_hand_tick']
        lines.append(f"| {r['file']} | {r['arrays']} | {', '.join(r['kinds'])} | "
                     f"{tick['median_us']:.1f} ({tick['p99_us']:.1f}) |")
    return '\n'.join(lines) + '\n'


def lowpass_cell(row: dict) -> str:
    filtered = row['full_hand_tick_lowpass']['median_us']
    plain = row['full_hand_tick']['median_us']
    return f'{filtered:.1f} (x {filtered / plain:.2f})'


def plot(rows: list[dict], array: str, source: str, path: Path) -> None:
    """The report's accuracy-against-time panel for this benchmark's rows."""
    from tacforce_ros.experiments.paper_reference import TABLE_I
    from tacforce_ros.experiments.plots import accuracy_vs_time
    table = {array: {r['label']: {
        'sim': {'e_hat': r['e_hat_mean'], 'per_plate': r['per_fold'],
                'tau_full_hand_ms': r['full_hand_tick']['median_us'] / 1e3,
                'tau_single_ms': r['predict_one']['median_us'] / 1e3},
        'paper': TABLE_I.get(array, {}).get(r['label'])} for r in rows}}
    accuracy_vs_time(table, None, path, source)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='bench', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--dataset', type=Path, help='processed dataset .npz (one array)')
    source.add_argument('--synthetic', action='store_true',
                        help='SYNTHETIC data (estimation/synthetic.py), until simulator bags exist')
    parser.add_argument('--array', default='index_tip', help='array for --synthetic')
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='synthetic seconds per plate (default 60)')
    parser.add_argument('--models', nargs='+', default=list(PAPER_LABELS), choices=PAPER_LABELS,
                        help='rows to run; M3-lambda-cv selects the damping by nested CV')
    parser.add_argument('--epochs', type=int, default=40, help='M4/M5 epochs (paper: 40)')
    parser.add_argument('--repeats', type=int, default=2000,
                        help='timed calls per measurement, interleaved across models')
    parser.add_argument('--lowpass-hz', type=float, default=CUTOFF_HZ,
                        help='also time the tick with the estimator\'s input low-pass at this '
                        'cut-off (Hz, XELA frames at 100 Hz; default: the training data\'s); '
                        '0 = not')
    parser.add_argument('--lowpass-order', type=int, default=2)
    parser.add_argument('--model-sets', nargs='+', type=Path, default=[],
                        help='models YAML files (estimation/model_set.py) whose full-hand tick '
                        'is timed too, e.g. config/models/default.yaml')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--out', type=output_folder, default='bench_out')
    args = parser.parse_args(argv)
    lowpass = (args.lowpass_hz, args.lowpass_order) if args.lowpass_hz > 0 else None
    try:
        design = None if lowpass is None else BatchLowPass(1, lowpass[0], SAMPLE_RATE_HZ,
                                                           lowpass[1])
    except ValueError as exc:
        parser.error(f'--lowpass-hz: {exc}')

    from tacforce_ros.hand.description import hand_config, load_hand
    try:
        if args.synthetic:
            hand = load_hand()
            array = hand.array(args.array)
            dataset = synthetic_dataset(array, seconds=args.seconds, seed=args.seed)
        else:
            dataset = CalibrationDataset.load(args.dataset)
            hand = load_hand(hand_config(dataset.hand_side))     # the dataset's own hand
            array = hand.array(dataset.array)
        X, F, offset = dataset.without_offsets()
        model_sets = [model_set_call(path, hand) for path in args.model_sets]
    except (DatasetError, ValueError, KeyError, OSError) as exc:
        print(f'bench: {exc}', file=sys.stderr)
        return 2
    configs = paper_configurations(args.seed, args.epochs)
    rows, calls = [], {}
    for label in tqdm(args.models, desc='models', unit='model'):
        kind, hyper = configs[label]
        row, timed = bench_model(array, hand, label, kind, hyper, dataset, X, F, offset,
                                 args.seed, lowpass)
        rows.append(row)
        calls.update({(label, key): call for key, call in timed.items()})
    calls.update({('model_set', k): call for k, (_, call) in enumerate(model_sets)})
    timings = time_interleaved(calls, args.repeats)
    set_rows = [{**row, 'full_hand_tick': timings[('model_set', k)]}
                for k, (row, _) in enumerate(model_sets)]
    for row in rows:
        row.update({key: timing for (label, key), timing in timings.items()
                    if label == row['label']})
    title = (f"{array.name} ({array.n_taxels} taxels), {dataset.source} data, "
             f"{len(dataset.plate_names())}-fold leave-one-plate-out")
    result = {'array': array.name, 'n_taxels': array.n_taxels, 'source': dataset.source,
              'samples': int(X.shape[0]), 'plates': dataset.plate_names(), 'seed': args.seed,
              'repeats': args.repeats, 'models': rows, 'model_sets': set_rows,
              'lowpass': None if design is None else {
                  'cutoff_hz': design.cutoff_hz, 'order': design.order,
                  'frame_rate_hz': design.rate_hz,
                  'group_delay_ms': design.group_delay_s() * 1e3}}
    (args.out / 'bench.json').write_text(json.dumps(result, indent=2))
    text = table(rows, title) + ('\n' + model_set_table(set_rows) if set_rows else '')
    (args.out / 'bench.md').write_text(text)
    plot(rows, array.name, dataset.source.upper(), args.out / 'bench.png')
    print(text)
    print(f"wrote {args.out / 'bench.json'}, bench.md, bench.png")
    return 0


if __name__ == '__main__':
    sys.exit(main())
