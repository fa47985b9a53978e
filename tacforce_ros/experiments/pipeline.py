"""The reproduction pipeline: stages, their cache keys, and the worker jobs that compute them.

Independent units (calibration sessions, cross-validation folds of one model, final fits,
closed-loop runs) go to a process pool; each unit is cached on its own, so a changed input
recomputes only the units whose key it enters.
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml
from tqdm import tqdm

from tacforce_ros.bringup.processes import executable, run_to_end
from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.control.force_controller import ForceControllerConfig, shipped_params_file
from tacforce_ros.estimation.causal_filter import BatchLowPass
from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.dataset import CalibrationDataset, concatenate
from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.estimation.model_io import load_model, save_model
from tacforce_ros.estimation.model_set import load_model_set
from tacforce_ros.estimation.preprocessing import CUTOFF_HZ, SAMPLE_RATE_HZ
from tacforce_ros.estimation.registry import paper_configurations
from tacforce_ros.estimation.runtime import RuntimeEstimator
from tacforce_ros.estimation.synthetic import synthetic_hand_estimator
from tacforce_ros.estimation.training import fit_bundles, for_deployment
from tacforce_ros.rig import HELD_OUT_PLATE, RATE_HZ, TRAINING_PLATES
from tacforce_ros.experiments import node_path
from tacforce_ros.experiments.cache import (StageCache, atomic_write, digest, file_digest,
                                            node_modules, scene_digest, source_digest,
                                            tool_modules)
from tacforce_ros.experiments.calibration_data import simulate_calibration
from tacforce_ros.experiments.closed_loop import ClosedLoopTrace, run_closed_loop
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.bringup.session_plan import shipped_parameters
from tacforce_ros.paths import config_dir
from tacforce_ros.sim import load_scene
from tacforce_ros.sim.effects.magnetic_skin import magnetic_skin_overlay
from tacforce_ros.sim.scene import calibration_scene_name, session_seed
from tacforce_ros.timing import time_interleaved

PLATES = TRAINING_PLATES
ARRAYS = ('index_tip', 'index_middle')                       # curved fingertip, flat phalanx
OBJECTS = ('spherical', 'foam_brick', 'softball', 'abrasive_sponge', 'bleach_cleanser')
CONTROLLERS = ('open_loop', 'M3-lambda', 'M4')               # Table III rows


def controllers_for(obj: str) -> tuple[str, ...]:
    """Paper Sec. IV-C: the open loop ran on the spherical plate only; the objects with the
    closed-loop controllers alone."""
    return CONTROLLERS if obj == HELD_OUT_PLATE else CONTROLLERS[1:]
ONLINE_MODELS = ('M3-lambda', 'M4')                          # Table II rows
# The estimator's input low-pass settings compared end to end (None: off, the node's default).
FILTER_CUTOFFS_HZ = (None, 20.0, 10.0, 5.0)
NODE_LATENCY_SECONDS = 10.0      # bench_ros's latency test, frames at 100 Hz


@dataclass(frozen=True)
class Settings:
    """Data sizes and choices of one run (the defaults are the full run)."""

    sessions_per_plate: int = 4          # paper: 4 x 100 s per plate and array
    session_seconds: float = 100.0
    online_seconds: float = 200.0        # paper: 200 s online on the spherical plate
    models: tuple[str, ...] = ('M1', 'M2', 'M3', 'M3-lambda', 'M3-lambda-cv', 'M4', 'M5')
    epochs: int = 40                     # M4/M5, as the paper
    timing_repeats: int = 2000
    objects: tuple[str, ...] = OBJECTS
    repeats: int = 5                     # paper: 5 runs per object and controller
    sequence: str = 'paper_70s'
    control_rate: float = RATE_HZ        # paper: control and estimation at the frame rate
    seed: int = 0
    # Static-segment force threshold for offsets [N], around the F/T's own no-contact reading
    # (estimation/preprocessing.py static_mask), so its un-zeroed bias does not matter.
    static_force: float = 0.3
    node_path: bool = True
    # The whole-hand campaign (every other array, M3-lambda): one session per training plate of
    # the paper's session length, a quarter of its data, for the budget (the Table I arrays
    # have the paper's sizes).
    whole_hand_seconds: float = 100.0
    skin: str = 'empirical'              # SKINS: every scene of the run on this skin

    @classmethod
    def quick(cls) -> Settings:
        """Small sizes for tests: every stage runs, on less data and fewer runs."""
        return cls(sessions_per_plate=1, session_seconds=20.0, online_seconds=20.0, epochs=1,
                   timing_repeats=100, objects=('spherical',), repeats=1, node_path=False,
                   whole_hand_seconds=20.0)


# The simulated skin: the empirical response (sim/taxel_response.py) or the one computed from
# the taxel's physics (sim/effects/magnetic_skin.py, docs/SKIN_PHYSICS.md).
SKINS = ('empirical', 'magnetic')


@dataclass
class Context:
    """What every stage needs: settings, cache, output folder, pool and progress output."""

    settings: Settings
    out: Path
    cache: StageCache
    pool: ProcessPoolExecutor
    log: Callable[[str], None] = print
    timings: dict[str, float] = field(default_factory=dict)


def scene_for(ctx: Context, name: str) -> str:
    """The scene `name` on the run's skin (skin_scene, files in <out>/scenes)."""
    return skin_scene(ctx.out / 'scenes', name, ctx.settings.skin)


