"""Train k small torch networks of one architecture as one network with stacked weights.

The folds of a cross-validation, the arrays of a campaign and the repeats of a search are tiny
networks on same-shaped data; trained one at a time, each step is dominated by per-operation
overhead, not arithmetic. Here one step runs all k: a batched forward and backward over weights
stacked on a leading model axis (batched matmuls), then one Adam update. The architecture brings
its gradient (StackedGradient): autograd's over its stacked forward (autograd_gradient), or one
written by hand where a measurement beside it shows that it pays (M4's).

Each network keeps what one-at-a-time training (torch_training.fit_torch_regressor) gives it: its
initial weights (built under its own seed), its shuffling generator, its minibatches (the short
last batch of an epoch included), its Adam moments and step count. A network whose epoch has no
batch left at a step is masked out: no loss, no Adam step, no BatchNorm statistics. The result
equals one-at-a-time training up to float32 rounding: the batched kernels add in another order,
and those differences grow slowly over the steps (test_estimation_batched_training measures it).

Torch is imported inside the functions, as in torch_training.
"""
from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from tacforce_ros.estimation.base import check_inputs
from tacforce_ros.estimation.torch_training import (SKIPPED_TORCH_STATE, STATE_DTYPE,
                                                    TorchTraining, reproducible_torch,
                                                    state_name, torch_device)

if TYPE_CHECKING:
    import torch

# torch.optim.Adam's defaults, which the one-at-a-time fit uses.
ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8


class StackedGradient(Protocol):
    def __call__(self, torch: Any, params: dict[str, torch.Tensor],
                 buffers: dict[str, torch.Tensor], x: torch.Tensor, mask: torch.Tensor,
                 targets: torch.Tensor, weights: torch.Tensor) -> dict[str, torch.Tensor]:
        """Gradient, per parameter of params, of sum(weights * (f(x) - targets) ** 2) / 2 for
        the k stacked networks f in training mode: x (k, B, ...), mask (k, B) bool of real
        samples, targets (k, B, 3), weights (k, B, 1), zero where mask is False.

        params and buffers are the modules' state_dict entries stacked on a leading k axis; a
        layer with statistics (BatchNorm) updates its buffers in place from the real samples.
        """


class StackedForward(Protocol):
    def __call__(self, torch: Any, params: dict[str, torch.Tensor],
                 buffers: dict[str, torch.Tensor], x: torch.Tensor,
                 mask: torch.Tensor) -> torch.Tensor:
        """Outputs (k, B, 3) of the k stacked networks in training mode, for StackedGradient's
        x and mask; a layer with statistics computes them over the real samples and updates its
        buffers in place, outside autograd."""


def autograd_gradient(forward: StackedForward) -> StackedGradient:
    """The StackedGradient of a stacked forward, by autograd."""
    def gradient(torch: Any, params: dict, buffers: dict, x: torch.Tensor, mask: torch.Tensor,
                 targets: torch.Tensor, weights: torch.Tensor) -> dict:
        leaves = {name: value.detach().requires_grad_(True) for name, value in params.items()}
        error = forward(torch, leaves, buffers, x, mask) - targets
        loss = error.square().mul(weights).sum() / 2
        return dict(zip(leaves, torch.autograd.grad(loss, list(leaves.values()))))

    gradient.by_autograd = True
    return gradient


def fit_models_stacked(models: Sequence[Any], data: Sequence[tuple[np.ndarray, np.ndarray]],
                       architecture: Callable[[Any], Hashable],
                       network_inputs: Callable[[Any, np.ndarray], np.ndarray],
                       gradient: StackedGradient) -> None:
    """Fit models[i] (M4 or M5) on data[i] = (X, F), stacking those of one architecture and
    training settings; a model alone in its group trains one at a time (model.fit).

    architecture(model) keys the groups; network_inputs(model, X) is what its network reads.
    """
    groups: dict[Hashable, list[int]] = {}
    for i, model in enumerate(models):
        t = model.training
        key = (architecture(model), t.epochs, t.batch_size, t.learning_rate, t.threads,
               t.device)
        groups.setdefault(key, []).append(i)
    for rows in groups.values():
        if len(rows) == 1:
            models[rows[0]].fit(*data[rows[0]])
            continue
        checked = [check_inputs(data[i][0], models[i].array.n_taxels, data[i][1]) for i in rows]
        states = fit_stacked([models[i]._build for i in rows],
                             [network_inputs(models[i], X).astype(np.float32)
                              for i, X in zip(rows, checked)],
                             [np.asarray(data[i][1], dtype=np.float64) for i in rows],
                             [models[i].training for i in rows], gradient)
        for i, state in zip(rows, states):
            models[i]._set_state(state)


