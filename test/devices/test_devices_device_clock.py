"""DeviceClock (devices/device_clock.py): device times on the host clock are used as they are;
mapped onto it by the minimum-delay offset, they keep the device's spacing and never run before
the true time; repeats give no stamp and a device clock set back restarts the estimate."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.devices.device_clock import DeviceClock

MS = 1_000_000
OFFSET = 7_000_000_000_123          # host clock minus device clock


def test_device_times_on_the_host_clock_are_the_stamps_whatever_the_arrival():
    clock = DeviceClock(True)
    assert [clock.stamp(t, t + d) for t, d in [(10 * MS, 3 * MS), (20 * MS, -MS), (30 * MS, 0)]
            ] == [10 * MS, 20 * MS, 30 * MS]
    assert clock.stamp(30 * MS, 31 * MS) is None and clock.counts.repeated == 1


def test_stamps_keep_the_device_spacing_once_a_fast_sample_was_seen():
    clock = DeviceClock(False, max_skew=0.0)
    delays = [5 * MS, 2 * MS, 0, 3 * MS, 9 * MS, 1 * MS]
    stamps = [clock.stamp(k * 10 * MS, k * 10 * MS + OFFSET + d) for k, d in enumerate(delays)]
    assert stamps[:3] == [OFFSET + 5 * MS, 10 * MS + OFFSET + 2 * MS, 20 * MS + OFFSET]
    assert stamps[3:] == [k * 10 * MS + OFFSET for k in (3, 4, 5)]     # jitter gone


def test_an_old_bound_is_loosened_by_the_skew_allowance():
    clock = DeviceClock(False, max_skew=1e-3)
    assert clock.stamp(0, OFFSET) == OFFSET
    # 1 s later the old bound allows 1 ms more; a sample 5 ms late is stamped 1 ms late.
    assert clock.stamp(1000 * MS, 1000 * MS + OFFSET + 5 * MS) == 1000 * MS + OFFSET + MS


def test_repeats_give_no_stamp_and_a_clock_set_back_restarts_the_estimate():
    clock = DeviceClock(False)
    assert clock.stamp(100 * MS, OFFSET + 100 * MS) is not None
    assert clock.stamp(100 * MS, OFFSET + 105 * MS) is None
    assert clock.counts.repeated == 1
    later = clock.stamp(50 * MS, OFFSET + 110 * MS)          # the device clock was set back
    assert clock.counts.resets == 1 and later == OFFSET + 110 * MS


def test_stamps_stay_strictly_increasing_when_the_estimate_drops():
    clock = DeviceClock(False, max_skew=0.0)
    first = clock.stamp(0, OFFSET + 50 * MS)                  # the first sample came 50 ms late
    second = clock.stamp(10 * MS, OFFSET + 10 * MS)           # the next one at once
    assert second == first + 1 and clock.counts.moved == 1
    assert clock.stamp(60 * MS, OFFSET + 61 * MS) == OFFSET + 60 * MS


def test_bad_skew_is_refused():
    with pytest.raises(ValueError, match='max_skew'):
        DeviceClock(False, max_skew=-1e-6)


@settings(max_examples=200, deadline=None)
@given(intervals=st.lists(st.integers(1, 20 * MS), min_size=2, max_size=200),
       delays=st.lists(st.integers(0, 30 * MS), min_size=200, max_size=200),
       skew_ppm=st.integers(-100, 100), fast=st.integers(0, 199))
def test_stamps_increase_and_bracket_the_true_time(intervals, delays, skew_ppm, fast):
    """With the true offset drifting within the allowance and every delay >= 0: stamps strictly
    increase, are never before the true time of the sample, and once a zero-delay sample was
    seen, never later than its bound aged by the allowance (unless moved to keep the order)."""
    max_skew = 1e-4
    delays[fast] = 0
    device = np.cumsum(intervals).astype(np.int64)
    clock = DeviceClock(False, max_skew)
    stamps = []
    for k, t in enumerate(device):
        true = int(t + OFFSET + skew_ppm * 1e-6 * t)
        stamps.append(clock.stamp(int(t), true + delays[k]))
        assert stamps[-1] >= true - 2                   # 2 ns: integer rounding
        if k > fast and clock.counts.moved == 0:
            aged = max_skew * (t - device[fast]) + abs(skew_ppm) * 1e-6 * (t - device[fast])
            assert stamps[-1] <= true + aged + 2
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
