"""The main job's worker jobs: units (a calibration session, a training set, a cross-validation
or final fit, a closed-loop run) run in a process pool, each cached on its own, so a changed
input recomputes only the units whose key it enters.
"""
from __future__ import annotations

import signal
import sys
import time
import warnings
from concurrent.futures import as_completed
from typing import Any, Callable

import numpy as np
from tqdm import tqdm

from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.estimation.cross_validation import cross_validate, transfer
from tacforce_ros.estimation.dataset import CalibrationDataset, concatenate
from tacforce_ros.estimation.learning_curve import (kind_curve, kind_folds, learning_curve,
                                                    shared_learning_curve)
from tacforce_ros.estimation.mirror import mirrored
from tacforce_ros.estimation.model_io import save_model
from tacforce_ros.estimation.model_set import load_model_set
from tacforce_ros.estimation.preprocessing import SAMPLE_RATE_HZ
from tacforce_ros.estimation.training import for_deployment
from tacforce_ros.experiments.cache import atomic_write
from tacforce_ros.experiments.calibration_data import simulate_calibration
from tacforce_ros.experiments.closed_loop import ClosedLoopTrace, run_closed_loop
from tacforce_ros.hand.description import DEFAULT_SIDE, hand_config, load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.experiments.settings import Context, controller_config, tare_frames

_WORKER: dict[str, Any] = {}


def init_worker() -> None:
    """Per-process hand and kinematics (loaded once per worker). The main process decides when
    the job stops: a worker ignores SIGINT (a Ctrl-C reaches the whole process group) and dies of
    SIGTERM (the main process's terminate()). Inheriting the main process's SIGTERM-as-SIGINT, a
    worker turned each into a KeyboardInterrupt of its current unit, which the pool returns as
    that unit's result, and went on to the next (test_experiments_workers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    warnings.simplefilter('ignore')     # sim warnings repeat per run; the report states effects
    _WORKER['hand'] = load_hand()
    _WORKER['kinematics'] = HandKinematics.for_hand(_WORKER['hand'])


def worker_hand(side: str = DEFAULT_SIDE):
    """The process's hand and kinematics: the right hand's, or the `side` hand's (the budget
    campaign's mirror hand), each loaded once."""
    if not _WORKER:
        init_worker()
    if side == DEFAULT_SIDE:
        return _WORKER['hand'], _WORKER['kinematics']
    if side not in _WORKER:
        hand = load_hand(hand_config(side))
        _WORKER[side] = hand, HandKinematics.for_hand(hand)
    return _WORKER[side]


def _mirrored(dataset: CalibrationDataset) -> CalibrationDataset:
    """A recording of the other hand's array in the right hand's layout (estimation/mirror.py)."""
    source, _ = worker_hand(dataset.hand_side)
    target, _ = worker_hand()
    return mirrored(dataset, source.array(dataset.array), target.array(dataset.array))


def job_calibration(scene: str, seed: int, seconds: float, target: str,
                    zero_phase_tactile: bool = True, side: str = DEFAULT_SIDE) -> str:
    hand, kinematics = worker_hand(side)
    dataset = simulate_calibration(hand, kinematics, scene, seed, seconds,
                                   zero_phase_tactile=zero_phase_tactile)
    atomic_write(target, dataset.save)
    return target


def job_training_set(paths: list[str], static_force: float, target: str,
                     mirror: bool = False) -> str:
    """Join the sessions of one array, remove each session's offsets, store uncompressed (the
    fits of every model load it; compressed session files would be unpacked once per fit).
    `mirror`: sessions of the other hand, reflected into the right hand's layout first."""
    dataset = concatenate([CalibrationDataset.load(p) for p in paths])
    dataset = _mirrored(dataset) if mirror else dataset
    X, F, offset = dataset.without_offsets(force_threshold=static_force)
    atomic_write(target, lambda tmp: np.savez(tmp, X=X, F=F, plates=dataset.plates.astype(str),
                                              x_offset=offset))
    return target


def load_training(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(X, F, plates, x_offset) of a training set written by job_training_set."""
    with np.load(path, allow_pickle=False) as npz:
        return npz['X'], npz['F'], npz['plates'], npz['x_offset']


def job_cross_validation(array: str, kind: str, hyper: dict, training_set: str) -> dict:
    hand, _ = worker_hand()
    X, F, plates, _ = load_training(training_set)
    return cross_validate(hand.array(array), kind, hyper, X, F, plates).summary()


def job_transfer(source: str, kind: str, hyper: dict, training_set: str,
                 targets: dict[str, str]) -> dict[str, dict]:
    """`source`'s model applied unadapted to each target array of its kind (training sets by
    name): {target: cross-validation summary}."""
    hand, _ = worker_hand()
    X, F, plates, _ = load_training(training_set)
    data = {name: load_training(path)[:3] for name, path in targets.items()}
    return {name: result.summary() for name, result in
            transfer(hand.array(source), kind, hyper, X, F, plates, data).items()}


def job_learning_curve(array: str, paths: list[str], label: str, kind: str, hyper: dict,
                       seconds: float, static_force: float) -> dict:
    """One point of an array's learning curve (estimation/learning_curve.py) for one model."""
    hand, _ = worker_hand()
    dataset = concatenate([CalibrationDataset.load(p) for p in paths])
    (row,) = learning_curve(hand.array(array), dataset, {label: (kind, hyper)}, (seconds,),
                            force_threshold=static_force)
    return row


def job_shared_curve(array: str, paths: list[str], others: dict[str, str], label: str, kind: str,
                     hyper: dict, seconds: list[float], static_force: float) -> list[dict]:
    """An array's learning curve with the model its kind's other arrays share, adapted to it
    (estimation/shared_model.py); others: name -> training set."""
    hand, _ = worker_hand()
    dataset = concatenate([CalibrationDataset.load(p) for p in paths])
    data = {name: load_training(path)[:3] for name, path in others.items()}
    return shared_learning_curve(hand.array(array), dataset, label, kind, hyper, data,
                                 tuple(seconds), force_threshold=static_force)


