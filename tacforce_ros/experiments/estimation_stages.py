"""Stages of the main job that estimate: the cost of a tick, the online test on the held-out
plate (Table II), the estimator node's latency and the input low-pass trade-off end to end.
"""
from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
import yaml

from tacforce_ros.bringup.processes import executable, run_to_end
from tacforce_ros.estimation.causal_filter import BatchLowPass
from tacforce_ros.estimation.dataset import CalibrationDataset, concatenate
from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.estimation.model_io import load_model
from tacforce_ros.estimation.preprocessing import CUTOFF_HZ, SAMPLE_RATE_HZ
from tacforce_ros.estimation.registry import paper_configurations
from tacforce_ros.estimation.runtime import RuntimeEstimator
from tacforce_ros.estimation.synthetic import synthetic_hand_estimator
from tacforce_ros.rig import HELD_OUT_PLATE
from tacforce_ros.experiments.cache import (digest, node_modules, source_digest,
                                            tool_modules)
from tacforce_ros.timing import time_interleaved
from tacforce_ros.experiments.calibration_stages import calibration_unit
from tacforce_ros.experiments.settings import (ARRAYS, FILTER_CUTOFFS_HZ, NODE_LATENCY_SECONDS,
                                             ONLINE_MODELS, PLATES, Context, estimator_parameter,
                                             model_hyper)
from tacforce_ros.experiments.workers import run_units, worker_hand


def timing_stage(ctx: Context, models: dict) -> dict:
    """Inference cost per array and model: one prediction, the compiled batch of one, and a
    full-hand tick (18 arrays of the kind), timed round-robin by the bench tool's timer so every
    model sees the same machine load. Runs in this process while the pool is idle."""
    s = ctx.settings
    order = int(estimator_parameter('lowpass_order'))
    key = digest({'models': {a: {m: Path(p).stem for m, p in by.items()}
                             for a, by in models.items()},
                  'repeats': s.timing_repeats, 'lowpass_order': order,
                  'code': source_digest(time_interleaved, synthetic_hand_estimator, load_model,
                                        paper_configurations)})
    cached = ctx.cache.load_json('timing', key)
    if cached is not None:
        return cached
    ctx.log(f'stage timing: {len(ARRAYS) * len(s.models)} models, {s.timing_repeats} calls each')
    started = time.perf_counter()
    hand, _ = worker_hand()
    calls = {}
    for label in s.models:
        kind, hyper = model_hyper(label, s)
        estimator = synthetic_hand_estimator(hand, kind, hyper, s.seed)
        filtered = RuntimeEstimator(hand, estimator.bundles)    # its cost is the cut-off's too
        filtered.set_lowpass(CUTOFF_HZ, SAMPLE_RATE_HZ, order)
        frame = np.clip(np.round(hand.merge([b.x_offset for b in estimator.bundles])), 0,
                        65535).astype(np.uint16)
        for array in ARRAYS:
            bundle = load_model(models[array][label], hand.array(array))
            one = np.zeros((1, bundle.array.n_taxels, 3))
            batch = type(bundle.model).compile_batch([bundle.model])
            calls[(array, label, 'predict_one')] = lambda m=bundle.model, x=one: m.predict(x)
            calls[(array, label, 'batch_one')] = lambda b=batch, x=one: b(x)
            calls[(array, label, 'full_hand_tick')] = \
                lambda e=estimator, f=frame: e.estimate(f)
            calls[(array, label, 'full_hand_tick_lowpass')] = \
                lambda e=filtered, f=frame: e.estimate(f)
    measured = time_interleaved(calls, s.timing_repeats)
    timing: dict[str, dict] = {}
    for (array, label, what), value in measured.items():
        timing.setdefault(array, {}).setdefault(label, {})[what] = value
    ctx.timings['timing'] = time.perf_counter() - started
    ctx.cache.store_json('timing', key, timing)
    return timing


def online_stage(ctx: Context, layout: dict, models: dict) -> dict:
    """Table II: the final models on the held-out spherical session of the index fingertip,
    beside the same models on their own training sessions (in distribution), so the report
    shows how much harder the unseen plate is."""
    hand, _ = worker_hand()
    static = {'force_threshold': ctx.settings.static_force}
    dataset = CalibrationDataset.load(layout['index_tip'][HELD_OUT_PLATE][0])
    X, F, _ = dataset.without_offsets(**static)
    X_in, F_in, _ = concatenate([CalibrationDataset.load(p) for plate in PLATES
                                 for p in layout['index_tip'][plate]]).without_offsets(**static)
    result = {'seconds': float(dataset.time[-1] - dataset.time[0]), 'samples': int(len(F)),
              'in_distribution_samples': int(len(F_in))}
    for label in ONLINE_MODELS:
        bundle = load_model(models['index_tip'][label], hand.array('index_tip'))
        # Offsets were removed from X already (each session's own static segments): no tare.
        tare = np.zeros_like(bundle.x_offset)
        result[label] = error_stats(F, bundle.predict(X, tare=tare)).as_dict()
        result[label]['in_distribution'] = error_stats(
            F_in, bundle.predict(X_in, tare=tare)).as_dict()
    ctx.log(f'stage online: {result["samples"]} samples on the held-out plate, '
            f'{result["in_distribution_samples"]} on the training plates')
    return result


