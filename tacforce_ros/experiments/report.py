"""The report: one JSON document of every number the run produced, and Markdown with the paper's
Table I, II and III layouts, our simulated numbers side by side with the paper's.

Every number in the Markdown is formatted from the JSON by `cell()`; the paper's column comes
from paper_reference.py only.
"""
from __future__ import annotations

import math
import statistics
from typing import Any

from tacforce_ros.bringup.processes import unclean_exits
from tacforce_ros.experiments import paper_reference as paper
from tacforce_ros.experiments.settings import EXTENDED_STAGES, GRASP_ARRAYS
from tacforce_ros.experiments.skin_targets import (LOOP_REDUCTION, LOOP_TRACK, loop_reason,
                                                  targets)
from tacforce_ros.hand.description import ARRAY_KIND_TITLES

MODEL_NAMES = {'M3-lambda': 'M3λ', 'M3-lambda-cv': 'M3λ (nested-CV λ)', 'open_loop': 'O.L.'}
ARRAY_TITLES = {'index_tip': 'Curved array (index_tip)',
                'index_middle': 'Flat array (index_middle)'}
OBJECT_NUMBERS = {'spherical': 1, 'foam_brick': 2, 'softball': 3, 'abrasive_sponge': 4,
                  'bleach_cleanser': 5}
SKIN_TITLES = {'empirical': 'empirical (sim/taxel_response.py: foundation-spring pressure '
                            'weights, tanh response)',
               'magnetic': 'magnetic, computed from the taxel\'s physics (docs/SKIN_PHYSICS.md; '
                           'the scene files in scenes/)'}
# The loop's must-show, the same as the magnetic skin's loop targets (experiments/skin_targets.py):
# e~ with M3-lambda >= 70 % below open loop, e_track below 0.1 N.
REDUCTION_TARGET_PERCENT = 100.0 * LOOP_REDUCTION
E_TRACK_TARGET_N = LOOP_TRACK


def cell(mean: float | None, std: float | None = None, digits: int = 2) -> str:
    """'m ± s' (or 'm', or '–' when there is no value)."""
    if mean is None:
        return '–'
    return f'{mean:.{digits}f}' if std is None else f'{mean:.{digits}f} ± {std:.{digits}f}'


def _percent(value: float | None) -> float | None:
    return None if value is None else 100.0 * value


def _pair(reference: dict, key: str) -> tuple[float | None, float | None]:
    return reference.get(key, (None, None))


def table_i(cv: dict, timing: dict) -> dict:
    rows: dict[str, dict[str, Any]] = {}
    for array, by_model in cv.items():
        rows[array] = {}
        for label, summary in by_model.items():
            t = timing[array][label]
            rows[array][label] = {
                'sim': {'e_r_percent': _percent(summary['e_r_mean']),
                        'e_r_std_percent': _percent(summary['e_r_std']),
                        'e_hat': summary['e_hat_mean'], 'e_hat_std': summary['e_hat_std'],
                        'mae_axis': summary['mae_axis'], 'n_parameters': summary['n_parameters'],
                        'train_seconds_per_fold': summary['train_seconds'],
                        'tau_single_ms': t['predict_one']['median_us'] / 1e3,
                        'tau_full_hand_ms': t['full_hand_tick']['median_us'] / 1e3,
                        'timing_us': t,
                        'per_plate': [{k: f[k] for k in ('test_plate', 'e_r_mean', 'e_r_std',
                                                         'e_hat_mean', 'e_hat_std', 'samples')}
                                      for f in summary['per_fold']]},
                'paper': paper.TABLE_I[array].get(label)}
    return rows


def table_ii(online: dict) -> dict:
    return {label: {'sim': {'e_r_percent': _percent(online[label]['e_r_mean']),
                            'e_r_std_percent': _percent(online[label]['e_r_std']),
                            'e_hat': online[label]['e_hat_mean'],
                            'e_hat_std': online[label]['e_hat_std'],
                            'samples': online[label]['samples'],
                            'in_distribution_e_hat': online[label]['in_distribution']['e_hat_mean'],
                            'in_distribution_e_hat_std':
                                online[label]['in_distribution']['e_hat_std']},
                    'paper': paper.TABLE_II[label]}
            for label in paper.TABLE_II if label in online}


def table_iii(closed: dict[tuple[str, str], dict]) -> list[dict]:
    rows = []
    for (obj, controller), m in closed.items():
        rows.append({'object': obj, 'controller': controller,
                     'row': f'({OBJECT_NUMBERS[obj]})-{MODEL_NAMES.get(controller, controller)}',
                     'sim': {'e_r_percent': _percent(m['e_r_mean']),
                             'e_r_std_percent': _percent(m['e_r_std']),
                             'e_hat': m['e_hat_mean'], 'e_hat_std': m['e_hat_std'],
                             'e_track': m['e_track_mean'], 'e_track_std': m['e_track_std'],
                             'e_tilde': m['e_tilde_mean'], 'e_tilde_std': m['e_tilde_std'],
                             'e_tilde_per_run': m['e_tilde_per_run'], 'runs': m['runs'],
                             'estimate_gain': m.get('estimate_gain'),
                             'first_touch_peak_n': m.get('first_touch_peak_n'),
                             'first_touch_ratio': m.get('first_touch_ratio')},
                     'paper': paper.TABLE_III.get((obj, controller))})
    return rows


