"""Stages of the main job that calibrate: simulated calibration sessions, training sets, the
leave-one-plate-out benchmark (Table I) and the whole-hand campaign.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tacforce_ros.estimation.cross_validation import cross_validate, transfer
from tacforce_ros.estimation.dataset import concatenate
from tacforce_ros.estimation.learning_curve import shared_learning_curve
from tacforce_ros.estimation.mirror import mirrored
from tacforce_ros.estimation.shared_model import shared_folds
from tacforce_ros.estimation.training import fit_bundles, for_deployment
from tacforce_ros.rig import HELD_OUT_PLATE
from tacforce_ros.experiments.cache import digest, scene_digest, source_digest
from tacforce_ros.experiments.calibration_data import simulate_calibration
from tacforce_ros.hand.description import DEFAULT_SIDE, load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.sim.scene import calibration_scene_name, session_seed
from tacforce_ros.experiments.settings import (ARRAYS, GRASP_ARRAYS, PLATES, SHARED_MODEL,
                                             WHOLE_HAND_MODEL,
                                             Context, Settings, hand_digest, model_hyper,
                                             scene_for)
from tacforce_ros.experiments.workers import (job_benchmark, job_calibration, job_cross_validation,
                                            job_learning_curve, job_shared_curve,
                                            job_training_set, job_transfer,
                                            run_units, worker_hand)


def calibration_unit(ctx: Context, array: str, plate: str, session: int, seconds: float,
                     zero_phase_tactile: bool = True, side: str = DEFAULT_SIDE
                     ) -> tuple[str, tuple | None]:
    """(dataset path, job unit to run, or None when the cache has it) of one session, on the
    right hand or on the `side` hand (another hand: its own modules and session seeds)."""
    scene = scene_for(ctx, calibration_scene_name(array, plate))
    seed = session_seed(ctx.settings.seed, array if side == DEFAULT_SIDE else f'{side}/{array}',
                        plate, session)
    key = digest({'scene': scene_digest(scene), 'seed': seed, 'seconds': seconds,
                  'code': source_digest(simulate_calibration, load_hand, HandKinematics),
                  'hand': hand_digest(),
                  **({} if zero_phase_tactile else {'zero_phase_tactile': False}),
                  **({} if side == DEFAULT_SIDE else {'side': side})})
    path = ctx.cache.path('calibration', key, '.npz')
    if ctx.cache.lookup('calibration', key, '.npz') is not None:
        return str(path), None
    path.parent.mkdir(parents=True, exist_ok=True)
    return str(path), (str(path), job_calibration,
                       (scene, seed, seconds, str(path), zero_phase_tactile, side))


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


def training_sets(ctx: Context, title: str, sessions: dict[str, list[str]],
                  mirror: bool = False) -> dict[str, str]:
    """{array: training set path} from {array: session dataset paths}, made where not cached.
    `mirror`: sessions of the other hand, reflected into the right hand's layout."""
    static_force = ctx.settings.static_force
    sets, jobs = {}, []
    for array, paths in sessions.items():
        key = digest({'data': sorted(Path(p).stem for p in paths),
                      'static_force': static_force, 'code': source_digest(concatenate),
                      **({'mirror': source_digest(mirrored)} if mirror else {})})
        sets[array] = str(ctx.cache.path('training_set', key, '.npz'))
        if ctx.cache.lookup('training_set', key, '.npz') is None:
            Path(sets[array]).parent.mkdir(parents=True, exist_ok=True)
            jobs.append((array, job_training_set, (paths, static_force, sets[array], mirror)))
    run_units(ctx, title, jobs)
    return sets


