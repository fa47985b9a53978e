"""Estimator model lists: arrays without a model are skipped (the others estimate exactly as
their model files do), unknown arrays and broken entries are refused with the reason."""
import numpy as np
import pytest
import yaml

from tacforce_ros.estimation.model_io import load_model
from tacforce_ros.estimation.model_set import (ModelConfigError, load_model_set,
                                               write_synthetic_model_set)
from tacforce_ros.hand.description import load_hand


@pytest.fixture(scope='module')
def hand():
    return load_hand()


@pytest.fixture(scope='module')
def full_set(tmp_path_factory, hand):
    return write_synthetic_model_set(tmp_path_factory.mktemp('models'), hand)


def subset(full_set, names, tmp_path):
    models = yaml.safe_load(full_set.read_text())['models']
    path = tmp_path / 'subset.yaml'
    path.write_text(yaml.safe_dump({'models': {n: str(full_set.parent / models[n])
                                               for n in names}}))
    return path


def test_skipped_arrays_leave_the_others_unchanged(full_set, hand, tmp_path):
    names = ['index_tip', 'palm_center', 'thumb_distal']       # scattered over the flat order
    models = load_model_set(subset(full_set, names, tmp_path), hand)
    assert [a.name for a in models.arrays] == [a.name for a in hand.arrays if a.name in names]
    assert set(models.skipped) == {a.name for a in hand.arrays} - set(names)
    counts = np.random.default_rng(1).uniform(15000, 30000, (hand.n_taxels, 3))
    estimate = models.estimate(counts)
    for k, array in enumerate(models.arrays):
        bundle = load_model(full_set.parent / f'{array.name}_M3.npz', array)
        expected = bundle.predict(counts[array.flat_indices][None])[0]
        np.testing.assert_allclose(estimate.force[k], expected, rtol=1e-9, atol=1e-9)
    assert estimate.valid.all()


def test_tare_takes_full_hand_frames(full_set, hand, tmp_path):
    models = load_model_set(subset(full_set, ['index_tip', 'ring_middle'], tmp_path), hand)
    rest = np.random.default_rng(2).uniform(15000, 30000, (hand.n_taxels, 3))
    models.set_tare(np.repeat(rest[None], 5, axis=0))
    # At the tared rest the models see zero input: their output is the force mean (no contact).
    zero_input = models.estimate(rest).force
    shifted = models.estimate(rest + 50.0).force
    assert not np.allclose(zero_input, shifted)
    np.testing.assert_allclose(models.estimator.tare('index_tip'),
                               rest[hand.array('index_tip').flat_indices])


def test_a_saved_tare_is_loaded_as_it_was_and_a_wrong_one_is_refused(full_set, hand, tmp_path):
    """A restarted estimator takes the tare of its session instead of taring on a loaded array:
    the saved offsets come back exactly; a file for other arrays or with NaN is refused."""
    names = ['index_tip', 'ring_middle']
    models = load_model_set(subset(full_set, names, tmp_path), hand)
    rest = np.random.default_rng(3).uniform(15000, 30000, (hand.n_taxels, 3))
    models.set_tare(rest[None] + np.random.default_rng(4).normal(0, 20, (7, hand.n_taxels, 3)))
    models.save_tare(tmp_path / 'tare.npz')
    restarted = load_model_set(subset(full_set, names, tmp_path), hand)
    restarted.load_tare(tmp_path / 'tare.npz')
    for name in names:
        np.testing.assert_array_equal(restarted.estimator.tare(name), models.estimator.tare(name))
    np.testing.assert_array_equal(restarted.estimate(rest).force, models.estimate(rest).force)
    other = load_model_set(subset(full_set, ['index_tip', 'thumb_tip'], tmp_path), hand)
    with pytest.raises(ValueError, match='no tare for thumb_tip'):
        other.load_tare(tmp_path / 'tare.npz')
    np.savez(tmp_path / 'nan.npz', index_tip=np.full((hand.array('index_tip').n_taxels, 3),
                                                     np.nan), ring_middle=np.zeros((1, 3)))
    with pytest.raises(ValueError, match='not .* finite counts'):
        models.load_tare(tmp_path / 'nan.npz')
    with pytest.raises(FileNotFoundError):
        models.load_tare(tmp_path / 'absent.npz')


