"""The guarded approach: the law's position target brought from where the finger engaged toward
q_d at a bounded joint speed, and stopped where the tactile estimate first shows the touch; from
there force control presses (in closed loop the force command waits for the touch).

Why. The law's P term pulls toward q_d, which lies inside the plate or object (so that the tip
stays pressed at f_d = 0, paper). Switched on as a step from a start pose clear of the plate, it
flung the fingertip onto it: the F/T sensor read 3.7 N at first touch on a 0 N command, settling
to the 0.65 N the P term holds (simulated spherical plate, seed 0). With the target moving at a
bounded speed the tip arrives at about that speed; stopped at the touch, the target no longer
drags the pad along the surface as it rolls on toward q_d (a target moved on to q_d after the
touch left 0.42 N of shear on 0.7 N of press, against 0.14 N after the step).

A touch is an estimate that is fresh and at least `touch_force` in magnitude. Without a fresh
estimate (open loop, which has none, or an estimate gone stale) the target moves at the blind
speed, and on to q_d: what the finger cannot feel it approaches as if it were already touching,
and the open loop, the paper's baseline, keeps its P-term press.
"""
from __future__ import annotations

import numpy as np


class GuardedApproach:
    """A joint-space target moving from `q_start` toward `q_goal` along the straight line between
    them, its largest joint at `speed` rad/s while the finger feels (a fresh estimate), at
    `blind_speed` while it does not; the first touch ends the way there: the target stays where
    it is. Time comes from the caller."""

    def __init__(self, q_start: np.ndarray, q_goal: np.ndarray, speed: float,
                 blind_speed: float) -> None:
        self.q_ref = np.array(q_start, dtype=np.float64)
        self.q_goal = np.array(q_goal, dtype=np.float64)
        if self.q_ref.shape != self.q_goal.shape or not (np.isfinite(self.q_ref).all()
                                                         and np.isfinite(self.q_goal).all()):
            raise ValueError(f'start {q_start!r} and goal {q_goal!r} must be finite joint angles '
                             'of one finger')
        if not (0.0 < blind_speed <= speed):
            raise ValueError(f'speeds must satisfy 0 < blind_speed ({blind_speed}) <= speed '
                             f'({speed})')
        self.speed, self.blind_speed = float(speed), float(blind_speed)
        self.touched_at: float | None = None
        self._t: float | None = None

    @property
    def done(self) -> bool:
        """The target moves no more: touched, or at q_goal."""
        return self.touched_at is not None or bool(np.array_equal(self.q_ref, self.q_goal))

    def update(self, t: float, feels: bool, touch: bool) -> np.ndarray:
        """The target at time t. feels: a fresh estimate came this tick; touch: it shows contact
        (the target stops where it was at the last tick). Returns the target (a copy)."""
        elapsed = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        if touch and self.touched_at is None:
            self.touched_at = float(t)
        if self.done:
            return self.q_ref.copy()
        speed = self.speed if feels else self.blind_speed
        step = self.q_goal - self.q_ref
        largest = float(np.abs(step).max())
        if largest <= speed * elapsed:
            self.q_ref = self.q_goal.copy()
        else:
            self.q_ref = self.q_ref + step * (speed * elapsed / largest)
        return self.q_ref.copy()
