"""A calibration campaign: plan, coverage verdicts, resuming an interrupted simulated campaign."""
import json
import math
import os
import signal
import subprocess
import time

import pytest

from tacforce_ros.bringup.processes import executable
from tacforce_ros.recording.campaign import (Campaign, CampaignError, CampaignPlan,
                                             CoverageLimits, SessionSlot)
from tacforce_ros.estimation.model_set import load_model_set
from tacforce_ros.hand.description import load_hand
from tacforce_ros.tools import campaign as campaign_tool
from tacforce_ros.tools import train

ARRAYS = ('index_middle', 'palm_center')    # a flat phalanx pad and a palm pad
PLATES = ('flat', 'edge')


def make(folder, limits=CoverageLimits(min_peak_force=1.0, min_shear_sectors=4, min_rests=2),
         **kw):
    plan = CampaignPlan(**{'hand_side': 'right', 'arrays': ARRAYS, 'plates': PLATES,
                           'sessions': 1, 'seconds': 20.0, 'seed': 4, 'limits': limits, **kw})
    return Campaign.create(folder, plan)


def test_the_plan_goes_plate_by_plate_and_refuses_another_plan_in_its_folder(tmp_path):
    campaign = make(tmp_path / 'c', sessions=2)
    assert [s.name for s in campaign.plan.slots()[:4]] == [
        'index_middle_flat_s0', 'index_middle_flat_s1', 'palm_center_flat_s0',
        'palm_center_flat_s1']
    assert Campaign(tmp_path / 'c').plan == campaign.plan          # read back as written
    with pytest.raises(CampaignError, match='another campaign plan'):
        make(tmp_path / 'c', sessions=3)
    with pytest.raises(CampaignError, match='not a campaign'):
        Campaign(tmp_path)


def test_an_interrupted_campaign_resumes_and_records_only_what_is_missing(tmp_path,
                                                                         monkeypatch):
    folder = tmp_path / 'c'
    make(folder)
    command = [str(executable('campaign')), 'run', str(folder), '--sim']
    first = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120.0
    try:
        # Killed (no chance to clean up) while its second session records.
        while time.monotonic() < deadline and not (folder / '.recording' / 'index_middle_edge_s0'
                                                   ).is_dir():
            time.sleep(0.02)
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
    assert (folder / '.recording' / 'index_middle_edge_s0').is_dir(), 'never reached session 2'
    finished = {p.name: os.stat(p / 'metadata.yaml').st_mtime_ns
                for p in Campaign(folder).bags()}
    assert 1 <= len(finished) < 4

    assert campaign_tool.main(['run', str(folder), '--sim']) == 0
    campaign = Campaign(folder)
    bags = {p.name: os.stat(p / 'metadata.yaml').st_mtime_ns for p in campaign.bags()}
    assert sorted(bags) == sorted(SessionSlot(a, p, 0).name for a in ARRAYS for p in PLATES)
    assert all(bags[name] == stamp for name, stamp in finished.items())    # not recorded again
    assert not (folder / '.recording').exists() or not any((folder / '.recording').iterdir())
    records = campaign.check(*campaign_tool._hand_and_kinematics('right'))
    assert campaign.due(records) == [] and len(campaign.counted_bags(records)) == 4
    verdicts = json.loads((folder / 'verdicts.json').read_text())
    assert {v['array'] for v in verdicts.values()} == set(ARRAYS)

    # train CAMPAIGN: every array of it, one model list for the estimator; with no verdict
    # stored, judging a bag and training on it read it once.
    from tacforce_ros.estimation import bag_dataset
    reads = []
    reading = bag_dataset.dataset_from_bag
    monkeypatch.setattr(bag_dataset, 'dataset_from_bag',
                        lambda bag, *a: reads.append(bag.name) or reading(bag, *a))
    (folder / 'verdicts.json').unlink()
    models = tmp_path / 'models'
    assert train.main([str(folder), '--out', str(models), '--kinds', 'M3-lambda']) == 0
    assert sorted(reads) == sorted(bags)
    report = json.loads((models / 'report.json').read_text())
    assert {(m['array'], m['array_type']) for m in report['models']} == {
        ('index_middle', 'phalanx'), ('palm_center', 'palm')}
    assert all(m['cross_validation']['folds'] == 2 for m in report['models'])
    model_set = load_model_set(models / 'models_M3-lambda.yaml', load_hand())
    assert [a.name for a in model_set.arrays] == list(ARRAYS)


