"""Runtime estimator: one batched pass for the whole hand, agreeing with each bundle alone."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.runtime import (RuntimeEstimator, destandardised_batch,
                                            folded_linear_batch)
from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.estimation.training import fit_bundle

KIND_CYCLE = ('M1', 'M2', 'M3', 'M3-lambda')


@pytest.fixture(scope='module')
def hand_data(hand):
    """Per array: (offset-corrected X, F, tare, raw dataset), short synthetic recordings."""
    out = []
    for k, array in enumerate(hand.arrays):
        data = synthetic_dataset(array, plates=('flat', 'edge'), seconds=6.0, seed=k)
        X, F, offset = data.without_offsets()
        out.append((X, F, offset, data))
    return out


def make_estimator(hand, hand_data, kinds):
    bundles = [fit_bundle(array, kind, {}, X, F, data.plates, x_offset=offset)
               for array, kind, (X, F, offset, data) in zip(hand.arrays, kinds, hand_data)]
    return RuntimeEstimator(hand, bundles), bundles


@pytest.fixture(scope='module')
def mixed(hand, hand_data):
    kinds = [KIND_CYCLE[k % len(KIND_CYCLE)] for k in range(len(hand.arrays))]
    return make_estimator(hand, hand_data, kinds)


def pressed_frame(hand, hand_data, row):
    """Whole-hand flat counts taken from each array's recording at sample `row`."""
    return hand.merge([data.X[row] for _, _, _, data in hand_data])


def test_batched_pass_matches_each_bundle(hand, hand_data, mixed):
    estimator, bundles = mixed
    assert len(set(estimator.kinds)) == 4
    for row in (0, 150, 420):
        frame = pressed_frame(hand, hand_data, row)
        result = estimator.estimate(frame)
        assert result.valid.all() and set(result.status) == {'ok'}
        for k, (array, bundle) in enumerate(zip(hand.arrays, bundles)):
            expected = bundle.predict(frame[array.flat_indices][None])[0]
            np.testing.assert_allclose(result.force[k], expected, atol=1e-9)


def test_single_kind_hand_matches_too(hand, hand_data):
    estimator, bundles = make_estimator(hand, hand_data, ['M3-lambda'] * len(hand.arrays))
    frame = pressed_frame(hand, hand_data, 300)
    result = estimator.estimate(frame)
    first = hand.arrays[0]
    np.testing.assert_allclose(result.force[0],
                               bundles[0].predict(frame[first.flat_indices][None])[0], atol=1e-9)
    # the callable's output buffer is never handed out: a second tick leaves the first intact
    kept = result.force.copy()
    estimator.estimate(pressed_frame(hand, hand_data, 100))
    np.testing.assert_array_equal(result.force, kept)


def test_nan_or_inf_invalidates_only_its_array(hand, hand_data, mixed):
    estimator, _ = mixed
    frame = pressed_frame(hand, hand_data, 200).astype(np.float64)
    clean = estimator.estimate(frame)
    bad_array = hand.arrays[5]
    frame[bad_array.flat_indices[3], 1] = np.nan
    frame[hand.arrays[9].flat_indices[0], 2] = np.inf
    result = estimator.estimate(frame)
    bad = {5, 9}
    for k in range(len(hand.arrays)):
        if k in bad:
            assert not result.valid[k] and 'NaN or Inf' in result.status[k]
            assert np.all(result.force[k] == 0.0) and result.ood_score[k] == np.inf
        else:
            assert result.valid[k] and result.status[k] == 'ok'
            np.testing.assert_array_equal(result.force[k], clean.force[k])
    assert np.all(np.isfinite(result.force))


def test_wrong_length_input_is_flagged(hand, mixed):
    estimator, _ = mixed
    result = estimator.estimate(np.zeros((367, 3)))
    assert not result.valid.any() and 'expected (368, 3)' in result.status[0]
    assert np.all(result.force == 0.0)


@pytest.mark.parametrize('counts', [0, 65535])
def test_rail_counts_give_finite_output_and_a_high_ood_score(hand, hand_data, mixed, counts):
    estimator, _ = mixed
    rest = estimator.estimate(pressed_frame(hand, hand_data, 0))
    result = estimator.estimate(np.full((368, 3), counts, dtype=np.uint16))
    assert result.valid.all() and np.all(np.isfinite(result.force))
    assert np.all(result.ood_score > 10.0 * rest.ood_score)