def must_show(rows: list[dict]) -> dict:
    by = {(r['object'], r['controller']): r['sim'] for r in rows}
    open_loop, closed = by.get(('spherical', 'open_loop')), by.get(('spherical', 'M3-lambda'))
    if open_loop is None or closed is None:
        return {'evaluated': False}
    reduction = 100.0 * (1.0 - closed['e_tilde'] / open_loop['e_tilde'])
    return {'evaluated': True, 'e_tilde_open_loop': open_loop['e_tilde'],
            'e_tilde_m3_lambda': closed['e_tilde'], 'e_tilde_reduction_percent': reduction,
            'reduction_target_percent': REDUCTION_TARGET_PERCENT,
            'paper_reduction_percent': paper.E_TILDE_REDUCTION_PERCENT,
            'reduction_met': reduction >= REDUCTION_TARGET_PERCENT,
            'e_track_m3_lambda': closed['e_track'], 'e_track_target_n': E_TRACK_TARGET_N,
            'e_track_met': closed['e_track'] is not None and closed['e_track'] < E_TRACK_TARGET_N}


def skin_targets(table_i: dict, rows: list[dict], seed: int) -> list[dict]:
    """The magnetic skin's targets (experiments/skin_targets.py) on this run's Table I and
    spherical-plate closed loop: [{'target', 'values': [value], 'met': 0 or 1}]."""
    by = {(r['object'], r['controller']): r['sim'] for r in rows}
    open_loop = by.get(('spherical', 'open_loop'))
    loop = {} if open_loop is None else {'open_loop': open_loop['e_tilde']}
    for (obj, controller), sim in by.items():
        if obj == 'spherical' and controller != 'open_loop' and open_loop is not None:
            loop[controller] = {'reduction': 1.0 - sim['e_tilde'] / open_loop['e_tilde'],
                                'e_track': sim['e_track']}
    models = sorted({label for by_model in table_i.values() for label in by_model})
    checks = targets({'arrays': list(table_i), 'models': models, 'variants': [{
        'name': 'values', 'seed': seed, 'closed_loop': loop,
        'e_hat': {array: {label: row['sim']['e_hat'] for label, row in by_model.items()}
                  for array, by_model in table_i.items()}}]})
    for check in checks:
        network = check.get('below_linear')
        if network is not None and not check['met']:
            check['why_missed'] = plates_against_linear(table_i[network['array']],
                                                        network['model'])
        if check.get('loop') and not check['met'] and 'why_missed' in check:
            gain = (by.get(('spherical', check['loop'])) or {}).get('estimate_gain')
            check['why_missed'] = loop_reason(gain[2] if gain and gain[2] else None)
    return checks


def plates_against_linear(by_model: dict, model: str) -> str:
    """Why a network misses its margin below M3-lambda on this run, plate by plate: on which
    held-out plates it does not beat M3-lambda, and by how much it does on the others."""
    mine = {row['test_plate']: row['e_hat_mean'] for row in by_model[model]['sim']['per_plate']}
    ratio = {row['test_plate']: mine[row['test_plate']] / row['e_hat_mean']
             for row in by_model['M3-lambda']['sim']['per_plate']}
    behind = [plate for plate, r in ratio.items() if r > 1.0]
    ahead = [r for r in ratio.values() if r <= 1.0]
    parts = [f'held out, {model} errs {ratio[p]:.2f} times as much as M3-lambda on the {p} plate'
             for p in behind]
    if ahead:
        parts.append(f'{min(ahead):.2f}-{max(ahead):.2f} times as much on the other '
                     f'{len(ahead)} plate(s)')
    worst = max(mine, key=mine.get)
    why = ', '.join(parts) + ' (per_plate_errors.png)'
    if worst in behind:
        why += (f'; the {worst} plate is also where it errs most ({mine[worst]:.2f} N), so it '
                'weighs most in the mean')
    return why


def skin_targets_section(checks: list[dict] | None) -> list[str]:
    if checks is None:
        return []
    return (["## The magnetic skin's targets on this run", '',
             'The paper\'s findings as a skin computed from the taxel\'s physics must show them '
             '(docs/SKIN_PHYSICS.md; `skin_sensitivity` judges them over several seeds).', '',
             '| target | sim | met |', '|---|---|---|']
            + [f"| {c['target']} | {cell(c['values'][0], digits=2)} | "
               f"**{'met' if c['met'] else 'NOT met'}** |" for c in checks] + ['']
            + [f"* Not met, {c['target']}: {c['why_missed']}." for c in checks
               if not c['met'] and c.get('why_missed')]
            + ([''] if any(not c['met'] and c.get('why_missed') for c in checks) else []))


def best_cutoffs(end_to_end: dict) -> dict[str, float | None]:
    """Per model, the low-pass setting with the lowest e_hat on the held-out session."""
    best: dict[str, dict] = {}
    for row in end_to_end['rows']:
        if row['model'] not in best or row['e_hat_mean'] < best[row['model']]['e_hat_mean']:
            best[row['model']] = row
    return {model: row['cutoff_hz'] for model, row in best.items()}


def filter_closed_loop(filtered: dict, without: dict, with_filter: dict) -> dict:
    """The input low-pass's closed-loop effect: `without` and `with_filter` are trace_metrics
    of the same seeds; e~ per run differences are paired by seed. The effect is called clear when
    the mean difference exceeds twice its standard error (about 95 %, normal approximation)."""
    diffs = [w - o for w, o in zip(with_filter['e_tilde_per_run'], without['e_tilde_per_run'])]
    n = len(diffs)
    mean = statistics.fmean(diffs)
    sd = statistics.stdev(diffs) if n > 1 else None
    margin = None if sd is None else 2.0 * sd / math.sqrt(n)
    if margin is None:
        verdict = f'undetermined ({n} run each)'
    elif abs(mean) <= margin:
        verdict = 'no clear effect'
    else:
        verdict = 'the filter lowers e~' if mean < 0 else 'the filter raises e~'
    return {**{k: v for k, v in filtered.items() if k != 'traces'}, 'runs': n,
            'without': without, 'with': with_filter, 'e_tilde_difference_mean': mean,
            'e_tilde_difference_std': sd, 'e_tilde_difference_margin': margin,
            'verdict': verdict}


