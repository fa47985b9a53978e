"""Transport: latency with jitter, and drop-outs, per stream (tactile, ft, joints)."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from operator import attrgetter

import numpy as np

from tacforce_ros.sim.effects import Effect

# Each stream and the step-state fields its messages carry.
STREAM_FIELDS = {'tactile': ('counts_out', 'temperatures'), 'ft': ('wrench',),
                 'joints': ('q', 'qdot')}
BLOCK = 256   # steps of random draws made at once


@dataclass
class Transport(Effect):
    name = 'transport'
    # Latency and drop rates: our estimates for xela_server's WebSocket (CAN -> JSON), Net F/T
    # RDT over UDP and the Allegro CAN bus.
    latency: dict = field(default_factory=lambda: {'tactile': 0.008, 'ft': 0.001,
                                                   'joints': 0.001})   # s
    jitter: dict = field(default_factory=lambda: {'tactile': 0.004, 'ft': 0.0005,
                                                  'joints': 0.0005})   # s, half-normal
    drop: dict = field(default_factory=lambda: {'tactile': 0.005, 'ft': 0.001,
                                                'joints': 0.001})      # probability per message

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._rng = rng
        self._dt = ctx.physics_dt
        self._streams = tuple(STREAM_FIELDS)
        self._latency = np.array([self.latency[s] for s in self._streams])
        self._jitter = np.array([self.jitter[s] for s in self._streams])
        self._drop = np.array([self.drop[s] for s in self._streams])
        depth = np.ceil((self._latency + 4.0 * self._jitter) / self._dt).astype(int) + 1
        # One history of every carried field per step (one C call to take), each stream
        # reaching back at most its own depth - 1 steps.
        carried = [name for s in self._streams for name in STREAM_FIELDS[s]]
        self._snapshot = attrgetter(*carried)
        self._fields = tuple(tuple((name, carried.index(name)) for name in STREAM_FIELDS[s])
                             for s in self._streams)
        self._reach = tuple(int(d) - 1 for d in depth)
        self._history = deque(maxlen=int(depth.max()))
        self._next = BLOCK

    def _draw(self) -> None:
        n = len(self._streams)
        delay = self._latency + np.abs(self._rng.standard_normal((BLOCK, n))) * self._jitter
        # Python lists: one step reads 3 + 3 of them, cheaper than numpy scalars.
        self._delay = np.rint(delay / self._dt).astype(int).tolist()
        self._dropped = (self._rng.random((BLOCK, n)) < self._drop).tolist()
        self._next = 0

    def on_delivery(self, state) -> None:
        # Each stream delivers what it carried `delay` steps ago (the oldest held while the
        # history is short); a dropped message is flagged, the step keeps the delayed values.
        if self._next == BLOCK:
            self._draw()
        delays, dropped = self._delay[self._next], self._dropped[self._next]
        self._next += 1
        history = self._history
        history.append(self._snapshot(state))
        newest = len(history) - 1
        for stream, fields, reach, delay, lost in zip(self._streams, self._fields, self._reach,
                                                      delays, dropped):
            if delay:   # (no delay: the step's own values go out as they are)
                past = history[newest - min(delay, reach, newest)]
                for name, index in fields:
                    setattr(state, name, past[index])
            if lost:
                state.delivered[stream] = False


EFFECT = Transport
