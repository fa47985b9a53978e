"""M4 (MLP) and M5 (CNN): training, determinism, numpy vs torch, batching, files, bad input."""
import json
import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.base import ModelNotFittedError
from tacforce_ros.estimation.m4_mlp import MLPModel
from tacforce_ros.estimation.m5_cnn import PREDICT_CHUNK, CNNModel
from tacforce_ros.hand.description import load_hand

# Fast training settings for tests (the paper's lr 2.5e-4 for 40 epochs needs far more data).
FAST = dict(epochs=12, batch_size=64, learning_rate=1e-2)


@dataclass(frozen=True)
class FakeArray:
    """The TaxelArray fields the models read, for grids the hand does not have."""

    name: str
    n_taxels: int
    grid_index: np.ndarray


def grid_array(name: str, mask: np.ndarray) -> FakeArray:
    """Array whose taxels fill the True cells of mask in row-major order."""
    grid = np.full(mask.shape, -1, dtype=np.int64)
    grid[mask] = np.arange(int(mask.sum()))
    return FakeArray(name, int(mask.sum()), grid)


HAND = load_hand()
TIP, PHALANX, PALM = (HAND.array(name) for name in ('index_tip', 'index_middle', 'palm_center'))
ARRAYS = {16: PHALANX, 24: PALM, 30: TIP}
MODELS = {'M4': MLPModel, 'M5': CNNModel}


def contact_dataset(array, n_samples: int, seed: int):
    """Seeded synthetic presses: force F (N, 3) at a random spot on the grid, taxel readings X.

    Each taxel reads the saturating response tanh(1.5 F) weighted by a Gaussian footprint around
    the contact whose width grows with the normal force, plus noise: nonlinear in F and in space.
    """
    rng = np.random.default_rng(seed)
    rows, cols = np.nonzero(array.grid_index >= 0)
    cells = np.empty((array.n_taxels, 2))
    cells[array.grid_index[rows, cols]] = np.c_[rows, cols]
    F = rng.standard_normal((n_samples, 3))
    centre = rng.uniform((0, 0), np.array(array.grid_index.shape) - 1, (n_samples, 2))
    sigma = 0.7 + 0.6 * np.abs(F[:, 2:])
    footprint = np.exp(-((cells - centre[:, None]) ** 2).sum(axis=-1) / (2 * sigma ** 2))
    X = 2.0 * footprint[..., None] * np.tanh(1.5 * F)[:, None, :]
    return X + 0.05 * rng.standard_normal(X.shape), F


def random_state(model, seed: int) -> dict:
    """Plausible weights of the right shapes (BatchNorm variances positive)."""
    rng = np.random.default_rng(seed)
    shapes = model._state_shapes()
    arrays = {name: 0.4 * rng.standard_normal(shape) for name, shape in shapes.items()}
    if 'norm_running_var_' in arrays:
        arrays['norm_running_var_'] = rng.uniform(0.3, 2.0, arrays['norm_running_var_'].shape)
    return arrays


def with_random_state(cls, array, seed, **hyper):
    return cls.from_state(array, hyper, random_state(cls(array, **hyper), seed))


def torch_forward(model, X: np.ndarray) -> np.ndarray:
    """The fitted network's torch eval-mode output for taxel inputs X."""
    x = X.reshape(len(X), -1) if model.kind == 'M4' else model.images(X).transpose(0, 3, 1, 2)
    with torch.no_grad():
        return model.torch_module()(torch.as_tensor(np.ascontiguousarray(x),
                                                    dtype=torch.float32)).numpy()


@pytest.fixture(scope='module')
def fitted():
    """Each kind fitted on the fingertip layout, with held-out data for scoring."""
    X, F = contact_dataset(TIP, 1500, seed=0)
    models = {kind: cls(TIP, seed=3, **FAST).fit(X[:1000], F[:1000])
              for kind, cls in MODELS.items()}
    return models, X[1000:], F[1000:]


@pytest.mark.parametrize('kind', MODELS)
def test_fit_beats_constant_and_least_squares_predictors(fitted, kind):
    models, X_test, F_test = fitted
    X_train, F_train = contact_dataset(TIP, 1500, seed=0)
    X_train, F_train = X_train[:1000], F_train[:1000]
    mse = np.mean((models[kind].predict(X_test) - F_test) ** 2)
    constant = np.mean((F_train.mean(axis=0) - F_test) ** 2)
    design = np.c_[X_train.reshape(1000, -1), np.ones(1000)]
    coef = np.linalg.lstsq(design, F_train, rcond=None)[0]
    linear = np.mean((np.c_[X_test.reshape(len(X_test), -1), np.ones(len(X_test))] @ coef
                      - F_test) ** 2)
    assert mse < 0.3 * constant
    assert mse < 0.85 * linear     # the nonlinearity is captured, not only the linear part


@pytest.mark.parametrize('kind', MODELS)
def test_numpy_forward_matches_torch_eval_forward(fitted, kind):
    models, X_test, _ = fitted
    ours, reference = models[kind].predict(X_test), torch_forward(models[kind], X_test)
    np.testing.assert_allclose(ours, reference, rtol=1e-5, atol=1e-5)


