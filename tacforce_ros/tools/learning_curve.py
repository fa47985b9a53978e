"""learning_curve: how much calibration a model needs. Calibration bags, campaign folders or
processed datasets (as `train` reads them) -> per array and model kind, the leave-one-plate-out
e_hat of models trained on the first `--seconds` of the recording, spread evenly over the plates
(each plate's sessions in the order recorded: estimation/learning_curve.py); JSON, a Markdown
table and a figure (learning_curve.png).

    learning_curve CAMPAIGN_DIR --out out/curve --kinds M3-lambda M4
    learning_curve data/sim/*.npz --out out/curve --arrays index_tip --seconds 25 100 400
    learning_curve CAMPAIGN_DIR --out out/kinds --kind-curve --seconds 100 200 400 1000

--kind-curve draws, for each kind of array with three or more arrays in the inputs, the curve a
campaign with a budget plans on (`campaign plan --budget ... --curves out/kinds/
learning_curve.json`): every array of the kind cut to the same seconds, each one's model the
M3-lambda the others' cuts share, adapted to its own cut (estimation/learning_curve.kind_curve).
`--pool` adds the mirror hand's calibration, whole, to every shared model (estimation/mirror.py):

    learning_curve RIGHT_CAMPAIGN --out out/kinds --kind-curve --pool LEFT_CAMPAIGN
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from tacforce_ros import results
from tacforce_ros.estimation.dataset import DatasetError, concatenate
from tacforce_ros.estimation.learning_curve import (SECONDS, curve_table, kind_curve,
                                                    learning_curve, plot_curves)
from tacforce_ros.estimation.preprocessing import StaticSegmentError
from tacforce_ros.estimation.registry import MODEL_KINDS
from tacforce_ros.hand.description import SIDES
from tacforce_ros.paths import output_folder
from tacforce_ros.tools.calibration_inputs import (expand_campaigns, load_inputs, load_pool,
                                                   model_hyper)


def markdown(result: dict[str, Any]) -> str:
    return (results.header(result, 'Learning curves: held-out e_hat against labelled seconds',
                           result['command'])
            + '\nLeave-one-plate-out e_hat [N] of each model trained on the first seconds of '
              'the recording, spread evenly over the plates; tested on all of the held-out '
              "plate's data.\n\n" + '\n'.join(curve_table(result['rows'])) + '\n')


def _kind_curves(hand, datasets: dict[str, Any], args, pool: dict[str, Any]
                 ) -> list[dict[str, Any]]:
    """kind_curve of each kind with three or more of `datasets`' arrays, counting those of the
    `pool` (load_pool) of that kind."""
    kinds: dict[str, dict[str, Any]] = {}
    for name, dataset in datasets.items():
        kinds.setdefault(hand.array(name).kind, {})[name] = (hand.array(name), dataset)
    pooled = {kind: {n: d for n, d in pool.items() if hand.array(d.array).kind == kind}
              for kind in kinds}
    usable = {kind: arrays for kind, arrays in kinds.items()
              if len(arrays) + len(pooled[kind]) >= 3}
    if not usable:
        raise ValueError(f'--kind-curve needs three or more arrays of a kind, found '
                         f'{ {k: sorted(v) for k, v in kinds.items()} }'
                         + (f' and the pool {sorted(pool)}' if pool else ''))
    kind, hyper = 'M3-lambda', model_hyper('M3-lambda', args.seed, False, args.lam, 'cpu')
    rows = []
    for name, arrays in usable.items():
        mine = kind_curve(arrays, kind, kind, hyper, args.seconds, pool=pooled[name],
                          force_threshold=args.static_force)
        rows += mine
        for seconds in args.seconds:
            values = [r['e_hat_n'] for r in mine if r['seconds'] == seconds]
            print(f'{name} ({len(arrays)} arrays, {len(pooled[name])} pooled) {seconds:g} s: '
                  f'mean e_hat {sum(values) / len(values):.3f} N', flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='learning_curve', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('inputs', nargs='+', type=Path,
                        help='calibration bag folders, campaign folders and/or dataset .npz files')
    parser.add_argument('--out', type=output_folder, required=True,
                        help='folder for learning_curve.json, .md and .png')
    parser.add_argument('--kinds', nargs='+', default=['M3-lambda', 'M4'],
                        choices=sorted(MODEL_KINDS), help='model kinds (default M3-lambda M4)')
    parser.add_argument('--arrays', nargs='+', help='only these arrays (default: all found)')
    parser.add_argument('--seconds', nargs='+', type=float, default=list(SECONDS),
                        help='labelled seconds per array of each point (default: %(default)s)')
    parser.add_argument('--hand-side', choices=SIDES, default=None,
                        help='the hand of the inputs (default: the one they name)')
    parser.add_argument('--lam', type=float, default=33.0, help='M3-lambda damping (paper: 33)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the random models (M4, M5)')
    parser.add_argument('--static-force', type=float, default=0.3,
                        help='offsets: force within this of the no-contact reading [N]')
    parser.add_argument('--kind-curve', action='store_true',
                        help='instead of each array\'s own models: per kind of array, the '
                             'M3-lambda shared and adapted when every array has the seconds')
    parser.add_argument('--pool', nargs='+', type=Path, metavar='INPUT',
                        help='with --kind-curve: another hand\'s calibration (the mirror hand\'s '
                             'campaign, bags or datasets, reflected into this hand\'s layout) '
                             'in every shared model, whole, not judged')
    args = parser.parse_args(argv)
    if any(s <= 0 for s in args.seconds):
        parser.error('--seconds must all be > 0')
    if args.pool and not args.kind_curve:
        parser.error('--pool joins the shared models of --kind-curve; without it each array\'s '
                     'own model is drawn')
    missing = [str(p) for p in args.inputs + (args.pool or []) if not p.exists()]
    if missing:
        parser.error(f'inputs not found: {missing}')
    result: dict[str, Any] = {'provenance': results.provenance(),
                              'command': 'learning_curve ' + ' '.join(argv or sys.argv[1:]),
                              'rows': []}
    try:
        read: dict = {}
        hand, by_array, _ = load_inputs(expand_campaigns(args.inputs, read), args.hand_side,
                                        read)
        arrays = args.arrays or sorted(by_array)
        unknown = [a for a in arrays if a not in by_array]
        if unknown:
            raise ValueError(f'no recordings of {unknown} in the inputs (found '
                             f'{sorted(by_array)})')
        models = {kind: (kind, model_hyper(kind, args.seed, False, args.lam, 'cpu'))
                  for kind in args.kinds}
        if args.kind_curve:
            pool = load_pool(args.pool, hand) if args.pool else {}
            result['rows'] = _kind_curves(hand, {a: concatenate(by_array[a]) for a in arrays},
                                          args, pool)
            arrays = []
        for array in arrays:
            dataset = concatenate(by_array[array])
            rows = learning_curve(hand.array(array), dataset, models, args.seconds,
                                  force_threshold=args.static_force)
            result['rows'] += rows
            print(f'{array}: ' + ', '.join(
                f"{r['model']} {r['seconds']:g} s {r['e_hat_n']:.3f} N"
                if r['e_hat_n'] is not None else f"{r['model']} {r['seconds']:g} s -"
                for r in rows), flush=True)
    except (DatasetError, StaticSegmentError, ValueError, OSError) as exc:
        print(f'learning_curve: {exc}', file=sys.stderr)
        return 1
    json_path, md_path = results.write(args.out, 'learning_curve', result, markdown)
    figure = plot_curves(result['rows'], args.out / 'learning_curve.png',
                         'held-out e_hat against labelled seconds',
                         'kind' if args.kind_curve else 'array')
    print(f'wrote {json_path}, {md_path}, {figure}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
