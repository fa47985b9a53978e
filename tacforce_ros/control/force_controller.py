"""Fingertip force controller of one finger (paper Sec. IV-C, Eq. full-controller), pure numpy.

    tau = J^T R (f_d + K_i * integral(e_f)) + tau_g - K_d qdot - K_p (q - q_d),  e_f = f_d - f_hat

Sign convention. Every force here is the force the fingertip applies to the environment (what the
F/T sensor under the plate reads and what the estimator is trained against), expressed in
`force_frame` ({F} in the paper). With that convention the integral correction must be ADDED:
the paper prints ``f_d - K_i * integral(e_f)``, which with e_f = f_d - f_hat and a shared sign
convention for f_d and f_hat would be positive feedback; the closed-loop test in
test/control/ checks the sign used here removes a constant plant error.

Around the law, in this order per tick:
1. Watchdog. `f_hat_age` and `q_age` come from the caller. A stale or non-finite estimate ramps
   from the law's torque to a contact hold: the law itself with its force command frozen at that of
   the last fresh tick (f_d + K_i * integral then), open loop, i.e. gravity + PD toward q_d + J^T R
   of that command. At the pose of that tick it is the torque the law gave there, so the fingertip
   keeps pressing as it was (an estimator that stops for a moment must not drop what the finger
   holds; holding the angles of that moment instead would remove the PD term's share of the press),
   and it cannot run off: motion meets the same PD as in closed loop. A command that changes
   meanwhile is not followed (there is no estimate to close the loop on). A linear blend of the two
   saturated torques over `ramp_time` keeps every joint's |torque| within the range between the
   two. Stale joints make every feedback term meaningless (the law would be evaluated at an old q),
   so then the command of the last tick with fresh joints fades linearly to zero: no joint's
   |torque| ever rises above its value at that moment. The integral is frozen while the estimate is
   stale, so that the law resumes where it left off when the estimate returns, and reset once stale
   joints have faded the torque out. When the streams come back, the gains ramp in again at the
   same rate (no torque step). Worst case from the last good message to the hold (or to zero
   torque): timeout + ramp_time + one tick (defaults: 50 + 35 + 10 ms). Each state says why the
   controller is in its mode (`reason`), for the log of its transitions.
2. Integral with a rate limiter (each axis of e_f clipped to `integral_rate_limit` N before
   integrating, so one bad estimate moves the integral by at most that many N s per second),
   clamped to +/- `integral_limit`, and conditional integration: while saturated, a step that
   would push the binding joint further into saturation is not taken (anti-windup). The integral
   only integrates while a force is commanded (f_d != 0): with f_d = 0 there is no contact force
   to regulate, and integrating toward zero parks the tip at the contact boundary, where friction
   holds no shear and the residual shear integral slides it off (measured on the simulated
   spherical plate: 2 of 4 seeds slid off during the paper sequence's 15 s at f_d = 0).
3. Saturation: one common factor s = min(1, min_j limit_j / |tau_j|) with
   limit_j = min(torque_cap, firmware clamp of joint j). All four joints are scaled by s, so the
   firmware's per-joint clamps never act on their own and the direction of tau is kept.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping, Protocol

import numpy as np
import yaml

from tacforce_ros.paths import config_dir
from tacforce_ros.rig import FINGERS, finger_torque_limits

SAME_LINKS_AS_INDEX = ('index', 'middle', 'ring')     # URDF: equal link lengths and inertias

MODE_OPEN_LOOP = 'open_loop'
MODE_CLOSED_LOOP = 'closed_loop'
MODE_SAFE = 'safe'      # watchdog ramp-down in progress (or whole torque off: joints stale)
MODE_HOLD = 'hold'      # contact hold: the law with its force command latched, open loop


class Kinematics(Protocol):
    """What the controller needs from tacforce_ros.hand.kinematics.HandKinematics."""

    def finger_joints(self, finger: str) -> slice: ...
    def fingertip_jacobian(self, q16: np.ndarray, finger: str) -> np.ndarray: ...
    def gravity_torques(self, q16: np.ndarray) -> np.ndarray: ...
    def rotation_between(self, q16: np.ndarray, from_frame: str, to_frame: str) -> np.ndarray: ...


def _param(default: Any, description: str) -> Any:
    """A configuration field with its description (the node's parameter help reads it)."""
    return field(default=default, metadata={'help': description})


def shipped_params_file() -> Path:
    """config/params/force_controller.yaml: the one file where each gain and limit is set, with
    its reason; the configuration's defaults are read from it."""
    return config_dir() / 'params' / 'force_controller.yaml'


@functools.lru_cache(maxsize=1)
def _shipped_group() -> dict:
    doc = yaml.safe_load(shipped_params_file().read_text()) or {}
    for node_params in doc.values():
        params = (node_params or {}).get('ros__parameters', {})
        if 'force_controller' in params:
            return dict(params['force_controller'])
    raise ControllerConfigError(f'{shipped_params_file()}: no "force_controller" group')


def _shipped(name: str) -> Any:
    """One value of the shipped file's `force_controller` group (lists as tuples)."""
    group = _shipped_group()
    if name not in group:
        raise ControllerConfigError(f'{shipped_params_file()}: no force_controller.{name}')
    value = group[name]
    return tuple(value) if isinstance(value, list) else value


class ControllerConfigError(ValueError):
    """A controller configuration that cannot be used; the message names the field."""


def finger_params_file(finger: str) -> Path:
    """The parameters file (config/params/) of a finger whose links differ from the index's."""
    return config_dir() / 'params' / f'force_controller_{finger}.yaml'


@dataclass(frozen=True)
class ForceControllerConfig:
    """Gains and limits of one finger's controller (SI units; vectors are per axis / per joint).

    The defaults are those of config/params/force_controller.yaml (where each value is argued),
    but for estimate_frame: empty, the force frame itself."""

    finger: str = _param(_shipped('finger'),
                         'finger under force control (index, middle, ring, thumb)')
    base_frame: str = _param(_shipped('base_frame'), 'hand base frame of the URDF')
    force_frame: str = _param(_shipped('force_frame'),
                              'frame of f_d and of the integral ({F} = ft_sensor in the paper)')
    estimate_frame: str = _param(
        '', 'frame of the force estimate (the array frame); empty = force_frame')
    k_i: tuple[float, ...] = _param(_shipped('k_i'),
                                    'integral gains per axis (1/s); all zero = open loop')
    k_p: tuple[float, ...] = _param(_shipped('k_p'), 'joint stiffness per finger joint (N m/rad)')
    k_d: tuple[float, ...] = _param(_shipped('k_d'),
                                    'joint damping per finger joint (N m s/rad)')
    q_d: tuple[float, ...] = _param(
        _shipped('q_d'), 'finger joint target (rad), chosen so the fingertip stays in contact')
    torque_cap: float = _param(_shipped('torque_cap'),
                               'largest joint torque (N m), within the firmware clamps')
    integral_rate_limit: float = _param(
        _shipped('integral_rate_limit'),
        '|f_d - f_hat| per axis clipped to this before integrating (N)')
    integral_limit: float = _param(_shipped('integral_limit'), 'integral clamp per axis (N s)')
    estimate_timeout: float = _param(_shipped('estimate_timeout'),
                                     'force estimates older than this are stale (s)')
    joints_timeout: float = _param(_shipped('joints_timeout'),
                                   'joint states older than this are stale (s)')
    ramp_time: float = _param(_shipped('ramp_time'), 'time to ramp to the hold (or zero torque) '
                              'once a stream is stale (s)')
    approach_speed: float = _param(
        _shipped('approach_speed'), 'guarded approach: speed of the position target toward q_d '
        'while a fresh estimate shows no touch yet, its largest joint (rad/s)')
    blind_speed: float = _param(
        _shipped('blind_speed'), 'guarded approach: that speed with no fresh estimate to feel '
        'the touch by (open loop: all the way to q_d) (rad/s; at most approach_speed)')
    touch_force: float = _param(_shipped('touch_force'), 'guarded approach: a fresh estimate '
                                'this large is the touch; the target stops there (N)')

    def __post_init__(self) -> None:
        if self.finger not in FINGERS:
            raise ControllerConfigError(f'finger: {self.finger!r} is not one of {FINGERS}')
        for name, size in (('k_i', 3), ('k_p', 4), ('k_d', 4), ('q_d', 4)):
            values = np.asarray(getattr(self, name), dtype=np.float64)
            if values.shape != (size,) or not np.all(np.isfinite(values)):
                raise ControllerConfigError(f'{name}: expected {size} finite numbers, '
                                            f'got {getattr(self, name)!r}')
            if name != 'q_d' and np.any(values < 0):
                raise ControllerConfigError(f'{name}: gains must be >= 0, got {list(values)}')
            object.__setattr__(self, name, tuple(float(v) for v in values))
        for name in ('torque_cap', 'integral_rate_limit', 'integral_limit', 'estimate_timeout',
                     'joints_timeout', 'ramp_time', 'approach_speed', 'blind_speed',
                     'touch_force'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ControllerConfigError(f'{name}: {value!r} must be a positive number')
            object.__setattr__(self, name, float(value))
        if self.blind_speed > self.approach_speed:
            raise ControllerConfigError(f'blind_speed: {self.blind_speed:g} rad/s is faster than '
                                        f'approach_speed ({self.approach_speed:g} rad/s)')

    @property
    def joint_torque_limits(self) -> np.ndarray:
        """Per-joint limit actually applied: the controller cap within the firmware clamps."""
        return np.minimum(self.torque_cap, finger_torque_limits(self.finger))

    def pressing_with(self, fingertip: Any, rig_frame: str) -> ForceControllerConfig:
        """This configuration on the finger that carries `fingertip` (a hand description's
        TaxelArray), its estimates in that array's frame, f_d in `rig_frame` (the F/T frame of
        the rig as mounted for that finger). Gains and q_d stay where the finger shares the
        index finger's links (URDF: middle, ring); another finger takes them from its own
        parameters file, finger_params_file(finger), which the node loads after the shipped
        one."""
        finger = fingertip.finger
        if finger is None or fingertip.name != f'{finger}_tip':
            raise ControllerConfigError(f'{fingertip.name} is not a fingertip array: the '
                                        'controller pushes with a fingertip')
        config = self
        if finger not in SAME_LINKS_AS_INDEX:
            own = finger_params_file(finger)
            if not own.is_file():
                raise ControllerConfigError(
                    f'{fingertip.name}: k_p, k_d and q_d are sized for {list(SAME_LINKS_AS_INDEX)};'
                    f' the {finger} needs its own in {own}')
            group = ForceControllerConfig.from_yaml(own)
            config = replace(self, k_p=group.k_p, k_d=group.k_d, q_d=group.q_d)
        return replace(config, finger=finger, estimate_frame=fingertip.frame_id,
                       force_frame=rig_frame)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> ForceControllerConfig:
        """From a flat mapping (ROS parameters or YAML); unknown keys are refused."""
        known = {f.name for f in fields(cls)}
        unknown = set(values) - known
        if unknown:
            raise ControllerConfigError(f'unknown controller parameters {sorted(unknown)}; '
                                        f'expected some of {sorted(known)}')
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})

    @classmethod
    def from_yaml(cls, path: str | Path, section: str = 'force_controller'
                  ) -> ForceControllerConfig:
        """From a ROS 2 parameter file: the `<section>` group under any node's ros__parameters."""
        doc = yaml.safe_load(Path(path).read_text()) or {}
        for node_params in doc.values():
            params = (node_params or {}).get('ros__parameters', {})
            if section in params:
                return cls.from_mapping(params[section])
        raise ControllerConfigError(f'{path}: no "{section}" group under ros__parameters')


