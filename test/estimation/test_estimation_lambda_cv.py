"""Metrics, leave-one-plate-out CV, and damping selection nested inside the training plates."""
import numpy as np
import pytest
from conftest import linear_problem
from hypothesis import given
from hypothesis import strategies as st

from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.m3_lambda import DEFAULT_GRID, M3Lambda, select_damping
from tacforce_ros.estimation.metrics import average_folds, error_stats


def test_error_stats_by_hand():
    true = np.array([[1.0, 0.1, -2.0], [2.0, 0.0, 4.0]])
    pred = np.array([[1.5, 0.3, -1.0], [2.0, 1.0, 3.0]])
    s = error_stats(true, pred)
    # sample 1: axes x, z counted: (0.5/1 + 1/2)/2 = 0.5; sample 2: (0 + 1/4)/2 = 0.125
    assert s.e_r_mean == pytest.approx(0.3125)
    assert s.e_r_std == pytest.approx(0.1875)
    assert s.e_r_samples == 2
    assert s.e_hat_mean == pytest.approx(np.mean([(0.5 + 0.2 + 1.0) / 3, 2.0 / 3]))
    assert s.mae_axis == pytest.approx((0.25, 0.6, 1.0))


@given(st.floats(0.0, 0.49), st.integers(0, 1000))
def test_relative_error_ignores_small_forces_and_never_divides_by_zero(scale, seed):
    rng = np.random.default_rng(seed)
    true = rng.uniform(-1.0, 1.0, (30, 3)) * scale       # all below 0.5 N
    true[0] = 0.0
    s = error_stats(true, true + 0.1)
    assert s.e_r_mean is None and s.e_r_samples == 0
    assert s.e_hat_mean == pytest.approx(0.1)
    assert average_folds([s, s])['e_r_mean'] is None


def test_error_stats_refuse_nan_and_mismatch():
    with pytest.raises(ValueError, match='NaN'):
        error_stats(np.ones((2, 3)), np.array([[1, 1, np.nan], [1, 1, 1]]))
    with pytest.raises(ValueError, match='matching'):
        error_stats(np.ones((2, 3)), np.ones((3, 3)))


def test_cross_validation_holds_out_each_plate_once(tip, tip_data):
    data, X, F, _ = tip_data
    result = cross_validate(tip, 'M3', {}, X, F, data.plates)
    assert [f.test_plate for f in result.folds] == data.plate_names()
    for fold in result.folds:
        assert fold.stats.samples == int(np.sum(data.plates == fold.test_plate))
    summary = result.summary()
    assert summary['folds'] == 5 and summary['n_parameters'] == 9 * 30 + 3
    assert summary['e_hat_mean'] == pytest.approx(
        np.mean([f.stats.e_hat_mean for f in result.folds]))


def test_cross_validation_error_reflects_the_model(tip, tip_data):
    """On this data M3 beats a model that ignores the inputs (damping 1e12 = predict the mean)."""
    data, X, F, _ = tip_data
    m3 = cross_validate(tip, 'M3-lambda', {'lam': 33.0}, X, F, data.plates).summary()
    mean_only = cross_validate(tip, 'M3-lambda', {'lam': 1e12}, X, F, data.plates).summary()
    assert m3['e_hat_mean'] < 0.5 * mean_only['e_hat_mean']


def test_cross_validation_needs_two_plates(tip, tip_data):
    data, X, F, _ = tip_data
    with pytest.raises(ValueError, match='>= 2 plates'):
        cross_validate(tip, 'M3', {}, X, F, np.full(len(X), 'flat'))


def test_lambda_selection_prefers_damping_on_noisy_underdetermined_data(tip):
    rng = np.random.default_rng(0)
    X, F, _, _ = linear_problem(rng, 200, tip.n_taxels, noise=0.0)
    F = 0.2 * F + 3.0 * rng.standard_normal(F.shape)       # weak signal, strong noise
    groups = np.repeat(np.arange(4), 50)
    lam, scores = select_damping(X.reshape(200, -1), F, groups, DEFAULT_GRID)
    assert lam > 1.0
    assert scores.shape == (len(DEFAULT_GRID),) and np.all(np.isfinite(scores))
    X, F, _, _ = linear_problem(rng, 400, tip.n_taxels, noise=0.001)
    lam_clean, _ = select_damping(X.reshape(400, -1), F, np.repeat(np.arange(4), 100),
                                  DEFAULT_GRID)
    assert lam_clean < lam


def test_nested_selection_fits_at_the_damping_it_chose_as_a_direct_fit_would(tip, tip_data):
    """The final fit from the plates' factors equals M3-lambda fitted on the rows at that
    damping."""
    data, X, F, _ = tip_data
    nested = M3Lambda(tip, lambda_grid=DEFAULT_GRID[::4]).fit(X, F, groups=data.plates)
    direct = M3Lambda(tip, lam=nested.damping).fit(X, F)
    np.testing.assert_allclose(nested.coef_, direct.coef_,
                               atol=1e-9 * (1.0 + np.abs(direct.coef_).max()))
    np.testing.assert_allclose(nested.predict(X), direct.predict(X), atol=1e-9)


def test_nested_selection_never_sees_the_held_out_plate(tip, tip_data):
    """Corrupting the held-out plate changes neither the damping chosen for that fold nor the
    fitted weights; it only changes that fold's test error."""
    data, X, F, _ = tip_data
    hyper = {'lam': 33.0, 'lambda_grid': list(DEFAULT_GRID[::2])}
    clean = cross_validate(tip, 'M3-lambda', hyper, X, F, data.plates)
    for fold_index, plate in enumerate(data.plate_names()[:2]):
        held = data.plates == plate
        X_bad, F_bad = X.copy(), F.copy()
        rng = np.random.default_rng(fold_index)
        X_bad[held] = rng.normal(0.0, 5e3, X_bad[held].shape)
        F_bad[held] = rng.normal(0.0, 50.0, F_bad[held].shape)
        corrupted = cross_validate(tip, 'M3-lambda', hyper, X_bad, F_bad, data.plates)
        chosen = clean.folds[fold_index].hyperparameters['lam']
        assert corrupted.folds[fold_index].hyperparameters['lam'] == chosen
        assert corrupted.folds[fold_index].stats.e_hat_mean > \
            10 * clean.folds[fold_index].stats.e_hat_mean
        # ...whereas the other folds, which train on the corrupted plate, do see it.
        others = [k for k in range(5) if k != fold_index]
        assert any(corrupted.folds[k].stats.e_hat_mean != clean.folds[k].stats.e_hat_mean
                   for k in others)


def test_nested_selection_requires_groups(tip):
    X, F, _, _ = linear_problem(np.random.default_rng(1), 60, tip.n_taxels)
    with pytest.raises(ValueError, match='needs groups'):
        M3Lambda(tip, lambda_grid=[1.0, 10.0]).fit(X, F)
    with pytest.raises(ValueError, match='>= 2 plates'):
        M3Lambda(tip, lambda_grid=[1.0, 10.0]).fit(X, F, groups=np.zeros(60))
    with pytest.raises(ValueError, match='lam must be'):
        M3Lambda(tip, lam=-1.0)
