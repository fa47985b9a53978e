"""Shared fixtures of the estimation tests: the real hand description and small synthetic data."""
import numpy as np
import pytest
import torch

from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.hand.description import load_hand


@pytest.fixture(scope='session')
def hand():
    return load_hand()


@pytest.fixture(scope='session')
def tip(hand):
    return hand.array('index_tip')          # curved, 30 taxels, varied R_i^0


@pytest.fixture(scope='session')
def phalanx(hand):
    return hand.array('index_middle')       # flat 4x4


@pytest.fixture(scope='session')
def tip_data(tip):
    """Offset-corrected synthetic recordings of the tip: (dataset, X counts, F newtons, offset)."""
    data = synthetic_dataset(tip, seconds=12.0, seed=7)
    X, F, offset = data.without_offsets()
    return data, X, F, offset


def linear_problem(rng: np.random.Generator, n_samples: int, n_taxels: int,
                   noise: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """X (N, n, 3) standard normal, F = A x + b (+ noise) with known A (3, 3n), b (3,)."""
    X = rng.standard_normal((n_samples, n_taxels, 3))
    A = rng.standard_normal((3, 3 * n_taxels))
    b = rng.standard_normal(3)
    F = X.reshape(n_samples, -1) @ A.T + b + noise * rng.standard_normal((n_samples, 3))
    return X, F, A, b


@pytest.fixture(params=['cpu', pytest.param('cuda', marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason='no CUDA GPU here'))])
def training_device(request):
    """Each torch device M4 and M5 train on: the GPU case runs where one is (never in CI), the
    only test `--device cuda` has."""
    return request.param
