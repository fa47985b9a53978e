"""The main job's campaign with a budget: the full campaign plan (`campaign plan`'s default, two
sessions per plate for every array), its kind curves, a plan of `budget_minutes` of pressing
chosen on them (recording/budget.py), that campaign simulated with sessions of its own as
`campaign run --sim` records them (a session judged poor is pressed again, and its time counts),
and its shared, adapted models judged against the full plan's own models on the same held-out
data.

The kind curves the plan is chosen on come from this run's own full plan of the same simulated
hand; the budget campaign's sessions are new ones (other seeds). A lab would plan on the curves
of a hand it calibrated before; here the two hands are one. With `budget_pool` the mirror hand,
a second simulated hand with its own modules, is pressed on the full plan and its arrays join
each kind's shared model (the curves' and the campaign's), reflected into this hand's layout:
a lab that calibrated its left hand before calibrating the right one.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tacforce_ros.estimation.dataset import CalibrationDataset
from tacforce_ros.estimation.learning_curve import kind_curve, kind_folds
from tacforce_ros.estimation.mirror import mirrored
from tacforce_ros.experiments.cache import digest, source_digest
from tacforce_ros.experiments.calibration_stages import (_training_key, calibration_unit,
                                                         training_sets)
from tacforce_ros.experiments.settings import PLATES, SHARED_MODEL, Context, model_hyper
from tacforce_ros.experiments.workers import (job_cross_validation, job_kind_curve,
                                            job_kind_folds, run_units, worker_hand)
from tacforce_ros.recording.budget import RESERVE, Allocation, ExpectedError, allocate
from tacforce_ros.recording.campaign import CoverageLimits, session_coverage

# Budget sessions take session indices from here up (the full plan's are 0, 1, ...), one more
# for each time a session is pressed again; SIM_ROUNDS as `campaign run --sim`.
BUDGET_SESSION = 100
SIM_ROUNDS = 3
# The must-show: per kind and per array, e_hat of the budget campaign over the full's.
KIND_RATIO, ARRAY_RATIO = 1.15, 1.3


def budget_stage(ctx: Context) -> dict:
    """report.json `budget_campaign`."""
    s = ctx.settings
    hand, _ = worker_hand()
    arrays = [a for a in hand.arrays if a.kind in s.budget_kinds]
    kinds: dict[str, list[str]] = {}
    for array in arrays:
        kinds.setdefault(array.kind, []).append(array.name)
    label = SHARED_MODEL
    model, hyper = model_hyper(label, s)

    # The full plan: its sessions, training sets and each array's own model.
    jobs, full = [], {}
    for array in arrays:
        for plate in PLATES:
            for session in range(s.full_plan_sessions):
                path, job = calibration_unit(ctx, array.name, plate, session, s.session_seconds)
                full.setdefault(array.name, []).append(path)
                jobs += [job] if job is not None else []
    ctx.log(f'stage budget campaign: the full plan, {len(arrays)} arrays x {len(PLATES)} plates '
            f'x {s.full_plan_sessions} sessions, {len(jobs)} to simulate')
    run_units(ctx, 'full-plan sessions', jobs)
    full_sets = training_sets(ctx, 'full-plan training sets', full)
    # The mirror hand's full plan, its arrays pooled into each kind's shared model, whole.
    pool, jobs = {}, []
    for array in arrays if s.budget_pool else ():
        for plate in PLATES:
            for session in range(s.full_plan_sessions):
                path, job = calibration_unit(ctx, array.name, plate, session, s.session_seconds,
                                             side=s.budget_pool)
                pool.setdefault(f'{s.budget_pool}/{array.name}', []).append(path)
                jobs += [job] if job is not None else []
    if pool:
        ctx.log(f'stage budget campaign: the {s.budget_pool} hand\'s full plan, pooled, '
                f'{len(jobs)} sessions to simulate')
        run_units(ctx, f'{s.budget_pool}-hand sessions', jobs)
    pool_sets = training_sets(ctx, f'{s.budget_pool}-hand training sets', pool, mirror=True)
    pool_of = {kind: {n: paths for n, paths in pool.items()
                      if hand.array(n.split('/', 1)[1]).kind == kind} for kind in kinds}
    own = _cached_units(ctx, 'cross_validation', {
        array: (_training_key(paths, label, s), job_cross_validation,
                (array, model, hyper, full_sets[array])) for array, paths in full.items()},
        'full-plan cross-validations')

    # Kind curves on the full plan; the allocation on them.
    curve_units = {}
    for kind, names in kinds.items():
        for seconds in s.budget_seconds:
            paths = {n: full[n] for n in names}
            key = digest({'data': {n: [Path(p).stem for p in ps] for n, ps in paths.items()},
                          'pool': {n: [Path(p).stem for p in ps]
                                   for n, ps in pool_of[kind].items()},
                          'model': [model, hyper], 'seconds': seconds,
                          'static_force': s.static_force,
                          'code': source_digest(job_kind_curve, kind_curve, mirrored)})
            curve_units[f'{kind}/{seconds:g}'] = (key, job_kind_curve, (
                paths, label, model, hyper, seconds, s.static_force, pool_of[kind]))
    curves = _cached_units(ctx, 'kind_curve', curve_units, 'kind curves')
    curve_rows = [row for name in curve_units for row in curves[name]]
    expected = ExpectedError.from_rows(curve_rows, 'kind curves of the full plan of this run')
    allocation = allocate(s.budget_minutes * 60.0, {k: len(v) for k, v in kinds.items()},
                          len(PLATES), expected, s.budget_min_session_s, RESERVE)
    ctx.log('budget campaign: ' + ', '.join(f'{k} {v:g} s per session'
                                            for k, v in allocation.session_s.items()))

    # The budget campaign, pressed until each session's coverage passes (or SIM_ROUNDS).
    chosen: dict[tuple[str, str], str] = {}
    judged: dict[tuple[str, str], bool] = {}
    again: list[dict] = []
    for round_ in range(SIM_ROUNDS):
        due = [(a.name, p) for a in arrays for p in PLATES if not judged.get((a.name, p))]
        if not due:
            break
        units, paths = [], {}
        for name, plate in due:
            seconds = allocation.session_s[hand.array(name).kind]
            paths[name, plate], job = calibration_unit(ctx, name, plate, BUDGET_SESSION + round_,
                                                       seconds)
            units += [job] if job is not None else []
            if round_:
                again.append({'array': name, 'plate': plate, 'seconds': seconds})
        run_units(ctx, 'budget sessions', units)
        for key, path in paths.items():
            chosen[key] = path
            limits = CoverageLimits().for_session(allocation.session_s[hand.array(key[0]).kind])
            judged[key] = session_coverage(CalibrationDataset.load(path), limits).ok
    budget_sets = training_sets(ctx, 'budget training sets', {
        a.name: [chosen[a.name, p] for p in PLATES] for a in arrays})

    # Each kind's budget models, judged on the full plan's data.
    fold_units = {}
    for kind, names in kinds.items():
        pooled = {n: pool_sets[n] for n in pool_of[kind]}
        key = digest({'recorded': {n: Path(budget_sets[n]).stem for n in names},
                      'held_out': {n: Path(full_sets[n]).stem for n in names},
                      'pool': {n: Path(p).stem for n, p in pooled.items()},
                      'model': [model, hyper], 'code': source_digest(job_kind_folds, kind_folds)})
        fold_units[kind] = (key, job_kind_folds, ({n: budget_sets[n] for n in names},
                                                 {n: full_sets[n] for n in names}, model, hyper,
                                                 pooled))
    folds = _cached_units(ctx, 'budget_folds', fold_units, 'budget models')
    rows = [{'array': n, 'kind': k, 'seconds': allocation.session_s[k] * len(PLATES),
             'e_hat_n': folds[k][n]['e_hat_mean'], 'full_e_hat_n': own[n]['e_hat_mean'],
             'full_seconds': s.full_plan_sessions * s.session_seconds * len(PLATES)}
            for k, names in kinds.items() for n in names]
    summary = budget_summary(s.budget_minutes, allocation, again,
                             sum(not ok for ok in judged.values()), rows, curve_rows)
    summary['pool'] = {'hand': s.budget_pool or None, 'arrays': len(pool),
                       'seconds_per_array': (s.full_plan_sessions * s.session_seconds
                                             * len(PLATES)) if pool else 0.0}
    return summary


def _cached_units(ctx: Context, stage: str, units: dict[str, tuple], title: str) -> dict:
    """{name: result} of units {name: (cache key, job, args)}, running those not cached."""
    jobs = [(name, job, args) for name, (key, job, args) in units.items()
            if ctx.cache.load_json(stage, key) is None]
    for name, value in run_units(ctx, title, jobs).items():
        ctx.cache.store_json(stage, units[name][0], value)
    return {name: ctx.cache.load_json(stage, key) for name, (key, _, _) in units.items()}


def budget_summary(budget_minutes: float, allocation: Allocation, again: list[dict], poor: int,
                   rows: list[dict], curve_rows: list[dict]) -> dict:
    """report.json `budget_campaign`: minutes pressed (every session recorded: the plan's and
    those pressed again, `again`), the allocation, per array its e_hat against the full plan's
    own model's, per kind the ratio of the means, and the issue's verdicts."""
    for row in rows:
        row['ratio'] = row['e_hat_n'] / row['full_e_hat_n']
    by_kind = {}
    for kind in dict.fromkeys(r['kind'] for r in rows):
        mine = [r for r in rows if r['kind'] == kind]
        budget = float(np.mean([r['e_hat_n'] for r in mine]))
        full = float(np.mean([r['full_e_hat_n'] for r in mine]))
        by_kind[kind] = {'arrays': len(mine), 'session_s': allocation.session_s[kind],
                         'expected_e_hat_n': allocation.expected_e_hat[kind],
                         'e_hat_n': budget, 'full_e_hat_n': full, 'ratio': budget / full}
    worst = max(rows, key=lambda r: r['ratio'])
    minutes = (allocation.pressing_s + sum(a['seconds'] for a in again)) / 60.0
    return {
        'budget_minutes': budget_minutes, 'plates': allocation.plates,
        'planned_minutes': allocation.pressing_s / 60.0, 'minutes': minutes,
        'sessions': len(rows) * allocation.plates + len(again),
        'sessions_pressed_again': len(again), 'pressed_again': again,
        'poor_sessions_kept': poor, 'rows': rows, 'by_kind': by_kind,
        'e_hat_ratio_by_kind': {k: v['ratio'] for k, v in by_kind.items()},
        'worst_array_ratio': worst['ratio'], 'worst_array': worst['array'],
        'kind_curve_rows': curve_rows,
        'must_show': {'minutes': minutes <= budget_minutes + 1e-9,
                      'kinds': all(v['ratio'] <= KIND_RATIO for v in by_kind.values()),
                      'arrays': worst['ratio'] <= ARRAY_RATIO}}
