"""Actuator torque-gain error: the motor delivers a per-joint share of the commanded torque."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class TorqueGainError(Effect):
    name = 'torque_gain_error'
    # The V4 driver maps torque to PWM with one nominal factor (1200 PWM/N m, PROTOCOLS.md
    # section 2); motor constants and gearbox efficiency vary per joint. Range: our estimate.
    low: float = 0.80
    high: float = 0.95

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        self.gain = rng.uniform(self.low, self.high, 16)

    def on_torque(self, state) -> None:
        state.torque = state.torque * self.gain


EFFECT = TorqueGainError
