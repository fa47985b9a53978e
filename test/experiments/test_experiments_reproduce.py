"""reproduce --quick end to end, with the extensions but skin_sensitivity (its tool has its own
tests): the Markdown tables say what the JSON says, the figures are images, a second run comes
entirely from the cache with the same results, and the default run, without the extensions,
has the same paper tables and says what it left out."""
import json
import re

import numpy as np
import pytest

from tacforce_ros.estimation.causal_filter import BatchLowPass
from tacforce_ros.estimation.model_set import model_files
from tacforce_ros.experiments import paper_reference as paper
from tacforce_ros.experiments.settings import FILTER_CUTOFFS_HZ
from tacforce_ros.experiments.report import MODEL_NAMES
from tacforce_ros.experiments import reproduce

NUMBER = re.compile(r'-?\d+(?:\.\d+)?')
LABELS = {v: k for k, v in MODEL_NAMES.items()}


EXTENSIONS = ['whole_hand', 'cross_array', 'learning_curve', 'budget']


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp('reproduce')
    assert reproduce.main(['--quick', '--out', str(out), '--stages', *EXTENSIONS]) == 0
    first = json.loads((out / 'report.json').read_text())
    first_md = (out / 'report.md').read_text()
    assert reproduce.main(['--quick', '--out', str(out), '--stages', *EXTENSIONS]) == 0
    second = json.loads((out / 'report.json').read_text())
    return out, first, first_md, second


def test_the_default_run_has_the_paper_s_tables_and_says_which_extensions_it_left_out(runs):
    out, extended, _, _ = runs
    assert reproduce.main(['--quick', '--out', str(out)]) == 0     # every unit from the cache
    doc = json.loads((out / 'report.json').read_text())
    md = (out / 'report.md').read_text()
    assert doc['run']['cache']['misses'] == 0
    assert doc['settings']['extended'] == [] and extended['settings']['extended'] == EXTENSIONS
    for key in ('table_I', 'table_II', 'table_III', 'end_to_end', 'grasp', 'online',
                'must_show', 'filter_closed_loop', 'skin_targets'):
        assert doc[key] == extended[key], key
    for key in ('whole_hand', 'cross_array', 'learning_curve', 'budget_campaign',
                'skin_sensitivity'):
        assert doc[key] is None, key
    for heading in ('## Whole hand', '## Across arrays', '## Learning curves',
                    '## A campaign with a budget'):
        assert heading not in md
    assert ('* not run: whole_hand, cross_array, learning_curve, budget, skin_sensitivity '
            '(`reproduce --extended`') in md
    assert 'whole_hand.png' not in doc['figures'] and 'learning_curve.png' not in doc['figures']


def test_the_extensions_bring_the_stages_they_need(monkeypatch, tmp_path):
    from tacforce_ros.experiments.settings import EXTENDED_STAGES, with_needs
    assert with_needs(['cross_array']) == ('whole_hand', 'cross_array')
    assert with_needs(['learning_curve', 'budget']) == ('whole_hand', 'learning_curve', 'budget')
    with pytest.raises(ValueError, match='nosuch'):
        with_needs(['nosuch'])
    seen = []

    def stop_before_running(settings, out, jobs):     # the parsed settings are what is checked
        seen.append((settings, jobs))
        raise SystemExit(0)

    monkeypatch.setattr(reproduce, 'run', stop_before_running)
    with pytest.raises(SystemExit):
        reproduce.main(['--extended', '--workers', '3', '--out', str(tmp_path)])
    settings, jobs = seen[0]
    assert settings.extended == tuple(EXTENDED_STAGES) and jobs == 3
    with pytest.raises(SystemExit) as refused:
        reproduce.main(['--stages', 'nosuch'])
    assert refused.value.code == 2


