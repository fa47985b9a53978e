"""Allegro actuators: firmware torque clamps and thermal throttling above 0.35 N m."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.rig import TORQUE_LIMITS
from tacforce_ros.sim.effects import Effect



@dataclass
class ActuatorLimits(Effect):
    name = 'actuator_limits'
    # The paper saw actuators overheat and throttle when driven above 0.35 N m (section IV-C).
    # First-order heating towards (tau / threshold)^2; throttled while the state is above 1, with
    # hysteresis down to `recover`. Time constant and throttled share are our estimates.
    threshold: float = 0.35        # N m
    time_constant: float = 10.0    # s
    throttled_scale: float = 0.5
    recover: float = 0.8

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._clamp = TORQUE_LIMITS.copy()   # the firmware's clamps
        self._negative_clamp = -self._clamp
        # heat' = (1 - a) heat + a (tau / threshold)^2 each step, a = dt / time_constant
        alpha = ctx.physics_dt / self.time_constant
        self._keep, self._gain = 1.0 - alpha, alpha / self.threshold ** 2
        self.heat = np.zeros(16)
        self.throttled = np.zeros(16, bool)
        self.throttling = False     # any joint throttled

    def on_torque(self, state) -> None:
        tau = np.minimum(np.maximum(state.torque, self._negative_clamp), self._clamp)  # np.clip
        self.heat *= self._keep
        self.heat += self._gain * (tau * tau)
        # np.maximum.reduce: ndarray.max without its Python wrapper (this runs every step)
        if not self.throttling and np.maximum.reduce(self.heat) <= 1.0:   # the usual step
            state.torque = tau
            return
        self.throttled = (self.heat > 1.0) | (self.throttled & (self.heat > self.recover))
        self.throttling = bool(self.throttled.any())
        state.torque = np.where(self.throttled, self.throttled_scale * tau, tau)


EFFECT = ActuatorLimits
