"""M5: small CNN over the taxel grid (paper Sec. III), trained with torch, run with numpy.

The array is an image of 3 channels (the x, y, z readings of each taxel) laid out by
array.grid_index; cells without a taxel are zero (the standardised mean reading). Layers, as in
the paper: conv 3x3 -> 6, ReLU; conv 3x3 -> 12, ReLU; BatchNorm2d(12); conv 2x2 -> 24, ReLU;
dense 16, ReLU; linear 3.

Padding. All three convolutions are 'valid'; they shrink each side by 2 + 2 + 1 = 5 cells, so the
image must be at least 6 x 6. A 6 x 6 grid gives a 1 x 1 x 24 map and p = 2479, the paper's count.
Smaller grids (the 4 x 4 phalanges, the 4 x 6 palm, the fingertip) are zero-padded, centred, to at
least 6 x 6 before the first convolution. Every array of this hand therefore has the paper's 2479
parameters, and the 4 x 4 taxels of a phalanx all reach every output through the full receptive
field. Grids larger than 6 x 6 keep their size and get a wider dense layer.

Inference (numpy, float32 as in m4_mlp): BatchNorm sits between a ReLU and the last convolution,
so it is folded into that convolution (exact, because the convolution is 'valid': every tap sees
a normalised value, never padding). Convolutions are im2col (sliding_window_view) + matmul, with
weights stacked per grid shape so k arrays run as one batched matmul chain.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from tacforce_ros.estimation.base import ForceModel, ModelNotFittedError, check_inputs
from tacforce_ros.estimation.m4_mlp import mlp_forward, relu, same_kind_models
from tacforce_ros.estimation.torch_batched import autograd_gradient, fit_models_stacked
from tacforce_ros.estimation.torch_training import (STATE_DTYPE, TorchTraining, checked_state,
                                                    fit_torch_regressor, load_module_state,
                                                    module_state)

if TYPE_CHECKING:
    import torch

    from tacforce_ros.hand.description import TaxelArray

KERNELS = (3, 3, 2)                       # paper: two 3x3 convolutions, then one 2x2
MIN_GRID = sum(k - 1 for k in KERNELS) + 1  # smallest image the valid convolutions accept: 6
BN_EPS = 1e-5                             # torch's BatchNorm2d default, needed again to fold it
BN_MOMENTUM = 0.1                         # torch's BatchNorm2d default, which _build keeps
PREDICT_CHUNK = 4096                      # samples per numpy pass: bounds the im2col copies (~7 MB)


def padded_grid(grid_index: np.ndarray) -> np.ndarray:
    """grid_index zero-padded (with -1 cells), centred, to at least MIN_GRID x MIN_GRID."""
    grid = np.asarray(grid_index, dtype=np.int64)
    h, w = grid.shape
    H, W = max(h, MIN_GRID), max(w, MIN_GRID)
    top, left = (H - h) // 2, (W - w) // 2
    out = np.full((H, W), -1, dtype=np.int64)
    out[top:top + h, left:left + w] = grid
    return out


def conv_valid(x: np.ndarray, w: np.ndarray, b: np.ndarray, kernel: int) -> np.ndarray:
    """'Valid' convolution of channels-last images by im2col + matmul.

    x (G, M, H, W, C): M images for each of G models; w (G, C*kernel*kernel, O) with rows in
    (C, kh, kw) order; b (G, 1, O). Returns (G, M, H-kernel+1, W-kernel+1, O).
    """
    windows = sliding_window_view(x, (kernel, kernel), axis=(2, 3))   # (G, M, h, w, C, kh, kw)
    g, m, h, wd = windows.shape[:4]
    cols = windows.reshape(g, m * h * wd, w.shape[-2])
    return (cols @ w + b).reshape(g, m, h, wd, -1)


class CNNModel(ForceModel):
    """M5: three valid convolutions with a BatchNorm, then dense 16 and linear 3."""

    kind: ClassVar[str] = 'M5'

    def __init__(self, array: TaxelArray, *, channels: Sequence[int] = (6, 12, 24),
                 dense: int = 16, epochs: int = 40, batch_size: int = 256,
                 learning_rate: float = 2.5e-4, seed: int = 0, threads: int = 1,
                 device: str = 'cpu') -> None:
        super().__init__(array)
        self.channels = tuple(int(c) for c in channels)
        self.dense = int(dense)
        if len(self.channels) != len(KERNELS) or min(self.channels) < 1 or self.dense < 1:
            raise ValueError(f'channels must be {len(KERNELS)} positive widths and dense >= 1, '
                             f'got channels={channels}, dense={dense}')
        self.training = TorchTraining(epochs, batch_size, learning_rate, seed, threads, device)
        self.grid = padded_grid(array.grid_index)
        placed = np.sort(self.grid[self.grid >= 0])
        if not np.array_equal(placed, np.arange(array.n_taxels)):
            raise ValueError(f'grid_index of {array.name} must hold each of its '
                             f'{array.n_taxels} taxels exactly once')
        h3, w3 = (d - MIN_GRID + 1 for d in self.grid.shape)
        self.final_map = (h3, w3)        # spatial size after the last convolution
        self._state: dict[str, np.ndarray] | None = None
        self._inference: list[np.ndarray] | None = None     # folded weights, set with the state

    def _state_shapes(self) -> dict[str, tuple[int, ...]]:
        (c1, c2, c3), (k1, k2, k3) = self.channels, KERNELS
        flat = c3 * self.final_map[0] * self.final_map[1]
        return {'conv1_weight_': (c1, 3, k1, k1), 'conv1_bias_': (c1,),
                'conv2_weight_': (c2, c1, k2, k2), 'conv2_bias_': (c2,),
                'norm_weight_': (c2,), 'norm_bias_': (c2,),
                'norm_running_mean_': (c2,), 'norm_running_var_': (c2,),
                'conv3_weight_': (c3, c2, k3, k3), 'conv3_bias_': (c3,),
                'dense_weight_': (self.dense, flat), 'dense_bias_': (self.dense,),
                'output_weight_': (3, self.dense), 'output_bias_': (3,)}

    def _build(self, torch: Any) -> torch.nn.Module:
        nn = torch.nn
        (c1, c2, c3), (k1, k2, k3) = self.channels, KERNELS
        return nn.Sequential(OrderedDict([
            ('conv1', nn.Conv2d(3, c1, k1)), ('relu1', nn.ReLU()),
            ('conv2', nn.Conv2d(c1, c2, k2)), ('relu2', nn.ReLU()),
            ('norm', nn.BatchNorm2d(c2, eps=BN_EPS)),
            ('conv3', nn.Conv2d(c2, c3, k3)), ('relu3', nn.ReLU()),
            ('flatten', nn.Flatten()),
            ('dense', nn.Linear(c3 * self.final_map[0] * self.final_map[1], self.dense)),
            ('relu4', nn.ReLU()),
            ('output', nn.Linear(self.dense, 3)),
        ]))

    def images(self, X: np.ndarray) -> np.ndarray:
        """(N, n, 3) taxel inputs -> (N, H, W, 3) channels-last images, zeros where no taxel."""
        padded = np.concatenate([X, np.zeros_like(X[:, :1])], axis=1)   # row n: the empty cell
        return padded[:, np.where(self.grid >= 0, self.grid, X.shape[1])]

    def fit(self, X: np.ndarray, F: np.ndarray) -> CNNModel:
        X = check_inputs(X, self.array.n_taxels, F)
        nchw = self.images(X).transpose(0, 3, 1, 2)
        module = fit_torch_regressor(self._build, np.ascontiguousarray(nchw), F, self.training)
        return self._set_state(module_state(module))

    @classmethod
    def fit_many(cls, models: Sequence[ForceModel],
                 data: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        """Models of one padded grid and layer widths train as one stacked network."""
        from tacforce_ros.estimation.m5_stacked import stacked_cnn_forward

        fit_models_stacked(same_kind_models(cls, models), [(X, F) for X, F, _ in data],
                           lambda m: (m.grid.shape, m.channels, m.dense),
                           lambda m, X: m.images(X),
                           gradient=autograd_gradient(stacked_cnn_forward))

    def _set_state(self, arrays: dict[str, np.ndarray]) -> CNNModel:
        state = checked_state(arrays, self._state_shapes(), self.kind)
        if np.any(state['norm_running_var_'] < 0.0):
            raise ValueError(f'{self.kind} state array norm_running_var_ has negative variances')
        self._state = state
        self._inference = self._fold()
        return self

    def _fitted_state(self) -> dict[str, np.ndarray]:
        if self._state is None:
            raise ModelNotFittedError(f'{self.kind} model for {self.array.name} is not fitted')
        return self._state

    def inference_weights(self) -> list[np.ndarray]:
        """Weights for the numpy forward, BatchNorm folded into conv3, matmul layouts, float32.

        Order: conv1 (w, b), conv2 (w, b), conv3 (w, b), dense (w, b), output (w, b); conv
        weights (C*kh*kw, O), biases (O,), dense rows in channels-last (h, w, C) order.
        """
        self._fitted_state()        # raises if not fitted
        return self._inference

    def _fold(self) -> list[np.ndarray]:
        """Compute inference_weights() from the torch-layout state (folding in float64)."""
        s = {name: value.astype(np.float64) for name, value in self._fitted_state().items()}
        scale = s['norm_weight_'] / np.sqrt(s['norm_running_var_'] + BN_EPS)
        shift = s['norm_bias_'] - scale * s['norm_running_mean_']
        conv3 = s['conv3_weight_'] * scale[None, :, None, None]
        conv3_bias = s['conv3_bias_'] + np.einsum('ocij,c->o', s['conv3_weight_'], shift)
        c3, (h3, w3) = self.channels[2], self.final_map
        dense = s['dense_weight_'].reshape(self.dense, c3, h3, w3).transpose(0, 2, 3, 1)
        weights = [
            s['conv1_weight_'].reshape(len(s['conv1_bias_']), -1).T, s['conv1_bias_'],
            s['conv2_weight_'].reshape(len(s['conv2_bias_']), -1).T, s['conv2_bias_'],
            conv3.reshape(c3, -1).T, conv3_bias,
            dense.reshape(self.dense, -1).T, s['dense_bias_'],
            s['output_weight_'].T, s['output_bias_'],
        ]
        return [np.ascontiguousarray(w, dtype=STATE_DTYPE) for w in weights]

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = check_inputs(X, self.array.n_taxels)
        stacked = [w[None] for w in self.inference_weights()]   # a group of one model
        out = np.empty((len(X), 3))
        for start in range(0, len(X), PREDICT_CHUNK):
            chunk = X[start:start + PREDICT_CHUNK].astype(np.float32)
            out[start:start + len(chunk)] = _cnn_forward(self.images(chunk)[None], stacked)[0]
        return out

    def torch_module(self) -> torch.nn.Module:
        """The fitted network as an eval-mode torch module (fine-tuning, export, cross-checks)."""
        import torch

        return load_module_state(self._build(torch), self._fitted_state())

    def n_parameters(self) -> int:
        """Learned scalars; BatchNorm running statistics are estimated, not learned."""
        shapes = self._state_shapes()
        del shapes['norm_running_mean_'], shapes['norm_running_var_']
        return sum(int(np.prod(shape)) for shape in shapes.values())

    def hyperparameters(self) -> dict:
        return {'channels': list(self.channels), 'dense': self.dense,
                **self.training.hyperparameters()}

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {name: value.copy() for name, value in self._fitted_state().items()}

    @classmethod
    def from_state(cls, array: TaxelArray, hyper: dict,
                   arrays: dict[str, np.ndarray]) -> CNNModel:
        return cls(array, **hyper)._set_state(arrays)

    @classmethod
    def compile_batch(cls, models: Sequence[ForceModel]) -> Callable[[np.ndarray], np.ndarray]:
        """Stack k CNNs once, grouped by padded grid and layer widths; (k, n_max, 3) -> (k, 3).

        Each group gathers its images from the zero-padded batch input with one precomputed
        index (empty cells point at an appended zero row) and runs one batched forward.
        """
        cnns = same_kind_models(cls, models)
        n_max = max(m.array.n_taxels for m in cnns)
        k = len(cnns)
        groups: dict[tuple, list[int]] = {}
        for i, m in enumerate(cnns):
            groups.setdefault((m.grid.shape, m.channels, m.dense), []).append(i)
        compiled = []
        for rows in groups.values():
            cells = np.stack([np.where(cnns[i].grid >= 0, cnns[i].grid, n_max) for i in rows])
            per_model = [cnns[i].inference_weights() for i in rows]
            stacked = [np.stack([w[j] for w in per_model]) for j in range(len(per_model[0]))]
            compiled.append((np.array(rows), cells, stacked))
        expected = (k, n_max, 3)

        def forward(X: np.ndarray) -> np.ndarray:
            if X.shape != expected:
                raise ValueError(f'batched M5 input must have shape {expected}, got {X.shape}')
            padded = np.zeros((k, n_max + 1, 3), np.float32)
            padded[:, :n_max] = X
            out = np.empty((k, 3))
            for rows, cells, stacked in compiled:
                images = padded[rows[:, None, None], cells][:, None]     # (G, 1, H, W, 3)
                out[rows] = _cnn_forward(images, stacked)[:, 0]
            return out

        return forward


def _cnn_forward(images: np.ndarray, weights: Sequence[np.ndarray]) -> np.ndarray:
    """Folded CNN: images (G, M, H, W, 3), weights stacked per model (G, ...) -> (G, M, 3)."""
    w1, b1, w2, b2, w3, b3, wd, bd, wo, bo = weights
    x = relu(conv_valid(images, w1, b1[:, None], KERNELS[0]))
    x = relu(conv_valid(x, w2, b2[:, None], KERNELS[1]))
    x = relu(conv_valid(x, w3, b3[:, None], KERNELS[2]))
    g, m = x.shape[:2]
    return mlp_forward(x.reshape(g, m, wd.shape[-2]), wd, bd[:, None], wo, bo[:, None])
