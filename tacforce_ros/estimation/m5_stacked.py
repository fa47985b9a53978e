"""M5's training forward over k networks of one architecture stacked on a leading model axis
(torch_batched.StackedForward): convolutions as batched matmuls with dense matrices, the
BatchNorm over each network's real samples and folded into the convolution after it.

Autograd takes its backward (torch_batched.autograd_gradient). Why not by hand: the backward
written out for this forward was at most 1.45x faster, under the 1.5x that would pay for a second
derivation to keep right beside every change of the forward. Per step of 5 networks on index_tip
(batch 256, with the masked Adam, two rounds alternating in one process, load 1): 4.93-6.19 ms
by hand against 6.70-6.93 ms with autograd; `bench_train --models M5 --samples 100000` minutes
apart, load 1: the five folds together in 65.6 s by hand against 82.8 s with autograd (1.26x),
held-out e_hat 0.0858 N both. Torch is passed in, as in torch_batched.
"""
from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.m5_cnn import BN_EPS, BN_MOMENTUM, KERNELS

if TYPE_CHECKING:
    import torch


@functools.lru_cache(maxsize=32)     # cached: read by every training step, never written
def conv_as_matrix_index(in_shape: tuple[int, int, int], out_channels: int,
                         kernel: int) -> np.ndarray:
    """Index that spreads a 'valid' convolution's weights into its dense matrix.

    For channels-last images (H, W, C) flattened, the convolution with weight (O, C, k, k) is the
    matrix product with a (H*W*C, h*w*O) matrix whose entries are weights or zero; entry e is
    weight.ravel()[index[e]], or zero where index[e] is weight.size (an appended zero).
    """
    H, W, C = in_shape
    h, w = H - kernel + 1, W - kernel + 1
    index = np.full((H, W, C, h, w, out_channels), out_channels * C * kernel * kernel)
    o, c, a, b = np.meshgrid(np.arange(out_channels), np.arange(C), np.arange(kernel),
                             np.arange(kernel), indexing='ij')
    flat = np.ravel_multi_index((o, c, a, b), (out_channels, C, kernel, kernel))
    for i in range(h):
        for j in range(w):
            index[i + a, j + b, c, i, j, o] = flat
    index = index.reshape(H * W * C, h * w * out_channels)
    return index


def stacked_cnn_forward(torch: Any, params: dict, buffers: dict, x: torch.Tensor,
                        mask: torch.Tensor) -> torch.Tensor:
    """Outputs of k stacked M5 networks in training mode (torch_batched.StackedForward); the
    BatchNorm's running statistics are updated as torch's BatchNorm2d updates them.

    x (k, B, H, W, 3) channels-last images. On maps this small each 'valid' convolution is
    cheapest as a batched matmul with its dense (Toeplitz) matrix, gathered from the weights at
    each step. The first layer takes the kernel's rows of the image under each output row as a
    sample of its own (one matmul) with the small matrix all rows share (its full matrix is
    three-quarters zeros). Per step for 5 networks, torch's grouped convolution and im2col with
    batched matmuls each took longer than the dense matrices. The BatchNorm, which conv3
    follows, is folded into conv3's matrix (batch_norm_folded).
    """
    k, batch, H, W, C = x.shape
    y, shape = x.reshape(k, batch, -1), (H, W, C)
    for name, kernel in zip(('conv1', 'conv2', 'conv3'), KERNELS):
        weight = params[f'{name}.weight']                    # (k, O, C, kh, kw)
        out_channels = weight.shape[1]
        out_shape = (shape[0] - kernel + 1, shape[1] - kernel + 1, out_channels)
        padded = torch.cat([weight.reshape(k, -1), weight.new_zeros(k, 1)], dim=1)
        banded = name == 'conv1'
        index = torch.as_tensor(conv_as_matrix_index(
            (kernel, *shape[1:]) if banded else shape, out_channels, kernel), device=x.device)
        matrix = padded.index_select(1, index.reshape(-1)).view(k, *index.shape)
        if banded:
            row = shape[1] * shape[2]
            rows = y.unfold(2, kernel * row, row).reshape(k, -1, kernel * row)
            bias = params[f'{name}.bias'].repeat(1, out_shape[1])[:, None]
            y = torch.baddbmm(bias, rows, matrix).relu().view(k, batch, -1)
        else:
            bias = params[f'{name}.bias'].repeat(1, out_shape[0] * out_shape[1])[:, None]
            if name == 'conv3':
                matrix, bias = batch_norm_folded(torch, y, mask, shape[2], params, buffers,
                                                 matrix, bias)
            y = torch.baddbmm(bias, y, matrix).relu()
        shape = out_shape
    h, w, c = shape
    flat = y.view(k, batch, h, w, c).permute(0, 1, 4, 2, 3).reshape(k, batch, -1)   # torch order
    dense = torch.baddbmm(params['dense.bias'][:, None], flat,
                          params['dense.weight'].transpose(1, 2)).relu()
    return torch.baddbmm(params['output.bias'][:, None], dense,
                         params['output.weight'].transpose(1, 2))


