"""Magnetic crosstalk: the loaded array's magnets shift the fields read by neighbouring arrays."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class Crosstalk(Effect):
    name = 'crosstalk'
    # Share of the loaded array's mean count change seen by an adjacent array's taxels; our
    # estimate (the paper raises inter-array interference as an open issue, section II).
    coupling: float = 0.03

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        self._source = ctx.array.flat_rows
        names = ctx.array.neighbours
        self._targets = (np.concatenate([ctx.hand.array(n).flat_indices for n in names])
                         if names else np.zeros(0, np.int64))
        # Taxels nearer the shared edge couple more; without a cross-array geometry a fixed
        # random weight per taxel (a property of the hand) stands in for that distance.
        self._weights = self.coupling * rng.uniform(0.2, 1.0, (len(self._targets), 1))
        self._ctx = ctx   # rest counts are final only after the response stage
        self._source_idle = None   # the source's rest counts, taken at the first frame

    def on_counts(self, state) -> None:
        if self._source_idle is None:
            self._source_idle = self._ctx.idle_counts[self._source]
        # the mean over the source taxels as np.mean computes it (sum, then / count), without
        # its Python wrapper: this runs on every tactile frame
        change = np.add.reduce(state.counts[self._source] - self._source_idle, axis=0)
        change /= len(self._source)
        state.counts[self._targets] += self._weights * change


EFFECT = Crosstalk
