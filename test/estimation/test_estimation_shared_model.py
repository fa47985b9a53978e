"""A model shared by the arrays of a kind and adapted to one (shared_model.py): the two ends of
the adaptation weight, its gain where the array's own data are few, and the refusals."""
import numpy as np
import pytest

from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.learning_curve import learning_curve, shared_learning_curve
from tacforce_ros.estimation.least_squares import fit_affine
from tacforce_ros.estimation.shared_model import (ADAPT_WEIGHTS, Adaptation, KindBlocks, adapt,
                                                  fit_adapted, shared_folds)
from tacforce_ros.estimation.training import fit_bundles

HYPER = {'lam': 1e-3, 'lambda_grid': None}


def module(X, seed):
    """X as another module of the kind reads the same presses: its taxels' gains differ (the
    simulated skin's magnets and layers; lognormal, 15 %)."""
    return X * np.random.default_rng(seed).lognormal(0.0, 0.15, X.shape[1:])


@pytest.fixture(scope='module')
def kind(tip_data):
    """The array (the fixture's data) and three others of its kind reading the same presses."""
    data, X, F, _ = tip_data
    others = {f'other_{k}': (module(X, 10 + k), F, data.plates) for k in range(3)}
    return (module(X, 9), F, data.plates), others


def fit_shared(array, others):
    """The shared model as the definition has it: M3-lambda fitted on the pooled rows."""
    pooled = tuple(np.concatenate([d[i] for d in others]) for i in range(3))
    return fit_bundles(array, 'M3-lambda', HYPER, [pooled])[0]


def first_rows(plates, n):
    keep = np.zeros(len(plates), bool)
    for plate in dict.fromkeys(plates.tolist()):
        keep[np.flatnonzero(plates == plate)[:n]] = True
    return keep


def test_weight_inf_is_the_shared_model_and_zero_the_arrays_own_fit(tip, kind):
    (X, F, plates), others = kind
    shared = fit_shared(tip, list(others.values()))
    np.testing.assert_array_equal(adapt(shared, np.inf, X, F).predict(X), shared.predict(X))
    # Weight 0: the prior no longer counts; what is left is the array's own least squares in
    # the shared model's units.
    xs = shared.x_scaler.transform(X)
    coef, intercept = fit_affine(shared.model.features(xs), shared.f_scaler.transform(F), 0.0)
    own = shared.f_scaler.inverse(shared.model.features(xs) @ coef.T + intercept)
    np.testing.assert_allclose(adapt(shared, 0.0, X, F).predict(X), own, atol=1e-6)
    # In between it moves from the shared model toward the array's own, and not past it.
    err = [np.abs(adapt(shared, w, X, F).predict(X) - F).mean() for w in (np.inf, 1.0, 0.0)]
    assert err[0] > err[1] > err[2]


def test_one_factor_adapts_at_every_weight_as_the_damped_fit_at_each(tip, kind):
    """Adaptation takes the data's factor once for all weights (the weight's choice); each
    weight's model is the damped fit of the residual taken on its own, to the bit."""
    (X, F, _), others = kind
    shared = fit_shared(tip, list(others.values()))
    xs = shared.x_scaler.transform(X[:500])
    residual = shared.f_scaler.transform(F[:500]) - shared.model.predict(xs)
    adaptation = Adaptation(shared, X[:500], F[:500])
    for weight in ADAPT_WEIGHTS[:-1]:
        delta, offset = fit_affine(shared.model.features(xs), residual, weight * 500)
        adapted = adaptation(weight)
        assert np.array_equal(adapted.model.coef_, shared.model.coef_ + delta)
        assert np.array_equal(adapted.model.intercept_, shared.model.intercept_ + offset)
    assert adaptation(np.inf).model.coef_ is not shared.model.coef_
    np.testing.assert_array_equal(adaptation(np.inf).model.coef_, shared.model.coef_)
    with pytest.raises(ValueError, match='must be >= 0'):
        adaptation(float('nan'))


def test_adapted_from_a_few_seconds_it_beats_the_arrays_own_model(tip, kind):
    (X, F, plates), others = kind
    keep = first_rows(plates, 150)                          # 1.5 s per plate of the array's own
    own = cross_validate(tip, 'M3-lambda', HYPER, X[keep], F[keep], plates[keep],
                         held_out=(X, F, plates)).summary()['e_hat_mean']
    (shared,) = shared_folds(tip, 'M3-lambda', HYPER, (X, F, plates), [keep], others)
    summary = shared.summary()
    print(f'own {own:.3f} N, shared and adapted {summary["e_hat_mean"]:.3f} N, weights',
          [f['hyperparameters']['adapt_weight'] for f in summary['per_fold']])
    assert summary['e_hat_mean'] < 0.8 * own
    assert [f['test_plate'] for f in summary['per_fold']] == list(dict.fromkeys(plates.tolist()))


def test_the_shared_curve_cuts_as_the_own_curve(tip, tip_data):
    data, X, F, _ = tip_data
    others = {f'other_{k}': (module(X, 20 + k), F, data.plates) for k in range(2)}
    seconds = (5.0, 20.0)
    own = learning_curve(tip, data, {'M3-lambda': ('M3-lambda', HYPER)}, seconds)
    shared = shared_learning_curve(tip, data, 'M3-lambda', 'M3-lambda', HYPER, others, seconds)
    assert [r['way'] for r in own + shared] == ['own'] * 2 + ['shared'] * 2
    for a, b in zip(own, shared):
        assert (a['seconds'], a['recorded_s'], a['samples']) == \
            (b['seconds'], b['recorded_s'], b['samples'])
        assert len(b['adapt_weights']) == len(data.plate_names())


