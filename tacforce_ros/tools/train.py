"""train: calibration bags or processed datasets -> one model file per array and kind + report.

Inputs are rosbag2 calibration bags (folders, docs/CONTRACTS.md) and/or processed dataset .npz
files (estimation/dataset.py), all of one hand: the one they name (the bags' session metadata,
the datasets' headers; none named: the right hand), or `--hand-side`; the models are its.
A campaign folder (`campaign`) stands for the bags of it that count (coverage verdict passed).
Per array: offsets from static segments per session, optional leave-one-plate-out
cross-validation (metrics go into the model's provenance), then a final fit on all plates.
With `--shared`, an array's model is instead the one the other arrays of its kind share,
adapted to its own data (estimation/shared_model.py): fewer seconds of pressing per array. A
campaign planned with a budget (`campaign plan --budget`) implies `--shared`. `--pool` adds
another hand's calibration to every shared model, the mirror hand's reflected into this hand's
layout (estimation/mirror.py): a lab that calibrated the left hand presses the right less.
Each model's provenance says which way it was made (`way`: own, shared or adapted) and how many
seconds of its own array's data went into it (`own_seconds`).
Writes `<array>_<kind>.npz`, a models list per kind for the estimator (`models_<kind>.yaml`),
report.md/json (arrays grouped by type: curved fingertips, flat phalanx pads, palm pads; and
M1's normal input per newton per array and plate, to set beside skin_sensitivity's for the
simulated skin) and, with cross-validation, a picture of the hand coloured by each array's
held-out error (`hand_<kind>.png`).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tacforce_ros import results
from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.dataset import CalibrationDataset, DatasetError, concatenate
from tacforce_ros.estimation.learning_curve import recorded_seconds
from tacforce_ros.estimation.m1_rotation_linear import NORMAL_INPUT_NOTE, normal_input_per_newton
from tacforce_ros.estimation.model_io import save_model
from tacforce_ros.estimation.model_set import write_model_config
from tacforce_ros.estimation.preprocessing import StaticSegmentError
from tacforce_ros.estimation.registry import MODEL_KINDS, TORCH_KINDS
from tacforce_ros.estimation.shared_model import BLOCK_KINDS, KindBlocks, fit_adapted
from tacforce_ros.estimation.training import fit_bundle, for_deployment
from tacforce_ros.hand.description import ARRAY_KIND_TITLES, SIDES
from tacforce_ros.paths import output_folder
from tacforce_ros.tools.calibration_inputs import (POOL_PREFIX, expand_campaigns, load_inputs,
                                                   load_pool, model_hyper)


def _budget_of(path: Path) -> dict:
    """The budget of a campaign planned with one; {} for anything else."""
    from tacforce_ros.recording.campaign import CampaignError, CampaignPlan, is_campaign
    try:
        return dict(CampaignPlan.load(path).budget or {}) if is_campaign(path) else {}
    except CampaignError:
        return {}           # expand_campaigns says what is wrong with it


def markdown_report(report: dict) -> str:
    lines = ['# Training report', '', f"code {report['code_version']}, {report['date']}, "
             f"seed {report['seed']}, {report['hand_side']} hand; held-out errors from the "
             'leave-one-plate-out benchmark', '',
             '| array | kind | made | plates | samples | e_r [%] | e_hat [N] | MAE x/y/z [N] '
             '| file |', '|---|---|---|---|---|---|---|---|---|']
    for group, title in ARRAY_KIND_TITLES.items():
        entries = [e for e in report['models'] if e['array_type'] == group]
        if entries:
            lines.append(f'| **{title}** ({len({e["array"] for e in entries})}) '
                         '| | | | | | | | |')
        lines += [_report_row(entry) for entry in entries]
    gains = report['normal_input_per_newton']
    plates = list(dict.fromkeys(p for g in gains.values() for p in g))
    if gains:
        lines += ['', "## M1's normal input per newton, by plate", '', NORMAL_INPUT_NOTE, '',
                  '| array | ' + ' | '.join(plates) + ' |', '|' + '---|' * (len(plates) + 1)]
        lines += [f'| {name} | ' + ' | '.join(
            '-' if g.get(p) is None else f'{g[p]:.0f}' for p in plates) + ' |'
                  for name, g in gains.items()]
    return '\n'.join(lines) + '\n'


def write_model_lists(folder: Path, report: dict) -> list[Path]:
    """models_<kind>.yaml per kind: the estimator's model list (estimation/model_set.py)."""
    paths = []
    for kind in sorted({e['kind'] for e in report['models']}):
        models = {e['array']: e['file'] for e in report['models'] if e['kind'] == kind}
        paths.append(write_model_config(
            folder / f'models_{kind}.yaml', models,
            f"{kind} for {len(models)} arrays of the {report['hand_side']} hand: train, code "
            f"{report['code_version']}, {report['date']}"))
    return paths


