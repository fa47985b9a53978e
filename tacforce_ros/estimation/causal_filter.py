"""Causal low-pass filtering of a block of channels, one filter state per channel, one sample per
call: the estimator's optional online counterpart of the zero-phase filter the training data
went through (estimation/preprocessing.py).

The design is scipy's (Butterworth, second-order sections); the per-sample step is written out
here because scipy.signal.sosfilt costs 44 us per single-sample call on the hand's 1104 input
channels against 6.7 us for this transposed direct form II in numpy (2nd order, best of 5 x 2000
calls each, this machine, 2026-11-23) — the whole M3-lambda tick is ~10 us.

A channel is started at steady state for its first input (and again after `restart`), so a
constant input passes unchanged from the first sample and a channel that carried NaN/Inf does
not keep it.
"""
from __future__ import annotations

import numpy as np
from scipy import signal


class FilterDesignError(ValueError):
    """A cut-off the filter cannot have at the given sample rate."""


class BatchLowPass:
    """Butterworth low-pass of `order` at `cutoff_hz` for samples arriving at `rate_hz`, over
    `n_channels` independent channels (filtered in place, one sample per call)."""

    def __init__(self, n_channels: int, cutoff_hz: float, rate_hz: float,
                 order: int = 2) -> None:
        if not 0.0 < cutoff_hz < 0.5 * rate_hz:
            raise FilterDesignError(f'low-pass cut-off {cutoff_hz:g} Hz must lie between 0 and '
                                    f'half the frame rate ({0.5 * rate_hz:g} Hz)')
        if order < 1:
            raise FilterDesignError(f'filter order must be at least 1, got {order}')
        self.cutoff_hz, self.rate_hz, self.order = float(cutoff_hz), float(rate_hz), int(order)
        self.sos = signal.butter(order, cutoff_hz, fs=rate_hz, output='sos')
        # Per section: numerator (3, 1) and the feedback pair a1, a2 (2, 1), as columns that
        # broadcast over the channels; a0 is 1 in scipy's sections.
        self._b = [section[:3, None].copy() for section in self.sos]
        self._a = [section[4:, None].copy() for section in self.sos]
        self._steady = signal.sosfilt_zi(self.sos)          # (sections, 2) per unit input
        self._z = np.zeros((len(self.sos), 2, n_channels))
        self._bu = np.empty((3, n_channels))
        self._ay = np.empty((2, n_channels))
        self._restart = np.ones(n_channels, dtype=bool)
        self._any_restart = True

    def group_delay_s(self) -> float:
        """Group delay at 0 Hz (s): the delay of slow force changes, which the controller sees."""
        b, a = signal.sos2tf(self.sos)
        _, delay = signal.group_delay((b, a), w=[0.0], fs=self.rate_hz)
        return float(delay[0]) / self.rate_hz

    def restart(self, channels: np.ndarray | None = None) -> None:
        """Start these channels (a bool mask; all when None) at steady state on their next
        input."""
        if channels is None:
            self._restart[:] = True
        else:
            self._restart |= channels
        self._any_restart = bool(self._restart.any())

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Filter one sample of every channel in place; `x`: flat (n_channels,) float64."""
        if self._any_restart:
            mask = self._restart
            self._z[:, :, mask] = self._steady[:, :, None] * x[mask]
            mask[:] = False
            self._any_restart = False
        bu, ay = self._bu, self._ay
        for z, b, a in zip(self._z, self._b, self._a):
            # y = b0 u + z0;  z0 <- b1 u - a1 y + z1;  z1 <- b2 u - a2 y  (y written into x)
            np.multiply(b, x, out=bu)
            np.add(bu[0], z[0], out=x)
            np.multiply(a, x, out=ay)
            np.add(bu[1], z[1], out=z[0])
            np.subtract(z[0], ay[0], out=z[0])
            np.subtract(bu[2], ay[1], out=z[1])
        return x

    def run(self, samples: np.ndarray) -> np.ndarray:
        """Filter a recorded sequence (N, n_channels) sample by sample, as it would be online;
        returns a new float64 array."""
        out = np.array(samples, dtype=np.float64)
        if out.ndim != 2 or out.shape[1] != self._z.shape[2]:
            raise ValueError(f'need samples (N, {self._z.shape[2]}), got {out.shape}')
        for row in out:
            self(row)
        return out
