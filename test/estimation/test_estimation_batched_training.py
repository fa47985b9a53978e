"""Several M4 / M5 networks trained as one (torch_batched) equal the same networks trained one at
a time with torch's own modules and Adam, to float32 rounding: same seeds, same shuffles, the
short last batch of each epoch, datasets of different sizes, BatchNorm statistics included."""
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.cross_validation import cross_validate
from tacforce_ros.estimation.m4_mlp import MLPModel, stacked_mlp_gradient
from tacforce_ros.estimation.m5_cnn import CNNModel
from tacforce_ros.estimation.m5_stacked import conv_as_matrix_index, stacked_cnn_forward
from tacforce_ros.estimation.torch_batched import autograd_gradient, fit_stacked
from tacforce_ros.estimation.torch_training import TorchTraining
from tacforce_ros.estimation.training import fit_bundle
from tacforce_ros.hand.description import load_hand

HAND = load_hand()
TIP, PHALANX = HAND.array('index_tip'), HAND.array('index_middle')
# Sizes chosen so the networks' epochs end at different steps, one inside its first batch.
SIZES = (300, 157, 40)
# float32 rounding of reordered sums, grown over a few hundred Adam steps (measured ~1e-6).
WEIGHT_RTOL = 1e-4
# Larger than the paper's 2.5e-4 so a few epochs move the weights. At 1e-2, after 5 steps of an
# M5 on a phalanx, 16 weights differed by ~lr while at 3e-3 and below every weight agreed to
# <= 5e-6: a jump, not growth, so (inferred) a unit near its ReLU threshold whose branch the
# rounding decided at the larger step.
LEARNING_RATE = 3e-3


def datasets(array, sizes, seed=0):
    rng = np.random.default_rng(seed)
    data = []
    for size in sizes:
        X = rng.standard_normal((size, array.n_taxels, 3))
        F = np.tanh(X.reshape(size, -1)[:, :3] + 0.5 * X.reshape(size, -1)[:, 3:6] ** 2)
        data.append((X, F, np.zeros(size, dtype=int)))
    return data


def assert_same_training(one, together):
    for a, b in zip(one, together):
        sa, sb = a.state_arrays(), b.state_arrays()
        assert sa.keys() == sb.keys()
        for name in sa:
            scale = max(float(np.abs(sa[name]).max()), 1e-3)
            np.testing.assert_allclose(sb[name], sa[name], rtol=0, atol=WEIGHT_RTOL * scale,
                                       err_msg=f'{a.kind} {name}')


def fit_both(cls, arrays, data, **hyper):
    one = [cls(array, seed=i, **hyper) for i, array in enumerate(arrays)]
    for model, (X, F, _) in zip(one, data):
        model.fit(X, F)
    together = [cls(array, seed=i, **hyper) for i, array in enumerate(arrays)]
    cls.fit_many(together, data)
    return one, together


@pytest.mark.parametrize('cls, array', [(MLPModel, TIP), (CNNModel, TIP), (CNNModel, PHALANX)])
def test_networks_trained_together_equal_one_at_a_time(cls, array, training_device):
    data = datasets(array, SIZES)
    one, together = fit_both(cls, [array] * len(SIZES), data, epochs=3, batch_size=64,
                             learning_rate=LEARNING_RATE, device=training_device)
    assert_same_training(one, together)
    if cls is CNNModel:     # the BatchNorm running statistics moved, and moved alike
        assert not np.allclose(together[0].state_arrays()['norm_running_var_'], 1.0)


def test_models_of_different_architectures_form_separate_groups():
    """Tip (30 taxels) and phalanx (16) CNNs, and a lone M5 of other settings, in one call."""
    arrays = [TIP, PHALANX, TIP, PHALANX]
    data = [datasets(a, (120,), seed=i)[0] for i, a in enumerate(arrays)]
    hyper = dict(batch_size=32, learning_rate=LEARNING_RATE)
    epochs = [2, 2, 2, 3]                       # the last is alone in its group
    together = [CNNModel(a, seed=i, epochs=e, **hyper) for i, (a, e) in enumerate(zip(arrays,
                                                                                         epochs))]
    CNNModel.fit_many(together, data)
    one = [CNNModel(a, seed=i, epochs=e, **hyper) for i, (a, e) in enumerate(zip(arrays, epochs))]
    for model, (X, F, _) in zip(one, data):
        model.fit(X, F)
    assert_same_training(one, together)


@settings(max_examples=12, deadline=None)
@given(sizes=st.lists(st.integers(1, 90), min_size=2, max_size=4),
       batch_size=st.integers(1, 40), seed=st.integers(0, 2 ** 16))
def test_any_sizes_and_batch_size_train_alike(sizes, batch_size, seed):
    data = datasets(PHALANX, sizes, seed)
    one, together = fit_both(MLPModel, [PHALANX] * len(sizes), data, epochs=2,
                             batch_size=batch_size, learning_rate=LEARNING_RATE, hidden=4)
    assert_same_training(one, together)


