"""M1, M2, M3, M3-lambda: recovery of known maps, parameter counts, batching, state, hard cases."""
import numpy as np
import pytest
from conftest import linear_problem
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.base import ModelNotFittedError
from tacforce_ros.estimation.least_squares import CentredSVD, GroupFactors, fit_affine
from tacforce_ros.estimation.m1_rotation_linear import (M1Linear, normal_input_per_newton,
                                                       rotated_sum)
from tacforce_ros.estimation.m2_rotation_quadratic import M2Quadratic, quadratic_features
from tacforce_ros.estimation.m3_lambda import M3Lambda
from tacforce_ros.estimation.m3_linear import M3Linear

LINEAR_KINDS = [M1Linear, M2Quadratic, M3Linear, M3Lambda]


def test_m3_recovers_a_noiseless_linear_map(tip):
    X, F, A, b = linear_problem(np.random.default_rng(0), 400, tip.n_taxels)
    model = M3Linear(tip).fit(X, F)
    np.testing.assert_allclose(model.coef_, A, atol=1e-9)
    np.testing.assert_allclose(model.intercept_, b, atol=1e-9)
    assert model.n_parameters() == 9 * tip.n_taxels + 3


def test_m1_recovers_a_map_of_the_rotated_sum(tip):
    rng = np.random.default_rng(1)
    X = rng.standard_normal((300, tip.n_taxels, 3))
    A, b = rng.standard_normal((3, 3)), rng.standard_normal(3)
    F = rotated_sum(X, tip.rotations) @ A.T + b
    model = M1Linear(tip).fit(X, F)
    np.testing.assert_allclose(model.coef_, A, atol=1e-9)
    np.testing.assert_allclose(model.predict(X), F, atol=1e-9)
    assert model.n_parameters() == 12
    # z = sum_i R_i x_i, written out
    np.testing.assert_allclose(rotated_sum(X[:1], tip.rotations)[0],
                               sum(tip.rotations[i] @ X[0, i] for i in range(tip.n_taxels)))


def test_m2_fits_a_quadratic_of_z_that_m1_cannot(tip):
    rng = np.random.default_rng(2)
    X = rng.standard_normal((500, tip.n_taxels, 3))
    z = rotated_sum(X, tip.rotations)
    F = np.column_stack([z[:, 0] ** 2, z[:, 1] * z[:, 2], z[:, 2]])
    m2 = M2Quadratic(tip).fit(X, F)
    m1 = M1Linear(tip).fit(X, F)
    assert np.abs(m2.predict(X) - F).max() < 1e-8 * np.abs(F).max()
    assert np.abs(m1.predict(X) - F).mean() > 0.1 * np.abs(F).mean()
    assert m2.n_parameters() == 30
    assert quadratic_features(np.array([[2.0, 3.0, 5.0]])).tolist() == [
        [2, 3, 5, 4, 9, 25, 6, 15, 10]]


def test_damping_shrinks_weights_monotonically_but_not_the_bias(tip):
    X, F, _, b = linear_problem(np.random.default_rng(3), 200, tip.n_taxels, noise=0.1)
    F = F + 100.0                   # a large bias must survive any damping
    norms = []
    for lam in (0.0, 1.0, 33.0, 1e3, 1e6):
        model = M3Lambda(tip, lam=lam).fit(X, F)
        norms.append(np.linalg.norm(model.coef_))
    assert all(a > c for a, c in zip(norms, norms[1:]))
    heavy = M3Lambda(tip, lam=1e12).fit(X, F)
    np.testing.assert_allclose(heavy.predict(X).mean(axis=0), F.mean(axis=0), rtol=1e-6)


@settings(max_examples=40, deadline=None)
@given(samples=st.integers(2, 300), features=st.integers(1, 12), rank=st.integers(1, 12),
       seed=st.integers(0, 2 ** 16))
def test_lambda_path_from_one_svd_equals_direct_solves(samples, features, rank, seed):
    """Tall and wide designs, full rank and rank-deficient."""
    rng = np.random.default_rng(seed)
    basis = rng.standard_normal((samples, min(rank, features)))
    phi = basis @ rng.standard_normal((basis.shape[1], features))
    F = rng.standard_normal((samples, 3))
    svd = CentredSVD.of(phi, F)
    for lam in (0.0, 0.5, 33.0):
        coef, intercept = svd.solve(lam)
        # reference: augmented least squares [Phi_c; sqrt(lam) I] w = [F_c; 0] (no inverse);
        # undamped, the minimum-norm solution
        pc, fc = phi - phi.mean(0), F - F.mean(0)
        aug = np.vstack([pc, np.sqrt(lam) * np.eye(features)])
        ref = np.linalg.lstsq(aug, np.vstack([fc, np.zeros((features, 3))]), rcond=None)[0].T
        scale = 1.0 + np.abs(ref).max()
        np.testing.assert_allclose(coef, ref, atol=1e-8 * scale)
        np.testing.assert_allclose(intercept, F.mean(0) - ref @ phi.mean(0),
                                   atol=1e-8 * scale * (1.0 + np.abs(phi).max()))


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(1, 60), min_size=2, max_size=5),
       features=st.integers(1, 12), seed=st.integers(0, 2 ** 16))
