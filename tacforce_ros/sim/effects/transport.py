"""Transport: latency with jitter, and drop-outs, per stream (tactile, ft, joints)."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from tacforce_ros.sim.effects import Effect

STREAMS = ('tactile', 'ft', 'joints')


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
        depth = {s: int(np.ceil((self.latency[s] + 4.0 * self.jitter[s]) / ctx.physics_dt)) + 1
                 for s in STREAMS}
        self._history = {s: deque(maxlen=depth[s]) for s in STREAMS}

    def on_delivery(self, state) -> None:
        # Each stream delivers what it carried `delay` steps ago (the oldest held when the
        # history is still short); a dropped message is flagged, the step keeps the old values.
        fields = {'tactile': ('counts_out', 'temperatures'), 'ft': ('wrench',),
                  'joints': ('q', 'qdot')}
        for stream in STREAMS:
            history = self._history[stream]
            history.append(tuple(getattr(state, f) for f in fields[stream]))
            delay = self.latency[stream] + abs(self._rng.normal(0.0, self.jitter[stream]))
            index = max(len(history) - 1 - int(round(delay / self._dt)), 0)
            for name, value in zip(fields[stream], history[index]):
                setattr(state, name, value)
            if self._rng.random() < self.drop[stream]:
                state.delivered[stream] = False


EFFECT = Transport