def test_training_together_is_deterministic(training_device):
    data = datasets(TIP, SIZES)
    runs = []
    for _ in range(2):
        models = [CNNModel(TIP, seed=i, epochs=1, batch_size=64, device=training_device)
                  for i in range(len(SIZES))]
        CNNModel.fit_many(models, data)
        runs.append([m.state_arrays() for m in models])
    for a, b in zip(*runs):
        for name in a:
            np.testing.assert_array_equal(a[name], b[name])


def test_cross_validation_folds_together_match_folds_one_at_a_time(tip_data):
    data, X, F, _ = tip_data
    hyper = dict(epochs=2, batch_size=128, learning_rate=LEARNING_RATE)
    together = cross_validate(TIP, 'M4', hyper, X, F, data.plates, together=True)
    alone = cross_validate(TIP, 'M4', hyper, X, F, data.plates, together=False)
    assert [f.test_plate for f in together.folds] == [f.test_plate for f in alone.folds]
    for a, b in zip(alone.folds, together.folds):
        assert b.stats.e_hat_mean == pytest.approx(a.stats.e_hat_mean, rel=1e-4)
        assert b.train_seconds > 0


def test_the_final_model_trains_with_the_folds_as_it_would_alone(tip_data):
    """cross_validate(final=True): the folds are unchanged and the model on every plate equals
    fit_bundle's on the same data (what the main job and train ship)."""
    data, X, F, _ = tip_data
    hyper = dict(epochs=2, batch_size=128, learning_rate=LEARNING_RATE)
    with_final = cross_validate(TIP, 'M4', hyper, X, F, data.plates, final=True)
    folds_only = cross_validate(TIP, 'M4', hyper, X, F, data.plates)
    assert folds_only.final is None
    for a, b in zip(folds_only.folds, with_final.folds):
        assert b.stats.e_hat_mean == pytest.approx(a.stats.e_hat_mean, rel=1e-4)
    alone = fit_bundle(TIP, 'M4', hyper, X, F, data.plates)
    assert_same_training([alone.model], [with_final.final.model])
    np.testing.assert_allclose(with_final.final.predict(X), alone.predict(X), atol=1e-4)


def test_networks_trained_together_must_share_their_optimiser_settings():
    build = MLPModel(TIP)._build
    X, F = np.zeros((4, 90)), np.zeros((4, 3))
    with pytest.raises(ValueError, match='must share epochs'):
        fit_stacked([build, build], [X, X], [F, F],
                    [TorchTraining(epochs=1), TorchTraining(epochs=2)], lambda *a: None)


@settings(max_examples=20, deadline=None)
@given(k=st.integers(1, 4), batch=st.integers(1, 20), hidden=st.integers(1, 8),
       seed=st.integers(0, 2 ** 16))
def test_the_hand_written_mlp_gradient_is_autograds(k, batch, hidden, seed):
    """Weighted squared error with some samples weighted zero (not real), and hidden units
    below their ReLU threshold (biases drawn around zero)."""
    import torch

    rng = np.random.default_rng(seed)
    n_in = 9

    def tensor(*shape):
        return torch.as_tensor(rng.standard_normal(shape), dtype=torch.float32)

    params = {'hidden.weight': tensor(k, hidden, n_in), 'hidden.bias': tensor(k, hidden),
              'output.weight': tensor(k, 3, hidden), 'output.bias': tensor(k, 3)}
    x, targets = tensor(k, batch, n_in), tensor(k, batch, 3)
    weights = torch.as_tensor(rng.uniform(0, 1, (k, batch, 1)) * (rng.uniform(size=(k, batch, 1))
                                                                   > 0.3), dtype=torch.float32)
    with torch.no_grad():
        by_hand = stacked_mlp_gradient(torch, params, {}, x, weights[..., 0] > 0, targets,
                                       weights)
    leaves = {name: value.clone().requires_grad_(True) for name, value in params.items()}
    hidden_out = torch.relu(x @ leaves['hidden.weight'].transpose(1, 2)
                            + leaves['hidden.bias'][:, None])
    output = hidden_out @ leaves['output.weight'].transpose(1, 2) + leaves['output.bias'][:, None]
    ((weights * (output - targets) ** 2).sum() / 2).backward()
    for name, leaf in leaves.items():
        np.testing.assert_allclose(by_hand[name].numpy(), leaf.grad.numpy(), rtol=1e-5,
                                   atol=1e-5, err_msg=name)


@settings(max_examples=10, deadline=None)
@given(real=st.lists(st.integers(0, 9), min_size=1, max_size=3), seed=st.integers(0, 2 ** 16),
       phalanx=st.booleans())
