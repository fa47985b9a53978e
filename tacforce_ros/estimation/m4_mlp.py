"""M4: fully connected MLP 3n -> 16 -> 3 (paper Sec. III), trained with torch, run with numpy.

Architecture. The paper describes "an input layer of size 3n with ReLU, a hidden layer of size 16
with ReLU and a linear output layer of size 3" and counts p = 48n + 69. We read the input layer as
the 3n-vector itself, with no activation on it: a ReLU on standardised inputs would discard every
below-mean reading (half of the signal) and has no parameters, so it cannot be what p counts. The
network is therefore Linear(3n, 16) -> ReLU -> Linear(16, 3) with p = 48n + 67
(16 x 3n + 16 + 3 x 16 + 3); no layout with one 16-wide hidden layer gives the paper's extra 2.

Training (paper Sec. IV-A): Adam, batch 256, lr 2.5e-4, 40 epochs, MSE, all hyper-parameters.
Torch is imported inside fit only (importing it takes ~1.5 s), so loading a model file and the
100 Hz inference stay torch-free.

Inference runs in float32 on purpose: the weights were trained in float32, so float64 arithmetic
adds no accuracy, and the float32 forward of numpy matches torch's to float32 rounding. Outputs are
returned as float64 like every other model's.

Training and state conversion are shared with M5 (torch_training.py).
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from tacforce_ros.estimation.base import ForceModel, ModelNotFittedError, check_inputs
from tacforce_ros.estimation.torch_batched import fit_models_stacked
from tacforce_ros.estimation.torch_training import (STATE_DTYPE, TorchTraining, checked_state,
                                                    fit_torch_regressor, load_module_state,
                                                    module_state)

if TYPE_CHECKING:
    import torch

    from tacforce_ros.hand.description import TaxelArray


def relu(x: np.ndarray) -> np.ndarray:
    """In-place ReLU on a freshly computed array."""
    return np.maximum(x, 0.0, out=x)


def mlp_forward(x: np.ndarray, w1: np.ndarray, b1: np.ndarray,
                w2: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """relu(x @ w1 + b1) @ w2 + b2, with weights stored input-major (in, out).

    Shapes broadcast as in np.matmul, so one piece serves one model on N samples
    (x (N, 3n), w1 (3n, 16)) and k stacked models on one sample each (x (k, 1, 3n), w1 (k, 3n, 16)).
    """
    return relu(x @ w1 + b1) @ w2 + b2


def stacked_mlp_gradient(torch: Any, params: dict, buffers: dict, x: torch.Tensor,
                         mask: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor) -> dict:
    """Training gradient of k stacked M4 networks (torch_batched.StackedGradient), by hand.

    Why not autograd: with it, training is at least 1.5x slower. A step of 5 networks on
    index_tip (batch 256, two rounds alternating in one process, load 1): 633-678 us by hand with
    the masked Adam against 986-1025 us with autograd and 1225-1324 us with autograd and torch's
    Adam; `bench_train --models M4 M5 --samples 100000`, one after the other (code 30156d1 by
    hand, 38cbb82 with autograd and torch's Adam): the five folds together in 10.8 s against
    31.4 s, at equal held-out e_hat (0.0379 N both). The two agree to float32 rounding
    (test_estimation_batched_training).
    """
    w1, w2 = params['hidden.weight'], params['output.weight']
    hidden = torch.baddbmm(params['hidden.bias'][:, None], x, w1.transpose(1, 2)).relu_()
    d_output = torch.baddbmm(params['output.bias'][:, None], hidden, w2.transpose(1, 2))
    d_output.sub_(targets).mul_(weights)
    # ReLU's backward as autograd runs it (zero where the unit is off, at 0 too), one kernel.
    d_hidden = torch.ops.aten.threshold_backward(torch.bmm(d_output, w2), hidden, 0.0)
    return {'hidden.weight': torch.bmm(d_hidden.transpose(1, 2), x),
            'hidden.bias': d_hidden.sum(dim=1),
            'output.weight': torch.bmm(d_output.transpose(1, 2), hidden),
            'output.bias': d_output.sum(dim=1)}


class MLPModel(ForceModel):
    """M4: Linear(3n, hidden) -> ReLU -> Linear(hidden, 3) over the flattened taxel inputs."""

    kind: ClassVar[str] = 'M4'

    def __init__(self, array: TaxelArray, *, hidden: int = 16, epochs: int = 40,
                 batch_size: int = 256, learning_rate: float = 2.5e-4, seed: int = 0,
                 threads: int = 1, device: str = 'cpu') -> None:
        super().__init__(array)
        if int(hidden) < 1:
            raise ValueError(f'hidden must be >= 1, got {hidden}')
        self.hidden = int(hidden)
        self.training = TorchTraining(epochs, batch_size, learning_rate, seed, threads, device)
        self._state: dict[str, np.ndarray] | None = None

    def _state_shapes(self) -> dict[str, tuple[int, ...]]:
        n_inputs = 3 * self.array.n_taxels
        return {'hidden_weight_': (self.hidden, n_inputs), 'hidden_bias_': (self.hidden,),
                'output_weight_': (3, self.hidden), 'output_bias_': (3,)}

    def _build(self, torch: Any) -> torch.nn.Module:
        nn = torch.nn
        return nn.Sequential(OrderedDict([
            ('hidden', nn.Linear(3 * self.array.n_taxels, self.hidden)),
            ('relu', nn.ReLU()),
            ('output', nn.Linear(self.hidden, 3)),
        ]))

    def fit(self, X: np.ndarray, F: np.ndarray) -> MLPModel:
        X = check_inputs(X, self.array.n_taxels, F)
        module = fit_torch_regressor(self._build, X.reshape(len(X), 3 * self.array.n_taxels), F,
                                     self.training)
        return self._set_state(module_state(module))

    @classmethod
    def fit_many(cls, models: Sequence[ForceModel],
                 data: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        """Models of one input width and hidden width train as one stacked network."""
        fit_models_stacked(same_kind_models(cls, models), [(X, F) for X, F, _ in data],
                           lambda m: (m.array.n_taxels, m.hidden),
                           lambda m, X: X.reshape(len(X), 3 * m.array.n_taxels),
                           gradient=stacked_mlp_gradient)

    def _set_state(self, arrays: dict[str, np.ndarray]) -> MLPModel:
        self._state = checked_state(arrays, self._state_shapes(), self.kind)
        return self

    def _fitted_state(self) -> dict[str, np.ndarray]:
        if self._state is None:
            raise ModelNotFittedError(f'{self.kind} model for {self.array.name} is not fitted')
        return self._state

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = check_inputs(X, self.array.n_taxels)
        s = self._fitted_state()
        x = X.reshape(len(X), 3 * self.array.n_taxels).astype(np.float32)
        out = mlp_forward(x, s['hidden_weight_'].T, s['hidden_bias_'],
                          s['output_weight_'].T, s['output_bias_'])
        return out.astype(np.float64)

    def torch_module(self) -> torch.nn.Module:
        """The fitted network as an eval-mode torch module (fine-tuning, export, cross-checks)."""
        import torch

        return load_module_state(self._build(torch), self._fitted_state())

    def n_parameters(self) -> int:
        return sum(int(np.prod(shape)) for shape in self._state_shapes().values())

    def hyperparameters(self) -> dict:
        return {'hidden': self.hidden, **self.training.hyperparameters()}

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {name: value.copy() for name, value in self._fitted_state().items()}

    @classmethod
    def from_state(cls, array: TaxelArray, hyper: dict,
                   arrays: dict[str, np.ndarray]) -> MLPModel:
        return cls(array, **hyper)._set_state(arrays)

    @classmethod
    def compile_batch(cls, models: Sequence[ForceModel]) -> Callable[[np.ndarray], np.ndarray]:
        """Stack k MLPs once; the callable maps (k, n_max, 3) -> (k, 3) in one matmul chain.

        Hidden layers of different widths and taxel counts are zero-padded: padded input columns
        multiply zeros, padded hidden units have zero weights and bias, so both contribute nothing.
        """
        mlps = same_kind_models(cls, models)
        n_max = max(m.array.n_taxels for m in mlps)
        width = max(m.hidden for m in mlps)
        k = len(mlps)
        w1 = np.zeros((k, 3 * n_max, width), STATE_DTYPE)
        b1 = np.zeros((k, 1, width), STATE_DTYPE)
        w2 = np.zeros((k, width, 3), STATE_DTYPE)
        b2 = np.zeros((k, 1, 3), STATE_DTYPE)
        for i, m in enumerate(mlps):
            s = m._fitted_state()
            n_in = 3 * m.array.n_taxels
            w1[i, :n_in, :m.hidden] = s['hidden_weight_'].T
            b1[i, 0, :m.hidden] = s['hidden_bias_']
            w2[i, :m.hidden] = s['output_weight_'].T
            b2[i, 0] = s['output_bias_']
        expected = (k, n_max, 3)

        def forward(X: np.ndarray) -> np.ndarray:
            if X.shape != expected:
                raise ValueError(f'batched M4 input must have shape {expected}, got {X.shape}')
            x = X.astype(np.float32).reshape(k, 1, 3 * n_max)
            return mlp_forward(x, w1, b1, w2, b2).reshape(k, 3).astype(np.float64)

        return forward


def same_kind_models(cls: type[ForceModel], models: Sequence[ForceModel]) -> list:
    """The models as a list, refusing an empty batch or models of another kind."""
    models = list(models)
    if not models:
        raise ValueError(f'compile_batch needs at least one {cls.kind} model')
    wrong = [type(m).__name__ for m in models if not isinstance(m, cls)]
    if wrong:
        raise TypeError(f'{cls.__name__}.compile_batch got other model kinds: {wrong}')
    return models
