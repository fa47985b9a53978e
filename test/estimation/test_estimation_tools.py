"""Datasets, calibration bags -> dataset, and the train / bench command-line tools."""
import dataclasses
import json
import subprocess

import numpy as np
import pytest

from tacforce_ros import bagio, topics
from tacforce_ros.estimation.bag_dataset import dataset_from_bag
from tacforce_ros.estimation.dataset import CalibrationDataset, DatasetError, concatenate
from tacforce_ros.estimation.model_io import load_model, read_header
from tacforce_ros.estimation.model_set import load_model_set, model_files
from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.paths import config_dir
from tacforce_ros.tools import train
from tacforce_ros.benchmarks import bench, bench_train
from tacforce_ros.bringup.processes import executable


def test_synthetic_is_deterministic_and_labelled(phalanx):
    a = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=5.0, seed=3)
    b = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=5.0, seed=3)
    c = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=5.0, seed=4)
    np.testing.assert_array_equal(a.X, b.X)
    assert not np.array_equal(a.X, c.X)
    assert a.source == 'synthetic' and a.plate_names() == ['flat', 'edge']
    assert a.X.min() >= 0.0 and a.X.max() <= 65535.0


def test_dataset_file_round_trip_and_refusals(phalanx, tmp_path):
    data = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=4.0, seed=1)
    loaded = CalibrationDataset.load(data.save(tmp_path / 'd.npz'))
    np.testing.assert_array_equal(loaded.X, data.X)
    np.testing.assert_array_equal(loaded.plates, data.plates)
    assert loaded.array == data.array and loaded.source == 'synthetic'
    with pytest.raises(DatasetError, match='expected'):
        CalibrationDataset(array='x', X=data.X, F=data.F[:-1], plates=data.plates,
                           sessions=data.sessions, time=data.time)
    (tmp_path / 'junk.npz').write_bytes(b'junk')
    with pytest.raises(DatasetError, match='not a readable dataset'):
        CalibrationDataset.load(tmp_path / 'junk.npz')


def test_concatenate_keeps_sessions_distinct(phalanx, tip):
    a = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=4.0, seed=1)
    joined = concatenate([a, a])
    assert np.unique(joined.sessions).size == 4
    with pytest.raises(DatasetError, match='different arrays'):
        concatenate([a, synthetic_dataset(tip, plates=('flat',), seconds=4.0, seed=1)])


def write_bag(path, hand, array, data, rows, q, kinematics, plate):
    """Calibration bag of `array` from synthetic rows: tactile at 100 Hz, wrench in {F} at
    100 Hz (offset by half a period), joints at 50 Hz; one malformed tactile frame."""
    rotation = kinematics.rotation_between(q, hand.ft_frame, array.frame_id)   # R^0_F
    others = hand.merge([np.full((a.n_taxels, 3), 20000.0) for a in hand.arrays])
    meta = bagio.session_metadata(array=array.name, plate=plate, source='sim', seed=0,
                                  hand_side=hand.side)
    t0 = 1_700_000_000 * 10**9
    with bagio.CalibrationBagWriter(path, meta) as writer:
        for i, row in enumerate(rows):
            stamp = t0 + i * 10_000_000
            counts = others.copy()
            counts[array.flat_indices] = data.X[row]
            msg = bagio.tactile_hand(stamp, hand, np.round(counts), None, stamp * 1e-9, i)
            if i == 7:
                msg.arrays[hand.index(array.name)].x = msg.arrays[hand.index(array.name)].x[:3]
            writer.write(topics.TOPIC_TACTILE, stamp, msg)
            force_f = rotation.T @ data.F[row]          # what the F/T sensor measures
            writer.write(topics.TOPIC_WRENCH, stamp + 5_000_000, bagio.wrench_stamped(
                stamp + 5_000_000, hand.ft_frame, [*force_f, 0.0, 0.0, 0.0]))
            if i % 2 == 0:
                writer.write(topics.TOPIC_JOINTS, stamp, bagio.joint_state(
                    stamp, kinematics.joint_names, q))