def test_the_stacked_cnn_gradient_is_torchs_modules(real, seed, phalanx):
    """Each network's gradient (autograd's over the stacked forward, with the BatchNorm folded)
    and BatchNorm statistics against its own torch module in training mode with MSELoss on its
    real samples; the batch holds 9 samples, the rest not real. A network with none (its epoch
    over) gets no gradient and keeps its statistics."""
    import torch

    array = PHALANX if phalanx else TIP
    rng = np.random.default_rng(seed)
    batch, k = 9, len(real)
    modules = []
    for i in range(k):
        torch.manual_seed(seed + i)
        modules.append(CNNModel(array)._build(torch).train())
    images = CNNModel(array).images(rng.standard_normal((k * batch, array.n_taxels, 3)))
    x = torch.as_tensor(images, dtype=torch.float32).view(k, batch, *images.shape[1:])
    targets = torch.as_tensor(rng.standard_normal((k, batch, 3)), dtype=torch.float32)
    mask = torch.as_tensor(np.arange(batch)[None] < np.array(real)[:, None])
    weights = (mask / (1.5 * torch.as_tensor(real, dtype=torch.float32).clamp(min=1))[:, None])[
        ..., None]
    states = [m.state_dict() for m in modules]
    params = {name: torch.stack([s[name] for s in states]).clone()
              for name, _ in modules[0].named_parameters()}
    buffers = {name: torch.stack([s[name] for s in states]).clone()
               for name in ('norm.running_mean', 'norm.running_var')}
    before = {name: value.clone() for name, value in buffers.items()}
    stacked = autograd_gradient(stacked_cnn_forward)(torch, params, buffers, x, mask, targets,
                                                     weights)
    for i, module in enumerate(modules):
        n = real[i]
        if n == 0:
            for name in stacked:
                assert not stacked[name][i].any(), name
            for name in buffers:
                assert torch.equal(buffers[name][i], before[name][i]), name
            continue
        prediction = module(x[i, :n].permute(0, 3, 1, 2))
        torch.nn.functional.mse_loss(prediction, targets[i, :n]).backward()
        for name, parameter in module.named_parameters():
            np.testing.assert_allclose(stacked[name][i].numpy(), parameter.grad.numpy(),
                                       rtol=1e-4, atol=1e-5, err_msg=name)
        for name in buffers:
            np.testing.assert_allclose(buffers[name][i].numpy(),
                                       module.state_dict()[name].numpy(), rtol=1e-5,
                                       atol=1e-6, err_msg=name)


def test_the_dense_form_of_a_valid_convolution_is_the_convolution():
    """conv_as_matrix_index against a direct loop over output cells (hand-computed case)."""
    rng = np.random.default_rng(3)
    H, W, C, n_out, k = 5, 4, 2, 3, 2
    weight = rng.standard_normal((n_out, C, k, k))
    image = rng.standard_normal((H, W, C))
    index = conv_as_matrix_index((H, W, C), n_out, k)
    matrix = np.append(weight.ravel(), 0.0)[index]
    expected = np.empty((H - k + 1, W - k + 1, n_out))
    for i in range(H - k + 1):
        for j in range(W - k + 1):
            patch = image[i:i + k, j:j + k].transpose(2, 0, 1)        # (C, k, k)
            expected[i, j] = (weight * patch).sum(axis=(1, 2, 3))
    np.testing.assert_allclose(image.reshape(-1) @ matrix, expected.reshape(-1), rtol=1e-12)


@pytest.mark.parametrize('device, reason', [('cuda:banana', 'unknown torch device'),
                                            ('meta', 'training runs on cpu or cuda')])
def test_a_device_training_cannot_run_on_is_refused_with_the_reason(device, reason):
    with pytest.raises(ValueError, match=reason):
        fit_both(MLPModel, [TIP], datasets(TIP, (20,)), epochs=1, device=device)


@pytest.mark.skipif(not torch.cuda.is_available(), reason='no CUDA GPU here')
@pytest.mark.parametrize('cls, array', [(MLPModel, TIP), (CNNModel, TIP), (CNNModel, PHALANX)])
def test_a_gpu_trains_the_network_the_cpu_does(cls, array):
    """Same seeds, same shuffles, float32 on both (no TF32): the weights agree to the rounding
    of reordered sums, one at a time and stacked."""
    data = datasets(array, SIZES)
    hyper = dict(epochs=3, batch_size=64, learning_rate=LEARNING_RATE)
    cpu = fit_both(cls, [array] * len(SIZES), data, device='cpu', **hyper)
    gpu = fit_both(cls, [array] * len(SIZES), data, device='cuda', **hyper)
    assert_same_training(cpu[0], gpu[0])
    assert_same_training(cpu[1], gpu[1])


@pytest.mark.parametrize('cls', [MLPModel, CNNModel])
def test_the_training_device_is_not_a_hyperparameter_of_the_model(cls):
    """Where a model trained is not what it is: its file does not keep the device, and the
    explicit CPU trains as the default does, one at a time and stacked."""
    data = datasets(TIP, (40, 30))
    default = fit_both(cls, [TIP, TIP], data, epochs=1, batch_size=16)
    explicit = fit_both(cls, [TIP, TIP], data, epochs=1, batch_size=16, device='cpu')
    for a, b in zip(default[0] + default[1], explicit[0] + explicit[1]):
        for name, value in a.state_arrays().items():
            np.testing.assert_array_equal(b.state_arrays()[name], value)
        assert 'device' not in b.hyperparameters()
        assert b.hyperparameters() == a.hyperparameters()