def _benchmark_unit(ctx: Context, name: str, array: str, label: str, paths: list[str],
                    training_set: str) -> tuple[str, str, dict | None, tuple | None]:
    """(cache key, model path, cached cross-validation or None, job unit or None) of one
    leave-one-plate-out benchmark of `label` on `array`'s sessions, with its model on all the
    plates fitted in the same job (job_benchmark)."""
    s = ctx.settings
    key = _training_key(paths, label, s)
    target = ctx.cache.path('models', key, '.npz')
    cached = ctx.cache.load_json('cross_validation', key)
    if cached is not None and ctx.cache.lookup('models', key, '.npz') is not None:
        return key, str(target), cached, None
    target.parent.mkdir(parents=True, exist_ok=True)
    kind, hyper = model_hyper(label, s)
    provenance = {'dataset': f'reproduce cache {key[:24]}', 'date':
                  time.strftime('%Y-%m-%dT%H:%M:%S%z'), 'seed': s.seed,
                  'code_version': source_digest(fit_bundles)[:12]}
    return key, str(target), None, (name, job_benchmark, (array, kind, hyper, training_set,
                                                          provenance, str(target)))


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
            name = f'{array}/{label}'
            keys[name], models.setdefault(array, {})[label], cached, job = _benchmark_unit(
                ctx, name, array, label, paths, sets[array])
            if cached is not None:
                cv.setdefault(array, {})[label] = cached
            jobs += [job] if job is not None else []
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


def _whole_hand_units(ctx: Context, arrays: list[str], sessions: int, seconds: float
                      ) -> tuple[dict[str, list[str]], list]:
    """({array: session paths}, job units not cached) of `sessions` per training plate."""
    jobs, layout = [], {}
    for array in arrays:
        for plate in PLATES:
            for session in range(sessions):
                path, job = calibration_unit(ctx, array, plate, session, seconds)
                layout.setdefault(array, []).append(path)
                jobs += [job] if job is not None else []
    return layout, jobs


def grasp_arrays_stage(ctx: Context) -> tuple[dict[str, dict], dict[str, str], dict[str, str]]:
    """The fingertips a grasp needs beyond Table I's (GRASP_ARRAYS), calibrated as the Table I
    arrays are, WHOLE_HAND_MODEL 5-fold leave-one-plate-out and fitted on all five plates (its
    model then stands beside the index fingertip's in the grasp): the whole-hand quarter of that
    data left the thumb's M3-lambda reading a pinched ball at 2-7x its force on the magnetic
    skin (held-out e_hat 0.32 N against 0.27 N with the full data).
    Returns ({array: cv summary}, {array: model path}, {array: training set path})."""
    s = ctx.settings
    layout, jobs = _whole_hand_units(ctx, list(GRASP_ARRAYS), s.sessions_per_plate,
                                     s.session_seconds)
    ctx.log(f'stage grasp fingertips: {len(GRASP_ARRAYS)} arrays x {len(PLATES)} plates, '
            f'{len(jobs)} sessions to simulate')
    run_units(ctx, 'grasp fingertip sessions', jobs)
    sets = training_sets(ctx, 'grasp fingertip training sets', layout)
    results, jobs, keys, final = {}, [], {}, {}
    for array, paths in layout.items():
        keys[array], final[array], cached, job = _benchmark_unit(
            ctx, array, array, WHOLE_HAND_MODEL, paths, sets[array])
        if cached is not None:
            results[array] = cached
        jobs += [job] if job is not None else []
    for array, value in run_units(ctx, 'grasp fingertip fits', jobs).items():
        ctx.cache.store_json('cross_validation', keys[array], value)
        results[array] = value
    return results, final, sets


