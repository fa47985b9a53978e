"""The estimator's optional causal low-pass: scipy's filter exactly, per channel; its delay on a
step in the batched estimator is the design's group delay; constants pass unchanged."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from tacforce_ros.estimation.causal_filter import BatchLowPass, FilterDesignError
from tacforce_ros.estimation.runtime import RuntimeEstimator
from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.estimation.training import fit_bundle

RATE_HZ = 100.0


@settings(max_examples=40, deadline=None)
@given(cutoff=st.floats(0.5, 45.0), order=st.integers(1, 6), seed=st.integers(0, 2**32 - 1),
       n_channels=st.integers(1, 40), n_samples=st.integers(1, 60))
def test_matches_scipy_sosfilt_started_at_steady_state(cutoff, order, seed, n_channels,
                                                        n_samples):
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 1.0, (n_samples, n_channels)) * rng.uniform(0.1, 1e3, n_channels)
    lowpass = BatchLowPass(n_channels, cutoff, RATE_HZ, order)
    got = np.stack([lowpass(row.copy()) for row in x])
    zi = signal.sosfilt_zi(lowpass.sos)[:, :, None] * x[0]
    expected, _ = signal.sosfilt(lowpass.sos, x, axis=0, zi=zi)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9 * np.abs(x).max())


def test_a_recorded_sequence_is_filtered_as_online_and_left_untouched():
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 50.0, (40, 6))
    online = BatchLowPass(6, 10.0, RATE_HZ, 2)
    expected = np.stack([online(row.copy()) for row in x])
    before = x.copy()
    np.testing.assert_array_equal(BatchLowPass(6, 10.0, RATE_HZ, 2).run(x), expected)
    np.testing.assert_array_equal(x, before)
    with pytest.raises(ValueError, match=r'need samples \(N, 6\)'):
        BatchLowPass(6, 10.0, RATE_HZ).run(x[:, :5])


@pytest.mark.parametrize('cutoff', [0.0, -1.0, 50.0, 80.0])
def test_a_cutoff_outside_the_band_is_refused(cutoff):
    with pytest.raises(FilterDesignError, match='half the frame rate'):
        BatchLowPass(3, cutoff, RATE_HZ)


@pytest.fixture(scope='module')
def estimator(hand):
    """M3 on every array (linear: the force step response is the filter's own)."""
    bundles, frames = [], []
    for k, array in enumerate(hand.arrays):
        data = synthetic_dataset(array, plates=('flat',), seconds=4.0, seed=k)
        X, F, offset = data.without_offsets()
        bundles.append(fit_bundle(array, 'M3', {}, X, F, data.plates, x_offset=offset))
        frames.append((data.X[:20].mean(axis=0), data.X[np.argmax(-F[:, 2])]))
    rest = hand.merge([r for r, _ in frames])
    pressed = hand.merge([p for _, p in frames])
    return RuntimeEstimator(hand, bundles), rest, pressed


@pytest.mark.parametrize('cutoff, order', [(10.0, 2), (5.0, 2), (10.0, 4), (2.0, 1)])
def test_step_delay_is_the_design_group_delay_within_a_frame(hand, estimator, cutoff, order):
    runtime, rest, pressed = estimator
    runtime.set_lowpass(cutoff, RATE_HZ, order)
    try:
        # Array 0 is pressed at frame 20; the others stay at rest.
        frames = [rest] * 20 + [np.where(np.isin(np.arange(hand.n_taxels),
                                                 hand.arrays[0].flat_indices)[:, None],
                                         pressed, rest)] * 400
        forces = np.stack([runtime.estimate(f).force.copy() for f in frames])
    finally:
        runtime.set_lowpass(None, RATE_HZ)
    before, after = forces[0, 0], runtime.estimate(frames[-1]).force[0]
    step = (forces[20:, 0] - before) / (after - before)       # per axis, 0 -> 1
    # Delay of a step = sum of (1 - s[n]): the first moment of the impulse response, which is
    # the group delay at 0 Hz for a filter of unit DC gain.
    measured_frames = (1.0 - step).sum(axis=0)
    design_frames = runtime_delay_frames(cutoff, order)
    np.testing.assert_allclose(measured_frames, design_frames, atol=1.0)
    # The other arrays, filtered with their own state, never moved.
    np.testing.assert_allclose(forces[:, 1:], np.broadcast_to(forces[0, 1:], forces[:, 1:].shape),
                               atol=1e-9)


def runtime_delay_frames(cutoff, order):
    return BatchLowPass(1, cutoff, RATE_HZ, order).group_delay_s() * RATE_HZ


def test_a_constant_input_passes_unchanged_from_the_first_frame(estimator):
    runtime, rest, pressed = estimator
    unfiltered = runtime.estimate(pressed).force.copy()
    runtime.set_lowpass(3.0, RATE_HZ, 4)
    try:
        for _ in range(30):
            np.testing.assert_allclose(runtime.estimate(pressed).force, unfiltered,
                                       rtol=1e-9, atol=1e-9)
    finally:
        runtime.set_lowpass(None, RATE_HZ)


def test_nan_input_is_not_carried_into_later_frames(hand, estimator):
    runtime, rest, pressed = estimator
    unfiltered = runtime.estimate(pressed).force.copy()
    runtime.set_lowpass(10.0, RATE_HZ)
    try:
        runtime.estimate(pressed)
        broken = pressed.astype(np.float64)
        broken[hand.arrays[3].flat_indices[0], 2] = np.nan
        result = runtime.estimate(broken)
        assert not result.valid[3] and result.valid.sum() == len(hand.arrays) - 1
        after = runtime.estimate(pressed)
    finally:
        runtime.set_lowpass(None, RATE_HZ)
    # The array restarts at steady state on its next finite frame; the others never stopped.
    assert after.valid.all()
    np.testing.assert_allclose(after.force, unfiltered, rtol=1e-9, atol=1e-9)
