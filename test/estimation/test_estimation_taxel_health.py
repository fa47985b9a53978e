"""Faulty taxels are named, not trusted: the checker tells clipped and frozen taxels from live
ones (a quiet taxel still has its noise), and the model set makes the array of a faulty taxel
invalid with a status naming it, leaving the other arrays' estimates as they were."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.estimation.model_set import load_model_set, write_synthetic_model_set
from tacforce_ros.estimation.taxel_health import (COUNT_MAX, FROZEN_FRAMES, TaxelHealth,
                                                  fault_status)
from tacforce_ros.hand.description import load_hand

HAND = load_hand()


def live(rng: np.random.Generator, rest: np.ndarray, sigma=(1.0, 0.9, 3.1)) -> np.ndarray:
    """One frame of a skin at rest: its rest reading plus noise, in whole counts."""
    return np.round(rest + rng.normal(0.0, sigma, rest.shape)).astype(np.uint16)


def test_a_clipped_channel_is_named_with_its_end_of_the_range():
    health = TaxelHealth(16)
    frame = np.full((16, 3), 30000, np.uint16)
    frame[3, 2], frame[9, 0] = COUNT_MAX, 0
    faults = health.check(frame)
    assert [(f.taxel, f.kind, f.detail) for f in faults] == [
        (9, 'clipped', 'reads 0'), (3, 'clipped', f'reads {COUNT_MAX}')]


def test_a_taxel_is_frozen_after_exactly_its_frames_and_any_change_releases_it():
    rng = np.random.default_rng(0)
    rest = np.full((16, 3), 30000.0)
    health = TaxelHealth(16, frozen_frames=5)
    stuck = live(rng, rest)[7]
    seen = []
    for _ in range(6):
        frame = live(rng, rest)
        frame[7] = stuck
        seen.append([f.taxel for f in health.check(frame)])
    assert seen == [[], [], [], [], [7], [7]]     # the fifth identical reading is the first flag
    frame = live(rng, rest)
    frame[7] = stuck
    frame[7, 1] += 1                               # one channel moved by one count: alive
    assert health.check(frame) == []


@settings(max_examples=25, deadline=None)
@given(sigma=st.floats(0.5, 10.0), seed=st.integers(0, 2**31))
def test_a_quiet_taxel_with_the_rest_noise_of_a_real_skin_is_never_frozen(sigma, seed):
    """Half the rest noise of the public uSkin recordings, or more, on X and Y (Z is noisier):
    2000 frames (20 s at 100 Hz) of 16 taxels at rest never look frozen."""
    rng = np.random.default_rng(seed)
    rest = rng.uniform(15000, 50000, (16, 3))
    health = TaxelHealth(16)
    for _ in range(2000):
        assert health.check(live(rng, rest, (sigma, sigma, 3.0 * sigma))) == []


def test_frozen_taxels_are_not_looked_for_when_switched_off():
    health = TaxelHealth(4, frozen_frames=None)
    frame = np.full((4, 3), 20000, np.uint16)
    assert all(health.check(frame) == [] for _ in range(3 * FROZEN_FRAMES))
    with pytest.raises(ValueError, match='at least 2'):
        TaxelHealth(4, frozen_frames=1)


@pytest.fixture(scope='module')
def models_file(tmp_path_factory):
    return write_synthetic_model_set(tmp_path_factory.mktemp('models'), HAND)


@pytest.mark.parametrize('kind', ['stuck', 'dead', 'clipped', 'far'])
def test_the_array_of_a_faulty_taxel_is_invalid_and_named_and_the_others_unchanged(
        models_file, kind):
    checked, plain = load_model_set(models_file, HAND), load_model_set(models_file, HAND)
    checked.check_taxels(out_of_range=20.0)     # the synthetic models' spreads are a few counts
    rng = np.random.default_rng(1)
    rest = HAND.merge([b.x_offset for b in plain.estimator.bundles])
    array = HAND.array('index_middle')
    row, k = int(array.flat_indices[5]), [a.name for a in HAND.arrays].index('index_middle')
    stuck = None
    for frame_index in range(2 * FROZEN_FRAMES):
        frame = live(rng, rest)
        if kind == 'stuck':
            stuck = frame[row].copy() if stuck is None else stuck
            frame[row] = stuck
        elif kind == 'dead':
            frame[row] = 0
        elif kind == 'clipped':
            frame[row, 2] = COUNT_MAX
        else:                   # far outside what the array was calibrated on
            frame[row, 2] = frame[row, 2] + 25.0 * plain.estimator.bundles[k].x_scaler.std[5, 2]
        got, reference = checked.estimate(frame), plain.estimate(frame)
        others = np.arange(len(HAND.arrays)) != k
        np.testing.assert_array_equal(got.force[others], reference.force[others])
        assert got.valid[others].all() and all(s == 'ok' for s in np.array(got.status)[others])
    expected = {'stuck': 'taxel 5 frozen', 'dead': 'taxel 5 clipped (reads 0)',
                'clipped': f'taxel 5 clipped (reads {COUNT_MAX})',
                'far': 'taxel 5 out of range'}[kind]
    assert not got.valid[k] and got.status[k] == expected
    assert np.array_equal(got.force[k], np.zeros(3))
    assert reference.valid[k]          # the model alone would have answered


def test_a_status_names_the_taxel_as_the_array_numbers_it():
    from tacforce_ros.estimation.taxel_health import TaxelFault
    assert fault_status(TaxelFault(200, 'frozen'), 3) == 'taxel 3 frozen'
    assert fault_status(TaxelFault(7, 'clipped', 'reads 0'), 7) == 'taxel 7 clipped (reads 0)'
