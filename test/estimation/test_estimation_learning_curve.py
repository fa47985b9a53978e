"""Learning curves (estimation/learning_curve.py): the cut an operator records, and the held-out
error of models trained on it."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.dataset import concatenate
from tacforce_ros.estimation.learning_curve import (first_seconds, learning_curve,
                                                    recorded_seconds)
from tacforce_ros.estimation.synthetic import synthetic_dataset

M3 = {'M3-lambda': ('M3-lambda', {'lam': 1e-3, 'lambda_grid': None})}


@pytest.fixture(scope='module')
def two_sessions(tip):
    """Two sessions per plate (8 s then 6 s), plates in turn, as a campaign records them."""
    first = synthetic_dataset(tip, seconds=8.0, seed=1)
    second = synthetic_dataset(tip, seconds=6.0, seed=2)
    return concatenate([first, second])


@settings(max_examples=40, deadline=None)
@given(per_plate=st.floats(0.05, 20.0))
def test_a_cut_keeps_each_plates_first_seconds_in_recording_order(two_sessions, per_plate):
    cut = first_seconds(two_sessions, per_plate)
    for plate in two_sessions.plate_names():
        on = cut.plates == plate
        kept = recorded_seconds(cut.__class__(
            array=cut.array, X=cut.X[on], F=cut.F[on], plates=cut.plates[on],
            sessions=cut.sessions[on], time=cut.time[on])) if on.any() else 0.0
        # As much as asked, to a sample, but never more than was recorded (14 s per plate).
        assert kept == pytest.approx(min(per_plate, 14.0), abs=0.011)
        sessions = list(dict.fromkeys(cut.sessions[on].tolist()))
        recorded = list(dict.fromkeys(two_sessions.sessions[two_sessions.plates == plate]
                                      .tolist()))
        assert sessions == recorded[:len(sessions)]          # the earlier session first
        for session in sessions[:-1]:                          # whole but for the last
            assert (cut.sessions == session).sum() == (two_sessions.sessions == session).sum()
        last = cut.time[cut.sessions == sessions[-1]]
        full = two_sessions.time[two_sessions.sessions == sessions[-1]]
        assert np.array_equal(last, full[:last.size])         # from its start


def test_the_full_recording_gives_table_is_error_and_less_data_a_larger_one(tip, two_sessions):
    rows = learning_curve(tip, two_sessions, M3, seconds=(5.0, 70.0), force_threshold=0.1)
    assert [(r['seconds'], r['model']) for r in rows] == [(5.0, 'M3-lambda'),
                                                         (70.0, 'M3-lambda')]
    small, full = rows
    assert full['recorded_s'] == pytest.approx(recorded_seconds(two_sessions), abs=0.05)
    X, F, _ = two_sessions.without_offsets(force_threshold=0.1)
    table_i = cross_validate(tip, 'M3-lambda', M3['M3-lambda'][1], X, F,
                             two_sessions.plates).summary()['e_hat_mean']
    assert full['e_hat_n'] == pytest.approx(table_i, rel=1e-9)
    assert small['recorded_s'] == pytest.approx(5.0, abs=0.05)
    assert small['samples'] < 0.1 * full['samples']
    assert small['e_hat_n'] > full['e_hat_n']


def test_a_cut_trains_on_its_own_rows_with_its_sessions_offsets(tip, two_sessions):
    """The rows of a cut, offsets taken from each whole session's rest: a cut of 0.05 s per plate
    (5 samples, no rest in it) still trains."""
    rows = learning_curve(tip, two_sessions, M3, seconds=(0.25,), force_threshold=0.1)
    assert rows[0]['samples'] == 25 and np.isfinite(rows[0]['e_hat_n'])


def test_the_command_writes_the_curve_of_each_array_from_datasets(tmp_path, tip, phalanx,
                                                                 two_sessions):
    """learning_curve on dataset files: JSON rows per array, model and point, the table and
    the figure; an array the inputs lack is refused with the arrays they have."""
    import json

    from tacforce_ros.tools.learning_curve import main
    inputs = [two_sessions.save(tmp_path / 'tip.npz'),
              synthetic_dataset(phalanx, seconds=8.0, seed=3).save(tmp_path / 'pad.npz')]
    out = tmp_path / 'out'
    assert main([*map(str, inputs), '--out', str(out), '--kinds', 'M3-lambda',
                 '--seconds', '10', '1000', '--static-force', '0.1']) == 0
    rows = json.loads((out / 'learning_curve.json').read_text())['rows']
    assert {(r['array'], r['seconds']) for r in rows} == {
        (a, s) for a in ('index_tip', 'index_middle') for s in (10.0, 1000.0)}
    assert all(r['model'] == 'M3-lambda' and r['way'] == 'own' for r in rows)
    pad = [r for r in rows if r['array'] == 'index_middle' and r['seconds'] == 1000.0][0]
    assert pad['recorded_s'] == pytest.approx(40.0, abs=0.1)       # 5 plates x 8 s
    table = (out / 'learning_curve.md').read_text()
    assert '| index_middle | M3-lambda | own |' in table and '(40 s)' in table, table
    assert (out / 'learning_curve.png').stat().st_size > 0
    assert main([*map(str, inputs), '--out', str(out), '--arrays', 'thumb_tip']) == 1


def test_the_command_draws_kind_curves_a_budget_plan_reads(tmp_path, hand):
    """learning_curve --kind-curve: rows per array and point of each kind with three or more
    arrays in the inputs, which `campaign plan --budget --curves` plans on; two arrays of a
    kind are refused."""
    import json

    from tacforce_ros.recording.budget import ExpectedError
    from tacforce_ros.tools.learning_curve import main
    pads = ('index_middle', 'middle_middle', 'ring_middle')
    inputs = [synthetic_dataset(hand.array(name), seconds=6.0, seed=10 + k).save(
        tmp_path / f'{name}.npz') for k, name in enumerate(pads)]
    out = tmp_path / 'out'
    assert main([*map(str, inputs), '--out', str(out), '--kind-curve', '--seconds', '10', '30',
                 '--static-force', '0.1']) == 0
    doc = json.loads((out / 'learning_curve.json').read_text())
    assert {(r['array'], r['seconds'], r['way'], r['kind']) for r in doc['rows']} == {
        (a, s, 'shared-kind', 'phalanx') for a in pads for s in (10.0, 30.0)}
    curves = ExpectedError.from_rows(doc['rows'])
    assert [s for s, _ in curves.curves['phalanx']] == [10.0, 30.0]
    assert (out / 'learning_curve.png').stat().st_size > 0
    assert main([*map(str, inputs[:2]), '--out', str(out), '--kind-curve']) == 1
