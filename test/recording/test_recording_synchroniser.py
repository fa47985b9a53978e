"""Approximate-time synchroniser: properties over random streams, plus exact small cases."""
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tacforce_ros.recording.synchroniser import (DROP_LATE, DROP_OVERFLOW, DROP_SUPERSEDED,
                                                 ApproximateTimeSynchroniser)

MS = 1_000_000


@st.composite
def streams(draw):
    """Messages of 2-4 inputs at different rates with jitter, delivered with random latency."""
    n_inputs = draw(st.integers(2, 4))
    arrivals = []
    for index in range(n_inputs):
        period = draw(st.integers(1, 12)) * MS
        stamp = draw(st.integers(0, 10 * MS))
        for seq in range(draw(st.integers(0, 40))):
            stamp += period + draw(st.integers(-period // 3, period // 3))
            latency = draw(st.integers(0, 25 * MS))
            arrivals.append((stamp + latency, index, stamp, (index, seq)))
    arrivals.sort()
    return n_inputs, [(index, stamp, msg) for _, index, stamp, msg in arrivals]


@given(case=streams(), queue_size=st.integers(1, 8), slop_ms=st.integers(0, 15))
def test_emitted_sets_are_within_slop_unique_monotone_and_queues_bounded(case, queue_size,
                                                                         slop_ms):
    n_inputs, arrivals = case
    sync = ApproximateTimeSynchroniser(n_inputs, queue_size, slop_ms / 1000)
    stamp_of = {msg: stamp for _, stamp, msg in arrivals}
    emitted = []
    for index, stamp, msg in arrivals:
        out = sync.add(index, stamp, msg)
        assert all(n <= queue_size for n in sync.queue_lengths())
        if out is not None:
            emitted.append(out)
    used = [msg for group in emitted for msg in group]
    assert len(used) == len(set(used)), 'a message was used twice'
    for group in emitted:
        assert [msg[0] for msg in group] == list(range(n_inputs)), 'one message per input'
        stamps = [stamp_of[msg] for msg in group]
        assert max(stamps) - min(stamps) <= slop_ms * MS
    for index in range(n_inputs):
        series = [stamp_of[group[index]] for group in emitted]
        assert series == sorted(series) and len(set(series)) == len(series)
        # Every message is accounted for: emitted, dropped (with a reason) or still queued.
        added = sum(1 for i, _, _ in arrivals if i == index)
        assert len(emitted) + sync.dropped[index] + sync.queue_lengths()[index] == added
        assert sum(sync.drop_reasons[index].values()) == sync.dropped[index]
    assert sync.emitted == len(emitted)


@given(n=st.integers(1, 40), rates=st.lists(st.sampled_from([1, 2, 4, 5]), min_size=3,
                                            max_size=3))
def test_in_order_streams_lose_no_coincident_set(n, rates):
    """Inputs ticking at 1, 2, 4 or 5 times per 10 ms, delivered in stamp order: a set is
    emitted at every instant where all inputs tick, made of exactly those messages."""
    sync = ApproximateTimeSynchroniser(3, queue_size=10, slop=0.0004)   # < 0.5 ms: 2 vs 2.5 ms
    ticks = [[k * (10 * MS // r) for k in range(n * r)] for r in rates]
    arrivals = sorted((stamp, i) for i, stamps in enumerate(ticks) for stamp in stamps)
    emitted = [out for stamp, i in arrivals if (out := sync.add(i, stamp, stamp)) is not None]
    coincident = sorted(set(ticks[0]) & set(ticks[1]) & set(ticks[2]))
    assert [group for group in emitted] == [(s, s, s) for s in coincident]


def test_picks_the_nearest_message_and_drops_the_older_ones():
    sync = ApproximateTimeSynchroniser(2, queue_size=10, slop=0.004)
    for stamp in (0, 2 * MS, 5 * MS, 9 * MS):      # wrench at irregular times
        assert sync.add(1, stamp, f'w{stamp // MS}') is None
    assert sync.add(0, 6 * MS, 't6') == ('t6', 'w5')
    assert sync.drop_reasons[1][DROP_SUPERSEDED] == 2     # w0 and w2 can never be used now
    assert sync.queue_lengths() == [0, 1]
    assert sync.add(1, 4 * MS, 'w4') is None               # older than w5, already emitted
    assert sync.drop_reasons[1][DROP_LATE] == 1
    assert sync.add(0, 20 * MS, 't20') is None             # w9 is 11 ms away: over the slop
    assert sync.add(1, 21 * MS, 'w21') == ('t20', 'w21')


def test_partners_each_within_slop_of_the_new_message_but_not_of_each_other_wait():
    sync = ApproximateTimeSynchroniser(3, queue_size=10, slop=0.004)
    sync.add(1, -4 * MS, 'a')
    sync.add(2, 4 * MS, 'b')
    assert sync.add(0, 0, 'p') is None              # a and b are 8 ms apart
    assert sync.add(1, 3 * MS, 'a2') == ('p', 'a2', 'b')


def test_full_queue_pushes_out_its_oldest_message():
    sync = ApproximateTimeSynchroniser(2, queue_size=2, slop=0.001)
    for stamp in (0, 10 * MS, 20 * MS):
        sync.add(0, stamp, stamp)
    assert sync.queue_lengths() == [2, 0] and sync.drop_reasons[0][DROP_OVERFLOW] == 1
    assert sync.add(1, 0, 'x') is None                      # its partner was pushed out
    assert sync.add(1, 10 * MS, 'y') == (10 * MS, 'y')


@pytest.mark.parametrize('args, field', [((1, 5, 0.01), 'n_inputs'), ((2, 0, 0.01), 'queue_size'),
                                         ((2, 5, -1.0), 'slop'), ((2, 5, float('nan')), 'slop')])
def test_bad_settings_are_refused(args, field):
    with pytest.raises(ValueError, match=field):
        ApproximateTimeSynchroniser(*args)