def test_the_stage_times_give_each_pool_stage_s_critical_path(runs):
    from tacforce_ros.experiments.workers import predicted_seconds
    _, doc, md, _ = runs
    run = doc['run']
    units = run['stage_units']
    assert units and set(units) <= set(run['stage_seconds'])
    for name, u in units.items():
        assert u['units'] >= 1 and 0 < u['longest_s'] <= u['work_s'], name
    # One worker does all the work; more cannot beat the longest unit of each stage.
    serial = run['wall_seconds'] - sum(run['stage_seconds'][n] for n in units)
    assert predicted_seconds(run['stage_seconds'], units, run['wall_seconds'], 1) == \
        pytest.approx(serial + sum(u['work_s'] for u in units.values()))
    floor = serial + sum(u['longest_s'] for u in units.values())
    assert run['predicted_seconds']['16'] >= floor - 1e-9
    assert [run['predicted_seconds'][n] for n in ('1', '2', '4', '8', '16')] == sorted(
        run['predicted_seconds'].values(), reverse=True)
    assert 'Predicted wall time with N workers' in md


def tables(markdown: str) -> dict[str, list[list[str]]]:
    """Markdown tables by the heading above them: rows of cells, header and rule dropped."""
    found, heading, current = {}, None, None
    for line in markdown.splitlines():
        if line.startswith('#'):
            heading, current = line.lstrip('# ').strip(), None
        elif line.startswith('|'):
            if current is None:
                current = found.setdefault(heading, [])
                continue                       # header row
            if not line.startswith('|---'):
                current.append([c.strip() for c in line.strip('|').split('|')])
        else:
            current = None
    return found


def numbers(text: str) -> list[float]:
    return [float(v) for v in NUMBER.findall(text)]


def assert_shows(text: str, mean, std, digits: int) -> None:
    """The cell shows mean (and std) to `digits` decimals, or '–' when there is none."""
    if mean is None:
        assert text == '–', text
        return
    shown = numbers(text)
    expected = [mean] if std is None else [mean, std]
    assert len(shown) == len(expected), text
    assert np.allclose(shown, expected, atol=0.5 * 10 ** -digits + 1e-12), (text, expected)


def test_markdown_tables_show_the_json_numbers(runs):
    _, doc, md, _ = runs
    by_heading = tables(md)
    for array, rows in doc['table_I'].items():
        heading = next(h for h in by_heading if h.endswith(f'({array})'))
        shown = {LABELS.get(r[0], r[0]): r for r in by_heading[heading]}
        assert set(shown) == set(rows)
        for label, row in rows.items():
            cells, sim, ref = shown[label], row['sim'], row['paper'] or {}
            assert_shows(cells[1], sim['e_r_percent'], sim['e_r_std_percent'], 1)
            assert_shows(cells[2], *(ref.get('e_r') or (None, None)), 1)
            assert_shows(cells[3], sim['e_hat'], sim['e_hat_std'], 2)
            assert_shows(cells[4], *(ref.get('e_hat') or (None, None)), 2)
            assert_shows(cells[5], sim['tau_single_ms'], None, 3)
            assert_shows(cells[6], ref.get('tau_ms'), None, 3)
            assert_shows(cells[7], sim['tau_full_hand_ms'], None, 3)
    table_ii = next(v for h, v in by_heading.items() if h.startswith('Table II'))
    assert len(table_ii) == len(doc['table_II'])
    for cells in table_ii:
        row = doc['table_II'][LABELS.get(cells[0], cells[0])]
        assert_shows(cells[1], row['sim']['e_r_percent'], row['sim']['e_r_std_percent'], 1)
        assert_shows(cells[3], row['sim']['e_hat'], row['sim']['e_hat_std'], 2)
        assert_shows(cells[4], *row['paper']['e_hat'], 2)
        assert_shows(cells[5], row['sim']['in_distribution_e_hat'],
                     row['sim']['in_distribution_e_hat_std'], 2)
    table_iii = next(v for h, v in by_heading.items() if h.startswith('Table III'))
    assert [c[0] for c in table_iii] == [r['row'] for r in doc['table_III']]
    for cells, row in zip(table_iii, doc['table_III']):
        sim, ref = row['sim'], row['paper'] or {}
        for k, key in enumerate(('e_r', 'e_hat', 'e_track', 'e_tilde')):
            sim_key = 'e_r_percent' if key == 'e_r' else key
            sim_std = 'e_r_std_percent' if key == 'e_r' else f'{key}_std'
            assert_shows(cells[1 + 2 * k], sim[sim_key], sim[sim_std], 2)
            assert_shows(cells[2 + 2 * k], *ref.get(key, (None, None)), 2)