@pytest.fixture(scope='module')
def bags(hand, tmp_path_factory):
    array = hand.array('index_middle')
    kinematics = HandKinematics(hand.urdf_path)
    q = np.zeros(16)
    q[1], q[2] = 0.4, 0.3           # bent index finger: R^0_F is not the identity
    data = synthetic_dataset(array, plates=('flat', 'edge', 'button'), seconds=8.0, seed=5)
    root = tmp_path_factory.mktemp('bags')
    paths = []
    for plate in data.plate_names():
        rows = np.flatnonzero(data.plates == plate)
        path = root / f'bag_{plate}'
        write_bag(path, hand, array, data, rows, q, kinematics, plate)
        paths.append(path)
    return paths, data, array, kinematics


def test_bag_to_dataset_recovers_counts_and_projected_force(hand, bags):
    paths, data, array, kinematics = bags
    dataset, dropped = dataset_from_bag(paths[0], hand, kinematics)
    assert dropped == 1 and dataset.array == array.name and dataset.source == 'sim'
    assert set(dataset.plates) == {'flat'}
    truth = data.F[data.plates == 'flat']
    rows = np.round(dataset.time / 0.01).astype(int) + 1     # first tactile frame precedes F/T
    assert 7 not in rows                                    # the malformed frame was dropped
    # the wrench of row r is stamped half a period after the tactile frame r
    expected = 0.5 * (truth[rows - 1] + truth[rows])
    core = slice(50, -50)                                   # away from the filter's edges
    err = np.abs(dataset.F[core] - expected[core]).max()
    assert err < 0.02, err          # projection with R^0_F(t) undoes the {F} rotation
    raw = data.X[data.plates == 'flat'][rows]
    assert np.abs(dataset.X[core] - raw[core]).max() < 5.0   # counts survive, low-passed