def whole_hand_stage(ctx: Context, cv: dict, table_i_layout: dict, grasp_cv: dict[str, dict],
                     grasp_sets: dict[str, str]) -> tuple[dict, dict[str, str]]:
    """The whole-hand campaign: every array not in Table I nor a grasp's fingertip, one session
    per training plate of `whole_hand_seconds`, WHOLE_HAND_MODEL leave-one-plate-out; the Table I
    arrays and the grasp's fingertips (grasp_arrays_stage) keep their rows.
    Returns ({array: {'type', 'sessions', 'seconds', 'cv'}} in hand order, {array: training set
    path} of every array, Table I's from `table_i_layout`)."""
    s = ctx.settings
    hand, _ = worker_hand()
    others = [a.name for a in hand.arrays if a.name not in ARRAYS and a.name not in GRASP_ARRAYS]
    layout, jobs = _whole_hand_units(ctx, others, 1, s.whole_hand_seconds)
    ctx.log(f'stage whole hand: {len(others)} arrays x {len(PLATES)} plates, {len(jobs)} '
            'sessions to simulate')
    run_units(ctx, 'whole-hand sessions', jobs)
    sets = training_sets(ctx, 'whole-hand training sets', layout)
    kind, hyper = model_hyper(WHOLE_HAND_MODEL, s)
    results, cv_jobs, keys = dict(grasp_cv), [], {}
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
    sets.update(grasp_sets)
    sets.update(training_sets(ctx, 'training sets', {
        array: [p for plate in PLATES for p in table_i_layout[array][plate]]
        for array in ARRAYS}))
    rows = {}
    for array in hand.arrays:
        if array.name in ARRAYS:
            rows[array.name] = {'type': array.kind, 'sessions': s.sessions_per_plate,
                                'seconds': s.session_seconds,
                                'cv': cv[array.name][WHOLE_HAND_MODEL]}
        elif array.name in GRASP_ARRAYS:
            rows[array.name] = {'type': array.kind, 'sessions': s.sessions_per_plate,
                                'seconds': s.session_seconds, 'cv': results[array.name]}
        else:
            rows[array.name] = {'type': array.kind, 'sessions': 1,
                                'seconds': s.whole_hand_seconds, 'cv': results[array.name]}
    return rows, sets


def cross_array_stage(ctx: Context, sets: dict[str, str], whole_hand: dict) -> dict:
    """Each array's WHOLE_HAND_MODEL applied unadapted to every other array of its kind
    (estimation/cross_validation.transfer: held-out plate by held-out plate, as the array's own
    model is judged), against each array's own held-out e_hat (the whole-hand rows). A unit per
    source array. Returns report.json's `cross_array`."""
    s = ctx.settings
    kind, hyper = model_hyper(WHOLE_HAND_MODEL, s)
    by_kind: dict[str, list[str]] = {}
    for array, row in whole_hand.items():
        by_kind.setdefault(row['type'], []).append(array)
    jobs, keys = [], {}
    for arrays in by_kind.values():
        for source in arrays:
            targets = {t: sets[t] for t in arrays if t != source}
            if not targets:
                continue
            keys[source] = digest({'source': Path(sets[source]).stem,
                                   'targets': {t: Path(p).stem for t, p in targets.items()},
                                   'model': [kind, hyper],
                                   'code': source_digest(job_transfer, transfer)})
            if ctx.cache.load_json('transfer', keys[source]) is None:
                jobs.append((source, job_transfer, (source, kind, hyper, sets[source], targets)))
    ctx.log(f'stage cross-array: {len(keys)} source arrays, {len(jobs)} to fit')
    for source, value in run_units(ctx, 'cross-array transfer', jobs).items():
        ctx.cache.store_json('transfer', keys[source], value)
    pairs = [{'source': source, 'target': target, 'kind': whole_hand[source]['type'],
              'e_hat_n': summary['e_hat_mean']}
             for source in keys
             for target, summary in ctx.cache.load_json('transfer', keys[source]).items()]
    return cross_array_summary(WHOLE_HAND_MODEL, pairs, whole_hand)


