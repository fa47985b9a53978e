"""Actuator torque-gain error: the motor delivers a per-joint share of the commanded torque."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.sim.effects import Effect


@dataclass
class TorqueGainError(Effect):
    name = 'torque_gain_error'
    # The V4 driver maps torque to PWM with one nominal factor (1200 PWM/N m, docs/PROTOCOLS.md
    # section 2): a voltage, not a current, command. The torque it yields scales with the
    # winding resistance (copper +0.39 %/K: a warm hand delivers 8-15 % less), with the motor
    # constant's tolerance (+/-10 %, usual for small DC motors) and with each joint's gear
    # efficiency, against which the nominal factor was set; the sign per joint is unknown, so
    # the draw is symmetric, +/-20 %, per joint of this hand (sensor_seed), uniform. SIZED, not
    # predicted: with the controller's q_d (config/params/force_controller.yaml) this range
    # makes the simulated open loop miss by about what the paper measured (0.46 N, Table III),
    # which is the only open-loop figure published; the paper gives no per-cause breakdown.
    low: float = 0.8
    high: float = 1.2

    def draw_hand(self, rng: np.random.Generator, ctx) -> None:
        self.gain = rng.uniform(self.low, self.high, 16)

    def on_torque(self, state) -> None:
        state.torque = state.torque * self.gain


EFFECT = TorqueGainError