def test_a_session_with_poor_coverage_is_kept_aside_and_recorded_again(tmp_path, capsys):
    folder = tmp_path / 'c'
    # No 20 s session has 50 rests: every one is judged poor.
    make(folder, arrays=('index_middle',), plates=('flat',), limits=CoverageLimits(min_rests=50))
    assert campaign_tool.main(['run', str(folder), '--sim']) == 1
    assert 'still due after 3 rounds' in capsys.readouterr().err
    rejected = sorted(p.name for p in (folder / 'rejected').iterdir() if p.is_dir())
    assert rejected == ['index_middle_flat_s0', 'index_middle_flat_s1', 'index_middle_flat_s2']
    verdict = json.loads((folder / 'rejected' / 'index_middle_flat_s0.verdict.json').read_text())
    assert any('let go between presses' in p for p in verdict['coverage']['problems'])
    assert Campaign(folder).bags() == []


def test_bags_count_by_their_metadata_whatever_their_names(tmp_path):
    """Lab recorder names (<date>_<array>_<plate>) count like sim_record's; of more bags than
    planned the first by natural order count (s2 before s10); a verdict is judged again when
    its bag changes."""
    from tacforce_ros.recording.sim_session import record_session
    folder = tmp_path / 'c'
    campaign = make(folder, arrays=('index_middle',), plates=('flat',))
    hand, kinematics = campaign_tool._hand_and_kinematics('right')
    for name, session in (('20261125_101010_index_middle_flat', 0), ('x_s10', 1), ('x_s2', 2)):
        record_session(folder / name, hand, 'index_middle', 'flat', session, 20.0, 4,
                       _Silent())
    records = campaign.check(hand, kinematics)
    assert len(records) == 3 and campaign.due(records) == []
    assert [p.name for p in campaign.counted_bags(records)] == [
        '20261125_101010_index_middle_flat']                 # sessions: 1, natural order
    stamps = json.loads((folder / 'verdicts.json').read_text())
    assert set(stamps) == {'20261125_101010_index_middle_flat', 'x_s10', 'x_s2'}
    # A bag removed: its verdict goes; a new bag under that name is judged, not trusted.
    import shutil
    shutil.rmtree(folder / 'x_s2')
    record_session(folder / 'x_s2', hand, 'palm_center', 'flat', 0, 20.0, 4, _Silent())
    records = Campaign(folder).check(hand, kinematics)
    assert {(r.bag, r.array) for r in records} >= {('x_s2', 'palm_center')}


def test_the_default_limits_pass_a_paper_session_and_refuse_a_timid_one(tmp_path):
    from tacforce_ros.experiments.calibration_data import simulate_calibration
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.recording.campaign import session_coverage
    hand = load_hand()
    kinematics = HandKinematics(hand.urdf_path)
    full = simulate_calibration(hand, kinematics, 'calibration_index_tip_flat', 1, 100.0)
    assert session_coverage(full).ok, session_coverage(full)
    timid = tmp_path / 'timid.yaml'
    timid.write_text('extends: calibration_index_middle_flat\n'
                     'operator: {normal_force: [0.3, 1.0], shear_ratio: 0.0}\n')
    coverage = session_coverage(simulate_calibration(hand, kinematics, str(timid), 1, 100.0))
    assert [p.split(':')[0] for p in coverage.problems] == [
        'press harder', 'vary the push direction']


