"""Grasp controller: the thumb and another fingertip holding an object at a commanded grip
force, each fingertip closing its own force loop on its own tactile estimate. Pure numpy, no ROS:
the grasp_controller node and the in-process experiments call it alike.

Per fingertip it runs the paper's law with its integral (control/force_controller.py, through a
FingerSession: start-pose hold, guarded approach, watchdog), in the hand's base frame. What a
grasp adds is what each fingertip is asked to push:

* Desired forces (internal plus weight). Each fingertip i pushes along d_i, the unit vector from
  its tip toward the centre of the grasp (midway between the thumb's tip and the mean of the
  others' tips) at this tick's joint angles: f_d,i = g_i d_i + w, w = -m * gravity / n for n
  fingertips. With the thumb opposing the others the internal forces g_i d_i balance (a pinch:
  equal and opposite on one line, so no torque on the object), and the weight is shared equally:
  the least-norm split of a load over the contacts (Kerr and Roth, 1986). The line follows the
  fingers: squeezed along the line the tips had when the goal started (or when both had
  touched), a ball held by the thumb and index fingertip rolled out of the pinch once the
  fixture let go (simulated golf ball, 1 N: 18 mm sideways within 0.5 s, or dropped 2 s later).
* The integral acts on the internal force alone, and only once every finger touches. Each
  finger integrates the same error, the grip asked (mean over the fingers) less the grip the
  estimates read (the mean of their components along their d_i), along its own d_i; so the
  fingers' corrections stay equal and opposite, and the net force on the object is the
  feed-forward's (the weight share) and the P term's. Each finger integrating its own force
  error (the single finger's law) let two estimates that disagree push the object between them:
  with the support there, the support takes the difference, and when it goes the object jumps
  to where the fingers' joint springs take it (simulated golf ball on the magnetic skin, 1 N: the
  thumb's estimate read twice its force and the index's 0.75 of its; the ball jumped 17 mm at the
  hand-over); without a support, the pinch drifts (empirical skin: 17-60 mm in 8 s, 6 of 8
  objects and grips dropped). The internal force is what the grasp is asked for; internal and
  external forces of a grasp are controlled apart (Yoshikawa and Nagai, 1991).
* Guarded approach and a ramp from the touch. Each finger closes at the approach speed of its
  FingerSession until its estimate shows the touch (the force command withheld till then); from
  the touch its g_i ramps from the normal force it touched with to the grip at `force_rate`
  (N/s), so the contact force rises at a bounded rate from where it is instead of stepping to
  the command (a step of the command is a step of J^T f_d in the torque). The weight share ramps
  with it. At the touch the law's position target, which led the finger while it closed, is set
  to where the finger is: left ahead, its P term pressed on top of the command (simulated golf
  ball at 1 N: the contact force led the ramp by the ~0.25 N of the touch, 1.25x the grip at its
  peak).
* Slip. Each finger's share of unasked tangential force (the estimate's tangential part less
  the commanded one, the weight share, over the estimate's normal part), low-passed over
  `slip_window` s, is taken as its baseline once every finger has held its grip `slip_window` s;
  a share that rises `slip_rise` above it (the load outgrows the grip: more mass than the goal
  said, a push, the support gone under an object whose mass was not given) raises the grip at
  `slip_rate` N/s, never above what the joints can press (max_grip); the raise is kept. A rise,
  not the share itself against an assumed friction: an estimate's error in direction is a share
  of its own (the magnetic skin's thumb model read a pinched golf ball's force at 0.42 of
  tangential against 0.25 commanded, and a fixed threshold raised every grip to the joints'
  limit).
* A stale fingertip holds: its FingerSession's watchdog ramps it to the contact hold (the law
  with its command latched, open loop); the other fingers go on.
* A drop: every finger's estimate fresh and below half the touch force for `drop_time` s after
  all had touched ends the grasp as dropped: from then no force is commanded and nothing
  integrated (the fingers hold where they are by the law's P term). A finger with a stale
  estimate, or the open loop, cannot tell a drop.
* One fingertip against the thumb: with more, the thumb would have to press as hard as the
  others together (not built yet: such goals are refused).

Open loop (K_i = 0: the paper's baseline, the same poses and gains): it feels no touch, so each
finger's ramp starts when it engages and its approach goes on, blind, to its target.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from tacforce_ros.control.finger_session import FingerSession
from tacforce_ros.control.force_controller import (ControllerState, ForceControllerConfig,
                                                   Kinematics)
from tacforce_ros.rig import FINGERS, finger_torque_limits


def _param(default, description: str):
    """A configuration field with its description (the node's parameter help reads it)."""
    return field(default=default, metadata={'help': description})


# The single finger's q_d lies 0.2 rad past the plate on each flexion joint, four times the
# 0.05 rad its start pose is clear of it (config/params/force_controller.yaml): the same here.
THROUGH = 4.0

PHASE_IDLE = 'idle'           # no goal
PHASE_CLOSING = 'closing'     # some finger has not touched yet
PHASE_RAMPING = 'ramping'     # every finger touched; some grip still ramping
PHASE_HOLDING = 'holding'     # every finger at its grip
PHASE_DROPPED = 'dropped'     # every finger lost the object


class GraspGoalError(ValueError):
    """A grasp goal that cannot run; the message says why (the action's refusal reason)."""


@dataclass(frozen=True)
class GraspConfig:
    """What the grasp adds to each finger's law (SI units, forces in the hand's base frame)."""

    gravity: tuple[float, float, float] = _param(
        (0.0, 0.0, -9.81), 'gravity in the hand base frame (m/s^2), from the mounting')
    force_rate: float = _param(2.0, 'rate of each grip from the touch to the command (N/s)')
    grip_min: float = _param(0.3, 'smallest grip a goal may ask (N): below it a grip is lost '
                             'in the estimate\'s noise')
    friction: float = _param(0.5, 'skin on an unknown surface, the low end (assumed): the '
                             'grip a goal\'s mass needs')
    slip_margin: float = _param(0.8, 'share of the friction cone a goal\'s weight may load')
    # A rise of the unasked tangential share over its baseline that is a slip. 0.2 raised the
    # grip on a still tennis ball to the joints' limit (magnetic skin, 1 N, seed 0: the noise of
    # the thumb's estimate); a load that outgrows a pinch runs the share up to the friction
    # limit, about 0.5 above the weight share at 1 N.
    slip_rise: float = _param(0.3, 'rise of a finger\'s unasked tangential share over its '
                              'baseline that is a slip')
    slip_window: float = _param(0.5, 'low-pass of the tangential share, and the wait for its '
                                'baseline (s)')
    slip_rate: float = _param(1.0, 'rate the grip rises at while the object slips (N/s)')
    drop_time: float = _param(0.1, 'no contact at every finger this long is a drop (s)')

    def __post_init__(self) -> None:
        gravity = np.asarray(self.gravity, dtype=np.float64)
        if gravity.shape != (3,) or not np.isfinite(gravity).all():
            raise ValueError(f'gravity: 3 finite numbers (m/s^2), got {self.gravity!r}')
        object.__setattr__(self, 'gravity', tuple(float(v) for v in gravity))
        for name in ('force_rate', 'grip_min', 'friction', 'slip_rise', 'slip_window',
                     'slip_rate', 'drop_time'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f'{name}: {value!r} must be a positive number')
        if not 0.0 < self.slip_margin <= 1.0:
            raise ValueError(f'slip_margin: {self.slip_margin!r} must be in (0, 1]')


@dataclass(frozen=True)
class GraspGoal:
    """What to hold: the fingertips (the thumb and another), the grip force each
    presses with (N), the object's mass if known (kg: its weight is then shared), and per finger
    the joint target its approach closes toward (rad; through the object)."""

    fingers: tuple[str, ...]
    grip: float
    targets: Mapping[str, tuple[float, ...]]
    mass: float = 0.0


@dataclass
class FingerGraspState:
    """One fingertip's tick (forces in the base frame)."""

    finger: str
    stage: str                      # 'approach' | 'ramp' | 'hold'
    controller: ControllerState
    desired: np.ndarray             # f_d this tick (zeros before the touch in closed loop)
    estimate: np.ndarray            # f_hat in the base frame (NaN when not fresh)
    normal: float                   # f_hat along d_i (NaN when not fresh)
    tangential: float               # |f_hat - normal d_i| (NaN when not fresh)
    grip: float                     # g_i commanded this tick


@dataclass
class GraspState:
    t: float
    phase: str
    grip: float                     # the grip now asked (the goal's, raised by slip)
    fingers: dict[str, FingerGraspState]
    transitions: list[str] = field(default_factory=list)
    reason: str = ''


def finger_configs(base: ForceControllerConfig, hand, fingers: Iterable[str]
                   ) -> dict[str, ForceControllerConfig]:
    """Each finger's law for a grasp: `base` on that fingertip (its own gains where its links
    differ, ForceControllerConfig.pressing_with), forces in the hand's base frame."""
    return {f: base.pressing_with(hand.array(f'{f}_tip'), hand.base_frame) for f in fingers}


def approach_targets(poses: Mapping[str, tuple[np.ndarray, np.ndarray]], kinematics: Kinematics,
                     lower: np.ndarray, upper: np.ndarray, through: float = THROUGH
                     ) -> dict[str, tuple[float, ...]]:
    """Each finger's joint target from its start pose and the pose where it touches the object
    (finger -> (start, contact), 4 angles each): past the contact by `through` times the way
    from the start to it, within the joint limits (16 each, lower and upper): the approach
    closes through the object, as the single finger's q_d lies past the plate."""
    targets = {}
    for finger, (start, contact) in poses.items():
        start, contact = np.asarray(start, np.float64), np.asarray(contact, np.float64)
        joints = kinematics.finger_joints(finger)
        target = np.clip(contact + through * (contact - start), lower[joints], upper[joints])
        targets[finger] = tuple(float(v) for v in target)
    return targets


def grip_directions(pad_centre, fingers: Iterable[str], q16: np.ndarray
                    ) -> dict[str, np.ndarray]:
    """Each finger's d_i at q16: the unit vector from its tip (pad_centre(q16, finger), base
    frame) toward the grasp's centre, midway between the thumb's tip and the others' mean."""
    fingers = tuple(fingers)
    tips = {f: np.asarray(pad_centre(q16, f), np.float64) for f in fingers}
    others = np.mean([tips[f] for f in fingers if f != 'thumb'], axis=0)
    centre = 0.5 * (tips['thumb'] + others)
    return {f: (centre - tips[f]) / np.linalg.norm(centre - tips[f]) for f in fingers}


def max_grip(kinematics: Kinematics, q16: np.ndarray, fingers: Iterable[str],
             directions: Mapping[str, np.ndarray], weight_share: np.ndarray,
             torque_cap: float) -> float:
    """Largest grip g (N) with every finger's torque J^T (g d + w) + gravity within its joint
    limits (min(torque_cap, firmware clamps)) at q16: what the actuators can press."""
    best = np.inf
    gravity = np.asarray(kinematics.gravity_torques(q16), np.float64)
    for finger in fingers:
        joints = kinematics.finger_joints(finger)
        jacobian = np.asarray(kinematics.fingertip_jacobian(q16, finger), np.float64)
        per_newton = jacobian.T @ directions[finger]
        offset = jacobian.T @ weight_share + gravity[joints]
        limits = np.minimum(torque_cap, finger_torque_limits(finger))
        for a, b, limit in zip(per_newton, offset, limits, strict=True):
            if abs(a) > 1e-12:      # |a g + b| <= limit, g > 0
                best = min(best, (limit - b) / a if a > 0 else (-limit - b) / a)
    return float(max(best, 0.0))


def scene_grip_top(scene, hand, base: ForceControllerConfig) -> float:
    """The largest grip (N) a goal of the grasp scene `scene` may ask at the scene's start pose
    (its hand pose with each finger at its own), as GraspController.check judges it there: the
    scene's object mass and gravity, `base` on each of its fingers. The hand's driver holds that
    pose until the goal, so a launch can refuse a grip above it before anything starts."""
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.hand.pinch import pad
    from tacforce_ros.sim.operator import FINGER_JOINTS
    gravity = np.asarray(scene.grasp['gravity'], np.float64)
    kinematics = HandKinematics.for_hand(hand, gravity=tuple(gravity))
    fingers = tuple(scene.grasp['fingers'])
    q16 = np.asarray(scene.grasp['hand_pose'], np.float64).copy()
    for finger, pose in scene.grasp['fingers'].items():
        q16[FINGER_JOINTS[finger]] = pose['pose']
    configs = finger_configs(base, hand, fingers)
    directions = grip_directions(lambda q, f: pad(hand, kinematics, q, f)[0], fingers, q16)
    share = -scene.grasp_object.mass * gravity / len(fingers)
    return max_grip(kinematics, q16, fingers, directions, share,
                    min(configs[f].torque_cap for f in fingers))


class GraspController:
    """The grasp's fingers under force control. `start(goal, ...)` begins a grasp, `update(...)`
    runs one tick of every finger and returns the 16 joint torques (zeros on joints no finger
    of the grasp drives) and the tick's GraspState, `release()` ends it."""

    def __init__(self, configs: Mapping[str, ForceControllerConfig], kinematics: Kinematics,
                 pad_centre, config: GraspConfig = GraspConfig()) -> None:
        """configs: each finger's law (its gains; force_frame = base_frame, estimate_frame =
        its array's frame). pad_centre(q16, finger) -> its tip's centre, base frame."""
        for finger, cfg in configs.items():
            if cfg.force_frame != cfg.base_frame:
                raise ValueError(f'{finger}: a grasp commands forces in the base frame '
                                 f'({cfg.base_frame}), not {cfg.force_frame}')
        self.configs = dict(configs)
        self.kinematics = kinematics
        self.pad_centre = pad_centre
        self.config = config
        self.goal: GraspGoal | None = None
        self.phase = PHASE_IDLE
        self.sessions: dict[str, FingerSession] = {}

    # ------------------------------------------------------------------ goals

    def check(self, goal: GraspGoal, q16: np.ndarray) -> None:
        """Raise GraspGoalError with the reason when `goal` cannot run from pose q16."""
        if not goal.fingers:
            raise GraspGoalError('no fingers: a grasp needs the thumb and another fingertip')
        unknown = [f for f in goal.fingers if f not in FINGERS]
        if unknown:
            raise GraspGoalError(f'{unknown} are not fingertips of the hand ({list(FINGERS)})')
        missing = [f for f in goal.fingers if f not in self.configs]
        if missing:
            raise GraspGoalError(f'{missing} have no force model here (fingertips with one: '
                                 f'{sorted(self.configs)})')
        if 'thumb' not in goal.fingers or len(goal.fingers) < 2 or \
                len(set(goal.fingers)) != len(goal.fingers):
            raise GraspGoalError(f'{list(goal.fingers)}: a grasp opposes the thumb to another '
                                 'fingertip, each named once')
        if len(goal.fingers) > 2:
            raise GraspGoalError(f'{list(goal.fingers)}: more than one fingertip against the '
                                 'thumb is not built yet (the thumb would have to press as hard '
                                 'as the others together)')
        for finger in goal.fingers:
            target = np.asarray(goal.targets.get(finger, ()), dtype=np.float64)
            if target.shape != (4,) or not np.isfinite(target).all():
                raise GraspGoalError(f'{finger}: its target must be 4 finite joint angles (rad)')
        if not (np.isfinite(goal.mass) and goal.mass >= 0.0):
            raise GraspGoalError(f'mass {goal.mass!r} kg: must be a number >= 0')
        cfg = self.config
        directions = self._directions(goal.fingers, q16)
        share = self._weight_share(goal)
        cap = min(self.configs[f].torque_cap for f in goal.fingers)
        top = max_grip(self.kinematics, q16, goal.fingers, directions, share, cap)
        if not (np.isfinite(goal.grip) and cfg.grip_min <= goal.grip <= top):
            raise GraspGoalError(
                f'grip {goal.grip!r} N is outside the safe range {cfg.grip_min:g}-{top:.2f} N: '
                f'below {cfg.grip_min:g} N the estimate cannot tell it from noise; above '
                f'{top:.2f} N a joint of the grasp would need more than its torque limit '
                f'({cap:g} N m cap within the firmware clamps) at this pose')
        weight = float(np.linalg.norm(share))
        needed = weight / (cfg.friction * cfg.slip_margin)
        if weight and goal.grip < needed:
            raise GraspGoalError(
                f'grip {goal.grip:g} N cannot carry {goal.mass:g} kg: each finger bears '
                f'{weight:.2f} N of its weight, which needs at least {needed:.2f} N of grip at '
                f'friction {cfg.friction:g} within {cfg.slip_margin:.0%} of the cone')

    def start(self, goal: GraspGoal, q16: np.ndarray) -> None:
        """Begin `goal` (checked: GraspGoalError) from pose q16; a running grasp is replaced."""
        self.check(goal, q16)
        self.goal = goal
        self.grip = float(goal.grip)
        self.directions = self._directions(goal.fingers, q16)
        self.share = self._weight_share(goal)
        self.top = max_grip(self.kinematics, q16, goal.fingers, self.directions, self.share,
                            min(self.configs[f].torque_cap for f in goal.fingers))
        self.sessions = {f: FingerSession(dataclasses.replace(
            self.configs[f], q_d=tuple(float(v) for v in goal.targets[f])), self.kinematics)
            for f in goal.fingers}
        self._ramp_from: dict[str, tuple[float, float]] = {}    # finger -> (t, g at the start)
        self._lost_since: float | None = None
        self._baseline: dict[str, float] = {}     # finger -> tangential / normal at the hold
        self._share: dict[str, float] = {}        # finger -> its low-passed share now
        self._held_since: float | None = None
        self._saturated = False                   # some finger's torque at the last tick
        self._q_timeout = min(self.configs[f].joints_timeout for f in goal.fingers)
        self._t: float | None = None
        self.phase = PHASE_CLOSING

    def release(self) -> None:
        """End the grasp: no finger is driven from here (the caller opens the hand)."""
        self.goal, self.sessions, self.phase = None, {}, PHASE_IDLE

    # ------------------------------------------------------------------ tick

    def update(self, t: float, q: np.ndarray, qdot: np.ndarray,
               estimates: Mapping[str, tuple[np.ndarray, float]], q_age: float
               ) -> tuple[np.ndarray, GraspState]:
        """One tick. estimates: finger -> (f_hat in its array's frame, its age in s; inf for
        none). Returns the 16 joint torques and the state."""
        tau = np.zeros(16)
        if self.goal is None:
            return tau, GraspState(float(t), PHASE_IDLE, 0.0, {})
        cfg = self.config
        elapsed = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        q = np.asarray(q, dtype=np.float64)
        # A stale or broken joint reading keeps the last line (each finger's watchdog fades its
        # torque out meanwhile).
        joints_ok = bool(q.shape == (16,) and np.isfinite(q).all() and q_age <= self._q_timeout)
        if joints_ok:
            self.directions = self._directions(self.sessions, q)
        directions = self.directions
        states, transitions, ticks = {}, [], {}
        for finger, session in self.sessions.items():
            f_hat, age = estimates.get(finger, (np.full(3, np.nan), np.inf))
            f_hat = np.asarray(f_hat, dtype=np.float64)
            fresh = joints_ok and session.controller.estimate_fresh(f_hat, age)
            base = self._to_base(q, finger, f_hat) if fresh else np.full(3, np.nan)
            d = directions[finger]
            normal = float(base @ d) if fresh else float('nan')
            started = self._ramp_from.get(finger)
            # The ramp starts at the tick after the touch (the session finds the touch in its
            # update), or where the approach ended without one (at its target: the P term
            # presses there; open loop: from engaging).
            touched = session.engaged and (session.controller.open_loop or (
                session.approach is not None and session.approach.done))
            if started is None and touched:
                start_grip = 0.0 if session.controller.open_loop or not fresh else \
                    min(max(normal, 0.0), self.grip)
                started = self._ramp_from[finger] = (float(t), start_grip)
                if not session.controller.open_loop and joints_ok:
                    # The P term's target, ahead of the finger while it closed, moves to where
                    # the finger is: from here the grasp presses by its force command alone.
                    session.controller.set_position_target(q[session.joints])
            grip = 0.0 if started is None or self.phase == PHASE_DROPPED else min(
                self.grip, started[1] + cfg.force_rate * (t - started[0]))
            ticks[finger] = (f_hat, age, base, normal, grip, started)
        # The internal force: the fingers' squeeze, commanded and as the estimates read it. It
        # is integrated only while every finger presses (the law integrates only under a
        # command), every closed-loop estimate is fresh (one finger's error alone would be the
        # single finger's law), and no finger's torque was saturated at the last tick (its
        # integral would skip a step the others take): so the fingers' corrections stay equal.
        closed = [f for f, s in self.sessions.items() if not s.controller.open_loop]
        integrate = (self.phase != PHASE_DROPPED and not self._saturated
                     and all(ticks[f][5] is not None and ticks[f][4] > 0.0 for f in ticks)
                     and all(np.isfinite(ticks[f][3]) for f in closed))
        internal = 0.0
        if integrate and closed:
            internal = float(np.mean([ticks[f][4] for f in ticks])
                             - np.mean([ticks[f][3] for f in closed]))
        for finger, session in self.sessions.items():
            f_hat, age, base, normal, grip, started = ticks[finger]
            d = directions[finger]
            desired = grip * d + grip / self.grip * self.share
            finger_tau, state, transition = session.update(t, q, qdot, f_hat, age, q_age, desired,
                                                           internal * d)
            tau[session.joints] = finger_tau
            if transition is not None:
                transitions.append(f'{finger}: {transition}')
            stage = 'approach' if started is None else ('hold' if grip >= self.grip else 'ramp')
            tangential = float(np.linalg.norm(base - normal * d)) if np.isfinite(normal) else \
                float('nan')
            states[finger] = FingerGraspState(finger, stage, state, state.desired_force,
                                              base, normal, tangential, grip)
        self._saturated = any(s.controller.saturation_scale < 1.0 for s in states.values())
        reason = self._advance(t, elapsed, states, q if joints_ok else None)
        return tau, GraspState(float(t), self.phase, self.grip, states, transitions, reason)

    def _advance(self, t: float, elapsed: float, states: dict[str, FingerGraspState],
                 q: np.ndarray | None) -> str:
        """Move the grasp's phase on from this tick's fingers; returns why it is in it."""
        cfg = self.config
        if self.phase == PHASE_DROPPED:
            return self._dropped
        stages = [s.stage for s in states.values()]
        if 'approach' in stages:
            self.phase = PHASE_CLOSING
            waiting = [f for f, s in states.items() if s.stage == 'approach']
            return f'closing: {", ".join(waiting)} not touching yet'
        self.phase = PHASE_RAMPING if 'ramp' in stages else PHASE_HOLDING
        closed = [s for s in states.values() if not s.controller.mode == 'open_loop']
        if not closed:
            return 'open loop: no estimate to hold by'
        fresh = [s for s in closed if np.isfinite(s.normal)]
        lost = len(fresh) == len(closed) and all(
            np.linalg.norm(s.estimate) < 0.5 * self.configs[s.finger].touch_force for s in fresh)
        if lost:
            self._lost_since = t if self._lost_since is None else self._lost_since
            if t - self._lost_since >= cfg.drop_time:
                self.phase = PHASE_DROPPED
                self._dropped = (f'dropped: no finger has felt the object since '
                                 f'{self._lost_since:.2f} s')
                return self._dropped
        else:
            self._lost_since = None
        if self.phase != PHASE_HOLDING:
            return 'ramping to the grip'
        self._held_since = t if self._held_since is None else self._held_since
        weight = min(1.0, elapsed / cfg.slip_window)
        for s in fresh:
            # A share over a normal force below the touch is the estimate's noise, not a load.
            if s.normal >= self.configs[s.finger].touch_force:
                d = self.directions[s.finger]
                asked = float(np.linalg.norm(s.desired - (s.desired @ d) * d))
                share = (s.tangential - asked) / s.normal
                before = self._share.get(s.finger, share)
                self._share[s.finger] = before + weight * (share - before)
        if t - self._held_since < cfg.slip_window:
            return 'holding'
        for finger, share in self._share.items():
            self._baseline.setdefault(finger, share)
        slipping = [f for f, share in self._share.items()
                    if share > self._baseline[f] + cfg.slip_rise]
        if not slipping:
            return 'holding'
        if q is not None:    # what the joints can press where the fingers are now
            self.top = max_grip(self.kinematics, q, self.sessions, self.directions, self.share,
                                min(self.configs[f].torque_cap for f in self.sessions))
        if self.grip < self.top:
            self.grip = min(self.top, self.grip + cfg.slip_rate * elapsed)
            return f'slip at {", ".join(slipping)}: grip raised to {self.grip:.2f} N'
        return f'slip at {", ".join(slipping)}: grip at the joints\' limit, {self.top:.2f} N'

    # ------------------------------------------------------------------ geometry

    def _directions(self, fingers: Iterable[str], q16: np.ndarray) -> dict[str, np.ndarray]:
        return grip_directions(self.pad_centre, fingers, q16)

    def _weight_share(self, goal: GraspGoal) -> np.ndarray:
        return -goal.mass * np.asarray(self.config.gravity) / len(goal.fingers)

    def _to_base(self, q16: np.ndarray, finger: str, f_hat: np.ndarray) -> np.ndarray:
        cfg = self.configs[finger]
        return np.asarray(self.kinematics.rotation_between(q16, cfg.estimate_frame,
                                                           cfg.base_frame), np.float64) @ f_hat
