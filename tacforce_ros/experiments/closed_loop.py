"""Closed-loop force control on the simulated hand, composed in-process (paper Sec. IV-C, V-C).

The same core objects the node graph wires over DDS, called directly and faster than real time:
the MuJoCo closed-loop simulator, the estimator's ModelSet (runtime estimator over the modelled
arrays, tared on the first frames as the estimator node tares), the FingerSession (start-pose
hold, engagement, force law and watchdog: the object the controller node runs), and the force
command sequence. Control and estimation tick at `control_rate` (paper: 100 Hz); the torque
is held over the physics steps in between, as the Allegro firmware holds the last command.

The torque of a tick reaches the hand `actuation_delay` after the state it was computed from
(default one control period, as in the node graph: in lockstep, simulated time may run one
controller period ahead of the controller's newest tick, so its command lands up to a period
late; a lab's ROS controller adds its compute and CAN transport, a few ms, an estimate). On the
empirical skin the loop hardly feels it; on the magnetic skin, whose gain changes within
millimetres, it sets where the tip comes to rest on the plate (docs/SKIN_PHYSICS.md).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.control.finger_session import FingerSession, Transition
from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.estimation.model_set import TareWindow
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.scene import Scene

if TYPE_CHECKING:
    from tacforce_ros.control.command_sequence import ForceSequence
    from tacforce_ros.control.force_controller import ForceControllerConfig
    from tacforce_ros.estimation.model_set import ModelSet
    from tacforce_ros.hand.description import HandDescription
    from tacforce_ros.hand.kinematics import HandKinematics

METRIC_WINDOW = (16.0, 70.0)   # s; paper Sec. V-C: after the initial f_d = 0 phase
SETTLE_SECONDS = 2.0           # start-pose hold before the sequence (tare and F/T zero)


@dataclass
class ClosedLoopTrace:
    """One run sampled at the control ticks; forces in the sequence's frame {F}, newtons."""

    t: np.ndarray          # (T,) s since the start of the sequence
    f_d: np.ndarray        # (T, 3) desired
    f_hat: np.ndarray      # (T, 3) estimate (NaN while there is none: open loop, before tare)
    f_tilde: np.ndarray    # (T, 3) F/T measurement
    transitions: list[str] = field(default_factory=list)   # the session's, in order

    def arrays(self) -> dict[str, np.ndarray]:
        return {'t': self.t, 'f_d': self.f_d, 'f_hat': self.f_hat, 'f_tilde': self.f_tilde,
                'transitions': np.asarray(self.transitions, dtype=str)}


class CommandLink:
    """Joint torques reaching the hand `delay_steps` physics steps after they were sent; zero
    torque before the first arrives (the Allegro's state before any command)."""

    def __init__(self, delay_steps: int, n_joints: int = 16) -> None:
        if delay_steps < 0:
            raise ValueError(f'a command cannot arrive before it is sent ({delay_steps} steps)')
        self._in_flight = deque([np.zeros(n_joints)] * delay_steps)

    def step(self, sent: np.ndarray) -> np.ndarray:
        """The torque the hand applies in this physics step, while `sent` goes on its way."""
        self._in_flight.append(sent)
        return self._in_flight.popleft()


def steps_per_tick(dt: float, control_rate: float) -> int:
    """Physics steps of `dt` s per control tick; the control rate must divide the physics
    rate."""
    every = int(round(1.0 / (control_rate * dt)))
    if every < 1 or abs(every * dt * control_rate - 1.0) > 1e-9:
        raise ValueError(f'control rate {control_rate} Hz must divide the physics rate '
                         f'{1.0 / dt:g} Hz')
    return every


def control_period(sim, link: CommandLink, torque: np.ndarray, every: int):
    """One control period: `every` physics steps, each applying what `link` delivers of the
    torque sent. Returns the last sample and the newest tactile frame delivered in the period
    (None when none came)."""
    frame = None
    for _ in range(every):
        sample = sim.step(link.step(torque))
        if sample.tactile_fresh and sample.delivered['tactile']:
            frame = sample.taxel_counts
    return sample, frame