def node_latency_stage(ctx: Context) -> dict:
    """The estimator node's frame -> 18 wrenches latency over DDS at 100 Hz (bench_ros, normal
    scheduler, synthetic models: the transport and wake-up dominate, not the model), with the
    node path only. A failure is recorded with its reason, never replaced by a number."""
    s = ctx.settings
    if not s.node_path:
        return {'measured': False,
                'reason': 'the node path is switched off for this run (--quick or --no-node-path)'}
    try:        # run as a command, as a user would: it starts the estimator node
        bench_ros, modules = executable('bench_ros'), tool_modules('bench_ros')
    except (FileNotFoundError, ValueError) as exc:
        return {'measured': False, 'reason': f'bench_ros is not installed: {exc}'}
    key = digest({'seconds': NODE_LATENCY_SECONDS,
                  'code': source_digest(*modules, *node_modules())})
    cached = ctx.cache.load_json('node_latency', key)
    if cached is not None:
        return cached
    target = ctx.cache.path('node_latency', key, '.bench_ros.json')
    target.parent.mkdir(parents=True, exist_ok=True)
    arguments = ['--parts', 'estimator', '--latency-seconds', f'{NODE_LATENCY_SECONDS:g}',
                 '--rates', '100', '--seconds', '1', '--realtime-priority', '0']
    ctx.log('stage node latency: bench_ros ' + ' '.join(arguments))
    started = time.perf_counter()
    try:
        done = run_to_end([str(bench_ros), *arguments, '--out', str(target)],
                          timeout=NODE_LATENCY_SECONDS + 300.0)
    except subprocess.TimeoutExpired:
        return {'measured': False, 'reason': 'bench_ros did not finish within '
                f'{NODE_LATENCY_SECONDS + 300.0:g} s'}
    if done.returncode != 0 or not target.is_file():
        tail = (done.stdout + done.stderr).strip().splitlines()[-1:] or ['no output']
        return {'measured': False, 'reason': f'bench_ros exited {done.returncode}: {tail[0]}'}
    measured = json.loads(target.read_text())
    latency = measured['estimator']['latency']
    result = {'measured': True, 'median_ms': latency['median_ms'], 'p99_ms': latency['p99_ms'],
              'frames': latency['frames'], 'complete': latency['complete'],
              'load_average': measured['load_average'],
              'command': 'bench_ros ' + ' '.join(arguments)}
    ctx.timings['node latency'] = time.perf_counter() - started
    ctx.cache.store_json('node_latency', key, result)
    return result


def end_to_end_stage(ctx: Context, layout: dict, models: dict, timing: dict,
                     latency: dict) -> dict:
    """What accuracy costs in time online: every model on the held-out session of the index
    fingertip as the estimator receives it (the same session simulated again without the
    training data's zero-phase filter on the tactile frames; offsets from the filtered one),
    with the estimator's causal input low-pass off and at FILTER_CUTOFFS_HZ. Time: the
    full-hand tick (with the filter when on), the filter's group delay, the node's median
    latency (when measured), and their sum."""
    s = ctx.settings
    filtered_path = layout['index_tip'][HELD_OUT_PLATE][0]
    raw_path, job = calibration_unit(ctx, 'index_tip', HELD_OUT_PLATE, 0, s.online_seconds,
                                     zero_phase_tactile=False)
    run_units(ctx, 'raw held-out session', [job] if job is not None else [])
    order = int(estimator_parameter('lowpass_order'))
    key = digest({'sessions': [Path(filtered_path).stem, Path(raw_path).stem],
                  'models': {m: Path(p).stem for m, p in models['index_tip'].items()},
                  'cutoffs': FILTER_CUTOFFS_HZ, 'order': order, 'static_force': s.static_force,
                  'code': source_digest(load_model, RuntimeEstimator, error_stats, BatchLowPass)})
    accuracy = ctx.cache.load_json('end_to_end', key)
    if accuracy is None:
        hand, _ = worker_hand()
        filtered, raw = CalibrationDataset.load(filtered_path), CalibrationDataset.load(raw_path)
        if not np.array_equal(filtered.time, raw.time):
            raise ValueError(f'{raw_path}: not the same session as {filtered_path}')
        X_filtered, F, _ = filtered.without_offsets(force_threshold=s.static_force)
        X = raw.X - (filtered.X - X_filtered)       # the same static offsets removed
        bundles = {label: load_model(models['index_tip'][label], hand.array('index_tip'))
                   for label in s.models}
        accuracy = []
        for cutoff in FILTER_CUTOFFS_HZ:
            design = None if cutoff is None else BatchLowPass(X[0].size, cutoff,
                                                              SAMPLE_RATE_HZ, order)
            X_in = X if design is None else design.run(X.reshape(len(X), -1)).reshape(X.shape)
            for label, bundle in bundles.items():
                stats = error_stats(F, bundle.predict(X_in, tare=np.zeros_like(bundle.x_offset)))
                accuracy.append({'model': label, 'cutoff_hz': cutoff,
                                 'group_delay_ms': 0.0 if design is None
                                 else 1e3 * design.group_delay_s(), **stats.as_dict()})
        ctx.cache.store_json('end_to_end', key, accuracy)
    node_ms = latency['median_ms'] if latency.get('measured') else None
    rows = []
    for row in accuracy:
        tick = timing['index_tip'][row['model']][
            'full_hand_tick' if row['cutoff_hz'] is None else 'full_hand_tick_lowpass']
        compute_ms = tick['median_us'] / 1e3
        rows.append({**row, 'compute_ms': compute_ms, 'node_latency_ms': node_ms,
                     'end_to_end_ms': compute_ms + row['group_delay_ms'] + (node_ms or 0.0)})
    return {'array': 'index_tip', 'plate': HELD_OUT_PLATE, 'filter_order': order,
            'node_latency': latency, 'rows': rows}


def model_config_file(ctx: Context, label: str, models: dict) -> Path:
    """An estimator model list (estimation/model_set.py format) with the index fingertip's model."""
    path = ctx.out / 'models' / f'{label}.yaml'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({'models': {'index_tip': str(Path(
        models['index_tip'][label]).resolve())}}))
    return path
