"""bench_train: leave-one-plate-out training, the folds one at a time against all together.

For each model (default M3-lambda, M4, M5 at the paper's 40 epochs) the same cross-validation
runs twice on one array's dataset (default: 200 000 SYNTHETIC samples over 5 plates): once
fitting the folds one at a time (cross_validate(together=False), torch's own Adam for M4/M5), once
all together (fit_bundles: M4 and M5 train as one stacked network, torch_batched.py). Both ways
start from the same seeds, so their held-out errors must agree to float32 rounding; the table
shows the seconds of each way, their ratio, and the largest per-fold e_hat difference.
`--device cuda` trains M4 and M5 on a GPU (both ways; the data on the GPU, the shuffles
drawn on the CPU as there), the GPU's name recorded with the results.
Writes bench_train.json and bench_train.md in --out; the load average is recorded with them.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from importlib.metadata import version

import numpy as np

from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.preprocessing import SAMPLE_RATE_HZ
from tacforce_ros.estimation.registry import PAPER_LABELS, TORCH_KINDS, paper_configurations
from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.rig import TRAINING_PLATES as PLATES
from tacforce_ros.paths import output_folder, write_results


def run_both(array, kind: str, hyper: dict, X: np.ndarray, F: np.ndarray,
             plates: np.ndarray) -> dict:
    """The cross-validation one fold at a time, then all folds together: seconds and results."""
    ways = {}
    for name, together in (('one_at_a_time', False), ('together', True)):
        started = time.perf_counter()
        summary = cross_validate(array, kind, hyper, X, F, plates, together=together).summary()
        ways[name] = {'seconds': time.perf_counter() - started,
                      'e_hat_mean': summary['e_hat_mean'],
                      'e_hat_per_fold': [f['e_hat_mean'] for f in summary['per_fold']]}
    difference = np.abs(np.subtract(ways['one_at_a_time']['e_hat_per_fold'],
                                    ways['together']['e_hat_per_fold']))
    return {'kind': kind, 'hyperparameters': hyper, **ways,
            'speed_up': ways['one_at_a_time']['seconds'] / ways['together']['seconds'],
            'e_hat_max_difference': float(difference.max())}


def torch_gpu_name(device) -> str | None:
    import torch

    return torch.cuda.get_device_name(device) if device.type == 'cuda' else None


def table(result: dict) -> str:
    lines = [f"## Training: {result['folds']} folds one at a time vs together",
             '', f"{result['array']} ({result['n_taxels']} taxels), {result['samples']} "
             f"{result['source']} samples, {result['epochs']} epochs (M4, M5, on "
             f"{result['device']}), "
             f"load average before / after: {result['load_before'][0]:.2f} / "
             f"{result['load_after'][0]:.2f}", '',
             '| model | one at a time [s] | together [s] | speed-up | e_hat [N] one / together '
             '| largest per-fold e_hat difference [N] |', '|---|---|---|---|---|---|']
    for label, r in result['models'].items():
        one, together = r['one_at_a_time'], r['together']
        lines.append(f"| {label} | {one['seconds']:.1f} | {together['seconds']:.1f} | "
                     f"{r['speed_up']:.2f}x | {one['e_hat_mean']:.4f} / "
                     f"{together['e_hat_mean']:.4f} | {r['e_hat_max_difference']:.1e} |")
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='bench_train', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--array', default='index_tip')
    parser.add_argument('--samples', type=int, default=200_000,
                        help='samples in the dataset, split evenly over the plates')
    parser.add_argument('--folds', type=int, default=5, choices=range(2, len(PLATES) + 1),
                        help='plates, hence leave-one-plate-out folds')
    parser.add_argument('--epochs', type=int, default=40, help='M4/M5 epochs (paper: 40)')
    parser.add_argument('--models', nargs='+', default=['M3-lambda', 'M4', 'M5'],
                        choices=PAPER_LABELS)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--device', default='cpu',
                        help="torch device that trains M4 and M5: 'cpu' (default), 'cuda'")
    parser.add_argument('--out', type=output_folder, default='bench_train_out')
    args = parser.parse_args(argv)
    if args.samples < 100 * args.folds or args.epochs < 1:
        parser.error('--samples must give >= 100 per plate and --epochs must be >= 1')

    from tacforce_ros.estimation.torch_training import torch_device
    from tacforce_ros.hand.description import load_hand
    try:
        array = load_hand().array(args.array)
        device = torch_device(args.device)
    except (KeyError, ValueError) as exc:
        print(f'bench_train: {exc}', file=sys.stderr)
        return 2
    seconds = args.samples / args.folds / SAMPLE_RATE_HZ
    dataset = synthetic_dataset(array, plates=PLATES[:args.folds], seconds=seconds,
                                seed=args.seed)
    X, F, _ = dataset.without_offsets()
    configs = paper_configurations(args.seed, args.epochs)
    result = {'array': array.name, 'n_taxels': array.n_taxels, 'source': dataset.source,
              'samples': int(X.shape[0]), 'folds': args.folds, 'epochs': args.epochs,
              'python': platform.python_version(), 'torch': version('torch'),
              'cpus': os.cpu_count(), 'device': args.device,
              'gpu': torch_gpu_name(device),
              'load_before': os.getloadavg(), 'models': {}}
    warm_up = np.concatenate([np.flatnonzero(dataset.plates == plate)[:200]
                              for plate in dataset.plate_names()])     # 200 samples per plate
    for label in args.models:
        kind, hyper = configs[label]
        if kind in TORCH_KINDS:
            hyper = {**hyper, 'device': args.device}
        # Torch's import and first calls cost seconds; pay them before the clock runs.
        run_both(array, kind, {**hyper, 'epochs': 1} if 'epochs' in hyper else hyper,
                 X[warm_up], F[warm_up], dataset.plates[warm_up])
        result['models'][label] = run_both(array, kind, hyper, X, F, dataset.plates)
        print(f"{label}: {result['models'][label]['speed_up']:.2f}x", flush=True)
    result['load_after'] = os.getloadavg()
    write_results(args.out, 'bench_train', result, table(result))
    return 0


if __name__ == '__main__':
    sys.exit(main())
