"""Holding an object on the simulated hand, composed in-process: the grasp simulator, the
estimator's ModelSet (tared on the first frames, as the estimator node tares) and the
GraspController, ticking at the control rate with the torque held over the physics steps in
between and reaching the hand one control period late (as closed_loop.run_closed_loop).

A run as a lab's: the fingers hold their start poses `settle_seconds` (the estimator tares on
the last frames of it, out of contact), the goal starts at t = 0 (its first tick one control
period later), the fingers close and ramp to
the grip while the fixture holds the object, the fixture lets go at the scene's `hand_over`, and
the fingers hold it to the scene's end.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.control.grasp import (THROUGH, GraspConfig, GraspController, GraspGoal,
                                        approach_targets)
from tacforce_ros.estimation.model_set import TareWindow
from tacforce_ros.experiments.closed_loop import CommandLink, control_period, steps_per_tick
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.hand.pinch import joint_limits, pad
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.scene import Scene

if TYPE_CHECKING:
    from tacforce_ros.control.force_controller import ForceControllerConfig
    from tacforce_ros.estimation.model_set import ModelSet
    from tacforce_ros.hand.description import HandDescription

SETTLED_AFTER_HAND_OVER = 1.0    # s after the fixture lets go before the hold is judged


@dataclass
class GraspTrace:
    """One grasp sampled at the control ticks; forces in the hand's base frame, newtons."""

    fingers: tuple[str, ...]
    t: np.ndarray                  # (T,) s since the goal started
    f_d: np.ndarray                # (T, n, 3) desired, per finger
    f_hat: np.ndarray              # (T, n, 3) estimate (NaN when not fresh)
    f_true: np.ndarray             # (T, n, 3) simulated contact force (the finger on the object)
    directions: np.ndarray         # (T, n, 3) each finger's grip direction d_i at each tick
    grip: np.ndarray               # (T,) grip asked (the goal's, raised on slip)
    object_position: np.ndarray    # (T, 3) m, base frame
    held_by_fixture: np.ndarray    # (T,) bool
    dropped: np.ndarray            # (T,) bool, the simulator's judgement
    phase: np.ndarray              # (T,) str, the controller's
    command: float                 # N, the goal's grip
    transitions: list[str] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) if not isinstance(v, np.ndarray) else v
                for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_arrays(cls, arrays) -> GraspTrace:
        values = {k: arrays[k] for k in arrays.files} if hasattr(arrays, 'files') else dict(arrays)
        values['fingers'] = tuple(str(f) for f in values['fingers'])
        values['command'] = float(values['command'])
        values['transitions'] = [str(x) for x in values['transitions']]
        return cls(**values)


def grasp_targets(scene: Scene, kinematics: HandKinematics, through: float = THROUGH
                  ) -> dict[str, tuple[float, ...]]:
    """Each finger's joint target for the scene's grasp (control.grasp.approach_targets from its
    start and contact poses)."""
    lower, upper = joint_limits(kinematics)
    poses = {f: (p['pose'], p['contact_pose']) for f, p in scene.grasp['fingers'].items()}
    return approach_targets(poses, kinematics, lower, upper, through)