def skin_scene(folder: Path, name: str, skin: str) -> str:
    """The scene `name` on `skin`: `name` itself on the empirical skin; on the magnetic skin, a
    scene file in `folder` that extends it, which the node graph's `session --scene` loads as
    the direct path does (and a user can launch)."""
    if skin == 'empirical':
        return name
    if skin != 'magnetic':
        raise ValueError(f'skin {skin!r}: one of {SKINS}')
    text = yaml.safe_dump({'extends': name, 'effects': magnetic_skin_overlay()}, sort_keys=False)
    return str(atomic_write(folder / f'{name}_{skin}.yaml', lambda tmp: tmp.write_text(text)))


# ---------------------------------------------------------------------------------- workers

_WORKER: dict[str, Any] = {}


def init_worker() -> None:
    """Per-process hand and kinematics (loaded once per worker)."""

    warnings.simplefilter('ignore')     # sim warnings repeat per run; the report states effects
    _WORKER['hand'] = load_hand()
    _WORKER['kinematics'] = HandKinematics.for_hand(_WORKER['hand'])


def _hand():
    if not _WORKER:
        init_worker()
    return _WORKER['hand'], _WORKER['kinematics']


def job_calibration(scene: str, seed: int, seconds: float, target: str,
                    zero_phase_tactile: bool = True) -> str:
    hand, kinematics = _hand()
    dataset = simulate_calibration(hand, kinematics, scene, seed, seconds,
                                   zero_phase_tactile=zero_phase_tactile)
    atomic_write(target, dataset.save)
    return target


def job_training_set(paths: list[str], static_force: float, target: str) -> str:
    """Join the sessions of one array, remove each session's offsets, store uncompressed (the
    fits of every model load it; compressed session files would be unpacked once per fit)."""
    dataset = concatenate([CalibrationDataset.load(p) for p in paths])
    X, F, offset = dataset.without_offsets(force_threshold=static_force)
    atomic_write(target, lambda tmp: np.savez(tmp, X=X, F=F, plates=dataset.plates.astype(str),
                                              x_offset=offset))
    return target


