"""SYNTHETIC calibration data for tests and `bench --synthetic`, until the simulator's bags exist.

Not a sensor model: a smooth, saturating, plate-dependent map from force and contact location to
taxel counts, with noise, per-taxel gains and baselines, so the models have something nonlinear to
fit and the leave-one-plate-out protocol has plates that differ. Each plate recording alternates
rest periods (no contact, for offset detection) and presses.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.dataset import CalibrationDataset
from tacforce_ros.estimation.preprocessing import SAMPLE_RATE_HZ, lowpass
from tacforce_ros.estimation.runtime import RuntimeEstimator
from tacforce_ros.estimation.training import fit_bundle
from tacforce_ros.rig import TRAINING_PLATES

if TYPE_CHECKING:
    from tacforce_ros.hand.description import HandDescription, TaxelArray

# Contact spread [m] per plate, by position in the plate list (indenter sharpness stand-in).
_SPREADS = (0.003, 0.009, 0.005, 0.006, 0.004)
_SATURATION_N = 2.0                         # taxel response saturates around this local force
_GAIN_COUNTS_PER_N = np.array([250.0, 250.0, 600.0])    # shear x, y; normal z (taxel frame)
_NOISE_COUNTS = 3.0
_FT_NOISE_N = 0.02


def synthetic_dataset(array: TaxelArray, plates: Sequence[str] = TRAINING_PLATES,
                      seconds: float = 60.0, seed: int = 0) -> CalibrationDataset:
    """One recording (session) of `seconds` per plate for `array`; deterministic for a seed."""
    rng = np.random.default_rng(seed)
    baseline = rng.uniform(15000.0, 30000.0, size=(array.n_taxels, 3))
    taxel_gain = rng.uniform(0.7, 1.3, size=(array.n_taxels, 1)) * _GAIN_COUNTS_PER_N
    coupling = np.eye(3) + rng.normal(0.0, 0.08, size=(3, 3))
    parts = []
    for index, plate in enumerate(plates):
        force, contact = _presses(array, rng, int(seconds * SAMPLE_RATE_HZ))
        spread = _SPREADS[index % len(_SPREADS)]
        counts = baseline + _response(array, force, contact, spread, taxel_gain, coupling)
        counts += rng.normal(0.0, _NOISE_COUNTS, counts.shape)
        counts = np.clip(np.round(counts), 0.0, 65535.0)
        measured = force + rng.normal(0.0, _FT_NOISE_N, force.shape) + rng.normal(0, 0.05, 3)
        n = force.shape[0]
        parts.append((lowpass(counts), lowpass(measured), np.full(n, plate),
                      np.full(n, index, dtype=np.int64), np.arange(n) / SAMPLE_RATE_HZ))
    X, F, labels, sessions, time = (np.concatenate(column) for column in zip(*parts))
    return CalibrationDataset(array=array.name, X=X, F=F, plates=labels.astype(str),
                              sessions=sessions, time=time, source='synthetic',
                              hand_side=array.hand_side)


def _presses(array: TaxelArray, rng: np.random.Generator, n: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Force (n, 3) in {S0} and contact point (n, 3): rests of ~1 s between 1.5-4 s presses."""
    force = np.zeros((n, 3))
    contact = np.repeat(array.positions.mean(axis=0, keepdims=True), n, axis=0)
    t = int(rng.uniform(0.8, 1.5) * SAMPLE_RATE_HZ)
    while t < n:
        length = int(rng.uniform(1.5, 4.0) * SAMPLE_RATE_HZ)
        stop = min(n, t + length)
        phase = np.linspace(0.0, np.pi, length)[:stop - t]
        taxel = rng.integers(array.n_taxels)
        normal = array.rotations[taxel][:, 2]
        shear = rng.normal(0.0, 0.35, 3)
        shear -= shear @ normal * normal
        direction = -normal + shear
        force[t:stop] = rng.uniform(1.0, 6.0) * np.sin(phase)[:, None] ** 2 * direction
        drift = rng.normal(0.0, 0.002, 3)
        contact[t:stop] = array.positions[taxel] + np.outer(np.sin(phase / 2.0), drift)
        t = stop + int(rng.uniform(0.8, 1.5) * SAMPLE_RATE_HZ)
    return force, contact


def _response(array: TaxelArray, force: np.ndarray, contact: np.ndarray, spread: float,
              taxel_gain: np.ndarray, coupling: np.ndarray) -> np.ndarray:
    """Counts change (n_samples, n_taxels, 3): each taxel's share of the force, saturated.

    The shares sum to one (the pressure under the indenter integrates to the force), so plates
    differ in how concentrated the load is, which saturation turns into a plate-dependent response.
    """
    distance2 = ((array.positions[None] - contact[:, None]) ** 2).sum(axis=-1)
    weight = np.exp(-distance2 / (2.0 * spread ** 2))
    share = weight / weight.sum(axis=1, keepdims=True)
    local = np.einsum('tji,sj->sti', array.rotations, force) * share[..., None]   # R_i^T f
    saturated = _SATURATION_N * np.tanh(local / _SATURATION_N)
    return np.einsum('ij,stj->sti', coupling, saturated) * taxel_gain


def synthetic_hand_estimator(hand: HandDescription, kind: str, hyper: dict, seed: int
                             ) -> RuntimeEstimator:
    """A runtime estimator over every array of `hand`, each model of `kind` fitted on 8 s of
    synthetic flat and edge presses: for timing, where only the shapes matter."""
    bundles = []
    for array in hand.arrays:
        data = synthetic_dataset(array, plates=('flat', 'edge'), seconds=8.0, seed=seed)
        X, F, offset = data.without_offsets()
        bundles.append(fit_bundle(array, kind, hyper, X, F, data.plates, x_offset=offset))
    return RuntimeEstimator(hand, bundles)