def run_closed_loop(hand: HandDescription, kinematics: HandKinematics,
                    scene: str | Path | Scene,
                    seed: int, config: ForceControllerConfig, sequence: ForceSequence,
                    models: ModelSet | None, control_rate: float = RATE_HZ,
                    tare_frames: int = 50, settle_seconds: float = SETTLE_SECONDS,
                    estimator_outage: tuple[float, float] | None = None,
                    actuation_delay: float | None = None) -> ClosedLoopTrace:
    """Play `sequence` once. `models` None runs without an estimator (open loop only).
    `estimator_outage` (start, end), seconds of the sequence: no estimate in between, as when
    the estimator process is down (the in-process counterpart of `session --crash`).
    `actuation_delay` s (a whole number of physics steps; None: one control period): from a
    tick's state to its torque at the hand.

    As a lab run: the finger first holds its start pose clear of the plate for
    `settle_seconds` (gravity compensation and the PD of the law, no force terms); over the last
    `tare_frames` tactile frames of that hold the F/T sensor is zeroed (its mean is the bias the
    Net F/T's bias command removes) and the estimator is tared (the model's own tare comes from
    other sessions). Then the controller runs the sequence from t = 0, its guarded approach
    bringing the fingertip into contact (control/approach.py).
    """
    session = FingerSession(config, kinematics)
    if models is None and not session.controller.open_loop:
        raise ValueError('a closed-loop controller (k_i != 0) needs force models')
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    sim = make_simulator(scene, hand, seed=seed)
    if sim.finger != config.finger:
        raise ValueError(f'scene {scene.name} presses the {sim.finger} finger, the controller '
                         f'drives the {config.finger} (ForceControllerConfig.pressing_with)')
    every = steps_per_tick(sim.dt, control_rate)
    delay = 1.0 / control_rate if actuation_delay is None else actuation_delay
    delay_steps = int(round(delay / sim.dt))
    if abs(delay_steps * sim.dt - delay) > 1e-9:
        raise ValueError(f'actuation delay {delay} s must be a whole number of physics steps '
                         f'({sim.dt:g} s)')
    link = CommandLink(delay_steps)
    row = None if models is None else [a.name for a in models.arrays].index(scene.array)
    settle_ticks = int(round(settle_seconds * control_rate))
    if settle_ticks < tare_frames:
        raise ValueError(f'settle_seconds {settle_seconds} s holds fewer than the '
                         f'{tare_frames} frames the tare needs at {control_rate:g} Hz')
    tare = TareWindow(tare_frames)
    if models is not None:      # as the estimator node checks them (its default parameters)
        models.check_taxels()
    wrenches: list[np.ndarray] = []
    transitions: list[Transition] = []
    ft_zero = np.zeros(3)
    q = qdot = None
    q_time = estimate_time = -np.inf
    f_hat = np.full(3, np.nan)
    torque = np.zeros(16)
    ticks = int(round(sequence.duration * control_rate))
    log = {key: np.full((ticks, 3), np.nan) for key in ('f_d', 'f_hat', 'f_tilde')}
    log_t = np.zeros(ticks)
    start = settle_ticks / control_rate
    for tick in range(-settle_ticks, ticks):
        sample, frame = control_period(sim, link, torque, every)
        t = sample.t - start    # closed-loop samples are stamped at the end of their step
        if q is None:   # the first state, even if its message was dropped (then it is stale)
            q, qdot = sample.q, sample.qdot
        if sample.delivered['joints']:
            q, qdot, q_time = sample.q, sample.qdot, t
        f_d = None      # no command during the settle: the session holds the start pose
        if -tare_frames <= tick < 0:
            wrenches.append(sample.ft_wrench[:3])
            if models is not None and frame is not None:
                tare.add(frame)
        if tick == 0:
            ft_zero = np.mean(wrenches, axis=0)
            if models is not None:
                models.set_tare(tare.take())
        if tick >= 0:
            down = estimator_outage is not None and (
                estimator_outage[0] <= t < estimator_outage[1])
            if models is not None and frame is not None and not down:
                estimate = models.estimate(frame)
                if estimate.valid[row]:
                    f_hat, estimate_time = estimate.force[row], t
            f_d = sequence.force_at(t)
        tau, state, transition = session.update(t, q, qdot, f_hat, t - estimate_time,
                                                t - q_time, f_d)
        if transition is not None:
            transitions.append(transition)
        torque = np.zeros(16)
        torque[session.joints] = tau
        if tick < 0:
            continue
        log_t[tick] = t
        log['f_d'][tick] = f_d
        if state.estimate_fresh:
            log['f_hat'][tick] = state.estimated_force
        log['f_tilde'][tick] = sample.ft_wrench[:3] - ft_zero
    return ClosedLoopTrace(t=log_t, transitions=[str(x) for x in transitions], **log)