def test_a_union_of_groups_from_their_factors_equals_the_direct_fit(sizes, features, seed):
    """Groups of one row, of fewer rows than features, and tall ones: the fold that leaves out
    each group, solved from the others' factors, equals the fit on its rows."""
    rng = np.random.default_rng(seed)
    groups = np.repeat(np.arange(len(sizes)), sizes)
    phi = rng.standard_normal((len(groups), features)) * rng.uniform(0.1, 10.0, features) + 3.0
    F = rng.standard_normal((len(groups), 3))
    factors = GroupFactors(phi, F, groups)
    for held in factors.labels:
        keep = groups != held
        together = factors.svd([g for g in factors.labels if g != held])
        direct = CentredSVD.of(phi[keep], F[keep])
        np.testing.assert_allclose(together.phi_mean, phi[keep].mean(0), rtol=1e-10)
        np.testing.assert_allclose(together.f_mean, F[keep].mean(0), atol=1e-12)
        for lam in (0.5, 33.0):
            (c1, b1), (c2, b2) = together.solve(lam), direct.solve(lam)
            scale = 1.0 + np.abs(c2).max()
            np.testing.assert_allclose(c1, c2, atol=1e-9 * scale)
            np.testing.assert_allclose(b1, b2, atol=1e-9 * scale * (1.0 + np.abs(phi).max()))
    (c1, b1), (c2, b2) = factors.svd(factors.labels).solve(1.0), CentredSVD.of(phi, F).solve(1.0)
    np.testing.assert_allclose(c1, c2, atol=1e-9 * (1.0 + np.abs(c2).max()))


@pytest.mark.parametrize('cls', LINEAR_KINDS)
def test_compiled_batch_matches_predict_across_array_sizes(hand, cls):
    arrays = [hand.array(n) for n in ('index_tip', 'index_middle', 'palm_center', 'thumb_tip')]
    rng = np.random.default_rng(5)
    models, inputs = [], []
    for array in arrays:
        X, F, _, _ = linear_problem(rng, 150, array.n_taxels, noise=0.2)
        models.append(cls(array).fit(X, F))
        inputs.append(X[:1])
    n_max = max(a.n_taxels for a in arrays)
    batch = np.full((len(arrays), n_max, 3), 0.0)
    for k, x in enumerate(inputs):
        batch[k, :x.shape[1]] = x[0]
    out = cls.compile_batch(models)(batch)
    expected = np.vstack([m.predict(x) for m, x in zip(models, inputs)])
    np.testing.assert_allclose(out, expected, atol=1e-10)


@pytest.mark.parametrize('cls', LINEAR_KINDS)
def test_state_round_trip_and_refusals(tip, phalanx, cls):
    X, F, _, _ = linear_problem(np.random.default_rng(6), 120, tip.n_taxels, noise=0.1)
    model = cls(tip).fit(X, F)
    state = model.state_arrays()
    assert all(name.endswith('_') for name in state)
    clone = cls.from_state(tip, model.hyperparameters(), state)
    np.testing.assert_array_equal(clone.predict(X), model.predict(X))
    if cls in (M3Linear, M3Lambda):     # M1/M2 weights are per array frame, any taxel count
        with pytest.raises(ValueError, match='expected'):
            cls.from_state(phalanx, model.hyperparameters(), state)     # 16-taxel array
    with pytest.raises(ValueError, match='state needs arrays'):
        cls.from_state(tip, model.hyperparameters(), {'coef_': state['coef_']})
    with pytest.raises(ModelNotFittedError):
        cls(tip).predict(X)


@pytest.mark.parametrize('cls', LINEAR_KINDS)
def test_bad_shapes_and_nan_targets_are_refused(tip, cls):
    X, F, _, _ = linear_problem(np.random.default_rng(7), 50, tip.n_taxels)
    with pytest.raises(ValueError, match='shape'):
        cls(tip).fit(X[:, :10], F)
    with pytest.raises(ValueError, match='shape'):
        cls(tip).fit(X, F[:10])
    F[3, 1] = np.nan
    with pytest.raises(ValueError, match='NaN'):
        cls(tip).fit(X, F)


# --- hard cases ------------------------------------------------------------------------------

def degenerate_inputs(rng, n_samples, n_taxels, case):
    X = rng.standard_normal((n_samples, n_taxels, 3))
    if case == 'constant':
        X[:, ::2, :] = 0.0                       # half the channels dead (standardised to 0)
    elif case == 'collinear':
        X[:, 1:, :] = X[:, :1, :] * rng.uniform(0.5, 2.0, (1, n_taxels - 1, 1))
    elif case == 'rank1':
        X = rng.standard_normal((n_samples, 1, 1)) * rng.standard_normal((1, n_taxels, 3))
    return X