class _Silent:
    def update(self, n):
        pass


def test_train_refuses_a_campaign_with_nothing_that_counts(tmp_path, capsys):
    folder = tmp_path / 'c'
    make(folder)
    assert train.main([str(folder), '--out', str(tmp_path / 'models')]) == 2
    assert 'has no bag that counts yet' in capsys.readouterr().err
    assert not list((tmp_path / 'models').glob('*.npz'))


def test_the_live_view_judges_the_samples_as_the_bag_is_judged_and_says_what_is_missing():
    """LiveCoverage takes the recorder's samples one by one (F/T force in its frame, joints) and
    judges them with coverage_of, as session_coverage judges the session's dataset."""
    import numpy as np
    from tacforce_ros.experiments.calibration_data import simulate_calibration
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.recording.campaign import LiveCoverage, coverage_of, coverage_view
    hand = load_hand()
    kinematics = HandKinematics(hand.urdf_path)
    array = hand.array('index_tip')
    data = simulate_calibration(hand, kinematics, 'calibration_index_tip_flat', 1, 30.0)
    rng = np.random.default_rng(0)
    live = LiveCoverage(kinematics, hand.ft_frame, array.frame_id)
    assert live.coverage() is None
    for x, f in zip(data.X, data.F):
        q = np.zeros(16)
        q[kinematics.finger_joints('index')] = rng.uniform(0.0, 0.8, 4)
        # The F/T reading that, at this pose, is f in the array frame.
        live.add(x, kinematics.rotation_between(q, array.frame_id, hand.ft_frame) @ f, q)
    whole = coverage_of(data.F, data.X)
    got = live.coverage()
    assert got.samples == len(data.X) and got.sectors == whole.sectors
    assert got.rests == whole.rests and abs(got.peak_force - whole.peak_force) < 1e-9
    text = coverage_view('index_tip on flat', got, live.limits, 30.0, 100.0)
    assert '[#########' in text and '30 / 100 s' in text and 'of 8 directions' in text
    assert text.splitlines()[-1] == '  so far: ' + (
        'enough' if got.ok else '; '.join(got.problems))
    timid = coverage_of(data.F * 0.1, data.X)
    assert 'press harder' in coverage_view('t', timid, live.limits, 5.0)
    assert 'waiting for synchronised samples' in coverage_view('t', None, live.limits, 0.0)


