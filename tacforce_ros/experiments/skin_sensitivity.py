"""skin_sensitivity: Table I on the magnetic skin, and how it moves with each estimated parameter.

The paper's leave-one-plate-out benchmark (held-out e_hat per model, the Table I arrays by
default) on calibration sessions simulated with the magnetic skin (sim/effects/magnetic_skin.py)
in place of the empirical response: once at the parameters' values, then with each parameter
that has no source (magnetic_skin.ESTIMATES, plus the chip noise) at --factors times its value
(Poisson's ratio kept below 0.5); a variant whose magnets cannot sit in their layer is reported
as infeasible. Each row also gives every model's e_hat over M3-lambda's, the ratios the
simulated skin is judged by (skin_targets). At the values, the paper's closed loop runs too (open
loop, and closed with each --closed-loop model fitted on the fingertip's sessions). The values
run once per --seeds entry (a seed draws the operator's sessions, the noise and the training;
the hand, where each magnet sits, is the scenes' sensor_seed), the variants at the first seed;
a table says, per target, in how many seeds it is met.

--set NAME=VALUE (repeatable) changes a magnetic_skin parameter in every run, variants included
(a variant of it scales the value set): a lab's measured value of an estimate, or a what-if
such as `--set rest_z_range=35600,35600` (every magnet at one height; the rest spread would then
be the chips' offsets, which the models' tare removes). The report names the settings.

Writes skin_sensitivity.json and skin_sensitivity.md in --out (created before any work).
Variants run in parallel (--jobs); the load average is recorded with them.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from tacforce_ros.estimation.m1_rotation_linear import NORMAL_INPUT_NOTE
from tacforce_ros.experiments import paper_reference as paper
from tacforce_ros.experiments.skin_targets import targets
from tacforce_ros.paths import output_folder, write_results
from tacforce_ros.rig import TRAINING_PLATES

ARRAYS = ('index_tip', 'index_middle')
LOOP_ARRAY, LOOP_SCENE = 'index_tip', 'closed_loop_spherical'   # the paper's Table III
NOISE = 'taxel_noise.scale'     # the chip noise times a factor (sim/effects/taxel_noise.py)
POISSON_LIMIT = 0.499


def skin_setting(text: str) -> tuple[str, float | tuple[float, ...]]:
    """NAME=VALUE of --set: a magnetic_skin parameter and its value, in the parameter's shape
    (comma-separated for a range)."""
    from tacforce_ros.sim.effects.magnetic_skin import MagneticSkin
    name, _, value = text.partition('=')
    defaults = {f.name: f.default for f in dataclasses.fields(MagneticSkin)}
    if name not in defaults:
        raise argparse.ArgumentTypeError(
            f'{name!r} is not a magnetic_skin parameter (one of {", ".join(defaults)})')
    try:
        numbers = tuple(float(v) for v in value.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r}: the value must be numbers') from None
    shape = len(defaults[name]) if isinstance(defaults[name], tuple) else 1
    if len(numbers) != shape:
        raise argparse.ArgumentTypeError(f'{name} takes {shape} comma-separated number(s), not '
                                         f'{value!r}')
    signed = name == 'readout_offset_xy'        # counts either way; the rest are magnitudes
    if not all(math.isfinite(v) and (signed or v >= 0.0) for v in numbers):
        raise argparse.ArgumentTypeError(
            f'{text!r}: the value must be finite{"" if signed else " and >= 0"}')
    if name == 'poisson' and not 0.0 < numbers[0] <= POISSON_LIMIT:
        raise argparse.ArgumentTypeError(f'poisson must lie in (0, {POISSON_LIMIT}], not '
                                         f'{value}')
    return name, numbers if shape > 1 else numbers[0]


def variants(factors: list[float], params: list[str], seeds: list[int],
             settings: dict | None = None) -> list[dict]:
    """[{'name', 'seed', 'skin': {param: value}, 'noise': factor}]: the values (with
    `settings`) at each seed first, then each variant at the first seed."""
    from tacforce_ros.sim.effects.magnetic_skin import MagneticSkin
    settings = dict(settings or {})
    nominal = MagneticSkin(**settings)
    rows = [{'name': 'values', 'seed': seed, 'skin': dict(settings), 'noise': 1.0}
            for seed in seeds]
    for param in params:
        for factor in factors:
            row = {'name': f'{param} x{factor:g}', 'seed': seeds[0], 'skin': dict(settings),
                   'noise': 1.0}
            if param == NOISE:
                row['noise'] = factor
            else:
                value = getattr(nominal, param) * factor
                row['skin'][param] = min(value, POISSON_LIMIT) if param == 'poisson' else value
            rows.append(row)
    return rows


def evaluate(variant: dict, arrays: list[str], sessions: int, seconds: float,
             models: list[str], epochs: int, loop_models: list[str]) -> dict:
    """Table I rows of one variant: {array: {label: e_hat}}, the closed loop of `loop_models`
    (trained on the fingertip's sessions) and the seconds it took."""
    from tacforce_ros.estimation.cross_validation import cross_validate
    from tacforce_ros.estimation.dataset import concatenate
    from tacforce_ros.estimation.m1_rotation_linear import normal_input_per_newton
    from tacforce_ros.estimation.registry import paper_configurations
    from tacforce_ros.experiments.calibration_data import simulate_calibration
    from tacforce_ros.hand.description import load_hand
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.sim import load_scene
    from tacforce_ros.sim.effects.magnetic_skin import with_magnetic_skin
    from tacforce_ros.sim.effects.magnetic_skin import SkinPlacementError
    from tacforce_ros.sim.scene import calibration_scene_name, session_seed

    def magnetic(name: str):
        scene = load_scene(name)
        effects = with_magnetic_skin(scene.effects, **variant['skin'])
        noise = effects.get('taxel_noise')
        if noise is not None and variant['noise'] != 1.0:
            effects['taxel_noise'] = {**noise,
                                      'scale': noise.get('scale', 1.0) * variant['noise']}
        return dataclasses.replace(scene, effects=effects)

    started = time.perf_counter()
    seed = variant['seed']
    hand = load_hand()
    kinematics = HandKinematics.for_hand(hand)
    configs = paper_configurations(seed, epochs)
    rows, per_plate, per_axis, normal_input, loop = {}, {}, {}, {}, None
    for array in arrays:
        parts = []
        for plate in TRAINING_PLATES:
            scene = magnetic(calibration_scene_name(array, plate))
            for k in range(sessions):
                try:
                    parts.append(simulate_calibration(
                        hand, kinematics, scene, session_seed(seed, array, plate, k), seconds))
                except SkinPlacementError as exc:     # a variant outside what the skin can be
                    return {**variant, 'infeasible': str(exc), 'e_hat': None,
                            'seconds': time.perf_counter() - started}
        dataset = concatenate(parts)
        X, F, offset = dataset.without_offsets(force_threshold=0.3)
        rows[array], per_plate[array], per_axis[array] = {}, {}, {}
        normal_input[array] = normal_input_per_newton(X, F, dataset.plates,
                                                      hand.array(array).rotations)
        for label in models:
            kind, hyper = configs[label]
            summary = cross_validate(hand.array(array), kind, hyper, X, F,
                                     dataset.plates).summary()
            rows[array][label] = summary['e_hat_mean']
            per_axis[array][label] = summary['mae_axis']
            per_plate[array][label] = {fold['test_plate']: fold['e_hat_mean']
                                       for fold in summary['per_fold']}
        if array == LOOP_ARRAY and loop_models:
            loop = closed_loop(hand, kinematics, magnetic(LOOP_SCENE), loop_models, configs,
                               X, F, dataset.plates, offset, seed)
    return {**variant, 'infeasible': None, 'e_hat': rows, 'e_hat_per_plate': per_plate,
            'mae_axis': per_axis, 'normal_input_per_newton': normal_input,
            'closed_loop': loop,
            'seconds': time.perf_counter() - started}


def closed_loop(hand, kinematics, scene, labels: list[str], configs: dict, X, F, plates,
                offset, seed: int) -> dict:
    """The paper's closed loop (70 s sequence, spherical plate) on this skin: open loop, and
    closed with each of `labels` fitted on the fingertip's training plates, as the main job
    runs it: {'open_loop': e~, label: {e_tilde, e_track, e_hat, reduction}}."""
    import tempfile
    from pathlib import Path

    from tacforce_ros.control.command_sequence import ForceSequence
    from tacforce_ros.estimation.model_io import save_model
    from tacforce_ros.estimation.model_set import load_model_set, write_model_config
    from tacforce_ros.estimation.training import fit_bundle
    from tacforce_ros.experiments.closed_loop import run_closed_loop, trace_metrics
    from tacforce_ros.experiments.settings import controller_config

    sequence = ForceSequence.load('paper_70s')
    open_loop = trace_metrics([run_closed_loop(hand, kinematics, scene, seed,
                                               controller_config('open_loop'), sequence, None)])
    result = {'open_loop': open_loop['e_tilde_mean']}
    provenance = {'dataset': 'skin_sensitivity: magnetic skin sessions', 'date':
                  time.strftime('%Y-%m-%dT%H:%M:%S%z'), 'seed': seed, 'code_version': '',
                  'metrics': None, 'plates': list(dict.fromkeys(plates.tolist())),
                  'samples': int(X.shape[0])}
    with tempfile.TemporaryDirectory() as folder:
        for label in labels:
            kind, hyper = configs[label]
            bundle = fit_bundle(hand.array(LOOP_ARRAY), kind, hyper, X, F, plates,
                                x_offset=offset, provenance=provenance)
            save_model(Path(folder) / f'{label}.npz', bundle)
            models = load_model_set(write_model_config(
                Path(folder) / 'models.yaml', {LOOP_ARRAY: f'{label}.npz'}), hand)
            closed = trace_metrics([run_closed_loop(hand, kinematics, scene, seed,
                                                    controller_config(label), sequence,
                                                    models)])
            result[label] = {'e_tilde': closed['e_tilde_mean'],
                             'e_track': closed['e_track_mean'], 'e_hat': closed['e_hat_mean'],
                             'estimate_gain': closed['estimate_gain'],
                             'reduction': 1.0 - closed['e_tilde_mean'] / result['open_loop']}
    return result


def table(result: dict) -> str:
    arrays, models = result['arrays'], result['models']
    reference = 'M3-lambda' if 'M3-lambda' in models else None
    head = ['variant', 'seed'] + [f'{a} {m}' for a in arrays for m in models]
    lines = ["## Table I on the magnetic skin: held-out e_hat [N] (5-fold leave-one-plate-out)",
             '', f"{result['sessions']} x {result['seconds']:g} s per plate and array, "
             f"M4/M5 {result['epochs']} epochs, seeds {', '.join(map(str, result['seeds']))}; "
             f"load average before / after: {result['load_before'][0]:.2f} / "
             f"{result['load_after'][0]:.2f}", '']
    if result['settings']:
        lines += ['magnetic_skin set (--set), in every row: ' + ', '.join(
            f'{name} = {value}' for name, value in result['settings'].items()), '']
    lines += ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    paper_row = ['paper', ''] + [f"{paper.TABLE_I[a][m]['e_hat'][0]:.2f}" for a in arrays
                                 for m in models]
    lines.append('| ' + ' | '.join(paper_row) + ' |')
    for row in result['variants']:
        cells = [row['name'], str(row['seed'])]
        if row['e_hat'] is None:
            lines.append('| ' + ' | '.join(cells + ['infeasible'] * (len(head) - 2)) + ' |')
            continue
        for a in arrays:
            for m in models:
                value = row['e_hat'][a][m]
                ratio = (f" ({value / row['e_hat'][a][reference]:.2f})"
                         if reference and m != reference else '')
                cells.append(f'{value:.3f}{ratio}')
        lines.append('| ' + ' | '.join(cells) + ' |')
    if reference:
        lines += ['', f'In brackets: e_hat over {reference} of the same array and variant.']
    lines += [f"Infeasible, {row['name']}: {row['infeasible']}" for row in result['variants']
              if row['e_hat'] is None]
    for row in result['variants']:
        loop = row.get('closed_loop')
        if not loop:
            continue
        lines += ['', f"Closed loop at the {row['name']}, seed {row['seed']} ({LOOP_ARRAY}, "
                  f"paper sequence, {LOOP_SCENE}): open loop e~ {loop['open_loop']:.3f} N", '',
                  '| model | e~ [N] | reduction | e_track [N] | e_hat [N] | '
                  'estimate over force x / y / z |', '|---|---|---|---|---|---|']
        lines += [f"| {label} | {m['e_tilde']:.3f} | {100 * m['reduction']:.1f} % | "
                  f"{m['e_track']:.3f} | {m['e_hat']:.3f} | "
                  + ' / '.join('-' if g is None else f'{g:.2f}' for g in m['estimate_gain'])
                  + ' |' for label, m in loop.items() if label != 'open_loop']
    lines += per_plate_table(result) + normal_input_table(result)
    checks = result['targets']
    if checks:
        seeds = [row['seed'] for row in result['variants'] if row['name'] == 'values'
                 and row['e_hat']]
        lines += ['', "## The magnetic skin's targets at the values", '',
                  '| target | ' + ' | '.join(f'seed {s}' for s in seeds) + ' | met |',
                  '|' + '---|' * (len(seeds) + 2)]
        lines += ['| ' + ' | '.join([c['target']] + ['' if v is None else f'{v:.2f}'
                                                     for v in c['values']]
                                    + [f"{c['met']} of {len(seeds)}"]) + ' |'
                  for c in checks]
    return '\n'.join(lines) + '\n'


def per_plate_table(result: dict) -> list[str]:
    """Lines: each model's held-out e_hat per test plate at the values, per seed, and its
    error per axis."""
    rows = [row for row in result['variants'] if row['name'] == 'values' and row['e_hat']]
    if not rows:
        return []
    plates = list(TRAINING_PLATES)
    lines = ['', '## Held-out e_hat [N] per test plate at the values', '',
             '| array | model | seed | ' + ' | '.join(plates) + ' | MAE x / y / z |',
             '|' + '---|' * (len(plates) + 4)]
    for array in result['arrays']:
        for model in result['models']:
            for row in rows:
                fold = row['e_hat_per_plate'][array][model]
                axes = ' / '.join(f'{v:.3f}' for v in row['mae_axis'][array][model])
                lines.append(f"| {array} | {model} | {row['seed']} | "
                             + ' | '.join(f'{fold[p]:.3f}' for p in plates) + f' | {axes} |')
    return lines + ['', 'MAE x / y / z: the held-out error per axis of {S0} (x, y shear, z '
                    'normal), mean over the five folds.']


def normal_input_table(result: dict) -> list[str]:
    """Lines: per row and array, M1's normal input per newton by plate (NORMAL_INPUT_NOTE)."""
    rows = [row for row in result['variants'] if row['e_hat']]
    if not rows:
        return []
    plates = list(TRAINING_PLATES)
    lines = ['', "## M1's normal input per newton, by plate", '',
             NORMAL_INPUT_NOTE, '',
             '| variant | seed | array | ' + ' | '.join(plates) + ' |',
             '|' + '---|' * (len(plates) + 3)]
    for row in rows:
        for array in result['arrays']:
            gains = row['normal_input_per_newton'][array]
            lines.append(f"| {row['name']} | {row['seed']} | {array} | " + ' | '.join(
                '-' if gains.get(p) is None else f'{gains[p]:.0f}' for p in plates) + ' |')
    return lines


def main(argv: list[str] | None = None) -> int:
    from tacforce_ros.estimation.registry import PAPER_LABELS
    from tacforce_ros.sim.effects.magnetic_skin import ESTIMATES

    parser = argparse.ArgumentParser(prog='skin_sensitivity', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--arrays', nargs='+', default=list(ARRAYS))
    parser.add_argument('--sessions', type=int, default=1, help='per plate (paper: 4)')
    parser.add_argument('--seconds', type=float, default=100.0, help='per session (paper: 100)')
    parser.add_argument('--models', nargs='+', default=['M1', 'M2', 'M3', 'M3-lambda'],
                        choices=PAPER_LABELS)
    parser.add_argument('--epochs', type=int, default=40, help='M4/M5 epochs (paper: 40)')
    parser.add_argument('--params', nargs='*', default=[*ESTIMATES, NOISE],
                        choices=[*ESTIMATES, NOISE],
                        help='estimates to vary (none: the values only)')
    parser.add_argument('--factors', nargs='+', type=float, default=[0.5, 1.5])
    parser.add_argument('--closed-loop', nargs='*', default=['M3-lambda', 'M4'],
                        choices=PAPER_LABELS, metavar='MODEL',
                        help='models of the closed loop run at the values (none: no loop)')
    parser.add_argument('--seeds', nargs='+', type=int, default=[0],
                        help='the values run at each; the variants at the first')
    parser.add_argument('--set', type=skin_setting, action='append', default=[],
                        metavar='NAME=VALUE', dest='settings',
                        help='a magnetic_skin parameter in every run (repeatable)')
    parser.add_argument('--jobs', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--out', type=output_folder, default='skin_sensitivity_out')
    args = parser.parse_args(argv)
    if (args.sessions < 1 or args.seconds <= 0 or args.epochs < 1 or args.jobs < 1
            or min(args.factors) <= 0):
        parser.error('--sessions, --seconds, --epochs, --jobs and --factors must be positive')
    unknown = sorted(set(args.arrays) - set(paper.TABLE_I))
    if unknown:
        parser.error(f'--arrays: the paper has Table I rows for {sorted(paper.TABLE_I)} only, '
                     f'not {unknown}')
    settings = dict(args.settings)
    if len(settings) != len(args.settings):
        parser.error('--set names a parameter twice')
    rows = variants(args.factors, args.params, args.seeds, settings)
    result = {'arrays': args.arrays, 'models': args.models, 'sessions': args.sessions,
              'seconds': args.seconds, 'epochs': args.epochs, 'seeds': args.seeds,
              'settings': settings, 'load_before': os.getloadavg()}
    with ProcessPoolExecutor(max_workers=min(args.jobs, len(rows))) as pool:
        futures = [pool.submit(evaluate, row, args.arrays, args.sessions, args.seconds,
                               args.models, args.epochs,
                               args.closed_loop if row['name'] == 'values' else [])
                   for row in rows]
        done = []
        for future in futures:
            done.append(future.result())
            print(f"{done[-1]['name']}, seed {done[-1]['seed']}: {done[-1]['seconds']:.0f} s",
                  flush=True)
    result.update(variants=done, load_after=os.getloadavg())
    result['targets'] = targets(result)
    write_results(args.out, 'skin_sensitivity', result, table(result))
    return 0


if __name__ == '__main__':
    sys.exit(main())