@dataclass
class ControllerState:
    """What one tick did; mirrors tacforce_msgs/msg/ControllerState (forces in force_frame)."""

    t: float
    mode: str
    desired_force: np.ndarray
    estimated_force: np.ndarray
    integral_error: np.ndarray
    tau_cmd: np.ndarray
    tau_unsaturated: np.ndarray
    saturation_scale: float
    estimate_fresh: bool
    joints_fresh: bool
    estimate_age: float          # s, as the caller gave it (inf: no valid estimate)
    force_gain: float            # 1 normal, ramps to 0 when a stream goes stale
    hold_gain: float             # 1 normal, ramps to 0 only when the joints go stale
    reason: str                  # why this mode: cause, then ': ' and figures if any,
    #                              e.g. 'estimate stale: age 0.061 s > 0.05 s'


@dataclass
class _Memory:
    t: float | None = None
    integral: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force_gain: float = 1.0
    hold_gain: float = 1.0
    f_hold: np.ndarray | None = None    # force command of the contact hold (force_frame)
    f_cmd: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the law's, last fresh tick
    tau: np.ndarray = field(default_factory=lambda: np.zeros(4))   # last command sent
    faded: np.ndarray | None = None     # command latched when the joints went stale
    faded_gain: float = 1.0             # hold_gain at that moment


