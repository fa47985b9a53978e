"""One finger's closed loop per tick, as a lab run goes: the object both the controller node and
the in-process experiments call, so the two differ only in how inputs reach it.

Until it engages, the finger holds the pose it had at the first tick with the law's own gravity and
PD terms and no force terms (k_i = 0, q_d = that pose), reported as mode 'hold': a session starts
clear of the plate while the F/T sensor is zeroed and the estimator tares. It engages on the first
desired force once (closed loop) a fresh, finite estimate is there; from then on the force law
runs, its position target brought from the engaging pose toward q_d by the guarded approach
(control/approach.py: stopped where the estimate first shows the touch, the force command waiting
for it; open loop, feeling nothing, closes slowly to q_d), with its watchdog
(control/force_controller.py), which ramps to a position hold on a stale estimate, fades to zero
torque on stale joints, and ramps back in when the streams return, holding the contact. Each change
of mode, or of its cause, is kept as a transition for the caller to log.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tacforce_ros.control.approach import GuardedApproach
from tacforce_ros.control.force_controller import (MODE_HOLD, MODE_OPEN_LOOP, ControllerState,
                                                   ForceController, ForceControllerConfig,
                                                   Kinematics)


@dataclass(frozen=True)
class Transition:
    t: float
    previous: str       # mode before ('start' at the first tick)
    mode: str
    reason: str

    def __str__(self) -> str:
        return f'controller {self.previous} -> {self.mode}: {self.reason}'


class FingerSession:
    """The start-pose hold, engagement, and the force law of one finger."""

    def __init__(self, config: ForceControllerConfig, kinematics: Kinematics) -> None:
        self.controller = ForceController(config, kinematics)
        self.kinematics = kinematics
        self.engaged = False
        self._start_hold: ForceController | None = None
        self.approach: GuardedApproach | None = None
        self._cause: tuple[str, str] | None = None      # mode, reason up to any ':'

    @property
    def config(self) -> ForceControllerConfig:
        return self.controller.config

    @property
    def joints(self) -> slice:
        return self.controller.joints

    def update(self, t: float, q: np.ndarray, qdot: np.ndarray, f_hat: np.ndarray,
               f_hat_age: float, q_age: float, f_d: np.ndarray | None,
               error: np.ndarray | None = None
               ) -> tuple[np.ndarray, ControllerState, Transition | None]:
        """One tick, arguments as ForceController.update; f_d None: no command has come yet.
        Returns the finger's 4 torques, the tick's state, and the transition this tick made
        (None when mode and cause are unchanged)."""
        if not self.engaged and f_d is not None:
            self.engaged = (self.controller.open_loop
                            or self.controller.estimate_fresh(f_hat, f_hat_age))
        if self.engaged:
            approaching, touch, arrived = self._approach(t, q, f_hat, f_hat_age)
            # Before the touch the law presses nothing: a force commanded in free space would
            # drive the tip onto the surface as a step of q_d did (open loop cannot tell the
            # touch, and is the paper's baseline: it gets the command as given).
            untouched = approaching and not self.controller.open_loop
            tau, state = self.controller.update(t, q, qdot, f_hat, f_hat_age, q_age,
                                                np.zeros(3) if untouched else f_d, error)
            if state.reason == 'streams fresh':
                if touch:
                    state.reason = (f'touched: |f_hat| {np.linalg.norm(f_hat):.2f} N, force '
                                    'control from here')
                elif arrived and not self.controller.open_loop:
                    # The target got to q_d before the estimate showed the touch (seen with a
                    # starved estimator): the P term presses from there, and the log says so.
                    state.reason = (f'at q_d without a touch: |f_hat| '
                                    f'{np.linalg.norm(f_hat):.2f} N < {self.config.touch_force:g}'
                                    ' N, force control from here')
                elif approaching:
                    state.reason = (f'approaching q_d at {self.approach.speed:g} rad/s'
                                    if not self.controller.open_loop else
                                    f'approaching q_d blind at {self.approach.blind_speed:g} '
                                    'rad/s (open loop feels no touch)')
        else:
            if self._start_hold is None:
                self._start_hold = ForceController(dataclasses.replace(
                    self.config, k_i=(0.0, 0.0, 0.0),
                    q_d=tuple(np.asarray(q, dtype=np.float64)[self.joints])), self.kinematics)
            tau, state = self._start_hold.update(t, q, qdot, f_hat, f_hat_age, q_age,
                                                 np.zeros(3))
            # The start hold is a K_i = 0 law, which names itself open loop (also while it
            # ramps back in after stale joints); only its watchdog's `safe` is said as is.
            if state.mode == MODE_OPEN_LOOP:
                state.mode = MODE_HOLD
                state.reason = ('start pose hold, no desired force yet' if f_d is None else
                                'start pose hold, waiting for a valid estimate')
        cause = (state.mode, state.reason.split(':')[0])
        transition = None
        if cause != self._cause:
            transition = Transition(float(t), 'start' if self._cause is None else self._cause[0],
                                    state.mode, state.reason)
            self._cause = cause
        return tau, state, transition

    def _approach(self, t: float, q: np.ndarray, f_hat: np.ndarray,
                  f_hat_age: float) -> tuple[bool, bool, bool]:
        """Move the law's position target on (the guarded approach). Returns whether it is still
        on its way (no touch yet, q_d not reached), whether this tick is the touch, and whether
        this tick brought the target to q_d without one."""
        cfg = self.config
        if self.approach is None:
            self.approach = GuardedApproach(np.asarray(q, dtype=np.float64)[self.joints],
                                            np.asarray(cfg.q_d), cfg.approach_speed,
                                            cfg.blind_speed)
        if self.approach.done:
            return False, False, False
        feels = (not self.controller.open_loop
                 and self.controller.estimate_fresh(f_hat, f_hat_age))
        touch = feels and float(np.linalg.norm(f_hat)) >= cfg.touch_force
        self.controller.set_position_target(self.approach.update(t, feels, touch))
        return not self.approach.done, touch, self.approach.done and not touch
