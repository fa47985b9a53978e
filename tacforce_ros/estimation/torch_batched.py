"""Train k small torch networks of one architecture as one network with stacked weights.

The folds of a cross-validation, the arrays of a campaign and the repeats of a search are tiny
networks on same-shaped data; trained one at a time, each step is dominated by per-operation
overhead, not arithmetic. Here one step runs all k: the architecture's forward over weights
stacked on a leading model axis (batched matmuls, StackedForward), autograd's backward and
torch's Adam, which keeps one parameter tensor per network so that each has its own step count.
Why autograd, not gradients written by hand: the hand-derived backward passes this replaced were
1.2-1.4x faster per step (5 networks on index_tip, batch 256, the two ways alternating in one
process: M4 608-676 against 809-884 us, M5 5.38-6.24 against 6.43-8.74 ms), which does not pay
for a second derivation to keep right beside every change of the forward.

Each network keeps what one-at-a-time training (torch_training.fit_torch_regressor) gives it: its
initial weights (built under its own seed), its shuffling generator, its minibatches (the short
last batch of an epoch included), its Adam moments and step count. A network whose epoch has no
batch left at a step is masked out: no loss, no Adam step (its gradient is dropped, which Adam
skips), no BatchNorm statistics. The result equals one-at-a-time training up to float32
rounding: the batched kernels add in another order, and those differences grow slowly over the
steps (test_estimation_batched_training measures it).

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


class StackedForward(Protocol):
    def __call__(self, torch: Any, params: dict[str, torch.Tensor],
                 buffers: dict[str, torch.Tensor], x: torch.Tensor,
                 mask: torch.Tensor) -> torch.Tensor:
        """Outputs (k, B, 3) of the k stacked networks in training mode: x (k, B, ...), mask
        (k, B) bool of real samples (each network's real samples are its first ones).

        params and buffers are the modules' state_dict entries stacked on a leading k axis
        (autograd tracks params); a layer with statistics (BatchNorm) computes them over the
        real samples and updates its buffers in place, outside autograd.
        """


def fit_models_stacked(models: Sequence[Any], data: Sequence[tuple[np.ndarray, np.ndarray]],
                       architecture: Callable[[Any], Hashable],
                       network_inputs: Callable[[Any, np.ndarray], np.ndarray],
                       forward: StackedForward) -> None:
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
                             [models[i].training for i in rows], forward)
        for i, state in zip(rows, states):
            models[i]._set_state(state)


def fit_stacked(builds: Sequence[Callable[[Any], torch.nn.Module]],
                inputs: Sequence[np.ndarray], targets: Sequence[np.ndarray],
                trainings: Sequence[TorchTraining],
                forward: StackedForward) -> list[dict[str, np.ndarray]]:
    """Train build_i(torch) on (inputs_i, targets_i) with Adam + MSE, all k in one loop.

    Every build must give the same architecture, every input the same per-sample shape, and every
    training the same epochs, batch size, learning rate, threads and device (seeds may differ).
    forward is the architecture's. Returns each network's state as
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
        adam = torch.optim.Adam(weights.leaves, lr=learning_rate, foreach=True)
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
            # Each network's loss is torch's MSELoss over its real samples: the mean of the
            # squared errors of its outputs x real samples.
            return (1.0 / torch.from_numpy(outputs * np.maximum(counts, 1.0)).float())[
                :, None, None].to(device)

        full_weights = sample_weights(np.full(k, batch_size))
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
                error = forward(torch, weights.params(), weights.buffers, x, mask) \
                    - batch[..., width:]
                # The networks share no weight, so each one's gradient is its own loss's.
                error.square().mul(step_weights).sum().backward()
                for i in np.flatnonzero(counts == 0):
                    weights.leaves[i].grad = None       # its epoch is over: Adam skips it
                adam.step()
                adam.zero_grad(set_to_none=True)
        return weights.states()


class _StackedWeights:
    """The k modules' parameters as one flat leaf tensor per network (each its own Adam step
    count), stacked at each step into the per-parameter (k, ...) views the forward reads; their
    buffers stacked (k, ...)."""

    def __init__(self, torch: Any, modules: Sequence[torch.nn.Module],
                 device: torch.device) -> None:
        self.torch, self.k = torch, len(modules)
        states = [m.state_dict() for m in modules]
        parameter_names = [name for name, _ in modules[0].named_parameters()]
        self.shapes = {name: tuple(states[0][name].shape) for name in parameter_names}
        self.leaves = [torch.cat([s[name].reshape(-1) for name in parameter_names]).to(device)
                       .requires_grad_(True) for s in states]
        self.buffers = {name: torch.stack([s[name] for s in states]).to(device)
                        for name, _ in modules[0].named_buffers()
                        if not name.endswith(SKIPPED_TORCH_STATE)}

    def params(self) -> dict[str, torch.Tensor]:
        sizes = [int(np.prod(shape)) for shape in self.shapes.values()]
        flat = self.torch.stack(self.leaves)
        return {name: part.view(self.k, *shape) for (name, shape), part
                in zip(self.shapes.items(), flat.split(sizes, dim=1))}

    def states(self) -> list[dict[str, np.ndarray]]:
        with self.torch.no_grad():
            tensors = {**self.params(), **self.buffers}
        return [{state_name(name): value[i].cpu().numpy().astype(STATE_DTYPE)
                 for name, value in tensors.items()} for i in range(self.k)]