def test_a_budget_plan_gives_each_kind_its_session_length_and_reads_back(tmp_path, capsys):
    rows = [{'array': a, 'kind': kind, 'seconds': s, 'e_hat_n': e, 'way': 'shared-kind'}
            for kind, a, points in (('phalanx', 'p', ((60, 0.40), (200, 0.30))),
                                    ('fingertip', 't', ((60, 0.90), (200, 0.50))))
            for s, e in points]
    # The main job's report.json holds its kind curves under budget_campaign.
    curves = tmp_path / 'report.json'
    curves.write_text(json.dumps({'budget_campaign': {'kind_curve_rows': rows},
                                  'run': {'code_version': 'abc1234'}}))
    pads, tips = ['index_middle', 'middle_middle', 'ring_middle'], ['index_tip', 'middle_tip',
                                                                    'ring_tip']
    arrays = pads + tips
    folder = tmp_path / 'c'
    assert campaign_tool.main(['plan', str(folder), '--arrays', *arrays, '--plates', 'flat',
                               'edge', '--budget', '9m', '--curves', str(curves),
                               '--min-session', '30']) == 0
    out = capsys.readouterr().out
    plan = Campaign(folder).plan
    assert plan.sessions == 1 and plan.pressing_s() <= 0.95 * 540.0
    assert {plan.session_seconds(a) for a in tips} == {plan.session_seconds('index_tip')}
    assert {plan.session_seconds(a) for a in pads} == {plan.session_seconds('index_middle')}
    assert plan.session_seconds('index_tip') > plan.session_seconds('index_middle') >= 30.0
    assert plan.budget['budget_s'] == 540.0 and plan.budget['reserve'] == 0.05
    assert 'report.json at abc1234' in out and 'shared models' in out
    operator = plan.pressing_s() + 12 * 20.0 + 2 * 120.0
    assert plan.duration_s() == pytest.approx(operator)
    assert f'about {operator / 3600:.1f} h of operator time' in out
    # A campaign plan of before budgets (no durations) still reads, every session alike.
    old = tmp_path / 'old'
    make(old)
    text = (old / 'campaign.yaml').read_text()
    assert 'durations' not in text and 'budget' not in text
    assert Campaign(old).plan.session_seconds('palm_center') == 20.0
    # Status gives each array's expected error from the bags it trains on.
    hand, kinematics = campaign_tool._hand_and_kinematics('right')
    campaign = Campaign(folder)
    records = campaign.check(hand, kinematics)
    lines = campaign_tool.expected_lines(campaign, records, hand)
    assert len(lines) == 2 + len(arrays) and all('none yet' in line for line in lines[2:])
    from tacforce_ros.recording.campaign import SessionRecord
    for name in ('x_s9', 'index_tip_flat_s0'):
        (folder / name).mkdir()
    pressed = [SessionRecord(name, 'index_tip', 'flat', {'samples': 10000, 'problems': []})
               for name in ('index_tip_flat_s0', 'x_s9')]       # x_s9: past the plan's one
    line = campaign_tool.expected_lines(campaign, pressed, hand)[2 + arrays.index('index_tip')]
    expected = 0.9 * (100 / 60) ** (math.log(0.5 / 0.9) / math.log(200 / 60))     # log-log
    planned = 2 * plan.session_seconds('index_tip')
    assert f'| index_tip | fingertip | 100 | {planned:.0f} | {expected:.3f} |' in line
    pressed[0].coverage['samples'] = 50000                          # 500 s: past the curve
    line = campaign_tool.expected_lines(campaign, pressed, hand)[2 + arrays.index('index_tip')]
    assert '<= 0.500 (beyond the curve)' in line


PALMS = ('palm_index_side', 'palm_center', 'palm_ring_side')


@pytest.mark.parametrize('argv, message', [
    (['--budget', '60m'], '--budget and --curves go together'),
    (['--budget', 'an hour', '--curves', 'x.json'], "budget 'an hour'"),
    (['--budget', '1m', '--curves', 'CURVES'], 'needs 5 min or more'),
    (['--budget', '60m', '--curves', 'missing.json'], 'no learning-curve rows'),
    (['--budget', '60m', '--curves', 'CURVES', '--seconds', '50'], 'leave out'),
    (['--min-session', '30'], 'go with --budget'),
    (['--budget', '60m', '--curves', 'CURVES', '--arrays', *ARRAYS], 'three or more arrays')])
def test_a_bad_budget_is_refused_before_a_plan_is_written(tmp_path, capsys, argv, message):
    curves = tmp_path / 'curves.json'
    curves.write_text(json.dumps({'rows': [{'array': a, 'kind': k, 'seconds': 100.0,
                                            'e_hat_n': 0.3, 'way': 'shared-kind'}
                                           for a, k in (('p', 'phalanx'), ('q', 'palm'))]}))
    argv = [str(curves) if a == 'CURVES' else a for a in argv]
    folder = tmp_path / 'c'
    try:
        code = campaign_tool.main(['plan', str(folder), '--arrays', *PALMS, *argv])
    except SystemExit as exc:       # argparse's refusals
        code = exc.code
    assert code == 2 and message in capsys.readouterr().err
    assert not (folder / 'campaign.yaml').exists()


