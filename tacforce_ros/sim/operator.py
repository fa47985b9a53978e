"""The human operator of the calibration rig, as a random but seeded pressing schedule.

The operator presses the array on the plate's indenter again and again, varying the force's
magnitude and direction while pressing, and lets go in between so static (no-contact) segments
exist for offset estimation (paper, section IV-A). Each press has its own contact location on
the array and its own finger pose. The whole schedule of a block is drawn at once, vectorised.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.hand.description import TaxelArray
from tacforce_ros.sim.contact import skin_surface

FINGER_JOINTS = {'index': slice(0, 4), 'middle': slice(4, 8), 'ring': slice(8, 12),
                 'thumb': slice(12, 16)}


@dataclass(frozen=True)
class OperatorParams:
    press_seconds: tuple[float, float] = (2.0, 6.0)
    pause_seconds: tuple[float, float] = (0.6, 2.0)
    normal_force: tuple[float, float] = (0.3, 3.5)   # N, peak normal force of a press
    shear_ratio: float = 0.4          # max |shear| / normal
    ramp_seconds: float = 0.4         # press and release ramps
    wobble_hz: tuple[float, float] = (0.1, 0.8)   # slow modulation of force while pressing
    location_sigma: float = 0.003     # m, contact offset from the chosen taxel
    pose_sigma: float = 0.12          # rad, per-press variation of the finger's joints
    rest_pose: tuple[float, ...] = (0.0, 0.3, 0.3, 0.3) * 3 + (0.8, 0.3, 0.3, 0.3)
    press_pose: tuple[float, float, float, float] = (0.0, 0.8, 0.7, 0.5)
    # The thumb's first joint turns it towards the palm; 0 is outside its range (URDF: 0.263 to
    # 1.396 rad), so its press pose is its own (estimate, inside every thumb joint's range).
    thumb_press_pose: tuple[float, float, float, float] = (0.9, 0.5, 0.6, 0.5)

    @classmethod
    def from_dict(cls, raw: dict) -> OperatorParams:
        fields = cls.__dataclass_fields__
        unknown = set(raw) - set(fields)
        if unknown:
            raise ValueError(f'operator: unknown fields {sorted(unknown)}; known {sorted(fields)}')
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})


@dataclass
class Schedule:
    """Per-step operator output for one block of steps, all in {S0} except q."""
    normal_force: np.ndarray   # (T,) N
    shear: np.ndarray          # (T, 3) N, in the tangent plane
    point: np.ndarray          # (T, 3) m
    normal: np.ndarray         # (T, 3)
    axis: np.ndarray           # (T, 3) indenter axis (cylinder plates)
    q: np.ndarray              # (T, 16) rad
    qdot: np.ndarray           # (T, 16) rad/s


def _smooth_ramp(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def draw_schedule(params: OperatorParams, array: TaxelArray, n_steps: int, dt: float,
                  rng: np.random.Generator, start_q: np.ndarray | None = None) -> Schedule:
    """A pressing schedule of n_steps, starting (and ending) with the finger released."""
    t = np.arange(n_steps) * dt
    normal_force = np.zeros(n_steps)
    shear = np.zeros((n_steps, 3))
    point = np.zeros((n_steps, 3))
    normal = np.zeros((n_steps, 3))
    axis = np.zeros((n_steps, 3))
    rest = np.asarray(params.rest_pose, np.float64)
    # Palm arrays: the operator moves the hand, not a finger; the fingers keep their rest pose.
    joints = FINGER_JOINTS.get(array.finger or '')
    press_pose = np.asarray(params.thumb_press_pose if array.finger == 'thumb'
                            else params.press_pose)
    pose_keys: list[tuple[float, np.ndarray]] = [(0.0, rest if start_q is None else start_q)]
    normals = array.rotations[:, :, 2]
    # Operators press near the middle of the pad more often than on its rim.
    centre = array.positions.mean(axis=0)
    spread = np.linalg.norm(array.positions - centre, axis=1)
    preference = np.exp(-0.5 * (spread / max(spread.max(), 1e-9)) ** 2)
    preference /= preference.sum()
    start = rng.uniform(*params.pause_seconds)
    while True:
        length = rng.uniform(*params.press_seconds)
        end = start + length
        if end + params.pause_seconds[0] > t[-1]:
            break
        k = (t >= start) & (t < end)
        tau = t[k] - start
        envelope = _smooth_ramp(tau / params.ramp_seconds) * _smooth_ramp(
            (length - tau) / params.ramp_seconds)
        wobble = 1.0 + 0.3 * np.sin(2 * np.pi * rng.uniform(*params.wobble_hz) * tau
                                     + rng.uniform(0, 2 * np.pi))
        fn = rng.uniform(*params.normal_force) * envelope * wobble
        taxel = rng.choice(array.n_taxels, p=preference)
        here, n = skin_surface(array.positions, normals,
                               array.positions[taxel] + rng.normal(0.0, params.location_sigma, 3))
        e1 = _unit(np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0]))
        e2 = np.cross(n, e1)
        turn = rng.uniform(0, 2 * np.pi) + rng.uniform(-1.0, 1.0) * tau   # direction sweeps
        ratio = params.shear_ratio * rng.uniform(0.0, 1.0) * np.abs(np.sin(
            2 * np.pi * rng.uniform(*params.wobble_hz) * tau + rng.uniform(0, np.pi)))
        normal_force[k] = fn
        shear[k] = (ratio * fn)[:, None] * (np.cos(turn)[:, None] * e1 + np.sin(turn)[:, None] * e2)
        point[k], normal[k] = here, n
        axis_angle = rng.uniform(0, np.pi)
        axis[k] = np.cos(axis_angle) * e1 + np.sin(axis_angle) * e2
        pose = rest.copy()
        pose_noise = rng.normal(0.0, params.pose_sigma, 4)
        if joints is not None:
            pose[joints] = press_pose + pose_noise
        pose_keys += [(start, pose), (end, pose)]
        start = end + rng.uniform(*params.pause_seconds)
    pose_keys.append((t[-1], pose_keys[-1][1]))
    key_t = np.array([p[0] for p in pose_keys])
    key_q = np.stack([p[1] for p in pose_keys])
    q = np.stack([np.interp(t, key_t, key_q[:, j]) for j in range(16)], axis=1)
    qdot = np.gradient(q, dt, axis=0) if n_steps > 1 else np.zeros_like(q)
    # Where the operator is not pressing, keep a valid geometry for the (inactive) contact.
    idle = normal_force <= 0.0
    point[idle] = array.positions.mean(axis=0)
    normal[idle] = _unit(normals.mean(axis=0))
    axis[idle] = array.rotations[0][:, 0]
    return Schedule(normal_force, shear, point, normal, axis, q, qdot)