# ---------------------------------------------------------------------------------- markdown

def filter_closed_loop_section(effect: dict | None) -> list[str]:
    lines = ["## Closed loop with the estimator's input low-pass (spherical plate, M3λ)", '']
    if effect is None:
        return lines + ['* not evaluated: this run has no M3λ runs on the spherical plate', '']
    chosen = (f"{effect['cutoff_hz']:g} Hz" + (
        ', the lowest e_hat of M3λ on the held-out session' if effect['best_offline']
        else '; no filter gave M3λ its lowest e_hat offline, so the best of the cut-offs'))
    lines += [f"Same seeds as Table III's (1)-M3λ, {effect['runs']} run(s) each; input low-pass "
              f"at {chosen}, group delay {cell(effect['group_delay_ms'], digits=1)} ms.", '',
              '| estimator input | e~ [N] | e_track [N] | e_hat [N] |', '|---|---|---|---|']
    for name, m in (('no filter', effect['without']),
                    (f"{effect['cutoff_hz']:g} Hz low-pass", effect['with'])):
        lines.append(f"| {name} | {cell(m['e_tilde_mean'], m['e_tilde_std'], 3)} | "
                     f"{cell(m['e_track_mean'], m['e_track_std'], 3)} | "
                     f"{cell(m['e_hat_mean'], m['e_hat_std'], 3)} |")
    margin = effect['e_tilde_difference_margin']
    lines += ['', f"e~ with the filter minus without, paired by seed: "
              f"{cell(effect['e_tilde_difference_mean'], digits=4)} N"
              + ('' if margin is None else f" (± {cell(margin, digits=4)} N, twice its standard "
                                          'error)')
              + f": **{effect['verdict']}**.", '']
    return lines


def end_to_end_section(e2e: dict) -> list[str]:
    latency = e2e['node_latency']
    if latency.get('measured'):
        node = (f"the estimator node's median frame -> 18 wrenches latency over DDS, "
                f"{cell(latency['median_ms'], digits=2)} ms (p99 "
                f"{cell(latency['p99_ms'], digits=2)} ms, {latency['complete']}/"
                f"{latency['frames']} frames complete; `{latency['command']}`, load average "
                f"{latency['load_average']['before'][0]:.1f})")
    else:
        node = (f"the estimator node's latency, **not measured in this run** "
                f"({latency['reason']}) and so left out of the sum")
    lines = [f"## What accuracy costs in time, end to end ({e2e['array']}, held-out "
             f"{e2e['plate']} plate)", '',
             'Every model on the held-out session as the estimator receives it (the same '
             'session simulated again without the training data\'s zero-phase filter on the '
             'tactile frames), with the estimator\'s causal input low-pass (Butterworth, order '
             f"{e2e['filter_order']}, parameter `lowpass_hz`) off and at a few cut-offs. Time "
             'per tick: compute (one full-hand tick of the runtime estimator, 18 arrays of the '
             'kind, with the filter when on), the filter\'s group delay at 0 Hz, and ' + node
             + '; end to end is their sum.', '',
             '| Model | low-pass | e_hat [N] | e_r [%] | compute [ms] | group delay [ms] '
             '| node latency [ms] | end to end [ms] |', '|---|---|---|---|---|---|---|---|']
    for row in e2e['rows']:
        lines.append('| ' + ' | '.join([
            MODEL_NAMES.get(row['model'], row['model']),
            'off' if row['cutoff_hz'] is None else f"{row['cutoff_hz']:g} Hz",
            cell(row['e_hat_mean'], row['e_hat_std'], 3),
            cell(_percent(row['e_r_mean']), _percent(row['e_r_std']), 1),
            cell(row['compute_ms'], digits=3), cell(row['group_delay_ms'], digits=1),
            cell(row['node_latency_ms'], digits=2), cell(row['end_to_end_ms'], digits=2)]) + ' |')
    best = best_cutoffs(e2e)
    lines += ['', 'Lowest e_hat per model at: ' + ', '.join(
        f"{MODEL_NAMES.get(m, m)} {'no filter' if c is None else f'{c:g} Hz'}"
        for m, c in best.items()) + '.', '']
    return lines


def _sim_paper(sim_mean, sim_std, ref: tuple | None, digits: int) -> list[str]:
    ref = ref or (None, None)
    return [cell(sim_mean, sim_std, digits), cell(ref[0], ref[1], digits)]


def learning_curve_section(curve: dict | None) -> list[str]:
    """Held-out e_hat against labelled seconds (not in the paper): what calibration costs."""
    if not curve:
        return []
    from tacforce_ros.estimation.learning_curve import curve_table
    return ['## Learning curves — held-out e_hat against labelled seconds (not in the paper)', '',
            "Leave-one-plate-out e_hat [N] of each model trained on the first seconds of the "
            "array's training sessions, spread evenly over the five plates (each plate's sessions "
            "in the order recorded), each fold tested on all of its held-out plate's data; the "
            "last point is the paper's campaign, Table I's figure. In brackets: the seconds "
            "recorded where less than asked. `learning_curve` draws the same from any bags or "
            "campaign. Figure: `learning_curve.png`.", '', *curve_table(curve['rows']), '',
            *shared_verdict(curve['rows'])]


