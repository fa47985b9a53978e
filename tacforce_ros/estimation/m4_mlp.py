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

The torch helpers here (TorchTraining, fit_torch_regressor, module state conversion) are shared
with M5 (m5_cnn.py).
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from tacforce_ros.estimation.base import ForceModel, ModelNotFittedError, check_inputs

if TYPE_CHECKING:
    import torch

    from tacforce_ros.hand.description import TaxelArray

STATE_DTYPE = np.float32
# Torch buffers that are bookkeeping, not learned state the numpy forward needs.
_SKIPPED_TORCH_STATE = ('num_batches_tracked',)


@dataclass(frozen=True)
class TorchTraining:
    """Optimiser settings shared by the torch-trained models (defaults: paper Sec. IV-A)."""

    epochs: int = 40
    batch_size: int = 256
    learning_rate: float = 2.5e-4
    seed: int = 0
    threads: int = 1        # torch intra-op threads during fit; fixed so runs are reproducible

    def __post_init__(self) -> None:
        for name in ('epochs', 'batch_size', 'threads'):
            if int(getattr(self, name)) < 1:
                raise ValueError(f'{name} must be >= 1, got {getattr(self, name)}')
        if not float(self.learning_rate) > 0.0:
            raise ValueError(f'learning_rate must be > 0, got {self.learning_rate}')
        # Normalise types so hyperparameters() is plain JSON whatever the caller passed.
        object.__setattr__(self, 'epochs', int(self.epochs))
        object.__setattr__(self, 'batch_size', int(self.batch_size))
        object.__setattr__(self, 'learning_rate', float(self.learning_rate))
        object.__setattr__(self, 'seed', int(self.seed))
        object.__setattr__(self, 'threads', int(self.threads))


def fit_torch_regressor(build: Callable[[Any], torch.nn.Module], inputs: np.ndarray,
                        targets: np.ndarray, training: TorchTraining) -> torch.nn.Module:
    """Train build(torch) on (inputs, targets) with Adam + MSE; return it in eval mode.

    Deterministic for a given seed and thread count: the weight initialisation runs under a forked,
    seeded global RNG (the caller's RNG state is left untouched), shuffling uses its own seeded
    generator, and torch's deterministic algorithms are enforced for the duration of the fit.
    """
    import torch

    if len(inputs) < 1:
        raise ValueError('cannot fit on an empty dataset')
    threads, deterministic = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(training.threads)
    torch.use_deterministic_algorithms(True)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(training.seed)
            module = build(torch).to(torch.float32)
        x = torch.as_tensor(inputs, dtype=torch.float32)
        y = torch.as_tensor(targets, dtype=torch.float32)
        shuffle = torch.Generator().manual_seed(training.seed)
        optimiser = torch.optim.Adam(module.parameters(), lr=training.learning_rate)
        loss_fn = torch.nn.MSELoss()
        module.train()
        for _ in range(training.epochs):
            order = torch.randperm(len(x), generator=shuffle)
            for start in range(0, len(x), training.batch_size):
                batch = order[start:start + training.batch_size]
                optimiser.zero_grad(set_to_none=True)
                loss_fn(module(x[batch]), y[batch]).backward()
                optimiser.step()
        return module.eval()
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(deterministic)


def state_name(torch_key: str) -> str:
    """Torch state_dict key -> state array name: 'hidden.weight' -> 'hidden_weight_'."""
    return torch_key.replace('.', '_') + '_'


def module_state(module: torch.nn.Module) -> dict[str, np.ndarray]:
    """The module's parameters and buffers as float32 numpy arrays named by state_name."""
    return {state_name(key): value.detach().cpu().numpy().astype(STATE_DTYPE)
            for key, value in module.state_dict().items()
            if not key.endswith(_SKIPPED_TORCH_STATE)}


def load_module_state(module: torch.nn.Module, arrays: Mapping[str, np.ndarray]) -> torch.nn.Module:
    """Copy state arrays into a freshly built module (inverse of module_state); eval mode."""
    import torch

    state = module.state_dict()
    for key in state:
        if not key.endswith(_SKIPPED_TORCH_STATE):
            value = np.asarray(arrays[state_name(key)])
            state[key] = torch.as_tensor(value, dtype=state[key].dtype)
    module.load_state_dict(state)
    return module.eval()


def checked_state(arrays: Mapping[str, np.ndarray],
                  shapes: Mapping[str, tuple[int, ...]], kind: str) -> dict[str, np.ndarray]:
    """The arrays as STATE_DTYPE, after checking their names, shapes and finiteness."""
    missing, extra = sorted(set(shapes) - set(arrays)), sorted(set(arrays) - set(shapes))
    if missing or extra:
        raise ValueError(f'{kind} state arrays do not match the model: missing {missing}, '
                         f'unexpected {extra}')
    state = {}
    for name, shape in shapes.items():
        value = np.asarray(arrays[name])
        if value.shape != tuple(shape):
            raise ValueError(f'{kind} state array {name!r} has shape {value.shape}, '
                             f'the model needs {tuple(shape)}')
        if not np.all(np.isfinite(value)):
            raise ValueError(f'{kind} state array {name!r} contains NaN or Inf')
        state[name] = value.astype(STATE_DTYPE)
    return state


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


class MLPModel(ForceModel):
    """M4: Linear(3n, hidden) -> ReLU -> Linear(hidden, 3) over the flattened taxel inputs."""

    kind: ClassVar[str] = 'M4'

    def __init__(self, array: TaxelArray, *, hidden: int = 16, epochs: int = 40,
                 batch_size: int = 256, learning_rate: float = 2.5e-4, seed: int = 0,
                 threads: int = 1) -> None:
        super().__init__(array)
        if int(hidden) < 1:
            raise ValueError(f'hidden must be >= 1, got {hidden}')
        self.hidden = int(hidden)
        self.training = TorchTraining(epochs, batch_size, learning_rate, seed, threads)
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
        self._state = checked_state(module_state(module), self._state_shapes(), self.kind)
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
        return {'hidden': self.hidden, **asdict(self.training)}

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {name: value.copy() for name, value in self._fitted_state().items()}

    @classmethod
    def from_state(cls, array: TaxelArray, hyper: dict,
                   arrays: dict[str, np.ndarray]) -> MLPModel:
        model = cls(array, **hyper)
        model._state = checked_state(arrays, model._state_shapes(), cls.kind)
        return model

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