def test_tare_from_a_no_contact_window(hand, hand_data, mixed):
    estimator, bundles = mixed
    rest = pressed_frame(hand, hand_data, 0)
    drifted = rest + 40.0                       # every baseline drifted by 40 counts
    window = drifted[None] + np.random.default_rng(0).normal(0, 2.0, (50, 368, 3))
    before = estimator.estimate(drifted)
    estimator.set_tare(window, names=[hand.arrays[0].name])
    np.testing.assert_allclose(estimator.tare(hand.arrays[0].name),
                               window.mean(0)[hand.arrays[0].flat_indices])
    np.testing.assert_allclose(estimator.tare(hand.arrays[1].name), bundles[1].x_offset)
    estimator.set_tare(window)
    after = estimator.estimate(drifted)
    # after taring, the drifted rest frame reads what the trained rest reads: near zero force
    assert np.abs(after.force).max() < np.abs(before.force).max()
    assert np.abs(after.force).max() < 0.2
    with pytest.raises(ValueError, match='NaN or Inf'):
        estimator.set_tare(np.full((2, 368, 3), np.nan))
    with pytest.raises(ValueError, match='tare needs frames'):
        estimator.set_tare(np.zeros((368, 3)))
    for k, bundle in enumerate(bundles):        # restore the module-scoped estimator
        estimator.set_tare(np.asarray(hand.merge([b.x_offset for b in bundles]))[None],
                           names=[hand.arrays[k].name])


def test_model_set_must_match_the_hand(hand, mixed):
    _, bundles = mixed
    with pytest.raises(ValueError, match='missing'):
        RuntimeEstimator(hand, bundles[:-1])


def test_torch_trained_kinds_mix_with_linear_ones(hand, hand_data):
    """M4 and M5 groups (tips only for M5: a group narrower than the hand's widest array
    for M4) run in the same pass and agree with their bundles."""
    kinds = ['M3-lambda'] * len(hand.arrays)
    for k, array in enumerate(hand.arrays):
        if array.kind == 'fingertip':
            kinds[k] = 'M5'
        elif k % 3 == 0:
            kinds[k] = 'M4'
    fast = {'epochs': 2, 'batch_size': 128, 'learning_rate': 1e-2, 'seed': 0}
    bundles = [fit_bundle(array, kind, {} if kind == 'M3-lambda' else fast, X, F, data.plates,
                          x_offset=offset)
               for array, kind, (X, F, offset, data) in zip(hand.arrays, kinds, hand_data)]
    estimator = RuntimeEstimator(hand, bundles)
    assert set(estimator.kinds) == {'M3-lambda', 'M4', 'M5'}
    frame = pressed_frame(hand, hand_data, 250)
    result = estimator.estimate(frame)
    assert result.valid.all()
    for k, (array, bundle) in enumerate(zip(hand.arrays, bundles)):
        expected = bundle.predict(frame[array.flat_indices][None])[0]
        np.testing.assert_allclose(result.force[k], expected, rtol=1e-4, atol=1e-4)


@settings(max_examples=40)
@given(kind=st.sampled_from(('M1', 'M3', 'M3-lambda')), array_index=st.integers(0, 17),
       scale=st.sampled_from((1e-3, 1.0, 1e3)), seed=st.integers(0, 2**32 - 1))
def test_folded_linear_weights_equal_the_destandardised_model(hand, hand_data, kind, array_index,
                                                               scale, seed):
    """Folding f_std and f_mean into W and b is exact: same newtons as the model's own batch
    followed by the de-standardisation, for standardised inputs from tiny to far out."""
    array = hand.arrays[array_index]
    X, F, offset, data = hand_data[array_index]
    bundle = fit_bundle(array, kind, {}, X[::4], F[::4], data.plates[::4], x_offset=offset)
    n_max = max(a.n_taxels for a in hand.arrays)
    z = np.zeros((1, n_max, 3))
    z[0, :array.n_taxels] = scale * np.random.default_rng(seed).normal(size=(array.n_taxels, 3))
    rows = z.reshape(1, 1, 3 * n_max)       # the runtime's block: one taxel-major row per array
    folded = folded_linear_batch([bundle], n_max)(rows)
    reference = destandardised_batch([bundle], n_max)(rows)
    np.testing.assert_allclose(folded, reference, rtol=1e-10, atol=1e-12 * max(1.0, scale))
    expected = bundle.f_scaler.inverse(bundle.model.predict(z[:, :array.n_taxels]))
    np.testing.assert_allclose(folded, expected, rtol=1e-10, atol=1e-12 * max(1.0, scale))


def test_a_non_finite_model_output_is_invalid_with_zero_force(hand, hand_data, mixed):
    """Loading refuses non-finite parameters; should a model still produce NaN or Inf at run
    time (here: an output mean poisoned in memory), that array is invalid and reports zero."""
    import dataclasses

    from tacforce_ros.estimation.preprocessing import Standardiser
    _, bundles = mixed
    poisoned = list(bundles)
    for k, value in ((2, np.nan), (7, np.inf)):
        f = bundles[k].f_scaler
        poisoned[k] = dataclasses.replace(bundles[k], f_scaler=Standardiser(
            mean=np.array([value, 0.0, 0.0]), std=f.std, dead=f.dead))
    result = RuntimeEstimator(hand, poisoned).estimate(pressed_frame(hand, hand_data, 200))
    for k in range(len(hand.arrays)):
        if k in (2, 7):
            assert not result.valid[k] and result.status[k] == 'model output is NaN or Inf'
            assert np.all(result.force[k] == 0.0)
        else:
            assert result.valid[k] and result.status[k] == 'ok'
    assert np.all(np.isfinite(result.force))