def test_end_to_end_costs_add_up_and_the_table_shows_them(runs):
    _, doc, md, _ = runs
    e2e = doc['end_to_end']
    models = doc['settings']['models']
    assert [(r['model'], r['cutoff_hz']) for r in e2e['rows']] == \
        [(m, c) for c in FILTER_CUTOFFS_HZ for m in models]
    # --quick has no node path: the latency is not measured, and not made up.
    assert e2e['node_latency']['measured'] is False and 'not measured in this run' in md
    for r in e2e['rows']:
        timing = doc['table_I']['index_tip'][r['model']]['sim']['timing_us']
        tick = timing['full_hand_tick' if r['cutoff_hz'] is None else 'full_hand_tick_lowpass']
        delay = 0.0 if r['cutoff_hz'] is None else 1e3 * BatchLowPass(
            1, r['cutoff_hz'], 100.0, e2e['filter_order']).group_delay_s()
        assert r['compute_ms'] == pytest.approx(tick['median_us'] / 1e3)
        assert r['group_delay_ms'] == pytest.approx(delay)
        assert r['node_latency_ms'] is None
        assert r['end_to_end_ms'] == pytest.approx(r['compute_ms'] + r['group_delay_ms'])
    (rows,) = [rows for heading, rows in tables(md).items()
               if heading.startswith('What accuracy costs in time, end to end')]
    assert len(rows) == len(e2e['rows'])
    for cells, r in zip(rows, e2e['rows']):
        assert LABELS.get(cells[0], cells[0]) == r['model']
        assert cells[1] == ('off' if r['cutoff_hz'] is None else f"{r['cutoff_hz']:g} Hz")
        assert_shows(cells[2], r['e_hat_mean'], r['e_hat_std'], 3)
        assert_shows(cells[4], r['compute_ms'], None, 3)
        assert_shows(cells[5], r['group_delay_ms'], None, 1)
        assert cells[6] == '–'
        assert_shows(cells[7], r['end_to_end_ms'], None, 2)


def test_the_closed_loop_filter_comparison_is_reported(runs):
    _, doc, md, _ = runs
    effect = doc['filter_closed_loop']
    assert effect['cutoff_hz'] in FILTER_CUTOFFS_HZ[1:] and effect['runs'] == \
        doc['settings']['repeats']
    plain = next(r for r in doc['table_III'] if r['row'] == '(1)-M3λ')['sim']
    assert effect['without']['e_tilde_mean'] == pytest.approx(plain['e_tilde'])
    # the same seeds, another estimator input: another trajectory
    assert effect['with']['e_tilde_mean'] != effect['without']['e_tilde_mean']
    (rows,) = [rows for heading, rows in tables(md).items()
               if heading.startswith("Closed loop with the estimator's input low-pass")]
    for cells, m in zip(rows, (effect['without'], effect['with'])):
        assert_shows(cells[1], m['e_tilde_mean'], m['e_tilde_std'], 3)
        assert_shows(cells[2], m['e_track_mean'], m['e_track_std'], 3)
    assert f"**{effect['verdict']}**" in md


