"""The mirror hand's recordings in this hand's layout (estimation/mirror.py): which arrays are
each other's mirror image, the reflection itself, the simulated hands agreeing with it, and the
pool it feeds (kind_folds, kind_curve, `learning_curve --pool`, `train --pool`)."""
import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.learning_curve import kind_curve, kind_folds
from tacforce_ros.estimation.mirror import (MirrorError, check_mirror, mirrored, reflect,
                                            to_layout)
from tacforce_ros.estimation.shared_model import shared_folds
from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.hand.description import hand_config, load_hand

HYPER = {'lam': 1e-3, 'lambda_grid': None}
PLATES = ('flat', 'spherical')


@pytest.fixture(scope='module')
def hands():
    return load_hand(hand_config('right')), load_hand(hand_config('left'))


def test_every_left_array_is_its_right_namesake_reflected(hands):
    right, left = hands
    for array in right.arrays:
        check_mirror(left.array(array.name), array)
        check_mirror(array, left.array(array.name))


def test_what_is_not_a_mirror_image_is_refused(hands):
    right, left = hands
    with pytest.raises(MirrorError, match='both of the right hand'):
        check_mirror(right.array('palm_center'), right.array('palm_ring_side'))
    with pytest.raises(MirrorError, match='not of the kind'):
        check_mirror(left.array('index_tip'), right.array('index_distal'))
    # A left module described as the right one, unreflected: its taxels are elsewhere.
    unreflected = dataclasses.replace(left.array('index_tip'),
                                      positions=right.array('index_tip').positions,
                                      rotations=right.array('index_tip').rotations)
    with pytest.raises(MirrorError, match='does not mirror the module'):
        check_mirror(unreflected, right.array('index_tip'))
    data = synthetic_dataset(right.array('palm_center'), PLATES, seconds=2.0)
    with pytest.raises(MirrorError, match="right hand's palm_center, not of the left"):
        mirrored(data, left.array('palm_center'), right.array('palm_center'))
    with pytest.raises(MirrorError, match='layout'):
        to_layout(data, right.array('palm_center'), right.array('index_distal'))


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_the_reflection_negates_y_alone_and_undoes_itself(n, taxels, seed):
    rng = np.random.default_rng(seed)
    X, F = rng.normal(0.0, 1e3, (n, taxels, 3)), rng.normal(0.0, 2.0, (n, 3))
    X1, F1 = reflect(X, F)
    np.testing.assert_array_equal(X1[..., [0, 2]], X[..., [0, 2]])
    np.testing.assert_array_equal(X1[..., 1], -X[..., 1])
    np.testing.assert_array_equal(F1 * [1, -1, 1], F)
    X2, F2 = reflect(X1, F1)
    assert np.array_equal(X2, X) and np.array_equal(F2, F)
    with pytest.raises(ValueError, match=r'\(N, n, 3\)'):
        reflect(X.reshape(n, -1), F)


def test_a_mirrored_recording_is_the_other_hands_layout(hands):
    right, left = hands
    data = synthetic_dataset(left.array('palm_center'), PLATES, seconds=2.0)
    as_right = mirrored(data, left.array('palm_center'), right.array('palm_center'))
    assert (as_right.array, as_right.hand_side) == ('palm_center', 'right')
    np.testing.assert_array_equal(as_right.X[..., 1], -data.X[..., 1])
    np.testing.assert_array_equal(as_right.F[:, 1], -data.F[:, 1])
    same = to_layout(data, left.array('palm_center'), left.array('palm_center'))
    assert same.X is data.X


@pytest.mark.parametrize('name', ['palm_center', 'index_tip'])
def test_the_simulated_left_array_reads_as_the_right_one_once_reflected(tmp_path, hands, name):
    """A model of the right hand's array (simulated magnetic skin) reads a second, left hand's
    (another sensor seed) better reflected than as recorded: a flat pad (taxel frames the
    identity) and a curved fingertip (taxel frames reflected too)."""
    from tacforce_ros.estimation.metrics import error_stats
    from tacforce_ros.estimation.training import fit_bundles
    from tacforce_ros.experiments.calibration_data import simulate_calibration
    from tacforce_ros.experiments.settings import skin_scene
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.sim.scene import calibration_scene_name, load_scene

    recorded = {}
    for hand in hands:
        kinematics = HandKinematics(hand.urdf_path)
        scene = load_scene(skin_scene(tmp_path, calibration_scene_name(name, 'flat'),
                                      'magnetic'))
        scene = dataclasses.replace(scene, sensor_seed=0 if hand.side == 'right' else 1)
        recorded[hand.side] = simulate_calibration(hand, kinematics, scene, 3, 30.0)
    X, F, _ = recorded['right'].without_offsets(force_threshold=0.3)
    (bundle,) = fit_bundles(hands[0].array(name), 'M3-lambda', {'lam': 33.0,
                                                                 'lambda_grid': None},
                            [(X, F, recorded['right'].plates)])
    left = recorded['left']
    errors = {}
    for way, data in (('as recorded', left), ('reflected', mirrored(
            left, hands[1].array(name), hands[0].array(name)))):
        X, F, _ = data.without_offsets(force_threshold=0.3)
        errors[way] = error_stats(F, bundle.predict(X)).e_hat_mean
    print(f'\nright {name} model on the left one: {errors}')
    assert errors['reflected'] < 0.8 * errors['as recorded']