def test_train_from_bags_writes_loadable_models_and_report(hand, bags, tmp_path):
    paths, _, array, _ = bags
    out = tmp_path / 'models'
    code = train.main([*map(str, paths), '--out', str(out), '--kinds', 'M1', 'M3-lambda',
                       '--lambda-cv', '--save-dataset'])
    assert code == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['dropped_messages'] == 3
    assert [m['kind'] for m in report['models']] == ['M1', 'M3-lambda']
    cv = report['models'][1]['cross_validation']
    assert cv['folds'] == 3 and cv['e_hat_mean'] < 0.5
    bundle = load_model(out / 'index_middle_M3-lambda.npz', array)
    assert bundle.provenance['plates'] == ['flat', 'edge', 'button']
    assert bundle.provenance['metrics']['folds'] == 3
    assert (out / 'report.md').read_text().count('index_middle') >= 2
    assert '**flat phalanx pads** (1)' in (out / 'report.md').read_text()
    # M1's normal input per newton, per plate of the bags, once per array
    gains = report['normal_input_per_newton']['index_middle']
    assert sorted(gains) == ['button', 'edge', 'flat'] and all(np.isfinite(list(gains.values())))
    assert "M1's normal input per newton" in (out / 'report.md').read_text()
    assert CalibrationDataset.load(out / 'index_middle.npz').array == 'index_middle'
    for kind in ('M1', 'M3-lambda'):          # the estimator's model lists, one per kind
        models = load_model_set(out / f'models_{kind}.yaml', hand)
        assert [a.name for a in models.arrays] == ['index_middle'] and models.kinds == (kind,)
        assert (out / f'hand_{kind}.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_bags_train_the_hand_they_name(bags, tmp_path, capsys):
    """A left hand's bag trains the left hand's model (its own flat order and frames); bags of
    both hands, or a bag read with the other hand's description, are refused."""
    from tacforce_ros.hand.description import hand_config, load_hand
    right_paths, data, right_array, _ = bags
    left = load_hand(hand_config('left'))
    array = left.array(right_array.name)
    kinematics = HandKinematics(left.urdf_path)
    q = np.zeros(16)
    q[1], q[2] = 0.4, 0.3
    paths = []
    for plate in data.plate_names():
        paths.append(tmp_path / f'left_{plate}')
        write_bag(paths[-1], left, array, data, np.flatnonzero(data.plates == plate), q,
                  kinematics, plate)
    out = tmp_path / 'models'
    assert train.main([*map(str, paths), '--out', str(out), '--kinds', 'M3-lambda',
                       '--save-dataset']) == 0
    bundle = load_model(out / f'{array.name}_M3-lambda.npz', array)
    assert read_header(out / f'{array.name}_M3-lambda.npz')['hand_side'] == 'left'
    assert bundle.provenance['metrics']['e_hat_mean'] < 0.5
    # The dataset it saved says whose it is: trained again alone, it makes the left hand's model.
    saved = out / f'{array.name}.npz'
    assert CalibrationDataset.load(saved).hand_side == 'left'
    assert train.main([str(saved), '--out', str(tmp_path / 'again'), '--no-cv']) == 0
    assert read_header(tmp_path / 'again' / f'{array.name}_M3-lambda.npz')['hand_side'] == 'left'
    with pytest.raises(DatasetError, match='both hands'):
        concatenate([CalibrationDataset.load(saved), data])
    with pytest.raises(DatasetError, match="a bag of the left hand, read with the right"):
        dataset_from_bag(paths[0], load_hand(), HandKinematics(load_hand().urdf_path))
    assert train.main([str(paths[0]), str(right_paths[1]), '--out', str(tmp_path / 'o')]) == 2
    assert "more than one hand (['left', 'right'])" in capsys.readouterr().err


def test_train_shared_adapts_the_kinds_model_and_says_how_each_was_made(hand, tmp_path, capsys):
    """--shared: three phalanx pads share a model, each adapted to its own data; the lone
    fingertip is trained on its own. Provenance and report say which way, with how many seconds
    of the array's own data."""
    pads = ('index_middle', 'middle_middle', 'ring_middle')
    paths = [synthetic_dataset(hand.array(name), seconds=4.0, seed=k).save(tmp_path / f'{name}.npz')
             for k, name in enumerate((*pads, 'index_tip'))]
    out = tmp_path / 'models'
    assert train.main([*map(str, paths), '--out', str(out), '--shared']) == 0
    report = json.loads((out / 'report.json').read_text())
    ways = {m['array']: m['way'] for m in report['models']}
    assert ways['index_tip'] == 'own'
    assert all(ways[p] in ('adapted', 'shared') for p in pads), ways
    for name in pads:
        bundle = load_model(out / f'{name}_M3-lambda.npz', hand.array(name))
        assert bundle.provenance['way'] == ways[name]
        assert sorted(bundle.provenance['shared_from']) == sorted(set(pads) - {name})
        assert bundle.provenance['own_seconds'] == pytest.approx(20.0, abs=0.5)   # 5 x 4 s
        assert bundle.provenance['metrics']['folds'] == 5
    assert load_model(out / 'index_tip_M3-lambda.npz', hand.array('index_tip')).provenance[
        'own_seconds'] == pytest.approx(20.0, abs=0.5)
    md = (out / 'report.md').read_text()
    assert 'from 2 other arrays' in md and 'own data, 20 s of its own' in md
    # --arrays picks the models made, not the arrays the shared model learns from.
    one = tmp_path / 'one'
    assert train.main([*map(str, paths), '--out', str(one), '--shared', '--no-cv',
                       '--arrays', pads[0]]) == 0
    assert sorted(p.name for p in one.glob('*.npz')) == [f'{pads[0]}_M3-lambda.npz']
    assert sorted(load_model(one / f'{pads[0]}_M3-lambda.npz', hand.array(pads[0])).provenance[
        'shared_from']) == sorted(pads[1:])
    # An array not asked for, with no rest to take its offsets from, leaves the shared model only.
    pressed = CalibrationDataset.load(paths[2])
    shaken = pressed.F + np.random.default_rng(0).normal(0.0, 5.0, pressed.F.shape)
    paths[2] = dataclasses.replace(pressed, F=shaken).save(
        tmp_path / 'pressed.npz')
    paths.append(synthetic_dataset(hand.array('middle_distal'), seconds=4.0, seed=7).save(
        tmp_path / 'middle_distal.npz'))
    capsys.readouterr()
    assert train.main([*map(str, paths), '--out', str(one), '--shared', '--no-cv',
                       '--arrays', pads[0]]) == 0
    assert f'{pads[2]} left out' in capsys.readouterr().err
    assert sorted(load_model(one / f'{pads[0]}_M3-lambda.npz', hand.array(pads[0])).provenance[
        'shared_from']) == sorted([pads[1], 'middle_distal'])
    with pytest.raises(SystemExit):
        train.main([*map(str, paths), '--out', str(out), '--shared', '--kinds', 'M4'])
    assert '--shared adapts M3, M3-lambda with a fixed damping only, not M4' in \
        capsys.readouterr().err


def test_train_refuses_unknown_arrays_and_missing_inputs(phalanx, tmp_path, capsys):
    path = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=4.0, seed=1).save(
        tmp_path / 'd.npz')
    assert train.main([str(path), '--out', str(tmp_path / 'o'), '--arrays', 'index_tip']) == 2
    assert 'no data for arrays' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train.main([str(tmp_path / 'absent.npz'), '--out', str(tmp_path / 'o')])