def shared_verdict(rows: list[dict], short_s: float = 400.0) -> list[str]:
    """Where the model the kind's other arrays share (`way` shared: fitted on their whole-hand
    training sets, adapted to the array's cut; estimation/shared_model.py) stands against the
    array's own model of the same kind: below it at every point up to `short_s`, and not above
    it at the last point."""
    shared = [r for r in rows if r.get('way') == 'shared' and r['e_hat_n'] is not None]
    if not shared:
        return []
    lines = ["Way *shared*: the model fitted on the other arrays of the kind (their whole-hand "
             "training sets, without the held-out plate) and adapted to the array's cut by "
             "damped least squares centred on it, its weight chosen by leave-one-array-out "
             "(`estimation/shared_model.py`).", '']
    for array, model in dict.fromkeys((r['array'], r['model']) for r in shared):
        own = {r['seconds']: r['e_hat_n'] for r in rows if (r['array'], r['model'],
               r.get('way', 'own')) == (array, model, 'own') and r['e_hat_n'] is not None}
        mine = {r['seconds']: r['e_hat_n'] for r in shared
                if (r['array'], r['model']) == (array, model) and r['seconds'] in own}
        if not mine:
            continue
        best = {t: min(r['e_hat_n'] for r in rows if (r['array'], r.get('way', 'own'),
                                                       r['seconds']) == (array, 'own', t)
                       and r['e_hat_n'] is not None) for t in mine}
        short = [t for t in sorted(mine) if t <= short_s]
        last = max(mine)
        for against, name in ((own, f'own {model}'), (best, 'the best own model')):
            wins = [t for t in short if mine[t] < against[t]]
            lines.append(
                f"* {array}, {model}: shared below {name} at {len(wins)} of {len(short)} "
                f"points up to {short_s:g} s"
                + ('' if len(wins) == len(short) else ' (NOT at '
                   + ', '.join(f'{t:g} s' for t in short if t not in wins) + ')')
                + f"; at {last:g} s {mine[last]:.3f} N against {against[last]:.3f} N "
                + ('(not worse)' if mine[last] <= against[last] else '(WORSE)') + '.')
    return lines + ['']


def shipped_models_section(rows: list[dict] | None) -> list[str]:
    """The models the job ships (its model lists under models/), and which way each was made."""
    if not rows:
        return []
    lines = ['## Shipped models — which way each was made', '',
             "The model lists this job writes (the closed loops' and the grasp's), each model's "
             "way from its provenance: own (fitted on its array's data alone), shared or adapted "
             "(the model the other arrays of its kind share, `train --shared`), and the seconds of "
             "its own array's data it was fitted on.", '',
             '| list | array | model | way | own data [s] |', '|---|---|---|---|---|']
    for r in rows:
        way = r['way'] or 'not recorded'
        if r.get('shared_from'):
            way += f" (from {', '.join(r['shared_from'])})"
        seconds = '-' if r['own_seconds'] is None else f"{r['own_seconds']:g}"
        lines.append(f"| {r['set']} | {r['array']} | {r['kind']} | {way} | {seconds} |")
    return lines + ['']


def whole_hand_section(rows: dict | None, settings: dict) -> list[str]:
    if not rows:
        return []
    lines = ['## Whole hand — M3λ on every array, 5-fold leave-one-plate-out', '',
             f"Every array pressed on the five training plates: the Table I arrays and the "
             f"grasp's ({', '.join(GRASP_ARRAYS)}) at the sizes above, the others "
             f"{settings['whole_hand_seconds']:g} s per plate (one session). "
             'Figure: whole_hand.png.', '',
             '| array | data | e_r [%] sim | e_hat [N] sim | MAE x / y / z [N] |',
             '|---|---|---|---|---|']
    for group, title in ARRAY_KIND_TITLES.items():
        members = {a: r for a, r in rows.items() if r['type'] == group}
        if not members:
            continue
        e_hat = [r['cv']['e_hat_mean'] for r in members.values()]
        lines.append(f'| **{title}** ({len(members)}; mean e_hat '
                     f'{statistics.mean(e_hat):.3f}) | | | | |')
        for array, r in members.items():
            cv = r['cv']
            lines.append(f"| {array} | {r['sessions']} x {r['seconds']:g} s per plate | "
                         f"{cell(_percent(cv['e_r_mean']), _percent(cv['e_r_std']), 1)} | "
                         f"{cell(cv['e_hat_mean'], cv['e_hat_std'], 3)} | "
                         + ' / '.join(f'{v:.3f}' for v in cv['mae_axis']) + ' |')
    return lines + ['']