def trace_metrics(traces: list[ClosedLoopTrace],
                  window: tuple[float, float] = METRIC_WINDOW) -> dict:
    """The paper's Table III metrics over `window`, pooled over the repeats (mean and std over
    samples), plus the spread of the per-repeat means of e~, and the worst first touch of the
    repeats (its peak in N, and that peak over the first force commanded: first_touch).

    e_r, e_hat: estimate vs F/T; e_track: desired vs estimate; e~: desired vs F/T. Metrics that
    need the estimate are None when the runs had none (open loop).
    """
    inside = [(tr.t >= window[0]) & (tr.t <= window[1]) for tr in traces]
    f_d = np.concatenate([tr.f_d[k] for tr, k in zip(traces, inside)])
    f_tilde = np.concatenate([tr.f_tilde[k] for tr, k in zip(traces, inside)])
    f_hat = np.concatenate([tr.f_hat[k] for tr, k in zip(traces, inside)])
    true_tracking = error_stats(f_d, f_tilde)
    per_run = [error_stats(tr.f_d[k], tr.f_tilde[k]).e_hat_mean for tr, k in zip(traces, inside)]
    result = {'runs': len(traces), 'samples': int(f_d.shape[0]), 'window_s': list(window),
              'e_tilde_mean': true_tracking.e_hat_mean, 'e_tilde_std': true_tracking.e_hat_std,
              'e_tilde_per_run': per_run, 'estimate_coverage': 0.0,
              'e_r_mean': None, 'e_r_std': None, 'e_hat_mean': None, 'e_hat_std': None,
              'e_track_mean': None, 'e_track_std': None, 'estimate_gain': None}
    touches = [first_touch(tr) for tr in traces]
    peaks = [t['peak_n'] for t in touches if t['peak_n'] is not None]
    ratios = [t['ratio'] for t in touches if t['ratio'] is not None]
    result.update(first_touch_peak_n=max(peaks) if peaks else None,
                  first_touch_ratio=max(ratios) if ratios else None)
    have = np.all(np.isfinite(f_hat), axis=1)
    if have.any():
        estimate = error_stats(f_tilde[have], f_hat[have])
        tracking = error_stats(f_d[have], f_hat[have])
        result.update(estimate_coverage=float(have.mean()),
                      e_r_mean=estimate.e_r_mean, e_r_std=estimate.e_r_std,
                      e_hat_mean=estimate.e_hat_mean, e_hat_std=estimate.e_hat_std,
                      e_track_mean=tracking.e_hat_mean, e_track_std=tracking.e_hat_std,
                      estimate_gain=estimate_gain(f_tilde[have], f_hat[have]))
    return result


def first_touch(trace: ClosedLoopTrace) -> dict:
    """The fingertip's first touch: the largest |f~| before the sequence first commands a force,
    over the first force it holds (|f_d| where it first stays the same from one tick to the
    next after that; the paper sequence's 1 N after its ramp). None where the sequence never
    holds a force, or the run starts in contact (no tick before the command)."""
    nonzero = np.any(trace.f_d != 0.0, axis=1)
    held = nonzero[1:] & np.all(trace.f_d[1:] == trace.f_d[:-1], axis=1)
    if not nonzero.any() or not held.any() or not nonzero.argmax():
        return {'peak_n': None, 'command_n': None, 'ratio': None}
    before = trace.t < trace.t[nonzero.argmax()]
    peak = float(np.linalg.norm(trace.f_tilde[before], axis=1).max())
    command = float(np.linalg.norm(trace.f_d[1:][held.argmax()]))
    return {'peak_n': peak, 'command_n': command, 'ratio': peak / command}


def estimate_gain(f_tilde: np.ndarray, f_hat: np.ndarray, least: float = 0.1
                  ) -> list[float | None]:
    """Per axis, the least-squares slope of the estimate over the measured force (through 0):
    1 where the estimate scales as the force does; None on an axis whose rms force is below
    `least` [N] (no slope to speak of)."""
    power = np.mean(f_tilde * f_tilde, axis=0)
    slope = np.mean(f_hat * f_tilde, axis=0) / np.maximum(power, least ** 2)
    return [float(g) if p >= least ** 2 else None for g, p in zip(slope, power)]