def ramp(value: float, target: float, step: float) -> float:
    """`value` moved towards `target` by at most `step` (np.clip's arithmetic, on floats)."""
    return float(min(max(target, value - step), value + step))


def saturation_scale(tau: np.ndarray, limits: np.ndarray) -> float:
    """Largest common factor in (0, 1] that brings every |tau_j| within limits_j."""
    over = np.abs(tau) / limits
    # np.maximum.reduce: np.max without its Python wrapper (up to three calls every tick)
    worst = float(np.maximum.reduce(over)) if over.size else 0.0
    return 1.0 if worst <= 1.0 else 1.0 / worst


class ForceController:
    """Eq. full-controller for one finger with rate-limited, anti-windup integral and watchdog.

    `update()` is called once per control tick with time from the caller (sim time works) and
    returns the finger's 4 joint torques (write them to `kinematics.finger_joints(finger)`).
    """

    def __init__(self, config: ForceControllerConfig, kinematics: Kinematics) -> None:
        self.config = config
        self.kinematics = kinematics
        self.joints = kinematics.finger_joints(config.finger)
        self._k_i = np.asarray(config.k_i)
        self._k_p = np.asarray(config.k_p)
        self._k_d = np.asarray(config.k_d)
        self._q_d = np.asarray(config.q_d)
        self._limits = config.joint_torque_limits
        self._mem = _Memory()
        self.open_loop = not np.any(self._k_i)   # K_i = 0: the paper's open loop

    def set_position_target(self, q_d: np.ndarray) -> None:
        """Finger joint target q_d (4,), chosen so the fingertip stays in contact."""
        q_d = np.asarray(q_d, dtype=np.float64)
        if q_d.shape != (4,) or not np.all(np.isfinite(q_d)):
            raise ValueError(f'q_d must be 4 finite joint angles, got {q_d!r}')
        self._q_d = q_d

    def reset(self) -> None:
        """Forget time, integral and watchdog state (e.g. after the sim clock jumped back)."""
        self._mem = _Memory()

    def estimate_fresh(self, f_hat: np.ndarray, f_hat_age: float) -> bool:
        """A force estimate the law may act on: three finite numbers, at most estimate_timeout
        old."""
        f_hat = np.asarray(f_hat, dtype=np.float64)
        return bool(f_hat.shape == (3,) and f_hat_age <= self.config.estimate_timeout
                    and np.isfinite(f_hat).all())

    def _reason(self, joints_fresh: bool, estimate_fresh: bool, q_age: float,
                f_hat_age: float) -> str:
        cfg = self.config
        if not joints_fresh:
            return (f'joints stale: age {q_age:.3f} s > {cfg.joints_timeout:g} s'
                    if q_age > cfg.joints_timeout else 'joints not finite')
        if estimate_fresh or self.open_loop:
            return 'streams fresh'
        if not np.isfinite(f_hat_age):
            return 'no valid estimate'
        return (f'estimate stale: age {f_hat_age:.3f} s > {cfg.estimate_timeout:g} s'
                if f_hat_age > cfg.estimate_timeout else 'estimate not finite')

    def update(self, t: float, q: np.ndarray, qdot: np.ndarray, f_hat: np.ndarray,
               f_hat_age: float, q_age: float, f_d: np.ndarray,
               error: np.ndarray | None = None) -> tuple[np.ndarray, ControllerState]:
        """One tick. q, qdot: all 16 joints (rad, rad/s); f_d: (3,) N in force_frame;
        f_hat in estimate_frame; ages in s (inf for a missing or invalid estimate). `error`:
        what the integral integrates instead of f_d - f_hat (force_frame; used only with a fresh
        estimate): a grasp integrates the error of its internal force alone.
        Returns (tau (4,) Nm, state); state forces are in force_frame."""
        cfg, mem = self.config, self._mem
        q = np.asarray(q, dtype=np.float64)
        qdot = np.asarray(qdot, dtype=np.float64)
        f_d = np.asarray(f_d, dtype=np.float64)
        f_hat = np.asarray(f_hat, dtype=np.float64)
        if q.shape != (16,) or qdot.shape != (16,):
            raise ValueError(f'q and qdot must hold all 16 joints, got {q.shape}, {qdot.shape}')
        if f_d.shape != (3,) or not np.isfinite(f_d).all():
            raise ValueError(f'f_d must be 3 finite numbers, got {f_d!r}')

        # A clock that went back (sim reset) or the first tick: no time has passed.
        if mem.t is not None and t < mem.t:
            self.reset()
            mem = self._mem
        elapsed = 0.0 if mem.t is None else t - mem.t
        mem.t = t

        joints_fresh = bool(q_age <= cfg.joints_timeout and np.isfinite(q).all()
                            and np.isfinite(qdot).all())
        estimate_fresh = self.estimate_fresh(f_hat, f_hat_age)
        reason = self._reason(joints_fresh, estimate_fresh, q_age, f_hat_age)
        step = elapsed / cfg.ramp_time
        # Open loop does not use the estimate, so only closed loop depends on its freshness.
        force_target = 1.0 if joints_fresh and (estimate_fresh or self.open_loop) else 0.0
        mem.force_gain = ramp(mem.force_gain, force_target, step)
        hold_target = 1.0 if joints_fresh else 0.0
        hold_gain_before = mem.hold_gain
        mem.hold_gain = ramp(mem.hold_gain, hold_target, step)

        qf, qdf = q[self.joints], qdot[self.joints]
        if force_target == 0.0 and mem.f_hold is None:
            mem.f_hold = mem.f_cmd
        if mem.hold_gain == 0.0:
            mem.integral = np.zeros(3)          # torque faded out: forget the old correction
        if mem.force_gain == 1.0:
            mem.f_hold = None

        jacobian = np.asarray(self.kinematics.fingertip_jacobian(q, cfg.finger), np.float64)
        rotation = np.asarray(
            self.kinematics.rotation_between(q, cfg.force_frame, cfg.base_frame), np.float64)
        if estimate_fresh and cfg.estimate_frame and cfg.estimate_frame != cfg.force_frame:
            f_hat = np.asarray(self.kinematics.rotation_between(
                q, cfg.estimate_frame, cfg.force_frame), np.float64) @ f_hat
        gravity_damping = (np.asarray(self.kinematics.gravity_torques(q), np.float64)[self.joints]
                           - self._k_d * qdf)

        spring = self._k_p * (qf - self._q_d)   # the same in every torque() of this tick

        def torque(f_cmd: np.ndarray) -> np.ndarray:
            return jacobian.T @ (rotation @ f_cmd) + gravity_damping - spring

        tau_raw = torque(f_d + self._k_i * mem.integral)
        if not estimate_fresh:
            error = np.zeros(3)
        elif error is None:
            error = f_d - f_hat
        else:
            error = np.asarray(error, dtype=np.float64)
        # A long gap between ticks must not integrate as one big step.
        dt = min(elapsed, cfg.estimate_timeout)
        if force_target == 1.0 and dt > 0.0 and not self.open_loop and f_d.any():
            # np.clip's arithmetic (the limits are > 0) without its Python wrapper
            rate = np.minimum(np.maximum(error, -cfg.integral_rate_limit), cfg.integral_rate_limit)
            candidate = np.minimum(np.maximum(mem.integral + dt * rate, -cfg.integral_limit),
                                   cfg.integral_limit)
            tau_candidate = torque(f_d + self._k_i * candidate)
            ratio_before = np.abs(tau_raw) / self._limits
            ratio_after = np.abs(tau_candidate) / self._limits
            binding = int(ratio_before.argmax())
            deepens = (ratio_before[binding] > 1.0
                       and ratio_after[binding] > ratio_before[binding])
            if not deepens:
                mem.integral, tau_raw = candidate, tau_candidate
        if force_target == 1.0:
            mem.f_cmd = f_d + self._k_i * mem.integral

        scale = saturation_scale(tau_raw, self._limits)
        tau = scale * tau_raw
        if mem.f_hold is not None:      # blend the law into the contact hold (or back)
            hold_raw = torque(mem.f_hold)
            hold_scale = saturation_scale(hold_raw, self._limits)
            tau = mem.force_gain * tau + (1.0 - mem.force_gain) * hold_scale * hold_raw
            tau_raw = mem.force_gain * tau_raw + (1.0 - mem.force_gain) * hold_raw
            if mem.force_gain == 0.0:
                scale = hold_scale
        if joints_fresh:
            mem.faded = None
            tau = mem.hold_gain * tau
        else:
            if mem.faded is None:
                mem.faded, mem.faded_gain = mem.tau.copy(), hold_gain_before
            tau = (mem.hold_gain / mem.faded_gain if mem.faded_gain > 0.0 else 0.0) * mem.faded
        mem.tau = tau.copy()

        if force_target == 1.0:     # running, or ramping back in after a stale spell
            mode = MODE_OPEN_LOOP if self.open_loop else MODE_CLOSED_LOOP
        elif joints_fresh and mem.force_gain == 0.0:
            mode = MODE_HOLD
        else:
            mode = MODE_SAFE
        state = ControllerState(
            t=float(t), mode=mode, desired_force=f_d.copy(),
            estimated_force=f_hat.copy() if f_hat.shape == (3,) else np.full(3, np.nan),
            integral_error=mem.integral.copy(), tau_cmd=tau.copy(), tau_unsaturated=tau_raw,
            saturation_scale=scale, estimate_fresh=estimate_fresh, joints_fresh=joints_fresh,
            estimate_age=float(f_hat_age), force_gain=mem.force_gain, hold_gain=mem.hold_gain,
            reason=reason)
        return tau, state