def test_cnn_predict_in_chunks_matches_torch():
    model = with_random_state(CNNModel, PALM, seed=9)
    X = np.random.default_rng(9).standard_normal((PREDICT_CHUNK + 3, PALM.n_taxels, 3))
    np.testing.assert_allclose(model.predict(X), torch_forward(model, X), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize('kind', MODELS)
def test_same_seed_bit_identical_other_seed_different(kind, training_device):
    X, F = contact_dataset(PHALANX, 200, seed=1)
    hyper = dict(FAST, epochs=2, device=training_device)
    states = [MODELS[kind](PHALANX, seed=s, **hyper).fit(X, F).state_arrays() for s in (5, 5, 6)]
    assert states[0].keys() == states[1].keys()
    for name in states[0]:
        np.testing.assert_array_equal(states[0][name], states[1][name])
    assert any(not np.array_equal(states[0][name], states[2][name]) for name in states[0]
               if name.endswith('weight_'))


def test_fit_leaves_global_torch_state_untouched():
    X, F = contact_dataset(PHALANX, 64, seed=2)
    threads, rng_state = torch.get_num_threads(), torch.random.get_rng_state()
    precision = torch.get_float32_matmul_precision()
    torch.set_float32_matmul_precision('medium')       # a caller's own choice, kept
    try:
        MLPModel(PHALANX, epochs=1, threads=2 if threads == 1 else 1).fit(X, F)
        assert torch.get_float32_matmul_precision() == 'medium'
    finally:
        torch.set_float32_matmul_precision(precision)
    assert torch.get_num_threads() == threads
    assert torch.equal(torch.random.get_rng_state(), rng_state)
    assert not torch.are_deterministic_algorithms_enabled()


@pytest.mark.parametrize('kind', MODELS)
@pytest.mark.parametrize('n_samples', [1, 10])
def test_dataset_smaller_than_one_batch_trains(kind, n_samples):
    X, F = contact_dataset(PALM, n_samples, seed=4)
    def error(epochs):
        model = MODELS[kind](PALM, epochs=epochs, batch_size=256, learning_rate=1e-2, seed=0)
        return np.mean((model.fit(X, F).predict(X) - F) ** 2)
    assert error(60) < error(1)


@pytest.mark.parametrize('kind', MODELS)
def test_compile_batch_equals_predict_for_mixed_taxel_counts(kind):
    cls = MODELS[kind]
    # M4 also mixes hidden widths, so padded hidden units are exercised.
    extra = [dict(hidden=8), {}, {}, {}] if kind == 'M4' else [{}] * 4
    arrays = [PHALANX, TIP, PALM, PHALANX]
    models = [with_random_state(cls, a, seed=i, **h) for i, (a, h) in enumerate(zip(arrays, extra))]
    rng = np.random.default_rng(7)
    inputs = [rng.standard_normal((5, a.n_taxels, 3)) for a in arrays]
    expected = np.stack([m.predict(x) for m, x in zip(models, inputs)], axis=1)   # (5, k, 3)
    forward = cls.compile_batch(models)
    for padding in (0.0, 1e3):      # zero padding per contract; junk there must not leak either
        for t in range(5):
            batch = np.full((len(models), 30, 3), padding)
            for i, x in enumerate(inputs):
                batch[i, :len(x[t])] = x[t]
            out = forward(batch)
            assert out.shape == (len(models), 3) and out.dtype == np.float64
            np.testing.assert_allclose(out, expected[t], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize('kind', MODELS)
def test_compile_batch_covers_the_whole_hand(kind):
    cls = MODELS[kind]
    models = [with_random_state(cls, a, seed=i) for i, a in enumerate(HAND.arrays)]
    X = np.random.default_rng(8).standard_normal((len(models), 30, 3))
    expected = np.concatenate([m.predict(X[i:i + 1, :m.array.n_taxels])
                               for i, m in enumerate(models)])
    np.testing.assert_allclose(cls.compile_batch(models)(X), expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize('kind', MODELS)
def test_raw_count_extremes_stay_finite(fitted, kind):
    model = fitted[0][kind]
    # XELA counts are 16 bit; a quiet taxel sits near 3e4 counts with a spread of tens of counts.
    mean, std = 30000.0, 40.0
    raw = np.array([0.0, 65535.0])[:, None, None] * np.ones((1, TIP.n_taxels, 3))
    X = (raw - mean) / std
    assert np.all(np.isfinite(model.predict(X)))
    assert np.all(np.isfinite(type(model).compile_batch([model, model])(X)))


@pytest.mark.parametrize('kind', MODELS)
def test_float32_and_float64_inputs_agree(fitted, kind):
    model, X = fitted[0][kind], fitted[1]
    np.testing.assert_allclose(model.predict(X.astype(np.float32)), model.predict(X),
                               rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize('kind', MODELS)
def test_state_round_trip_without_pickle(fitted, kind):
    model, X = fitted[0][kind], fitted[1]
    hyper = json.loads(json.dumps(model.hyperparameters()))
    arrays = model.state_arrays()
    assert all(name.endswith('_') and value.dtype == np.float32 for name, value in arrays.items())
    restored = MODELS[kind].from_state(TIP, hyper, arrays)
    np.testing.assert_array_equal(restored.predict(X), model.predict(X))
    assert restored.hyperparameters() == model.hyperparameters()


@pytest.mark.parametrize('kind', MODELS)
def test_state_for_another_array_is_refused(fitted, kind):
    arrays = fitted[0][kind].state_arrays()
    hyper = fitted[0][kind].hyperparameters()
    if kind == 'M5':    # same 6x6 padded grid, so the shapes fit: drop an array instead
        del arrays['norm_running_var_']
        with pytest.raises(ValueError, match='missing'):
            CNNModel.from_state(PHALANX, hyper, arrays)
    else:
        with pytest.raises(ValueError, match='hidden_weight_'):
            MLPModel.from_state(PHALANX, hyper, arrays)


@pytest.mark.parametrize('n', sorted(ARRAYS))
def test_parameter_counts_match_torch_and_paper(n):
    mlp = with_random_state(MLPModel, ARRAYS[n], seed=0)
    cnn = with_random_state(CNNModel, ARRAYS[n], seed=0)
    for model in (mlp, cnn):
        learned = sum(p.numel() for p in model.torch_module().parameters())
        assert model.n_parameters() == learned
    assert mlp.n_parameters() == 48 * n + 69 - 2    # paper's 48n + 69; see m4_mlp docstring
    assert cnn.n_parameters() == 2479               # paper's p_M5: every grid pads to 6x6


@settings(max_examples=20)
@given(h=st.integers(1, 8), w=st.integers(1, 8), data=st.data())
def test_cnn_numpy_matches_torch_on_any_grid(h, w, data):
    mask = np.array(data.draw(st.lists(st.booleans(), min_size=h * w, max_size=h * w)))
    mask[data.draw(st.integers(0, h * w - 1))] = True      # at least one taxel
    array = grid_array('any', mask.reshape(h, w))
    model = with_random_state(CNNModel, array, seed=data.draw(st.integers(0, 100)))
    X = np.random.default_rng(0).standard_normal((4, array.n_taxels, 3))
    np.testing.assert_allclose(model.predict(X), torch_forward(model, X), rtol=1e-5, atol=1e-5)
    assert model.grid.shape == (max(h, 6), max(w, 6))


def test_inference_does_not_import_torch():
    # A fresh interpreter: this test module itself imports torch.
    code = (
        'import sys, types, numpy as np\n'
        'from tacforce_ros.estimation.m4_mlp import MLPModel\n'
        'from tacforce_ros.estimation.m5_cnn import CNNModel\n'
        'grid = np.arange(36).reshape(6, 6)\n'
        'tip = types.SimpleNamespace(name="tip", n_taxels=36, grid_index=grid)\n'
        'for cls in (MLPModel, CNNModel):\n'
        '    shapes = cls(tip)._state_shapes()\n'
        '    m = cls.from_state(tip, {}, {k: np.ones(v) for k, v in shapes.items()})\n'
        '    m.predict(np.zeros((2, 36, 3))); cls.compile_batch([m])(np.zeros((1, 36, 3)))\n'
        'assert "torch" not in sys.modules, "inference imported torch"\n'
    )
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_bad_input_is_refused_with_a_reason():
    model = MLPModel(TIP)
    with pytest.raises(ModelNotFittedError):
        model.predict(np.zeros((1, 30, 3)))
    for cls in MODELS.values():     # no samples in, no forces out (and no crash)
        assert with_random_state(cls, TIP, seed=0).predict(np.zeros((0, 30, 3))).shape == (0, 3)
    with pytest.raises(ValueError, match=r'\(N, 30, 3\)'):
        with_random_state(MLPModel, TIP, seed=0).predict(np.zeros((1, 16, 3)))
    X, F = contact_dataset(TIP, 8, seed=0)
    F[3, 1] = np.nan
    with pytest.raises(ValueError, match='NaN'):
        CNNModel(TIP).fit(X, F)
    with pytest.raises(ValueError, match='zero samples'):
        MLPModel(TIP).fit(X[:0], F[:0])
    with pytest.raises(TypeError, match='other model kinds'):
        MLPModel.compile_batch([with_random_state(CNNModel, TIP, seed=0)])
    with pytest.raises(ValueError, match='shape'):
        MLPModel.compile_batch([with_random_state(MLPModel, TIP, seed=0)])(np.zeros((2, 30, 3)))
    arrays = random_state(CNNModel(TIP), seed=0)
    arrays['norm_running_var_'][2] = -1.0
    with pytest.raises(ValueError, match='negative variances'):
        CNNModel.from_state(TIP, {}, arrays)
    broken = FakeArray('broken', 16, np.arange(16).reshape(4, 4) % 15)   # taxel 15 missing
    with pytest.raises(ValueError, match='exactly once'):
        CNNModel(broken)
    with pytest.raises(ValueError, match='epochs'):
        MLPModel(TIP, epochs=0)
