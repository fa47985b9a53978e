"""The report's figures (PNG, matplotlib Agg): accuracy against time (the leave-one-plate-out
benchmark against the cost of a tick, and the estimator's input low-pass trade-off), force
tracking as the paper's Fig. 4 (mean and standard-deviation band over the repeats), and per-plate
errors, and the grasp's per-finger forces."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend is chosen first)
import numpy as np  # noqa: E402
from matplotlib import ticker  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from tacforce_ros.experiments.closed_loop import ClosedLoopTrace  # noqa: E402
from tacforce_ros.experiments.report import MODEL_NAMES  # noqa: E402

AXES = ('x', 'y', 'z')
SIM_LABEL = 'SIMULATION'
# Models are told apart by marker (one legend for all panels), series by colour.
MODEL_MARKERS = {'M1': 'o', 'M2': 's', 'M3': '^', 'M3-lambda': 'v', 'M3-lambda-cv': '<',
                 'M4': 'D', 'M5': 'P'}


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


def grasp_tracking(runs: dict, title: str, path: Path) -> Path:
    """Rows: controllers (one run each); columns: fingers. Each finger's commanded and simulated
    contact force along its grip direction d_i, its estimate, and the hand-over."""
    fingers = next(iter(runs.values())).fingers
    fig, axes = plt.subplots(len(runs), len(fingers), figsize=(6 * len(fingers), 2.8 * len(runs)),
                             sharex=True, squeeze=False)
    for row, (controller, trace) in enumerate(runs.items()):
        released = trace.t[(~trace.held_by_fixture).argmax()] if (~trace.held_by_fixture).any() \
            else None
        for i, ax in enumerate(axes[row]):
            def along(forces: np.ndarray) -> np.ndarray:
                return np.einsum('ti,ti->t', forces[:, i], trace.directions[:, i])
            ax.plot(trace.t, along(trace.f_d), 'k--', lw=1.0, label='desired f_d . d')
            if np.isfinite(trace.f_hat[:, i]).any():
                ax.plot(trace.t, along(trace.f_hat), color='tab:blue', lw=0.8,
                        label='estimate f_hat . d')
            ax.plot(trace.t, along(trace.f_true), color='tab:red', lw=1.0,
                    label='simulated contact f . d')
            if released is not None:
                ax.axvline(released, color='0.5', lw=0.8, ls=':', label='hand-over')
            ax.set_title(f'{MODEL_NAMES.get(controller, controller)}, {fingers[i]} [N]',
                         fontsize=9)
            ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel('t [s] since the goal')
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f'{SIM_LABEL}: {title}')
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


def pareto_front(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The (time, error) points no other point beats on both, by increasing time."""
    front: list[tuple[float, float]] = []
    for x, y in sorted(points):
        if not front or y < front[-1][1]:
            front.append((x, y))
    return front


def _log_time_axis(ax) -> None:
    ax.set_xscale('log')
    ax.xaxis.set_major_locator(ticker.LogLocator(base=10.0, numticks=8))
    ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f'{v:g}'))
    ax.xaxis.set_minor_formatter(ticker.NullFormatter())