def cross_array_section(cross: dict | None) -> list[str]:
    """Each array's model on the other arrays of its kind, unadapted (not in the paper): how
    far the arrays of one hand differ, which a model shared across them must bridge."""
    if not cross:
        return []
    model = MODEL_NAMES.get(cross['model'], cross['model'])
    lines = [f'## Across arrays — {model} applied unadapted to another array of its kind '
             '(not in the paper)', '',
             f"Each array's {model} (trained on its whole-hand data above) tested, held-out plate "
             "by held-out plate, on every other array of its kind (the same taxel layout, each "
             "array's own offsets removed), against the array's own held-out e_hat. Ratio: the "
             "other arrays' mean over the array's own; above 1, the arrays differ by that margin "
             "and a model must be adapted to carry over. The Table I and grasp arrays' models "
             "saw four times the data of the others'.", '',
             '| array | own e_hat [N] | unadapted e_hat [N]: mean (least - most) | ratio |',
             '|---|---|---|---|']
    for group, title in ARRAY_KIND_TITLES.items():
        summary = cross['by_kind'].get(group)
        if summary is None:
            continue
        lines.append(f"| **{title}** ({summary['arrays']}) | {summary['own_e_hat_n']:.3f} | "
                     f"{summary['unadapted_e_hat_n']:.3f} | **{summary['ratio']:.2f}** |")
        for row in cross['rows']:
            if row['kind'] == group:
                lines.append(f"| {row['array']} | {row['own_e_hat_n']:.3f} | "
                             f"{row['unadapted_e_hat_n']:.3f} ({row['unadapted_min_n']:.3f} - "
                             f"{row['unadapted_max_n']:.3f}) | {row['ratio']:.2f} |")
    alike = [ARRAY_KIND_TITLES.get(k, k) for k, v in cross['by_kind'].items() if v['ratio'] <= 1.0]
    if alike:
        lines += ['', f"On the {', '.join(alike)} another array's model errs no more than the "
                  "array's own: those arrays do not differ beyond their own error, and a model "
                  "carried over to them shows no transfer."]
    return lines + ['']


def _pool_sentence(pool: dict | None) -> str:
    if not pool or not pool.get('hand'):
        return ' No other hand was pooled.'
    return (f" The {pool['hand']} hand, a second simulated hand with modules of its own, was "
            f"pressed on the full plan before ({pool['seconds_per_array']:.0f} s per array); its "
            f"{pool['arrays']} arrays, reflected into this hand's layout, join every shared model "
            "of their kind, in the kind curves and in the campaign (`train --shared --pool`).")


def budget_section(budget: dict | None) -> list[str]:
    """The campaign with a budget against the full plan (not in the paper)."""
    if not budget:
        return []
    lines = [f"## A campaign with a budget — {budget['budget_minutes']:g} min of pressing "
             "against the full plan (not in the paper)", '',
             "`campaign plan --budget` chose one session per array and plate, its length per "
             "kind of array, on the kind curves of this run's full plan (every array of a kind "
             "cut alike; the curve rows are in report.json). The campaign was simulated with "
             "sessions of its own; a session whose coverage was poor was pressed again, and its "
             "time counts. Each array's model is the M3-lambda its kind's other arrays share, "
             "adapted to it (`train --shared`), tested held-out plate by held-out plate on the "
             "full plan's data, against the array's own M3-lambda trained on the full plan "
             f"(`campaign plan`'s default; {budget['rows'][0]['full_seconds']:.0f} s per array)."
             + _pool_sentence(budget.get('pool')),
             '', f"Pressed: **{budget['minutes']:.1f} min** in {budget['sessions']} sessions "
             f"({budget['sessions_pressed_again']} pressed again, "
             f"{budget['poor_sessions_kept']} still poor and kept); planned "
             f"{budget['planned_minutes']:.1f} min.", '',
             '| array | session [s] | per array [s] | expected e_hat [N] | e_hat [N] | '
             'full plan e_hat [N] | ratio |', '|---|---|---|---|---|---|---|']
    for kind, summary in budget['by_kind'].items():
        lines.append(f"| **{ARRAY_KIND_TITLES.get(kind, kind)}** ({summary['arrays']}) | "
                     f"{summary['session_s']:g} | {summary['session_s'] * budget['plates']:g} | "
                     f"{summary['expected_e_hat_n']:.3f} | {summary['e_hat_n']:.3f} | "
                     f"{summary['full_e_hat_n']:.3f} | **{summary['ratio']:.2f}** |")
        for row in budget['rows']:
            if row['kind'] == kind:
                lines.append(f"| {row['array']} | | {row['seconds']:g} | | "
                             f"{row['e_hat_n']:.3f} | {row['full_e_hat_n']:.3f} | "
                             f"{row['ratio']:.2f} |")
    verdict = budget['must_show']
    lines += ['', f"Must-show: at most {budget['budget_minutes']:g} min pressed: "
              f"{'met' if verdict['minutes'] else 'NOT met'}; each kind's mean e_hat at most "
              f"1.15x the full plan's: {'met' if verdict['kinds'] else 'NOT met'}; every "
              f"array's at most 1.3x: {'met' if verdict['arrays'] else 'NOT met'} (worst "
              f"{budget['worst_array']}, {budget['worst_array_ratio']:.2f}x).", '']
    return lines


