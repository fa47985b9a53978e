import dataclasses
import warnings

import numpy as np
import pytest

from tacforce_ros.hand.description import load_hand
from tacforce_ros.sim import load_scene, make_simulator


@pytest.fixture(scope='session')
def hand():
    return load_hand()


@pytest.fixture(scope='session')
def run_scene(hand):
    """run_scene(name, effects, steps, seed) -> list of SimSample, effects a dict or None (all)."""
    def run(name, effects=None, steps=300, seed=None):
        scene = load_scene(name)
        if effects is not None:
            scene = dataclasses.replace(scene, effects=effects)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            sim = make_simulator(scene, hand, seed=seed)
        return [sim.step() for _ in range(steps)]
    return run


def stack(samples, field):
    return np.array([getattr(s, field) for s in samples])