def test_bench_synthetic_writes_json_table_and_plot(tmp_path):
    out = tmp_path / 'bench'
    shipped = config_dir() / 'models' / 'default.yaml'
    code = bench.main(['--synthetic', '--array', 'index_middle', '--seconds', '6',
                       '--models', 'M1', 'M3-lambda', '--repeats', '50', '--model-sets',
                       str(shipped), '--out', str(out)])
    assert code == 0
    result = json.loads((out / 'bench.json').read_text())
    assert [m['label'] for m in result['models']] == ['M1', 'M3-lambda']
    (shipped_row,) = result['model_sets']
    assert shipped_row['arrays'] == len(model_files(shipped))
    tick = shipped_row['full_hand_tick']
    assert 0.0 < tick['median_us'] <= tick['p99_us']
    for row in result['models']:
        for key in ('predict_one', 'batch_one', 'full_hand_tick', 'full_hand_tick_lowpass'):
            assert 0.0 < row[key]['median_us'] <= row[key]['p99_us']
        assert row['folds'] == 5 and row['train_seconds'] > 0.0
    assert result['lowpass']['cutoff_hz'] == 10.0
    assert result['lowpass']['group_delay_ms'] == pytest.approx(21.8, abs=0.05)
    assert (out / 'bench.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert '| M3-lambda |' in (out / 'bench.md').read_text()
    assert '(x ' in (out / 'bench.md').read_text()


def test_bench_train_times_both_ways_and_their_results_agree(tmp_path):
    out = tmp_path / 'bench_train'
    code = bench_train.main(['--array', 'index_middle', '--samples', '2000', '--epochs', '2',
                             '--models', 'M3', 'M4', '--out', str(out)])
    assert code == 0
    result = json.loads((out / 'bench_train.json').read_text())
    assert result['samples'] == 2000 and result['folds'] == 5
    assert result['device'] == 'cpu' and result['gpu'] is None
    for label in ('M3', 'M4'):
        row = result['models'][label]
        assert row['one_at_a_time']['seconds'] > 0 and row['together']['seconds'] > 0
        assert len(row['together']['e_hat_per_fold']) == 5
        assert row['e_hat_max_difference'] < 1e-4
    assert '| M4 |' in (out / 'bench_train.md').read_text()
    assert '(M4, M5, on cpu)' in (out / 'bench_train.md').read_text()


def test_bench_train_refuses_an_unwritable_output_before_training(tmp_path, capsys):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    with pytest.raises(SystemExit) as exc:
        bench_train.main(['--out', str(blocker / 'out')])
    assert exc.value.code == 2


@pytest.mark.parametrize('tool', ['train', 'bench', 'bench_train', 'campaign'])
def test_tools_have_help(tool):
    out = subprocess.run([str(executable(tool)), '--help'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and 'usage' in out.stdout


def test_train_reports_a_missing_static_segment(phalanx, tmp_path, capsys):
    path = synthetic_dataset(phalanx, plates=('flat', 'edge'), seconds=4.0, seed=1).save(
        tmp_path / 'd.npz')
    code = train.main([str(path), '--out', str(tmp_path / 'o'), '--kinds', 'M1', '--no-cv',
                       '--static-seconds', '30'])
    assert code == 2 and 'no static no-contact segment' in capsys.readouterr().err
    assert train.main([str(path), '--out', str(tmp_path / 'o'), '--kinds', 'M1',
                       '--no-cv']) == 0