def fit_stacked(builds: Sequence[Callable[[Any], torch.nn.Module]],
                inputs: Sequence[np.ndarray], targets: Sequence[np.ndarray],
                trainings: Sequence[TorchTraining],
                gradient: StackedGradient) -> list[dict[str, np.ndarray]]:
    """Train build_i(torch) on (inputs_i, targets_i) with Adam + MSE, all k in one loop.

    Every build must give the same architecture, every input the same per-sample shape, and every
    training the same epochs, batch size, learning rate, threads and device (seeds may differ).
    gradient is the architecture's. Returns each network's state as
    torch_training.module_state would.
    """
    import torch

    k = len(builds)
    if not (k == len(inputs) == len(targets) == len(trainings)) or k == 0:
        raise ValueError('fit_stacked needs one build, input, target and training per network')
    settings = {(t.epochs, t.batch_size, t.learning_rate, t.threads, t.device)
                for t in trainings}
    if len(settings) != 1:
        raise ValueError(f'networks trained together must share epochs, batch size, learning '
                         f'rate, threads and device; got {sorted(settings)}')
    if len({np.shape(x)[1:] for x in inputs}) != 1 or min(len(x) for x in inputs) < 1:
        raise ValueError('inputs must be non-empty and of one per-sample shape')
    epochs, batch_size, learning_rate, threads, device_name = settings.pop()
    device = torch_device(device_name)
    with reproducible_torch(threads, device):
        modules = []
        for build, training in zip(builds, trainings):
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(training.seed)
                modules.append(build(torch).to(torch.float32))
        weights = _StackedWeights(torch, modules, device)
        params = weights.params()       # views: Adam updates them in place
        adam = _MaskedAdam(torch, weights.flat, learning_rate)
        shuffles = [torch.Generator().manual_seed(t.seed) for t in trainings]   # on the CPU
        sizes = np.array([len(x) for x in inputs])
        feature_shape, width = np.shape(inputs[0])[1:], int(np.prod(np.shape(inputs[0])[1:]))
        outputs = np.shape(targets[0])[1]
        # Inputs and targets side by side, network i's sample j in row i * N_max + j, so one
        # index_select per step fetches every network's batch.
        samples = torch.zeros((k, int(sizes.max()), width + outputs), dtype=torch.float32)
        for i, (x, y) in enumerate(zip(inputs, targets)):
            samples[i, :len(x), :width] = torch.as_tensor(np.reshape(x, (len(x), width)),
                                                          dtype=torch.float32)
            samples[i, :len(y), width:] = torch.as_tensor(y, dtype=torch.float32)
        first_rows = torch.arange(k)[:, None] * samples.shape[1]
        samples = samples.flatten(0, 1).to(device)
        steps = -(-int(sizes.max()) // batch_size)
        real = torch.arange(steps * batch_size)[None] < torch.as_tensor(sizes)[:, None]
        real = real.to(device)

        def sample_weights(counts: np.ndarray) -> torch.Tensor:
            # Each network's loss is torch's MSELoss over its real samples: the gradient's
            # weights are 2 / (outputs * real samples) (the 2 of StackedGradient's / 2).
            return (2.0 / torch.from_numpy(outputs * np.maximum(counts, 1.0)).float())[
                :, None, None].to(device)

        full_weights = sample_weights(np.full(k, batch_size))
        # A gradient by hand leaves autograd nothing to track: inference mode drops its
        # per-operation bookkeeping (a hand-written M5 gradient 2070 -> 1872 us against no mode,
        # best of 6).
        with torch.inference_mode(not getattr(gradient, 'by_autograd', False)):
            for _ in range(epochs):
                order = torch.zeros((k, steps * batch_size), dtype=torch.long)
                for i, (size, shuffle) in enumerate(zip(sizes, shuffles)):
                    order[i, :size] = torch.randperm(int(size), generator=shuffle)
                order = (order + first_rows).to(device)
                for start in range(0, steps * batch_size, batch_size):
                    counts = np.clip(sizes - start, 0, batch_size)
                    mask = real[:, start:start + batch_size]
                    batch = samples.index_select(0, order[:, start:start + batch_size].reshape(-1))
                    batch = batch.view(k, batch_size, width + outputs)
                    x = batch[..., :width].view(k, batch_size, *feature_shape)
                    step_weights = full_weights
                    if counts.min() < batch_size:
                        step_weights = sample_weights(counts) * mask[..., None]
                    grads = gradient(torch, params, weights.buffers, x, mask, batch[..., width:],
                                     step_weights)
                    adam.step(torch.cat([grads[name].reshape(k, -1) for name in weights.shapes],
                                        dim=1), counts > 0)
        return weights.states()


class _StackedWeights:
    """The k modules' parameters as one (k, P) tensor (one Adam update for all), their buffers
    stacked (k, ...), and the per-parameter views the gradient reads."""

    def __init__(self, torch: Any, modules: Sequence[torch.nn.Module],
                 device: torch.device) -> None:
        self.k = len(modules)
        states = [m.state_dict() for m in modules]
        parameter_names = [name for name, _ in modules[0].named_parameters()]
        self.shapes = {name: tuple(states[0][name].shape) for name in parameter_names}
        self.flat = torch.cat([torch.stack([s[name].reshape(-1) for s in states])
                               for name in parameter_names], dim=1).to(device)
        self.buffers = {name: torch.stack([s[name] for s in states]).to(device)
                        for name, _ in modules[0].named_buffers()
                        if not name.endswith(SKIPPED_TORCH_STATE)}

    def params(self) -> dict[str, torch.Tensor]:
        sizes = [int(np.prod(shape)) for shape in self.shapes.values()]
        return {name: part.view(self.k, *shape) for (name, shape), part
                in zip(self.shapes.items(), self.flat.split(sizes, dim=1))}

    def states(self) -> list[dict[str, np.ndarray]]:
        tensors = {**self.params(), **self.buffers}
        return [{state_name(name): value[i].cpu().numpy().astype(STATE_DTYPE)
                 for name, value in tensors.items()} for i in range(self.k)]


class _MaskedAdam:
    """torch.optim.Adam's update (no weight decay, no amsgrad) on the rows of a (k, P) tensor,
    with a step count per row; rows not active at a step are left untouched.

    Why not torch.optim.Adam: it keeps one step count per parameter tensor, and the k networks in
    one tensor end their epochs at different steps, so each needs its own count and its own
    skipped steps. (torch's Adam over one parameter tensor per network, stacked at each step,
    made a step of 5 M4 networks 901-928 us against 633-678 us with this.)
    test_estimation_batched_training checks the result against torch's Adam.
    """

    def __init__(self, torch: Any, flat: torch.Tensor, learning_rate: float) -> None:
        self.torch, self.flat, self.learning_rate = torch, flat, learning_rate
        self.first = torch.zeros_like(flat, requires_grad=False)
        self.second = torch.zeros_like(flat, requires_grad=False)
        self.steps = np.zeros(flat.shape[0], dtype=np.int64)

    def step(self, gradient: torch.Tensor, active: np.ndarray) -> None:
        """One update of the rows where `active` (k,) is True, from their (k, P) gradient."""
        torch = self.torch
        beta1, beta2 = ADAM_BETAS
        self.steps += active
        if active.all():
            rows, steps = None, self.steps
            param, first, second, grad = self.flat, self.first, self.second, gradient
        else:
            rows = torch.from_numpy(np.flatnonzero(active)).to(self.flat.device)
            steps = self.steps[active]
            param, first, second = self.flat[rows], self.first[rows], self.second[rows]
            grad = gradient[rows]
        first.lerp_(grad, 1 - beta1)
        second.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        # Bias corrections in float64, then float32, as Adam's python-float scalars are.
        step_size = torch.from_numpy(self.learning_rate / (1 - beta1 ** steps)).float().to(
            self.flat.device)
        correction2 = torch.from_numpy(np.sqrt(1 - beta2 ** steps)).float().to(
            self.flat.device)
        denominator = second.sqrt().div_(correction2[:, None]).add_(ADAM_EPS)
        param.sub_(first.div(denominator).mul_(step_size[:, None]))
        if rows is not None:
            self.flat.index_copy_(0, rows, param)
            self.first.index_copy_(0, rows, first)
            self.second.index_copy_(0, rows, second)