def test_report_holds_every_stage_and_labels_it_simulation(runs):
    _, doc, md, _ = runs
    assert 'SIMULATION' in md.splitlines()[0] and 'magnetic skin' in md.splitlines()[0]
    # The default skin is the magnetic one, and the run judges its targets on its own tables.
    assert doc['skin'] == doc['settings']['skin'] == 'magnetic'
    assert '* skin: magnetic' in md and "## The magnetic skin's targets on this run" in md
    judged = {c['target'] for c in doc['skin_targets']}
    assert 'index_tip M4 over M3-lambda <= 0.85' in judged
    assert 'closed loop M3-lambda: e~ reduction >= 70%' in judged
    assert set(doc['table_I']) == {'index_tip', 'index_middle'}
    assert all(len(rows) == len(doc['settings']['models']) for rows in doc['table_I'].values())
    objects, controllers = doc['settings']['objects'], doc['controllers']
    assert len(doc['table_III']) == len(objects) * (len(controllers) - 1) + (
        'spherical' in objects)      # the open loop ran on the spherical plate only
    open_loop = [r for r in doc['table_III'] if r['controller'] == 'open_loop']
    assert all(r['sim']['e_hat'] is None and r['sim']['e_tilde'] > 0 for r in open_loop)
    closed = [r for r in doc['table_III'] if r['controller'] != 'open_loop']
    assert all(r['sim']['e_track'] is not None for r in closed)
    # The paper column is the reference module's, unchanged.
    row = next(r for r in doc['table_III'] if r['row'] == '(1)-O.L.')
    assert tuple(row['paper']['e_tilde']) == paper.TABLE_III[('spherical', 'open_loop')]['e_tilde']
    # The held-out plate is the harder test: worse than the models' own training plates.
    for row in doc['table_II'].values():
        assert row['sim']['e_hat'] > row['sim']['in_distribution_e_hat']
    # --quick skips the node graph and the report says so instead of showing numbers.
    assert doc['node_path']['ran'] is False
    assert 'The node path did not run' in md
    check = doc['must_show']
    assert check['evaluated'] and check['reduction_met'] == (
        check['e_tilde_reduction_percent'] >= check['reduction_target_percent'])


def test_figures_are_png_images(runs):
    import matplotlib.image
    out, doc, _, _ = runs
    assert len(doc['figures']) == 4 + len(doc['settings']['objects']) + len(
        doc['settings']['grasp_objects'])
    for name in doc['figures']:
        path = out / name
        assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n', name
        image = matplotlib.image.imread(path)
        assert image.ndim == 3 and min(image.shape[:2]) > 100 and np.ptp(image) > 0, name


def test_the_learning_curves_hold_every_array_model_and_point_as_the_table_shows(runs):
    _, doc, md, _ = runs
    rows, s = doc['learning_curve']['rows'], doc['settings']
    arrays = ('index_tip', 'index_middle')
    assert {(r['array'], r['model'], r['way'], r['seconds']) for r in rows} == {
        (a, m, 'own', t) for a in arrays for m in s['learning_models']
        for t in s['learning_seconds']} | {
        (a, 'M3-lambda', 'shared', t) for a in arrays for t in s['learning_seconds']}
    assert all(r['e_hat_n'] > 0 for r in rows)
    assert '## Learning curves' in md and 'learning_curve.png' in doc['figures']
    for r in rows:
        line = next(x for x in md.splitlines()
                    if x.startswith(f"| {r['array']} | {r['model']} | {r['way']} |"))
        assert f"{r['e_hat_n']:.3f}" in line, (r, line)
    # The same cuts as the array's own model, each fold with the weight it chose.
    for r in rows:
        if r['way'] == 'shared':
            own = next(o for o in rows if (o['array'], o['model'], o['way'], o['seconds'])
                       == (r['array'], r['model'], 'own', r['seconds']))
            assert (r['samples'], r['recorded_s']) == (own['samples'], own['recorded_s'])
            assert len(r['adapt_weights']) == 5
    for array in arrays:
        assert any(line.startswith(f'* {array}, M3-lambda: shared below own M3-lambda at ')
                   for line in md.splitlines()), array
    # The quick run records 20 s per plate: its 100 s point is the whole recording.
    full = [r for r in rows if r['seconds'] == 100.0]
    assert all(abs(r['recorded_s'] - 100.0) < 1.0 for r in full)