def test_whole_hand_set_reads_the_frame_as_is(full_set, hand):
    """Every array modelled: each estimate equals its model file, before and after a tare."""
    models = load_model_set(full_set, hand)
    assert models.skipped == () and len(models.arrays) == len(hand.arrays)
    rng = np.random.default_rng(3)
    rest = rng.uniform(15000, 30000, (hand.n_taxels, 3))
    pressed = rest + rng.normal(0.0, 200.0, rest.shape)
    bundles = [load_model(full_set.parent / f'{a.name}_M3.npz', a) for a in hand.arrays]
    for tare in (None, rest):
        if tare is not None:
            models.set_tare(np.repeat(tare[None], 3, axis=0))
        estimate = models.estimate(pressed)
        for k, (array, bundle) in enumerate(zip(hand.arrays, bundles)):
            x = pressed[array.flat_indices][None]
            if tare is not None:     # the bundle's own tare replaced by the rest reading
                x = x - tare[array.flat_indices] + bundle.x_offset
            np.testing.assert_allclose(estimate.force[k], bundle.predict(x)[0],
                                       rtol=1e-9, atol=1e-9)


def test_wrong_shapes_are_flagged_not_raised(full_set, hand):
    models = load_model_set(full_set, hand)
    estimate = models.estimate(np.zeros((10, 3)))
    assert not estimate.valid.any() and 'shape' in estimate.status[0]


@pytest.mark.parametrize('doc, message', [
    ({'models': {'index_knuckle': 'x.npz'}}, 'unknown arrays'),
    ({'models': {}}, 'non-empty'),
    ({'model': {'index_tip': 'x.npz'}}, 'non-empty'),
    ({'models': {'index_tip': 'missing.npz'}}, 'models.index_tip'),
])
def test_bad_lists_are_refused(doc, message, hand, tmp_path):
    path = tmp_path / 'models.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ModelConfigError, match=message):
        load_model_set(path, hand)


def test_a_model_for_another_array_is_refused(full_set, hand, tmp_path):
    path = tmp_path / 'swapped.yaml'
    path.write_text(yaml.safe_dump({'models': {'index_tip': str(full_set.parent
                                                                / 'middle_tip_M3.npz')}}))
    with pytest.raises(ModelConfigError, match="models.index_tip: .*'middle_tip'"):
        load_model_set(path, hand)


def test_each_hand_starts_with_its_own_shipped_models_and_refuses_the_other_hands():
    from tacforce_ros.estimation.model_set import default_model_config
    from tacforce_ros.hand.description import hand_config
    left = load_hand(hand_config('left'))
    right = load_hand()
    for one, other in ((right, left), (left, right)):
        models = load_model_set(default_model_config(one), one)
        assert [a.name for a in models.arrays] == [a.name for a in one.arrays]    # all 18
        assert models.skipped == () and {a.hand_side for a in models.arrays} == {one.side}
        with pytest.raises(ModelConfigError, match=f"for the {one.side} hand's index_tip, not "
                           f"the {other.side} hand's"):
            load_model_set(default_model_config(one), other)


def test_a_tare_window_gathers_its_frames_then_hands_them_over_once():
    from tacforce_ros.estimation.model_set import TareWindow
    window = TareWindow(3)
    frames = [np.full((368, 3), float(k)) for k in range(3)]
    assert [window.add(f) for f in frames] == [False, False, True]
    taken = window.take()
    assert taken.shape == (3, 368, 3) and taken.dtype == np.float64
    assert np.array_equal(taken[:, 0, 0], [0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match='no frames'):
        window.take()
    with pytest.raises(ValueError, match='at least one frame'):
        TareWindow(0)