def job_kind_curve(paths: dict[str, list[str]], label: str, kind: str, hyper: dict,
                   seconds: float, static_force: float,
                   pool: dict[str, list[str]] | None = None) -> list[dict]:
    """One point of a kind curve (estimation/learning_curve.kind_curve): the kind's arrays'
    sessions by name, every array cut to `seconds`; `pool`: the other hand's sessions by name,
    reflected into this hand's layout, whole."""
    hand, _ = worker_hand()
    arrays = {name: (hand.array(name), concatenate([CalibrationDataset.load(p) for p in files]))
              for name, files in paths.items()}
    pooled = {name: _mirrored(concatenate([CalibrationDataset.load(p) for p in files]))
              for name, files in (pool or {}).items()}
    return kind_curve(arrays, label, kind, hyper, (seconds,), pool=pooled,
                      force_threshold=static_force)


def job_kind_folds(recorded: dict[str, str], held_out: dict[str, str], kind: str,
                   hyper: dict, pool: dict[str, str] | None = None) -> dict[str, dict]:
    """Each array of a kind's campaign with its shared, adapted model, tested on other data
    (estimation/learning_curve.kind_folds); training sets by name, `pool`'s the other hand's
    (job_training_set with mirror). {name: cv summary}."""
    hand, _ = worker_hand()
    results = kind_folds({name: hand.array(name) for name in recorded}, kind, hyper,
                         {name: load_training(path)[:3] for name, path in recorded.items()},
                         {name: load_training(path)[:3] for name, path in held_out.items()},
                         {name: load_training(path)[:3] for name, path in (pool or {}).items()})
    return {name: result.summary() for name, result in results.items()}


def job_benchmark(array: str, kind: str, hyper: dict, training_set: str, provenance: dict,
                  target: str) -> dict:
    """Cross-validation and the model on every plate in one fit (cross_validate(final=True));
    writes the model to `target` with the cross-validation in its provenance; returns that."""
    hand, _ = worker_hand()
    X, F, plates, offset = load_training(training_set)
    cv = cross_validate(hand.array(array), kind, hyper, X, F, plates, final=True)
    summary = cv.summary()
    bundle = for_deployment(cv.final, offset, {
        **provenance, 'plates': list(dict.fromkeys(plates.tolist())), 'samples': int(X.shape[0]),
        'metrics': summary, 'way': 'own',
        'own_seconds': round(X.shape[0] / SAMPLE_RATE_HZ, 1)})   # training sets: one row a tick
    atomic_write(target, lambda tmp: save_model(tmp, bundle))
    return summary


def job_closed_loop(scene: str, seed: int, controller: str, model_config: str | None,
                    sequence: str, control_rate: float, target: str,
                    lowpass: tuple[float, int] | None = None) -> str:
    """`lowpass`: (cut-off Hz, order) of the estimator's causal input low-pass, None: off."""
    hand, kinematics = worker_hand()
    models = None if model_config is None else load_model_set(model_config, hand)
    if lowpass is not None:
        models.estimator.set_lowpass(lowpass[0], SAMPLE_RATE_HZ, lowpass[1])
    trace = run_closed_loop(hand, kinematics, scene, seed, controller_config(controller),
                            ForceSequence.load(sequence), models, control_rate=control_rate,
                            tare_frames=tare_frames())
    atomic_write(target, lambda tmp: np.savez(tmp, **trace.arrays()))
    return target


def _timed(job: Callable, *args) -> tuple[Any, float]:
    """The job's result and its wall time in the worker."""
    started = time.perf_counter()
    return job(*args), time.perf_counter() - started


def run_units(ctx: Context, title: str, units: list[tuple[str, Callable, tuple]]
              ) -> dict[str, Any]:
    """Submit (name, job, args) units to the pool; tqdm over completions; results by name. The
    stage's wall time goes to ctx.timings, its units' times to ctx.units."""
    results: dict[str, Any] = {}
    if not units:
        return results
    started = time.perf_counter()
    futures = {ctx.pool.submit(_timed, job, *args): name for name, job, args in units}
    seconds = []
    with tqdm(total=len(futures), desc=title, unit='job', file=sys.stderr) as bar:
        for future in as_completed(futures):
            results[futures[future]], took = future.result()
            seconds.append(took)
            bar.update(1)
    ctx.timings[title] = ctx.timings.get(title, 0.0) + time.perf_counter() - started
    stage = ctx.units.setdefault(title, {'units': 0, 'work_s': 0.0, 'longest_s': 0.0})
    stage.update(units=stage['units'] + len(seconds), work_s=stage['work_s'] + sum(seconds),
                 longest_s=max(stage['longest_s'], max(seconds)))
    return results


def predicted_seconds(timings: dict[str, float], units: dict[str, dict], wall: float,
                      workers: int) -> float:
    """The run's wall time predicted on `workers` worker processes (one a core): each pool stage
    takes its units' summed time over the workers, or its longest unit if that is longer (its
    critical path); the rest (stages in the main process, the report) as long as it took. An
    estimate: a unit's time measured on a loaded machine stays what it was."""
    pooled = sum(max(u['work_s'] / workers, u['longest_s']) for u in units.values())
    return wall - sum(timings[t] for t in units) + pooled


def load_trace(path: str):
    with np.load(path) as npz:
        return ClosedLoopTrace(**{k: npz[k] for k in ('t', 'f_d', 'f_hat', 'f_tilde')},
                               transitions=npz['transitions'].tolist())