def test_the_shipped_models_say_which_way_each_was_made(runs):
    out, doc, md, _ = runs
    rows = doc['shipped_models']
    listed = {(f'models/{c.name}', a) for c in (out / 'models').glob('*.yaml')
              for a in model_files(c)}
    assert {(r['set'], r['array']) for r in rows} == listed and listed
    # Every model the job ships is fitted on its own array's data: the training set's seconds.
    assert all(r['way'] == 'own' and r['own_seconds'] > 0 for r in rows)
    tip = next(r for r in rows if r['array'] == 'index_tip' and r['kind'] == 'M3-lambda')
    s = doc['settings']
    assert tip['own_seconds'] == pytest.approx(
        len(doc['plates']) * s['sessions_per_plate'] * s['session_seconds'], rel=0.02)
    for r in rows:
        assert f"| {r['set']} | {r['array']} | {r['kind']} | own | {r['own_seconds']:g} |" in md


def test_second_run_comes_from_the_cache_with_the_same_results(runs):
    _, first, _, second = runs
    assert first['run']['cache']['misses'] > 0
    assert second['run']['cache']['misses'] == 0 and second['run']['cache']['hits'] > 0
    assert {k: v for k, v in first.items() if k != 'run'} == \
        {k: v for k, v in second.items() if k != 'run'}