def node_path_section(node: dict, tolerance_reason: str) -> list[str]:
    """The node graph's runs against the direct path: both checks, and how every node of
    their sessions ended."""
    lines = ['## Node graph against direct path', '']
    if not node.get('ran'):
        lines += [f"**The node path did not run**: {node.get('reason', 'unknown')}. Every "
                  f"result above comes from the direct (in-process) path.", '']
    else:
        cal, loop = node['calibration'], node['closed_loop']
        lines += ['| check | node graph | direct | difference | tolerance | agree |',
                  '|---|---|---|---|---|---|',
                  f"| calibration session: M3λ e_hat [N] | "
                  f"{cell(cal['node']['e_hat_mean'], digits=3)}"
                  f" | {cell(cal['direct']['e_hat_mean'], digits=3)} | "
                  f"{cell(cal['difference_n'], digits=3)} | {cell(cal['tolerance_n'], digits=3)} | "
                  f"{'yes' if cal['agree'] else 'NO'} |",
                  f"| closed loop (1)-M3λ, one run: e~ [N] | "
                  f"{cell(loop['node']['e_tilde_mean'], digits=3)} | "
                  f"{cell(loop['direct']['e_tilde_mean'], digits=3)} | "
                  f"{cell(loop['difference_n'], digits=3)} | {cell(loop['tolerance_n'], digits=3)}"
                  f" | {'yes' if loop['difference_n'] <= loop['tolerance_n'] else 'NO'} |"]
        grasp = node.get('grasp')
        if grasp is not None and grasp.get('ran', True) is False:
            lines += [f"| grasp through the node graph | did not run: {grasp['reason']} | | | | "
                      "NO |"]
        elif grasp is not None:
            n, d = grasp['node'], grasp['direct']
            lines += [f"| grasp, {grasp['object']} at {grasp['grip_n']:g} N, one run: per-finger "
                      f"e~ [N] (drops node / direct: {int(n['dropped'])} / {int(d['dropped'])}"
                      f"; first touch {cell(max(n['peak_over_command'].values()))} / "
                      f"{cell(max(d['peak_over_command'].values()))}; slip "
                      f"{cell(n['slip_mm'], digits=1)} / {cell(d['slip_mm'], digits=1)} mm) | "
                      f"{cell(n['finger_error_mean_n'], digits=3)} | "
                      f"{cell(d['finger_error_mean_n'], digits=3)} | "
                      f"{cell(grasp['difference_n'], digits=3)} | "
                      f"{cell(grasp['tolerance_n'], digits=3)} | "
                      f"{'yes' if grasp['agree'] else 'NO'} |"]
        if 'e_track_difference_n' in loop:
            track, track_tolerance = loop['e_track_difference_n'], loop['e_track_tolerance_n']
            lines += [f"| closed loop (1)-M3λ, one run: e_track [N] | "
                      f"{cell(loop['node']['e_track_mean'], digits=3)} | "
                      f"{cell(loop['direct']['e_track_mean'], digits=3)} | "
                      f"{cell(track, digits=3)} | {cell(track_tolerance, digits=3)} | "
                      f"{'yes' if track <= track_tolerance else 'NO'} |"]
        lines += ['', f"Tolerance: {tolerance_reason}", '']
        parts = [(part, name) for part, name in (('calibration', 'calibration'),
                                                  ('closed_loop', 'closed-loop'),
                                                  ('grasp', 'grasp'))
                 if 'exit_codes' in node.get(part, {}) or part != 'grasp']
        if all('exit_codes' in node[part] for part, _ in parts):
            unclean = [(name, unclean_exits(node[part]['exit_codes'])) for part, name in parts]
            lines += ['Every node of every session ended cleanly when its session stopped it: '
                      + ('yes' if not any(codes for _, codes in unclean) else 'NO: ' + '; '.join(
                          f'{part} session ' + ', '.join(f'{name} exit code {code}'
                                                         for name, code in codes.items())
                          for part, codes in unclean if codes)
                         + f" (negative: killed by that signal; logs in {node.get('work_dir')})"),
                      '']
        for key, name in (('closed_loop_bag', 'closed-loop'), ('grasp_bag', 'grasp')):
            bag = node.get(key)
            if bag is not None:
                lines += [f"The {name} run's bag: {bag['files']} MCAP file(s), "
                          f"{bag['messages']} messages; messages per topic by its metadata.yaml,"
                          " rosbags and Foxglove's mcap reader agree: "
                          f"{'yes' if bag['agree'] else 'NO: ' + str(bag['counts'])}", '']
    return lines


