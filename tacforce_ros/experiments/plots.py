"""The report's figures (PNG, matplotlib Agg) besides the bench tool's accuracy-against-time plot:
force tracking as the paper's Fig. 4 (mean and standard-deviation band over the repeats) and
per-plate errors."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend is chosen first)
import numpy as np  # noqa: E402

from tacforce_ros.experiments.closed_loop import ClosedLoopTrace  # noqa: E402

AXES = ('x', 'y', 'z')
SIM_LABEL = 'SIMULATION'


def _band(ax, t: np.ndarray, runs: list[np.ndarray], label: str, color: str) -> None:
    stack = np.stack(runs)
    mean = np.nanmean(stack, axis=0)
    std = np.nanstd(stack, axis=0)
    ax.plot(t, mean, color=color, lw=1.0, label=label)
    ax.fill_between(t, mean - std, mean + std, color=color, alpha=0.25, lw=0)


def tracking(traces: dict[str, list[ClosedLoopTrace]], title: str, path: Path) -> Path:
    """Rows: controllers; columns: force axes in {F}. Desired, estimate and F/T measurement."""
    fig, axes = plt.subplots(len(traces), 3, figsize=(13, 2.6 * len(traces)), sharex=True,
                             squeeze=False)
    for row, (controller, runs) in enumerate(traces.items()):
        n = min(len(r.t) for r in runs)
        t = runs[0].t[:n]
        for k, ax in enumerate(axes[row]):
            ax.plot(t, runs[0].f_d[:n, k], 'k--', lw=1.0, label='desired f_d')
            if np.isfinite(runs[0].f_hat[:, k]).any():
                _band(ax, t, [r.f_hat[:n, k] for r in runs], 'estimate f_hat', 'tab:blue')
            _band(ax, t, [r.f_tilde[:n, k] for r in runs], 'measured f~ (F/T)', 'tab:red')
            ax.set_title(f'{controller}, f_{AXES[k]} [N]', fontsize=9)
            ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel('t [s]')
    # The legend goes where every line is drawn (the open-loop row has no estimate).
    fullest = max((row[0] for row in axes), key=lambda ax: len(ax.get_lines()))
    fullest.legend(fontsize=7)
    fig.suptitle(f'{SIM_LABEL}: {title} (mean and std band over {len(runs)} runs)')
    return _save(fig, path)


def per_plate_errors(cv: dict[str, dict[str, dict]], path: Path) -> Path:
    """Held-out-plate e_hat (mean, std) per model, one group of bars per plate, per array."""
    fig, axes = plt.subplots(1, len(cv), figsize=(7 * len(cv), 4), squeeze=False)
    for ax, (array, by_model) in zip(axes[0], cv.items()):
        labels = list(by_model)
        plates = [f['test_plate'] for f in by_model[labels[0]]['per_fold']]
        width = 0.8 / len(labels)
        for j, label in enumerate(labels):
            folds = {f['test_plate']: f for f in by_model[label]['per_fold']}
            x = np.arange(len(plates)) + (j - (len(labels) - 1) / 2) * width
            ax.bar(x, [folds[p]['e_hat_mean'] for p in plates], width,
                   yerr=[folds[p]['e_hat_std'] for p in plates], capsize=2, label=label)
        ax.set_xticks(np.arange(len(plates)), plates)
        ax.set_ylabel('e_hat on the held-out plate [N]')
        ax.set_title(f'{SIM_LABEL}: {array}, leave-one-plate-out')
        ax.grid(True, axis='y', alpha=0.3)
        ax.legend(fontsize=7)
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