def run_grasp(hand: HandDescription, scene: str | Scene,
              seed: int, configs: dict[str, ForceControllerConfig], models: ModelSet | None,
              grip: float, grasp_config: GraspConfig | None = None, mass: float | None = None,
              control_rate: float = RATE_HZ, tare_frames: int = 50,
              settle_seconds: float | None = None,
              estimator_outage: dict[str, tuple[float, float]] | None = None) -> GraspTrace:
    """One grasp of the scene's object at `grip` N. configs: each finger's law (open loop: k_i
    = 0, models may then be None). mass: the goal's (default the scene object's: the operator
    knows what it hands over). estimator_outage: finger -> (start, end) s with no estimate.
    settle_seconds: the start-pose hold before the goal (default the scene's `goal_at`).
    The controller's kinematics take the scene's gravity (the hand's mount).
    """
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    if settle_seconds is None:
        settle_seconds = float(scene.grasp['goal_at'])
    sim = make_simulator(scene, hand, seed=seed)
    gravity = tuple(float(v) for v in scene.grasp['gravity'])
    kinematics = HandKinematics.for_hand(hand, gravity=gravity)
    config = dataclasses.replace(grasp_config or GraspConfig(), gravity=gravity)
    controller = GraspController(configs, kinematics,
                                 lambda q, f: pad(hand, kinematics, q, f)[0], config)
    open_loop = all(not any(c.k_i) for c in configs.values())
    if models is None and not open_loop:
        raise ValueError('a closed-loop grasp (k_i != 0) needs force models')
    every = steps_per_tick(sim.dt, control_rate)
    link = CommandLink(every)       # one control period from a tick's state to its torque
    fingers = sim.fingers
    rows = None if models is None else {f: [a.name for a in models.arrays].index(f'{f}_tip')
                                        for f in fingers}
    settle_ticks = int(round(settle_seconds * control_rate))
    if settle_ticks < tare_frames:
        raise ValueError(f'settle_seconds {settle_seconds} s holds fewer than the '
                         f'{tare_frames} frames the tare needs at {control_rate:g} Hz')
    tare = TareWindow(tare_frames)
    if models is not None:
        models.check_taxels()
    goal = GraspGoal(fingers=fingers, grip=grip, targets=grasp_targets(scene, kinematics),
                     mass=scene.grasp_object.mass if mass is None else mass)
    ticks = int(round((scene.duration - settle_seconds) * control_rate))
    n = len(fingers)
    log = {key: np.full((ticks, n, 3), np.nan) for key in ('f_d', 'f_hat', 'f_true')}
    directions = np.full((ticks, n, 3), np.nan)
    log_t, log_grip = np.zeros(ticks), np.zeros(ticks)
    position, fixture = np.zeros((ticks, 3)), np.zeros(ticks, bool)
    dropped, phase = np.zeros(ticks, bool), np.empty(ticks, dtype=object)
    transitions: list[str] = []
    q = qdot = None
    q_time = -np.inf
    estimates = {f: (np.full(3, np.nan), np.inf) for f in fingers}
    stamps = {f: -np.inf for f in fingers}
    torque = np.zeros(16)
    start = settle_ticks / control_rate
    hold = {f: None for f in fingers}   # the start-pose hold before the goal
    for tick in range(-settle_ticks, ticks):
        sample, frame = control_period(sim, link, torque, every)
        t = sample.t - start
        if q is None:
            q, qdot = sample.q, sample.qdot
        if sample.delivered['joints']:
            q, qdot, q_time = sample.q, sample.qdot, t
        if -tare_frames <= tick < 0 and models is not None and frame is not None:
            tare.add(frame)
        if tick == 0:
            if models is not None:
                models.set_tare(tare.take())
            controller.start(goal, q)
        if tick >= 0 and models is not None and frame is not None:
            estimate = models.estimate(frame)
            for f in fingers:
                down = estimator_outage is not None and f in estimator_outage and (
                    estimator_outage[f][0] <= t < estimator_outage[f][1])
                if estimate.valid[rows[f]] and not down:
                    stamps[f] = t
                    estimates[f] = (estimate.force[rows[f]], 0.0)
        ages = {f: (estimates[f][0], t - stamps[f]) for f in fingers}
        if tick < 0:
            torque = _start_hold(hold, configs, kinematics, t, q, qdot, t - q_time)
            continue
        tau, state = controller.update(t, q, qdot, ages, t - q_time)
        transitions += [f'{t:.3f} s {x}' for x in state.transitions]
        torque = tau
        log_t[tick], log_grip[tick], phase[tick] = t, state.grip, state.phase
        for i, f in enumerate(fingers):
            finger = state.fingers[f]
            log['f_d'][tick, i] = finger.desired
            log['f_hat'][tick, i] = finger.estimate
            log['f_true'][tick, i] = sample.finger_forces_base[f]
            directions[tick, i] = controller.directions[f]
        position[tick] = sample.object_position
        fixture[tick], dropped[tick] = sample.held_by_fixture, sample.dropped
    return GraspTrace(fingers=fingers, t=log_t, grip=log_grip, object_position=position,
                      held_by_fixture=fixture, dropped=dropped, phase=phase.astype(str),
                      command=float(grip),
                      directions=directions,
                      transitions=transitions, **log)


def _start_hold(hold: dict, configs: dict, kinematics, t: float, q: np.ndarray,
                qdot: np.ndarray, q_age: float) -> np.ndarray:
    """The fingers' start-pose hold before the goal (a FingerSession with no command yet)."""
    from tacforce_ros.control.finger_session import FingerSession
    torque = np.zeros(16)
    for f in hold:
        if hold[f] is None:
            hold[f] = FingerSession(configs[f], kinematics)
        tau, _, _ = hold[f].update(t, q, qdot, np.full(3, np.nan), np.inf, q_age, None)
        torque[hold[f].joints] = tau
    return torque


def grasp_metrics(trace: GraspTrace) -> dict:
    """One run's figures. Judged from SETTLED_AFTER_HAND_OVER s after the fixture let go (the
    load taken) to the end: per finger e~ (mean |f_d - f_true|, the paper's e~ per fingertip),
    the grip error (mean |grip measured - grip asked|, the measured grip being the mean over the
    fingers of f_true along d_i), slip (mm the object moved from the hand-over to the end, or to
    the drop). Before the hand-over (first touch and ramp, the fixture holding the object): each
    finger's peak |f_true| over its |f_d| at the hand-over."""
    t, before = trace.t, trace.held_by_fixture
    released = int((~before).argmax()) if (~before).any() else len(t) - 1
    judged = t >= t[released] + SETTLED_AFTER_HAND_OVER
    if released == len(t) - 1 or not judged.any():
        raise ValueError(f'the run ends {t[-1] - t[released]:.2f} s after the hand-over: '
                         f'nothing to judge (the hold is judged from '
                         f'{SETTLED_AFTER_HAND_OVER:g} s after it)')
    error = np.linalg.norm(trace.f_d - trace.f_true, axis=2)          # (T, n)
    per_finger = {f: float(error[judged, i].mean()) for i, f in enumerate(trace.fingers)}
    along = np.einsum('tni,tni->tn', trace.f_true, trace.directions)
    grip_error = float(np.abs(along[judged].mean(axis=1) - trace.grip[judged]).mean())
    peaks = {}
    for i, f in enumerate(trace.fingers):
        command = float(np.linalg.norm(trace.f_d[max(released - 1, 0), i]))
        peak = float(np.linalg.norm(trace.f_true[before, i], axis=1).max())
        peaks[f] = peak / command if command > 0 else None
    end = int(trace.dropped.argmax()) if trace.dropped.any() else len(t) - 1
    slip = float(np.linalg.norm(trace.object_position[end] - trace.object_position[released]))
    return {'finger_error_n': per_finger,
            'finger_error_mean_n': float(np.mean(list(per_finger.values()))),
            'grip_error_n': grip_error, 'peak_over_command': peaks, 'slip_mm': 1e3 * slip,
            'dropped': bool(trace.dropped.any()), 'grip_raised_to_n': float(trace.grip.max())}