def test_what_cannot_be_shared_is_refused(tip, kind):
    (X, F, plates), others = kind
    with pytest.raises(ValueError, match='only'):
        KindBlocks(tip, 'M4', {}, others)
    with pytest.raises(ValueError, match='needs the data of another array'):
        KindBlocks(tip, 'M3-lambda', HYPER, others).fit([])
    with pytest.raises(ValueError, match='two other arrays'):
        shared_folds(tip, 'M3-lambda', HYPER, (X, F, plates), [np.ones(len(F), bool)],
                     {'other_0': others['other_0']})
    short = plates != plates[0]
    lacking = {**others, 'other_0': (X[short], F[short], plates[short])}
    with pytest.raises(ValueError, match=f"other_0 has no data on the plates \\['{plates[0]}'\\]"):
        shared_folds(tip, 'M3-lambda', HYPER, (X, F, plates), [np.ones(len(F), bool)], lacking)
    shared = fit_shared(tip, list(others.values()))
    with pytest.raises(ValueError, match='must be >= 0'):
        adapt(shared, -1.0, X, F)


def test_the_blocks_fit_what_the_pooled_rows_fit(tip, kind):
    """KindBlocks: a union of (array, plate) blocks, the held-out plate left out, gives the
    model fit_shared fits on those rows: the same standardisation and predictions."""
    (X, F, plates), others = kind
    blocks = KindBlocks(tip, 'M3-lambda', HYPER, {'new': (X, F, plates), **others})
    plate = plates[0]
    names = ['other_0', 'other_2']
    rows = [(d[0][d[2] != plate], d[1][d[2] != plate], d[2][d[2] != plate])
            for name, d in others.items() if name in names]
    direct = fit_shared(tip, rows)
    fast = blocks.fit(names, without=plate)
    np.testing.assert_allclose(fast.x_scaler.mean, direct.x_scaler.mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fast.x_scaler.std, direct.x_scaler.std, rtol=1e-9)
    np.testing.assert_allclose(fast.f_scaler.std, direct.f_scaler.std, rtol=1e-9)
    np.testing.assert_allclose(fast.predict(X), direct.predict(X), atol=1e-7)
    with pytest.raises(ValueError, match='only'):
        KindBlocks(tip, 'M3-lambda', {'lam': 33.0, 'lambda_grid': [1.0, 10.0]}, others)


def test_the_shipped_adapted_model_is_the_weight_its_folds_liked(tip, kind):
    (X, F, plates), others = kind
    bundle, weight, cv = fit_adapted(tip, 'M3-lambda', HYPER, (X, F, plates), others)
    scores = np.mean([f.hyperparameters['weight_scores'] for f in cv.folds], axis=0)
    assert weight == ADAPT_WEIGHTS[int(np.argmin(scores))]
    expected = adapt(fit_shared(tip, list(others.values())), weight, X, F)
    np.testing.assert_allclose(bundle.predict(X), expected.predict(X), atol=1e-7)
    assert len(cv.folds) == len(set(plates.tolist()))


def test_a_kind_curve_cuts_every_array_and_judges_it_on_all_of_its_held_out_plate(tip,
                                                                                  tip_data):
    import dataclasses
    from tacforce_ros.estimation.learning_curve import cut_rows, kind_curve
    data = tip_data[0]
    arrays = {f'module_{k}': (tip, dataclasses.replace(data, X=module(data.X, 30 + k)))
              for k in range(3)}
    rows = kind_curve(arrays, 'M3-lambda', 'M3-lambda', HYPER, (5.0, 1e6))
    assert [(r['array'], r['seconds'], r['way'], r['kind']) for r in rows] == [
        (name, s, 'shared-kind', 'fingertip') for s in (5.0, 1e6) for name in arrays]
    plates = len(data.plate_names())
    for r in rows:
        assert r['samples'] == int(cut_rows(arrays[r['array']][1], r['seconds'] / plates).sum())
    # The whole recording is the shared model of the others' whole recordings, adapted to all
    # of its own and tested on it: shared_folds with no held-out data of its own.
    full = {name: d.without_offsets()[:2] + (d.plates,) for name, (_, d) in arrays.items()}
    for r in rows[3:4]:
        others = {o: v for o, v in full.items() if o != r['array']}
        (result,) = shared_folds(tip, 'M3-lambda', HYPER, full[r['array']],
                                 [np.ones(len(full[r['array']][1]), bool)], others)
        assert r['e_hat_n'] == pytest.approx(result.summary()['e_hat_mean'], rel=1e-9)
    # A cut trains on its rows and is tested on all of its held-out plate's, not on its own.
    keeps = {name: cut_rows(d, 5.0 / plates) for name, (_, d) in arrays.items()}
    cut = {name: tuple(part[keeps[name]] for part in full[name]) for name in arrays}
    assert all(r['samples'] < rows[3]['samples'] for r in rows[:3])
    for r in rows[:1]:
        own, others = cut[r['array']], {o: v for o, v in cut.items() if o != r['array']}
        every = [np.ones(len(own[1]), bool)]
        (tested,) = shared_folds(tip, 'M3-lambda', HYPER, own, every, others,
                                 held_out=full[r['array']])
        (on_itself,) = shared_folds(tip, 'M3-lambda', HYPER, own, every, others)
        assert r['e_hat_n'] == pytest.approx(tested.summary()['e_hat_mean'], rel=1e-9)
        assert r['e_hat_n'] != pytest.approx(on_itself.summary()['e_hat_mean'], rel=1e-3)
        assert sum(f['samples'] for f in tested.summary()['per_fold']) == len(full[r['array']][1])
    with pytest.raises(ValueError, match='three or more arrays'):
        kind_curve(dict(list(arrays.items())[:2]), 'M3-lambda', 'M3-lambda', HYPER, (5.0,))
