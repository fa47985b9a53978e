"""Training and state conversion shared by the torch-trained models (M4, M5).

Torch is imported inside the functions that need it, never at module import, so loading a model
file and the 100 Hz inference stay torch-free. Training runs on the CPU unless a model is given
another torch device (`device='cuda'`, the `--device` of train and bench_train); the weights
are initialised on the CPU either way, so a seed gives the same start on every device, and the
state comes back to the CPU as numpy arrays.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch

STATE_DTYPE = np.float32
# Torch buffers that are bookkeeping, not learned state the numpy forward needs.
SKIPPED_TORCH_STATE = ('num_batches_tracked',)


@dataclass(frozen=True)
class TorchTraining:
    """Optimiser settings shared by the torch-trained models (defaults: paper Sec. IV-A)."""

    epochs: int = 40
    batch_size: int = 256
    learning_rate: float = 2.5e-4
    seed: int = 0
    threads: int = 1        # torch intra-op threads during fit; fixed so runs are reproducible
    device: str = 'cpu'     # torch device the fit runs on: where, not what, so not saved

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
        object.__setattr__(self, 'device', str(self.device))

    def hyperparameters(self) -> dict:
        """The settings that define the trained model (what a model file keeps): all but the
        device."""
        settings = asdict(self)
        del settings['device']
        return settings


def torch_device(name: str) -> torch.device:
    """The torch device called name ('cpu', 'cuda', 'cuda:1'), refused with the reason where
    this machine cannot train on it."""
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f'unknown torch device {name!r}: {exc}') from None
    if device.type == 'cuda':
        if not torch.cuda.is_available():
            raise ValueError(f'torch device {name!r}: torch {torch.__version__} sees no CUDA GPU '
                             f'here (built for CUDA: {torch.version.cuda or "no"})')
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ValueError(f'torch device {name!r}: this machine has '
                             f'{torch.cuda.device_count()} CUDA GPU(s)')
    elif device.type != 'cpu':
        raise ValueError(f'torch device {name!r}: training runs on cpu or cuda')
    return device


@contextmanager
def reproducible_torch(threads: int, device: torch.device) -> Iterator[None]:
    """Torch set up for a reproducible fit, the caller's settings restored after.

    Fixed intra-op threads and deterministic algorithms, but without filling new memory with NaN
    (a debugging aid deterministic mode turns on; it changes no result of correct code and was a
    quarter of a batched M4 step in torch's profiler). On a CUDA device, cuBLAS needs a fixed
    workspace to be deterministic (torch.use_deterministic_algorithms refuses matmuls without
    one), set here unless the caller chose one.
    """
    import torch
    import torch.utils.deterministic

    if device.type == 'cuda':
        os.environ.setdefault('CUBLAS_WORKSPACE_CONFIG', ':4096:8')

    saved = (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled(),
             torch.utils.deterministic.fill_uninitialized_memory,
             torch.backends.cuda.matmul.fp32_precision, torch.backends.cudnn.conv.fp32_precision)
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)
    torch.utils.deterministic.fill_uninitialized_memory = False
    # float32 means float32 on a GPU too: cuDNN's convolutions default to TF32 (10-bit
    # mantissa), which would make a model trained there another model than the CPU's. (torch's
    # fp32_precision settings: mixing them with the older allow_tf32 flags breaks the caller's
    # torch.get_float32_matmul_precision.)
    torch.backends.cuda.matmul.fp32_precision = 'ieee'
    torch.backends.cudnn.conv.fp32_precision = 'ieee'
    try:
        yield
    finally:
        torch.set_num_threads(saved[0])
        torch.use_deterministic_algorithms(saved[1])
        torch.utils.deterministic.fill_uninitialized_memory = saved[2]
        torch.backends.cuda.matmul.fp32_precision = saved[3]
        torch.backends.cudnn.conv.fp32_precision = saved[4]


def fit_torch_regressor(build: Callable[[Any], torch.nn.Module], inputs: np.ndarray,
                        targets: np.ndarray, training: TorchTraining) -> torch.nn.Module:
    """Train build(torch) on (inputs, targets) with Adam + MSE; return it in eval mode.

    Deterministic for a given seed and thread count: the weight initialisation runs under a forked,
    seeded global RNG (the caller's RNG state is left untouched), shuffling uses its own seeded
    generator, and the fit runs under reproducible_torch.
    """
    import torch

    if len(inputs) < 1:
        raise ValueError('cannot fit on an empty dataset')
    device = torch_device(training.device)
    with reproducible_torch(training.threads, device):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(training.seed)
            module = build(torch).to(torch.float32).to(device)
        x = torch.as_tensor(inputs, dtype=torch.float32, device=device)
        y = torch.as_tensor(targets, dtype=torch.float32, device=device)
        shuffle = torch.Generator().manual_seed(training.seed)   # on the CPU: one order anywhere
        optimiser = torch.optim.Adam(module.parameters(), lr=training.learning_rate)
        loss_fn = torch.nn.MSELoss()
        module.train()
        for _ in range(training.epochs):
            order = torch.randperm(len(x), generator=shuffle).to(device)
            for start in range(0, len(x), training.batch_size):
                batch = order[start:start + training.batch_size]
                optimiser.zero_grad(set_to_none=True)
                loss_fn(module(x[batch]), y[batch]).backward()
                optimiser.step()
        return module.eval()


def state_name(torch_key: str) -> str:
    """Torch state_dict key -> state array name: 'hidden.weight' -> 'hidden_weight_'."""
    return torch_key.replace('.', '_') + '_'


def module_state(module: torch.nn.Module) -> dict[str, np.ndarray]:
    """The module's parameters and buffers as float32 numpy arrays named by state_name."""
    return {state_name(key): value.detach().cpu().numpy().astype(STATE_DTYPE)
            for key, value in module.state_dict().items()
            if not key.endswith(SKIPPED_TORCH_STATE)}


def load_module_state(module: torch.nn.Module, arrays: Mapping[str, np.ndarray]) -> torch.nn.Module:
    """Copy state arrays into a freshly built module (inverse of module_state); eval mode."""
    import torch

    state = module.state_dict()
    for key in state:
        if not key.endswith(SKIPPED_TORCH_STATE):
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