def made(entry: dict) -> str:
    """Which way the model was made, with how much of its own array's data."""
    own = f"{entry['own_seconds']:g} s of its own"
    if entry['way'] == 'own':
        return f'own data, {own}'
    weight = '' if entry['adapt_weight'] is None else f" (weight {entry['adapt_weight']:g})"
    pooled = sum(name.startswith(POOL_PREFIX) for name in entry['shared_from'])
    return (f"{entry['way']}{weight}: from {len(entry['shared_from'])} other arrays"
            f"{f' ({pooled} of the pool)' if pooled else ''}, "
            f"{'adapted to ' if entry['way'] == 'adapted' else 'not adapted to '}{own}")


def _report_row(entry: dict) -> str:
    cv = entry['cross_validation']
    if cv:
        e_r = '-' if cv['e_r_mean'] is None else \
            f"{100 * cv['e_r_mean']:.1f} ± {100 * cv['e_r_std']:.1f}"
        e_hat = f"{cv['e_hat_mean']:.3f} ± {cv['e_hat_std']:.3f}"
        axes = ' / '.join(f'{v:.3f}' for v in cv['mae_axis'])
    else:
        e_r = e_hat = axes = 'not run'
    return (f"| {entry['array']} | {entry['kind']} | {made(entry)} | "
            f"{', '.join(entry['plates'])} | "
            f"{entry['samples']} | {e_r} | {e_hat} | {axes} | {entry['file']} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='train', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('inputs', nargs='+', type=Path,
                        help='calibration bag folders, campaign folders and/or processed dataset '
                        '.npz files')
    parser.add_argument('--out', type=output_folder, required=True,
                        help='folder for model files + report')
    parser.add_argument('--kinds', nargs='+', default=['M3-lambda'], choices=sorted(MODEL_KINDS),
                        help='model kinds to train (default: M3-lambda)')
    parser.add_argument('--arrays', nargs='+',
                        help='models for these arrays only (default: all found); with --shared '
                             'the others found still join their kind\'s shared model')
    parser.add_argument('--hand-side', choices=SIDES, default=None,
                        help='the hand of the inputs (default: the one they name)')
    parser.add_argument('--lam', type=float, default=33.0, help='M3-lambda damping (paper: 33)')
    parser.add_argument('--lambda-cv', action='store_true',
                        help='choose the M3-lambda damping by CV nested in the training plates')
    parser.add_argument('--no-cv', action='store_true', help='skip leave-one-plate-out CV')
    parser.add_argument('--shared', action='store_true',
                        help='each array: the model the other arrays of its kind share, adapted '
                             'to its own data (an array whose kind has fewer than 3 arrays in '
                             f'the inputs: its own); kinds {", ".join(BLOCK_KINDS)} only, a '
                             'fixed damping')
    parser.add_argument('--pool', nargs='+', type=Path, metavar='INPUT',
                        help='with --shared: another hand\'s calibration (the mirror hand\'s '
                             'campaign, bags or datasets, reflected into this hand\'s layout) '
                             'in every shared model; its arrays are not trained')
    parser.add_argument('--seed', type=int, default=0, help='seed of the random models (M4, M5)')
    parser.add_argument('--device', default='cpu',
                        help="torch device that trains M4 and M5: 'cpu' (default) or 'cuda', "
                             "'cuda:N'")
    parser.add_argument('--static-force', type=float, default=0.3,
                        help='static segments: force within this of the F/T no-contact '
                             'reading [N] (default 0.3)')
    parser.add_argument('--static-activity', type=float, default=15.0,
                        help='static segments: rms taxel deviation from rest below this [counts]')
    parser.add_argument('--static-seconds', type=float, default=0.5,
                        help='static segments: minimum duration [s] (default 0.5)')
    parser.add_argument('--save-dataset', action='store_true',
                        help='also write the processed dataset of each array (<out>/<array>.npz)')
    args = parser.parse_args(argv)

    budgets = {p: _budget_of(p) for p in args.inputs}
    budgeted = [p for p, budget in budgets.items() if budget]
    pooled = [p for p in budgeted if budgets[p].get('expected', {}).get('pooled')]
    if pooled and not args.pool:
        print(f'train: {pooled[0]} was planned on kind curves with the other hand\'s pool; '
              'without --pool its shared models lack those arrays and err more than planned',
              file=sys.stderr)
    if budgeted and not args.shared and not (set(args.kinds) - set(BLOCK_KINDS)
                                             or args.lambda_cv):
        # A budget plan pressed each array too little for a model of its own alone.
        args.shared = True
        print(f'train: {budgeted[0]} is a campaign with a budget: each array gets the model its '
              'kind shares, adapted to it (--shared)', file=sys.stderr)
    if args.shared and (set(args.kinds) - set(BLOCK_KINDS) or args.lambda_cv):
        parser.error(f'--shared adapts {", ".join(BLOCK_KINDS)} with a fixed damping only, not '
                     f'{", ".join(sorted(set(args.kinds) - set(BLOCK_KINDS)))}'
                     + (' nor --lambda-cv' if args.lambda_cv else ''))
    if args.pool and not args.shared:
        parser.error('--pool joins the shared models of --shared (or of a budget campaign)')
    missing = [str(p) for p in args.inputs + (args.pool or []) if not p.exists()]
    if missing:
        parser.error(f'inputs not found: {missing}')
    both = sorted({p.resolve() for p in args.inputs} & {p.resolve() for p in args.pool or []})
    if both:
        parser.error(f'{list(map(str, both))} both an input and in the pool: the pool is another '
                     'hand\'s calibration')
    if args.device != 'cpu' and set(args.kinds) & set(TORCH_KINDS):
        from tacforce_ros.estimation.torch_training import torch_device
        try:
            torch_device(args.device)
        except ValueError as exc:
            parser.error(str(exc))
    try:
        read: dict = {}
        hand, by_array, dropped = load_inputs(expand_campaigns(args.inputs, read),
                                              args.hand_side, read)
        pool = load_pool(args.pool, hand) if args.pool else {}
        plates = {p for datasets in by_array.values() for d in datasets for p in d.plate_names()}
        for name, dataset in pool.items():
            if not plates <= set(dataset.plate_names()):
                raise ValueError(f'{name} has no data on the plates '
                                 f'{sorted(plates - set(dataset.plate_names()))}: a pooled '
                                 'array is pressed on every plate of the inputs')
    except (DatasetError, ValueError, RuntimeError, OSError) as exc:
        print(f'train: {exc}', file=sys.stderr)
        return 2
    if dropped:
        print(f'train: dropped {dropped} malformed messages', file=sys.stderr)
    names = sorted(by_array) if not args.arrays else args.arrays
    unknown = sorted(set(names) - set(by_array))
    if unknown:
        print(f'train: no data for arrays {unknown}; found {sorted(by_array)}', file=sys.stderr)
        return 2

    version, date = results.commit(), time.strftime('%Y-%m-%dT%H:%M:%S%z')
    report = {'code_version': version, 'date': date, 'seed': args.seed, 'hand_side': hand.side,
              'inputs': [str(p) for p in args.inputs], 'dropped_messages': dropped, 'models': [],
              'pool': [str(p) for p in args.pool or []],
              'normal_input_per_newton': {}}
    def without_offsets(name: str, dataset: CalibrationDataset) -> tuple | None:
        """(X, F, x_offset) with each session's static offsets removed; None, said, when a
        session has no static segment."""
        try:
            return dataset.without_offsets(
                force_threshold=args.static_force, activity_threshold=args.static_activity,
                min_duration=args.static_seconds)
        except StaticSegmentError as exc:
            print(f'train: {name}: {exc}', file=sys.stderr)
            return None

    # --arrays picks the models to make; with --shared every array found joins its kind's
    # shared model all the same.
    prepared = {}
    for name in sorted(by_array) if args.shared else names:
        array = hand.array(name)
        dataset = concatenate(by_array[name])
        if dataset.n_taxels != array.n_taxels:
            print(f'train: dataset for {name} has {dataset.n_taxels} taxels, the hand '
                  f'description {array.n_taxels}', file=sys.stderr)
            return 2
        if args.save_dataset and name in names:
            dataset.save(args.out / f'{name}.npz')
        removed = without_offsets(name, dataset)
        if removed is None and name in names:
            return 2
        if removed is None:     # not asked for: it only leaves the shared model
            print(f'train: {name} left out of its kind\'s shared model', file=sys.stderr)
            continue
        X, F, x_offset = removed
        prepared[name] = (dataset, X, F, x_offset)
        if name in names:
            report['normal_input_per_newton'][name] = normal_input_per_newton(
                X, F, dataset.plates, array.rotations)
    # --shared: the arrays of each kind of module, by kind of model (KindBlocks built once),
    # with the --pool hand's of that kind.
    pooled = {}
    for name, dataset in pool.items():
        removed = without_offsets(name, dataset)
        if removed is None:
            return 2
        pooled[name] = (removed[0], removed[1], dataset.plates)
    data = {**{n: (prepared[n][1], prepared[n][2], prepared[n][0].plates) for n in prepared},
            **pooled}
    kinship = {name: [n for n in prepared if hand.array(n).kind == hand.array(name).kind]
               + [n for n, d in pool.items() if hand.array(d.array).kind == hand.array(name).kind]
               for name in names}
    blocks: dict = {}
    for name, kind in tqdm([(n, k) for n in names for k in args.kinds], desc='models',
                           unit='model'):
        array = hand.array(name)
        dataset, X, F, x_offset = prepared[name]
        hyper = model_hyper(kind, args.seed, args.lambda_cv, args.lam, args.device)
        own_seconds = round(recorded_seconds(dataset), 1)
        provenance = {'dataset': sorted({str(p) for p in args.inputs}),
                      'source': dataset.source, 'plates': dataset.plate_names(),
                      'samples': int(X.shape[0]), 'date': date, 'seed': args.seed,
                      'code_version': version, 'way': 'own', 'own_seconds': own_seconds,
                      **({'trained_on': args.device} if kind in TORCH_KINDS else {})}
        others = [n for n in kinship[name] if n != name]
        if args.shared and len(others) >= 2:
            # The model the kind's other arrays share, adapted to this one's data; its folds
            # choose the weight, so it has a cross-validation even with --no-cv.
            key = (kind, array.kind)
            if key not in blocks:
                blocks[key] = KindBlocks(array, kind, hyper,
                                         {n: data[n] for n in kinship[name]})
            bundle, weight, validation = fit_adapted(
                array, kind, hyper, (X, F, dataset.plates), {n: data[n] for n in others},
                blocks=blocks[key])
            cv = validation.summary()
            provenance.update(way='shared' if np.isinf(weight) else 'adapted',
                              adapt_weight=None if np.isinf(weight) else weight,
                              shared_from=others, metrics=cv,
                              **({'pool': sorted({str(p) for p in args.pool})}
                                 if any(o.startswith(POOL_PREFIX) for o in others) else {}))
            bundle = for_deployment(bundle, x_offset, provenance)
        else:
            # The shipped model trains in the cross-validation's own fit (final=True).
            validation = None if args.no_cv else cross_validate(array, kind, hyper, X, F,
                                                                dataset.plates, final=True)
            cv = None if validation is None else validation.summary()
            provenance['metrics'] = cv
            bundle = (fit_bundle(array, kind, hyper, X, F, dataset.plates, x_offset=x_offset,
                                 provenance=provenance) if validation is None else
                      for_deployment(validation.final, x_offset, provenance))
        path = save_model(args.out / f"{name}_{kind}.npz", bundle)
        report['models'].append({'array': name, 'array_type': array.kind, 'kind': kind,
                                 'file': path.name, 'way': provenance['way'],
                                 'own_seconds': own_seconds,
                                 'adapt_weight': provenance.get('adapt_weight'),
                                 'shared_from': provenance.get('shared_from', []),
                                 'plates': provenance['plates'], 'samples': provenance['samples'],
                                 'hyperparameters': bundle.model.hyperparameters(),
                                 'n_parameters': bundle.model.n_parameters(),
                                 'cross_validation': cv})
    write_model_lists(args.out, report)
    if not args.no_cv:
        from tacforce_ros.hand.figure import hand_errors
        for kind in args.kinds:
            hand_errors(hand, {e['array']: e['cross_validation']['e_hat_mean']
                               for e in report['models'] if e['kind'] == kind},
                        f'{kind}: held-out e_hat per array [N]', args.out / f'hand_{kind}.png')
    (args.out / 'report.json').write_text(json.dumps(report, indent=2))
    (args.out / 'report.md').write_text(markdown_report(report))
    print(markdown_report(report))
    return 0


if __name__ == '__main__':
    sys.exit(main())
