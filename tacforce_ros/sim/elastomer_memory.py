"""The elastomer's memory of past loads: creep (viscoelastic) and play (hysteresis)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Creep:
    """Standard-linear-solid creep of the elastomer, per displacement component: under a held
    load the displacement grows from its instantaneous value u to (1 + share) u with the time
    constant `tau`; released, the extra part decays with it. Exact for loads held over a step."""
    share: float      # creep compliance over the instantaneous one
    tau: float        # s

    def __post_init__(self) -> None:
        if self.share < 0.0 or self.tau <= 0.0:
            raise ValueError(f'creep needs share >= 0 and tau > 0, got {self.share}, {self.tau}')
        self._state: np.ndarray | None = None
        self._decay = 0.0

    def reset(self, shape: tuple[int, ...], dt: float) -> None:
        self._state = np.zeros(shape)
        self._decay = float(np.exp(-dt / self.tau))

    def __call__(self, instantaneous: np.ndarray) -> np.ndarray:
        self._state *= self._decay
        self._state += (1.0 - self._decay) * self.share * instantaneous
        return instantaneous + self._state


@dataclass
class Play:
    """Rate-independent hysteresis (a play operator), per component: the output holds until the
    input moves more than the half-width `relative * |input| + width` away from it, then
    follows at that distance. A load cycle reads a loop whose width grows with the load."""
    relative: float
    width: float

    def __post_init__(self) -> None:
        self._output: np.ndarray | None = None

    def reset(self, shape: tuple[int, ...]) -> None:
        self._output = np.zeros(shape)

    def __call__(self, value: np.ndarray) -> np.ndarray:
        half = self.relative * np.abs(value) + self.width
        # np.clip, without its wrapper's ~15 us (the magnetic skin calls this every frame)
        np.minimum(np.maximum(self._output, value - half, out=self._output), value + half,
                   out=self._output)
        return self._output.copy()