def _kind(hand, names, seed, seconds=3.0):
    return {n: (hand.array(n), synthetic_dataset(hand.array(n), PLATES, seconds=seconds,
                                                  seed=seed + k)) for k, n in enumerate(names)}


def test_the_pool_joins_every_shared_model_and_is_not_judged(hands):
    right, left = hands
    pads = ('palm_index_side', 'palm_center', 'palm_ring_side')
    arrays = _kind(right, pads[:1], 40)
    pool = {f'pool:{n}': mirrored(d, left.array(n), right.array(n))
            for n, (_, d) in _kind(left, pads, 50).items()}
    prepared = {n: d.without_offsets()[:2] + (d.plates,) for n, (_, d) in arrays.items()}
    pooled = {n: d.without_offsets()[:2] + (d.plates,) for n, d in pool.items()}
    # One array of the kind with three pooled: its model is the pool's, adapted to it.
    results = kind_folds({n: a for n, (a, _) in arrays.items()}, 'M3-lambda', HYPER, prepared,
                         prepared, pooled)
    assert list(results) == ['palm_index_side']
    own = prepared['palm_index_side']
    (expected,) = shared_folds(right.array('palm_index_side'), 'M3-lambda', HYPER, own,
                               [np.ones(len(own[1]), bool)], pooled, held_out=own)
    assert results['palm_index_side'].summary()['e_hat_mean'] == pytest.approx(
        expected.summary()['e_hat_mean'], rel=1e-9)
    rows = kind_curve(arrays, 'M3-lambda', 'M3-lambda', HYPER, (2.0,), pool=pool)
    assert [(r['array'], r['way']) for r in rows] == [('palm_index_side', 'shared-kind+pool')]
    with pytest.raises(ValueError, match='three or more arrays'):
        kind_curve(arrays, 'M3-lambda', 'M3-lambda', HYPER, (2.0,),
                   pool=dict(list(pool.items())[:1]))
    with pytest.raises(ValueError, match='also arrays of the campaign'):
        kind_folds({n: a for n, (a, _) in arrays.items()}, 'M3-lambda', HYPER, prepared,
                   prepared, {'palm_index_side': pooled['pool:palm_index_side'], **pooled})


def test_the_commands_take_the_mirror_hands_calibration_as_a_pool(tmp_path, hands, capsys):
    from tacforce_ros.tools import learning_curve, train
    right, left = hands
    pads = ('palm_index_side', 'palm_center', 'palm_ring_side')
    mine = [d.save(tmp_path / f'right_{n}.npz') for n, (_, d) in _kind(right, pads[:1], 60,
                                                                       6.0).items()]
    theirs = [d.save(tmp_path / f'left_{n}.npz') for n, (_, d) in _kind(left, pads, 70,
                                                                         6.0).items()]
    out = tmp_path / 'curve'
    assert learning_curve.main([*map(str, mine), '--out', str(out), '--kind-curve', '--seconds',
                                '10', '--static-force', '0.1', '--pool', *map(str, theirs)]) == 0
    doc = json.loads((out / 'learning_curve.json').read_text())
    assert [(r['array'], r['way']) for r in doc['rows']] == [
        ('palm_index_side', 'shared-kind+pool')]
    with pytest.raises(SystemExit):
        learning_curve.main([*map(str, mine), '--out', str(out), '--pool', *map(str, theirs)])
    models = tmp_path / 'models'
    assert train.main([*map(str, mine), '--out', str(models), '--shared', '--static-force',
                       '0.1', '--pool', *map(str, theirs)]) == 0
    report = json.loads((models / 'report.json').read_text())
    (entry,) = report['models']
    assert entry['way'] in ('shared', 'adapted')
    assert entry['shared_from'] == sorted(f'pool:{n}' for n in pads)
    assert report['pool'] == [str(p) for p in theirs]
    from tacforce_ros.estimation.model_io import load_model
    provenance = load_model(models / entry['file'], right.array('palm_index_side')).provenance
    assert provenance['pool'] == sorted(map(str, theirs))
    assert '(3 of the pool)' in (models / 'report.md').read_text()
    with pytest.raises(SystemExit):
        train.main([*map(str, mine), '--out', str(models), '--pool', *map(str, theirs)])
    with pytest.raises(SystemExit):     # an input is not its own pool
        train.main([*map(str, mine), '--out', str(models), '--shared', '--pool', str(mine[0]),
                    *map(str, theirs)])
    # A pooled array pressed on fewer plates than the inputs: refused, saying which.
    short = synthetic_dataset(left.array('palm_center'), PLATES[:1], seconds=6.0, seed=80)
    theirs[1] = short.save(tmp_path / 'left_short.npz')
    assert train.main([*map(str, mine), '--out', str(models), '--shared', '--static-force',
                       '0.1', '--pool', *map(str, theirs)]) == 2
    assert "no data on the plates ['spherical']" in capsys.readouterr().err


def test_a_budget_plans_on_pooled_kind_curves_but_not_on_a_mix():
    from tacforce_ros.recording.budget import BudgetError, ExpectedError
    rows = [{'kind': 'palm', 'seconds': s, 'e_hat_n': e, 'way': 'shared-kind+pool'}
            for s, e in ((100.0, 0.35), (400.0, 0.3))]
    assert ExpectedError.from_rows(rows).curves == {'palm': ((100.0, 0.35), (400.0, 0.3))}
    with pytest.raises(BudgetError, match='with and without'):
        ExpectedError.from_rows(rows + [{**rows[0], 'way': 'shared-kind'}])
