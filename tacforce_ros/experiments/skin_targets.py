"""The magnetic skin's targets: the paper's findings as a simulated skin must show them.

Judged on Table I rows (held-out e_hat per array and model) and the closed loop on the
spherical plate, by `skin_sensitivity` over seeds and by the main job on its magnetic-skin run.
"""
from __future__ import annotations

from tacforce_ros.experiments import paper_reference as paper

CURVED, FLAT = 'index_tip', 'index_middle'   # the paper's Table I arrays
PAPER_BAND = (0.6, 1.5)         # M3-lambda, M4, M5 e_hat over the paper's
NONLINEAR_BELOW = 0.85          # M4, M5 over M3-lambda: at least 15 % below it
ORIENTATION_ABOVE = 1.5         # curved M1, M2 over M3-lambda: at least 50 % above it
FLAT_SPREAD = 1.25              # flat M1, M2, M3: within 25 % of each other
LOOP_REDUCTION, LOOP_TRACK = 0.70, 0.1   # closed loop: e~ cut by 70 %, e_track below 0.1 N

# Why this skin misses a target when it does, in one sentence (docs/SKIN_PHYSICS.md, the
# sections named, has the measurements).
WHY_MISSED = {
    'flat_spread': 'the layer keeps its volume, so the flat array\'s summed normal counts per '
                   'newton change sign from plate to plate and M1 and M2, which sum them, err '
                   'more than M3 on the four broad plates (docs/SKIN_PHYSICS.md, "Why M1 errs '
                   'on the flat array")',
}


def loop_reason(gain: float | None = None) -> str:
    """Why the closed loop misses its reduction, with the run's own reading of the normal force at
    the loop's spot (its estimate over the measured force) where the run has it."""
    reading = 'misreads the normal force' if gain is None else \
        f'reads the normal force {gain:.2f} times'
    return ('the loop holds one spot at about 1 N, where a model fitted on the five training '
            f'plates {reading} (the column under the magnet stiffens with the force, and where '
            'the fit lands at that spot and force depends on the sessions drawn and on the '
            'spot); the loop follows that estimate (docs/SKIN_PHYSICS.md, "Why the closed loop '
            'differs so much between seeds")')


def targets(result: dict) -> list[dict]:
    """The targets on the values rows: [{'target', 'values' (one per seed, None where the
    row lacks what it needs), 'met'}], for the targets the run's arrays and models allow."""
    rows = [row for row in result['variants'] if row['name'] == 'values' and row['e_hat']]
    models = set(result['models'])
    checks = []

    def check(label, measure, passes, why=None, **about):
        """`about`: what the target compares (array, model), for a report that explains it."""
        values = [measure(row) for row in rows]
        checks.append({'target': label, 'values': values,
                       'met': sum(v is not None and passes(v) for v in values),
                       **({'why_missed': why} if why else {}), **about})

    def ratio(array, model, over):
        return lambda row: row['e_hat'][array][model] / row['e_hat'][array][over]

    for array in result['arrays']:
        for model in sorted(models & {'M3-lambda', 'M4', 'M5'}):
            paper_value = paper.TABLE_I[array][model]['e_hat'][0]
            check(f'{array} {model} e_hat over the paper in [{PAPER_BAND[0]}, {PAPER_BAND[1]}]',
                  lambda row, a=array, m=model, v=paper_value: row['e_hat'][a][m] / v,
                  lambda v: PAPER_BAND[0] <= v <= PAPER_BAND[1])
        if 'M3-lambda' not in models:
            continue
        for model in sorted(models & {'M4', 'M5'}):
            check(f'{array} {model} over M3-lambda <= {NONLINEAR_BELOW}',
                  ratio(array, model, 'M3-lambda'), lambda v: v <= NONLINEAR_BELOW,
                  below_linear={'array': array, 'model': model})
        if array == CURVED:
            for model in sorted(models & {'M1', 'M2'}):
                check(f'{array} {model} over M3-lambda >= {ORIENTATION_ABOVE}',
                      ratio(array, model, 'M3-lambda'), lambda v: v >= ORIENTATION_ABOVE)
    if FLAT in result['arrays'] and {'M1', 'M2', 'M3'} <= models:
        check(f'{FLAT} M1, M2, M3 largest over smallest <= {FLAT_SPREAD}',
              lambda row: (max(row['e_hat'][FLAT][m] for m in ('M1', 'M2', 'M3'))
                           / min(row['e_hat'][FLAT][m] for m in ('M1', 'M2', 'M3'))),
              lambda v: v <= FLAT_SPREAD, WHY_MISSED['flat_spread'])
    loops = [label for row in rows for label in (row.get('closed_loop') or {})
             if label != 'open_loop']
    for label in dict.fromkeys(loops):
        check(f'closed loop {label}: e~ reduction >= {LOOP_REDUCTION:.0%}',
              lambda row, m=label: (row.get('closed_loop') or {}).get(m, {}).get('reduction'),
              lambda v: v >= LOOP_REDUCTION, loop_reason(), loop=label)
        check(f'closed loop {label}: e_track < {LOOP_TRACK} N',
              lambda row, m=label: (row.get('closed_loop') or {}).get(m, {}).get('e_track'),
              lambda v: v < LOOP_TRACK)
    return checks