def test_the_whole_hand_section_shows_every_array_s_held_out_error(runs):
    out, doc, md, second = runs
    from tacforce_ros.hand.description import load_hand
    hand = load_hand()
    rows = doc['whole_hand']
    assert list(rows) == [a.name for a in hand.arrays]
    assert {r['type'] for r in rows.values()} == {'fingertip', 'phalanx', 'palm'}
    for name, row in rows.items():
        assert row['cv']['folds'] == 5 and 0.0 < row['cv']['e_hat_mean'] < 2.0, name
    # The Table I arrays carry their Table I row; the others their own short sessions.
    assert rows['index_tip']['cv']['e_hat_mean'] == doc['table_I']['index_tip']['M3-lambda'][
        'sim']['e_hat']
    assert rows['palm_center']['seconds'] == doc['settings']['whole_hand_seconds']
    shown = {r[0]: r for r in next(v for h, v in tables(md).items()
                                   if h.startswith('Whole hand')) if not r[0].startswith('**')}
    assert set(shown) == set(rows)
    for name, row in rows.items():
        assert_shows(shown[name][3], row['cv']['e_hat_mean'], row['cv']['e_hat_std'], 3)
    assert (out / 'whole_hand.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert second['whole_hand'] == rows               # from the cache, the same



def test_the_grasp_table_holds_its_rows_as_the_json_says(runs):
    out, doc, md, second = runs
    rows = doc['grasp']['rows']
    settings = doc['settings']
    assert [(r['object'], r['grip_n']) for r in rows] == [
        (o, g) for o in settings['grasp_objects'] for g in settings['grasp_grips']]
    for row in rows:
        assert set(row) >= {'object', 'grip_n', 'fingers', 'runs', 'drops', 'finger_error_n',
                            'open_loop_finger_error_n', 'single_finger_error_n',
                            'peak_over_command', 'slip_mm'}
        assert row['fingers'] == ['thumb', 'index'] and row['runs'] == settings['grasp_repeats']
        single = next(r for r in doc['table_III']
                      if r['object'] == 'spherical' and r['controller'] == 'M3-lambda')
        assert row['single_finger_error_n'] == single['sim']['e_tilde']
    shown = next(v for h, v in tables(md).items() if h.startswith('Grasp'))
    for cells, row in zip(shown, rows, strict=True):
        assert cells[0] == row['object'] and float(cells[1]) == row['grip_n']
        assert_shows(cells[4], row['finger_error_n'], None, 2)
        assert_shows(cells[5], row['open_loop_finger_error_n'], None, 2)
    for obj in settings['grasp_objects']:
        assert f'grasp_{obj}.png' in doc['figures']
    assert second['grasp'] == doc['grasp']


def test_the_cross_array_table_holds_every_pair_of_a_kind_and_shows_each_row(runs):
    _, doc, md, second = runs
    cross, rows = doc['cross_array'], doc['whole_hand']
    kinds: dict[str, list[str]] = {}
    for name, row in rows.items():
        kinds.setdefault(row['type'], []).append(name)
    assert {(p['source'], p['target']) for p in cross['pairs']} == {
        (a, b) for arrays in kinds.values() for a in arrays for b in arrays if a != b}
    assert [r['array'] for r in cross['rows']] == list(rows)
    shown = {r[0]: r for r in next(v for h, v in tables(md).items()
                                   if h.startswith('Across arrays'))}
    for row in cross['rows']:
        on_it = [p['e_hat_n'] for p in cross['pairs'] if p['target'] == row['array']]
        assert row['own_e_hat_n'] == rows[row['array']]['cv']['e_hat_mean']
        assert row['unadapted_e_hat_n'] == pytest.approx(np.mean(on_it))
        assert row['ratio'] == pytest.approx(row['unadapted_e_hat_n'] / row['own_e_hat_n'])
        cells = shown[row['array']]
        assert_shows(cells[1], row['own_e_hat_n'], None, 3)
        assert numbers(cells[2]) == pytest.approx(
            [row['unadapted_e_hat_n'], row['unadapted_min_n'], row['unadapted_max_n']],
            abs=5e-4)
    for kind, summary in cross['by_kind'].items():
        members = [r for r in cross['rows'] if r['kind'] == kind]
        assert summary['arrays'] == len(members) == len(kinds[kind])
        assert summary['ratio'] == pytest.approx(summary['unadapted_e_hat_n']
                                                 / summary['own_e_hat_n'])
    assert second['cross_array'] == cross             # from the cache, the same


def test_the_budget_campaign_is_planned_pressed_and_judged_as_the_table_shows(runs):
    _, doc, md, second = runs
    budget, settings = doc['budget_campaign'], doc['settings']
    kinds = settings['budget_kinds']
    assert {r['kind'] for r in budget['rows']} == set(kinds)
    # Every session was pressed for its kind's length: the minutes are the sessions' seconds.
    lengths = {k: v['session_s'] for k, v in budget['by_kind'].items()}
    assert all(length >= settings['budget_min_session_s'] for length in lengths.values())
    assert budget['planned_minutes'] <= settings['budget_minutes'] + 1e-9
    assert budget['sessions'] == len(budget['rows']) * budget['plates'] + \
        budget['sessions_pressed_again']
    pressed = sum(r['seconds'] for r in budget['rows']) + sum(
        again['seconds'] for again in budget['pressed_again'])
    assert budget['minutes'] == pytest.approx(pressed / 60.0)
    assert budget['must_show']['minutes'] == (budget['minutes'] <= settings['budget_minutes'])
    for row in budget['rows']:
        assert row['seconds'] == lengths[row['kind']] * budget['plates']
        assert row['ratio'] == pytest.approx(row['e_hat_n'] / row['full_e_hat_n'])
    for kind, summary in budget['by_kind'].items():
        mine = [r for r in budget['rows'] if r['kind'] == kind]
        assert summary['ratio'] == pytest.approx(np.mean([r['e_hat_n'] for r in mine])
                                                 / np.mean([r['full_e_hat_n'] for r in mine]))
        assert budget['e_hat_ratio_by_kind'][kind] == summary['ratio']
    assert budget['worst_array_ratio'] == max(r['ratio'] for r in budget['rows'])
    pooled = settings['budget_pool']
    assert {r['way'] for r in budget['kind_curve_rows']} == {
        'shared-kind+pool' if pooled else 'shared-kind'}
    assert budget['pool']['hand'] == (pooled or None)
    assert budget['pool']['arrays'] == (len(budget['rows']) if pooled else 0)
    assert {r['seconds'] for r in budget['kind_curve_rows']} == set(settings['budget_seconds'])
    shown = {r[0]: r for r in next(v for h, v in tables(md).items()
                                   if h.startswith('A campaign with a budget'))}
    for row in budget['rows']:
        cells = shown[row['array']]
        assert [numbers(c)[0] for c in cells[4:7]] == pytest.approx(
            [row['e_hat_n'], row['full_e_hat_n'], row['ratio']], abs=5e-3)
    assert second['budget_campaign'] == budget        # from the cache, the same
