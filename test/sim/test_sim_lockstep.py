"""TimeGate (sim/lockstep.py): simulated time never runs more than one period (plus the slack)
beyond the newest stamp of a gated stream, never deadlocks a stream that keeps up, and is
released by a silent one; RealTimeMeter: the achieved factor."""
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.sim.lockstep import JOIN_INTERVALS, PERIOD_WINDOW, RealTimeMeter, TimeGate

MS = 1_000_000


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_stream_holds_time_once_its_period_is_known():
    gate = TimeGate(['/a'], slack_s=0.002, silence_s=5.0)
    assert gate.holding(10**12) is None              # not heard yet: start-up order is free
    for k in range(JOIN_INTERVALS):
        gate.heard('/a', 100 * MS + k * 10 * MS)
        assert gate.holding(10**12) is None          # period not known yet
    newest = 100 * MS + JOIN_INTERVALS * 10 * MS
    gate.heard('/a', newest)
    assert gate.holding(newest + 12 * MS) is None    # newest + period 10 + slack 2
    assert gate.holding(newest + 13 * MS).name == '/a'


def test_the_slowest_stream_holds_and_a_gap_does_not_loosen_the_gate():
    gate = TimeGate(['/fast', '/slow'], slack_s=0.0, silence_s=5.0)
    for k in range(20):
        gate.heard('/fast', k * 3 * MS)
        gate.heard('/slow', k * 10 * MS)
    # newest: fast 57 ms (+3), slow 190 ms (+10): the fast one is furthest behind
    assert gate.holding(61 * MS).name == '/fast'
    assert gate.holding(60 * MS) is None
    gate.heard('/fast', 100 * MS)                    # a 43 ms gap (a starved consumer)
    assert gate.streams['/fast'].period_ns() == 3 * MS
    assert gate.holding(106 * MS).name == '/fast'
    for k in range(1, PERIOD_WINDOW // 2):           # and jitter: 1 ms early, then late
        gate.heard('/fast', 100 * MS + k * 3 * MS + (-1 if k % 2 else 1) * MS)
    assert gate.streams['/fast'].period_ns() >= 3 * MS


def test_a_silent_stream_is_released_and_rejoins_when_it_speaks():
    clock, events = FakeClock(), []
    gate = TimeGate(['/a'], slack_s=0.0, silence_s=1.0, on_event=events.append, clock=clock)
    for k in range(JOIN_INTERVALS + 1):
        gate.heard('/a', k * 10 * MS)
    held = (JOIN_INTERVALS + 2) * 10 * MS
    assert not gate.wait(held, timeout_s=0.0)        # held, not yet silent for 1 s
    clock.now += 1.5
    assert gate.wait(held, timeout_s=0.0)            # released
    assert gate.streams['/a'].released and gate.streams['/a'].releases == 1
    assert 'no longer waits' in events[-1]
    gate.heard('/a', held)                           # back: its period is learnt again
    assert not gate.streams['/a'].released and 'again' in events[-1]
    assert gate.holding(10**12) is None


def test_an_ongoing_stream_holds_time_at_its_newest_stamp_plus_the_slack():
    """A device stream that keeps coming (the joint states): its rate in simulated time follows
    how fast the simulation runs, so no period is learnt; simulated time stays within the slack
    of its newest stamp, which keeps coming at the held time."""
    gate = TimeGate([], slack_s=0.006, silence_s=5.0, ongoing=['/joints'])
    assert gate.holding(10**12) is None
    gate.heard('/joints', 100 * MS)
    assert gate.holding(106 * MS) is None and gate.holding(107 * MS).name == '/joints'
    for _ in range(20):                          # a starved intake: bursts, then a long gap
        gate.heard('/joints', 100 * MS)
    gate.heard('/joints', 150 * MS)
    assert gate.holding(157 * MS).name == '/joints'      # the gap did not loosen it


def test_an_ongoing_stream_holds_time_from_its_start_before_it_speaks():
    """When simulated time starts, a device stream is due: a consumer still starting up holds
    time at the start plus the slack, and is released if it stays silent."""
    clock, events = FakeClock(), []
    gate = TimeGate(['/state'], slack_s=0.004, silence_s=1.0, ongoing=['/joints'],
                    on_event=events.append, clock=clock)
    assert gate.holding(10**12) is None              # before the start: nothing holds
    gate.start(500 * MS)
    assert gate.holding(504 * MS) is None and gate.holding(505 * MS).name == '/joints'
    gate.heard('/joints', 520 * MS)
    assert gate.holding(524 * MS) is None
    gate.start(510 * MS)                             # a stream that spoke since keeps its stamp
    assert gate.streams['/joints'].newest_ns == 520 * MS
    clock.now += 1.5
    assert gate.wait(10**12, timeout_s=0.0) and 'no longer waits' in events[-1]


def test_a_stream_of_known_period_holds_time_from_its_first_message():
    """The estimate of each tactile frame: its period is the simulator's frame period, so it
    holds time at once instead of after JOIN_INTERVALS intervals of free-running time."""
    gate = TimeGate(['/wrench', '/state'], slack_s=0.004, silence_s=5.0,
                    periods={'/wrench': 0.01})
    assert gate.holding(10**12) is None
    gate.heard('/wrench', 500 * MS)
    assert gate.holding(514 * MS) is None and gate.holding(515 * MS).name == '/wrench'
    gate.heard('/state', 500 * MS)                   # a learnt one still has to join
    assert gate.holding(514 * MS) is None


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match='silence'):
        TimeGate(['/a'], slack_s=0.0, silence_s=0.0)
    with pytest.raises(ValueError, match='twice'):
        TimeGate(['/a', '/a'], slack_s=0.0, silence_s=1.0)
    with pytest.raises(ValueError, match='twice'):
        TimeGate(['/a'], slack_s=0.0, silence_s=1.0, ongoing=['/a'])
    with pytest.raises(ValueError, match='periods'):
        TimeGate(['/a'], slack_s=0.0, silence_s=1.0, ongoing=['/b'], periods={'/b': 0.01})
    with pytest.raises(ValueError, match='periods'):
        TimeGate(['/a'], slack_s=0.0, silence_s=1.0, periods={'/a': 0.0})