def batch_norm_folded(torch: Any, y: torch.Tensor, mask: torch.Tensor, channels: int,
                      params: dict, buffers: dict, matrix: torch.Tensor,
                      bias: torch.Tensor) -> tuple:
    """Training-mode BatchNorm2d of channels-last y (k, B, cells * C), per network over its real
    samples, folded into the matmul (matrix, bias) that follows it: (y * s + t) @ M + b =
    y @ (s M) + (t @ M + b), with s = gamma / std and t = beta - mean * s from the batch's
    statistics; returns the folded matrix and bias. The running statistics are updated as
    torch's (momentum 0.1, unbiased variance). Why folded: the activations are never normalised,
    and the batch norm's share of a step shrinks to small reductions (written out on the
    activations it took 574 of 2705 us of a hand-written gradient; folded, the whole took 2252
    us, 5 networks on index_tip, batch 256; autograd's backward rides on the same fold)."""
    k, batch = mask.shape
    cells = y.shape[2] // channels
    values = y.view(k, batch * cells, channels)
    real = mask.sum(dim=1)
    if bool(real.min() == batch):
        mean, variance = _mean_and_variance(values, dim=1)
    else:                            # each network's real samples are its first ones
        stats = [_mean_and_variance(values[i, :n * cells], dim=0) if n
                 else (values.new_zeros(channels), values.new_ones(channels))
                 for i, n in enumerate(real.tolist())]
        mean, variance = (torch.stack(s) for s in zip(*stats))
    with torch.no_grad():
        count = (real * cells).to(y.dtype)[:, None]
        moved = (real * cells > 1)[:, None]
        unbiased = variance * count / (count - 1).clamp(min=1)
        for name, value in (('norm.running_mean', mean), ('norm.running_var', unbiased)):
            running = buffers[name]
            running.copy_(torch.where(moved, (1 - BN_MOMENTUM) * running + BN_MOMENTUM * value,
                                      running))
    scale = params['norm.weight'] * torch.rsqrt(variance + BN_EPS)
    shift = params['norm.bias'] - mean * scale
    # s and t per activation, in the activations' channels-last order
    cell_scale, cell_shift = scale.repeat(1, cells), shift.repeat(1, cells)
    return matrix * cell_scale[:, :, None], torch.baddbmm(bias, cell_shift[:, None], matrix)


def _mean_and_variance(values: torch.Tensor, dim: int) -> tuple:
    """Mean and biased variance along dim, two passes: torch.var_mean over a non-innermost
    dimension took 350 us against 30 us for (5, 1024, 12) values (2026-11-26)."""
    mean = values.mean(dim=dim, keepdim=True)
    return mean.squeeze(dim), (values - mean).square().mean(dim=dim)