def load_training(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(X, F, plates, x_offset) of a training set written by job_training_set."""
    with np.load(path, allow_pickle=False) as npz:
        return npz['X'], npz['F'], npz['plates'], npz['x_offset']


def job_cross_validation(array: str, kind: str, hyper: dict, training_set: str) -> dict:
    hand, _ = _hand()
    X, F, plates, _ = load_training(training_set)
    return cross_validate(hand.array(array), kind, hyper, X, F, plates).summary()


def job_benchmark(array: str, kind: str, hyper: dict, training_set: str, provenance: dict,
                  target: str) -> dict:
    """Cross-validation and the model on every plate in one fit (cross_validate(final=True));
    writes the model to `target` with the cross-validation in its provenance; returns that."""
    hand, _ = _hand()
    X, F, plates, offset = load_training(training_set)
    cv = cross_validate(hand.array(array), kind, hyper, X, F, plates, final=True)
    summary = cv.summary()
    bundle = for_deployment(cv.final, offset, {
        **provenance, 'plates': list(dict.fromkeys(plates.tolist())), 'samples': int(X.shape[0]),
        'metrics': summary})
    atomic_write(target, lambda tmp: save_model(tmp, bundle))
    return summary


def job_closed_loop(scene: str, seed: int, controller: str, model_config: str | None,
                    sequence: str, control_rate: float, target: str,
                    lowpass: tuple[float, int] | None = None) -> str:
    """`lowpass`: (cut-off Hz, order) of the estimator's causal input low-pass, None: off."""
    hand, kinematics = _hand()
    models = None if model_config is None else load_model_set(model_config, hand)
    if lowpass is not None:
        models.estimator.set_lowpass(lowpass[0], SAMPLE_RATE_HZ, lowpass[1])
    trace = run_closed_loop(hand, kinematics, scene, seed, controller_config(controller),
                            ForceSequence.load(sequence), models, control_rate=control_rate,
                            tare_frames=tare_frames())
    atomic_write(target, lambda tmp: np.savez(tmp, **trace.arrays()))
    return target


# ---------------------------------------------------------------------------------- inputs

def controller_config(controller: str):
    """The project's controller parameters; open loop is the same with K_i = 0 (paper)."""
    config = ForceControllerConfig.from_yaml(shipped_params_file())
    return dataclasses.replace(config, k_i=(0.0, 0.0, 0.0)) if controller == 'open_loop' \
        else config


def estimator_parameter(name: str):
    """A parameter of the estimator node as the project ships it (config/params/estimator.yaml)."""
    return shipped_parameters('estimator')[name]


def tare_frames() -> int:
    """Frames the estimator node tares on."""
    return int(estimator_parameter('tare_frames'))


def hand_digest() -> str:
    hand_dir = config_dir() / 'hand'
    return file_digest(*sorted(hand_dir.glob('*.yaml')),
                       *sorted((config_dir() / 'urdf').glob('*.urdf')))


def model_hyper(label: str, settings: Settings) -> tuple[str, dict]:
    return paper_configurations(settings.seed, settings.epochs)[label]


# ---------------------------------------------------------------------------------- running

def run_units(ctx: Context, title: str, units: list[tuple[str, Callable, tuple]]
              ) -> dict[str, Any]:
    """Submit (name, job, args) units to the pool; tqdm over completions; results by name."""
    results: dict[str, Any] = {}
    if not units:
        return results
    started = time.perf_counter()
    futures = {ctx.pool.submit(job, *args): name for name, job, args in units}
    with tqdm(total=len(futures), desc=title, unit='job', file=sys.stderr) as bar:
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            bar.update(1)
    ctx.timings[title] = ctx.timings.get(title, 0.0) + time.perf_counter() - started
    return results


def calibration_unit(ctx: Context, array: str, plate: str, session: int, seconds: float,
                     zero_phase_tactile: bool = True) -> tuple[str, tuple | None]:
    """(dataset path, job unit to run, or None when the cache has it) of one session."""
    scene = scene_for(ctx, calibration_scene_name(array, plate))
    seed = session_seed(ctx.settings.seed, array, plate, session)
    key = digest({'scene': scene_digest(scene), 'seed': seed, 'seconds': seconds,
                  'code': source_digest(simulate_calibration, load_hand, HandKinematics),
                  'hand': hand_digest(),
                  **({} if zero_phase_tactile else {'zero_phase_tactile': False})})
    path = ctx.cache.path('calibration', key, '.npz')
    if ctx.cache.lookup('calibration', key, '.npz') is not None:
        return str(path), None
    path.parent.mkdir(parents=True, exist_ok=True)
    return str(path), (str(path), job_calibration,
                       (scene, seed, seconds, str(path), zero_phase_tactile))


def calibration_stage(ctx: Context) -> dict[str, dict[str, list[str]]]:
    """Simulated sessions: {array: {plate: [dataset paths]}}, training plates + held-out."""
    s = ctx.settings
    jobs, layout = [], {}
    plan = [(a, p, k, s.session_seconds) for a in ARRAYS for p in PLATES
            for k in range(s.sessions_per_plate)]
    plan.append(('index_tip', HELD_OUT_PLATE, 0, s.online_seconds))   # online test session
    for array, plate, session, seconds in plan:
        path, job = calibration_unit(ctx, array, plate, session, seconds)
        layout.setdefault(array, {}).setdefault(plate, []).append(path)
        jobs += [job] if job is not None else []
    ctx.log(f'stage calibration: {len(plan)} sessions, {len(jobs)} to simulate')
    run_units(ctx, 'calibration sessions', jobs)
    return layout


def _training_key(paths: list[str], label: str, settings: Settings) -> str:
    return digest({'data': sorted(Path(p).stem for p in paths),
                   'model': model_hyper(label, settings),
                   'static_force': settings.static_force,
                   'code': source_digest(cross_validate, fit_bundles, for_deployment)})


def training_sets(ctx: Context, title: str, sessions: dict[str, list[str]]) -> dict[str, str]:
    """{array: training set path} from {array: session dataset paths}, made where not cached."""
    static_force = ctx.settings.static_force
    sets, jobs = {}, []
    for array, paths in sessions.items():
        key = digest({'data': sorted(Path(p).stem for p in paths),
                      'static_force': static_force, 'code': source_digest(concatenate)})
        sets[array] = str(ctx.cache.path('training_set', key, '.npz'))
        if ctx.cache.lookup('training_set', key, '.npz') is None:
            Path(sets[array]).parent.mkdir(parents=True, exist_ok=True)
            jobs.append((array, job_training_set, (paths, static_force, sets[array])))
    run_units(ctx, title, jobs)
    return sets


def benchmark_stage(ctx: Context, layout: dict) -> tuple[dict, dict]:
    """Table I: leave-one-plate-out CV per array and model; final models on all five plates.

    Returns ({array: {label: cv summary}}, {array: {label: model path}}).
    """
    s = ctx.settings
    sets = training_sets(ctx, 'training sets', {
        array: [p for plate in PLATES for p in layout[array][plate]] for array in ARRAYS})
    jobs, cv, models, keys = [], {}, {}, {}
    for array in ARRAYS:
        paths = [p for plate in PLATES for p in layout[array][plate]]
        for label in s.models:
            kind, hyper = model_hyper(label, s)
            key = _training_key(paths, label, s)
            name = f'{array}/{label}'
            keys[name] = key
            target = ctx.cache.path('models', key, '.npz')
            models.setdefault(array, {})[label] = str(target)
            cached = ctx.cache.load_json('cross_validation', key)
            if cached is not None and ctx.cache.lookup('models', key, '.npz') is not None:
                cv.setdefault(array, {})[label] = cached
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            provenance = {'dataset': f'reproduce cache {key[:24]}', 'date':
                          time.strftime('%Y-%m-%dT%H:%M:%S%z'), 'seed': s.seed,
                          'code_version': source_digest(fit_bundles)[:12]}
            jobs.append((name, job_benchmark, (array, kind, hyper, sets[array], provenance,
                                               str(target))))
    ctx.log(f'stage benchmark: {len(jobs)} of {len(ARRAYS) * len(s.models)} cross-validations, '
            f'each with its final model in the same fit, to run')
    # Slow (torch) units first, so the pool does not end on one long job.
    slow = ('M5', 'M4')
    order = sorted(jobs, key=lambda u: [u[0].endswith(k) for k in slow], reverse=True)
    for name, value in run_units(ctx, 'benchmark fits', order).items():
        ctx.cache.store_json('cross_validation', keys[name], value)
        array, label = name.split('/')
        cv.setdefault(array, {})[label] = value
    # Rows in the settings' model order, whatever order the units finished in.
    return {a: {label: cv[a][label] for label in s.models} for a in ARRAYS}, models


WHOLE_HAND_MODEL = 'M3-lambda'


def whole_hand_stage(ctx: Context, cv: dict) -> dict:
    """The whole-hand campaign: every array not in Table I, one session per training plate of
    `whole_hand_seconds`, M3-lambda leave-one-plate-out; the Table I arrays keep their rows.
    Returns {array: {'type', 'sessions', 'seconds', 'cv'}} in hand order."""
    s = ctx.settings
    hand, _ = _hand()
    others = [a.name for a in hand.arrays if a.name not in ARRAYS]
    jobs, layout = [], {}
    for array in others:
        for plate in PLATES:
            path, job = calibration_unit(ctx, array, plate, 0, s.whole_hand_seconds)
            layout.setdefault(array, []).append(path)
            jobs += [job] if job is not None else []
    ctx.log(f'stage whole hand: {len(others)} arrays x {len(PLATES)} plates, {len(jobs)} '
            'sessions to simulate')
    run_units(ctx, 'whole-hand sessions', jobs)
    sets = training_sets(ctx, 'whole-hand training sets', layout)
    kind, hyper = model_hyper(WHOLE_HAND_MODEL, s)
    results, cv_jobs, keys = {}, [], {}
    for array, paths in layout.items():
        keys[array] = _training_key(paths, WHOLE_HAND_MODEL, s)
        cached = ctx.cache.load_json('cross_validation', keys[array])
        if cached is None:
            cv_jobs.append((array, job_cross_validation, (array, kind, hyper, sets[array])))
        else:
            results[array] = cached
    for array, value in run_units(ctx, 'whole-hand cross-validations', cv_jobs).items():
        ctx.cache.store_json('cross_validation', keys[array], value)
        results[array] = value
    rows = {}
    for array in hand.arrays:
        if array.name in ARRAYS:
            rows[array.name] = {'type': array.kind, 'sessions': s.sessions_per_plate,
                                'seconds': s.session_seconds,
                                'cv': cv[array.name][WHOLE_HAND_MODEL]}
        else:
            rows[array.name] = {'type': array.kind, 'sessions': 1,
                                'seconds': s.whole_hand_seconds, 'cv': results[array.name]}
    return rows


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
    hand, _ = _hand()
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
    hand, _ = _hand()
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
    key = digest({'seconds': NODE_LATENCY_SECONDS,
                  'code': source_digest(*tool_modules('bench_ros'), *node_modules())})
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
        done = run_to_end([str(executable('bench_ros')), *arguments, '--out', str(target)],
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
        hand, _ = _hand()
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


def closed_loop_seed(obj: str, repeat: int, base: int) -> int:
    """Repeat k of every controller on one object shares its seed (a paired comparison)."""
    return session_seed(base, 'closed_loop', obj, repeat)


def closed_loop_unit(ctx: Context, obj: str, controller: str, repeat: int, models: dict,
                     lowpass: tuple[float, int] | None = None) -> tuple[str, tuple | None]:
    """(trace path, job unit to run, or None when the cache has it) of one closed-loop run."""
    s = ctx.settings
    scene = scene_for(ctx, f'closed_loop_{obj}')
    code = source_digest(run_closed_loop, load_model_set, ForceSequence, load_hand, HandKinematics)
    inputs = file_digest(shipped_params_file(), config_dir() / 'commands' / f'{s.sequence}.yaml',
                         config_dir() / 'params' / 'estimator.yaml')
    model_config = None if controller == 'open_loop' else \
        model_config_file(ctx, controller, models)
    model_key = None if model_config is None else Path(models['index_tip'][controller]).stem
    seed = closed_loop_seed(obj, repeat, s.seed)
    key = digest({'scene': scene_digest(scene), 'seed': seed, 'model': model_key,
                  'controller': controller, 'rate': s.control_rate, 'code': code,
                  'inputs': inputs, 'hand': hand_digest(),
                  **({} if lowpass is None else {'lowpass': lowpass,
                                                 'filter_code': source_digest(BatchLowPass)})})
    target = ctx.cache.path('closed_loop', key, '.npz')
    if ctx.cache.lookup('closed_loop', key, '.npz') is not None:
        return str(target), None
    target.parent.mkdir(parents=True, exist_ok=True)
    return str(target), (str(target), job_closed_loop,
                         (scene, seed, controller,
                          None if model_config is None else str(model_config),
                          s.sequence, s.control_rate, str(target), lowpass))


def closed_loop_stage(ctx: Context, models: dict) -> dict[tuple[str, str], list[str]]:
    """Table III runs: {(object, controller): [trace paths]}."""
    s = ctx.settings
    jobs, traces = [], {}
    for obj in s.objects:
        for controller in controllers_for(obj):
            for repeat in range(s.repeats):
                path, job = closed_loop_unit(ctx, obj, controller, repeat, models)
                traces.setdefault((obj, controller), []).append(path)
                jobs += [job] if job is not None else []
    ctx.log(f'stage closed loop: {sum(map(len, traces.values()))} runs, {len(jobs)} to simulate')
    run_units(ctx, 'closed-loop runs', jobs)
    return traces


def filtered_closed_loop_stage(ctx: Context, models: dict, end_to_end: dict) -> dict:
    """The closed-loop effect of the input low-pass: M3-lambda on the spherical plate, the same
    repeats (seeds) as Table III's, with the estimator's input low-pass at the cut-off that gave
    M3-lambda the lowest e_hat of the cut-offs on the held-out session (`best_offline`: and
    lower than without a filter). Returns the cut-off, its group delay and the trace paths."""
    s = ctx.settings
    label = 'M3-lambda'
    mine = [r for r in end_to_end['rows'] if r['model'] == label]
    best = min((r for r in mine if r['cutoff_hz'] is not None), key=lambda r: r['e_hat_mean'])
    chosen = best['cutoff_hz']
    lowpass = (chosen, end_to_end['filter_order'])
    jobs, paths = [], []
    for repeat in range(s.repeats):
        path, job = closed_loop_unit(ctx, HELD_OUT_PLATE, label, repeat, models, lowpass)
        paths.append(path)
        jobs += [job] if job is not None else []
    ctx.log(f'stage filtered closed loop: {len(paths)} runs of {label} with a {chosen:g} Hz '
            f'input low-pass, {len(jobs)} to simulate')
    run_units(ctx, 'filtered closed-loop runs', jobs)
    unfiltered = next(r for r in mine if r['cutoff_hz'] is None)
    return {'controller': label, 'object': HELD_OUT_PLATE, 'cutoff_hz': chosen,
            'best_offline': best['e_hat_mean'] < unfiltered['e_hat_mean'],
            'group_delay_ms': best['group_delay_ms'], 'traces': paths}


def load_trace(path: str):
    with np.load(path) as npz:
        return ClosedLoopTrace(**{k: npz[k] for k in ('t', 'f_d', 'f_hat', 'f_tilde')},
                               transitions=npz['transitions'].tolist())


def node_path_stage(ctx: Context, models: dict) -> dict:
    """One calibration session and one closed-loop run (M3-lambda, spherical plate) through the
    node graph, each compared with the direct path on the same scene and seed. Cached like the
    other stages; a failure is recorded with its reason, never replaced by direct results."""
    s = ctx.settings
    if not s.node_path:
        return {'ran': False, 'reason': 'switched off for this run (--quick or --no-node-path)'}
    hand, kinematics = _hand()
    calibration_scene = scene_for(ctx, calibration_scene_name('index_tip', HELD_OUT_PLATE))
    loop_scene = scene_for(ctx, 'closed_loop_spherical')
    model = models['index_tip']['M3-lambda']
    key = digest({'scenes': [scene_digest(calibration_scene), scene_digest(loop_scene)],
                  'model': Path(model).stem,
                  'code': source_digest(node_path.run_session, *tool_modules('session'),
                                        node_path.closed_loop_against_direct,
                                        node_path.bag_check, run_closed_loop,
                                        *node_modules()),
                  'inputs': file_digest(*sorted((config_dir() / 'params').glob('*.yaml')),
                                        config_dir() / 'commands' / f'{s.sequence}.yaml')})
    cached = ctx.cache.load_json('node_path', key)
    if cached is not None:
        return cached
    work = ctx.cache.path('node_path', key, '.d')
    result: dict[str, Any] = {'ran': True, 'work_dir': str(work)}
    started = time.perf_counter()
    try:
        ctx.log(f'stage node path: calibration session ({node_path.CALIBRATION_SECONDS:g} s '
                'simulated)')
        bag = node_path.run_session('calibration', calibration_scene, HELD_OUT_PLATE,
                                    work / 'calibration', node_path.CALIBRATION_SECONDS,
                                    seed=load_scene(calibration_scene).seed)
        result['calibration'] = node_path.compare_calibration(
            bag, hand, kinematics, calibration_scene, load_scene(calibration_scene).seed, model,
            s.static_force)
        sequence = ForceSequence.load(s.sequence)
        ctx.log(f'stage node path: closed-loop run ({sequence.duration:g} s + start-up, '
                'simulated)')
        result['closed_loop'], trace, direct, bag = node_path.closed_loop_against_direct(
            hand, kinematics, loop_scene, HELD_OUT_PLATE, load_scene(loop_scene).seed,
            model_config_file(ctx, 'M3-lambda', models), sequence, work / 'closed_loop',
            controller_config('M3-lambda'), tare_frames(), control_rate=s.control_rate)
        result['closed_loop_bag'] = node_path.bag_check(bag)
        np.savez(work / 'closed_loop_traces.npz',
                 **{f'node_{k}': v for k, v in trace.arrays().items()},
                 **{f'direct_{k}': v for k, v in direct.arrays().items()})
    except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
        result.update(ran=False, reason=str(exc))
        ctx.log(f'stage node path: did not complete: {exc}')
        return result          # not cached: the next run tries again
    ctx.timings['node path'] = time.perf_counter() - started
    ctx.cache.store_json('node_path', key, result)
    return result
