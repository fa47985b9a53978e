"""Actuator torque-gain error: the motor delivers a per-joint share of the commanded torque."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class TorqueGainError(Effect):
    name = 'torque_gain_error'
    # The V4 driver maps torque to PWM with one nominal factor (1200 PWM/N m, PROTOCOLS.md
    # section 2): a voltage, not a current, command. The torque it yields scales with the
    # winding resistance (copper +0.39 %/K: a hand warmed 30 min and run near its 0.35 N m
    # throttling point, paper Sec. IV-C, sits some 20-40 K above the factor's calibration:
    # -8..-15 %), with the motor constant's tolerance (+/-10 %, usual for small DC motors) and
    # with each joint's gear efficiency. Drawn per joint of this hand (sensor_seed), uniform.
    low: float = 0.65
    high: float = 0.95

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        self.gain = rng.uniform(self.low, self.high, 16)

    def on_torque(self, state) -> None:
        state.torque = state.torque * self.gain


EFFECT = TorqueGainError