def accuracy_vs_time(table_i: dict, end_to_end: dict | None, path: Path,
                     source: str = SIM_LABEL) -> Path:
    """Accuracy against time, per array of `table_i` ({array: {model: {'sim': ..., 'paper':
    ...}}}, the report's Table I rows), e_hat on the held-out plate (mean over the folds; bar:
    standard deviation of the fold means). Top: against the time a tick costs end to end
    (full-hand tick plus the estimator node's median latency, when measured), with the Pareto
    front, on a linear axis: the latency shifts every model alike. Bottom: against compute only
    (log): one prediction and the full-hand tick, and the paper's Table I (tau per prediction).
    With `end_to_end` (the report's), a panel for the input low-pass trade-off on the index
    fingertip's held-out session. `source` names where the data come from, in every title."""
    latency = (end_to_end or {}).get('node_latency', {})
    node_ms = latency['median_ms'] if latency.get('measured') else 0.0
    arrays = list(table_i)
    columns = len(arrays) + (end_to_end is not None)
    fig, axes = plt.subplots(2, columns, figsize=(max(5.0 * columns, 8.0), 8.2), squeeze=False)
    mine = source.lower()
    for column, array in enumerate(arrays):
        top, bottom = axes[0, column], axes[1, column]
        front = []
        for label, row in table_i[array].items():
            sim, paper = row['sim'], row['paper']
            marker = MODEL_MARKERS.get(label, 'o')
            spread = float(np.std([p['e_hat_mean'] for p in sim['per_plate']]))
            x = sim['tau_full_hand_ms'] + node_ms
            front.append((x, sim['e_hat']))
            top.errorbar(x, sim['e_hat'], yerr=spread, fmt=marker, color='C0', capsize=3)
            bottom.errorbar(sim['tau_full_hand_ms'], sim['e_hat'], yerr=spread, fmt=marker,
                            color='C0', capsize=3)
            bottom.errorbar(sim['tau_single_ms'], sim['e_hat'], yerr=spread, fmt=marker,
                            color='C1', mfc='none', capsize=3)
            if paper:
                bottom.plot(paper['tau_ms'], paper['e_hat'][0], marker, color='C2', mfc='none')
        xs, ys = zip(*pareto_front(front))
        top.step(xs, ys, where='post', color='C3', ls='--', lw=0.9)
        top.plot(xs, ys, 'o', ms=14, mfc='none', color='C3')
        top.set_xlabel('end to end: full-hand tick + node latency [ms]' if latency.get('measured')
                       else 'full-hand tick [ms] (node latency not measured)')
        top.set_title(f'{source}: {array}, leave-one-plate-out', fontsize=9)
        _log_time_axis(bottom)
        bottom.set_xlabel('compute [ms] (log)')
        bottom.set_title(f'{source}: {array}, compute only', fontsize=9)
        for ax in (top, bottom):
            ax.set_ylabel('e_hat, held-out plate [N]')
            ax.grid(True, which='major', alpha=0.3)
    top_series = [Line2D([], [], color='C0', marker='o', ls='', label=f'{mine}: models'),
                  Line2D([], [], color='C3', ls='--', marker='o', ms=10, mfc='none',
                         label=f'{mine}: Pareto front')]
    axes[0, 0].legend(handles=top_series, fontsize=7)
    bottom_series = [
        Line2D([], [], color='C0', marker='o', ls='', label=f'{mine}: full-hand tick (18 arrays)'),
        Line2D([], [], color='C1', marker='o', mfc='none', ls='',
               label=f'{mine}: one prediction (τ)'),
        Line2D([], [], color='C2', marker='o', mfc='none', ls='',
               label='paper Table I: one prediction (τ)')]
    axes[1, 0].legend(handles=bottom_series, fontsize=7)
    models = [Line2D([], [], color='k', marker=MODEL_MARKERS.get(label, 'o'), ls='',
                     label=MODEL_NAMES.get(label, label)) for label in table_i[arrays[0]]]
    if end_to_end is not None:
        _filter_panel(axes[0, -1], end_to_end)
        axes[1, -1].axis('off')
        axes[1, -1].legend(handles=models, loc='center', fontsize=9, title='models')
    else:
        fig.legend(handles=models, loc='lower center', ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f'{source}: what accuracy costs in time (error bars: spread of the fold '
                 'means; paper: its means)', fontsize=10)
    fig.tight_layout(rect=(0, 0.07 if end_to_end is None else 0, 1, 0.97))
    return _save(fig, path, layout=False)


def _filter_panel(ax, end_to_end: dict) -> None:
    """e_hat online against end-to-end time, one line per model through the cut-offs."""
    rows = end_to_end['rows']
    cutoffs = list(dict.fromkeys(r['cutoff_hz'] for r in rows))
    for label in dict.fromkeys(r['model'] for r in rows):
        mine = sorted((r['end_to_end_ms'], r['e_hat_mean']) for r in rows if r['model'] == label)
        xs, ys = zip(*mine)
        ax.plot(xs, ys, color='k', lw=0.7, alpha=0.6, marker=MODEL_MARKERS.get(label, 'o'))
    for cutoff in cutoffs:
        x = float(np.median([r['end_to_end_ms'] for r in rows if r['cutoff_hz'] == cutoff]))
        ax.axvline(x, color='0.8', lw=0.8, zorder=0)
        ax.text(x, 1.01, 'no filter' if cutoff is None else f'{cutoff:g} Hz', ha='center',
                va='bottom', fontsize=7, transform=ax.get_xaxis_transform())
    measured = end_to_end['node_latency'].get('measured')
    ax.set_xlabel('end to end: tick + filter group delay' + (' + node latency' if measured
                                                             else ' (node latency not measured)')
                  + ' [ms]')
    ax.set_ylabel(f"e_hat, held-out {end_to_end['plate']} plate [N]")
    ax.set_title(f"{SIM_LABEL}: {end_to_end['array']}, input low-pass (order "
                 f"{end_to_end['filter_order']}), raw frames", fontsize=9, pad=14)
    ax.grid(True, alpha=0.3)


def _save(fig, path: Path, layout: bool = True) -> Path:
    if layout:
        fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
