"""compare_reports: two main-job reports compared figure by figure."""
import json

import pytest

from tacforce_ros.experiments.compare_reports import compare, main


def report(**changes):
    """A report.json shaped like reproduce's, small."""
    rows = [{'object': 'spherical', 'controller': 'M4', 'sim': {'e_tilde': 0.15, 'runs': 5}},
            {'object': 'spherical', 'controller': 'M3-lambda', 'sim': {'e_tilde': 0.20}}]
    base = {'skin': 'empirical', 'table_I': {'index_tip': {'M5': {'sim': {
                'e_hat': 0.19, 'train_seconds_per_fold': 37.7, 'tau_single_ms': 0.14,
                'per_plate': [{'test_plate': 'button', 'e_hat_mean': 0.34}]}}}},
            'table_III': rows, 'end_to_end': {'rows': [{'model': 'M4', 'cutoff_hz': None,
                                                        'group_delay_ms': 0.0,
                                                        'compute_ms': 0.21}]},
            'node_path': {'closed_loop': {'e_tilde': 0.17}}, 'label': 'magnetic',
            'run': {'code_version': 'abc1234', 'wall_seconds': 700.0}}
    for path, value in changes.items():
        where = base
        *parents, last = path.split('.')
        for key in parents:
            where = where[int(key)] if isinstance(where, list) else where[key]
        where[last] = value
    return base


def test_the_same_figures_are_equal_and_measured_ones_are_set_aside():
    result = compare(report(), report(**{'run.wall_seconds': 900.0,
                                         'node_path.closed_loop.e_tilde': 0.2,
                                         'end_to_end.rows.0.compute_ms': 0.5}))
    assert result['differ'] == [] and result['equal'] > 0
    assert result['measured_set_aside'] >= 5


def test_a_computed_figure_that_moved_is_named_with_both_values():
    result = compare(report(), report(**{'table_I.index_tip.M5.sim.e_hat': 0.1901,
                                         'end_to_end.rows.0.group_delay_ms': 9.7}))
    moved = {d['figure']: d for d in result['differ']}
    assert set(moved) == {'table_I/index_tip/M5/sim/e_hat',
                          'end_to_end/rows[model=M4,cutoff_hz=None]/group_delay_ms'}
    assert moved['table_I/index_tip/M5/sim/e_hat']['after'] == 0.1901
    assert compare(report(), report(**{'table_I.index_tip.M5.sim.e_hat': 0.1901}),
                   tolerance=1e-3)['differ'] == []


def test_rows_are_paired_by_their_names_not_their_order():
    swapped = report()
    swapped['table_III'] = swapped['table_III'][::-1]
    assert compare(report(), swapped)['differ'] == []
    dropped = report()
    dropped['table_III'] = dropped['table_III'][:1]
    only = compare(report(), dropped)['only']
    assert 'table_III[object=spherical,controller=M3-lambda]/sim/e_tilde' in only['before']
    assert only['after'] == []


def test_rows_that_share_a_name_are_paired_by_place_not_merged():
    before, after = report(), report()
    for rows, e_tilde in ((before['table_III'], (0.15, 0.20)), (after['table_III'], (0.15, 0.25))):
        for row, value in zip(rows, e_tilde):
            row['controller'] = 'M4'
            row['sim']['e_tilde'] = value
    moved = compare(before, after)['differ']
    assert [d['figure'] for d in moved] == ['table_III[1]/sim/e_tilde']


def test_the_tool_writes_its_files_and_exits_1_on_a_difference(tmp_path, capsys):
    before, after = tmp_path / 'a.json', tmp_path / 'b.json'
    before.write_text(json.dumps(report()))
    after.write_text(json.dumps(report()))
    assert main([str(before), str(after), '--out', str(tmp_path / 'same')]) == 0
    after.write_text(json.dumps(report(**{'table_III.1.sim.e_tilde': 0.3})))
    assert main([str(before), str(after), '--out', str(tmp_path / 'moved')]) == 1
    written = json.loads((tmp_path / 'moved' / 'compare.json').read_text())
    assert written['comparison']['differ'][0]['before'] == 0.2
    assert 'e_tilde' in (tmp_path / 'moved' / 'compare.md').read_text()


@pytest.mark.parametrize('text, why', [('{"table_I": ', 'Expecting'),
                                       ('{"a": 1}', 'not a reproduce report')])
def test_a_file_that_is_not_a_report_is_refused_with_why(tmp_path, capsys, text, why):
    bad, good = tmp_path / 'bad.json', tmp_path / 'good.json'
    bad.write_text(text)
    good.write_text(json.dumps(report()))
    with pytest.raises(SystemExit) as ended:
        main([str(bad), str(good), '--out', str(tmp_path)])
    assert ended.value.code == 2 and why in capsys.readouterr().err


def test_the_trained_models_figures_may_have_a_tolerance_of_their_own(tmp_path, capsys):
    """Reports of two processor models: M4's and M5's figures within --trained-tolerance are
    equal, every other figure still to --tolerance."""
    before = report()
    after = report(**{'table_I.index_tip.M5.sim.e_hat': 0.193,             # M5, 3 mN
                      'table_III.0.sim.e_tilde': 0.152,                   # M4's row, 2 mN
                      'table_III.1.sim.e_tilde': 0.2001})                 # M3-lambda's, 0.1 mN
    result = compare(before, after, trained_tolerance=0.005)
    assert [d['figure'] for d in result['differ']] == [
        'table_III[object=spherical,controller=M3-lambda]/sim/e_tilde']
    assert result['equal_within_trained_tolerance'] == 2
    assert len(compare(before, after, trained_tolerance=0.001)['differ']) == 3
    assert len(compare(before, after)['differ']) == 3       # no trained tolerance: all judged
    paths = []
    for name, doc in (('before', before), ('after', after)):
        paths.append(tmp_path / f'{name}.json')
        paths[-1].write_text(json.dumps(doc))
    assert main([*map(str, paths), '--out', str(tmp_path / 'c'), '--tolerance', '0.001',
                 '--trained-tolerance', '0.005']) == 0
    assert '2 equal only within it' in (tmp_path / 'c' / 'compare.md').read_text()
    with pytest.raises(SystemExit) as refused:
        main([*map(str, paths), '--out', str(tmp_path / 'c'), '--trained-tolerance', '-1'])
    assert refused.value.code == 2 and '--trained-tolerance -1' in capsys.readouterr().err