def cross_array_summary(model: str, pairs: list[dict], whole_hand: dict) -> dict:
    """Per target array: its own held-out e_hat, the other arrays' models' on it (mean, least,
    most) and their ratio; per kind the means and the ratio of the means."""
    rows = []
    for array, row in whole_hand.items():
        unadapted = [p['e_hat_n'] for p in pairs if p['target'] == array]
        if not unadapted:
            continue
        own = row['cv']['e_hat_mean']
        rows.append({'array': array, 'kind': row['type'], 'own_e_hat_n': own,
                     'unadapted_e_hat_n': float(np.mean(unadapted)),
                     'unadapted_min_n': float(min(unadapted)),
                     'unadapted_max_n': float(max(unadapted)),
                     'ratio': float(np.mean(unadapted)) / own})
    kinds = {}
    for kind in dict.fromkeys(r['kind'] for r in rows):
        own = float(np.mean([r['own_e_hat_n'] for r in rows if r['kind'] == kind]))
        unadapted = float(np.mean([r['unadapted_e_hat_n'] for r in rows if r['kind'] == kind]))
        kinds[kind] = {'arrays': sum(r['kind'] == kind for r in rows), 'own_e_hat_n': own,
                       'unadapted_e_hat_n': unadapted, 'ratio': unadapted / own}
    return {'model': model, 'pairs': pairs, 'rows': rows, 'by_kind': kinds}


def learning_curve_stage(ctx: Context, layout: dict) -> list[dict]:
    """Held-out e_hat against labelled seconds (estimation/learning_curve.py) on the Table I
    arrays' training sessions, for each model of `learning_models`: a unit per array, model and
    point, cached on its own. Rows as report.json `learning_curve.rows`."""
    s = ctx.settings
    jobs, keys, names = [], {}, []
    for array in ARRAYS:
        paths = [p for plate in PLATES for p in layout[array][plate]]
        for label in s.learning_models:
            kind, hyper = model_hyper(label, s)
            for seconds in s.learning_seconds:
                name = f'{array}/{label}/{seconds:g}'
                names.append(name)
                keys[name] = digest({'data': [Path(p).stem for p in paths], 'model': [kind, hyper],
                                     'seconds': seconds, 'static_force': s.static_force,
                                     'code': source_digest(job_learning_curve)})
                if ctx.cache.load_json('learning_curve', keys[name]) is None:
                    jobs.append((name, job_learning_curve, (array, paths, label, kind, hyper,
                                                            seconds, s.static_force)))
    ctx.log(f'stage learning curves: {len(names)} points, {len(jobs)} to fit')
    slow = sorted(jobs, key=lambda u: (u[0].split('/')[1] != 'M4', -float(u[0].split('/')[2])))
    for name, row in run_units(ctx, 'learning curves', slow).items():
        ctx.cache.store_json('learning_curve', keys[name], row)
    return [ctx.cache.load_json('learning_curve', keys[name]) for name in names]


def shared_curve_stage(ctx: Context, layout: dict, sets: dict[str, str]) -> list[dict]:
    """The learning curve of SHARED_MODEL shared by each Table I array's kind and adapted to it
    (estimation/shared_model.py): the other arrays of the kind give the whole-hand training sets
    (`sets`), the array its training sessions cut as for its own curve. A unit per array. Rows as
    report.json `learning_curve.rows`, `way` 'shared'."""
    s = ctx.settings
    hand, _ = worker_hand()
    kind, hyper = model_hyper(SHARED_MODEL, s)
    jobs, keys = [], {}
    for array in ARRAYS:
        paths = [p for plate in PLATES for p in layout[array][plate]]
        others = {a.name: sets[a.name] for a in hand.arrays
                  if a.kind == hand.array(array).kind and a.name != array and a.name in sets}
        keys[array] = digest({'data': [Path(p).stem for p in paths],
                              'others': {n: Path(p).stem for n, p in others.items()},
                              'model': [kind, hyper], 'seconds': list(s.learning_seconds),
                              'static_force': s.static_force,
                              'code': source_digest(job_shared_curve, shared_learning_curve,
                                                    shared_folds)})
        if ctx.cache.load_json('shared_curve', keys[array]) is None:
            jobs.append((array, job_shared_curve, (array, paths, others, SHARED_MODEL, kind, hyper,
                                                   list(s.learning_seconds), s.static_force)))
    ctx.log(f'stage shared models: {len(keys)} arrays, {len(jobs)} to fit')
    for array, rows in run_units(ctx, 'shared models', jobs).items():
        ctx.cache.store_json('shared_curve', keys[array], rows)
    return [row for array in keys for row in ctx.cache.load_json('shared_curve', keys[array])]