@given(seed=st.integers(0, 2**31 - 1), n_samples=st.integers(1, 40),
       case=st.sampled_from(['constant', 'collinear', 'rank1', 'plain']),
       log_lam=st.floats(-8.0, 8.0), kind=st.sampled_from(LINEAR_KINDS))
def test_degenerate_designs_give_finite_bounded_fits(tip, seed, n_samples, case, log_lam, kind):
    """Collinear/constant channels, rank-deficient designs, fewer samples than parameters,
    lambda from 1e-8 to 1e8: finite weights, and never worse on the training data than the mean."""
    rng = np.random.default_rng(seed)
    X = degenerate_inputs(rng, n_samples, tip.n_taxels, case)
    F = rng.standard_normal((n_samples, 3))
    model = kind(tip, lam=10.0 ** log_lam) if kind is M3Lambda else kind(tip)
    model.fit(X, F)
    pred = model.predict(X)
    assert np.all(np.isfinite(model.coef_)) and np.all(np.isfinite(pred))
    baseline = np.sum((F - F.mean(axis=0)) ** 2)
    assert np.sum((pred - F) ** 2) <= baseline * (1 + 1e-8) + 1e-12
    probe = rng.standard_normal((3, tip.n_taxels, 3))
    assert np.all(np.isfinite(model.predict(probe)))


def test_zero_samples_refused(tip):
    with pytest.raises(ValueError, match='zero samples'):
        M3Linear(tip).fit(np.zeros((0, tip.n_taxels, 3)), np.zeros((0, 3)))


@pytest.mark.parametrize('counts', [0.0, 65535.0])
def test_m2_extreme_inputs_stay_finite(tip, counts):
    """Inputs at the 16-bit rails, standardised against a quiet training set: z' is huge but
    finite, and the fit itself stays well conditioned thanks to the z scaling."""
    rng = np.random.default_rng(8)
    raw = 20000.0 + 30.0 * rng.standard_normal((300, tip.n_taxels, 3))
    mean, std = raw.mean(0), raw.std(0)
    X = (raw - mean) / std
    F = rng.standard_normal((300, 3))
    model = M2Quadratic(tip).fit(X, F)
    design = model.features(X)
    assert np.linalg.cond(design - design.mean(0)) < 1e3
    rail = (np.full((1, tip.n_taxels, 3), counts) - mean) / std
    out = model.predict(rail)
    assert np.all(np.isfinite(out))
    batch = M2Quadratic.compile_batch([model])(rail)
    np.testing.assert_allclose(batch, out, rtol=1e-9)


@pytest.mark.parametrize('kind', LINEAR_KINDS)
def test_float32_and_float64_inputs_agree(tip, kind):
    X, F, _, _ = linear_problem(np.random.default_rng(9), 300, tip.n_taxels, noise=0.3)
    X32 = X.astype(np.float32)
    m64 = kind(tip).fit(X32.astype(np.float64), F)
    m32 = kind(tip).fit(X32, F.astype(np.float32))
    np.testing.assert_allclose(m32.predict(X32), m64.predict(X32), rtol=1e-5, atol=1e-5)
    assert m32.predict(X32).dtype == np.float64
    assert fit_affine(X32.reshape(300, -1), F)[0].dtype == np.float64


def test_m1s_normal_input_per_newton_is_the_slope_of_the_rotated_sum():
    # Two taxels, the second turned upside down about x: its z counts enter M1's sum negated.
    rotations = np.stack([np.eye(3), np.diag([1.0, -1.0, -1.0])])
    force = np.zeros((8, 3))
    force[:, 2] = [-1.0, -2.0, -3.0, -0.1, -1.0, -2.0, -1.0, -3.0]
    X = np.zeros((8, 2, 3))
    X[:3, 0, 2], X[:3, 1, 2] = -500.0 * force[:3, 2], 100.0 * force[:3, 2]   # sum -600 F
    X[3:6, 0, 2] = 250.0 * force[3:6, 2]                                    # sum 250 F
    X[3, 0, 2] = 1e6                 # below 0.3 N: not counted
    # an offset: the slope through the origin is (60 + 780) / 10 = 84, a fitted line's 100
    X[6:, 0, 2] = 100.0 * force[6:, 2] + 40.0
    plates = np.array(['a'] * 3 + ['b'] * 3 + ['c'] * 2)
    gains = normal_input_per_newton(X, force, plates, rotations)
    assert gains == {'a': pytest.approx(-600.0), 'b': pytest.approx(250.0),
                     'c': pytest.approx(84.0)}
    # a plate without a press has no slope
    assert normal_input_per_newton(X[3:4], force[3:4], np.array(['b']),
                                   rotations) == {'b': None}