@settings(max_examples=100, deadline=None)
@given(period_steps=st.integers(1, 20), step_ms=st.sampled_from([1, 10]),
       slack_ms=st.integers(0, 3), eagerness=st.floats(0.05, 0.95),
       seed=st.integers(0, 2**31 - 1))
def test_lockstep_with_a_consumer_that_keeps_up_never_deadlocks_nor_runs_ahead(
        period_steps, step_ms, slack_ms, eagerness, seed):
    """A stepping loop and a periodic consumer (one message per period_steps steps of simulated
    time, e.g. an estimate per tactile frame) taking turns at random. The consumer stamps each
    message with its data's time as its clock reads it: up to a step early (that step's /clock
    can reach it after the data) or late by up to the slack (a timer's callback runs once
    simulated time has moved on); sim_world gives the gate two steps of slack. Simulated time
    reaches its end with no release, and never runs more than one period + slack beyond the
    newest stamp once the stream holds."""
    rng = random.Random(seed)
    slack = slack_ms + 2 * step_ms
    gate = TimeGate(['/consumer'], slack_s=slack * 1e-3, silence_s=3600.0)
    t = 0                       # simulated time, ms
    due = 0                     # simulated time of the consumer's next message
    newest = None
    end = 40 * period_steps * step_ms
    for _ in range(1_000_000):
        if t >= end:
            break
        if due <= t and rng.random() < eagerness:
            stamp = rng.randint(max(0, due - step_ms), min(t, due + slack))
            gate.heard('/consumer', stamp * MS)
            newest = stamp if newest is None else max(newest, stamp)
            due += period_steps * step_ms
        elif gate.holding((t + step_ms) * MS) is None:
            t += step_ms
            if gate.streams['/consumer'].period_ns() is not None:
                period = gate.streams['/consumer'].period_ns() // MS
                assert t <= newest + period + slack
        elif due > t:
            break               # the consumer has nothing to send and time is held: deadlock
    assert t >= end, f'stuck at {t} ms with newest stamp {newest} ms'
    assert gate.streams['/consumer'].releases == 0


def test_meter_reports_simulated_per_wall_second():
    clock = FakeClock()
    meter = RealTimeMeter(clock)
    meter.start(2.0)
    clock.now += 10.0
    assert meter.window(6.0) == pytest.approx((0.4, 10.0))
    clock.now += 5.0
    assert meter.window(11.0) == pytest.approx((1.0, 5.0))
    assert meter.overall(11.0) == pytest.approx((0.6, 9.0, 15.0))