def test_pooled_curves_plan_a_budget_for_fewer_than_three_arrays_of_a_kind(tmp_path, capsys):
    """A lab that re-covers one pad: with kind curves made with the other hand's pool, its
    shared model has arrays enough, and the plan says to train with the pool."""
    curves = tmp_path / 'curves.json'
    curves.write_text(json.dumps({'rows': [{'array': a, 'kind': k, 'seconds': s, 'e_hat_n': e,
                                            'way': 'shared-kind+pool'}
                                           for a, k in (('p', 'phalanx'), ('q', 'palm'))
                                           for s, e in ((40.0, 0.6), (120.0, 0.4))]}))
    folder = tmp_path / 'c'
    assert campaign_tool.main(['plan', str(folder), '--arrays', *ARRAYS, '--plates', *PLATES,
                               '--budget', '5m', '--curves', str(curves)]) == 0
    assert '--pool POOL' in capsys.readouterr().out
    assert Campaign(folder).plan.budget['expected']['pooled'] is True
    train.main([str(folder), '--out', str(tmp_path / 'models')])   # nothing pressed yet
    assert 'planned on kind curves with the other hand\'s pool' in capsys.readouterr().err


def test_a_short_session_is_asked_for_directions_and_rests_in_proportion():
    limits = CoverageLimits()
    assert limits.for_session(100.0) == limits.for_session(400.0) == limits
    short = limits.for_session(20.0)
    assert (short.min_peak_force, short.min_shear_sectors, short.min_rests) == (2.0, 2, 1)
    assert limits.for_session(1.0).min_shear_sectors == limits.for_session(1.0).min_rests == 1
    plan = CampaignPlan(hand_side='right', arrays=ARRAYS, plates=PLATES, sessions=1,
                        seconds=100.0, durations={'index_middle': 40.0})
    assert plan.limits_for('index_middle') == limits.for_session(40.0)
    assert plan.limits_for('palm_center') == limits
    with pytest.raises(CampaignError, match='durations'):
        CampaignPlan(hand_side='right', arrays=ARRAYS, plates=PLATES, sessions=1,
                     seconds=100.0, durations={'thumb_tip': 40.0})


def test_a_budget_campaign_runs_in_the_simulator_and_trains_shared_models(tmp_path, capsys):
    """plan --budget, run --sim, status, train --shared: the palm pads (three of a kind) on two
    plates."""
    curves = tmp_path / 'curves.json'
    curves.write_text(json.dumps({'rows': [
        {'array': 'a', 'kind': 'palm', 'seconds': s, 'e_hat_n': e, 'way': 'shared-kind'}
        for s, e in ((40.0, 0.6), (120.0, 0.4))]}))
    folder = tmp_path / 'c'
    palms = ['palm_index_side', 'palm_center', 'palm_ring_side']
    assert campaign_tool.main(['plan', str(folder), '--arrays', *palms, '--plates', *PLATES,
                               '--budget', '2.5m', '--curves', str(curves)]) == 0
    plan = Campaign(folder).plan
    assert plan.pressing_s() <= 150.0 and plan.session_seconds('palm_center') >= 20.0
    assert campaign_tool.main(['run', str(folder), '--sim']) == 0
    out = capsys.readouterr().out
    assert '6 of 6 sessions done' in out
    assert campaign_tool.main(['status', str(folder)]) == 0
    status = capsys.readouterr().out
    pressed = f'| palm_center | palm | {2 * plan.session_seconds("palm_center"):.0f} |'
    assert pressed in status and 'none yet' not in status
    models = tmp_path / 'models'
    assert train.main([str(folder), '--out', str(models)]) == 0     # --shared, implied
    assert 'a campaign with a budget' in capsys.readouterr().err
    report = json.loads((models / 'report.json').read_text())
    assert sorted(m['array'] for m in report['models']) == sorted(palms)
    assert {m['way'] for m in report['models']} <= {'adapted', 'shared'}
    assert all(m['own_seconds'] == pytest.approx(2 * plan.session_seconds(m['array']), abs=1.0)
               for m in report['models'])
