"""Simulated time that waits for the node graph: a gate on the stamps its consumers publish.

A free-running simulator outruns the nodes that close its loop on a slow machine: the
controller then acts on old joints and estimates, its watchdog trips, and a slower machine gives
a different result. With a TimeGate the stepping loop asks, before each step, whether simulated
time may reach the step's end: only if every gated stream has published a message stamped
recently enough. A periodic stream (one message per period of simulated time: the controller's
ticks, the estimates of a tactile frame, the recorder's samples) may be one of its periods plus
`slack` behind; an ongoing stream (a device stream that keeps coming whatever simulated time
does, stamped on arrival with the current clock: the joint states) only `slack`, so the
consumer's intake of it is never further behind than that, and as it keeps coming at the held
time it cannot hold time for ever. A consumer that falls behind therefore holds simulated time;
the run gets slower, not different.

A stream whose period is known (`periods`: one estimate or sample per tactile frame, whose rate
is the simulator's own) holds time from its first message with that period; the period of any
other is learnt from its stamps: the upper median of its last PERIOD_WINDOW intervals. A
stream's stamps are its data's simulated time (a frame's arrival, a timer's tick), off by up to
a step (the step's /clock can reach the consumer after its data) plus the slack (a
tick's callback may run once simulated time has moved on); the median is off by less, which the
slack covers, so the gate does not hold time before the stream's next message can exist. A gap
the stream left while starved does not loosen the gate (the largest interval would: in a closed-
loop session that let simulated time run past the estimator's stale timeout). A controller at 50
Hz therefore needs no setting. A stream of learnt period holds time once it has shown
JOIN_INTERVALS intervals (start-up order does not matter), and a stream that stays silent for
`silence` wall seconds while holding time is released (a node that died or stopped on purpose
must not freeze the world, and a gate that waited for a message that cannot come would be
freed); it rejoins, learning its period again, when it speaks again. No ROS here: sim_world
feeds the stamps from its subscriptions.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

PERIOD_WINDOW = 16      # stamp intervals a stream's period is taken over
JOIN_INTERVALS = 8      # intervals a stream must have shown before it holds time


@dataclass
class GatedStream:
    """What the gate knows about one consumer stream."""

    name: str
    periodic: bool                    # one message per period of simulated time (else: ongoing)
    known_period_ns: int | None = None    # a periodic stream's period when known, else learnt
    newest_ns: int | None = None      # newest stamp seen; None until the stream's first message
    intervals_ns: deque = field(default_factory=lambda: deque(maxlen=PERIOD_WINDOW))
    heard_wall: float = 0.0           # monotonic time of its last message
    released: bool = False            # silent too long: not holding time until it speaks again
    held_s: float = 0.0               # wall seconds simulated time waited for this stream
    releases: int = 0

    def period_ns(self) -> int | None:
        """How far beyond its newest stamp its next message may be due: for a periodic stream
        its known period from its first message, or the upper median of its recent intervals
        (None until it has joined); for an ongoing one nothing (0 from its first message)."""
        if self.newest_ns is not None and (not self.periodic or self.known_period_ns):
            return self.known_period_ns if self.periodic else 0
        if not self.periodic:
            return None
        if len(self.intervals_ns) < JOIN_INTERVALS:
            return None
        return sorted(self.intervals_ns)[len(self.intervals_ns) // 2]


class TimeGate:
    """May simulated time reach t? Only up to each active stream's newest stamp plus one of its
    periods and the slack."""

    def __init__(self, periodic: Sequence[str], slack_s: float, silence_s: float,
                 ongoing: Sequence[str] = (), periods: Mapping[str, float] | None = None,
                 on_event: Callable[[str], None] = lambda message: None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if slack_s < 0.0 or silence_s <= 0.0:
            raise ValueError(f'slack ({slack_s} s) must be >= 0 and silence ({silence_s} s) > 0')
        names = [*periodic, *ongoing]
        if len(set(names)) != len(names):
            raise ValueError(f'streams named twice: {names}')
        periods = dict(periods or {})
        if set(periods) - set(periodic) or not all(p > 0.0 for p in periods.values()):
            raise ValueError(f'periods {periods} must be > 0 s and name periodic streams')
        self.slack_ns = int(round(slack_s * 1e9))
        self.silence_s = silence_s
        self.streams = {name: GatedStream(name, name in periodic,
                                          int(round(periods[name] * 1e9)) if name in periods
                                          else None)
                        for name in names}
        self._on_event = on_event
        self._clock = clock
        self._changed = threading.Condition()

    def start(self, t_ns: int) -> None:
        """Simulated time starts at t_ns: every ongoing stream holds it from now on, as if it had
        just spoken at t_ns. A device stream is due from the first step, and a consumer still
        starting up when time starts (the hand's driver switches the servos on before its
        first joint state) would otherwise let time run free until its first message."""
        with self._changed:
            for s in self.streams.values():
                if not s.periodic and (s.newest_ns is None or s.newest_ns < t_ns):
                    s.newest_ns, s.heard_wall, s.released = t_ns, self._clock(), False
            self._changed.notify_all()

    def heard(self, stream: str, stamp_ns: int) -> None:
        """A message of `stream` stamped `stamp_ns` arrived (any thread)."""
        with self._changed:
            s = self.streams[stream]
            if s.released:
                s.released = False
                s.intervals_ns.clear()      # the gap it left is not its period
                self._on_event(f'{stream} speaks again: simulated time waits for it again')
            elif s.newest_ns is not None and stamp_ns > s.newest_ns:
                s.intervals_ns.append(stamp_ns - s.newest_ns)
            s.newest_ns = stamp_ns if s.newest_ns is None else max(s.newest_ns, stamp_ns)
            s.heard_wall = self._clock()
            self._changed.notify_all()

    def holding(self, t_ns: int) -> GatedStream | None:
        """The active stream furthest behind, if it keeps simulated time from reaching t_ns."""
        limits = [(s.newest_ns + s.period_ns() + self.slack_ns, s) for s in self.streams.values()
                  if s.period_ns() is not None and not s.released]
        if not limits:
            return None
        limit, slowest = min(limits, key=lambda item: item[0])
        return slowest if limit < t_ns else None

    def wait(self, t_ns: int, timeout_s: float) -> bool:
        """Block until simulated time may reach t_ns (True) or `timeout_s` passed (False).

        A stream that holds time and has been silent for `silence_s` is released here."""
        deadline = self._clock() + timeout_s
        with self._changed:
            while True:
                stream = self.holding(t_ns)
                if stream is None:
                    return True
                now = self._clock()
                if now - stream.heard_wall >= self.silence_s:
                    stream.released = True
                    stream.releases += 1
                    self._on_event(
                        f'{stream.name} silent for {now - stream.heard_wall:.1f} s (wall) at '
                        f'{stream.newest_ns * 1e-9:.3f} s simulated: simulated time no longer '
                        'waits for it')
                    continue
                if now >= deadline:
                    return False
                self._changed.wait(min(deadline, stream.heard_wall + self.silence_s) - now)
                stream.held_s += self._clock() - now


class RealTimeMeter:
    """Achieved real-time factor (simulated seconds per wall second) over the last window."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self.started: tuple[float, float] | None = None     # (wall, simulated) at the start
        self._mark: tuple[float, float] | None = None

    def start(self, t_sim: float) -> None:
        self.started = self._mark = (self._clock(), t_sim)

    def window(self, t_sim: float) -> tuple[float, float]:
        """(factor, wall seconds) since the previous call (or the start); starts a new window."""
        now = self._clock()
        wall, sim = self._mark
        self._mark = (now, t_sim)
        return ((t_sim - sim) / (now - wall) if now > wall else 0.0), now - wall

    def overall(self, t_sim: float) -> tuple[float, float, float]:
        """(factor, simulated seconds, wall seconds) since the start."""
        wall, sim = self.started
        elapsed = self._clock() - wall
        return ((t_sim - sim) / elapsed if elapsed > 0 else 0.0), t_sim - sim, elapsed