def grasp_section(grasp: dict | None) -> list[str]:
    """The grasp table (not in the paper): the thumb and index fingertip holding objects."""
    if not grasp:
        return []
    lines = ['## Grasp — the thumb and index fingertip holding an object (not in the paper)', '',
             f"Each object handed over by a fixture that lets go {grasp['hand_over_s']:g} s "
             "after the goal; the fingers close by their guarded approach, ramp to the grip from "
             "the touch and integrate the internal force's error (control/grasp.py). Per-finger "
             "e~: mean |f_d - f| per fingertip against its simulated contact force, from 1 s "
             "after the hand-over to the end; the open loop is the same poses and gains without "
             "the tactile integral; single finger: Table III's M3λ e~ on the spherical plate. "
             "First touch: the worst fingertip's peak contact force before the hand-over over "
             "its command. Slip: mm the object moved from the hand-over to the end. Estimate "
             "gain: the estimate along d_i over the contact force along it, per finger, while "
             "the fixture held the object / in the judged hold, the fingers alone carrying it "
             "(1: the model reads this contact as it is). The closed loop regulates the mean "
             "of the two estimates along d_i, so where the mean holding gain is off 1 the grip "
             "is about as far off. One "
             "grasp through the node graph (grasp_controller's Grasp action): \"Node graph "
             "against direct path\" below.", '',
             '| object | grip [N] | runs | drops | e~ per finger [N] | open loop [N] '
             '| reduction | single finger [N] | grip error [N] | first touch / command '
             '| slip [mm] mean / max | open-loop slip [mm] | grip raised to [N] '
             '| estimate gain, fixture / holding |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for row in grasp['rows']:
        holding = row.get('estimate_gain_holding') or {}    # reports before it lack it
        gain = ', '.join(f'{f} {cell(g)}' + (f' / {cell(holding[f])}' if f in holding else '')
                         for f, g in row['estimate_gain'].items())
        lines.append('| ' + ' | '.join([
            row['object'], f"{row['grip_n']:g}", str(row['runs']),
            f"{row['drops']} (open loop {row['open_loop_drops']})", cell(row['finger_error_n']),
            cell(row['open_loop_finger_error_n']),
            cell(None if row['reduction'] is None else 100 * row['reduction'], digits=0) + ' %',
            cell(row['single_finger_error_n']), cell(row['grip_error_n']),
            cell(row['peak_over_command']),
            f"{cell(row['slip_mm'], digits=1)} / {cell(row['slip_mm_max'], digits=1)}",
            cell(row['open_loop_slip_mm'], digits=1), cell(row['grip_raised_to_n']), gain])
            + ' |')
    check = grasp['must_show']
    lines += ['', 'Against the issue\'s targets: no drops '
              f"**{'met' if check['no_drops'] else 'NOT met'}**; per-finger e~ at most 1.2x the "
              f"single finger's **{'met' if check['within_1_2x_single_finger'] else 'NOT met'}"
              f"**; at least 60 % below the open loop "
              f"**{'met' if check['at_least_60pct_below_open_loop'] else 'NOT met'}**; first "
              f"touch at most 1.25x its command "
              f"**{'met' if check['first_touch_within_1_25x'] else 'NOT met'}**.", '']
    return lines


def markdown(doc: dict) -> str:
    s, run = doc['settings'], doc['run']
    lines = [f"# Reproduction of the paper's experiments — SIMULATION, {s['skin']} skin", '',
             f"**All numbers in the \"sim\" columns come from the simulated hand "
             f"(tacforce_ros.sim), not from hardware.** The \"paper\" columns are the published "
             f"values (tacforce_ros/experiments/paper_reference.py). Generated {run['date']}, "
             f"code {run['code_version']}, wall time {run['wall_seconds']:.0f} s on "
             f"{run['machine']['cpus']} CPUs with {run['machine']['jobs']} workers (load average "
             f"{run['machine']['load_before'][0]:.1f} before, "
             f"{run['machine']['load_after'][0]:.1f} after; a bare MuJoCo step of the hand "
             f"model took {run['machine']['mujoco_step_us'][0]:.1f} us at the start, "
             f"{run['machine']['mujoco_step_us'][1]:.1f} us at the end: the machine's speed, "
             f"against which to read the wall time).", '',
             '## Sizes of this run', '',
             f"* calibration: {s['sessions_per_plate']} session(s) x {s['session_seconds']:g} s "
             f"per plate and array (paper: 4 x 100 s), plates {', '.join(doc['plates'])}; "
             f"online test {s['online_seconds']:g} s on the held-out spherical plate "
             f"(paper: 200 s)",
             f"* M4/M5: {s['epochs']} epochs (paper: 40), batch 256, lr 2.5e-4; the five "
             f"folds of each cross-validation train together as one stacked network "
             f"(estimation/torch_batched.py)",
             f"* closed loop: {len(s['objects'])} object(s) x {len(doc['controllers'])} "
             f"controllers (open loop on the spherical plate only, as in the paper) x "
             f"{s['repeats']} run(s) x the {s['sequence']} sequence "
             f"(paper: 5 objects, 5 runs); metrics over t = 16..70 s; control and estimation "
             f"at {s['control_rate']:g} Hz",
             f"* skin: {SKIN_TITLES[s['skin']]}",
             f"* cache: {run['cache']['hits']} hits, {run['cache']['misses']} misses",
             *extensions_lines(s.get('extended', ())), '']
    lines += ['## Which path produced which result', '']
    lines += [f'* {item}' for item in doc['paths']] + ['']

    lines += ['## Table I — offline benchmark, 5-fold leave-one-plate-out', '',
              'τ single: one prediction of one array (the paper\'s τ); full hand: one tick of '
              'the runtime estimator over 18 arrays of that kind.', '']
    for array, by_model in doc['table_I'].items():
        lines += [f'### {ARRAY_TITLES.get(array, array)}', '',
                  '| Model | e_r [%] sim | e_r [%] paper | e_hat [N] sim | e_hat [N] paper '
                  '| τ single [ms] sim | τ [ms] paper | full hand [ms] sim |',
                  '|---|---|---|---|---|---|---|---|']
        for label, row in by_model.items():
            sim, ref = row['sim'], row['paper'] or {}
            lines.append('| ' + ' | '.join(
                [MODEL_NAMES.get(label, label)]
                + _sim_paper(sim['e_r_percent'], sim['e_r_std_percent'], ref.get('e_r'), 1)
                + _sim_paper(sim['e_hat'], sim['e_hat_std'], ref.get('e_hat'), 2)
                + [cell(sim['tau_single_ms'], digits=3), cell(ref.get('tau_ms'), digits=3),
                   cell(sim['tau_full_hand_ms'], digits=3)]) + ' |')
        lines.append('')

    lines += learning_curve_section(doc.get('learning_curve'))
    lines += whole_hand_section(doc['whole_hand'], s)
    lines += cross_array_section(doc.get('cross_array'))
    lines += budget_section(doc.get('budget_campaign'))
    lines += shipped_models_section(doc.get('shipped_models'))
    lines += ['## Table II — online test, index fingertip on the held-out spherical plate', '',
              f"Models retrained on all five training plates; {doc['online']['samples']} samples "
              f"({doc['online']['seconds']:.0f} s). Last column: the same models on their own "
              f"training sessions ({doc['online']['in_distribution_samples']} samples, in "
              "distribution), against which the held-out plate is the harder test.", '',
              '| Model | e_r [%] sim | e_r [%] paper | e_hat [N] sim | e_hat [N] paper '
              '| e_hat [N] sim, training plates |',
              '|---|---|---|---|---|---|']
    for label, row in doc['table_II'].items():
        sim, ref = row['sim'], row['paper']
        lines.append('| ' + ' | '.join(
            [MODEL_NAMES.get(label, label)]
            + _sim_paper(sim['e_r_percent'], sim['e_r_std_percent'], ref['e_r'], 1)
            + _sim_paper(sim['e_hat'], sim['e_hat_std'], ref['e_hat'], 2)
            + [cell(sim['in_distribution_e_hat'], sim['in_distribution_e_hat_std'], 2)]
            ) + ' |')
    lines.append('')

    lines += end_to_end_section(doc['end_to_end'])

    lines += ['## Table III — closed-loop force control', '',
              '(1) spherical plate, (2) foam brick, (3) softball, (4) abrasive sponge, '
              '(5) bleach cleanser. Mean ± std over the samples of all runs in t = 16..70 s. '
              'Each run starts clear of the plate; the F/T sensor is zeroed and the estimator '
              'tared there before the controller brings the fingertip into contact by its '
              'guarded approach (experiments/closed_loop.py, control/approach.py). First '
              'touch: the largest |f~| before the first force command, and that over the first '
              'force commanded (the worst run; not in the paper).', '',
              '| Exp. | e_r [%] sim | e_r [%] paper | e_hat [N] sim | e_hat [N] paper '
              '| e_track [N] sim | e_track [N] paper | e~ [N] sim | e~ [N] paper '
              '| first touch [N] | over command |',
              '|---|---|---|---|---|---|---|---|---|---|---|']
    for row in doc['table_III']:
        sim, ref = row['sim'], row['paper'] or {}
        lines.append('| ' + ' | '.join(
            [row['row']]
            + _sim_paper(sim['e_r_percent'], sim['e_r_std_percent'], _pair(ref, 'e_r'), 2)
            + _sim_paper(sim['e_hat'], sim['e_hat_std'], _pair(ref, 'e_hat'), 2)
            + _sim_paper(sim['e_track'], sim['e_track_std'], _pair(ref, 'e_track'), 2)
            + _sim_paper(sim['e_tilde'], sim['e_tilde_std'], _pair(ref, 'e_tilde'), 2)
            + [cell(sim.get('first_touch_peak_n')), cell(sim.get('first_touch_ratio'))]) + ' |')
    lines.append('')

    lines += filter_closed_loop_section(doc['filter_closed_loop'])

    check = doc['must_show']
    lines += ['## Closed loop against open loop (spherical plate)', '']
    if check['evaluated']:
        lines += [f"* e~ open loop {cell(check['e_tilde_open_loop'], digits=3)} N, closed loop "
                  f"with M3λ {cell(check['e_tilde_m3_lambda'], digits=3)} N: reduction "
                  f"{cell(check['e_tilde_reduction_percent'], digits=1)} % (target ≥ "
                  f"{check['reduction_target_percent']:g} %, paper ≈ "
                  f"{check['paper_reduction_percent']} %): "
                  f"**{'met' if check['reduction_met'] else 'NOT met'}**",
                  f"* e_track with M3λ {cell(check['e_track_m3_lambda'], digits=3)} N (target < "
                  f"{check['e_track_target_n']:g} N): "
                  f"**{'met' if check['e_track_met'] else 'NOT met'}**", '']
    else:
        lines += ['* not evaluated: this run has no open-loop and M3λ runs on the spherical '
                  'plate', '']

    lines += grasp_section(doc.get('grasp'))
    lines += skin_targets_section(doc['skin_targets'])
    lines += node_path_section(doc['node_path'], doc['node_tolerance_reason'])
    lines += ['## Figures', ''] + [f'* [{name}]({name})' for name in doc['figures']] + ['']
    lines += skin_sensitivity_section(doc.get('skin_sensitivity'))
    lines += stage_times_section(run)
    return '\n'.join(lines)


def extensions_lines(extended) -> list[str]:
    """Which of the longer extensions this run added, and how to add the others."""
    left = [name for name in EXTENDED_STAGES if name not in extended]
    lines = [f"* extensions: {', '.join(extended) if extended else 'none'}"]
    if left:
        lines.append(f"* not run: {', '.join(left)} (`reproduce --extended` adds them all, "
                     '`--stages NAME ...` those named)')
    return lines


def skin_sensitivity_section(result: dict | None) -> list[str]:
    if not result:
        return []
    met = sum(t['met'] == len(t['values']) for t in result['targets'])
    return ["## The magnetic skin's sensitivity to its estimated parameters", '',
            f"The skin_sensitivity tool's tables: [{result['files'][0]}]({result['files'][0]}) "
            f"(JSON beside it); {met} of {len(result['targets'])} targets met at the values in "
            'every seed.', '']


def stage_times_section(run: dict) -> list[str]:
    """Each stage's wall time; for the stages run in the worker pool their units' count, summed
    and longest time (the stage's critical path), and the run's predicted wall time by workers."""
    units = run.get('stage_units', {})
    lines = ['## Stage wall times [s]', '',
             'Pool stages: units, their summed time (work) and the longest unit (the critical '
             'path, which more cores cannot shorten); the other stages run in the main process.',
             '', '| stage | wall [s] | units | work [s] | longest unit [s] |',
             '|---|---|---|---|---|']
    for name, wall in run['stage_seconds'].items():
        u = units.get(name)
        lines.append(f'| {name} | {wall:.1f} | ' + (
            f"{u['units']} | {u['work_s']:.1f} | {u['longest_s']:.1f} |" if u else '– | – | – |'))
    predicted = run.get('predicted_seconds')
    if predicted:
        lines += ['', 'Predicted wall time with N workers (one a core; each pool stage takes its '
                  'work over N or its longest unit, the rest as measured): '
                  + ', '.join(f'{n}: {v:.0f} s' for n, v in predicted.items()) + '.']
    return lines + ['']
